"""Policy tables: the solver's actions, packed to one bit per statistic, in an ``.npz`` file.

File layout (``numpy.savez_compressed``, loaded with ``allow_pickle=False``):

* ``actions``: uint8, the layers' action bits, each layer packed on its own
  (``numpy.packbits``, most significant bit first) and the layers' bytes concatenated.
  Layer ``i`` is a ``(n_timer_values, n_count_tuples(max_count_i))`` boolean array,
  row-major: the bit of statistic ``(z, p2, q2, p3, q3)`` is bit
  ``z * size_i + count_index(p2, q2, p3, q3)`` from the start of the layer's bytes.
* ``metadata``: a JSON string: format name and version, solver version, mode, horizon,
  memory, model parameters and their SHA-256, timer size and the layers' max counts.

Episodic tables hold layers for steps ``t = 1 .. T-1`` (max count t); receding tables
hold one layer (max count M).
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from infomax_contingency.core.model import ModelParams, ParameterError, Statistic
from infomax_contingency.core.statespace import count_index, n_count_tuples

FORMAT_NAME = "infomax_contingency.policy_table"
FORMAT_VERSION = 1
EPISODIC, RECEDING = "episodic", "receding"


class PolicyTableError(ValueError):
    """A policy table that is missing, unreadable, malformed or built for other parameters."""


@dataclass
class PolicyTable:
    """An optimal policy as a lookup table (see the module docstring for the layout)."""

    params: ModelParams
    mode: str
    horizon: int
    memory: int
    layer_max_counts: list[int]
    packed_actions: np.ndarray
    solver_version: int
    values: list[np.ndarray] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self._bytes = self.packed_actions.tobytes()
        self._n_timer = self.params.n_timer_values
        self._layer_sizes = [n_count_tuples(n) for n in self.layer_max_counts]
        self._byte_offsets = [0]
        for size in self._layer_sizes:
            self._byte_offsets.append(self._byte_offsets[-1] + (self._n_timer * size + 7) // 8)

    # ----------------------------------------------------------------------------------
    # Construction

    @classmethod
    def from_packed_layers(
        cls,
        params: ModelParams,
        mode: str,
        horizon: int,
        memory: int,
        max_counts: list[int],
        packed_layers: list[np.ndarray],
        solver_version: int,
    ) -> PolicyTable:
        """Join layers packed with ``numpy.packbits`` (see the module docstring)."""
        packed = np.concatenate(packed_layers) if packed_layers else np.zeros(0, np.uint8)
        return cls(params, mode, horizon, memory, max_counts, packed, solver_version)

    # ----------------------------------------------------------------------------------
    # Lookup

    @property
    def n_statistics(self) -> int:
        """Number of statistics the table holds an action for."""
        return self._n_timer * sum(self._layer_sizes)

    @property
    def n_layers(self) -> int:
        """1 for receding tables; T-1 for episodic tables."""
        return len(self.layer_max_counts)

    def action(self, statistic: Statistic, step: int | None = None) -> int:
        """Optimal action (1 = vocalize) for a statistic; ``step`` t is 1-based (episodic).

        Raises ``IndexError`` for a statistic outside the table: an episodic step outside
        ``1 .. T-1``, counts summing to more than the layer holds, a timer out of range.
        """
        z, p2, q2, p3, q3 = statistic
        if self.mode == EPISODIC:
            if step is None or not 1 <= step < self.horizon:
                raise IndexError(
                    f"episodic table of horizon {self.horizon} has steps 1 .. {self.horizon - 1},"
                    f" got {step}"
                )
            layer = step - 1
        else:
            layer = 0
        if p2 + q2 + p3 + q3 > self.layer_max_counts[layer] or not 0 <= z < self._n_timer:
            raise IndexError(
                f"statistic {tuple(statistic)} is outside the table"
                f" (counts sum <= {self.layer_max_counts[layer]}, z < {self._n_timer})"
            )
        bit = z * self._layer_sizes[layer] + count_index(p2, q2, p3, q3)
        return (self._bytes[self._byte_offsets[layer] + (bit >> 3)] >> (7 - (bit & 7))) & 1

    def layer(self, index: int) -> np.ndarray:
        """Unpacked boolean actions of layer ``index`` (0-based), shape (n_timer, n_tuples)."""
        start, stop = self._byte_offsets[index], self._byte_offsets[index + 1]
        size = self._layer_sizes[index]
        bits = np.unpackbits(self.packed_actions[start:stop], count=self._n_timer * size)
        return bits.astype(bool).reshape(self._n_timer, size)

    # ----------------------------------------------------------------------------------
    # Files

    def metadata(self) -> dict[str, Any]:
        """The JSON metadata record stored with the table."""
        return {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "solver_version": self.solver_version,
            "mode": self.mode,
            "horizon": self.horizon,
            "memory": self.memory,
            "params": self.params.to_dict(),
            "params_sha256": self.params.digest(),
            "n_timer_values": self.params.n_timer_values,
            "layer_max_counts": self.layer_max_counts,
            "n_statistics": self.n_statistics,
        }

    def save(self, path: str | Path) -> None:
        """Write the table as a compressed ``.npz`` file."""
        path = Path(path)
        with path.open("wb") as stream:
            np.savez_compressed(
                stream, actions=self.packed_actions, metadata=np.array(json.dumps(self.metadata()))
            )

    @classmethod
    def load(cls, path: str | Path, expected_params: ModelParams | None = None) -> PolicyTable:
        """Read and validate a table; with ``expected_params``, refuse a foreign table.

        Every problem raises :class:`PolicyTableError` naming the file and what to do.
        """
        path = Path(path)
        how_to_fix = "rebuild it with `infomax-contingency solve` (see policies/README.md)"
        if not path.is_file():
            raise PolicyTableError(f"policy table {path} does not exist ({how_to_fix})")
        try:
            with np.load(path, allow_pickle=False) as archive:
                if "actions" not in archive or "metadata" not in archive:
                    raise PolicyTableError(
                        f"{path} is not a policy table: it lacks the 'actions' or 'metadata'"
                        f" array ({how_to_fix})"
                    )
                packed = archive["actions"]
                metadata = json.loads(str(archive["metadata"]))
        except PolicyTableError:
            raise
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as error:
            raise PolicyTableError(
                f"cannot read policy table {path}: the file is truncated or corrupt"
                f" ({type(error).__name__}: {error}); {how_to_fix}"
            ) from None
        table = cls._from_metadata(path, metadata, packed, how_to_fix)
        if expected_params is not None and table.params != expected_params:
            differences = "; ".join(table.params.differences(expected_params))
            raise PolicyTableError(
                f"policy table {path} was built for other model parameters (table vs expected:"
                f" {differences}); use a table solved for these parameters or {how_to_fix}"
            )
        return table

    @classmethod
    def _from_metadata(
        cls, path: Path, metadata: Any, packed: np.ndarray, how_to_fix: str
    ) -> PolicyTable:
        """Validate the metadata record and the packed array against each other."""
        if not isinstance(metadata, dict) or metadata.get("format") != FORMAT_NAME:
            raise PolicyTableError(f"{path} is not an infomax_contingency policy table")
        if metadata.get("format_version") != FORMAT_VERSION:
            raise PolicyTableError(
                f"{path} has format version {metadata.get('format_version')!r}; this version"
                f" reads {FORMAT_VERSION}: {how_to_fix}"
            )
        try:
            params = ModelParams.from_mapping(metadata["params"], source=f"{path} metadata")
            mode, horizon = metadata["mode"], int(metadata["horizon"])
            memory = int(metadata["memory"])
            max_counts = [int(n) for n in metadata["layer_max_counts"]]
            solver_version = int(metadata["solver_version"])
        except (KeyError, TypeError, ValueError, ParameterError) as error:
            raise PolicyTableError(f"{path} has malformed metadata: {error}") from None
        if params.digest() != metadata.get("params_sha256"):
            raise PolicyTableError(
                f"{path}: the parameter hash does not match the stored parameters (the file"
                f" was edited or damaged); {how_to_fix}"
            )
        if mode == EPISODIC:
            expected_counts = list(range(1, horizon))
        elif mode == RECEDING:
            expected_counts = [memory]
        else:
            raise PolicyTableError(f"{path} has unknown mode {mode!r}")
        if max_counts != expected_counts:
            raise PolicyTableError(
                f"{path}: layer sizes {max_counts[:5]}... do not fit a {mode} table of horizon"
                f" {horizon} and memory {memory}"
            )
        n_bytes = sum((params.n_timer_values * n_count_tuples(n) + 7) // 8 for n in max_counts)
        if packed.dtype != np.uint8 or packed.shape != (n_bytes,):
            raise PolicyTableError(
                f"{path}: action array has shape {packed.shape} and type {packed.dtype}, expected"
                f" ({n_bytes},) uint8 for this table (truncated or damaged); {how_to_fix}"
            )
        return cls(params, mode, horizon, memory, max_counts, packed, solver_version)

    def same_policy_as(self, other: PolicyTable) -> bool:
        """True when both tables hold the same metadata and the same action bits."""
        return self.metadata() == other.metadata() and np.array_equal(
            self.packed_actions, other.packed_actions
        )

"""Policy tables: the solver's actions, packed to one bit per statistic, in an ``.npz`` file.

File layout (a zip archive as ``numpy.savez_compressed`` writes it, two entries):

* ``actions.npy``: uint8, the layers' action bits, each layer packed on its own
  (``numpy.packbits``, most significant bit first) and the layers' bytes concatenated.
  Layer ``i`` is a ``(n_timer_values, n_count_tuples(max_count_i))`` boolean array,
  row-major: the bit of statistic ``(z, p2, q2, p3, q3)`` is bit
  ``z * size_i + count_index(p2, q2, p3, q3)`` from the start of the layer's bytes.
* ``metadata.npy``: a 0-d unicode array holding a JSON object: format name and version,
  solver version, mode, horizon, memory, model parameters and their SHA-256, timer size,
  the layers' max counts, the number of statistics and ``content_sha256``.

``content_sha256`` (format version 2) is the SHA-256 of the canonical JSON of every other
metadata field (sorted keys, no spaces, ASCII), one NUL byte, then the packed action
bytes: a flipped bit or an edited field is refused at load.

Episodic tables hold layers for steps ``t = 1 .. T-1`` (max count t); receding tables
hold one layer (max count M).

Loading trusts nothing in the file: it reads the zip directory and the ``.npy`` headers
first and refuses an entry larger than the table its metadata describes (plus
:data:`SIZE_MARGIN_BYTES`), larger than :data:`MAX_TABLE_BYTES`, or compressed more than
:data:`MAX_COMPRESSION_RATIO` to one, before anything is decompressed or allocated; the
metadata JSON is bounded in size and nesting depth before it is parsed.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import zipfile
import zlib
from dataclasses import dataclass, field
from math import comb
from pathlib import Path
from typing import IO, Any

import numpy as np

from infomax_contingency.core.model import ModelParams, ParameterError, Statistic
from infomax_contingency.core.statespace import count_index, n_count_tuples
from infomax_contingency.limits import refuse_over_budget, written_atomically

FORMAT_NAME = "infomax_contingency.policy_table"
FORMAT_VERSION = 2
"""Version 2 added ``content_sha256``; version 1 tables must be solved again."""
EPISODIC, RECEDING = "episodic", "receding"

ACTIONS_ENTRY, METADATA_ENTRY = "actions.npy", "metadata.npy"
MAX_TABLE_BYTES = 4 * 2**30
"""Largest packed action array (bytes) a table may declare: 32 Gi statistics."""
SIZE_MARGIN_BYTES = 64 * 2**10
"""Slack over the size a table's metadata implies (the .npy header, rounding)."""
LOAD_COPIES = 3
"""Copies of the action bytes a load holds at once (read, digested, kept): its memory is
checked against :func:`~infomax_contingency.limits.memory_budget` before it reads them."""
MAX_COMPRESSION_RATIO = 250
"""Largest uncompressed/compressed size ratio of an entry above 64 KiB (real tables: ~10)."""
MAX_METADATA_CHARS = 16 * 2**10
"""Largest metadata JSON text, characters (real tables: about 600)."""
MAX_JSON_DEPTH = 8
"""Deepest nesting of arrays and objects in the metadata JSON (real tables: 2)."""
MAX_NPY_HEADER_BYTES = 4096
"""Largest ``.npy`` header read (numpy writes 128 bytes)."""
MAX_ZIP_ENTRIES, MAX_ZIP_DIRECTORY_BYTES = 16, 64 * 2**10
"""Largest zip directory parsed (a table: 2 entries, about 200 bytes)."""

READ_ERRORS = (
    zipfile.BadZipFile,
    zlib.error,
    EOFError,
    OSError,
    ValueError,
    UnicodeError,
    NotImplementedError,
    SyntaxError,
    RuntimeError,
    KeyError,
    TypeError,
)
"""What the zip, zlib and .npy readers raise on damaged input (all become one line)."""


class PolicyTableError(ValueError):
    """A policy table that is missing, unreadable, malformed or built for other parameters."""


def canonical_json(record: dict[str, Any]) -> bytes:
    """The canonical JSON bytes of a record: sorted keys, no spaces, ASCII only."""
    return json.dumps(record, sort_keys=True, separators=(",", ":"), ensure_ascii=True).encode()


def content_digest(metadata: dict[str, Any], packed_actions: bytes) -> str:
    """SHA-256 (hex) over the canonical metadata without ``content_sha256``, NUL, the bits."""
    record = {key: value for key, value in metadata.items() if key != "content_sha256"}
    digest = hashlib.sha256(canonical_json(record))
    digest.update(b"\0")
    digest.update(packed_actions)
    return digest.hexdigest()


def table_bytes(n_timer_values: int, layer_max_counts: list[int]) -> int:
    """Packed size (bytes) of a table with these layers (each layer rounded up to a byte)."""
    return sum((n_timer_values * n_count_tuples(n) + 7) // 8 for n in layer_max_counts)


def table_bytes_bound(n_timer_values: int, mode: str, horizon: int, memory: int) -> int:
    """Upper bound of the packed size (bytes) of a table, in closed form (any horizon).

    Episodic: layers ``1 .. T-1`` hold ``n_timer * (C(T + 4, 5) - 1)`` bits, plus at most
    one rounding byte per layer; receding: one layer of ``n_timer * C(M + 4, 4)`` bits.
    """
    if mode == EPISODIC:
        layers = max(horizon - 1, 0)
        bits = n_timer_values * (comb(horizon + 4, 5) - 1) if layers else 0
        return bits // 8 + layers
    return (n_timer_values * n_count_tuples(memory) + 7) // 8


def json_depth(text: str) -> int:
    """Deepest nesting of ``[`` and ``{`` in JSON text, outside strings (no parsing)."""
    depth = deepest = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    return deepest


def resolve_command(metadata: Any) -> str:
    """The ``solve`` command line that rebuilds the table a metadata record describes."""
    how = "infomax-contingency solve --params NAME|FILE"
    if isinstance(metadata, dict) and metadata.get("mode") in (EPISODIC, RECEDING):
        how += f" --mode {metadata['mode']} --horizon {metadata.get('horizon', 'T')}"
        if metadata["mode"] == RECEDING:
            how += f" --memory {metadata.get('memory', 'M')}"
    else:
        how += " --mode MODE --horizon N"
    return how + " --out FILE"


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
        return cls(params.for_table(), mode, horizon, memory, max_counts, packed, solver_version)

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
        z, (p2, q2, p3, q3) = statistic.z, statistic.counts
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
        """The JSON metadata record stored with the table (with its content digest)."""
        record: dict[str, Any] = {
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
        record["content_sha256"] = content_digest(record, self._bytes)
        return record

    def save(self, path: str | Path) -> None:
        """Write the table as a compressed ``.npz`` file.

        The file appears complete or not at all, and only where nothing or a regular file
        was (``limits.written_atomically``: never over a device, FIFO or symbolic link).
        """
        with written_atomically(path, "table file") as stream:
            np.savez_compressed(
                stream,
                actions=self.packed_actions,
                metadata=np.array(json.dumps(self.metadata())),
            )

    @classmethod
    def load(cls, path: str | Path, expected_params: ModelParams | None = None) -> PolicyTable:
        """Read and validate a table; with ``expected_params``, refuse a foreign table.

        Every problem raises :class:`PolicyTableError`, one line naming the file and what
        is wrong (missing, a directory, not a table, truncated, damaged, too large, an
        old format, other parameters); sizes are checked before anything is decompressed.
        """
        reader = _ArchiveReader(Path(path))
        metadata, fields, packed = reader.read()
        table = cls._from_fields(reader, metadata, fields, packed)
        if expected_params is not None and table.params != expected_params.for_table():
            differences = "; ".join(table.params.differences(expected_params.for_table()))
            raise reader.fail(
                f"was built for other model parameters (table vs expected: {differences});"
                f" use a table solved for these parameters or {reader.how_to_fix}"
            )
        return table

    @classmethod
    def _from_fields(
        cls, reader: _ArchiveReader, metadata: dict, fields: _Fields, packed: np.ndarray
    ) -> PolicyTable:
        """Check the (digest-sealed) metadata against itself and the packed array."""
        params = fields.params
        if params.digest() != metadata.get("params_sha256"):
            raise reader.fail(
                "is damaged: the parameter hash does not match the stored parameters;"
                f" {reader.how_to_fix}"
            )
        if fields.mode == EPISODIC:
            expected_counts = list(range(1, fields.horizon))
        else:
            expected_counts = [fields.memory]
        if fields.max_counts != expected_counts:
            raise reader.fail(
                f"is damaged: layer sizes {fields.max_counts[:5]}... do not fit a {fields.mode}"
                f" table of horizon {fields.horizon} and memory {fields.memory}"
            )
        n_bytes = table_bytes(params.n_timer_values, fields.max_counts)
        if packed.shape != (n_bytes,):
            raise reader.fail(
                f"is damaged: action array has shape {packed.shape}, expected ({n_bytes},)"
                f" uint8 for this table (truncated or damaged); {reader.how_to_fix}"
            )
        table = cls(
            params,
            fields.mode,
            fields.horizon,
            fields.memory,
            fields.max_counts,
            packed,
            fields.solver_version,
        )
        if table.metadata() != metadata:
            raise reader.fail(
                "is damaged: its metadata does not describe its actions (extra or derived"
                f" fields differ); {reader.how_to_fix}"
            )
        return table

    def same_policy_as(self, other: PolicyTable) -> bool:
        """True when both tables hold the same metadata and the same action bits."""
        return self.metadata() == other.metadata() and np.array_equal(
            self.packed_actions, other.packed_actions
        )


def _one_line(error: BaseException) -> str:
    """An exception as ``Type: message`` on one line."""
    return f"{type(error).__name__}: {' '.join(str(error).split())}"


@dataclass(frozen=True)
class _Fields:
    """The metadata fields a table is rebuilt from (validated types)."""

    params: ModelParams
    mode: str
    horizon: int
    memory: int
    max_counts: list[int]
    solver_version: int


class _ArchiveReader:
    """Reads one table file with every size checked before it is decompressed."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.how_to_fix = "rebuild it with `infomax-contingency solve` (see policies/README.md)"

    def fail(self, what: str) -> PolicyTableError:
        """The one-line error for this file."""
        return PolicyTableError(f"policy table {self.path} {what}")

    def read(self) -> tuple[dict[str, Any], _Fields, np.ndarray]:
        """Metadata, its fields and the packed actions, every check passed."""
        self._check_path()
        try:
            stream = self.path.open("rb")
        except OSError as error:
            raise self.fail(f"cannot be read ({error.strerror})") from None
        try:
            with stream:
                magic = stream.read(4)
                if not zipfile.is_zipfile(stream):
                    if magic == b"PK\x03\x04":
                        raise self.fail(
                            f"is truncated (its zip directory is missing); {self.how_to_fix}"
                        )
                    raise self.fail("is not a policy table (not a zip archive)")
                self._check_directory_size(stream)
                with zipfile.ZipFile(stream) as archive:
                    return self._read_entries(archive)
        except PolicyTableError:
            raise
        except READ_ERRORS as error:
            raise self.fail(
                f"is damaged or truncated ({_one_line(error)}); {self.how_to_fix}"
            ) from None

    def _check_path(self) -> None:
        if self.path.is_dir():
            raise self.fail("is a directory, not a table file")
        if not self.path.exists():
            raise self.fail(f"does not exist ({self.how_to_fix})")
        if not self.path.is_file():
            raise self.fail("is not a regular file")
        size = self.path.stat().st_size
        if size > MAX_TABLE_BYTES + SIZE_MARGIN_BYTES:
            raise self.fail(f"is too large ({size:,} bytes; at most {MAX_TABLE_BYTES:,})")

    def _check_directory_size(self, stream: IO[bytes]) -> None:
        """Refuse a zip directory of many entries before zipfile parses it into memory.

        Reads the end-of-central-directory record (the last 22 bytes before an archive
        comment of at most 64 KiB): a table lists 2 entries in a few hundred bytes.
        """
        size = stream.seek(0, os.SEEK_END)
        stream.seek(max(0, size - (22 + 0xFFFF)))
        tail = stream.read()
        start = tail.rfind(b"PK\x05\x06")
        if start < 0 or len(tail) - start < 22:
            return  # zipfile itself reports what is wrong
        entries, directory_bytes = struct.unpack("<HL", tail[start + 10 : start + 16])
        if entries > MAX_ZIP_ENTRIES or directory_bytes > MAX_ZIP_DIRECTORY_BYTES:
            raise self.fail(
                f"is not a policy table: its zip directory lists {entries:,} entries in"
                f" {directory_bytes:,} bytes (a table has 2 entries)"
            )

    def _read_entries(self, archive: zipfile.ZipFile) -> tuple[dict, _Fields, np.ndarray]:
        entries = self._check_directory(archive)
        metadata = self._read_metadata(archive, entries[METADATA_ENTRY])
        fields = self._fields(metadata)
        limit = table_bytes_bound(
            fields.params.n_timer_values, fields.mode, fields.horizon, fields.memory
        )
        if limit > MAX_TABLE_BYTES:
            raise self.fail(
                f"is too large: its metadata describes {limit:,} bytes of actions"
                f" (at most {MAX_TABLE_BYTES:,})"
            )
        actions = entries[ACTIONS_ENTRY]
        if actions.file_size > limit + SIZE_MARGIN_BYTES:
            raise self.fail(
                f"is damaged or not what it claims: its action entry holds"
                f" {actions.file_size:,} bytes, more than a {fields.mode} table of horizon"
                f" {fields.horizon} can ({limit:,} bytes plus {SIZE_MARGIN_BYTES:,})"
            )
        refuse_over_budget(
            LOAD_COPIES * actions.file_size,
            f"load policy table {self.path}: its action entry declares {actions.file_size:,}"
            " bytes", "solve a smaller table (a shorter --horizon or --memory)",
            PolicyTableError,
        )
        packed = self._read_actions(archive, actions, limit)
        if metadata.get("content_sha256") != content_digest(metadata, packed.tobytes()):
            raise self.fail(f"is damaged: content digest mismatch; {self.how_to_fix}")
        return metadata, fields, packed

    def _check_directory(self, archive: zipfile.ZipFile) -> dict[str, zipfile.ZipInfo]:
        """The two entries, from the zip directory alone (nothing decompressed)."""
        infos = archive.infolist()
        names = sorted(info.filename for info in infos)
        if names != sorted([ACTIONS_ENTRY, METADATA_ENTRY]):
            shown = ", ".join(names[:4]) + (", ..." if len(names) > 4 else "")
            raise self.fail(
                f"is not a policy table: it holds [{shown}], not the 'actions' and"
                f" 'metadata' arrays ({self.how_to_fix})"
            )
        for info in infos:
            if info.flag_bits & 0x1:
                raise self.fail(f"is not a policy table: entry {info.filename} is encrypted")
            if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                raise self.fail(
                    f"is not a policy table: entry {info.filename} uses compression method"
                    f" {info.compress_type} (tables are deflated or stored)"
                )
            ratio = info.file_size / max(info.compress_size, 1)
            if info.file_size > 64 * 2**10 and ratio > MAX_COMPRESSION_RATIO:
                raise self.fail(
                    f"is refused: entry {info.filename} expands {ratio:,.0f}-fold"
                    f" ({info.compress_size:,} -> {info.file_size:,} bytes; a table expands"
                    f" at most {MAX_COMPRESSION_RATIO}-fold)"
                )
        return {info.filename: info for info in infos}

    def _npy_header(self, stream: IO[bytes], entry: str) -> tuple[tuple, np.dtype]:
        """Shape and dtype from a ``.npy`` header (bounded; nothing allocated)."""
        version = np.lib.format.read_magic(stream)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(stream, MAX_NPY_HEADER_BYTES)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(stream, MAX_NPY_HEADER_BYTES)
        else:
            raise self.fail(f"is not a policy table: {entry} has .npy version {version}")
        return shape, dtype

    def _read_exactly(self, stream: IO[bytes], size: int, entry: str) -> bytes:
        data = stream.read(size)
        if len(data) != size or stream.read(1):
            raise self.fail(f"is damaged: {entry} does not hold what its header declares")
        return data

    def _read_metadata(self, archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> dict:
        """The metadata JSON, bounded in size and depth before it is parsed."""
        limit = 4 * MAX_METADATA_CHARS + MAX_NPY_HEADER_BYTES
        if info.file_size > limit:
            raise self.fail(
                f"is refused: its metadata entry holds {info.file_size:,} bytes (at most {limit:,})"
            )
        with archive.open(info) as stream:
            shape, dtype = self._npy_header(stream, METADATA_ENTRY)
            if shape != () or dtype.kind != "U":
                raise self.fail(
                    f"is not a policy table: its metadata is a {dtype} array of shape {shape},"
                    " not a text"
                )
            if dtype.itemsize > 4 * MAX_METADATA_CHARS:
                raise self.fail(
                    f"is refused: its metadata declares {dtype.itemsize // 4:,} characters"
                    f" (at most {MAX_METADATA_CHARS:,})"
                )
            data = self._read_exactly(stream, dtype.itemsize, METADATA_ENTRY)
        text = str(np.frombuffer(data, dtype=dtype)[0])
        depth = json_depth(text)
        if depth > MAX_JSON_DEPTH:
            raise self.fail(
                f"is refused: its metadata JSON is nested {depth} deep (at most {MAX_JSON_DEPTH})"
            )
        metadata = json.loads(text)
        if not isinstance(metadata, dict) or metadata.get("format") != FORMAT_NAME:
            raise self.fail("is not an infomax_contingency policy table")
        if metadata.get("format_version") != FORMAT_VERSION:
            raise self.fail(
                f"has format version {metadata.get('format_version')!r}; this version reads"
                f" {FORMAT_VERSION}: solve it again with `{resolve_command(metadata)}`"
            )
        return metadata

    def _fields(self, metadata: dict[str, Any]) -> _Fields:
        try:
            fields = _Fields(
                params=ModelParams.from_mapping(metadata["params"], source=f"{self.path} metadata"),
                mode=metadata["mode"],
                horizon=_whole(metadata["horizon"]),
                memory=_whole(metadata["memory"]),
                max_counts=[_whole(n) for n in metadata["layer_max_counts"]],
                solver_version=_whole(metadata["solver_version"]),
            )
        except (KeyError, TypeError, ValueError, ParameterError) as error:
            raise self.fail(f"has malformed metadata: {_one_line(error)}") from None
        if fields.mode not in (EPISODIC, RECEDING):
            raise self.fail(f"has unknown mode {fields.mode!r}")
        return fields

    def _read_actions(
        self, archive: zipfile.ZipFile, info: zipfile.ZipInfo, limit: int
    ) -> np.ndarray:
        """The packed action bytes, their declared shape checked before they are read."""
        with archive.open(info) as stream:
            shape, dtype = self._npy_header(stream, ACTIONS_ENTRY)
            if dtype != np.uint8 or len(shape) != 1:
                raise self.fail(
                    f"is damaged: action array has shape {shape} and type {dtype}, expected"
                    f" a 1-d uint8 array; {self.how_to_fix}"
                )
            if shape[0] > limit:
                raise self.fail(
                    f"is damaged: action array has shape {shape}, more than its metadata"
                    f" allows ({limit:,} bytes); {self.how_to_fix}"
                )
            data = self._read_exactly(stream, shape[0], ACTIONS_ENTRY)
        return np.frombuffer(data, dtype=np.uint8)


def _whole(value: Any) -> int:
    """A JSON whole number >= 0 (no floats, no booleans)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{value!r} is not a whole number >= 0")
    return value

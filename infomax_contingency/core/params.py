"""The model's parameters (MODEL.md sections 1 and 5): periods, prior, Beta priors.

:class:`ModelParams` is one frozen set of them; ``paper`` and ``robot`` are the named sets
(:data:`NAMED_PARAMS`), any other comes from a YAML file. :mod:`infomax_contingency.core.model`
holds what is computed from them and re-exports these names.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from infomax_contingency.limits import finite, load_yaml, short_repr

BETA_FIELDS = ("b11", "b12", "b21", "b22", "b31", "b32")

MAX_TIMER_STEPS = 10_000
"""Largest ``ta2`` (steps): the timer's values are kept as arrays, in the worlds, the
solver and the belief; 10,000 are 83 minutes of 0.5-s windows, far past any reply."""


class ParameterError(ValueError):
    """Model parameters that are invalid or cannot be loaded."""


@dataclasses.dataclass(frozen=True)
class ModelParams:
    """Model parameters (MODEL.md section 1).

    Attributes:
        dt: step (microphone window) length, seconds.
        ts1, ts2: first and last timer value of the self-feedback period, steps.
        ta1, ta2: first and last timer value of the agent period, steps.
        pi: prior probability P(S=1) that a responsive agent is present.
        b11, b12: Beta prior of the self-feedback rate K1.
        b21, b22: Beta prior of the agent-period rate K2 (when S=1).
        b31, b32: Beta prior of the background rate K3 (and of the shared rate when S=0).
        k2_per_lag: False (the paper's model): one agent-period rate K2. True: one rate
            per agent timer value ``ta1 .. ta2``, each with the prior Beta(b21, b22), so
            a partner who answers after a delay of its own is heard at that delay (the
            belief, MODEL.md section 2). Policy tables do not depend on it: they are
            solved for one K2 (:meth:`for_table`).
    """

    dt: float
    ts1: int
    ts2: int
    ta1: int
    ta2: int
    pi: float
    b11: float = 1.0
    b12: float = 1.0
    b21: float = 1.0
    b22: float = 1.0
    b31: float = 1.0
    b32: float = 1.0
    k2_per_lag: bool = False

    def __post_init__(self) -> None:
        self._coerce_types()
        self._check_ranges()

    def _coerce_types(self) -> None:
        """Whole-number periods, float rates and priors, a bool ``k2_per_lag`` (or refuse)."""
        for name in ("ts1", "ts2", "ta1", "ta2"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                if isinstance(value, float) and value.is_integer():
                    object.__setattr__(self, name, int(value))
                else:
                    raise ParameterError(f"{name} must be a whole number of steps,"
                                         f" got {short_repr(value)}")
            object.__setattr__(self, name, int(getattr(self, name)))
        for name in ("dt", "pi", *BETA_FIELDS):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
                raise ParameterError(f"{name} must be a number, got {short_repr(value)}")
            if not finite(value):
                raise ParameterError(f"{name} must be finite, got {short_repr(value)}")
            object.__setattr__(self, name, float(value))
        if not isinstance(self.k2_per_lag, bool | np.bool_):
            raise ParameterError(
                f"k2_per_lag must be true or false, got {short_repr(self.k2_per_lag)}"
            )
        object.__setattr__(self, "k2_per_lag", bool(self.k2_per_lag))

    def _check_ranges(self) -> None:
        """Periods in order and at most :data:`MAX_TIMER_STEPS`, pi in (0, 1), Beta > 0."""
        if self.dt <= 0:
            raise ParameterError(f"dt must be > 0 seconds, got {self.dt}")
        if self.ts1 < 0:
            raise ParameterError(f"ts1 must be >= 0, got {self.ts1}")
        if self.ts2 < self.ts1:
            raise ParameterError(f"ts2 must be >= ts1 (= {self.ts1}), got {self.ts2}")
        if self.ta1 <= self.ts2:
            raise ParameterError(
                f"ta1 must be > ts2 (= {self.ts2}): the agent period follows the self period;"
                f" got ta1 = {self.ta1}"
            )
        if self.ta2 < self.ta1:
            raise ParameterError(f"ta2 must be >= ta1 (= {self.ta1}), got {self.ta2}")
        if self.ta2 > MAX_TIMER_STEPS:
            raise ParameterError(f"ta2 must be at most {MAX_TIMER_STEPS} steps (the timer's"
                                 f" values are kept in arrays), got {self.ta2}")
        if not 0.0 < self.pi < 1.0:
            raise ParameterError(f"pi must lie strictly between 0 and 1, got {self.pi}")
        for name in BETA_FIELDS:
            if getattr(self, name) <= 0:
                raise ParameterError(
                    f"{name} must be > 0 (a Beta prior parameter), got {getattr(self, name)}"
                )

    @property
    def n_timer_values(self) -> int:
        """Number of timer values ``0 .. ta2 + 1``."""
        return self.ta2 + 2

    @property
    def timer_long_ago(self) -> int:
        """The timer value meaning "no vocalization for a long time" (``ta2 + 1``)."""
        return self.ta2 + 1

    @property
    def agent_lags(self) -> int:
        """Agent timer values ``ta1 .. ta2``: the belief's rates K2 with ``k2_per_lag``."""
        return self.ta2 - self.ta1 + 1

    def for_table(self) -> ModelParams:
        """The parameters a policy table is solved for: these with one K2."""
        return dataclasses.replace(self, k2_per_lag=False) if self.k2_per_lag else self

    def to_dict(self) -> dict[str, float | int | bool]:
        """Plain dict of the fields, in declaration order; ``k2_per_lag`` only when true.

        (Left out when false, a set's digest and its files are those of the paper's model.)
        """
        values = dataclasses.asdict(self)
        if not self.k2_per_lag:
            del values["k2_per_lag"]
        return values

    def digest(self) -> str:
        """SHA-256 of the canonical JSON of the parameters (identifies a policy table)."""
        canonical = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()

    def differences(self, other: ModelParams) -> list[str]:
        """Human-readable list of the fields that differ from ``other``."""
        mine, theirs = dataclasses.asdict(self), dataclasses.asdict(other)
        return [f"{k}: {mine[k]!r} != {theirs[k]!r}" for k in mine if mine[k] != theirs[k]]

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], source: str = "parameters") -> ModelParams:
        """Build from a mapping; unknown or missing fields are refused by name."""
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - fields)
        if unknown:
            raise ParameterError(
                f"{source}: unknown model parameter(s) {unknown}; allowed: {sorted(fields)}"
            )
        required = {"dt", "ts1", "ts2", "ta1", "ta2", "pi"}
        missing = sorted(required - set(values))
        if missing:
            raise ParameterError(f"{source}: missing model parameter(s) {missing}")
        try:
            return cls(**values)
        except ParameterError as error:
            raise ParameterError(f"{source}: {error}") from None

    @classmethod
    def named(cls, name: str) -> ModelParams:
        """One of the reference sets of MODEL.md section 5: ``paper`` or ``robot``."""
        try:
            return NAMED_PARAMS[name]
        except KeyError:
            raise ParameterError(
                f"unknown parameter set {name!r}; named sets: {sorted(NAMED_PARAMS)},"
                " or give a YAML file"
            ) from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> ModelParams:
        """Load from a YAML file holding the fields (optionally under a ``model:`` key).

        The file's size and nesting are bounded before it is parsed
        (:func:`~infomax_contingency.limits.load_yaml`).
        """
        path = Path(path)
        try:
            data = load_yaml(path, "parameter file")
        except FileNotFoundError:
            raise ParameterError(f"parameter file {path} does not exist") from None
        except ValueError as error:
            raise ParameterError(str(error)) from None
        if isinstance(data, Mapping) and isinstance(data.get("model"), Mapping):
            data = data["model"]
        if not isinstance(data, Mapping):
            raise ParameterError(
                f"parameter file {path} must hold a mapping of model parameters"
                " (dt, ts1, ts2, ta1, ta2, pi, b11 .. b32, k2_per_lag)"
            )
        return cls.from_mapping(data, source=str(path))

    @classmethod
    def load(cls, name_or_path: str | Path) -> ModelParams:
        """A named set (``paper``, ``robot``) or a YAML file."""
        if str(name_or_path) in NAMED_PARAMS:
            return NAMED_PARAMS[str(name_or_path)]
        path = Path(name_or_path)
        if path.suffix in (".yaml", ".yml") or path.exists():
            return cls.from_yaml(path)
        return cls.named(str(name_or_path))


NAMED_PARAMS: dict[str, ModelParams] = {
    "paper": ModelParams(dt=0.8, ts1=0, ts2=0, ta1=1, ta2=3, pi=0.01),
    # b31, b32: mic_node's default bit source holds K3 near its false_alarm (0.05): a
    # Beta prior of that mean, worth 10 windows (docs/RESULTS.md section 7)
    # k2_per_lag: a partner answers after a delay of its own; one K2 per agent timer value
    # hears it there (docs/RESULTS.md section 7)
    "robot": ModelParams(dt=0.5, ts1=0, ts2=1, ta1=2, ta2=4, pi=0.01, b31=0.5, b32=9.5,
                         k2_per_lag=True),
}

"""The infomax contingency model: parameters, sufficient statistic and exact inference.

This is the one implementation of the statistic ``a = (z, p2, q2, p3, q3)``, its update,
the posterior P(S=1 | a), its entropy, the predictive probability of the next bit and
the posterior rate variances (MODEL.md sections 1-2). Every function that takes counts
accepts numpy arrays and broadcasts, so the solver evaluates millions of statistics at
once and the nodes evaluate one.

Conventions:
    * ``z`` is the timer in steps since the last vocalization, ``0 .. ta2 + 1``;
      ``ta2 + 1`` means "long ago".
    * Periods: :data:`SELF` (``ts1 <= z <= ts2``), :data:`AGENT` (``ta1 <= z <= ta2``),
      :data:`BACKGROUND` (otherwise).
    * Counts ``p_i`` / ``q_i`` are active / inactive bits seen in period i (2 = agent,
      3 = background). Self-period bits are not counted (they carry no information
      about S).
    * Entropies are in bits; log odds are natural logarithms.
    * A window's observation is its bit (0 or 1), ``None`` when the bit is missing, or a
      :class:`Withheld` bit: heard while the robot declared sound of its own (speech,
      motors), observed but not evidence. Both of the last two are left out of the counts,
      which is exact (:class:`StatisticTracker`).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

from infomax_contingency.core.selfsound import Withheld
from infomax_contingency.limits import load_yaml, short_repr


@functools.cache
def _special() -> ModuleType:
    """``scipy.special``, imported on the first call (see :func:`betaln`)."""
    import scipy.special

    return scipy.special


def betaln(a: Any, b: Any) -> Any:
    """``scipy.special.betaln``, loaded on first use.

    scipy.special takes about 0.25 s to import, and most node processes (mic, posture,
    speaker, recorder) never compute a belief: they load this module for its parameters.
    Later calls find it cached (an import statement here cost a few microseconds on each
    of the solver's and simulator's hundreds of thousands of calls).
    """
    return _special().betaln(a, b)


def expit(x: Any) -> Any:
    """``scipy.special.expit`` (the logistic function), loaded on first use (see betaln)."""
    return _special().expit(x)

SELF, AGENT, BACKGROUND = 1, 2, 3
"""Period labels, numbered as in MODEL.md."""

BETA_FIELDS = ("b11", "b12", "b21", "b22", "b31", "b32")

TIE_TOLERANCE = 1e-12
"""Vocalizing must beat silence by more than this many bits of expected (summed) entropy:
ties, and floating-point noise around them, go to silence."""


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

    def __post_init__(self) -> None:  # noqa: C901
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
            if not math.isfinite(float(value)):
                raise ParameterError(f"{name} must be finite, got {short_repr(value)}")
            object.__setattr__(self, name, float(value))
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

    def to_dict(self) -> dict[str, float | int]:
        """Plain dict of the fields, in declaration order."""
        return dataclasses.asdict(self)

    def digest(self) -> str:
        """SHA-256 of the canonical JSON of the parameters (identifies a policy table)."""
        canonical = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()

    def differences(self, other: ModelParams) -> list[str]:
        """Human-readable list of the fields that differ from ``other``."""
        mine, theirs = self.to_dict(), other.to_dict()
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
                " (dt, ts1, ts2, ta1, ta2, pi, b11 .. b32)"
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
    "robot": ModelParams(dt=0.5, ts1=0, ts2=1, ta1=2, ta2=4, pi=0.01, b31=0.5, b32=9.5),
}


# --------------------------------------------------------------------------------------
# Periods and timer


def period_of(params: ModelParams, z: np.ndarray | int) -> np.ndarray | int:
    """Period label (SELF, AGENT, BACKGROUND) of timer value(s) ``z``."""
    if isinstance(z, int | np.integer):  # one step of a simulation: no array needed
        if params.ts1 <= z <= params.ts2:
            return SELF
        return AGENT if params.ta1 <= z <= params.ta2 else BACKGROUND
    z_arr = np.asarray(z)
    labels = np.where(
        (params.ts1 <= z_arr) & (z_arr <= params.ts2),
        SELF,
        np.where((params.ta1 <= z_arr) & (z_arr <= params.ta2), AGENT, BACKGROUND),
    )
    return int(labels) if labels.ndim == 0 else labels


def advance_timer(params: ModelParams, z: np.ndarray | int, u: np.ndarray | int) -> Any:
    """Timer after action ``u``: 0 after a vocalization, else ``min(z + 1, ta2 + 1)``."""
    if isinstance(z, int | np.integer) and isinstance(u, int | np.integer | np.bool_):
        return 0 if u != 0 else min(int(z) + 1, params.ta2 + 1)
    z_next = np.where(np.asarray(u) != 0, 0, np.minimum(np.asarray(z) + 1, params.ta2 + 1))
    return int(z_next) if z_next.ndim == 0 else z_next


# --------------------------------------------------------------------------------------
# Exact inference on counts (vectorised)


def _betaln_of_counts(alpha: float, beta: float, x: Any, y: Any) -> Any:
    """``betaln(alpha + x, beta + y)``; large integer arrays go through a grid of values.

    The grid holds the same betaln values, evaluated once per distinct ``(x, y)``; this
    makes the solver's millions of statistics cheap without a second formula.
    """
    x, y = np.asarray(x), np.asarray(y)
    if x.size > 4096 and x.dtype.kind in "iu" and y.dtype.kind in "iu":
        x_max, y_max = int(x.max()), int(y.max())
        if (x_max + 1) * (y_max + 1) <= x.size:
            grid = betaln(alpha + np.arange(x_max + 1.0)[:, None], beta + np.arange(y_max + 1.0))
            return grid[x, y]
    return betaln(alpha + x, beta + y)


def log_odds(params: ModelParams, p2: Any, q2: Any, p3: Any, q3: Any) -> Any:
    """Log posterior odds ``lam = log P(S=1|a) / P(S=0|a)`` (natural log), exact."""
    b21, b22, b31, b32 = params.b21, params.b22, params.b31, params.b32
    p2, q2, p3, q3 = (np.asarray(v) for v in (p2, q2, p3, q3))
    prior = math.log(params.pi) - math.log1p(-params.pi)
    return (
        prior
        + _betaln_of_counts(b21, b22, p2, q2)
        - betaln(b21, b22)
        + _betaln_of_counts(b31, b32, p3, q3)
        - _betaln_of_counts(b31, b32, p2 + p3, q2 + q3)
    )


def belief_from_log_odds(lam: Any) -> Any:
    """P(S=1) from log odds with a stable sigmoid."""
    return expit(lam)


def entropy_from_log_odds(lam: Any) -> Any:
    """Binary entropy (bits) of the belief, computed stably from the log odds.

    ``H = b softplus(-lam) + (1 - b) softplus(lam)`` in nats, divided by ln 2, which
    stays accurate when the belief is within 1e-300 of 0 or 1.
    """
    lam = np.asarray(lam, dtype=float)
    b = expit(lam)
    nats = b * np.logaddexp(0.0, -lam) + (1.0 - b) * np.logaddexp(0.0, lam)
    return nats / math.log(2.0)


def belief(params: ModelParams, p2: Any, q2: Any, p3: Any, q3: Any) -> Any:
    """P(S=1 | counts), exact."""
    return belief_from_log_odds(log_odds(params, p2, q2, p3, q3))


def entropy(params: ModelParams, p2: Any, q2: Any, p3: Any, q3: Any) -> Any:
    """Entropy of S given the counts, in bits."""
    return entropy_from_log_odds(log_odds(params, p2, q2, p3, q3))


def _beta_mean_of_counts(alpha: float, beta: float, x: Any, y: Any) -> Any:
    """Posterior mean ``(alpha + x) / (alpha + beta + x + y)`` of a Beta-Bernoulli rate.

    Large integer arrays go through a grid of the same values, like :func:`_betaln_of_counts`.
    """
    x, y = np.asarray(x), np.asarray(y)
    if x.size > 4096 and x.dtype.kind in "iu" and y.dtype.kind in "iu":
        x_max, y_max = int(x.max()), int(y.max())
        if (x_max + 1) * (y_max + 1) <= x.size:
            grid_x = alpha + np.arange(x_max + 1.0)[:, None]
            grid = grid_x / (grid_x + beta + np.arange(y_max + 1.0))
            return grid[x, y]
    return (alpha + x) / (alpha + beta + x + y)


def predictive_active(
    params: ModelParams, period: int, p2: Any, q2: Any, p3: Any, q3: Any, b: Any = None
) -> Any:
    """P(y = 1) for the next bit if it falls in ``period`` (AGENT or BACKGROUND).

    ``b`` is the belief P(S=1 | counts); it is computed when not given. For the SELF
    period the bit does not change the statistic and this function is not defined.
    """
    p2, q2, p3, q3 = (np.asarray(v) for v in (p2, q2, p3, q3))
    if b is None:
        b = belief(params, p2, q2, p3, q3)
    pooled = _beta_mean_of_counts(params.b31, params.b32, p2 + p3, q2 + q3)
    if period == AGENT:
        under_s1 = _beta_mean_of_counts(params.b21, params.b22, p2, q2)
    elif period == BACKGROUND:
        under_s1 = _beta_mean_of_counts(params.b31, params.b32, p3, q3)
    else:
        raise ValueError(f"predictive probability is defined for AGENT or BACKGROUND, not {period}")
    return pooled + b * (under_s1 - pooled)


def beta_variance(x: Any, y: Any) -> Any:
    """Variance of Beta(x, y)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    return x * y / ((x + y) ** 2 * (x + y + 1.0))


def rate_variances(params: ModelParams, p2: Any, q2: Any, p3: Any, q3: Any) -> tuple[Any, Any]:
    """``(Var(K2 | a, S=1), Var(K3 | a, S=1))``."""
    return (
        beta_variance(params.b21 + np.asarray(p2), params.b22 + np.asarray(q2)),
        beta_variance(params.b31 + np.asarray(p3), params.b32 + np.asarray(q3)),
    )


def variance_ratio(params: ModelParams, p2: int, q2: int, p3: int, q3: int) -> float | None:
    """``[Var(K2)/n2] / [Var(K3)/n3]`` under S=1; None where n2 or n3 is 0."""
    n2, n3 = p2 + q2, p3 + q3
    if n2 == 0 or n3 == 0:
        return None
    var2, var3 = rate_variances(params, p2, q2, p3, q3)
    return float((var2 / n2) / (var3 / n3))


# --------------------------------------------------------------------------------------
# The statistic


class Statistic(NamedTuple):
    """The sufficient statistic ``(z, p2, q2, p3, q3)`` (MODEL.md section 2)."""

    z: int
    p2: int = 0
    q2: int = 0
    p3: int = 0
    q3: int = 0

    @property
    def counts(self) -> tuple[int, int, int, int]:
        """``(p2, q2, p3, q3)``."""
        return self.p2, self.q2, self.p3, self.q3

    def observe(self, params: ModelParams, y: int | bool) -> Statistic:
        """Count bit ``y`` in the period of the current timer (nothing in the self period)."""
        period = period_of(params, self.z)
        if period == AGENT:
            return self._replace(p2=self.p2 + 1) if y else self._replace(q2=self.q2 + 1)
        if period == BACKGROUND:
            return self._replace(p3=self.p3 + 1) if y else self._replace(q3=self.q3 + 1)
        return self

    def act(self, params: ModelParams, u: int | bool) -> Statistic:
        """Advance the timer with action ``u``."""
        return self._replace(z=advance_timer(params, self.z, int(bool(u))))

    def update(self, params: ModelParams, u: int | bool, y: int | bool) -> Statistic:
        """``a_{t+1} = f(a_t, u_t, y_{t+1})``: advance the timer, then count the bit."""
        return self.act(params, u).observe(params, y)

    def log_odds(self, params: ModelParams) -> float:
        """Log posterior odds of S=1."""
        return float(log_odds(params, *self.counts))

    def belief(self, params: ModelParams) -> float:
        """P(S=1 | a)."""
        return float(belief(params, *self.counts))

    def entropy(self, params: ModelParams) -> float:
        """Entropy of S given a, in bits."""
        return float(entropy(params, *self.counts))

    def variance_ratio(self, params: ModelParams) -> float | None:
        """``[Var(K2)/n2] / [Var(K3)/n3]``; None where undefined."""
        return variance_ratio(params, *self.counts)


def expected_next_entropy(params: ModelParams, statistic: Statistic, u: int) -> float:
    """``sum_y P(y | a, u) H(f(a, u, y))`` in bits: the one-step look-ahead of action u."""
    after_action = statistic.act(params, u)
    period = period_of(params, after_action.z)
    if period == SELF:
        return statistic.entropy(params)
    p_active = float(predictive_active(params, period, *statistic.counts))
    entropy_active = after_action.observe(params, 1).entropy(params)
    entropy_inactive = after_action.observe(params, 0).entropy(params)
    return p_active * entropy_active + (1.0 - p_active) * entropy_inactive


MAX_MEMORY_STEPS = 1_000_000
"""Largest sliding memory the robot's belief keeps, observations (belief_node's
``memory_steps``; the demo refuses a larger ``--memory`` before a node starts)."""


class StatisticTracker:
    """The statistic of a running history, with an optional sliding memory and gaps.

    With ``memory > 0`` the counts are those of the last ``memory`` *counted*
    observations (agent or background period; self-feedback bits carry no information
    and are never counted), so ``n2 + n3 <= memory`` always holds and a receding-horizon
    table indexed by ``n2 + n3 <= M`` never runs out. ``memory = 0`` keeps everything.

    Per step, call :meth:`observe` with the bit ``y_t`` and then :meth:`act` with the
    decision ``u_t`` — the order of the step clock.

    **Gaps, handled exactly.** A listener may miss messages (a node restarted, an
    intruder, a lost sample); nothing is guessed:

    * a missing bit (:meth:`skip_observation`) is not counted. Each window's likelihood
      sums to one over its bit, so leaving it out gives exactly the posterior given the
      bits that were seen;
    * a missing decision (:meth:`act_unknown`), or a stretch of unknown length without
      steps (:meth:`forget_timer`), leaves the timer uncertain: the tracker keeps every
      timer value still possible, and a bit is counted only when all of them put its
      window in the same period (so its likelihood is known). The timer is certain again
      after the next known vocalization, or once ``ta2 + 1`` silent steps have passed.

    A withheld bit (:class:`Withheld`: the window overlapped sound the robot declared as
    its own) is not counted either, for the same reason as a missing one:
    :meth:`observe_window` takes any observation of a step.

    Attributes:
        uncounted: bits not counted because the period of their window was uncertain.
        withheld: bits not counted because they were withheld.
    """

    def __init__(self, params: ModelParams, memory: int = 0, z_initial: int | None = None):
        if memory < 0:
            raise ValueError(f"memory must be >= 0 observations (0 = unbounded), got {memory}")
        self.params = params
        self.memory = memory
        self._z_initial = params.timer_long_ago if z_initial is None else z_initial
        if not 0 <= self._z_initial <= params.timer_long_ago:
            raise ValueError(
                f"z_initial must lie in 0 .. {params.timer_long_ago}, got {self._z_initial}"
            )
        self.uncounted = 0
        self.withheld = 0
        self.reset()

    def reset(self) -> None:
        """Forget the history: zero counts, timer at its initial value (and certain)."""
        self.statistic = Statistic(self._z_initial)
        self._window: deque[tuple[int, bool]] = deque()
        self._other_timers: frozenset[int] = frozenset()

    @property
    def timer_certain(self) -> bool:
        """True when the timer value is known (no missing decision is still in effect)."""
        return not self._other_timers

    @property
    def possible_timers(self) -> frozenset[int]:
        """Every timer value the history allows (one value when it is certain)."""
        return self._other_timers | {self.statistic.z}

    def observe(self, y: int | bool) -> Statistic:
        """Count bit ``y`` at the current timer; returns the new statistic.

        While the timer is uncertain the bit is counted only if every possible timer value
        puts it in the same period (otherwise :attr:`uncounted` grows).
        """
        before = self.statistic
        if self._other_timers:
            periods = {period_of(self.params, z) for z in self.possible_timers}
            if len(periods) > 1:
                self.uncounted += 1
                return before
        after = before.observe(self.params, y)
        if after is not before and self.memory > 0:
            period = period_of(self.params, before.z)
            self._window.append((period, bool(y)))
            if len(self._window) > self.memory:
                old_period, old_bit = self._window.popleft()
                after = _uncount(after, old_period, old_bit)
        self.statistic = after
        return after

    def skip_observation(self) -> Statistic:
        """The bit of this step is missing: nothing is counted (exact, see the class)."""
        return self.statistic

    def observe_window(self, y: int | bool | Withheld | None) -> Statistic:
        """Count what a step observed (a bit); skip a withheld or a missing one.

        A bit is counted as by :meth:`observe`; a :class:`Withheld` bit (counted in
        :attr:`withheld`) and a missing one (``None``) are not.
        """
        if y is None:
            return self.skip_observation()
        if isinstance(y, Withheld):
            self.withheld += 1
            return self.skip_observation()
        return self.observe(y)

    def act(self, u: int | bool) -> Statistic:
        """Advance the timer with decision ``u``; returns the new statistic."""
        self.statistic = self.statistic.act(self.params, u)
        if self._other_timers:
            self._narrow({advance_timer(self.params, z, int(bool(u))) for z in self._other_timers})
        return self.statistic

    def act_unknown(self) -> Statistic:
        """The decision of this step is missing: the timer may have been reset or not."""
        possible = self.possible_timers
        self.statistic = self.statistic.act(self.params, 0)
        self._narrow(
            {advance_timer(self.params, z, u) for z in possible for u in (0, 1)}
        )
        return self.statistic

    def forget_timer(self) -> Statistic:
        """An unknown number (>= 1) of silent windows passed unseen (e.g. a restart)."""
        long_ago = self.params.timer_long_ago
        possible = {
            min(z + k, long_ago) for z in self.possible_timers for k in range(1, long_ago + 1)
        }
        self.statistic = self.statistic._replace(z=min(self.statistic.z + 1, long_ago))
        self._narrow(possible)
        return self.statistic

    def forget_timer_completely(self) -> Statistic:
        """Joining a history in the middle: every timer value is possible."""
        self._narrow(set(range(self.params.n_timer_values)))
        return self.statistic

    def _narrow(self, possible: set[int]) -> None:
        self._other_timers = frozenset(possible - {self.statistic.z})


def _uncount(statistic: Statistic, period: int, bit: bool) -> Statistic:
    """Remove one observation from the counts (sliding memory)."""
    field = {(AGENT, True): "p2", (AGENT, False): "q2", (BACKGROUND, True): "p3"}.get(
        (period, bit), "q3"
    )
    return statistic._replace(**{field: getattr(statistic, field) - 1})

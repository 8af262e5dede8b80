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

import functools
import math
from collections import deque
from types import ModuleType
from typing import Any, NamedTuple

import numpy as np

from infomax_contingency.core.params import (  # noqa: F401  (re-exported: the model's parameters)
    BETA_FIELDS,
    NAMED_PARAMS,
    ModelParams,
    ParameterError,
)
from infomax_contingency.core.selfsound import Withheld


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

TIE_TOLERANCE = 1e-12
"""Vocalizing must beat silence by more than this many bits of expected (summed) entropy:
ties, and floating-point noise around them, go to silence."""


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
    p2, q2, p3, q3 = (np.asarray(v) for v in (p2, q2, p3, q3))
    agent = _betaln_of_counts(params.b21, params.b22, p2, q2)
    return log_odds_of_agent(params, agent, 1, p2, q2, p3, q3)


def log_odds_of_agent(params: ModelParams, agent_betaln: Any, rates: int, p2: Any, q2: Any,
                       p3: Any, q3: Any) -> Any:  # fmt: skip
    """The log posterior odds given the agent bits' evidence under S=1 (MODEL.md section 2).

    ``agent_betaln``: the sum, over the ``rates`` agent rates (one K2, or one per lag),
    of ``lnB(b21 + p, b22 + q)`` of each rate's counts; ``p2``, ``q2`` are all the agent
    bits (under S=0 they share the background's rate).
    """
    b21, b22, b31, b32 = params.b21, params.b22, params.b31, params.b32
    prior = math.log(params.pi) - math.log1p(-params.pi)
    return (
        prior
        + agent_betaln
        - rates * betaln(b21, b22)
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


def per_lag_log_odds(params: ModelParams, lags: tuple[int, ...], p2: int, q2: int, p3: int,
                     q3: int) -> float:  # fmt: skip
    """Log posterior odds of S=1 with one K2 per agent timer value (``k2_per_lag``), exact.

    ``lags``: the active and inactive agent bits at timer ``ta1``, then ``ta1 + 1``, ...
    (:attr:`Statistic.lags`; empty: none yet); ``p2``, ``q2`` are their sums. Under S=1
    each lag's bits are Bernoulli of its own rate, Beta(b21, b22) a priori, and the
    background's of K3; under S=0 every bit is Bernoulli of one rate, Beta(b31, b32).
    """
    counts = np.asarray(lags, dtype=float).reshape(-1, 2)
    agent = np.sum(betaln(params.b21 + counts[:, 0], params.b22 + counts[:, 1]))
    return float(log_odds_of_agent(params, agent, len(counts), p2, q2, p3, q3))


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
    params: ModelParams, period: int, p2: Any, q2: Any, p3: Any, q3: Any, b: Any = None,
    agent_counts: tuple[Any, Any] | None = None,
) -> Any:
    """P(y = 1) for the next bit if it falls in ``period`` (AGENT or BACKGROUND).

    ``b`` is the belief P(S=1 | counts); it is computed when not given. For the SELF
    period the bit does not change the statistic and this function is not defined.
    ``agent_counts``: the active and inactive bits of the agent rate the bit belongs to,
    where it is not the pooled ``p2``, ``q2`` (one K2 per lag: that lag's).
    """
    p2, q2, p3, q3 = (np.asarray(v) for v in (p2, q2, p3, q3))
    if b is None:
        b = belief(params, p2, q2, p3, q3)
    pooled = _beta_mean_of_counts(params.b31, params.b32, p2 + p3, q2 + q3)
    if period == AGENT:
        active, inactive = (p2, q2) if agent_counts is None else agent_counts
        under_s1 = _beta_mean_of_counts(params.b21, params.b22, active, inactive)
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
    """The sufficient statistic ``(z, p2, q2, p3, q3)`` (MODEL.md section 2).

    With ``k2_per_lag`` it also holds :attr:`lags`, the agent counts by timer value; the
    belief and entropy are then those of that model, while policy tables and the rule
    read the pooled ``p2``, ``q2`` (:attr:`counts`).
    """

    z: int
    p2: int = 0
    q2: int = 0
    p3: int = 0
    q3: int = 0
    lags: tuple[int, ...] = ()
    """``k2_per_lag``: active and inactive agent bits at timer ``ta1``, ``ta1 + 1``, ...
    ``ta2`` (``2 * agent_lags`` counts; empty until the first agent bit)."""

    @property
    def counts(self) -> tuple[int, int, int, int]:
        """``(p2, q2, p3, q3)``."""
        return self.p2, self.q2, self.p3, self.q3

    def observe(self, params: ModelParams, y: int | bool) -> Statistic:
        """Count bit ``y`` in the period of the current timer (nothing in the self period)."""
        period = period_of(params, self.z)
        if period == AGENT:
            counted = self._replace(p2=self.p2 + 1) if y else self._replace(q2=self.q2 + 1)
            return counted.count_lag(params, self.z, y, 1) if params.k2_per_lag else counted
        if period == BACKGROUND:
            return self._replace(p3=self.p3 + 1) if y else self._replace(q3=self.q3 + 1)
        return self

    def count_lag(self, params: ModelParams, z: int, y: int | bool, change: int) -> Statistic:
        """:attr:`lags` with the count of bit ``y`` at agent timer ``z`` changed by ``change``."""
        lags = list(self.lags) or [0] * (2 * params.agent_lags)
        lags[2 * (z - params.ta1) + (0 if y else 1)] += change
        return self._replace(lags=tuple(lags) if any(lags) else ())  # (): none, one form

    def act(self, params: ModelParams, u: int | bool) -> Statistic:
        """Advance the timer with action ``u``."""
        return self._replace(z=advance_timer(params, self.z, int(bool(u))))

    def update(self, params: ModelParams, u: int | bool, y: int | bool) -> Statistic:
        """``a_{t+1} = f(a_t, u_t, y_{t+1})``: advance the timer, then count the bit."""
        return self.act(params, u).observe(params, y)

    def log_odds(self, params: ModelParams) -> float:
        """Log posterior odds of S=1 (of the per-lag model with ``k2_per_lag``)."""
        if params.k2_per_lag:
            if self.p2 + self.q2 and not self.lags:
                raise ValueError("agent bits counted without k2_per_lag: keep the statistic"
                                 " with the parameters its belief is asked of")  # fmt: skip
            return per_lag_log_odds(params, self.lags, *self.counts)
        return float(log_odds(params, *self.counts))

    def belief(self, params: ModelParams) -> float:
        """P(S=1 | a)."""
        return float(belief_from_log_odds(self.log_odds(params)))

    def entropy(self, params: ModelParams) -> float:
        """Entropy of S given a, in bits."""
        return float(entropy_from_log_odds(self.log_odds(params)))

    def predictive_active(self, params: ModelParams) -> float:
        """P(y = 1) of a bit counted at the timer ``z`` (an agent or background value)."""
        period = period_of(params, self.z)
        lag = None
        if params.k2_per_lag and period == AGENT:  # this lag's counts
            lag = tuple(self.lags[2 * (self.z - params.ta1):][:2]) if self.lags else (0, 0)
        return float(predictive_active(params, period, *self.counts, b=self.belief(params),
                                       agent_counts=lag))  # fmt: skip

    def variance_ratio(self, params: ModelParams) -> float | None:
        """``[Var(K2)/n2] / [Var(K3)/n3]``; None where undefined."""
        return variance_ratio(params, *self.counts)


def expected_next_entropy(params: ModelParams, statistic: Statistic, u: int) -> float:
    """``sum_y P(y | a, u) H(f(a, u, y))`` in bits: the one-step look-ahead of action u."""
    after_action = statistic.act(params, u)
    period = period_of(params, after_action.z)
    if period == SELF:
        return statistic.entropy(params)
    p_active = after_action.predictive_active(params)
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
      window in the same period, and with ``k2_per_lag`` an agent window at the same
      timer value (so its likelihood is known). The timer is certain again
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
        self._window: deque[tuple[int, bool]] = deque()  # (timer, bit) of each counted bit
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
        puts it in the same period, and with ``k2_per_lag`` an agent bit at the same timer
        (otherwise :attr:`uncounted` grows).
        """
        before = self.statistic
        if self._other_timers:
            rates = {self._rate_of(z) for z in self.possible_timers}
            if len(rates) > 1:
                self.uncounted += 1
                return before
        after = before.observe(self.params, y)
        if after is not before and self.memory > 0:
            self._window.append((before.z, bool(y)))
            if len(self._window) > self.memory:
                old_z, old_bit = self._window.popleft()
                after = _uncount(self.params, after, old_z, old_bit)
        self.statistic = after
        return after

    def _rate_of(self, z: int) -> tuple[int, int | None]:
        """The rate a bit at timer ``z`` is evidence of: its period, and its lag.

        The lag (the timer) only with ``k2_per_lag`` in the agent period; else None.
        """
        period = period_of(self.params, z)
        return period, (z if self.params.k2_per_lag and period == AGENT else None)

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


def _uncount(params: ModelParams, statistic: Statistic, z: int, bit: bool) -> Statistic:
    """Remove one observation, a bit counted at timer ``z``, from the counts (sliding memory)."""
    period = period_of(params, z)
    field = {(AGENT, True): "p2", (AGENT, False): "q2", (BACKGROUND, True): "p3"}.get(
        (period, bit), "q3"
    )
    statistic = statistic._replace(**{field: getattr(statistic, field) - 1})
    if params.k2_per_lag and period == AGENT:
        statistic = statistic.count_lag(params, z, bit, -1)
    return statistic

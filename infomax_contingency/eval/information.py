"""The information bound: how many vocalizations a bit contrast allows at best.

With a partner, the bits of the agent-period windows after a vocalization are active
with probability ``p_agent`` (the model's K2); without one, with ``p_background`` (K3).
Even an observer who knew both rates gains, per vocalization, in expectation

    ``sum over the agent windows of KL(Bern(p_agent) || Bern(p_background))``  nats

(``p_agent`` that window's: one per lag where the lags answer apart)

of log odds for S = 1 when the partner is there (the windows of the agent period are the
only ones whose distribution depends on S; natural logs throughout). The robot's belief
does not know the rates (it integrates over their priors), so it gains less: the
vocalizations this bound gives are a *lower bound* on what any controller and posture
rule need to move the belief from the prior ``pi`` to a threshold.

The bound is an expectation, and it ignores what the belief must learn. What the model's
own belief needs is :func:`belief_crossing`: the exact distribution of the number of
vocalizations after which the model's posterior (its Beta priors on K2 and K3, nothing
known) first exceeds the threshold, when the bits are independent at exactly the given
rates, on a fixed schedule (a number of background windows per vocalization) and with
the whole history (the rooms' belief forgets all but its last 60 steps, which lowers its
chance in long runs). It is a reference, not a bound: it depends on the schedule (fewer
background windows per vocalization leave K3 less known), and settling for good is a
later event than a first crossing. Where a room's runs need clearly more, its bits are
not independent (bursts), or its vocalizations are spaced otherwise.

Agent rates may be given per agent timer value (``ta1 .. ta2``: a partner answers after a
delay of its own). The belief is then the one ``params`` say: with ``k2_per_lag`` one K2
per lag (the robot's), else one K2 for all (the paper's), either exact.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from infomax_contingency.core.model import ModelParams, betaln, log_odds, log_odds_of_agent


def _check_probability(value: float, name: str) -> float:
    if not (isinstance(value, int | float) and 0.0 <= value <= 1.0):
        raise ValueError(f"{name} = {value!r}: must be a probability in [0, 1]")
    return float(value)


def bernoulli_kl(p: float, q: float) -> float:
    """KL(Bern(p) || Bern(q)) in nats; ``inf`` where q puts no mass on an outcome p has."""
    p = _check_probability(p, "p")
    q = _check_probability(q, "q")
    total = 0.0
    for a, b in ((p, q), (1.0 - p, 1.0 - q)):
        if a > 0.0:
            if b == 0.0:
                return math.inf
            total += a * math.log(a / b)
    return total


def agent_window_count(params: ModelParams) -> int:
    """Windows of the agent period after each vocalization (timer ``ta1 .. ta2``)."""
    return params.ta2 - params.ta1 + 1


AgentRates = float | Sequence[float]
"""P(active) of agent windows: one for every lag, or one per agent timer value ``ta1 ..``."""


def lag_rates(agent_windows: int, p_agent: AgentRates) -> tuple[float, ...]:
    """One P(active) per agent window (lag) from ``p_agent`` (one rate: the same at each)."""
    if isinstance(p_agent, int | float):
        return (_check_probability(p_agent, "p_agent"),) * agent_windows
    rates = tuple(p_agent)
    if len(rates) != agent_windows:
        raise ValueError(f"p_agent has {len(rates)} rates: give one per agent window"
                         f" ({agent_windows})")  # fmt: skip
    return tuple(_check_probability(p, "p_agent") for p in rates)


def evidence_per_vocalization(p_agent: AgentRates, p_background: float,
                              agent_windows: int) -> float:  # fmt: skip
    """Expected log-odds gain (nats) per vocalization with the partner there, known rates."""
    if agent_windows < 1:
        raise ValueError(f"agent_windows = {agent_windows!r}: must be >= 1")
    return sum(bernoulli_kl(p, p_background) for p in lag_rates(agent_windows, p_agent))


def evidence_needed(prior: float, target: float) -> float:
    """Log-odds change (nats) from belief ``prior`` to ``target`` (both in (0, 1))."""
    for value, name in ((prior, "prior"), (target, "target")):
        if not 0.0 < value < 1.0:
            raise ValueError(f"{name} = {value!r}: must be in (0, 1)")
    return math.log(target / (1.0 - target)) - math.log(prior / (1.0 - prior))


def vocalizations_bound(
    p_agent: AgentRates, p_background: float, agent_windows: int, prior: float, target: float
) -> float:
    """At least this many vocalizations (expected, ``inf`` for no contrast) to reach ``target``."""
    needed = evidence_needed(prior, target)
    per = evidence_per_vocalization(p_agent, p_background, agent_windows)
    if needed <= 0:
        return 0.0
    return math.inf if per == 0 else needed / per


def agent_rate_needed(
    p_background: float,
    vocalizations: float,
    agent_windows: int,
    prior: float,
    target: float,
    lag_profile: Sequence[float] | None = None,
) -> float | None:
    """The least P(active) in agent windows that allows ``target`` within ``vocalizations``.

    The smallest ``p_agent >= p_background`` whose bound (:func:`vocalizations_bound`) is
    at most ``vocalizations``, to 1e-6 (KL grows with ``p_agent`` above ``p_background``);
    None if even ``p_agent = 1`` is not enough. With ``lag_profile`` (a room's rate per
    lag) the rates keep its shape, ``min(1, c * profile)`` with c searched from where the
    largest is ``p_background``, and their mean is returned.
    """
    if not vocalizations > 0:
        raise ValueError(f"vocalizations = {vocalizations!r}: must be > 0")
    _check_probability(p_background, "p_background")
    needed = evidence_needed(prior, target) / vocalizations
    profile = lag_rates(agent_windows, 1.0 if lag_profile is None else lag_profile)
    if not any(profile):
        return None

    def rates(scale: float) -> tuple[float, ...]:
        return tuple(min(1.0, scale * p) for p in profile)

    low, high = p_background / max(profile), 1.0 / min(p for p in profile if p > 0)
    if evidence_per_vocalization(rates(high), p_background, agent_windows) < needed:
        return None
    while (high - low) * max(profile) > 1e-6:
        middle = 0.5 * (low + high)
        if evidence_per_vocalization(rates(middle), p_background, agent_windows) >= needed:
            high = middle
        else:
            low = middle
    return float(np.mean(rates(high)))


VOCALIZATION_TARGETS = (3, 4, 6)
"""Vocalizations to a correct posture the rooms are held to: quiet and office rooms, babble
rooms, TV rooms (docs/RESULTS.md section 7)."""

MAX_CROSSING_VOCALIZATIONS = 40
"""Most vocalizations :func:`belief_crossing` follows."""
MAX_CROSSING_BACKGROUND_WINDOWS = 100
"""Most background windows per vocalization :func:`belief_crossing` takes (cost grows with it)."""
MAX_CROSSING_WORK = 5 * 10**8
"""Most count tuples x windows :func:`belief_crossing` updates (about 25 ns each here, so at
most about 13 s; measured: 9 background windows and 20 vocalizations with a K2 per lag,
1.8 million tuples, 4.4 * 10**8, 10 s and 160 MB at the peak)."""
NEED_SEARCH_STEPS = 12
"""About how many crossings :func:`agent_rate_the_belief_needs` computes (its bisection)."""
CROSSING_VOCALIZATIONS_FOLLOWED = 20
"""Vocalizations :func:`information_bound` follows for the median (at least its targets)."""


def belief_crossing(
    params: ModelParams,
    p_agent: AgentRates,
    p_background: float,
    background_windows: int,
    target: float,
    vocalizations: int,
) -> np.ndarray:
    """Exact P(the model's belief first exceeds ``target`` after n vocalizations).

    The schedule: ``background_windows`` background windows, then per vocalization its
    self-feedback windows (not counted), its agent windows (``ta1 .. ta2``) and again
    ``background_windows`` background windows. With the partner there, the agent window
    at each lag is active with probability ``p_agent`` (one rate, or one per lag) and
    background windows with ``p_background``, each independently. The belief is the
    model's (``params``: one K2 per lag with ``k2_per_lag``, else one; from the prior
    ``params.pi``, the whole history: no sliding memory), looked at after every window,
    as posture_node does. A crossing in the windows after vocalization n (before
    vocalization n + 1) counts as n vocalizations.

    Returns:
        ``vocalizations + 2`` probabilities: entry n (0 .. ``vocalizations``) that the
        first crossing comes after exactly n vocalizations, the last that it has not come
        by then. They sum to 1. Cost: a dynamic programme over the active counts (of the
        agent windows, or of each lag's, and of the background windows) updated once per
        window: one K2, about 0.1 s for 5 background windows and 20 vocalizations; one
        per lag, about 3 s.
    """
    rates = lag_rates(agent_window_count(params), p_agent)
    _check_crossing_arguments(p_background, background_windows, target, vocalizations)
    threshold = math.log(target) - math.log1p(-target)
    crossing = np.zeros(vocalizations + 2)
    if float(log_odds(params, 0, 0, 0, 0)) > threshold:  # the prior alone is past the target
        crossing[0] = 1.0
        return crossing
    shape = crossing_shape(params, background_windows, vocalizations)
    work = crossing_work(params, background_windows, vocalizations)
    if work > MAX_CROSSING_WORK:
        raise ValueError(f"{work:,} count tuples x windows to follow (at most"
                         f" {MAX_CROSSING_WORK:,}): fewer vocalizations or background windows")
    mass = np.zeros(shape)  # P(these active counts so far and no crossing yet)
    mass[(0,) * len(shape)] = 1.0
    active = np.indices(shape, sparse=True)
    all_active = sum(active[1:], start=active[0])  # every counted window's, for S = 0
    counted = [0] * len(shape)
    for made, lag in _crossing_schedule(len(rates), background_windows, vocalizations):
        axis = len(shape) - 1 if lag is None else (lag if params.k2_per_lag else 0)
        mass = _count_window(mass, axis, p_background if lag is None else rates[lag])
        counted[axis] += 1
        lam = _log_odds_of_counts(params, counted, active, all_active)
        crossed = lam > threshold
        crossing[made] += mass[crossed].sum()
        mass[crossed] = 0.0
    crossing[-1] = mass.sum()
    return crossing


def crossing_shape(params: ModelParams, background_windows: int,
                   vocalizations: int) -> tuple[int, ...]:  # fmt: skip
    """The shape of the count tuples :func:`belief_crossing` follows.

    Its axes: the active agent windows (one axis, or one per lag with ``k2_per_lag``), then
    the background's.
    """
    agent = agent_window_count(params)
    lags = agent if params.k2_per_lag else 1
    per_axis = vocalizations if params.k2_per_lag else agent * vocalizations
    return (per_axis + 1,) * lags + (background_windows * (vocalizations + 1) + 1,)


def crossing_work(params: ModelParams, background_windows: int, vocalizations: int) -> int:
    """Count tuples x counted windows of :func:`belief_crossing` (its cost)."""
    windows = background_windows + vocalizations * (agent_window_count(params)
                                                     + background_windows)  # fmt: skip
    return math.prod(crossing_shape(params, background_windows, vocalizations)) * windows


def _log_odds_of_counts(params: ModelParams, counted: list[int], active: list[np.ndarray],
                        all_active: np.ndarray) -> np.ndarray:  # fmt: skip
    """The belief's log odds at every count tuple (``-inf`` where counts exceed ``counted``).

    Axes as in :func:`belief_crossing`: the agent's (a K2 each), then the background's.
    The model's own formula (:func:`~infomax_contingency.core.model.log_odds_of_agent`),
    given each agent axis's evidence under S = 1; counts beyond those counted are clipped
    to a valid tuple and their log odds set to ``-inf`` (no mass is ever there).
    """
    *agent, background = counted
    clipped = [np.minimum(a, n) for a, n in zip(active, counted, strict=True)]
    evidence = sum(betaln(params.b21 + a, params.b22 + n - a)
                   for a, n in zip(clipped, agent, strict=False))  # fmt: skip
    p2 = sum(clipped[:-1], start=np.zeros((1,) * len(counted), dtype=int))
    p3 = clipped[-1]
    lam = log_odds_of_agent(params, evidence, len(agent), p2, sum(agent) - p2, p3,
                            background - p3)  # fmt: skip
    valid = all_active == sum(clipped, start=np.zeros((1,) * len(counted), dtype=int))
    return np.where(valid, lam, -np.inf)


def _check_crossing_arguments(
    p_background: float, background_windows: int, target: float, vocalizations: int,
) -> None:  # fmt: skip
    """ValueError naming the first argument of :func:`belief_crossing` that is wrong."""
    _check_probability(p_background, "p_background")
    for value, name, most in (
        (background_windows, "background_windows", MAX_CROSSING_BACKGROUND_WINDOWS),
        (vocalizations, "vocalizations", MAX_CROSSING_VOCALIZATIONS),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= most:
            raise ValueError(f"{name} = {value!r}: must be a whole number in 0 .. {most}")
    if not 0.0 < target < 1.0:
        raise ValueError(f"target = {target!r}: must be in (0, 1)")


def _crossing_schedule(
    agent_windows: int, background_windows: int, vocalizations: int
) -> list[tuple[int, int | None]]:
    """(vocalizations made, lag: 0, 1, ...; None: background) of each counted window, in order."""
    per_vocalization = [*range(agent_windows), *[None] * background_windows]
    return [(0, None)] * background_windows + [
        (made, lag) for made in range(1, vocalizations + 1) for lag in per_vocalization
    ]


def _count_window(mass: np.ndarray, axis: int, p_active: float) -> np.ndarray:
    """``mass`` after one more window counted along ``axis``, active with ``p_active``."""
    shifted = np.roll(mass, 1, axis=axis)
    first = [slice(None)] * mass.ndim
    first[axis] = 0
    shifted[tuple(first)] = 0.0
    return (1.0 - p_active) * mass + p_active * shifted


def belief_median_vocalizations(crossing: np.ndarray) -> int | None:
    """The median of :func:`belief_crossing`'s distribution; None if it is not reached."""
    reached = np.flatnonzero(np.cumsum(crossing[:-1]) >= 0.5)
    return int(reached[0]) if reached.size else None


def agent_rate_the_belief_needs(
    params: ModelParams,
    p_background: float,
    background_windows: int,
    target: float,
    vocalizations: int,
    lag_profile: Sequence[float] | None = None,
) -> float | None:
    """The least P(active) in agent windows for which the belief's median is <= ``vocalizations``.

    :func:`belief_crossing` with ``p_agent`` searched to 1e-3 (it assumes the chance of a
    crossing by n vocalizations grows with ``p_agent``: true in practice near one half,
    not proved — the log odds are not monotone in the agent count). With ``lag_profile``
    (a room's P(active) per lag) the rates keep its shape: ``min(1, c * profile)``, c
    searched, and the mean over the lags is returned; else one rate at every lag, from
    ``p_background`` up. None if even every rate 1 is not enough.
    """
    windows = agent_window_count(params)
    profile = lag_rates(windows, 1.0 if lag_profile is None else lag_profile)
    if not any(profile):
        return None
    _check_probability(p_background, "p_background")

    def rates(scale: float) -> tuple[float, ...]:
        return tuple(min(1.0, scale * p) for p in profile)

    def enough(scale: float) -> bool:
        crossing = belief_crossing(
            params, rates(scale), p_background, background_windows, target, vocalizations
        )
        return float(crossing[:-1].sum()) >= 0.5

    low, high = (0.0, 1.0 / min(p for p in profile if p > 0)) if lag_profile is not None else (
        p_background, 1.0)  # fmt: skip
    if not enough(high):
        return None
    while (high - low) * max(profile) > 1e-3:
        middle = 0.5 * (low + high)
        if enough(middle):
            high = middle
        else:
            low = middle
    return float(np.mean(rates(high)))


def information_bound(
    p_agent: float,
    p_background: float,
    params: ModelParams,
    target: float,
    vocalization_targets: tuple[int, ...] = VOCALIZATION_TARGETS,
    background_windows: int | None = None,
    p_agent_lags: Sequence[float] | None = None,
) -> dict[str, object]:
    """The bound for one measured contrast, as plain data.

    Keys: ``nats_per_vocalization`` (:func:`evidence_per_vocalization` with the model's
    agent windows, at ``p_agent_lags`` where given), ``nats_needed`` (from the model's
    prior ``params.pi`` to ``target``), ``vocalizations_bound``
    (:func:`vocalizations_bound`) and ``p_agent_needed``: per number of vocalizations in
    ``vocalization_targets``, the least P(active) (the lags' profile kept where given, else
    the same at every lag) that the bound allows with this ``p_background`` (None: none
    suffices). With ``background_windows``
    (background windows per vocalization), also ``belief``: the model's own belief
    (``params``) on independent bits at these rates (:func:`belief_crossing`, at
    ``p_agent_lags`` where given): its median vocalizations to ``target``, the chance of
    a crossing by each target number, and the least P(agent) for a median within each
    (:func:`agent_rate_the_belief_needs`, keeping the lags' profile).
    """
    windows = agent_window_count(params)
    rates = lag_rates(windows, p_agent if p_agent_lags is None else p_agent_lags)
    belief: dict[str, object] | None = None
    if background_windows is not None:
        if max(vocalization_targets) > MAX_CROSSING_VOCALIZATIONS:
            raise ValueError(f"vocalization targets above {MAX_CROSSING_VOCALIZATIONS}"
                             f" are not followed: {vocalization_targets!r}")  # fmt: skip
        belief = _belief_figures(params, rates, p_background, background_windows, target,
                                 vocalization_targets, p_agent_lags is not None)  # fmt: skip
    return {
        "belief": belief,
        "p_agent": p_agent,
        "p_agent_lags": None if p_agent_lags is None else list(rates),
        "p_background": p_background,
        "nats_per_vocalization": evidence_per_vocalization(rates, p_background, windows),
        "nats_needed": evidence_needed(params.pi, target),
        "vocalizations_bound": vocalizations_bound(
            rates, p_background, windows, params.pi, target
        ),
        "p_agent_needed": {
            str(n): agent_rate_needed(p_background, n, windows, params.pi, target,
                                      None if p_agent_lags is None else rates)  # fmt: skip
            for n in vocalization_targets
        },
    }


def _belief_figures(params: ModelParams, rates: tuple[float, ...], p_background: float,
                    background_windows: int, target: float, vocalization_targets: tuple[int, ...],
                    keep_profile: bool) -> dict[str, object] | None:  # fmt: skip
    """:func:`information_bound`'s ``belief``: the crossing followed as far as its median needs.

    The first entries of a crossing do not depend on how far it is followed: a short one
    first (to the targets and 2 more), the full :data:`CROSSING_VOCALIZATIONS_FOLLOWED`
    only if its median lies beyond (``followed``: how far it was). None where the targets'
    crossings and searches would cost more than :data:`MAX_CROSSING_WORK` (many background
    windows per vocalization: 30 or more with one K2 per lag).
    """
    longest = max(CROSSING_VOCALIZATIONS_FOLLOWED, *vocalization_targets)
    shortest = max(vocalization_targets)
    searches = 1 + NEED_SEARCH_STEPS * len(vocalization_targets)  # with the needs' searches
    if searches * crossing_work(params, background_windows, shortest) > MAX_CROSSING_WORK:
        return None  # too many background windows per vocalization to follow
    lengths = [n for n in (min(shortest + 2, longest), longest)
               if crossing_work(params, background_windows, n) <= MAX_CROSSING_WORK]  # fmt: skip
    for followed in lengths or [shortest]:  # the median may lie beyond those followed
        crossing = belief_crossing(params, rates, p_background, background_windows, target,
                                   followed)  # fmt: skip
        median = belief_median_vocalizations(crossing)
        if median is not None:
            break
    return {
        "background_windows": background_windows,
        "followed": len(crossing) - 2,
        "median_vocalizations": median,
        "p_crossed_by": {str(n): float(crossing[: n + 1].sum()) for n in vocalization_targets},
        "p_agent_needed": {
            str(n): agent_rate_the_belief_needs(params, p_background, background_windows,
                                                target, n, rates if keep_profile else None)
            for n in vocalization_targets
        },
    }

"""The information bound: how many vocalizations a bit contrast allows at best.

With a partner, the bits of the agent-period windows after a vocalization are active
with probability ``p_agent`` (the model's K2); without one, with ``p_background`` (K3).
Even an observer who knew both rates gains, per vocalization, in expectation

    ``agent_windows * KL(Bern(p_agent) || Bern(p_background))``  nats

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
"""

from __future__ import annotations

import math

import numpy as np

from infomax_contingency.core.model import ModelParams, log_odds


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


def evidence_per_vocalization(p_agent: float, p_background: float, agent_windows: int) -> float:
    """Expected log-odds gain (nats) per vocalization with the partner there, known rates."""
    if agent_windows < 1:
        raise ValueError(f"agent_windows = {agent_windows!r}: must be >= 1")
    return agent_windows * bernoulli_kl(p_agent, p_background)


def evidence_needed(prior: float, target: float) -> float:
    """Log-odds change (nats) from belief ``prior`` to ``target`` (both in (0, 1))."""
    for value, name in ((prior, "prior"), (target, "target")):
        if not 0.0 < value < 1.0:
            raise ValueError(f"{name} = {value!r}: must be in (0, 1)")
    return math.log(target / (1.0 - target)) - math.log(prior / (1.0 - prior))


def vocalizations_bound(
    p_agent: float, p_background: float, agent_windows: int, prior: float, target: float
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
) -> float | None:
    """The least P(active) in agent windows that allows ``target`` within ``vocalizations``.

    The smallest ``p_agent >= p_background`` whose bound (:func:`vocalizations_bound`) is
    at most ``vocalizations``, to 1e-6 (KL grows with ``p_agent`` above ``p_background``);
    None if even ``p_agent = 1`` is not enough.
    """
    if not vocalizations > 0:
        raise ValueError(f"vocalizations = {vocalizations!r}: must be > 0")
    needed = evidence_needed(prior, target) / vocalizations
    if evidence_per_vocalization(1.0, p_background, agent_windows) < needed:
        return None
    low, high = _check_probability(p_background, "p_background"), 1.0
    while high - low > 1e-6:
        middle = 0.5 * (low + high)
        if evidence_per_vocalization(middle, p_background, agent_windows) >= needed:
            high = middle
        else:
            low = middle
    return high


VOCALIZATION_TARGETS = (3, 4, 6)
"""Vocalizations to a correct posture the rooms are held to: quiet and office rooms, babble
rooms, TV rooms (docs/RESULTS.md section 7)."""

MAX_CROSSING_VOCALIZATIONS = 40
"""Most vocalizations :func:`belief_crossing` follows."""
MAX_CROSSING_BACKGROUND_WINDOWS = 100
"""Most background windows per vocalization :func:`belief_crossing` takes (cost grows with it)."""
CROSSING_VOCALIZATIONS_FOLLOWED = 20
"""Vocalizations :func:`information_bound` follows for the median (at least its targets)."""


def belief_crossing(
    params: ModelParams,
    p_agent: float,
    p_background: float,
    background_windows: int,
    target: float,
    vocalizations: int,
) -> np.ndarray:
    """Exact P(the model's belief first exceeds ``target`` after n vocalizations).

    The schedule: ``background_windows`` background windows, then per vocalization its
    self-feedback windows (not counted), its agent windows (``ta1 .. ta2``) and again
    ``background_windows`` background windows. With the partner there, agent bits are
    active with probability ``p_agent`` and background bits with ``p_background``, each
    independently. The belief is the model's (:func:`~infomax_contingency.core.model.log_odds`
    from the prior ``params.pi``, the whole history: no sliding memory), looked at after
    every window, as posture_node does. A crossing in the windows after vocalization n
    (before vocalization n + 1) counts as n vocalizations.

    Returns:
        ``vocalizations + 2`` probabilities: entry n (0 .. ``vocalizations``) that the
        first crossing comes after exactly n vocalizations, the last that it has not come
        by then. They sum to 1. Cost: a dynamic programme over the active counts, an
        array of (agent windows x V) x (``background_windows`` x V) entries updated once
        per window, V = ``vocalizations``: about 0.3 s for 5 background windows and 20
        vocalizations, 14 s for 60.
    """
    _check_crossing_arguments(p_agent, p_background, background_windows, target, vocalizations)
    agent = agent_window_count(params)
    threshold = math.log(target) - math.log1p(-target)
    crossing = np.zeros(vocalizations + 2)
    if float(log_odds(params, 0, 0, 0, 0)) > threshold:  # the prior alone is past the target
        crossing[0] = 1.0
        return crossing
    # mass[p2, p3]: P(these active counts so far and no crossing yet)
    mass = np.zeros((agent * vocalizations + 1, background_windows * (vocalizations + 1) + 1))
    mass[0, 0] = 1.0
    p2 = np.arange(mass.shape[0])[:, None]
    p3 = np.arange(mass.shape[1])[None, :]
    counted = [0, 0]  # agent and background windows counted so far
    for made, is_agent in _crossing_schedule(agent, background_windows, vocalizations):
        axis = 0 if is_agent else 1
        mass = _count_window(mass, axis, p_agent if is_agent else p_background)
        counted[axis] += 1
        n2, n3 = counted
        lam = log_odds(params, np.minimum(p2, n2), n2 - np.minimum(p2, n2),
                       np.minimum(p3, n3), n3 - np.minimum(p3, n3))  # fmt: skip
        crossed = (p2 <= n2) & (p3 <= n3) & (lam > threshold)
        crossing[made] += mass[crossed].sum()
        mass[crossed] = 0.0
    crossing[-1] = mass.sum()
    return crossing


def _check_crossing_arguments(
    p_agent: float, p_background: float, background_windows: int, target: float,
    vocalizations: int,
) -> None:  # fmt: skip
    """ValueError naming the first argument of :func:`belief_crossing` that is wrong."""
    _check_probability(p_agent, "p_agent")
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
) -> list[tuple[int, bool]]:
    """(vocalizations made, an agent window?) of each counted window of the schedule, in order."""
    per_vocalization = [True] * agent_windows + [False] * background_windows
    return [(0, False)] * background_windows + [
        (made, is_agent) for made in range(1, vocalizations + 1) for is_agent in per_vocalization
    ]


def _count_window(mass: np.ndarray, axis: int, p_active: float) -> np.ndarray:
    """``mass`` after one more window counted along ``axis``, active with ``p_active``."""
    shifted = np.roll(mass, 1, axis=axis)
    if axis == 0:
        shifted[0, :] = 0.0
    else:
        shifted[:, 0] = 0.0
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
) -> float | None:
    """The least P(active) in agent windows for which the belief's median is <= ``vocalizations``.

    :func:`belief_crossing` with ``p_agent`` searched in ``[p_background, 1]`` to 1e-3
    (it assumes the chance of a crossing by n vocalizations grows with ``p_agent``: true
    in practice near one half, not proved — the log odds are not monotone in the agent
    count); None if even ``p_agent = 1`` is not enough.
    """

    def enough(p_agent: float) -> bool:
        crossing = belief_crossing(
            params, p_agent, p_background, background_windows, target, vocalizations
        )
        return float(crossing[:-1].sum()) >= 0.5

    if not enough(1.0):
        return None
    low, high = _check_probability(p_background, "p_background"), 1.0
    while high - low > 1e-3:
        middle = 0.5 * (low + high)
        if enough(middle):
            high = middle
        else:
            low = middle
    return high


def information_bound(
    p_agent: float,
    p_background: float,
    params: ModelParams,
    target: float,
    vocalization_targets: tuple[int, ...] = VOCALIZATION_TARGETS,
    background_windows: int | None = None,
) -> dict[str, object]:
    """The bound for one measured contrast, as plain data.

    Keys: ``nats_per_vocalization`` (:func:`evidence_per_vocalization` with the model's
    agent windows), ``nats_needed`` (from the model's prior ``params.pi`` to ``target``),
    ``vocalizations_bound`` (:func:`vocalizations_bound`) and ``p_agent_needed``: per
    number of vocalizations in ``vocalization_targets``, the least P(active) in agent
    windows that the bound allows with this ``p_background`` (None: none suffices).
    With ``background_windows`` (background windows per vocalization), also ``belief``:
    the model's own belief on independent bits at these rates (:func:`belief_crossing`):
    its median vocalizations to ``target``, the chance of a crossing by each target
    number, and the least P(agent) for a median within each
    (:func:`agent_rate_the_belief_needs`).
    """
    windows = agent_window_count(params)
    belief: dict[str, object] | None = None
    if background_windows is not None:
        if max(vocalization_targets) > MAX_CROSSING_VOCALIZATIONS:
            raise ValueError(f"vocalization targets above {MAX_CROSSING_VOCALIZATIONS}"
                             f" are not followed: {vocalization_targets!r}")  # fmt: skip
        followed = max(CROSSING_VOCALIZATIONS_FOLLOWED, *vocalization_targets)
        crossing = belief_crossing(
            params, p_agent, p_background, background_windows, target, followed
        )
        belief = {
            "background_windows": background_windows,
            "median_vocalizations": belief_median_vocalizations(crossing),
            "p_crossed_by": {str(n): float(crossing[: n + 1].sum()) for n in vocalization_targets},
            "p_agent_needed": {
                str(n): agent_rate_the_belief_needs(
                    params, p_background, background_windows, target, n
                )
                for n in vocalization_targets
            },
        }
    return {
        "belief": belief,
        "p_agent": p_agent,
        "p_background": p_background,
        "nats_per_vocalization": evidence_per_vocalization(p_agent, p_background, windows),
        "nats_needed": evidence_needed(params.pi, target),
        "vocalizations_bound": vocalizations_bound(
            p_agent, p_background, windows, params.pi, target
        ),
        "p_agent_needed": {
            str(n): agent_rate_needed(p_background, n, windows, params.pi, target)
            for n in vocalization_targets
        },
    }

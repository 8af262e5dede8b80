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
"""

from __future__ import annotations

import math

from infomax_contingency.core.model import ModelParams


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


VOCALIZATION_TARGETS = (3, 4, 8)
"""Issue 13's targets, vocalizations to a correct posture: quiet room, office, poster session."""


def information_bound(
    p_agent: float,
    p_background: float,
    params: ModelParams,
    target: float,
    vocalization_targets: tuple[int, ...] = VOCALIZATION_TARGETS,
) -> dict[str, object]:
    """The bound for one measured contrast, as plain data.

    Keys: ``nats_per_vocalization`` (:func:`evidence_per_vocalization` with the model's
    agent windows), ``nats_needed`` (from the model's prior ``params.pi`` to ``target``),
    ``vocalizations_bound`` (:func:`vocalizations_bound`) and ``p_agent_needed``: per
    number of vocalizations in ``vocalization_targets``, the least P(active) in agent
    windows that the bound allows with this ``p_background`` (None: none suffices).
    """
    windows = agent_window_count(params)
    return {
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

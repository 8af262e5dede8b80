"""Reference implementations that share nothing with the core but the parameters.

They work on explicit histories of ``(period, bit)`` events, compute likelihoods by
direct counting, and enumerate every action/observation history. Slow, obviously
correct, for small cases only.
"""

from __future__ import annotations

import math

from scipy.special import betaln

from infomax_contingency.core.model import ModelParams

SELF, AGENT, BACKGROUND = "self", "agent", "background"


def period(params: ModelParams, z: int) -> str:
    """Period of timer value z, straight from the table in MODEL.md section 1."""
    if params.ts1 <= z <= params.ts2:
        return SELF
    if params.ta1 <= z <= params.ta2:
        return AGENT
    return BACKGROUND


def evidence(params: ModelParams, z: int) -> str | tuple[str, int]:
    """What a bit at timer z is evidence of: its period, or ``(AGENT, z)`` with k2_per_lag.

    (Each agent timer value its own rate, MODEL.md section 2.)
    """
    where = period(params, z)
    return (AGENT, z) if where == AGENT and params.k2_per_lag else where


def next_timer(params: ModelParams, z: int, u: int) -> int:
    """Timer after action u."""
    return 0 if u else min(z + 1, params.ta2 + 1)


def log_marginals(params: ModelParams, events: list[tuple[object, int]]) -> tuple[float, float]:
    """``log P(agent/background bits | S=1)`` and ``| S=0``, by direct counting.

    An event's place is SELF (not counted), BACKGROUND, or an agent rate: AGENT, or
    ``(AGENT, z)`` for one rate per agent timer value (:func:`evidence`); under S=1 each
    agent rate has its own Beta(b21, b22) prior, under S=0 every bit shares one rate.
    """
    ones: dict[object, int] = {}
    zeros: dict[object, int] = {}
    for where, bit in events:
        if where != SELF:
            (ones if bit else zeros)[where] = (ones if bit else zeros).get(where, 0) + 1
    b21, b22, b31, b32 = params.b21, params.b22, params.b31, params.b32
    log_s1 = 0.0
    for where in set(ones) | set(zeros):
        a, b = (b31, b32) if where == BACKGROUND else (b21, b22)
        log_s1 += betaln(a + ones.get(where, 0), b + zeros.get(where, 0)) - betaln(a, b)
    log_s0 = betaln(b31 + sum(ones.values()), b32 + sum(zeros.values())) - betaln(b31, b32)
    return log_s1, log_s0


def log_evidence(params: ModelParams, events: list[tuple[str, int]]) -> float:
    """``log P(history)`` of the agent/background bits, mixing over S."""
    log_s1, log_s0 = log_marginals(params, events)
    return math.log(params.pi * math.exp(log_s1) + (1 - params.pi) * math.exp(log_s0))


def belief(params: ModelParams, events: list[tuple[str, int]]) -> float:
    """P(S=1 | history) by Bayes' rule on the marginal likelihoods."""
    log_s1, log_s0 = log_marginals(params, events)
    s1 = params.pi * math.exp(log_s1)
    return s1 / (s1 + (1 - params.pi) * math.exp(log_s0))


def entropy_bits(b: float) -> float:
    """Binary entropy in bits."""
    return -sum(p * math.log2(p) for p in (b, 1 - b) if p > 0)


def probability_of_bit(
    params: ModelParams, events: list[tuple[str, int]], where: str, y: int
) -> float:
    """``P(y | history)`` for a bit in period ``where``, as a ratio of evidences."""
    if where == SELF:  # K1 is its own Beta-Bernoulli rate
        ones = sum(bit for w, bit in events if w == SELF)
        count = sum(1 for w, _ in events if w == SELF)
        p_one = (params.b11 + ones) / (params.b11 + params.b12 + count)
        return p_one if y else 1 - p_one
    return math.exp(log_evidence(params, [*events, (where, y)]) - log_evidence(params, events))


def expectimax(
    params: ModelParams, events: list[tuple[str, int]], z: int, steps_to_go: int, tie: float
) -> tuple[float, int | None, dict]:
    """Value of the best plan over ``steps_to_go`` more decisions, and its first action.

    Also returns a record ``{(steps_to_go, z, history): (value, action)}`` of every node.
    """
    record: dict = {}

    def visit(events: list[tuple[str, int]], z: int, k: int) -> float:
        reward = -entropy_bits(belief(params, events))
        if k == 0:
            record[(k, z, tuple(events))] = (reward, None)
            return reward
        q = []
        for u in (0, 1):
            z_next = next_timer(params, z, u)
            where = period(params, z_next)
            q.append(
                sum(
                    probability_of_bit(params, events, where, y)
                    * visit([*events, (where, y)], z_next, k - 1)
                    for y in (0, 1)
                )
            )
        action = 1 if q[1] > q[0] + tie else 0
        value = reward + max(q)
        record[(k, z, tuple(events))] = (value, action)
        return value

    value = visit(list(events), z, steps_to_go)
    return value, record[(steps_to_go, z, tuple(events))][1], record

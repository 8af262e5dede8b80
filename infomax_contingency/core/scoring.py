"""Exact scores of policies over the whole finite state space (no sampling).

* **Policy score** (episodic, horizon T): the expected sum of ``-H(a_t)`` over
  ``t = 1 .. T`` from the episode start, computed by backward induction of the policy's own
  actions (:func:`infomax_contingency.core.solver.backward_induction` with
  ``fixed_actions``), normalised so that never vocalizing scores 0 and the DP optimum 1.
  Because the entropy at the start is fixed, the score is equally the expected
  information gained about S, summed over the episode, relative to the optimum's.
* **Episode start** (MODEL.md section 4): zero counts, ``z_1`` uniform in
  ``1 .. ta2 + 1``, then ``y_1`` from the prior predictive (counted in ``a_1`` unless
  ``z_1`` is a self-feedback timer value).
* **Visit distributions**: the probability of each statistic at each step when rooms are
  drawn from the prior, by forward propagation.
* **Reachable statistics**: those with positive probability at step t under some policy,
  or under one given policy.

An episodic policy is given as a function of the step ``t`` (1 .. T-1) returning its
boolean actions, shape ``(n_timer_values, n_count_tuples(t))``, rows the timer z, columns
:func:`~infomax_contingency.core.statespace.count_index` (the layout of policy-table
layers). Used by the experiments (:mod:`infomax_contingency.eval.experiments`) and by TD
learning (:mod:`infomax_contingency.core.learning`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from math import comb

import numpy as np

from infomax_contingency.core.controllers import (
    rule_decisions,
)
from infomax_contingency.core.model import SELF, ModelParams, advance_timer, period_of
from infomax_contingency.core.policy_table import EPISODIC, PolicyTable
from infomax_contingency.core.solver import (
    SolveCost,
    backward_induction,
    induction_cost,
    tuple_quantities,
)
from infomax_contingency.core.statespace import count_tuples, n_count_tuples

ActionsByStep = Callable[[int], np.ndarray]
"""Step t (1-based) -> boolean actions of shape (n_timer_values, n_count_tuples(t))."""


# --------------------------------------------------------------------------------------
# Policies as action arrays


def table_actions(table: PolicyTable) -> ActionsByStep:
    """The actions of an episodic table, by step."""
    if table.mode != EPISODIC:
        raise ValueError(f"need an episodic table, got a {table.mode} one")
    return lambda t: table.layer(t - 1)


def never_actions(params: ModelParams) -> ActionsByStep:
    """The policy that never vocalizes."""
    return lambda t: np.zeros((params.n_timer_values, n_count_tuples(t)), dtype=bool)


def rule_actions(params: ModelParams, c: float) -> ActionsByStep:
    """The interpretable rule with constant ``c`` as an episodic policy."""

    def actions(t: int) -> np.ndarray:
        counts = count_tuples(t).T
        z = np.arange(params.n_timer_values)[:, None]
        return rule_decisions(params, c, z, *(column[None, :] for column in counts))

    return actions


def greedy_actions(params: ModelParams, max_count: int) -> np.ndarray:
    """One-step infomax (``policy_1``) over all statistics with counts summing to <= max_count."""
    solution = backward_induction(params, max_count + 1, 1, {1})
    size = params.n_timer_values * n_count_tuples(max_count)
    bits = np.unpackbits(solution.actions[1], count=size).astype(bool)
    return bits.reshape(params.n_timer_values, -1)


def receding_layers(
    params: ModelParams, horizons: Sequence[int], max_count: int
) -> dict[int, np.ndarray]:
    """``policy_H`` for each H, on the statistics with counts summing to <= max_count.

    One backward induction serves every horizon: layer H of a solve with base
    ``max_count + max(horizons)`` holds counts up to ``max_count + max(horizons) - H``.
    :func:`receding_layers_cost` tells what it takes.
    """
    top = max(horizons)
    solution = backward_induction(params, max_count + top, top, set(horizons))
    n_timer = params.n_timer_values
    layers = {}
    for horizon in horizons:
        full = n_count_tuples(solution.max_counts[horizon])
        bits = np.unpackbits(solution.actions[horizon], count=n_timer * full).astype(bool)
        layers[horizon] = bits.reshape(n_timer, full)[:, : n_count_tuples(max_count)].copy()
    return layers


def receding_layers_cost(params: ModelParams, longest: int, max_count: int) -> SolveCost:
    """Peak memory and time of :func:`receding_layers` for horizons ``1 .. longest`` (at once).

    Closed form for any size: the sweep of :func:`~infomax_contingency.core.solver.solve_cost`
    from the base ``max_count + longest``, the packed actions of every layer kept
    (``n_timer * C(max_count + longest + 4, 5) - C(max_count + 4, 5)`` statistics) and one
    unpacked layer on the domain per horizon (a byte per statistic). A horizon or count
    below 1 or 0 is refused (ValueError), as by the sweep itself.
    """
    if longest < 1 or max_count < 0:
        raise ValueError(f"need horizons >= 1 and a count >= 0, got {longest} and {max_count}")
    n_timer = params.n_timer_values
    kept = n_timer * (comb(max_count + longest + 4, 5) - comb(max_count + 4, 5))
    domain = n_timer * n_count_tuples(max_count)
    return induction_cost(params, max_count + longest, longest, kept,
                          kept // 8 + longest + longest * domain)  # fmt: skip


# --------------------------------------------------------------------------------------
# Exact episode values, scores and visit distributions


def start_distribution(params: ModelParams, tuples: dict) -> np.ndarray:
    """P(a_1): zero counts, ``z_1`` uniform in ``1 .. ta2 + 1``, ``y_1`` from the prior predictive.

    Shape ``(n_timer_values, n_count_tuples(1))``.
    """
    start = np.zeros((params.n_timer_values, n_count_tuples(1)))
    weight = 1.0 / params.timer_long_ago
    for z in range(1, params.timer_long_ago + 1):
        period = period_of(params, z)
        if period == SELF:
            start[z, 0] += weight
            continue
        p_active = tuples[period][0]
        start[z, tuples["neighbours"][(period, 1)][0]] += weight * p_active
        start[z, tuples["neighbours"][(period, 0)][0]] += weight * (1.0 - p_active)
    return start


@functools.lru_cache(maxsize=8)
def _episode_tuples(params: ModelParams, horizon: int) -> dict:
    return tuple_quantities(params, horizon)


def episode_values(
    params: ModelParams, horizon: int, actions: ActionsByStep | None = None
) -> list[np.ndarray]:
    """Exact values ``V_t`` for steps ``t = 1 .. T-1`` (expected sum of -H from step t to T).

    ``actions`` None gives the optimal values (the solver's); else the values of that
    policy. Each array has shape ``(n_timer_values, n_count_tuples(t))``.
    """
    if horizon < 2:
        raise ValueError(f"episode horizon must be >= 2 steps, got {horizon}")
    fixed = None if actions is None else (lambda k: np.asarray(actions(horizon - k), dtype=bool))
    steps = horizon - 1
    solution = backward_induction(
        params, horizon, steps, set(range(1, steps + 1)), keep_values=True, fixed_actions=fixed
    )
    return [solution.values[horizon - t] for t in range(1, horizon)]


def episode_value(params: ModelParams, horizon: int, actions: ActionsByStep | None = None) -> float:
    """Expected sum of ``-H(a_t)``, t = 1 .. T, from the episode start (bits; <= 0)."""
    first = episode_values(params, horizon, actions)[0]
    start = start_distribution(params, _episode_tuples(params, horizon))
    return float(np.sum(start * first))


class Scorer:
    """Exact normalised scores of episodic policies for one parameter set and horizon.

    ``score = (V_policy - V_never) / (V_optimal - V_never)``: 0 for never vocalizing, 1 for
    the DP optimum (and for every optimal policy).
    """

    def __init__(self, params: ModelParams, horizon: int):
        self.params = params
        self.horizon = horizon
        self.optimal_value = episode_value(params, horizon)
        self.never_value = episode_value(params, horizon, never_actions(params))
        if not self.optimal_value > self.never_value:
            raise ValueError(
                f"horizon {horizon} is too short for vocalizing to be worth anything"
                " (the optimum equals never vocalizing); use a longer horizon"
            )

    def value(self, actions: ActionsByStep) -> float:
        """Expected summed -H of a policy (bits)."""
        return episode_value(self.params, self.horizon, actions)

    def score(self, actions: ActionsByStep) -> float:
        """Normalised score of a policy."""
        return (self.value(actions) - self.never_value) / (self.optimal_value - self.never_value)


def _forward_step(
    params: ModelParams, tuples: dict, t: int, mass_by_action: dict[int, np.ndarray]
) -> np.ndarray:
    """Distribution over step t+1's statistics from the mass at step t taking each action."""
    n_timer = params.n_timer_values
    size = n_count_tuples(t)
    out = np.zeros((n_timer, n_count_tuples(t + 1)))
    neighbours = tuples["neighbours"]
    for u, mass in mass_by_action.items():
        for z in range(n_timer):
            z_next = advance_timer(params, z, u)
            period = period_of(params, z_next)
            if period == SELF:
                out[z_next, :size] += mass[z]
                continue
            p_active = tuples[period][:size]
            # Each neighbour map is one-to-one, so the fancy-indexed additions never collide.
            out[z_next, neighbours[(period, 1)][:size]] += mass[z] * p_active
            out[z_next, neighbours[(period, 0)][:size]] += mass[z] * (1.0 - p_active)
    return out


def visit_distributions(
    params: ModelParams, horizon: int, actions: ActionsByStep
) -> list[np.ndarray]:
    """P(a_t = a) for t = 1 .. T under a policy, rooms drawn from the prior (exact)."""
    tuples = _episode_tuples(params, horizon)
    distributions = [start_distribution(params, tuples)]
    for t in range(1, horizon):
        vocalize = np.asarray(actions(t), dtype=bool)
        mass = distributions[-1]
        distributions.append(
            _forward_step(params, tuples, t, {0: np.where(vocalize, 0.0, mass), 1: mass * vocalize})
        )
    return distributions


def reachable_statistics(params: ModelParams, horizon: int) -> list[np.ndarray]:
    """Statistics reachable at t = 1 .. T with positive probability under *some* policy."""
    tuples = _episode_tuples(params, horizon)
    reach = [start_distribution(params, tuples) > 0]
    for t in range(1, horizon):
        indicator = reach[-1].astype(float)
        reach.append(_forward_step(params, tuples, t, {0: indicator, 1: indicator}) > 0)
    return reach



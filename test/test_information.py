"""The information bound of eval/information.py."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from infomax_contingency.core.model import ModelParams, log_odds, per_lag_log_odds
from infomax_contingency.eval.information import (
    agent_rate_needed,
    agent_rate_the_belief_needs,
    agent_window_count,
    belief_crossing,
    belief_median_vocalizations,
    bernoulli_kl,
    evidence_needed,
    evidence_per_vocalization,
    information_bound,
    vocalizations_bound,
)


def test_bernoulli_kl() -> None:
    p, q = 0.96, 0.86
    expected = p * math.log(p / q) + (1 - p) * math.log((1 - p) / (1 - q))
    assert bernoulli_kl(p, q) == pytest.approx(expected)
    assert bernoulli_kl(0.3, 0.3) == 0.0
    assert bernoulli_kl(1.0, 0.5) == pytest.approx(math.log(2.0))
    assert bernoulli_kl(0.5, 0.0) == math.inf
    with pytest.raises(ValueError, match="p = 1.5: must be a probability"):
        bernoulli_kl(1.5, 0.5)


def test_vocalizations_bound_for_the_tv_rooms_contrast() -> None:
    windows = agent_window_count(ModelParams.named("robot"))
    assert windows == 3
    per = evidence_per_vocalization(0.96, 0.86, windows)
    assert per == pytest.approx(3 * 0.05549, abs=1e-4)
    needed = evidence_needed(0.01, 0.9)
    assert needed == pytest.approx(math.log(9) + math.log(99))
    assert vocalizations_bound(0.96, 0.86, windows, 0.01, 0.9) == pytest.approx(needed / per)
    assert vocalizations_bound(0.5, 0.5, windows, 0.01, 0.9) == math.inf
    assert vocalizations_bound(0.7, 0.1, windows, 0.95, 0.9) == 0.0


def test_agent_rate_needed_meets_the_bound_exactly() -> None:
    rate = agent_rate_needed(0.2, 8, 3, 0.01, 0.9)
    assert rate is not None and 0.2 < rate < 1.0
    assert (
        vocalizations_bound(rate, 0.2, 3, 0.01, 0.9)
        <= 8
        < vocalizations_bound(rate - 1e-4, 0.2, 3, 0.01, 0.9)
    )
    # a background active in 99 % of windows leaves too little room even for p_agent = 1
    assert agent_rate_needed(0.99, 8, 3, 0.01, 0.9) is None
    with pytest.raises(ValueError, match="vocalizations"):
        agent_rate_needed(0.2, 0, 3, 0.01, 0.9)


def _crossing_by_enumeration(
    params: ModelParams,
    p_agent: float | tuple[float, ...],
    p_background: float,
    background: int,
    target: float,
    vocalizations: int,
) -> np.ndarray:
    """Every bit sequence of the schedule, its probability, its first crossing (by brute force).

    The belief from the model's own log odds: one K2 (``log_odds``) or one per lag
    (``per_lag_log_odds``), counts kept per lag (-1: the background).
    """
    agent = agent_window_count(params)
    rates = (p_agent,) * agent if isinstance(p_agent, float) else p_agent
    schedule = [(0, -1)] * background + [
        (n, lag)
        for n in range(1, vocalizations + 1)
        for lag in [*range(agent), *[-1] * background]
    ]
    out = np.zeros(vocalizations + 2)
    for bits in itertools.product((0, 1), repeat=len(schedule)):
        probability = 1.0
        counts = {lag: [0, 0] for lag in range(-1, agent)}
        first = vocalizations + 1
        for (made, lag), bit in zip(schedule, bits, strict=True):
            rate = rates[lag] if lag >= 0 else p_background
            probability *= rate if bit else 1.0 - rate
            counts[lag][0 if bit else 1] += 1
            p2 = sum(counts[k][0] for k in range(agent))
            q2 = sum(counts[k][1] for k in range(agent))
            if params.k2_per_lag:
                lags = tuple(c for k in range(agent) for c in counts[k])
                lam = per_lag_log_odds(params, lags, p2, q2, *counts[-1])
            else:
                lam = float(log_odds(params, p2, q2, *counts[-1]))
            if first > vocalizations and 1.0 / (1.0 + np.exp(-lam)) > target:
                first = made
        out[first] += probability
    return out


@pytest.mark.parametrize(
    ("p_agent", "p_background", "background", "vocalizations", "target"),
    [
        (0.6, 0.05, 1, 2, 0.9),
        (0.9, 0.2, 2, 2, 0.5),
        (0.41, 0.041, 0, 3, 0.9),
        (0.3, 0.3, 1, 2, 0.2),
    ],
)
def test_the_beliefs_crossing_equals_brute_force(
    p_agent: float, p_background: float, background: int, vocalizations: int, target: float
) -> None:
    params = ModelParams.named("robot").for_table()  # one K2
    exact = belief_crossing(params, p_agent, p_background, background, target, vocalizations)
    brute = _crossing_by_enumeration(
        params, p_agent, p_background, background, target, vocalizations
    )
    np.testing.assert_allclose(exact, brute, atol=1e-12)
    assert exact.sum() == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("p_agent", "p_background", "background", "vocalizations", "target", "per_lag"),
    [
        ((0.5, 0.8, 0.1), 0.05, 1, 2, 0.9, True),
        ((0.9, 0.3, 0.6), 0.2, 0, 3, 0.5, True),
        (0.6, 0.05, 1, 2, 0.9, True),
        ((0.2, 0.7, 0.05), 0.1, 2, 2, 0.3, True),
        ((0.5, 0.8, 0.1), 0.05, 1, 2, 0.9, False),  # one K2, a rate per lag
    ],
)
def test_the_crossing_of_a_belief_with_a_k2_per_lag_equals_brute_force(
    p_agent: float | tuple[float, ...], p_background: float, background: int,
    vocalizations: int, target: float, per_lag: bool,
) -> None:  # fmt: skip
    robot = ModelParams.named("robot")
    params = robot if per_lag else robot.for_table()
    assert params.k2_per_lag is per_lag
    exact = belief_crossing(params, p_agent, p_background, background, target, vocalizations)
    brute = _crossing_by_enumeration(
        params, p_agent, p_background, background, target, vocalizations
    )
    np.testing.assert_allclose(exact, brute, atol=1e-12)
    assert exact.sum() == pytest.approx(1.0)


def test_lags_that_answer_apart_are_worth_more_to_a_belief_with_a_k2_per_lag() -> None:
    """The TV room's lags (0.51 / 0.60 / 0.13): one K2 per lag crosses sooner than one K2."""
    robot = ModelParams.named("robot")
    lags = (0.51, 0.60, 0.13)
    per_lag = belief_crossing(robot, lags, 0.036, 5, 0.9, 8)
    one = belief_crossing(robot.for_table(), lags, 0.036, 5, 0.9, 8)
    assert belief_median_vocalizations(per_lag) == 5 < belief_median_vocalizations(one) == 6
    bound = information_bound(sum(lags) / 3, 0.036, robot, 0.9, background_windows=5,
                              p_agent_lags=lags)  # fmt: skip
    assert bound["belief"]["median_vocalizations"] == 5 and bound["p_agent_lags"] == list(lags)
    # what a median of 4 needs: the lags' profile scaled, its mean returned
    needed = bound["belief"]["p_agent_needed"]["4"]
    assert needed is not None and sum(lags) / 3 < needed < 1.0
    scale = needed / (sum(lags) / 3)
    at = belief_crossing(robot, tuple(min(1.0, scale * p) for p in lags), 0.036, 5, 0.9, 4)
    below = belief_crossing(robot, tuple(min(1.0, (scale - 0.01) * p) for p in lags), 0.036, 5,
                            0.9, 4)  # fmt: skip
    assert at[:-1].sum() >= 0.5 > below[:-1].sum()
    # the bound (known rates) keeps the profile too: its need meets the bound exactly
    known = bound["p_agent_needed"]["4"]
    assert known is not None and known < needed  # known rates need less than the belief
    scale = known / (sum(lags) / 3)
    assert (vocalizations_bound(tuple(min(1.0, scale * p) for p in lags), 0.036, 3, robot.pi, 0.9)
            <= 4 < vocalizations_bound(tuple(min(1.0, (scale - 1e-4) * p) for p in lags), 0.036,
                                       3, robot.pi, 0.9))  # fmt: skip
    with pytest.raises(ValueError, match="p_agent has 2 rates: give one per agent window"):
        belief_crossing(robot, (0.5, 0.5), 0.036, 5, 0.9, 4)
    with pytest.raises(ValueError, match="count tuples x windows to follow"):
        belief_crossing(robot, lags, 0.036, 100, 0.9, 20)
    # many background windows per vocalization: followed as far as the cost allows, or not
    assert bound["belief"]["followed"] == 8  # its median within the short crossing
    assert information_bound(0.4, 0.036, robot, 0.9, background_windows=60,
                             p_agent_lags=lags)["belief"] is None  # fmt: skip


def test_the_belief_needs_more_than_the_bound_and_its_need_is_met_exactly() -> None:
    params = ModelParams.named("robot").for_table()  # one K2
    # the TV room's contrast: the bound allows 4 vocalizations, the belief's median is more
    assert vocalizations_bound(0.41, 0.041, 3, params.pi, 0.9) < 4
    crossing = belief_crossing(params, 0.41, 0.041, 5, 0.9, 20)
    median = belief_median_vocalizations(crossing)
    assert median is not None and median > 4
    needed = agent_rate_the_belief_needs(params, 0.041, 5, 0.9, 4)
    assert needed is not None and 0.41 < needed < 1.0
    at = belief_crossing(params, needed, 0.041, 5, 0.9, 4)
    below = belief_crossing(params, needed - 2e-3, 0.041, 5, 0.9, 4)
    assert at[:-1].sum() >= 0.5 > below[:-1].sum()
    # a prior already past the target crosses before any vocalization
    assert belief_crossing(params, 0.5, 0.1, 5, params.pi / 2, 3)[0] == 1.0
    # no contrast: never enough
    assert agent_rate_the_belief_needs(params, 0.999, 1, 0.9, 3) is None
    with pytest.raises(ValueError, match="vocalizations = 41"):
        belief_crossing(params, 0.5, 0.1, 5, 0.9, 41)
    bound = information_bound(0.41, 0.041, params, 0.9, background_windows=5)
    assert bound["belief"]["median_vocalizations"] == median
    assert information_bound(0.41, 0.041, params, 0.9)["belief"] is None
    # a target beyond the vocalizations followed for the median is followed too
    late = information_bound(0.2, 0.041, params, 0.9, (3, 25), background_windows=5)["belief"]
    exact = belief_crossing(params, 0.2, 0.041, 5, 0.9, 25)[:26].sum()
    assert late["p_crossed_by"]["25"] == pytest.approx(exact) and exact < 0.99
    with pytest.raises(ValueError, match="above 40"):
        information_bound(0.41, 0.041, params, 0.9, (3, 41), background_windows=5)

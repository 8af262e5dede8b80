"""The information bound of eval/information.py."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from infomax_contingency.core.model import ModelParams, log_odds
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
    p_agent: float,
    p_background: float,
    background: int,
    target: float,
    vocalizations: int,
) -> np.ndarray:
    """Every bit sequence of the schedule, its probability, its first crossing (by brute force)."""
    agent = agent_window_count(params)
    schedule = [(0, 3)] * background + [
        (n, period)
        for n in range(1, vocalizations + 1)
        for period in [2] * agent + [3] * background
    ]
    out = np.zeros(vocalizations + 2)
    for bits in itertools.product((0, 1), repeat=len(schedule)):
        probability = 1.0
        counts = {2: [0, 0], 3: [0, 0]}
        first = vocalizations + 1
        for (made, period), bit in zip(schedule, bits, strict=True):
            rate = p_agent if period == 2 else p_background
            probability *= rate if bit else 1.0 - rate
            counts[period][0 if bit else 1] += 1
            lam = float(log_odds(params, *counts[2], *counts[3]))
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
    params = ModelParams.named("robot")
    exact = belief_crossing(params, p_agent, p_background, background, target, vocalizations)
    brute = _crossing_by_enumeration(
        params, p_agent, p_background, background, target, vocalizations
    )
    np.testing.assert_allclose(exact, brute, atol=1e-12)
    assert exact.sum() == pytest.approx(1.0)


def test_the_belief_needs_more_than_the_bound_and_its_need_is_met_exactly() -> None:
    params = ModelParams.named("robot")
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

"""The information bound of eval/information.py."""

from __future__ import annotations

import math

import pytest

from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.information import (
    agent_rate_needed,
    agent_window_count,
    bernoulli_kl,
    evidence_needed,
    evidence_per_vocalization,
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

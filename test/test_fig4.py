"""The Fig. 4 study: known self-feedback and reply periods are found, absent ones are not."""

from __future__ import annotations

import numpy as np
import pytest

from infomax_contingency.eval.fig4 import fig4_study, wilson


def _session(steps: int, partner: bool, seed: int = 0) -> tuple[list[bool], list[bool]]:
    """Bits and decisions of a session with sounds every 6 to 12 windows of 0.5 s.

    The robot hears itself in the window after its sound (360 ms); a partner replies
    1.1-1.5 s after it (lag 2).
    """
    rng = np.random.default_rng(seed)
    bits, decisions, lag, wait = [], [], None, 0
    for _ in range(steps):
        if lag == 0:
            p = 0.9
        elif lag == 2 and partner:
            p = 0.8
        else:
            p = 0.05
        bits.append(bool(rng.random() < p))
        wait -= 1
        vocalize = wait <= 0
        if vocalize:
            wait = int(rng.integers(6, 13))
        decisions.append(vocalize)
        lag = 0 if vocalize else (None if lag is None else lag + 1)
    return bits, decisions


def test_known_periods_and_rates_are_recovered() -> None:
    study = fig4_study(*_session(2000, partner=True))
    assert study.self_period == (0, 0)
    assert study.agent_period == (2, 2)
    low, high = study.reply_rate.interval
    assert low <= 0.8 <= high
    low, high = study.self_rate.interval
    assert low <= 0.9 <= high
    low, high = study.background.interval
    assert low <= 0.05 <= high
    assert study.shortcomings() == []


def test_no_partner_means_no_reply_peak_and_says_what_to_record() -> None:
    study = fig4_study(*_session(2000, partner=False))
    assert study.self_period == (0, 0)
    assert study.agent_period is None and study.reply_rate is None
    assert any("no reply peak" in line for line in study.shortcomings())


def test_too_few_vocalizations_are_reported() -> None:
    study = fig4_study(*_session(60, partner=True))
    assert study.vocalizations < 20
    assert any("vocalizations" in line for line in study.shortcomings())


def test_wilson_interval_and_bad_input() -> None:
    low, high = wilson(8, 10)
    assert 0.49 < low < 0.5 and 0.94 < high < 0.95
    with pytest.raises(ValueError, match="one each per step"):
        fig4_study([True], [])

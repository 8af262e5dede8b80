"""Posture hysteresis: two thresholds, changes reported once."""

import pytest

from infomax_contingency.core.posture import ATTENTIVE, BORED, PostureHysteresis


def test_switches_only_past_each_threshold() -> None:
    switch = PostureHysteresis(attentive_above=0.9, bored_below=0.2)
    assert switch.posture == BORED
    changes = [switch.update(b) for b in (0.5, 0.9, 0.95, 0.97, 0.5, 0.2, 0.19, 0.1, 0.91)]
    assert changes == [None, None, ATTENTIVE, None, None, None, BORED, None, ATTENTIVE]
    assert switch.posture == ATTENTIVE


def test_hovering_between_thresholds_never_twitches() -> None:
    switch = PostureHysteresis(0.9, 0.2, initial=ATTENTIVE)
    assert all(switch.update(b) is None for b in (0.21, 0.89, 0.5, 0.2, 0.3) * 20)


@pytest.mark.parametrize(
    ("above", "below", "initial"),
    [(0.2, 0.9, BORED), (0.5, 0.5, BORED), (1.1, 0.2, BORED), (0.9, -0.1, BORED), (0.9, 0.2, "x")],
)
def test_bad_settings_are_refused(above: float, below: float, initial: str) -> None:
    with pytest.raises(ValueError, match="posture"):
        PostureHysteresis(above, below, initial)


@pytest.mark.parametrize("belief", [float("nan"), -0.1, 1.5])
def test_a_belief_that_is_no_probability_is_refused(belief: float) -> None:
    with pytest.raises(ValueError, match="probability"):
        PostureHysteresis().update(belief)

"""Bits withheld after a gap: the belief stays exact when windows give no step mid-run.

The controller and the belief count steps, the model's timer windows. After windows
without a step (a recalibration, a threshold out of range) a step's timer may lag its
window's; mic_node and the offline loop withhold the next ``ta2 + 1`` bits
(:class:`~infomax_contingency.core.selfsound.GapWithholding`), so the belief equals
direct counting with every window's true timer.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import brute_force
from infomax_contingency.core.controllers import ReplayedDecisions
from infomax_contingency.core.model import NAMED_PARAMS
from infomax_contingency.core.selfsound import GapWithholding
from infomax_contingency.sim.audio_loop import AudioWorld
from infomax_contingency.sim.loop import run_loop

PARAMS = NAMED_PARAMS["robot"]


def test_no_bit_is_withheld_before_the_first_one() -> None:
    gap = GapWithholding(5)
    assert not gap.bit(gap_before=True)  # the warm-up before it is no gap
    assert [gap.bit() for _ in range(3)] == [False] * 3
    assert gap.withheld == gap.gaps == 0


def test_without_the_decisions_every_gap_withholds_ta2_plus_1_bits() -> None:
    gap = GapWithholding(3)
    assert [gap.bit() for _ in range(4)] == [False] * 4
    assert [gap.bit(gap_before=True)] + [gap.bit() for _ in range(3)] == [True] * 3 + [False]
    assert [gap.bit(gap_before=True), gap.bit(), gap.bit(gap_before=True)] == [True] * 3
    assert [gap.bit() for _ in range(3)] == [True, True, False]  # a gap in a withholding
    assert (gap.withheld, gap.gaps, gap.bits) == (8, 3, 14)


def test_with_the_decisions_only_the_steps_whose_timer_lags_are_withheld() -> None:
    gap = GapWithholding(5)  # ta2 = 4
    for step in range(1, 11):
        gap.bit()
        gap.decided(step, int(step == 8))  # a vocalization decided on step 8
    # steps 9, 10 had timers 0, 1; after the gap steps 11, 12, 13 would have 2, 3, 4
    assert [gap.bit(gap_before=True), gap.bit(), gap.bit(), gap.bit()] == [True] * 3 + [False]
    quiet = GapWithholding(5)
    for step in range(1, 11):
        quiet.bit()
        quiet.decided(step, 0)
    assert not quiet.bit(gap_before=True)  # no vocalization: both timers are "long ago"
    lost = GapWithholding(5)
    for step in range(1, 11):
        lost.bit()
        lost.decided(step, None if step == 9 else 0)  # a lost decision: it might have been 1
    assert [lost.bit(gap_before=True)] + [lost.bit() for _ in range(5)] == [True] * 5 + [False]


def test_a_vocalization_after_the_gap_ends_the_withholding() -> None:
    gap = GapWithholding(5)
    for step in range(1, 11):
        gap.bit()
        gap.decided(step, int(step == 10))
    assert gap.bit(gap_before=True)  # step 11
    gap.decided(11, 1)  # both timers 0 at step 12
    assert not gap.bit()


@pytest.mark.parametrize("steps", [0, -1, 2.5, True])
def test_a_bad_count_is_refused(steps) -> None:
    with pytest.raises(ValueError, match="whole number >= 1"):
        GapWithholding(steps)


class _Room:
    """Silent windows; the robot's sound is never declared."""

    def next_window(self) -> SimpleNamespace:
        return SimpleNamespace(samples=np.zeros(8000, dtype=np.float32), partner_present=False,
                               robot_sound=False)  # fmt: skip

    def vocalize(self) -> None:
        pass


class _GivenBits:
    """A bit source giving fixed bits, None (no step) where given."""

    needs_decisions = False
    last_energy_db = -60.0

    def __init__(self, bits: list[int | None]) -> None:
        self.bits = iter(bits)

    def push_window(self, samples: np.ndarray) -> bool | None:
        bit = next(self.bits)
        return None if bit is None else bool(bit)


def _window_timers(windows: list[int | None], decisions: list[int]) -> list[int]:
    """The model's timer of each window with a bit (every window moves it on).

    A window without a step decides nothing; a window with one, its step's decision.
    """
    z, step, timers = PARAMS.ta2 + 1, 0, []
    for bit in windows:
        if bit is None:
            z = brute_force.next_timer(PARAMS, z, 0)
            continue
        timers.append(z)
        z = brute_force.next_timer(PARAMS, z, decisions[step])
        step += 1
    return timers


@pytest.mark.parametrize("seed", range(40))
def test_the_offline_belief_in_random_runs_equals_counting_with_the_windows_timers(
    seed: int,
) -> None:
    """Random bits, gaps and vocalizations (some right before a gap, some on withheld steps).

    Exactly the steps whose timer lags their window's are withheld, and the belief equals
    direct counting of the other steps' bits at their windows' timers.
    """
    rng = np.random.default_rng(seed)
    windows: list[int | None] = [int(b) for b in rng.random(8) < 0.3]
    while len(windows) < 80:
        if rng.random() < 0.08:
            windows += [None] * int(rng.integers(1, 9))
        windows.append(int(rng.random() < 0.4))
    steps = sum(bit is not None for bit in windows)
    decisions = [int(u) for u in rng.random(steps) < 0.3]
    world = AudioWorld(_Room(), _GivenBits(windows), gap_steps=PARAMS.ta2 + 1)  # type: ignore[arg-type]
    loop = list(run_loop(world, ReplayedDecisions(PARAMS, decisions), steps))
    timers = _window_timers(windows, decisions)
    events = []
    for taken, z in zip(loop, timers, strict=True):
        assert taken.observation.withheld == (taken.z != z), (taken.t, taken.z, z)
        if not taken.observation.withheld:
            events.append((brute_force.evidence(PARAMS, z), taken.observation.y))
        assert taken.statistic.belief(PARAMS) == pytest.approx(
            brute_force.belief(PARAMS, events), abs=1e-12)


@pytest.mark.parametrize("vocalize_at", [7, 9, 10])
def test_the_offline_belief_equals_counting_with_the_windows_timers(vocalize_at: int) -> None:
    """A vocalization shortly before a gap of 6 windows, replies of the room after it."""
    windows: list[int | None] = [0] * 10 + [None] * 6 + [1, 1, 0, 1, 1, 0, 1, 0, 0, 1] * 2
    steps = sum(bit is not None for bit in windows)
    decisions = [int(step == vocalize_at) for step in range(1, steps + 1)]
    world = AudioWorld(_Room(), _GivenBits(windows), gap_steps=PARAMS.ta2 + 1)  # type: ignore[arg-type]
    loop = list(run_loop(world, ReplayedDecisions(PARAMS, decisions), steps))

    z, step, events, timers_lagged = PARAMS.ta2 + 1, 0, [], 0
    for bit in windows:
        if bit is None:  # no step: the window's timer runs on
            z = brute_force.next_timer(PARAMS, z, 0)
            continue
        taken = loop[step]
        timers_lagged += taken.z != z
        assert taken.observation.withheld == (taken.z != z)
        if not taken.observation.withheld:
            events.append((brute_force.evidence(PARAMS, z), bit))
        assert taken.statistic.belief(PARAMS) == pytest.approx(
            brute_force.belief(PARAMS, events), abs=1e-12)
        z = brute_force.next_timer(PARAMS, z, decisions[step])
        step += 1
    assert timers_lagged > 0  # the steps' timer did lag: the withholding mattered

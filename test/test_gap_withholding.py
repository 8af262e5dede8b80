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
from infomax_contingency.sim.fake_room import AudioWorld
from infomax_contingency.sim.loop import run_loop

PARAMS = NAMED_PARAMS["robot"]


def test_no_bit_is_withheld_before_the_first_one() -> None:
    gap = GapWithholding(5)
    assert not any(gap.no_step() for _ in range(12))  # the warm-up
    assert [gap.bit() for _ in range(3)] == [False] * 3
    assert gap.withheld == gap.gaps == 0


def test_the_bits_after_windows_without_a_step_are_withheld() -> None:
    gap = GapWithholding(3)
    assert [gap.bit() for _ in range(4)] == [False] * 4
    assert gap.no_step() and not gap.no_step()  # one gap of two windows: one line to log
    assert [gap.bit() for _ in range(4)] == [True, True, True, False]
    assert [gap.bit(audio_lost_before=True), gap.bit()] == [True, True]
    assert not gap.no_step()  # during a withholding: it starts again, no new line
    assert [gap.bit() for _ in range(4)] == [True, True, True, False]
    assert (gap.withheld, gap.gaps, gap.bits) == (8, 2, 14)


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
        if taken.observation.withheld:
            assert taken.z != z or step >= 10, "only bits right after the gap are withheld"
        else:
            assert taken.z == z or z == PARAMS.ta2 + 1 == taken.z
            events.append((brute_force.period(PARAMS, z), bit))
        assert taken.statistic.belief(PARAMS) == pytest.approx(
            brute_force.belief(PARAMS, events), abs=1e-12)
        z = brute_force.next_timer(PARAMS, z, decisions[step])
        step += 1
    assert timers_lagged > 0  # the steps' timer did lag: the withholding mattered
    assert sum(s.observation.withheld for s in loop) == PARAMS.ta2 + 1

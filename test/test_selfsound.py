"""The robot's own sound: withheld windows, exact belief, the gate and the chunk clock."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import betaln

import brute_force
from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.audio.windows import SourceWindow, TopicWindows
from infomax_contingency.core.controllers import PolicyController
from infomax_contingency.core.model import ModelParams, StatisticTracker, Withheld
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.core.selfsound import (
    NS_PER_S,
    ChunkClock,
    SelfSoundGate,
    Verdict,
    describe,
)
from infomax_contingency.core.stepclock import StepJoiner
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.audio_loop import simulate_audio_loop
from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.room_config import FakeRoomConfig

ROBOT = ModelParams.named("robot")
PAPER = ModelParams.named("paper")
NOW = 1_700_000_000 * NS_PER_S
"""A ROS time (ns) of today's system clock."""


def brute_force_belief(params: ModelParams, z_initial: int, actions: list[int],
                       bits: list[int], withheld: list[bool]) -> float:  # fmt: skip
    """P(S=1 | every bit), the robot's own sound modelled explicitly.

    A withheld window's bit is driven by the robot: a rate K_R of its own, Beta(1, 1),
    whatever S. Its likelihood is computed and multiplied into both hypotheses, by
    direct counting (brute_force.log_marginals for the room's bits).
    """
    z_values = [z_initial]
    for u in actions:
        z_values.append(brute_force.next_timer(params, z_values[-1], u))
    room = [(brute_force.evidence(params, z), y)
            for z, y, w in zip(z_values, bits, withheld, strict=True) if not w]  # fmt: skip
    robot = [y for y, w in zip(bits, withheld, strict=True) if w]
    log_robot = float(betaln(1 + sum(robot), 1 + len(robot) - sum(robot)) - betaln(1, 1))
    log_s1, log_s0 = brute_force.log_marginals(params, room)
    s1 = math.log(params.pi) + log_s1 + log_robot
    s0 = math.log1p(-params.pi) + log_s0 + log_robot
    return 1.0 / (1.0 + math.exp(s0 - s1))


@pytest.mark.parametrize("params", [ROBOT, PAPER], ids=["robot", "paper"])
def test_withheld_windows_keep_the_belief_exact(params: ModelParams) -> None:
    """Against brute force: withholding a window is exact (the robot's rate cancels)."""
    rng = np.random.default_rng(30)
    for _ in range(60):
        length = int(rng.integers(1, 40))
        z_initial = int(rng.integers(0, params.timer_long_ago + 1))
        bits = [int(b) for b in rng.integers(0, 2, size=length)]
        withheld = [bool(w) for w in rng.random(length) < 0.3]
        actions = [int(u) for u in rng.random(length - 1) < 0.3]
        tracker = StatisticTracker(params, z_initial=z_initial)
        for t, (y, w) in enumerate(zip(bits, withheld, strict=True)):
            tracker.observe_window(Withheld(bool(y)) if w else y)
            if t < len(actions):
                tracker.act(actions[t])
        expected = brute_force_belief(params, z_initial, actions, bits, withheld)
        assert tracker.statistic.belief(params) == pytest.approx(expected, rel=1e-9, abs=1e-12)
        assert tracker.withheld == sum(withheld)


def test_withheld_windows_stay_out_of_the_sliding_memory() -> None:
    """With a memory of M, the counts are those of the last M counted (not withheld) bits."""
    rng = np.random.default_rng(5)
    for _ in range(40):
        length = int(rng.integers(5, 80))
        bits = [int(b) for b in rng.integers(0, 2, size=length)]
        withheld = [bool(w) for w in rng.random(length) < 0.4]
        actions = [int(u) for u in rng.random(length) < 0.25]
        with_memory = StatisticTracker(ROBOT, memory=7)
        z, counted = ROBOT.timer_long_ago, []
        for y, w, u in zip(bits, withheld, actions, strict=True):
            with_memory.observe_window(Withheld(bool(y)) if w else y)
            where = brute_force.period(ROBOT, z)
            if not w and where != brute_force.SELF:
                counted.append((where, y))
            with_memory.act(u)
            z = brute_force.next_timer(ROBOT, z, u)
        last = counted[-7:]
        expected = (last.count(("agent", 1)), last.count(("agent", 0)),
                    last.count(("background", 1)), last.count(("background", 0)))  # fmt: skip
        assert with_memory.statistic.counts == expected


def test_a_withheld_bit_cannot_be_counted_by_mistake() -> None:
    with pytest.raises(TypeError, match="not evidence"):
        bool(Withheld(True))
    assert Withheld(True).bit is True


def test_the_joiner_passes_withheld_bits_on() -> None:
    applied = []
    joiner = StepJoiner(lambda step, y, u: applied.append((step, y, u)))
    joiner.bit(1, True)
    joiner.bit(2, Withheld(True))
    joiner.decision(1, False)
    joiner.decision(2, True)
    assert applied == [(1, True, False), (2, Withheld(True), True)]


def test_controller_does_not_count_a_withheld_bit() -> None:
    """The controller decides on a withheld window but counts it as a missing bit."""
    table = PolicyTable.load(resource_path("policies", "robot_receding_H24_M60.npz"))
    controller, by_hand = PolicyController(table, ROBOT), StatisticTracker(ROBOT, memory=60)
    for t in range(60):
        y = Withheld(True) if t % 3 == 0 else int(t % 4 == 1)
        u = controller.step(y)
        by_hand.skip_observation() if t % 3 == 0 else by_hand.observe(y)
        by_hand.act(u)
        assert controller.tracker.statistic == by_hand.statistic
    assert controller.tracker.withheld == 20


# ---------------------------------------------------------------- the gate


def test_gate_withholds_the_windows_a_range_overlaps() -> None:
    gate: SelfSoundGate[int] = SelfSoundGate(hold_s=0.2)
    half = NS_PER_S // 2
    for k in range(4):  # windows [NOW + k/2 s, NOW + (k+1)/2 s)
        gate.push(NOW + k * half, NOW + (k + 1) * half, k)
    assert gate.declare(NOW + half, NOW + half + 10, NOW).accepted  # inside window 1
    assert gate.release(NOW + half + half // 5, holding=True) == []  # held 0.2 s past its end
    assert gate.release(NOW + 3 * half, holding=True) == [(0, False), (1, True)]
    assert gate.declare(NOW + 4 * half - 1, NOW + 9 * half, NOW).accepted  # last ns of window 3
    assert gate.release(NOW + 10 * half, holding=True) == [(2, False), (3, True)]
    assert gate.withheld == 2 and gate.late == 0


def test_a_long_range_is_applied_and_said() -> None:
    """30 s or less: said nothing; longer: applied, and one line says what it withholds."""
    gate: SelfSoundGate[int] = SelfSoundGate(hold_s=0.1)
    assert gate.declare(NOW, NOW + 30 * NS_PER_S, NOW) == Verdict(True)
    verdict = gate.declare(NOW, NOW + 590 * NS_PER_S, NOW)
    assert verdict.accepted and gate.long == 1 and "\n" not in verdict.problem
    assert "declares 590.0 s of the robot's own sound: every window in it is withheld" in (
        verdict.problem
    )
    gate.push(NOW + 300 * NS_PER_S, NOW + 301 * NS_PER_S, 0)
    assert gate.release(NOW + 302 * NS_PER_S, holding=True) == [(0, True)]
    assert describe(gate)["self_sound_long"] == 1


def test_a_long_range_that_is_also_late_is_said_and_counted_as_both() -> None:
    """A 40 s range arriving after a window it overlaps was reported as late only."""
    gate: SelfSoundGate[int] = SelfSoundGate(hold_s=0.1)
    gate.push(NOW, NOW + NS_PER_S, 0)
    assert gate.release(NOW + 2 * NS_PER_S, holding=True) == [(0, False)]
    verdict = gate.declare(NOW + NS_PER_S // 2, NOW + 40 * NS_PER_S, NOW + 2 * NS_PER_S)
    assert (gate.long, gate.late) == (1, 1)
    assert verdict.accepted and verdict.late_windows == 1
    assert [kind for kind, _ in verdict.problems] == ["long", "late"]
    assert all("\n" not in line for _, line in verdict.problems)
    assert describe(gate)["self_sound_long"] == 1 and len(gate.problems) == 2


def test_gate_without_declarers_releases_at_once() -> None:
    gate: SelfSoundGate[str] = SelfSoundGate(hold_s=5.0)
    gate.push(NOW, NOW + NS_PER_S, "a")
    assert gate.release(NOW, holding=False) == [("a", False)]


def test_a_late_range_is_reported_not_applied_to_published_windows() -> None:
    gate: SelfSoundGate[int] = SelfSoundGate(hold_s=0.1)
    gate.push(NOW, NOW + NS_PER_S, 0)
    assert gate.release(NOW + 2 * NS_PER_S, holding=True) == [(0, False)]
    verdict = gate.declare(NOW + NS_PER_S // 2, NOW + NS_PER_S, NOW + 2 * NS_PER_S)
    assert verdict.accepted and verdict.late_windows == 1
    assert "arrived 1.000 s after the end of a window" in verdict.problem
    assert "counted as evidence" in verdict.problem and gate.late == 1


@pytest.mark.parametrize(("start", "end", "words"), [
    (NOW + 5, NOW, "0 < start_ns <= end_ns"),
    (0, NOW, "0 < start_ns <= end_ns"),
    (NOW, NOW + 3600 * NS_PER_S, "more than 600 s"),
    (12_345 * NS_PER_S, 12_346 * NS_PER_S, "from this node's ROS clock: stamped on another clock"),
    (NOW + 1000 * NS_PER_S, NOW + 1001 * NS_PER_S, "+1000.0 s from this node's ROS clock"),
])  # fmt: skip
def test_nonsense_and_other_clocks_are_refused_in_one_line(start: int, end: int,
                                                           words: str) -> None:  # fmt: skip
    gate: SelfSoundGate[int] = SelfSoundGate(hold_s=0.1)
    verdict = gate.declare(start, end, NOW)
    assert not verdict.accepted and words in verdict.problem and "\n" not in verdict.problem
    gate.push(min(start, end), max(start, end) + 1, 0)
    assert gate.release(NOW + 10**13, holding=True) == [(0, False)]
    assert gate.refused == 1


def test_chunk_clock_spans_each_chunk_since_the_previous_one() -> None:
    clock = ChunkClock(rate_hz=1000)
    clock.add(500, NOW)  # first chunk: its own length, 0.5 s
    clock.add(500, NOW + 10_000_000)  # a fast simulation: the next window 10 ms later
    assert clock.window_ns(0, 500) == (NOW - NS_PER_S // 2, NOW)
    assert clock.window_ns(500, 500) == (NOW, NOW + 10_000_000)
    clock.add(1000, NOW + 1_010_000_000)  # a real-time chunk of 1 s: two windows in it
    assert clock.window_ns(1000, 500) == (NOW + 10_000_000, NOW + 510_000_000)
    assert clock.window_ns(1500, 500) == (NOW + 510_000_000, NOW + 1_010_000_000)
    clock.reset()
    clock.add(250, NOW + 5 * NS_PER_S)
    assert clock.window_ns(0, 250) == (NOW + 4_750_000_000, NOW + 5 * NS_PER_S)


# ---------------------------------------------------------------- the offline loop


def test_the_robots_speech_is_taken_for_a_partner_unless_it_is_declared() -> None:
    """A silent room where the robot speaks after each vocalization (offline loop)."""
    table = PolicyTable.load(resource_path("policies", "robot_receding_H24_M60.npz"))
    final = {}
    for declare in (False, True):
        room = FakeRoom(FakeRoomConfig.preset("silent", robot_speech_probability=1.0), 3)
        bits = make_bit_source("energy", 16000, 0.5, threshold_mode="fixed", threshold_db=-40.0)
        records = simulate_audio_loop(PolicyController(table, ROBOT), room, bits, 120, memory=60,
                                      declare_self_sound=declare)  # fmt: skip
        final[declare] = records[-1].belief
        assert room.robot_utterances > 5
        assert any(r.withheld for r in records) == declare
    assert final[False] > 0.9, "undeclared, the robot's speech looks like replies"
    assert final[True] < 0.05, "declared, it is not evidence"


def test_the_robot_also_speaks_on_its_own_and_those_windows_are_marked() -> None:
    config = FakeRoomConfig.preset("silent", robot_speech_rate_hz=0.5, event_rate_hz=0.0)
    room = FakeRoom(config, 4)
    windows = [room.next_window() for _ in range(120)]  # 60 s, no vocalization
    loud = [float(np.mean(w.samples**2)) > 1e-4 for w in windows]  # above -40 dB
    marked = [w.robot_sound for w in windows]
    assert room.robot_utterances >= 10 and room.vocalizations == 0
    assert all(m for m, sound in zip(marked, loud, strict=True) if sound), "unmarked speech"
    assert sum(loud) >= 0.8 * sum(marked), "marked windows without the robot's speech"
    quiet = FakeRoom(FakeRoomConfig.preset("silent", event_rate_hz=0.0), 4)
    assert not any(quiet.next_window().robot_sound for _ in range(120))


def test_window_sources_give_each_window_its_time_range() -> None:
    """The 'audio' topic's windows from the chunks' publication, a device's from its ADC."""
    topic = TopicWindows(1000, 0.5)
    topic.feed(np.zeros(250, np.float32), 1, NOW)
    topic.feed(np.zeros(750, np.float32), 2, NOW + 30_000_000)  # 10 ms per 250 samples
    first, second = topic.take()
    assert first.time_range_ns(0, 0, 0.5) == (NOW - NS_PER_S // 4, NOW + 10_000_000)
    assert second.time_range_ns(0, 0, 0.5) == (NOW + 10_000_000, NOW + 30_000_000)
    topic.feed(np.zeros(500, np.float32), 4, NOW + 10 * NS_PER_S)  # chunk 3 lost: a gap
    (after_gap,) = topic.take()
    assert after_gap.time_range_ns(0, 0, 0.5) == (NOW + 9_500_000_000, NOW + 10 * NS_PER_S)
    assert (first.gap_s, second.gap_s, after_gap.gap_s) == (0.0, 0.0, 0.5)  # audio lost before
    live = SourceWindow(-50.0, start_time=100.0, end_time=100.5)  # monotonic seconds
    assert live.time_range_ns(NOW, 101 * NS_PER_S, 0.5) == (NOW - NS_PER_S,
                                                            NOW - NS_PER_S // 2)  # fmt: skip
    assert SourceWindow(-50.0).time_range_ns(NOW, 0, 0.5) == (NOW - NS_PER_S // 2, NOW)

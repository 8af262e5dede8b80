"""End to end: a robot that speaks, and the ``self_sound`` topic that says so.

The fake room's robot speaks after each vocalization, in the agent period: without a
declaration its speech looks exactly like a partner's reply. With fake_audio_node
declaring it on ``self_sound``, mic_node publishes those windows withheld and no node
counts them. In the test process on one hand-stepped executor (real DDS between the
nodes); every run equals the offline loop, withheld windows included.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.parameter import Parameter
from std_msgs.msg import Float64, Int64MultiArray

from graph_harness import FIXED_THRESHOLD, room_nodes
from infomax_contingency.audio.bag_replay import BagReplay
from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.core.controllers import PolicyController, default_check_in
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.core.selfsound import NS_PER_S
from infomax_contingency.eval.sessions import load_session, replay_recorded, write_offline_session
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.step_topics import (
    SELF_SOUND,
    parse_self_sound,
    self_sound_message,
)
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.audio_loop import simulate_audio_loop
from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.room_config import FakeRoomConfig
from infomax_contingency.testing.stepped import nodes_on_their_own_executors
from stepped_graph import stepped_graph

STEPS, SEED, MEMORY = 100, 3, 60
SPEAKING_ROBOT = {"room": "silent", "seed": SEED, "robot_speech_probability": 1.0}
"""Nobody in the room; the robot speaks 1.0 s after every vocalization, for 0.6-1.0 s."""


def offline(declare: bool) -> list:
    """The offline loop of the same room, memory and threshold."""
    params = ModelParams.named("robot")
    table = PolicyTable.load(resource_path("policies", "robot_receding_H24_M60.npz"),
                             expected_params=params)  # fmt: skip
    config = FakeRoomConfig.preset("silent", robot_speech_probability=1.0)
    bits = make_bit_source("energy", 16000, 0.5, **FIXED_THRESHOLD)
    return simulate_audio_loop(PolicyController(table, params, default_check_in(params)),
                               FakeRoom(config, SEED), bits, STEPS,
                               memory=MEMORY, declare_self_sound=declare)  # fmt: skip


@pytest.mark.parametrize("declare", [False, True], ids=["undeclared", "declared"])
def test_the_robots_speech_counts_only_when_undeclared(declare: bool) -> None:
    nodes = room_nodes({**SPEAKING_ROBOT, "declare_self_sound": declare}, STEPS,
                       memory_steps=MEMORY)  # fmt: skip
    nodes["mic_node"]["self_sound_hold_s"] = 0.01  # one process: declarations come first
    with stepped_graph(nodes, "fake_audio_node") as graph:
        graph.run_steps(STEPS)
        rec = graph.recorder
        expected = offline(declare)
        withheld = [bool(fields[4]) for fields in rec.sound_step[:STEPS]]
        assert withheld == [r.withheld for r in expected]
        assert rec.sound[:STEPS] == [bool(r.y) for r in expected]
        assert rec.vocalize[:STEPS] == [bool(u.u) for u in expected]
        assert rec.belief[:STEPS] == [r.belief for r in expected]
        beliefs = np.array(rec.belief[:STEPS])
        mic = graph.nodes["mic_node"]
        if declare:
            assert sum(withheld) >= 10 and mic.self_sound.gate.late == 0
            assert beliefs.max() < 0.05, f"declared speech still counted: {beliefs.max():.3f}"
        else:
            assert not any(withheld) and mic.self_sound.gate.declared == 0
            assert beliefs[-1] > 0.9, "undeclared, the robot's speech is a partner's reply"
        assert graph.nodes["belief_node"].tracker.withheld == sum(withheld)
        assert graph.nodes["controller_node"].withheld_bits == sum(withheld)


def test_bad_self_sound_ranges_get_a_clear_diagnostic() -> None:
    """Ranges from another clock, reversed or endless: refused, counted, named."""
    with nodes_on_their_own_executors() as start:
        mic, probe, executor = start(MicNode, source="topic", **FIXED_THRESHOLD)
        declare = probe.talk(SELF_SOUND, Int64MultiArray)
        executor.connected(declare)
        now = mic.get_clock().now().nanoseconds
        steady = 12_345 * NS_PER_S  # a steady clock's time since boot
        for start_ns, end_ns in ((steady, steady + NS_PER_S), (now, now - NS_PER_S),
                                 (now, now + 3600 * NS_PER_S)):  # fmt: skip
            declare.publish(self_sound_message(start_ns, end_ns))
        declare.publish(Int64MultiArray(data=[1, 2, 3]))
        declare.publish(self_sound_message(now, now + NS_PER_S))  # a good one
        executor.run_until(lambda: mic.self_sound.gate.refused + mic.self_sound.gate.declared == 5,
                           "five declarations handled")  # fmt: skip
        assert (mic.self_sound.gate.refused, mic.self_sound.gate.declared) == (4, 1)
        level, message, values = mic.diagnostic_status()
        assert level in (DiagnosticStatus.WARN, DiagnosticStatus.OK)
        assert values["self_sound_refused"] == 4
        assert "another clock" in mic.self_sound.gate.problems[0]
        assert "0 < start_ns <= end_ns" in mic.self_sound.gate.problems[1]
        assert "more than 600 s" in mic.self_sound.gate.problems[2]
        assert "expected [start_ns, end_ns]" in mic.self_sound.gate.problems[3]
        assert values["self_sound_last_problem"] == mic.self_sound.gate.problems[3]


def test_each_kind_of_self_sound_problem_is_said_whatever_came_just_before(
    capfd: pytest.CaptureFixture[str],
) -> None:
    """A long range, then refused ones: each kind its own WARN line within the 5 s throttle.

    One throttle for every kind had kept the refused ranges out of the log after the long
    one; a flood of one kind is still one line per period.
    """
    with nodes_on_their_own_executors() as start:
        mic, probe, executor = start(MicNode, source="topic", **FIXED_THRESHOLD)
        declare = probe.talk(SELF_SOUND, Int64MultiArray)
        executor.connected(declare)
        now = mic.get_clock().now().nanoseconds
        declare.publish(self_sound_message(now, now + 40 * NS_PER_S))  # long: applied, said
        for _ in range(3):  # reversed: refused, said once
            declare.publish(self_sound_message(now, now - NS_PER_S))
        declare.publish(self_sound_message(12_345 * NS_PER_S, 12_346 * NS_PER_S))  # a clock's
        gate = mic.self_sound.gate
        executor.run_until(lambda: gate.refused + gate.declared == 5, "five declarations")
        err = capfd.readouterr().err
        assert err.count("declares 40.0 s of the robot's own sound") == 1, err
        assert err.count("0 < start_ns <= end_ns") == 1, err
        assert err.count("stamped on another clock") == 1, err
        assert (gate.long, gate.refused) == (1, 4)


def test_posture_node_declares_its_moves() -> None:
    """Each move of the head is the robot's own sound for ``move_duration_s``."""
    with nodes_on_their_own_executors() as start:
        posture, probe, executor = start(PostureNode, declare_motion_sound=True,
                                         move_duration_s=1.5)  # fmt: skip
        declared = probe.listen(SELF_SOUND, Int64MultiArray)
        belief = probe.talk("belief", Float64)
        executor.connected(belief)
        executor.run_until(lambda: posture.self_sound_pub.get_subscription_count() > 0,
                           "the probe on self_sound")  # fmt: skip
        before = posture.get_clock().now().nanoseconds
        belief.publish(Float64(data=0.95))  # bored -> attentive: the head moves
        executor.run_until(lambda: bool(declared), "a declared move")
        start_ns, end_ns = parse_self_sound(declared[-1])
        assert before <= start_ns and end_ns - start_ns == round(1.5 * NS_PER_S)
        assert posture.hysteresis.posture == "attentive"
        # mic_node holds its windows while 'self_sound' has a publisher: none when not declaring
        result = posture.set_parameters([Parameter("declare_motion_sound", value=False)])
        assert result[0].successful and posture.self_sound_pub is None
        assert posture.count_publishers(SELF_SOUND) == 0


def test_a_session_with_withheld_windows_replays_to_its_belief(tmp_path: Path) -> None:
    """Recorded withheld windows stay withheld: offline replay, bag reader and the graph."""
    expected = offline(declare=True)
    session_dir = write_offline_session(
        tmp_path / "session", [r.y for r in expected], [r.u for r in expected],
        [r.belief for r in expected], 0.5, withheld=[r.withheld for r in expected])
    withheld = [r.withheld for r in expected]
    replayed = list(replay_recorded(load_session(session_dir), ModelParams.named("robot"),
                                    memory=MEMORY))  # fmt: skip
    assert [row.belief for row in replayed] == [r.belief for r in expected]
    reader = BagReplay(session_dir, 0.5, 16000)
    served = [(reader.next_window(), reader.last_withheld) for _ in range(STEPS)]
    assert [w for _, w in served] == withheld and sum(withheld) >= 10
    mic = {"source": "bag", "bag_dir": str(session_dir), "lockstep": True,
           "exit_at_end": True, "threshold_mode": "fixed", "wait_for_listeners": 3}
    nodes = {"controller_node": {"controller": f"recorded:{session_dir}"},
             "belief_node": {"memory_steps": MEMORY}, "mic_node": mic}
    with stepped_graph(nodes, "mic_node") as graph:
        graph.run_steps(STEPS)
        rec = graph.recorder
        assert [bool(fields[4]) for fields in rec.sound_step[:STEPS]] == withheld
        assert rec.belief[:STEPS] == [r.belief for r in expected]

"""Each node on its own, in the test process, on a hand-stepped executor with a probe.

Messages travel over real DDS between the probe and the node under test; the executor
runs only inside ``graph.run_until``, so nothing happens between the test's steps.
"""

from __future__ import annotations

import array
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import Parameter
from std_msgs.msg import (
    Bool,
    Float32,
    Float32MultiArray,
    Float64,
    Int64MultiArray,
    MultiArrayDimension,
    String,
)
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.audio.threshold import kmeans_split
from infomax_contingency.core.controllers import CheckIn, PolicyController, default_check_in
from infomax_contingency.core.model import ModelParams, StatisticTracker
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.nodes.belief_node import BeliefNode
from infomax_contingency.nodes.controller_node import ControllerNode
from infomax_contingency.nodes.fake_audio_node import FakeAudioNode
from infomax_contingency.nodes.graph_node import ERROR, OK, THROTTLE_S, WARN
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.parameters import ConfigError
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.qos import LATCHED_READER_QOS
from infomax_contingency.nodes.speaker_node import SpeakerNode
from infomax_contingency.nodes.step_topics import (
    NoStep,
    StepBit,
    StepDecision,
    bit_message,
    decision_message,
    no_step_message,
    parse_bit,
    parse_decision,
)
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.fake_room import FakeRoom, as_transmitted
from infomax_contingency.sim.room_config import FakeRoomConfig
from infomax_contingency.testing.stepped import (
    Probe,
    SteppedExecutor,
    nodes_on_their_own_executors,
)

ROBOT = ModelParams.named("robot")
WINDOW_US = 500_000
STREAM = 77


def params(**values: Any) -> list[Parameter]:
    return [Parameter(name, value=value) for name, value in values.items()]


@pytest.fixture
def run() -> Iterator[Callable[..., tuple[Any, Probe, SteppedExecutor]]]:
    """``run(NodeClass, **parameters)`` -> (node, probe, stepped executor); cleaned up after."""
    with nodes_on_their_own_executors() as start:
        yield start


def bits_of(stream: int, bits: Any, first_step: int = 1) -> list[Int64MultiArray]:
    return [
        bit_message(StepBit(stream, first_step + i, bool(y), WINDOW_US)) for i, y in enumerate(bits)
    ]


def decisions_of(stream: int, decisions: Any, controller: int = 5, first_step: int = 1) -> list:
    return [
        decision_message(StepDecision(stream, first_step + i, bool(u), controller))
        for i, u in enumerate(decisions)
    ]


def offline_beliefs(bits: Any, decisions: Any, memory: int = 0) -> tuple[list[float], Any]:
    tracker = StatisticTracker(ROBOT, memory=memory)
    beliefs = []
    for y, u in zip(bits, decisions, strict=True):
        beliefs.append(tracker.observe(y).belief(ROBOT))
        tracker.act(u)
    return beliefs, tracker


# ---------------------------------------------------------------------- controller


def test_controller_answers_every_bit_like_the_offline_controller(run: Callable) -> None:
    node, probe, graph = run(ControllerNode, wait_for_listeners=1)  # the probe
    decisions = probe.listen("vocalize", Bool)
    steps = probe.listen("vocalize_step", Int64MultiArray)
    sound = probe.talk("sound_step", Int64MultiArray)
    graph.connected(sound)
    graph.connected(node.step_pub)
    graph.run_until(lambda: node.answering, "the controller to answer")
    bits = np.random.default_rng(4).random(80) < 0.3
    for message in bits_of(STREAM, bits):
        sound.publish(message)
    graph.run_until(lambda: len(steps) == 80 and len(decisions) == 80, "80 decisions")
    offline = PolicyController(PolicyTable.load(resource_path(
        "policies", "robot_receding_H24_M60.npz")), ROBOT, default_check_in(ROBOT))  # the node's
    expected = [bool(offline.step(int(y))) for y in bits]
    assert [m.data for m in decisions] == expected
    answered = [parse_decision(m) for m in steps]
    assert [d.step for d in answered] == list(range(1, 81))
    assert [d.vocalize for d in answered] == expected
    assert {d.stream for d in answered} == {STREAM} and {d.controller for d in answered} == {
        node.controller_id
    }
    assert any(expected)


def test_controller_ignores_a_second_stream_and_repeated_steps(run: Callable) -> None:
    node, probe, graph = run(ControllerNode, wait_for_listeners=1)  # the probe
    steps = probe.listen("vocalize_step", Int64MultiArray)
    sound = probe.talk("sound_step", Int64MultiArray)
    graph.connected(sound)
    graph.connected(node.step_pub)
    graph.run_until(lambda: node.answering, "the controller to answer")
    first, intruder = bits_of(STREAM, [1, 0, 0, 1]), bits_of(STREAM + 1, [1, 1, 1])
    second_mic = probe.talk("sound_step", Int64MultiArray)  # a second mic_node: its own writer
    graph.connected(second_mic)
    for message in (first[0], intruder[0], first[1], first[1], intruder[1], first[2],
                    intruder[2], first[3]):  # fmt: skip
        (second_mic if message in intruder else sound).publish(message)
    graph.run_until(lambda: node.steps == 4 and node.foreign.count == 3, "4 steps, 3 foreign")
    graph.run_for_callbacks(20)
    assert [parse_decision(m).step for m in steps] == [1, 2, 3, 4]
    assert node.stale_bits.count == 1
    level, message, values = node.diagnostic_status()
    assert level == ERROR and values["foreign_messages"] == 3 and values["stream"] == STREAM


def test_controller_counts_steps_it_never_saw(run: Callable) -> None:
    node, probe, graph = run(ControllerNode, wait_for_listeners=1)  # the probe
    steps = probe.listen("vocalize_step", Int64MultiArray)
    sound = probe.talk("sound_step", Int64MultiArray)
    graph.connected(sound)
    graph.connected(node.step_pub)
    graph.run_until(lambda: node.answering, "the controller to answer")
    messages = bits_of(STREAM, [0] * 10)
    for message in messages[:3] + messages[7:]:
        sound.publish(message)
    graph.run_until(lambda: len(steps) == 6, "6 decisions")
    assert [parse_decision(m).step for m in steps] == [1, 2, 3, 8, 9, 10]
    assert node.missed_steps == 4


def test_controller_takes_a_table_by_name_and_matching_params(run: Callable) -> None:
    node, _, _ = run(ControllerNode, params="paper", policy_file="paper_episodic_T40.npz",
                     window_s=0.8)  # fmt: skip
    assert node.controller.table.mode == "episodic" and node.controller.table.horizon == 40
    assert node.controller.check_in == CheckIn(5, 0.9), "4 s of 0.8-s windows"


@pytest.mark.parametrize(("overrides", "expected"), [
    ({}, CheckIn(8, 0.9)),
    ({"check_in_every_s": 0.0}, CheckIn(0, 0.9)),
    ({"check_in_every_s": 6.0, "check_in_above": 0.99}, CheckIn(12, 0.99)),
    ({"check_in_every_s": 1.0}, CheckIn(5, 0.9)),  # at least the reply period, ta2 + 1
])
def test_controller_checks_in_as_its_parameters_say(run: Callable, overrides: dict,
                                                    expected: CheckIn) -> None:
    node, _, _ = run(ControllerNode, **overrides)
    assert node.controller.check_in == expected
    assert dict(node.diagnostic_status()[2])["check_ins"] == 0


@pytest.mark.parametrize("node_class", [ControllerNode, BeliefNode, MicNode])
def test_a_window_other_than_the_model_dt_is_refused(node_class: type) -> None:
    rclpy.init()
    try:
        with pytest.raises(ConfigError, match=r"'window_s' = 0.25 s differs from the model's dt"):
            node_class(parameter_overrides=params(window_s=0.25))
    finally:
        rclpy.try_shutdown()


def test_the_diagnostics_come_every_diagnostics_period_s(
    run: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    node, probe, graph = run(PostureNode, diagnostics_period_s=0.05)
    statuses = probe.listen("/diagnostics", DiagnosticArray, 100)
    graph.run_until(lambda: len(statuses) >= 3, "3 diagnostics")
    periods = {timer.timer_period_ns for timer in node.timers}
    assert 50_000_000 in periods and 1_000_000_000 not in periods
    node, _, _ = run(PostureNode)
    assert 1_000_000_000 in {timer.timer_period_ns for timer in node.timers}, "1 s by default"
    with pytest.raises(ConfigError, match=r"'diagnostics_period_s' = 0.01 is not allowed"):
        run(PostureNode, diagnostics_period_s=0.01)
    assert "shorter than diagnostics_period_s" not in capfd.readouterr().err
    run(PostureNode, fault_hold_s=0.5)  # a fault may come and go between two messages
    assert ("fault_hold_s (0.5 s) is shorter than diagnostics_period_s (1 s): a fault that"
            " starts and ends between two diagnostics messages shows only in the counts"
            in capfd.readouterr().err)  # fmt: skip


@pytest.mark.parametrize(
    ("node_class", "parameters", "topic", "error", "refusal"),
    [
        (MicNode, {"source": "wav", "wav_file": "/nonexistent/a.wav"}, "/sound", AudioError,
         "does not exist"),
        (SpeakerNode, {"dry_run": False, "device": "no such loudspeaker"}, "/speaker_started",
         ConfigError, "parameter 'device'"),
    ],
)  # fmt: skip
def test_a_node_refused_after_it_made_its_publishers_leaves_none_behind(
    node_class: type, parameters: dict, topic: str, error: type, refusal: str
) -> None:
    """A refusal late in ``__init__`` leaves no publisher of the half-built node.

    A process that goes on (a test, a composed bringup) sees none, as if it never started.
    """
    rclpy.init()
    try:
        with pytest.raises(error, match=refusal):
            node_class(parameter_overrides=params(**parameters))
        witness = rclpy.create_node("witness")
        try:
            assert witness.get_publishers_info_by_topic(topic) == []
            assert node_class.NODE_NAME not in witness.get_node_names()
        finally:
            witness.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_a_repeated_fault_is_logged_once_per_period_and_each_kind_apart(
    run: Callable, monkeypatch: pytest.MonkeyPatch
) -> None:
    node, _, _ = run(PostureNode)
    now = [100.0]
    lines: list[tuple[str, str]] = []
    monkeypatch.setattr(node, "now_s", lambda: now[0])
    monkeypatch.setattr(node, "log_at", lambda level, message: lines.append((level, message)))
    for step in range(1000):  # a flood: one line, and rclpy is not asked 999 times
        node.log_throttled("gap", "warning", f"step {step}")
    node.log_throttled("refused", "error", "another kind")
    now[0] += THROTTLE_S - 0.1
    node.log_throttled("gap", "warning", "still quiet")
    now[0] += 0.2
    node.log_throttled("gap", "warning", "the next period")
    assert lines == [("warning", "step 0"), ("error", "another kind"),
                     ("warning", "the next period")]  # fmt: skip


# ---------------------------------------------------------------------- belief


def _belief_graph(run: Callable, **parameters: Any) -> tuple[Any, Probe, SteppedExecutor, Any,
                                                               Any, list]:  # fmt: skip
    node, probe, graph = run(BeliefNode, **parameters)
    beliefs = probe.listen("belief", Float64)
    sound = probe.talk("sound_step", Int64MultiArray)
    vocalize = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(sound)
    graph.connected(vocalize)
    graph.connected(node.belief_pub)
    return node, probe, graph, sound, vocalize, beliefs


def _second_writers(probe: Probe, graph: SteppedExecutor) -> tuple[Any, Any]:
    """A second writer on ``sound_step`` and on ``vocalize_step`` (a rogue), connected."""
    sound = probe.talk("sound_step", Int64MultiArray)
    vocalize = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(sound)
    graph.connected(vocalize)
    return sound, vocalize


def test_belief_joins_bits_and_decisions_by_step_whatever_their_order(run: Callable) -> None:
    node, _, graph, sound, vocalize, beliefs = _belief_graph(run, memory_steps=5)
    rng = np.random.default_rng(2)
    bits, decisions = rng.random(60) < 0.4, rng.random(60) < 0.2
    bit_messages, decision_messages = bits_of(STREAM, bits), decisions_of(STREAM, decisions)
    # decisions first for the first 20 steps, bits first for the next 20, then interleaved
    for message in decision_messages[:20] + bit_messages[:40]:
        (vocalize if message in decision_messages else sound).publish(message)
    graph.run_until(lambda: len(beliefs) >= 20, "20 beliefs")
    for message in decision_messages[20:40]:
        vocalize.publish(message)
    for b, d in zip(bit_messages[40:], decision_messages[40:], strict=True):
        vocalize.publish(d)
        sound.publish(b)
    graph.run_until(lambda: len(beliefs) == 60, "60 beliefs")
    offline, tracker = offline_beliefs(bits, decisions, memory=5)
    assert [m.data for m in beliefs] == offline
    assert node.tracker.statistic == tracker.statistic
    counts = node.joiner.counts
    assert (counts.steps, counts.missing_bits, counts.missing_decisions) == (60, 0, 0)
    assert node.diagnostic_status()[0] == OK


def test_belief_follows_one_stream_and_one_controller(run: Callable) -> None:
    node, probe, graph, sound, vocalize, beliefs = _belief_graph(run)
    rng = np.random.default_rng(3)
    bits, decisions = rng.random(30) < 0.5, rng.random(30) < 0.3
    true_bits, true_decisions = bits_of(STREAM, bits), decisions_of(STREAM, decisions)
    stray_bits = bits_of(STREAM + 9, rng.random(30) < 0.5)
    stray_decisions = decisions_of(STREAM, ~decisions, controller=99)
    # a second mic_node and a second controller: writers of their own
    stray_sound, stray_vocalize = _second_writers(probe, graph)
    for step in range(30):
        sound.publish(true_bits[step])
        stray_sound.publish(stray_bits[step])
        if step % 2:
            stray_vocalize.publish(stray_decisions[step])
            vocalize.publish(true_decisions[step])
        else:
            vocalize.publish(true_decisions[step])
            stray_vocalize.publish(stray_decisions[step])
    graph.run_until(lambda: len(beliefs) == 30, "30 beliefs")
    graph.run_for_callbacks(20)
    assert [m.data for m in beliefs] == offline_beliefs(bits, decisions)[0]
    assert node.foreign.count >= 30 + 29  # every stray bit; every stray decision but a first
    level, message, _ = node.diagnostic_status()
    assert level == ERROR and "second stream or controller" in message


def test_belief_stays_on_its_stream_against_bits_and_decisions_forged_for_another(
    run: Callable,
) -> None:
    """A forger's bit and decision (the controller's id) on a new stream, again and again.

    The followed stream still publishes: the controller would not have moved (it moves
    only after ``source_timeout_s`` of silence), so the decision is not its own.
    """
    node, probe, graph, sound, vocalize, beliefs = _belief_graph(run)
    rng = np.random.default_rng(4)
    bits, decisions = rng.random(30) < 0.5, rng.random(30) < 0.3
    true_bits, true_decisions = bits_of(STREAM, bits), decisions_of(STREAM, decisions)
    forged_sound, forged_vocalize = _second_writers(probe, graph)
    for step in range(30):
        sound.publish(true_bits[step])
        vocalize.publish(true_decisions[step])
        graph.run_until(lambda step=step: len(beliefs) == step + 1, f"belief {step + 1}")
        if step % 10 == 5:  # a new stream each time: bit first, then the decision
            forged_sound.publish(bits_of(STREAM + step, [1])[0])
            graph.run_for_callbacks(5)
            forged_vocalize.publish(decisions_of(STREAM + step, [1])[0])
            graph.run_for_callbacks(5)
    assert [m.data for m in beliefs] == offline_beliefs(bits, decisions)[0]
    assert node.stream == STREAM and node.stream_changes == 0
    assert node.foreign.count >= 6  # each forged bit, each forged decision


def test_belief_never_guesses_a_missing_decision(run: Callable) -> None:
    node, _, graph, sound, vocalize, beliefs = _belief_graph(run)
    bits = [1, 0, 1, 1, 0, 1, 1, 1, 0, 1, 1, 0]
    decisions = [0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0]
    for step, (b, d) in enumerate(zip(bits_of(STREAM, bits), decisions_of(STREAM, decisions),
                                      strict=True), start=1):  # fmt: skip
        sound.publish(b)
        if step != 2:  # the vocalization of step 2 is lost
            vocalize.publish(d)
    graph.run_until(lambda: len(beliefs) == 11, "11 beliefs")  # step 12 waits for its decision
    tracker = StatisticTracker(ROBOT)
    expected = []
    for step, (y, u) in enumerate(zip(bits[:11], decisions[:11], strict=True), start=1):
        expected.append(tracker.observe(y).belief(ROBOT))
        tracker.act_unknown() if step == 2 else tracker.act(u)
    assert [m.data for m in beliefs] == expected
    assert node.joiner.counts.missing_decisions == 1 and node.tracker.uncounted > 0
    assert node.diagnostic_status()[0] != OK  # the gap is shown while it is recent


def test_belief_reset_service_forgets_the_history(run: Callable) -> None:
    node, probe, graph, sound, vocalize, beliefs = _belief_graph(run)
    for b, d in zip(bits_of(STREAM, [1, 1, 1]), decisions_of(STREAM, [0, 0, 0]), strict=True):
        sound.publish(b)
        vocalize.publish(d)
    graph.run_until(lambda: len(beliefs) == 3, "the three beliefs")
    assert node.tracker.statistic.p3 > 0
    client = probe.create_client(Trigger, "/belief_node/reset")
    graph.run_until(client.service_is_ready, "the reset service")
    future = client.call_async(Trigger.Request())
    graph.run_until(future.done, "the reset answer")
    assert future.result().success and "reset after" in future.result().message
    assert node.tracker.statistic.counts == (0, 0, 0, 0)
    assert node.belief == pytest.approx(ROBOT.pi)


def test_belief_names_a_second_publisher(run: Callable) -> None:
    node, probe, graph, sound, vocalize, beliefs = _belief_graph(run)
    other = Probe("intruder")
    graph.add(other)
    intruder = other.talk("vocalize", Bool)
    controller = probe.talk("vocalize", Bool)
    graph.run_until(lambda: node.count_publishers("vocalize") == 2, "two publishers")
    statuses = probe.listen("/diagnostics", DiagnosticArray)
    node.publish_diagnostics()
    level, message, _values = node.diagnostic_status()
    assert level == ERROR and "'vocalize'" in message

    def belief_values() -> dict[str, str]:
        found = [s for m in statuses for s in m.status if s.name.startswith("belief_node")]
        return {kv.key: kv.value for kv in found[-1].values} if found else {}

    def published() -> dict[str, str]:
        node.publish_diagnostics()  # again, until the probe's subscription is matched
        return belief_values()

    graph.run_until(lambda: "publishers_vocalize" in published(), "the named publishers")
    publishers = belief_values()["publishers_vocalize"]  # every node's diagnostics name them
    assert "/intruder" in publishers and "/probe" in publishers
    other.destroy_publisher(intruder)
    graph.run_until(lambda: node.count_publishers("vocalize") == 1, "the intruder gone")
    node.publish_diagnostics()
    assert node.diagnostic_status()[0] == OK
    assert controller is not None


# ---------------------------------------------------------------------- posture


def test_posture_follows_the_belief_with_hysteresis(run: Callable) -> None:
    node, probe, graph = run(PostureNode, joint_names=["pan", "tilt"],
                             attentive_positions=[0.0, 0.2], bored_positions=[0.5, -0.3],
                             move_duration_s=1.5)  # fmt: skip
    postures = probe.listen("posture", String, LATCHED_READER_QOS)
    targets = probe.listen("joint_targets", JointTrajectory, LATCHED_READER_QOS)
    graph.run_until(lambda: postures and targets, "the initial posture (to a late joiner)")
    assert postures[0].data == "bored"
    belief = probe.talk("belief", Float64)
    graph.connected(belief)
    for b in (0.5, 0.95, 0.5, 0.15):
        belief.publish(Float64(data=b))
    graph.run_until(lambda: node.belief == 0.15, "the belief 0.15 taken")
    assert node.hysteresis.posture == "attentive"  # between the thresholds: bored below 0.1
    for b in (0.05, 0.3):
        belief.publish(Float64(data=b))
    graph.run_until(lambda: len(postures) >= 3 and len(targets) >= 3, "two posture changes")
    assert [m.data for m in postures] == ["bored", "attentive", "bored"]
    assert list(targets[1].joint_names) == ["pan", "tilt"]
    assert list(targets[1].points[0].positions) == [0.0, 0.2]
    assert list(targets[2].points[0].positions) == [0.5, -0.3]
    duration = targets[1].points[0].time_from_start
    assert (duration.sec, duration.nanosec) == (1, 500_000_000)
    assert node.changes == 2


# ---------------------------------------------------------------------- mic


def _room_audio(windows: int, seed: int = 1) -> np.ndarray:
    room = FakeRoom(FakeRoomConfig.preset("noisy", event_rate_hz=2.0), seed=seed)
    return np.concatenate([as_transmitted(room.next_window().samples) for _ in range(windows)])


def _audio_message(chunk: np.ndarray) -> Float32MultiArray:
    message = Float32MultiArray()
    message.data = array.array("f", chunk.astype(np.float32).tobytes())
    return message


def test_mic_topic_source_windows_any_chunking_and_calibrates(run: Callable) -> None:
    node, probe, graph = run(MicNode, source="topic", bit_source="energy", calibration_s=2.0,
                             wait_for_listeners=1, start_delay_s=0.0)  # fmt: skip
    bits = probe.listen("sound", Bool)
    steps = probe.listen("sound_step", Int64MultiArray)
    energies = probe.listen("sound_energy", Float32)
    audio = probe.talk("audio", Float32MultiArray)
    graph.connected(audio)
    graph.run_until(lambda: node.started, "the mic's start gate")
    samples = _room_audio(16)
    for chunk in np.array_split(samples, 37):  # chunks that do not line up with windows
        audio.publish(_audio_message(chunk))
    graph.run_until(lambda: len(energies) == 16 and len(steps) == 12, "16 windows, 12 bits")
    expected = window_energies_db(samples.astype(np.float64), 16000, 0.5)
    assert np.array_equal(np.float32([m.data for m in energies]), expected.astype(np.float32))
    threshold = kmeans_split(expected[:4]).threshold_db  # 2 s of calibration = 4 windows
    expected_bits = [bool(e > threshold) for e in expected[4:]]
    assert [m.data for m in bits] == expected_bits
    parsed = [parse_bit(m) for m in steps]
    assert [p.step for p in parsed] == list(range(1, 13))
    assert [p.bit for p in parsed] == expected_bits
    assert {(p.stream, p.window_us) for p in parsed} == {(node.stream_id, WINDOW_US)}
    assert node.source.dropped_chunks == 0 and node.windows == 12


def test_mic_says_once_when_the_audio_breaks_its_contract(
    run: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    """Samples of 3e38 and a 2-channel layout were windowed without a word.

    Counted, worded once, a WARN diagnostic; the audio is still windowed (nothing lost).
    """
    node, probe, graph = run(MicNode, source="topic", bit_source="energy", threshold_mode="fixed",
                             wait_for_listeners=1, start_delay_s=0.0)  # fmt: skip
    probe.listen("sound_step", Int64MultiArray)
    energies = probe.listen("sound_energy", Float32)
    audio = probe.talk("audio", Float32MultiArray)
    graph.connected(audio)
    graph.run_until(lambda: node.started, "the mic's start gate")
    capfd.readouterr()
    assert node.diagnostic_status()[0] == OK
    loud = np.full(8000, 3e38, np.float32)
    stereo = _audio_message(np.zeros(8000, np.float32))
    stereo.layout.dim = [MultiArrayDimension(label="frames", size=4000, stride=8000),
                         MultiArrayDimension(label="channels", size=2, stride=2)]  # fmt: skip
    for message in (_audio_message(loud), _audio_message(loud), stereo, stereo):
        audio.publish(message)
    graph.run_until(lambda: len(energies) == 4, "4 windows")
    err = capfd.readouterr().err
    assert err.count("audio samples outside [-1, 1]") == 1, err
    assert err.count("multi-channel audio on 'audio' (layout frames=4000 x channels=2)") == 1
    level, message, values = node.diagnostic_status()
    assert level == WARN, message
    assert "outside [-1, 1] (up to 3e+38)" in message and "multi-channel" in message
    assert values["chunks_out_of_range"] == 2 and values["samples_out_of_range"] == 16000
    assert values["chunks_multichannel"] == 2
    assert node.contract.rate.paced_by_source() is False  # the probe is no paced source


@pytest.mark.parametrize(
    ("bit_source", "options", "calibration"),
    [
        ("speech_band", {"threshold_mode": "calibrate", "calibration_s": 2.0}, 4),
        ("energy", {"threshold_mode": "noise_floor", "calibration_s": 2.0}, 4),
        ("speech_band", {"threshold_mode": "noise_floor", "calibration_s": 1.0}, 2),
        ("vad", {}, 0),
    ],
)
def test_mic_bit_sources_window_any_chunking_like_offline(
    run: Callable, bit_source: str, options: dict[str, Any], calibration: int
) -> None:
    node, probe, graph = run(MicNode, source="topic", bit_source=bit_source,
                             wait_for_listeners=1, start_delay_s=0.0, **options)  # fmt: skip
    steps = probe.listen("sound_step", Int64MultiArray)
    energies = probe.listen("sound_energy", Float32)
    audio = probe.talk("audio", Float32MultiArray)
    graph.connected(audio)
    graph.run_until(lambda: node.started, "the mic's start gate")
    samples = _room_audio(16).astype(np.float64)
    broken = np.zeros(5000)
    broken[[10, 20]] = np.nan, np.inf
    audio.publish(_audio_message(broken))  # refused whole: counted, no window from it
    for chunk in np.array_split(samples, 37):  # chunks that do not line up with windows
        audio.publish(_audio_message(chunk))
    graph.run_until(lambda: len(energies) == 16 and len(steps) == 16 - calibration,
                    "16 windows and their bits")  # fmt: skip
    assert node.source.bad_chunks == 1
    offline = make_bit_source(bit_source, 16000, 0.5, **options)
    expected = [offline.push_window(w) for w in samples.reshape(16, 8000)]
    assert expected[:calibration] == [None] * calibration
    assert [parse_bit(m).bit for m in steps] == expected[calibration:]
    assert 0 < sum(expected[calibration:]) < 16 - calibration
    assert np.array_equal(
        np.float32([m.data for m in energies]),
        window_energies_db(samples, 16000, 0.5).astype(np.float32),
    )
    _, _, values = node.diagnostic_status()
    assert values["bit_source"] == bit_source and values["calibration_state"] == "ready"


def test_mic_holds_a_burst_until_the_controller_answers(run: Callable) -> None:
    node, probe, graph = run(MicNode, source="topic", bit_source="energy", threshold_mode="fixed",
                             threshold_db=-40.0, wait_for_listeners=1, start_delay_s=0.0,
                             max_steps_ahead=4)  # fmt: skip
    steps = probe.listen("sound_step", Int64MultiArray)
    audio = probe.talk("audio", Float32MultiArray)
    answers = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(audio)
    graph.run_until(lambda: node.started and node._decisions_sub.get_publisher_count() == 1,
                    "start, with a controller")  # fmt: skip
    audio.publish(_audio_message(_room_audio(30)))  # 15 s in one message
    graph.run_until(lambda: len(steps) == 4, "the first 4 steps")
    graph.run_for_callbacks(30)
    assert len(steps) == 4 and node.outbox.backlog == 26, "no step beyond max_steps_ahead"
    while len(steps) < 30:
        published = len(steps)  # answer the last step out: 4 more may go
        answers.publish(decisions_of(node.stream_id, [0] * published)[-1])
        graph.run_until(lambda n=published: len(steps) == min(30, n + 4), "the next 4 steps")
    assert [parse_bit(m).step for m in steps] == list(range(1, 31))
    assert node.outbox.dropped == 0


def test_mic_says_the_warmup_on_no_step_and_decides_a_window_after_the_decisions_before_it(
    run: Callable,
) -> None:
    """The default source (background) labels windows by the decisions.

    Its 12 warm-up windows give no step, each said on ``no_step``. A window that comes
    before the decision on the last bit (DDS orders no topic against another: in lockstep
    the room's next window may overtake the decision) waits for it, so every bit is the
    offline loop's, which hears each decision before the next window.
    """
    node, probe, graph = run(MicNode, source="topic", wait_for_listeners=1, start_delay_s=0.0,
                             lockstep_timeout_s=600.0)  # fmt: skip
    steps = probe.listen("sound_step", Int64MultiArray)
    no_steps = probe.listen("no_step", Int64MultiArray)
    audio = probe.talk("audio", Float32MultiArray)
    answers = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(audio)
    graph.run_until(lambda: node.started and node.count_publishers("vocalize_step") == 1,
                    "start, with a controller")  # fmt: skip
    windows = _room_audio(16).reshape(16, 8000)
    for window in windows[:13]:
        audio.publish(_audio_message(window))
    graph.run_until(lambda: len(no_steps) == 12 and len(steps) == 1, "the warm-up, a step")
    assert [list(m.data) for m in no_steps] == [[node.stream_id, w] for w in range(1, 13)]
    decisions = [1, 0, 0]
    for step, (window, u) in enumerate(zip(windows[13:], decisions, strict=True), start=1):
        audio.publish(_audio_message(window))  # before the decision on step `step`
        graph.run_for_callbacks(30)
        assert len(steps) == step and len(node.controls.held) == 1, "it waits for the decision"
        answers.publish(decisions_of(node.stream_id, [u], first_step=step)[0])
        graph.run_until(lambda n=step: len(steps) == n + 1, "its step, after the decision")
    offline = make_bit_source("background", 16000, 0.5)
    offline.follow_model(ROBOT)
    expected = [offline.push_window(w) for w in windows[:13]]
    for window, u in zip(windows[13:], decisions, strict=True):
        offline.note_decision(u)
        expected.append(offline.push_window(window))
    assert expected[:12] == [None] * 12
    assert [parse_bit(m).bit for m in steps] == expected[12:]
    assert node.controls.values()["windows_decided_early"] == 0


def test_mic_accepts_an_integer_for_a_float_parameter(run: Callable) -> None:
    node, _, _ = run(MicNode, source="topic", bit_source="energy", start_delay_s=1)
    parameter = node.get_parameter("start_delay_s")
    assert parameter.type_ == Parameter.Type.DOUBLE and parameter.value == 1.0


# ---------------------------------------------------------------------- fake room, speaker


def _silent_room(run: Callable, **parameters: Any) -> tuple[Any, Probe, SteppedExecutor, list]:
    """A lockstep fake room (silent, no events, seed 4), its probe, executor and audio."""
    node, probe, graph = run(FakeAudioNode, room="silent", event_rate_hz=0.0, seed=4,
                             start_delay_s=0.0, **parameters)  # fmt: skip
    return node, probe, graph, probe.listen("audio", Float32MultiArray)


def _assert_silent_room_windows(audio: list, vocalize_after: int) -> list:
    """The messages are the offline room's windows; returns those.

    The robot vocalized after window ``vocalize_after`` (1, 2, ...).
    """
    offline = FakeRoom(FakeRoomConfig.preset("silent", event_rate_hz=0.0), seed=4)
    expected = [offline.next_window() for _ in range(vocalize_after)]
    offline.vocalize()
    expected += [offline.next_window() for _ in range(len(audio) - vocalize_after)]
    for message, window in zip(audio, expected, strict=True):
        assert np.array_equal(np.frombuffer(message.data, np.float32),
                              as_transmitted(window.samples))  # fmt: skip
    return expected


def test_fake_room_waits_in_lockstep_and_puts_the_robot_sound_after_vocalize(
    run: Callable,
) -> None:
    node, probe, graph, audio = _silent_room(run)
    truth = probe.listen("partner_present", Bool)
    vocalize = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(vocalize)
    graph.run_until(lambda: len(audio) == 1, "the first window")
    graph.run_for_callbacks(30)
    assert len(audio) == 1, "lockstep: no window before a decision"
    for message in decisions_of(STREAM, [True, False, False]):
        vocalize.publish(message)
    graph.run_until(lambda: len(audio) == 4 and len(truth) == 4, "3 more windows")
    expected = _assert_silent_room_windows(audio, vocalize_after=1)
    loud = [float(window_energies_db(w.samples, 16000, 0.5)[0]) > -40 for w in expected]
    assert loud == [False, True, False, False]
    assert [m.data for m in truth] == [False] * 4


def test_fake_room_in_lockstep_goes_on_when_the_mic_says_a_window_gave_no_step(
    run: Callable,
) -> None:
    """A window that gave mic_node no step is answered on ``no_step``.

    (Its bit source warming up.) The room goes on, once per window said; then on a
    decision, as before.
    """
    node, probe, graph, audio = _silent_room(run)
    no_step = probe.talk("no_step", Int64MultiArray)
    vocalize = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(vocalize)
    graph.connected(no_step)
    graph.run_until(lambda: len(audio) == 1, "the first window")
    for window in (1, 1, 2):  # window 1 said twice: one window more, not two
        no_step.publish(no_step_message(NoStep(STREAM, window)))
        graph.run_until(lambda w=window: len(audio) == w + 1, f"the window after {window}")
    graph.run_for_callbacks(30)
    assert len(audio) == 3 and node.windows_without_step == 2
    for message in decisions_of(STREAM, [True]):  # the mic's first step: window 3
        vocalize.publish(message)
    graph.run_until(lambda: len(audio) == 4, "the window after the first decision")
    assert node.pacer.answers == 3 and node.pacer.timeouts == 0
    _assert_silent_room_windows(audio, vocalize_after=3)  # the chirp in window 4


def test_fake_room_in_lockstep_ignores_a_no_step_far_ahead(run: Callable) -> None:
    """A forged ``no_step`` 3,000 windows ahead releases nothing and blocks nothing.

    (Without the pace rule every real ``no_step`` after it looked like a repeat: the room
    went on only at its lockstep timeout.)
    """
    node, probe, graph, audio = _silent_room(run)
    no_step = probe.talk("no_step", Int64MultiArray)
    graph.connected(probe.talk("vocalize_step", Int64MultiArray))  # the room waits for one
    graph.connected(no_step)
    graph.run_until(lambda: len(audio) == 1, "the first window")
    no_step.publish(no_step_message(NoStep(STREAM, 1)))
    graph.run_until(lambda: len(audio) == 2, "the window after 1")
    no_step.publish(no_step_message(NoStep(STREAM, 3001)))
    graph.run_until(lambda: node.no_step_pace.jumps == 1, "the jump named")
    for window in (2, 3):
        no_step.publish(no_step_message(NoStep(STREAM, window)))
        graph.run_until(lambda w=window: len(audio) == w + 1, f"the window after {window}")
    graph.run_for_callbacks(30)
    assert len(audio) == 4 and node.windows_without_step == 3
    assert node.pacer.timeouts == 0
    level, _, values = node.diagnostic_status()
    assert values["jumps_ignored"] == 1 and level == ERROR


def test_fake_room_in_lockstep_holds_each_window_for_its_max_speed(run: Callable) -> None:
    """lockstep_max_speed 2: each next window waits 0.25 s after its decision.

    A bound from below only: a loaded machine makes the gaps longer, never shorter.
    """
    node, probe, graph = run(FakeAudioNode, room="silent", event_rate_hz=0.0, seed=4,
                             start_delay_s=0.0, lockstep_max_speed=2.0)  # fmt: skip
    arrived: list[float] = []
    audio = probe.listen("audio", Float32MultiArray,
                         then=lambda _: arrived.append(time.monotonic()))  # fmt: skip
    vocalize = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(vocalize)
    graph.run_until(lambda: len(audio) == 1, "the first window")
    answered: list[float] = []
    for count, message in enumerate(decisions_of(STREAM, [True, False, False]), start=2):
        answered.append(time.monotonic())
        vocalize.publish(message)
        graph.run_until(lambda n=count: len(audio) == n, "the next window")
    gaps = [window - answer for answer, window in zip(answered, arrived[1:], strict=True)]
    assert min(gaps) >= 0.25, gaps
    assert node.pacer.answers == 3 and node.pacer.timeouts == 0
    _assert_silent_room_windows(audio, vocalize_after=1)  # the same room, held


def test_fake_room_hears_one_controller_once_per_step(run: Callable) -> None:
    node, probe, graph = run(FakeAudioNode, room="silent", event_rate_hz=0.0, seed=4,
                             start_delay_s=0.0)  # fmt: skip
    audio = probe.listen("audio", Float32MultiArray)
    vocalize = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(vocalize)
    graph.run_until(lambda: len(audio) == 1, "the first window")
    true, repeated = decisions_of(STREAM, [False]), decisions_of(STREAM, [False])
    second = decisions_of(STREAM, [True], controller=6)
    for message in true + repeated + second:
        vocalize.publish(message)
    graph.run_until(lambda: node.foreign.count == 1, "the second controller seen")
    graph.run_for_callbacks(30)
    assert len(audio) == 2 and node.room.vocalizations == 0


def test_speaker_dry_run_counts_vocalizations(run: Callable) -> None:
    node, probe, graph = run(SpeakerNode)
    vocalize = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(vocalize)
    for message in decisions_of(STREAM, (True, False, True, False)):
        vocalize.publish(message)
    graph.run_until(lambda: node.requests == 2, "2 vocalizations")
    level, message, values = node.diagnostic_status()
    assert "dry run" in message and values["played"] == 0


def test_speaker_obeys_only_the_controller_it_follows(run: Callable) -> None:
    """A second controller, a repeated step and a forged jump: named, none of them played."""
    node, probe, graph = run(SpeakerNode)
    vocalize = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(vocalize)
    true = decisions_of(STREAM, (True, False, False, True, False))
    second = decisions_of(STREAM, [True] * 5, controller=6)  # always vocalize
    forged = decision_message(StepDecision(STREAM, 3000, True, 5))  # the true controller's id
    other_controller = probe.talk("vocalize_step", Int64MultiArray)  # its own writer
    forger = probe.talk("vocalize_step", Int64MultiArray)
    graph.connected(other_controller)
    graph.connected(forger)
    vocalize.publish(true[0])  # the first controller heard is followed
    graph.run_until(lambda: node._answered == (STREAM, 1), "the first decision")
    for step, (mine, other) in enumerate(zip(true, second, strict=True), start=1):
        if step > 1:
            vocalize.publish(mine)
        other_controller.publish(other)
        if step == 2:
            vocalize.publish(true[0])  # step 1 again
            forger.publish(forged)
    graph.run_until(lambda: node._answered == (STREAM, 5) and node.pace.jumps == 1
                    and node.controllers.foreign_messages == 5, "every decision taken")  # fmt: skip
    assert node.requests == 2, "the followed controller's two vocalizations, once each"
    level, message, values = node.diagnostic_status()
    assert level == ERROR and "second controller" in message, message
    assert values["controller"] == 5 and values["foreign_decisions"] == 5


@pytest.mark.parametrize(
    "node_class", [MicNode, ControllerNode, BeliefNode, PostureNode, SpeakerNode, FakeAudioNode]
)
def test_every_parameter_has_a_description_and_numbers_a_range(
    run: Callable, node_class: type
) -> None:
    node, _, _ = run(node_class)
    builtin = {"use_sim_time", "start_type_description_service"}
    names = [name for name in node.list_parameters([], 0).names if name not in builtin]
    assert len(names) >= 2
    for name, descriptor in zip(names, node.describe_parameters(names), strict=True):
        assert descriptor.description, name
        assert descriptor.additional_constraints, name
        if descriptor.type == ParameterType.PARAMETER_DOUBLE:
            assert len(descriptor.floating_point_range) == 1, name
        if descriptor.type == ParameterType.PARAMETER_INTEGER:
            assert len(descriptor.integer_range) == 1, name


def test_mic_refuses_a_calibration_that_cannot_separate_sound_from_quiet(run: Callable) -> None:
    node, probe, graph = run(MicNode, source="topic", bit_source="energy", calibration_s=2.0,
                             wait_for_listeners=1, start_delay_s=0.0)  # fmt: skip
    steps = probe.listen("sound_step", Int64MultiArray)
    energies = probe.listen("sound_energy", Float32)
    audio = probe.talk("audio", Float32MultiArray)
    graph.connected(audio)
    graph.run_until(lambda: node.started, "the mic's start gate")
    hiss = np.random.default_rng(0).normal(0.0, 0.05, 16 * 8000)  # steady noise, no contrast
    audio.publish(_audio_message(hiss))
    graph.run_until(lambda: len(energies) == 16, "16 windows")
    graph.run_for_callbacks(20)
    assert steps == [], "no bit from a calibration that does not separate"
    level, message, values = node.diagnostic_status()
    assert level == ERROR and "cannot separate" in message and " dB" in message
    assert int(values["calibration_failures"]) >= 1

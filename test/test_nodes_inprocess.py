"""Each node on its own, in the test process, driven over real DDS by a probe node."""

from __future__ import annotations

import array
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import rclpy
from rcl_interfaces.msg import ParameterType
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Bool, Float32, Float32MultiArray, Float64, String
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.audio.threshold import kmeans_split
from infomax_contingency.core.controllers import PolicyController
from infomax_contingency.core.model import ModelParams, StatisticTracker
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.nodes.belief_node import BeliefNode
from infomax_contingency.nodes.controller_node import ControllerNode
from infomax_contingency.nodes.fake_audio_node import FakeAudioNode
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.qos import LATCHED_READER_QOS, STREAM_QOS
from infomax_contingency.nodes.speaker_node import SpeakerNode
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.fake_room import FakeRoom, FakeRoomConfig, as_transmitted
from infomax_contingency.testing.graph import SpinThread, wait_until

ROBOT = ModelParams.named("robot")
TIMEOUT_S = 30.0


class Probe(Node):
    """Publishes to and records from the node under test."""

    def __init__(self) -> None:
        super().__init__("probe")
        self.received: dict[str, list[Any]] = {}
        self.pubs: dict[str, Any] = {}

    def listen(self, topic: str, kind: type, qos=STREAM_QOS) -> list[Any]:
        self.received[topic] = []
        self.create_subscription(kind, topic, self.received[topic].append, qos)
        return self.received[topic]

    def talk(self, topic: str, kind: type) -> Any:
        self.pubs[topic] = self.create_publisher(kind, topic, STREAM_QOS)
        return self.pubs[topic]


def params(**values: Any) -> list[Parameter]:
    return [Parameter(name, value=value) for name, value in values.items()]


@pytest.fixture
def run() -> Iterator[Callable[..., tuple[Any, Probe]]]:
    """``run(NodeClass, **parameters)`` -> (node, probe), both spinning; cleaned up after."""
    rclpy.init()
    made: list[Node] = []
    spinners: list[SpinThread] = []

    def start(node_class: type, **parameters: Any) -> tuple[Any, Probe]:
        node = node_class(parameter_overrides=params(**parameters))
        probe = Probe()
        made.extend([node, probe])
        spinner = SpinThread(node, probe)
        spinners.append(spinner.__enter__())
        return node, probe

    try:
        yield start
    finally:
        for spinner in spinners:
            spinner.__exit__(None, None, None)
        for node in made:
            node.destroy_node()
        rclpy.try_shutdown()


def connected(publisher: Any, count: int = 1) -> None:
    assert wait_until(lambda: publisher.get_subscription_count() >= count, TIMEOUT_S)


def wait_len(items: list, n: int) -> None:
    assert wait_until(lambda: len(items) >= n, TIMEOUT_S), f"got {len(items)} of {n}"


def test_controller_answers_every_bit_like_the_offline_controller(run: Callable) -> None:
    node, probe = run(ControllerNode)
    decisions = probe.listen("vocalize", Bool)
    sound = probe.talk("sound", Bool)
    connected(sound)
    assert wait_until(lambda: node.vocalize_pub.get_subscription_count() >= 1, TIMEOUT_S)
    bits = np.random.default_rng(4).random(80) < 0.3
    for y in bits:
        sound.publish(Bool(data=bool(y)))
    wait_len(decisions, len(bits))
    table = PolicyTable.load(resource_path("policies", "robot_receding_H24_M60.npz"))
    offline = PolicyController(table)
    assert [m.data for m in decisions] == [bool(offline.step(int(y))) for y in bits]
    assert any(m.data for m in decisions)


def test_controller_takes_a_table_by_name_and_matching_params(run: Callable) -> None:
    node, _ = run(ControllerNode, params="paper", policy_file="paper_episodic_T40.npz")
    assert node.controller.table.mode == "episodic" and node.controller.table.horizon == 40


def test_belief_pairs_bits_and_decisions_whatever_their_order(run: Callable) -> None:
    node, probe = run(BeliefNode, memory_steps=5)
    beliefs = probe.listen("belief", Float64)
    sound, vocalize = probe.talk("sound", Bool), probe.talk("vocalize", Bool)
    connected(sound)
    connected(vocalize)
    assert wait_until(lambda: node.belief_pub.get_subscription_count() >= 1, TIMEOUT_S)
    rng = np.random.default_rng(2)
    bits, decisions = rng.random(40) < 0.4, rng.random(40) < 0.2
    vocalize.publish(Bool(data=True))  # answers a window the node never saw: dropped
    for y, u in zip(bits, decisions, strict=True):
        sound.publish(Bool(data=bool(y)))
        vocalize.publish(Bool(data=bool(u)))
    wait_len(beliefs, len(bits))
    assert wait_until(lambda: node.pairer.steps == 40 and node.pairer.pending_decisions == 0, 10)
    assert node.pairer.dropped_decisions == 1
    tracker = StatisticTracker(ROBOT, memory=5)
    offline = []
    for y, u in zip(bits, decisions, strict=True):
        offline.append(tracker.observe(y).belief(ROBOT))
        tracker.act(u)
    assert [m.data for m in beliefs] == offline
    assert node.tracker.statistic == tracker.statistic


def test_belief_reset_service_forgets_the_history(run: Callable) -> None:
    node, probe = run(BeliefNode)
    sound, vocalize = probe.talk("sound", Bool), probe.talk("vocalize", Bool)
    connected(sound)
    connected(vocalize)
    for _ in range(3):
        sound.publish(Bool(data=True))
        vocalize.publish(Bool(data=False))
    assert wait_until(lambda: node.tracker.statistic.p3 > 0, TIMEOUT_S)
    client = probe.create_client(Trigger, "reset")
    assert client.wait_for_service(timeout_sec=TIMEOUT_S)
    future = client.call_async(Trigger.Request())
    assert wait_until(future.done, TIMEOUT_S)
    assert future.result().success and "reset after" in future.result().message
    assert node.tracker.statistic.counts == (0, 0, 0, 0)
    assert node.belief == pytest.approx(ROBOT.pi)


def test_posture_follows_the_belief_with_hysteresis(run: Callable) -> None:
    node, probe = run(PostureNode, joint_names=["pan", "tilt"], attentive_positions=[0.0, 0.2],
                      bored_positions=[0.5, -0.3], move_duration_s=1.5)  # fmt: skip
    postures = probe.listen("posture", String, LATCHED_READER_QOS)
    targets = probe.listen("joint_targets", JointTrajectory, LATCHED_READER_QOS)
    wait_len(postures, 1)  # the initial posture reaches a late joiner
    wait_len(targets, 1)
    assert postures[0].data == "bored"
    belief = probe.talk("belief", Float64)
    connected(belief)
    for b in (0.5, 0.95, 0.5, 0.1, 0.3):
        belief.publish(Float64(data=b))
    wait_len(postures, 3)
    assert wait_until(lambda: len(targets) >= 3, TIMEOUT_S)
    assert [m.data for m in postures] == ["bored", "attentive", "bored"]
    assert list(targets[1].joint_names) == ["pan", "tilt"]
    assert list(targets[1].points[0].positions) == [0.0, 0.2]
    assert list(targets[2].points[0].positions) == [0.5, -0.3]
    duration = targets[1].points[0].time_from_start
    assert (duration.sec, duration.nanosec) == (1, 500_000_000)
    assert node.changes == 2


def test_mic_topic_source_windows_any_chunking_and_calibrates(run: Callable) -> None:
    node, probe = run(MicNode, source="topic", calibration_s=2.0, wait_for_listeners=1,
                      start_delay_s=0.0)  # fmt: skip
    bits = probe.listen("sound", Bool)
    energies = probe.listen("sound_energy", Float32)
    audio = probe.talk("audio", Float32MultiArray)
    connected(audio)
    room = FakeRoom(FakeRoomConfig.preset("noisy", event_rate_hz=2.0), seed=1)
    samples = np.concatenate([as_transmitted(room.next_window().samples) for _ in range(16)])
    for chunk in np.array_split(samples, 37):  # chunks that do not line up with windows
        message = Float32MultiArray()
        message.data = array.array("f", chunk.tobytes())
        audio.publish(message)
    wait_len(energies, 16)
    wait_len(bits, 12)
    expected = window_energies_db(samples.astype(np.float64), 16000, 0.5)
    assert np.array_equal(np.float32([m.data for m in energies]), expected.astype(np.float32))
    threshold = kmeans_split(expected[:4]).threshold_db  # 2 s of calibration = 4 windows
    assert [m.data for m in bits] == [bool(e > threshold) for e in expected[4:]]
    assert node.dropped_chunks == 0 and node.windows == 12


def test_mic_accepts_an_integer_for_a_float_parameter(run: Callable) -> None:
    node, _ = run(MicNode, source="topic", window_s=1)
    assert node.window_s == 1.0
    parameter = node.get_parameter("window_s")
    assert parameter.type_ == Parameter.Type.DOUBLE and parameter.value == 1.0


def test_fake_room_waits_in_lockstep_and_puts_the_robot_sound_after_vocalize(
    run: Callable,
) -> None:
    node, probe = run(FakeAudioNode, room="silent", event_rate_hz=0.0, seed=4, start_delay_s=0.0)
    audio = probe.listen("audio", Float32MultiArray)
    truth = probe.listen("partner_present", Bool)
    vocalize = probe.talk("vocalize", Bool)
    connected(vocalize)
    wait_len(audio, 1)
    assert not wait_until(lambda: len(audio) > 1, 0.5), "lockstep: no window before vocalize"
    for u in (True, False, False):
        vocalize.publish(Bool(data=u))
    wait_len(audio, 4)
    wait_len(truth, 4)
    offline = FakeRoom(FakeRoomConfig.preset("silent", event_rate_hz=0.0), seed=4)
    expected = [offline.next_window()]
    offline.vocalize()
    expected += [offline.next_window() for _ in range(3)]
    for message, window in zip(audio, expected, strict=True):
        assert np.array_equal(
            np.frombuffer(message.data, np.float32), as_transmitted(window.samples)
        )
    loud = [float(window_energies_db(w.samples, 16000, 0.5)[0]) > -40 for w in expected]
    assert loud == [False, True, False, False]
    assert [m.data for m in truth] == [False] * 4


def test_speaker_dry_run_counts_vocalizations(run: Callable) -> None:
    node, probe = run(SpeakerNode)
    vocalize = probe.talk("vocalize", Bool)
    connected(vocalize)
    for u in (True, False, True, False):
        vocalize.publish(Bool(data=u))
    assert wait_until(lambda: node.requests == 2, TIMEOUT_S)
    level, message, values = node.diagnostic_status()
    assert "dry run" in message and values["played"] == 0


@pytest.mark.parametrize(
    "node_class", [MicNode, ControllerNode, BeliefNode, PostureNode, SpeakerNode, FakeAudioNode]
)
def test_every_parameter_has_a_description_and_numbers_a_range(
    run: Callable, node_class: type
) -> None:
    extra = {"source": "topic"} if node_class is MicNode else {}
    node, _ = run(node_class, **extra)
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

"""Live parameters through the parameter services, as ``ros2 param set`` uses them.

Each node runs in the test process on a hand-stepped executor; a probe node sets its
parameters with rclpy's parameter client over DDS (the services ``/<node>/set_parameters``
that ``ros2 param set`` calls) and watches the node's output change.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Float64, String

from infomax_contingency.nodes.belief_node import BeliefNode
from infomax_contingency.nodes.controller_node import ControllerNode
from infomax_contingency.nodes.fake_audio_node import FakeAudioNode
from infomax_contingency.nodes.graph_node import WAITING_NOTICE_S, WARN
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.qos import LATCHED_READER_QOS
from infomax_contingency.nodes.speaker_node import SpeakerNode
from infomax_contingency.testing.stepped import Probe, SteppedExecutor

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def graph() -> Iterator[Callable[..., tuple[Any, Probe, SteppedExecutor]]]:
    """``graph(NodeClass, **parameters)`` -> (node, probe, executor); cleaned up after."""
    rclpy.init()
    executors: list[SteppedExecutor] = []

    def start(node_class: type, **parameters: Any) -> tuple[Any, Probe, SteppedExecutor]:
        overrides = [Parameter(name, value=value) for name, value in parameters.items()]
        node = node_class(parameter_overrides=overrides)
        probe = Probe()
        executors.append(SteppedExecutor([node, probe]))
        return node, probe, executors[-1]

    try:
        yield start
    finally:
        for executor in executors:
            executor.close()
        rclpy.try_shutdown()


def set_remotely(
    probe: Probe, executor: SteppedExecutor, node: str, **values: Any
) -> list[SetParametersResult]:
    """Set parameters of ``node`` through its set_parameters service; the results."""
    client = AsyncParameterClient(probe, node)
    executor.run_until(lambda: client.services_are_ready(), f"the parameter services of {node}")
    future = client.set_parameters([Parameter(k, value=v) for k, v in values.items()])
    executor.run_until(future.done, f"the answer of {node}/set_parameters")
    return list(future.result().results)


def test_a_live_posture_threshold_changes_the_posture_at_once(graph: Callable) -> None:
    _node, probe, executor = graph(PostureNode)
    postures = probe.listen("posture", String, LATCHED_READER_QOS)
    executor.run_until(lambda: postures, "the initial posture")
    belief = probe.talk("belief", Float64)
    executor.connected(belief)
    belief.publish(Float64(data=0.7))  # below the default attentive_above 0.9: stays bored
    [result] = set_remotely(probe, executor, "posture_node", attentive_above=0.6)
    assert result.successful, result.reason
    belief.publish(Float64(data=0.7))
    executor.run_until(lambda: len(postures) >= 2, "the posture change after the new threshold")
    assert [m.data for m in postures] == ["bored", "attentive"]


def test_a_live_set_is_checked_as_at_start_up(graph: Callable) -> None:
    node, probe, executor = graph(PostureNode)
    [result] = set_remotely(probe, executor, "posture_node", bored_below=0.95)
    assert not result.successful
    assert "must be below 'attentive_above'" in result.reason
    assert node.hysteresis.bored_below == 0.2
    [result] = set_remotely(probe, executor, "posture_node", bored_positions=[0.0])
    assert not result.successful and "one position per joint" in result.reason


def test_parameters_that_cannot_change_are_read_only_with_a_reason(graph: Callable) -> None:
    node, probe, executor = graph(PostureNode)
    [result] = set_remotely(probe, executor, "posture_node", initial_posture="attentive")
    assert not result.successful and "read-only" in result.reason
    assert node.describe_parameter("initial_posture").read_only
    assert not node.describe_parameter("attentive_above").read_only


def test_mic_threshold_is_live_in_fixed_mode_only(graph: Callable) -> None:
    node, probe, executor = graph(MicNode, threshold_mode="fixed", threshold_db=-40.0)
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-5.0)
    assert result.successful, result.reason
    assert node.binarizer.threshold_db == -5.0
    [result] = set_remotely(probe, executor, "mic_node", threshold_mode="bogus")
    assert not result.successful
    for name in ("source", "window_s", "device"):
        assert node.describe_parameter(name).read_only, name


def test_mic_threshold_is_refused_while_calibrating(graph: Callable) -> None:
    node, probe, executor = graph(MicNode, threshold_mode="calibrate")
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-5.0)
    assert not result.successful and "threshold_mode fixed" in result.reason
    assert node.binarizer.calibrating


def test_mic_bit_source_parameters_are_read_only_and_vad_has_no_live_threshold(
    graph: Callable,
) -> None:
    node, probe, executor = graph(MicNode, bit_source="vad", threshold_mode="fixed")
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-5.0)
    assert not result.successful and "no effect with bit_source vad" in result.reason
    assert node.binarizer is None and node.bits.name == "vad"
    for name in ("bit_source", "noise_margin_db", "noise_window_s", "noise_percentile",
                 "vad_aggressiveness", "vad_frame_ms", "vad_min_voiced_s"):  # fmt: skip
        assert node.describe_parameter(name).read_only, name
    [result] = set_remotely(probe, executor, "mic_node", bit_source="energy")
    assert not result.successful and "read-only" in result.reason


def test_mic_speech_band_threshold_is_live_in_fixed_mode(graph: Callable) -> None:
    node, probe, executor = graph(MicNode, bit_source="speech_band", threshold_mode="fixed")
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-30.0)
    assert result.successful, result.reason
    assert node.bits.threshold_db == -30.0


@pytest.mark.parametrize(
    "node_class",
    [MicNode, ControllerNode, BeliefNode, PostureNode, SpeakerNode, FakeAudioNode],
)
def test_code_defaults_equal_config_robot_yaml(graph: Callable, node_class: type) -> None:
    """A missing params file changes nothing: every value robot.yaml sets is the default."""
    config = yaml.safe_load((ROOT / "config" / "robot.yaml").read_text())
    node, _probe, _executor = graph(node_class)
    name = node.get_name()
    expected = {**config["/**"]["ros__parameters"], **config[f"/**/{name}"]["ros__parameters"]}
    for parameter, value in expected.items():
        if node.has_parameter(parameter):
            assert node.get_parameter(parameter).value == value, f"{name}: {parameter}"


def test_fake_room_lockstep_timeout_is_live(graph: Callable) -> None:
    node, probe, executor = graph(FakeAudioNode, lockstep=True)
    [result] = set_remotely(probe, executor, "fake_audio_node", lockstep_timeout_s=7.5)
    assert result.successful, result.reason
    assert node.pacer.timeout_s == 7.5
    [result] = set_remotely(probe, executor, "fake_audio_node", seed=3)
    assert not result.successful and "read-only" in result.reason


# ------------------------------------------------------------------ waiting is visible


@pytest.mark.parametrize(
    ("node_class", "topic", "how"),
    [(MicNode, "/audio", "fake_audio_node"), (ControllerNode, "/sound_step", "mic_node")],
)
def test_a_waiting_node_says_what_it_waits_for(
    graph: Callable, node_class: type, topic: str, how: str
) -> None:
    node, probe, executor = graph(node_class)
    statuses = probe.listen("/diagnostics", DiagnosticArray)
    assert node.check_waiting(1.0) == ""  # too early to say anything
    waiting = node.check_waiting(WAITING_NOTICE_S + 1.0)
    assert f"waiting for '{topic}'" in waiting and how in waiting
    node.publish_diagnostics()
    executor.run_until(lambda: statuses, "a diagnostics message")
    [status] = statuses[-1].status
    assert status.level == WARN and waiting in status.message
    node.count_arrival(topic.lstrip("/"))
    assert node.check_waiting(WAITING_NOTICE_S + 2.0) == ""

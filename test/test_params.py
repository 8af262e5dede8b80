"""Live parameters through the parameter services, as ``ros2 param set`` uses them.

Each node runs in the test process on a hand-stepped executor; a probe node sets its
parameters with rclpy's parameter client over DDS (the services ``/<node>/set_parameters``
that ``ros2 param set`` calls) and watches the node's output change.
"""

from __future__ import annotations

import array
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Bool, Float32, Float32MultiArray, Float64, Int64MultiArray, String
from std_srvs.srv import Trigger

from infomax_contingency.audio.devices import AudioDeviceError
from infomax_contingency.audio.playback import PlayEvent
from infomax_contingency.audio.threshold import ThresholdFit, kmeans_split
from infomax_contingency.audio.threshold_file import save_threshold
from infomax_contingency.audio.windows import WavReplay
from infomax_contingency.core.posture import BORED_BELOW
from infomax_contingency.nodes import speaker_node
from infomax_contingency.nodes.belief_node import BeliefNode
from infomax_contingency.nodes.controller_node import ControllerNode
from infomax_contingency.nodes.fake_audio_node import FakeAudioNode
from infomax_contingency.nodes.graph_node import ERROR, WAITING_NOTICE_S, WARN
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.parameters import SIM_TIME_REASON, ConfigError
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.qos import LATCHED_READER_QOS
from infomax_contingency.nodes.speaker_node import EVENTS_POLL_S, SpeakerNode
from infomax_contingency.nodes.step_topics import (
    StepDecision,
    decision_message,
    parse_decision,
)
from infomax_contingency.testing.stepped import (
    Probe,
    SteppedExecutor,
    nodes_on_their_own_executors,
)

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def graph() -> Iterator[Callable[..., tuple[Any, Probe, SteppedExecutor]]]:
    """``graph(NodeClass, **parameters)`` -> (node, probe, executor); cleaned up after."""
    with nodes_on_their_own_executors() as start:
        yield start


def set_remotely(
    probe: Probe, executor: SteppedExecutor, node: str, **values: Any
) -> list[SetParametersResult]:
    """Set parameters of ``node`` through its set_parameters service; the results."""
    client = AsyncParameterClient(probe, node)
    executor.run_until(lambda: client.services_are_ready(), f"the parameter services of {node}")
    future = client.set_parameters([Parameter(k, value=v) for k, v in values.items()])
    executor.run_until(future.done, f"the answer of {node}/set_parameters")
    return list(future.result().results)


def test_posture_node_holds_while_a_second_publisher_is_on_belief(graph: Callable) -> None:
    """A plain Float64 names no sender: a forged belief must not move the robot.

    As ``ros2 topic pub --once``: a publisher that appears, sends one belief, and goes.
    """
    node, probe, executor = graph(PostureNode)
    rightful = probe.talk("belief", Float64)
    executor.connected(rightful)
    forger = probe.talk("belief", Float64)
    executor.connected(forger)
    forger.publish(Float64(data=0.99))
    executor.run_until(lambda: node.beliefs_ignored == 1, "the forged belief, ignored")
    assert node.hysteresis.posture == "bored" and node.changes == 0
    level, message, values = node.diagnostic_status()
    assert level == ERROR and "1 beliefs ignored, the posture held" in message, message
    probe.destroy_publisher(forger)
    executor.run_until(lambda: node.count_publishers("belief") == 1, "the forger gone")
    rightful.publish(Float64(data=0.95))
    executor.run_until(lambda: node.changes == 1, "the rightful belief, acted on")
    assert node.hysteresis.posture == "attentive"
    assert values["beliefs_ignored"] == node.diagnostic_status()[2]["beliefs_ignored"] == 1
    # a forger gone from the graph before its message is handled: numbered 1 by DDS,
    # below belief_node's numbers, it is still another writer's
    for belief in (0.97, 0.98):
        rightful.publish(Float64(data=belief))
    executor.run_until(lambda: node.belief == 0.98, "belief_node's next beliefs")
    late = probe.talk("belief", Float64)
    executor.connected(late)
    node.count_publishers = lambda topic: 1  # type: ignore[method-assign]  # it left
    late.publish(Float64(data=0.0))
    executor.run_until(lambda: node.beliefs_ignored == 2, "the late forgery, ignored")
    assert node.hysteresis.posture == "attentive" and node.changes == 1


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


def test_an_atomic_set_is_checked_by_the_values_it_sets_together(graph: Callable) -> None:
    """A pair valid together is taken, though one of it is not valid with the other's old value.

    bored_below 0.95 is above the old attentive_above 0.9; a pair that is not valid names
    the values of the set.
    """
    node, probe, executor = graph(PostureNode)
    client = AsyncParameterClient(probe, "posture_node")
    executor.run_until(lambda: client.services_are_ready(), "the parameter services")

    def atomically(**values: float) -> SetParametersResult:
        future = client.set_parameters_atomically(
            [Parameter(name, value=value) for name, value in values.items()])
        executor.run_until(future.done, "the answer of set_parameters_atomically")
        return future.result().result

    result = atomically(bored_below=0.95, attentive_above=0.97)
    assert result.successful, result.reason
    assert (node.hysteresis.bored_below, node.hysteresis.attentive_above) == (0.95, 0.97)
    result = atomically(attentive_above=0.5, bored_below=0.6)
    assert not result.successful and result.reason.startswith(
        "parameter 'bored_below' = 0.6: must be below 'attentive_above' (= 0.5)")
    assert (node.hysteresis.bored_below, node.hysteresis.attentive_above) == (0.95, 0.97)
    [result] = set_remotely(probe, executor, "posture_node", attentive_above=0.9)
    assert not result.successful and "(= 0.9)" in result.reason, "one at a time: the old pair"


def test_an_atomic_set_of_the_fake_rooms_bounds_is_checked_and_applied_as_a_pair(
    graph: Callable,
) -> None:
    """event_min_s above the old event_max_s, with a new event_max_s above it: one room."""
    node, probe, executor = graph(FakeAudioNode)
    client = AsyncParameterClient(probe, "fake_audio_node")
    executor.run_until(lambda: client.services_are_ready(), "the parameter services")
    low, high = node.room.config.event_max_s + 1.0, node.room.config.event_max_s + 2.0
    future = client.set_parameters_atomically(
        [Parameter("event_min_s", value=low), Parameter("event_max_s", value=high)])
    executor.run_until(future.done, "the answer of set_parameters_atomically")
    assert future.result().result.successful, future.result().result.reason
    assert (node.room.config.event_min_s, node.room.config.event_max_s) == (low, high)


def test_a_live_set_is_checked_as_at_start_up(graph: Callable) -> None:
    node, probe, executor = graph(PostureNode)
    [result] = set_remotely(probe, executor, "posture_node", bored_below=0.95)
    assert not result.successful
    assert "must be below 'attentive_above'" in result.reason
    assert node.hysteresis.bored_below == BORED_BELOW
    [result] = set_remotely(probe, executor, "posture_node", bored_positions=[0.0])
    assert not result.successful and "one position per joint" in result.reason


@pytest.mark.parametrize("node_class", [PostureNode, MicNode])
def test_use_sim_time_true_is_refused_live_and_the_timers_run_on(
    graph: Callable, node_class: type
) -> None:
    """Nothing publishes /clock: a node on simulated time would stop its timers unseen."""
    node, probe, executor = graph(node_class)
    [result] = set_remotely(probe, executor, node_class.NODE_NAME, use_sim_time=True)
    assert not result.successful and result.reason == SIM_TIME_REASON
    assert node.get_parameter("use_sim_time").value is False
    assert not node.get_clock().ros_time_is_active
    statuses = probe.listen("/diagnostics", DiagnosticArray)
    executor.run_until(lambda: len(statuses) >= 2, "diagnostics on the node's timer")
    [result] = set_remotely(probe, executor, node_class.NODE_NAME, use_sim_time=False)
    assert result.successful, result.reason
    [result] = set_remotely(probe, executor, node_class.NODE_NAME, use_sim_tme=True)  # a typo
    assert not result.successful and "'use_sim_tme' is not a parameter" in result.reason


def test_parameters_that_cannot_change_are_read_only_with_a_reason(graph: Callable) -> None:
    node, probe, executor = graph(PostureNode)
    [result] = set_remotely(probe, executor, "posture_node", initial_posture="attentive")
    assert not result.successful and "read-only" in result.reason
    assert node.describe_parameter("initial_posture").read_only
    assert not node.describe_parameter("attentive_above").read_only


def test_an_out_of_range_set_gets_the_start_up_message(graph: Callable) -> None:
    """The node's own check runs before rclpy's range check: the reason is the node's."""
    with pytest.raises(ConfigError) as start_up:
        MicNode(namespace="start_up", parameter_overrides=[
            Parameter("bit_source", value="energy"), Parameter("threshold_db", value=5.0)])
    node, probe, executor = graph(
        MicNode, bit_source="energy", threshold_mode="fixed", threshold_db=-40.0
    )
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=5.0)
    assert not result.successful and result.reason == str(start_up.value)
    assert result.reason == (
        "parameter 'threshold_db' = 5.0 is not allowed: a number in [-150, 0] dB"
    )
    assert node.get_parameter("threshold_db").value == -40.0
    assert node.bits.threshold_db == -40.0
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-30)  # an integer
    assert result.successful, result.reason
    assert node.get_parameter("threshold_db").value == -30.0
    assert node.bits.threshold_db == -30.0
    [result] = set_remotely(probe, executor, "mic_node", threshold_db="loud")
    assert result.reason == (
        "parameter 'threshold_db' = 'loud' is not allowed: a number in [-150, 0] dB"
    )


def test_mic_threshold_is_live_in_fixed_mode_only(graph: Callable) -> None:
    node, probe, executor = graph(
        MicNode, bit_source="energy", threshold_mode="fixed", threshold_db=-40.0
    )
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-5.0)
    assert result.successful, result.reason
    assert node.bits.threshold_db == -5.0
    for name in ("source", "device", "threshold_mode", "threshold_file", "refresh_s"):
        assert node.describe_parameter(name).read_only, name
    [result] = set_remotely(probe, executor, "mic_node", threshold_mode="calibrate")
    assert not result.successful and "read-only" in result.reason


def test_a_name_no_node_declares_is_refused_naming_it(graph: Callable) -> None:
    """The node names a parameter it does not declare; rclpy's own answer names none.

    The set is refused whole and changes nothing, in one request with a declared name too.
    """
    node, probe, executor = graph(PostureNode)
    [result] = set_remotely(probe, executor, "posture_node", attentive_abve=0.6)
    assert not result.successful
    assert result.reason == ("parameter 'attentive_abve' is not a parameter of /posture_node"
                             " (`ros2 param list /posture_node` lists them)")  # fmt: skip
    assert not node.has_parameter("attentive_abve")
    client = AsyncParameterClient(probe, "posture_node")
    future = client.set_parameters_atomically(
        [Parameter("attentive_above", value=0.6), Parameter("vad_frame_ms", value=20)]
    )
    executor.run_until(future.done, "the answer of posture_node/set_parameters_atomically")
    result = future.result().result
    assert not result.successful and "'vad_frame_ms' is not a parameter" in result.reason
    future = client.set_parameters_atomically(
        [Parameter("bored_blow", value=0.1), Parameter("attentive_abve", value=0.6)]
    )
    executor.run_until(future.done, "the answer of posture_node/set_parameters_atomically")
    reason = future.result().result.reason
    assert "'bored_blow' is not" in reason and "; parameter 'attentive_abve' is not" in reason
    future = client.set_parameters_atomically(
        [Parameter("initial_posture", value="bored"), Parameter("attentive_abve", value=0.6),
         Parameter("attentive_above", value=0.6)]
    )  # a read-only name too: both named, nothing set
    executor.run_until(future.done, "the answer of posture_node/set_parameters_atomically")
    reason = future.result().result.reason
    assert reason.startswith("parameter 'attentive_abve' is not a parameter of /posture_node")
    assert reason.endswith("; parameter 'initial_posture' is read-only while the node runs;"
                           " restart the node to change it")  # fmt: skip
    assert node.get_parameter("attentive_above").value == 0.9
    assert node.hysteresis.attentive_above == 0.9


def test_mic_threshold_is_refused_while_calibrating(graph: Callable) -> None:
    node, probe, executor = graph(MicNode, bit_source="energy", threshold_mode="calibrate")
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-5.0)
    assert not result.successful and "threshold_mode fixed" in result.reason
    assert node.bits.calibrating


def _windows(levels_db: list[float], seed: int = 3) -> np.ndarray:
    """Noise windows of 0.5 s at 16 kHz, one per RMS level (dB full scale)."""
    rng = np.random.default_rng(seed)
    return np.concatenate([rng.standard_normal(8000) * 10 ** (level / 20) for level in levels_db])


def _audio(samples: np.ndarray) -> Float32MultiArray:
    message = Float32MultiArray()
    message.data = array.array("f", samples.astype(np.float32).tobytes())
    return message


def _threshold_file(path: Path, threshold_db: float) -> Path:
    fit = ThresholdFit(threshold_db, threshold_db - 20, threshold_db + 20, 5, 5)
    save_threshold(path, fit, window_s=0.5, rate=16000, source="test")
    return path


def test_a_threshold_file_outside_the_parameters_range_is_refused_like_the_parameter(
    graph: Callable, tmp_path: Path
) -> None:
    # what calibrate wrote before on unscaled float audio: every bit would be 0
    loud = _threshold_file(tmp_path / "loud.yaml", 86.28)
    with pytest.raises(ValueError, match="threshold_db 86.28 dB is not allowed: -150 .. 0 dB"):
        MicNode(namespace="start_up",
                parameter_overrides=[Parameter("bit_source", value="energy"),
                                     Parameter("threshold_mode", value="file"),
                                     Parameter("threshold_file", value=str(loud))])
    # the file's threshold is read by the one load_threshold, which ~/recalibrate calls too
    node, _, _ = graph(MicNode, bit_source="energy", threshold_mode="file",
                       threshold_file=str(_threshold_file(tmp_path / "ok.yaml", -30)))
    assert node.describe_parameter("threshold_db").floating_point_range[0].to_value == 0.0


def test_a_threshold_file_that_nothing_reads_is_named_at_start_up(
    graph: Callable, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """Given while the bit source or its threshold_mode reads no file: a WARN, not silence."""
    path = str(_threshold_file(tmp_path / "t.yaml", -30))
    unread = f"parameter 'threshold_file' = '{path}' is not read:"
    for settings, reader in (
        ({"bit_source": "background"}, "bit_source background reads no threshold file"),
        ({"bit_source": "energy", "threshold_mode": "calibrate"},
         "bit_source energy with threshold_mode calibrate reads no threshold file"),
        ({"bit_source": "vad"}, "bit_source vad reads no threshold file"),
    ):
        graph(MicNode, threshold_file=path, **settings)
        err = capfd.readouterr().err
        assert f"{unread} {reader}; threshold_mode file of bit_source energy or speech_band" \
            " reads it" in err, err
    graph(MicNode, bit_source="energy", threshold_mode="file", threshold_file=path)
    graph(MicNode, bit_source="background", threshold_file="")  # robot.yaml's: nothing given
    assert "is not read" not in capfd.readouterr().err


def _live_mic(graph: Callable, **parameters: Any) -> tuple[Any, Probe, SteppedExecutor, Callable]:
    """A mic_node on 'audio' at a fixed -40 dB (1 s calibration if asked), and ``play``.

    ``play(levels_db, bits_expected)`` sends one 0.5 s noise window per level and returns
    the bits that came back.
    """
    defaults = {"source": "topic", "bit_source": "energy", "threshold_mode": "fixed",
                "threshold_db": -40.0, "calibration_s": 1.0, "wait_for_listeners": 1,
                "start_delay_s": 0.0}  # fmt: skip
    node, probe, executor = graph(MicNode, **{**defaults, **parameters})
    bits = probe.listen("sound", Bool)
    probe.listen("sound_step", Int64MultiArray)  # the listener mic_node waits for
    energies = probe.listen("sound_energy", Float32)
    audio = probe.talk("audio", Float32MultiArray)
    executor.connected(audio)
    executor.run_until(lambda: node.started, "the mic's start gate")

    def play(levels: list[float], bits_expected: int) -> list[bool]:
        before, heard = len(bits), len(energies)
        audio.publish(_audio(_windows(levels)))
        executor.run_until(
            lambda: len(energies) == heard + len(levels) and len(bits) == before + bits_expected,
            f"{len(levels)} windows",
        )
        return [m.data for m in bits[before:]]

    return node, probe, executor, play


def test_a_computed_threshold_outside_the_range_is_a_warn_and_gives_no_bits(
    graph: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    """A noise floor of audio not scaled to [-1, 1]: no made-up bits, a WARN that says why."""
    node, _, _, play = _live_mic(graph, threshold_mode="noise_floor", noise_margin_db=10.0,
                                 noise_window_s=2.0)  # fmt: skip
    assert play([-5.0, -5.0], 0) == []  # the warm-up (calibration_s 1 s)
    assert play([-5.0, 5.0, -5.0], 0) == []  # threshold about +5 dB: above full scale
    level, message, values = node.diagnostic_status()
    assert level == WARN and "noise-floor threshold: threshold_db" in message, message
    assert "is not allowed: -150 .. 0 dB" in message and values["calibration_state"] == \
        "out_of_range"
    assert capfd.readouterr().err.count("its windows give no bit until it is back in range") == 1
    # scaled again: from the window after the first quiet one, bits on the new floor
    assert play([-40.0] * 4 + [-10.0], 4) == [False, False, False, True]


def test_a_dead_input_turns_the_mic_status_to_warn_and_sound_back_says_so(
    graph: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    """10 s of digital silence: a WARN line and status, once; sound back: an INFO line."""
    node, probe, executor, play = _live_mic(graph)
    assert play([-30.0, -60.0], 2) == [True, False]
    [audio] = [p for p in probe.publishers if p.topic_name == "/audio"]
    before = len(node.diagnostic_status()[2])
    audio.publish(_audio(np.zeros(8000 * 20)))
    executor.run_until(lambda: node.windows == 22, "10 s of digital silence")
    level, message, values = node.diagnostic_status()
    assert level == WARN and message.startswith("the input has been digital silence for 10 s")
    assert values["digital_silence_s"] == 10.0 and len(values) == before
    audio.publish(_audio(_windows([-60.0])))  # any sound: the input lives
    executor.run_until(lambda: node.windows == 23, "a window of sound")
    level, message, values = node.diagnostic_status()
    assert level != WARN and values["digital_silence_s"] == 0.0, message
    err = capfd.readouterr().err
    assert err.count("the input has been digital silence") == 1
    assert "sound again after 10 s of digital silence" in err


def recalibrate(probe: Probe, executor: SteppedExecutor) -> Trigger.Response:
    """Call mic_node's ~/recalibrate; its answer."""
    client = probe.create_client(Trigger, "/mic_node/recalibrate")
    executor.run_until(client.service_is_ready, "mic_node's recalibrate service")
    future = client.call_async(Trigger.Request())
    executor.run_until(future.done, "the answer of mic_node/recalibrate")
    return future.result()


def test_mic_recalibrate_reads_the_file_again_or_calibrates_anew(
    graph: Callable, tmp_path: Path
) -> None:
    """~/recalibrate replaces the live threshold_mode set: the file again, a new calibration."""
    threshold = _threshold_file(tmp_path / "threshold.yaml", -10.0)
    node, probe, executor, play = _live_mic(graph, threshold_mode="file",
                                            threshold_file=str(threshold))  # fmt: skip
    assert play([-20.0, -5.0], 2) == [False, True]  # the file's -10 dB
    _threshold_file(threshold, -30.0)  # a new calibration written by the CLI
    answer = recalibrate(probe, executor)
    assert answer.success and "-30.00 dB" in answer.message, answer.message
    assert play([-20.0, -40.0], 2) == [True, False]  # the file's new -30 dB, at once
    threshold.write_text("just text")
    answer = recalibrate(probe, executor)
    assert not answer.success and "threshold file" in answer.message
    assert str(threshold) in answer.message
    assert play([-20.0], 1) == [True]  # still the good threshold
    for name, value in (("threshold_mode", "calibrate"), ("refresh_s", 2.0)):
        [result] = set_remotely(probe, executor, "mic_node", **{name: value})
        assert not result.successful and "read-only" in result.reason, name


def test_mic_recalibrate_starts_a_new_calibration_on_a_stream(graph: Callable) -> None:
    node, probe, executor, play = _live_mic(graph, threshold_mode="calibrate", refresh_s=2.0)
    # calibration_s 1 s = 2 windows without bits, then the k-means threshold (-40 dB here)
    assert play([-60.0, -20.0, -30.0, -50.0], 2) == [True, False]
    assert abs(node.bits.threshold_db - (-40.0)) < 1.0
    answer = recalibrate(probe, executor)
    assert answer.success and "calibrating on the next 2 windows" in answer.message
    assert node.bits.calibrating and node.bits.rule.refresh_windows == 4
    assert play([-70.0, -10.0, -35.0, -45.0], 2) == [True, False]  # about -40 dB again
    # a full refresh buffer of quiet -60 and sound -10 dB moves the threshold from about
    # -40 to about -35 dB: a -37 dB window after it is quiet
    assert play([-60.0, -10.0, -60.0, -10.0, -37.0], 5) == [False, True, False, True, False]
    assert node.bits.rule.refits_accepted >= 1


def test_mic_withholds_the_bits_right_after_a_recalibration(graph: Callable) -> None:
    """The windows of a new calibration give no step: the next ta2 + 1 bits go out withheld.

    The controller and the belief count steps, the model's timer windows: right after a
    gap a step's timer may lag its window's (core.selfsound.GapWithholding).
    """
    node, probe, executor, play = _live_mic(graph, threshold_mode="calibrate")
    steps = probe.listen("sound_step", Int64MultiArray)
    executor.run_until(lambda: node.step_pub.get_subscription_count() >= 2, "a second listener")
    assert play([-60.0, -20.0] + [-60.0, -20.0] * 2, 4) == [False, True] * 2
    assert recalibrate(probe, executor).success
    play([-60.0, -20.0] + [-60.0, -20.0] * 4, 8)  # 2 windows calibrate, then 8 bits
    withheld = [m.data[4] for m in steps]
    assert withheld == [0] * 4 + [1] * 5 + [0] * 3, withheld  # ta2 + 1 = 5 (robot)
    assert node.diagnostic_status()[2]["bits_withheld_after_gap"] == 5


def test_mic_takes_steps_a_controller_never_answered_as_lost_and_goes_on(
    graph: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    """A restarted controller never gets the steps out before it joined: no deadlock.

    Here a controller answers step 1, then falls silent (its publisher stays, as a new
    controller's would be). mic_node may have 2 steps out unanswered; after
    listener_timeout_s without an answer it takes them as lost and publishes on.
    """
    node, probe, executor, play = _live_mic(graph, max_steps_ahead=2, listener_timeout_s=0.5)
    steps = probe.listen("sound_step", Int64MultiArray)
    controller = probe.talk("vocalize_step", Int64MultiArray)
    executor.connected(controller)
    executor.run_until(lambda: node._decisions_sub.get_publisher_count() == 1, "the controller")
    assert play([-20.0], 1) == [True]
    executor.run_until(lambda: steps, "step 1")
    controller.publish(decision_message(StepDecision(node.stream_id, 1, False, 5)))
    executor.run_until(lambda: node.outbox.last_answered == 1, "the answer to step 1")
    assert play([-20.0, -60.0], 2) == [True, False]  # steps 2, 3: out, unanswered (the most)
    executor.run_until(lambda: node.outbox.answers_overdue(node.now_s()), "0.5 s, no answer")
    assert play([-20.0], 1) == [True]  # the next window finds them overdue: it goes out
    assert node.outbox.answers_given_up == 2
    level, message, values = node.diagnostic_status()
    assert level == WARN and "or the controller stalled" in message, message
    assert values["answers_given_up"] == 2
    executor.run_until(lambda: len(steps) == 4, "step 4")
    assert [m.data[1] for m in steps] == [1, 2, 3, 4]
    assert "no decision on steps 2..3 for 0.5 s" in capfd.readouterr().err


def test_mic_recalibrate_in_fixed_mode_keeps_the_live_threshold(graph: Callable) -> None:
    node, probe, executor, play = _live_mic(graph)
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-30.0)
    assert result.successful, result.reason
    answer = recalibrate(probe, executor)
    assert answer.success and "threshold -30.00 dB" in answer.message, answer.message
    assert play([-25.0, -35.0], 2) == [True, False]


# ------------------------------------------------------------------ speaker, fake room


class FakeSpeaker:
    """Stands in for SpeakerOutput: every play() starts a sound at once."""

    opened: list[FakeSpeaker] = []
    fail = False

    def __init__(self, device: Any, log: Any = None, **sound: Any) -> None:
        self.sequence = 0
        self.pending: list[PlayEvent] = []
        self.closed = False

    def start(self) -> FakeSpeaker:
        if FakeSpeaker.fail:
            raise AudioDeviceError("no output device 'x'; output devices: none")
        FakeSpeaker.opened.append(self)
        return self

    def play(self) -> int:
        self.sequence += 1
        self.pending.append(PlayEvent(self.sequence, 1.0, 1.0, 0.2, False))
        return self.sequence

    def events(self, timeout: float = 0.0) -> list[PlayEvent]:
        events, self.pending = self.pending, []
        return events

    def close(self) -> None:
        self.closed = True


def fast_timers(node: Node) -> list[float]:
    """Periods (s) of the node's running timers that fire more than once a second."""
    periods = [timer.timer_period_ns / 1e9 for timer in node.timers if not timer.is_canceled()]
    return [period for period in periods if period < 1.0]


def test_speaker_dry_run_is_live(graph: Callable, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(speaker_node, "SpeakerOutput", FakeSpeaker)
    monkeypatch.setattr(FakeSpeaker, "opened", [])
    node, probe, executor = graph(SpeakerNode)
    started = probe.listen("speaker_started", TimeMsg)
    vocalize = probe.talk("vocalize_step", Int64MultiArray)
    executor.connected(vocalize)
    steps = iter(range(1, 100))

    def vocalize_once() -> None:
        requests = node.requests
        vocalize.publish(decision_message(StepDecision(7, next(steps), True, 5)))
        executor.run_until(lambda: node.requests == requests + 1, "a vocalization")

    vocalize_once()
    assert fast_timers(node) == [], "a dry run has nothing to check for"
    monkeypatch.setattr(FakeSpeaker, "fail", True)
    [result] = set_remotely(probe, executor, "speaker_node", dry_run=False)
    assert not result.successful and result.reason.startswith("parameter 'device' = '':")
    assert "dry_run:=true runs the node without a loudspeaker" in result.reason
    assert node.dry_run and node.speaker is None and fast_timers(node) == []
    monkeypatch.setattr(FakeSpeaker, "fail", False)
    [result] = set_remotely(probe, executor, "speaker_node", dry_run=False)
    assert result.successful, result.reason
    vocalize_once()
    executor.run_until(lambda: len(started) == 1, "the sound's start time")
    assert fast_timers(node) == [EVENTS_POLL_S], "playing: sounds that started are checked"
    [speaker] = FakeSpeaker.opened
    [result] = set_remotely(probe, executor, "speaker_node", dry_run=True)
    assert result.successful, result.reason
    assert speaker.closed and node.speaker is None
    assert fast_timers(node) == []
    vocalize_once()
    executor.run_for_callbacks(20)
    assert len(started) == 1 and node.requests == 3, "dry run again: counted, not played"


def test_mic_bit_source_parameters_are_read_only_and_vad_has_no_live_threshold(
    graph: Callable,
) -> None:
    node, probe, executor = graph(MicNode, bit_source="vad", threshold_mode="fixed")
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-5.0)
    assert not result.successful
    assert result.reason == (
        "parameter 'threshold_db' is a setting of bit_source energy or speech_band, and"
        " /mic_node runs bit_source vad: not a parameter of it (start the node with"
        " bit_source energy and threshold_db in its parameter file, or after the file"
        " -p mic_node:bit_source:=energy -p mic_node:threshold_db:=...)"
    )
    assert node.bits.threshold_db is None and node.bits.name == "vad"
    for name in ("threshold_db", "threshold_mode", "noise_margin_db"):
        assert not node.has_parameter(name), f"{name}: not a setting of vad"
    for name in ("bit_source", "vad_aggressiveness", "vad_frame_ms", "vad_min_voiced_s"):
        assert node.describe_parameter(name).read_only, name
    [result] = set_remotely(probe, executor, "mic_node", bit_source="energy")
    assert not result.successful and "read-only" in result.reason
    answer = recalibrate(probe, executor)
    assert not answer.success and answer.message == "bit source 'vad' has nothing to calibrate"


def test_mic_speech_band_threshold_is_live_in_fixed_mode(graph: Callable) -> None:
    node, probe, executor = graph(MicNode, bit_source="speech_band", threshold_mode="fixed")
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-30.0)
    assert result.successful, result.reason
    assert node.bits.threshold_db == -30.0


def test_mic_noise_floor_recalibrate_starts_a_new_floor(graph: Callable) -> None:
    node, probe, executor, play = _live_mic(graph, threshold_mode="noise_floor",
                                            noise_margin_db=10.0)  # fmt: skip
    # calibration_s 1 s = 2 windows start the floor (-60 dB), then 10 dB above it
    assert play([-60.0, -60.0, -45.0, -55.0], 2) == [True, False]
    [result] = set_remotely(probe, executor, "mic_node", threshold_db=-30.0)
    assert not result.successful and "threshold_mode fixed" in result.reason
    answer = recalibrate(probe, executor)
    assert answer.success and "noise floor on the next 2 windows" in answer.message
    assert node.bits.name == "energy" and node.bits.calibrating
    assert play([-40.0, -40.0, -25.0, -35.0], 2) == [True, False]  # the floor at -40 dB


def test_mic_speech_band_keeps_its_filter_when_recalibrated(graph: Callable) -> None:
    node, probe, executor = graph(MicNode, bit_source="speech_band", threshold_mode="calibrate")
    band = node.bits.band
    answer = recalibrate(probe, executor)
    assert answer.success, answer.message
    assert node.bits.name == "speech_band" and node.bits.band is band


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


def test_an_empty_list_is_named_as_given(graph: Callable) -> None:
    """``-p joint_names:=[]`` was refused as ``= None``: rcl reads [] as a value of no type."""
    for arguments, allowed in ((["-p", "joint_names:=[]"], "a non-empty list of strings"),
                               (["-p", "move_duration_s:=[]"], "a number in [0, 60] s")):
        with pytest.raises(ConfigError) as refused:
            PostureNode(namespace="empty", cli_args=["--ros-args", *arguments])
        name = arguments[1].split(":=")[0]
        assert str(refused.value) == f"parameter '{name}' = [] is not allowed: {allowed}"


def test_fake_room_partner_and_replies_are_live(graph: Callable) -> None:
    """The partner leaves and comes back, replies stop: seen on partner_present and audio."""
    node, probe, executor = graph(
        FakeAudioNode, room="responsive", event_rate_hz=0.0, reply_probability=1.0,
        seed=5, start_delay_s=0.0,
    )  # fmt: skip
    truth = probe.listen("partner_present", Bool)
    audio = probe.listen("audio", Float32MultiArray)
    decisions = probe.talk("vocalize_step", Int64MultiArray)
    executor.connected(decisions)
    step = [0]

    def windows(vocalize: list[bool]) -> list[bool]:
        """One decision per window (after the first); the ground truth of the new windows."""
        executor.run_until(lambda: len(truth) == step[0] + 1, "a window")
        before = len(truth)
        for u in vocalize:
            step[0] += 1
            message = Int64MultiArray(data=[77, step[0], int(u), 5])
            assert parse_decision(message) is not None
            decisions.publish(message)
            executor.run_until(
                lambda: len(truth) == len(audio) == step[0] + 1, f"window {step[0] + 1}"
            )
        return [m.data for m in truth[before:]]

    assert windows([True, False, False, False, False, False]) == [True] * 6
    assert node.room.replies == 1
    [result] = set_remotely(probe, executor, "fake_audio_node", partner_leave_s=0.0)
    assert not result.successful
    assert result.reason == (
        "room parameter partner_leave_s = 0.0: must be > partner_arrive_s (= 0.0) or negative"
    )
    leave_s = node.room.now_s + 1.0  # two windows from now
    [result] = set_remotely(probe, executor, "fake_audio_node", partner_leave_s=leave_s)
    assert result.successful, result.reason
    assert windows([False, False, True, False, False, False]) == [True, True] + [False] * 4
    assert node.room.replies == 1, "nobody there to reply"
    results = set_remotely(probe, executor, "fake_audio_node", partner_leave_s=-1.0,
                           reply_probability=0.0)  # fmt: skip
    assert [r.successful for r in results] == [True, True]
    assert windows([True, False, False, False, False, False]) == [True] * 6
    assert node.room.replies == 1 and node.room.vocalizations == 3, "present, but silent"
    [result] = set_remotely(probe, executor, "fake_audio_node", noise_floor_db=-30.0)
    assert result.successful, result.reason
    windows([False])
    last = np.frombuffer(audio[-1].data, np.float32).astype(np.float64)
    assert abs(10 * np.log10(np.mean(last**2)) - (-30.0)) < 0.5, "the new floor at once"
    [result] = set_remotely(probe, executor, "fake_audio_node", rate_hz=8000)
    assert not result.successful and "read-only" in result.reason
    assert not node.has_parameter("window_s"), "the window is the model's dt"


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


def test_mic_calibrate_live_on_a_wav_file_reads_its_start_again(graph: Callable) -> None:
    """A wav source is calibrated again on its first seconds: no window goes without a bit."""
    wav = ROOT / "test" / "data" / "interaction.wav"
    node, probe, executor = graph(
        MicNode, source="wav", wav_file=str(wav), bit_source="energy", threshold_mode="calibrate",
        calibration_s=4.0,
    )  # fmt: skip
    answer = recalibrate(probe, executor)
    assert answer.success, answer.message
    energies = WavReplay(wav, 0.5).calibration_energies(4.0, 0.5)
    assert node.bits.threshold_db == kmeans_split(energies).threshold_db
    assert not node.bits.calibrating
    [result] = set_remotely(probe, executor, "mic_node", min_separation_db=50.0)
    assert not result.successful and "read-only" in result.reason


def test_a_new_bit_source_is_a_mic_node_bit_source_with_its_parameters(graph: Callable) -> None:
    """The toy source (test/toy_bit_source.py), registered: its setting is a parameter."""
    from toy_bit_source import registered_toy

    with registered_toy():
        node, probe, executor, play = _live_mic(graph, bit_source="toy", toy_level_db=-40.0)
        descriptor = node.describe_parameter("toy_level_db")
        assert descriptor.description.startswith("Energy above which a window is sound")
        assert not descriptor.read_only
        assert descriptor.floating_point_range[0].to_value == 0.0
        assert not node.has_parameter("threshold_db")
        assert play([-35.0, -45.0], 2) == [True, False]
        [result] = set_remotely(probe, executor, "mic_node", toy_level_db=-30.0)
        assert result.successful, result.reason
        assert play([-35.0], 1) == [False]
        [result] = set_remotely(probe, executor, "mic_node", toy_level_db=3.0)
        assert result.reason == (
            "parameter 'toy_level_db' = 3.0 is not allowed: a number in [-150, 0] dB"
        )


def test_mic_knows_the_settings_of_the_bit_sources_it_does_not_use(graph: Callable) -> None:
    """robot.yaml gives every bit source's settings: none is reported as undeclared."""
    from infomax_contingency.nodes.parameter_files import undeclared_parameters

    node, _probe, _executor = graph(MicNode, bit_source="vad")
    assert not node.has_parameter("threshold_mode") and "threshold_mode" in node.parameters.known
    assert undeclared_parameters([str(ROOT / "config" / "robot.yaml")], [node]) == []
    assert "treshold_mode" not in node.parameters.known

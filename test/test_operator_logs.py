"""Logs an operator can act on: the threshold in force, and what each node waits for.

In-process nodes on a hand-stepped executor; their log lines are read from the
process's stderr (rcutils writes there), with pytest's ``capfd``.
"""

from __future__ import annotations

import array
import itertools
from collections.abc import Callable, Iterator
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Bool, Float32, Float32MultiArray, Float64, Int64MultiArray
from std_srvs.srv import Trigger

from infomax_contingency.core.steady import SteadyInputs
from infomax_contingency.nodes import mic_bits
from infomax_contingency.nodes.belief_node import BeliefNode
from infomax_contingency.nodes.graph_node import WAITING_NOTICE_S
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.step_topics import NoStep, no_step_message
from infomax_contingency.testing.stepped import (
    Probe,
    SteppedExecutor,
    nodes_on_their_own_executors,
)


@pytest.fixture
def graph() -> Iterator[Callable[..., tuple[Any, Probe, SteppedExecutor]]]:
    """``graph(NodeClass, **parameters)`` -> (node, probe, executor); cleaned up after."""
    with nodes_on_their_own_executors() as start:
        yield start


def _audio(levels_db: list[float]) -> Float32MultiArray:
    """Noise windows of 0.5 s at 16 kHz, one per RMS level (dB full scale)."""
    rng = np.random.default_rng(3)
    samples = np.concatenate([rng.standard_normal(8000) * 10 ** (db / 20) for db in levels_db])
    message = Float32MultiArray()
    message.data = array.array("f", samples.astype(np.float32).tobytes())
    return message


def _set(probe: Probe, executor: SteppedExecutor, node: str, **values: Any) -> None:
    """Set parameters of ``node`` through its parameter service (as ``ros2 param set``)."""
    client = AsyncParameterClient(probe, node)
    executor.run_until(lambda: client.services_are_ready(), f"the parameter services of {node}")
    future = client.set_parameters([Parameter(k, value=v) for k, v in values.items()])
    executor.run_until(future.done, f"the answer of {node}/set_parameters")
    assert all(result.successful for result in future.result().results), future.result()


def _threshold_lines(text: str) -> list[str]:
    """mic_node's lines that name the threshold in force (also a calibration's end)."""
    said = [line.split("[mic_node]: ", 1)[1] for line in text.splitlines()
            if "[mic_node]: " in line]  # fmt: skip
    return [line for line in said if line.startswith(("threshold in force", "calibrated:",
                                                      "noise floor"))]  # fmt: skip


OK, WARN = DiagnosticStatus.OK, DiagnosticStatus.WARN


def _mic(graph: Callable, **parameters: Any) -> tuple[Any, Probe, SteppedExecutor, Callable]:
    """A mic_node on 'audio', started; ``play(levels_db)`` sends one window per level."""
    node, probe, executor = graph(
        MicNode, source="topic", bit_source="energy", calibration_s=1.0, wait_for_listeners=1,
        start_delay_s=0.0, **parameters,
    )  # fmt: skip
    probe.listen("sound_step", Int64MultiArray)  # the listener mic_node waits for
    energies = probe.listen("sound_energy", Float32)
    probe.listen("sound", Bool)
    audio = probe.talk("audio", Float32MultiArray)
    executor.connected(audio)
    executor.run_until(lambda: node.started, "the mic's start gate")

    def play(levels: list[float]) -> None:
        heard = len(energies)
        audio.publish(_audio(levels))
        executor.run_until(lambda: len(energies) == heard + len(levels), "the windows")

    return node, probe, executor, play


def test_mic_node_logs_the_threshold_in_force_at_start_up_and_when_set_live(
    graph: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    node, probe, executor, play = _mic(graph, threshold_mode="fixed", threshold_db=-40.0)
    assert _threshold_lines(capfd.readouterr().err) == [
        "threshold in force: -40.00 dB (threshold_db, threshold_mode fixed; bit_source energy)"
    ]
    _set(probe, executor, "mic_node", threshold_db=-30.0)  # live: logged at once
    play([-35.0, -45.0])  # the same threshold: nothing more
    assert _threshold_lines(capfd.readouterr().err) == [
        "threshold in force: -30.00 dB (threshold_db, threshold_mode fixed; bit_source energy)"
    ]


def test_mic_node_logs_a_threshold_that_follows_the_noise_floor_when_it_moved(
    graph: Callable, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(mic_bits, "ROOM_LOG_PERIOD_S", 0.0)  # here: the 1 dB rule alone
    node, probe, executor, play = _mic(
        graph, threshold_mode="noise_floor", noise_window_s=1.0, noise_percentile=0.0
    )
    # 2 windows start the floor at -60 dB; it then follows the last 2 windows: -40 dB
    # moves it 20 dB up, -40.5 dB by less than 1 dB (not logged again)
    play([-60.0, -60.0, -60.0, -40.0, -40.0, -40.5])
    assert _threshold_lines(capfd.readouterr().err) == [
        "noise floor -60.11 dB after 2 windows: threshold -50.11 dB (margin 10 dB)",
        "threshold in force: -30.04 dB (noise floor -40.0 dB + margin 10 dB; bit_source"
        " energy; it follows the room: said again at most every 0 s, every value in the"
        " diagnostics' threshold_db)",
    ]


class _SwingingThreshold:
    """A bit source whose threshold follows the room and swings every window (background's)."""

    calibrating = False

    def __init__(self) -> None:
        self.threshold_db = -70.0

    def threshold_origin(self) -> str:
        return "room: the 2nd loudest of 8 background windows' speech-band levels"


def test_a_threshold_that_follows_the_room_is_logged_at_most_once_a_minute() -> None:
    """In lockstep, background's threshold (-64 .. -33 dB) had been 94 of 131 lines in 20 s.

    Now a line at most every ROOM_LOG_PERIOD_S of audio and of the clock alike; every
    value stays in the diagnostics (threshold_db), the changes not said are counted.
    """
    lines: list[str] = []
    now = [0.0]
    log = mic_bits.ThresholdLog(SimpleNamespace(info=lines.append), "background", 0.5,
                                lambda: now[0])  # fmt: skip
    bits = _SwingingThreshold()
    log(bits)  # at start-up: said
    swings = itertools.cycle([-64.0, -50.0, -33.0, -45.0])
    for window in range(1, 4001):  # 2000 s of audio in 20 s of a lockstep replay
        now[0] = window * 0.005
        bits.threshold_db = next(swings)
        log.after_window(bits, was_calibrating=False)
    assert len(lines) == 1 and log.unsaid == 4000
    for _ in range(240):  # then in real time: 120 s of audio and of the clock
        now[0] += 0.5
        bits.threshold_db = next(swings)
        log.after_window(bits, was_calibrating=False)
    assert len(lines) == 3, lines
    assert lines[-1].startswith("threshold in force: ") and lines[-1].endswith(
        "; bit_source background; it follows the room: said again at most every 60 s, every"
        " value in the diagnostics' threshold_db)")


def test_mic_node_logs_the_end_of_its_calibration_and_of_a_recalibration(
    graph: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    """The window that completes a calibration yields no bit: its end is logged there."""
    node, probe, executor, play = _mic(graph, threshold_mode="calibrate")
    assert _threshold_lines(capfd.readouterr().err) == []  # calibrating: no threshold yet
    play([-60.0, -20.0])  # calibration_s 1.0: two windows, quiet and loud
    calibrated = "calibrated: threshold -40.04 dB (quiet -60.0 dB, sound -20.1 dB)"
    assert _threshold_lines(capfd.readouterr().err) == [calibrated]
    play([-30.0])  # a bit against that threshold: nothing more
    assert _threshold_lines(capfd.readouterr().err) == []
    client = probe.create_client(Trigger, "/mic_node/recalibrate")
    executor.run_until(client.service_is_ready, "mic_node's ~/recalibrate")
    answer = client.call_async(Trigger.Request())
    executor.run_until(answer.done, "the answer of ~/recalibrate")
    play([-60.0, -20.0])  # the same audio again: the same threshold, logged again
    assert _threshold_lines(capfd.readouterr().err) == [calibrated]


def test_belief_and_posture_nodes_say_what_they_wait_for_and_when_it_came(
    graph: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    posture, probe, executor = graph(PostureNode)
    belief_node, _, _ = graph(BeliefNode)
    err = capfd.readouterr().err
    assert "[posture_node]: waiting for '/belief'" in err
    assert "[belief_node]: waiting for '/vocalize_step'" in err
    assert "[belief_node]: waiting for '/sound_step'" in err
    assert "'/belief' (" in posture.check_waiting(WAITING_NOTICE_S + 1.0)
    no_step = probe.talk("no_step", Int64MultiArray)
    executor.connected(no_step)
    no_step.publish(no_step_message(NoStep(7, 3)))  # mic_node calibrating: the graph is alive
    executor.run_until(lambda: posture.arrivals.get("no_step"), "no_step at posture_node")
    assert posture.check_waiting(WAITING_NOTICE_S + 2.0) == ""  # not said to be missing
    capfd.readouterr()
    belief = probe.talk("belief", Float64)
    executor.connected(belief)
    belief.publish(Float64(data=0.95))
    executor.run_until(lambda: posture.arrivals.get("belief"), "the belief at posture_node")
    lines = [line for line in capfd.readouterr().err.splitlines() if "received after" in line]
    assert len(lines) == 1 and "[posture_node]: '/belief' received after" in lines[0], lines
    assert lines[0].endswith(" s of waiting")


@pytest.mark.parametrize("node_class", [PostureNode, MicNode])
def test_a_steady_input_that_stops_is_said_once_and_again_when_it_is_back(
    graph: Callable, capfd: pytest.CaptureFixture[str], node_class: type
) -> None:
    """posture_node's ``belief`` and mic_node's ``audio`` stop: one WARN, one WARN diagnostic.

    Each names the topic and the silence; an INFO line says when it is back (the node's
    clock is the test's: ``now_s``). mic_node's ``no_step`` (windows without a step) keeps
    ``belief`` alive.
    """
    if node_class is MicNode:
        node, probe, executor, play = _mic(graph, threshold_mode="fixed")
        topic, message, talk = "audio", _audio([-50.0]), probe.pubs["audio"]
    else:
        node, probe, executor = graph(PostureNode)
        topic, message, talk = "belief", Float64(data=0.95), probe.talk("belief", Float64)
        executor.connected(talk)
    clock = [1000.0]
    node.now_s = lambda: clock[0]
    statuses = probe.listen("/diagnostics", DiagnosticArray)

    def send(publisher: Any, message: Any, name: str, at_s: float) -> None:
        clock[0] = at_s
        count = node.arrivals.get(name, 0)
        publisher.publish(message)
        executor.run_until(lambda: node.arrivals.get(name, 0) > count, f"'{name}' at the node")

    def status_at(at_s: float) -> tuple[bytes, str, dict[str, str]]:
        clock[0] = at_s
        heard = len(statuses)
        node.publish_diagnostics()
        executor.run_until(lambda: len(statuses) > heard, "a diagnostics message")
        [status] = statuses[-1].status
        return status.level, status.message, {v.key: v.value for v in status.values}

    def said(fragment: str) -> list[str]:
        return [line for line in capfd.readouterr().err.splitlines() if fragment in line]

    send(talk, message, topic, 999.5)
    send(talk, message, topic, 1000.0)  # from the second message on: judged, at 0.5 s a window
    last_s = 1000.0
    if node_class is PostureNode:  # windows without a step: the beliefs pause, not stop
        no_step = probe.talk("no_step", Int64MultiArray)
        executor.connected(no_step)
        send(no_step, no_step_message(NoStep(7, 3)), "no_step", 1000.5)
        last_s = 1000.5
    said("")  # what came so far
    level, _, values = status_at(last_s + 4.0)
    assert level == OK and f"{topic}_silent_s" not in values and said("nothing on") == []
    level, text, values = status_at(last_s + 6.0)
    stopped = said("nothing on")
    assert len(stopped) == 1 and "WARN" in stopped[0] and "for 6.0 s, after 2 messages" in (
        stopped[0]) and f"'/{topic}'" in stopped[0], (stopped, text)  # fmt: skip
    assert level == WARN and f"nothing on '/{topic}' for 6 s" in text, text
    assert float(values[f"{topic}_silent_s"]) == 6.0 and values["input_stops"] == "1"
    level, text, values = status_at(last_s + 9.0)  # still silent: no second line
    assert level == WARN and float(values[f"{topic}_silent_s"]) == 9.0 and said("nothing on") == []
    send(talk, message, topic, last_s + 11.0)
    back = said("back after")
    assert len(back) == 1 and f"'/{topic}' back after 11.0 s without a message" in back[0], back
    level, _, values = status_at(last_s + 12.0)
    assert level == OK and f"{topic}_silent_s" not in values and values["input_stops"] == "1"


def test_a_steady_inputs_bound_follows_its_usual_pace_and_no_message_is_no_stop() -> None:
    """A steady input's bound: at least the floor, four usual intervals when longer.

    Never judged before its second message; a companion's message counts as its own once
    its own first came, and before says only that its source is alive ("after 0 messages"
    and a slow room's first windows were said to be stops).
    """
    inputs = SteadyInputs(floor_s=5.0)
    inputs.watch("sound_step", companions=("no_step",))
    assert inputs.newly_silent(1e6) == [], "nothing came yet: not judged here"
    assert not inputs.heard("sound_step")
    inputs.arrived("no_step", 1.0)  # mic_node calibrating: alive, no step yet
    assert inputs.heard("sound_step") and inputs.newly_silent(1e6) == []
    inputs = SteadyInputs(floor_s=5.0)
    inputs.watch("sound_step", companions=("no_step",))
    for at_s in (0.0, 0.5, 1.0):
        inputs.arrived("sound_step", at_s)
    assert inputs.bound_s("sound_step") == 5.0
    inputs.arrived("no_step", 5.0)
    assert inputs.newly_silent(9.9) == [] and inputs.newly_silent(10.5) == [("sound_step", 5.5)]
    assert inputs.newly_silent(12.0) == [] and inputs.silent(12.0) == {"sound_step": 7.0}
    assert inputs.arrived("sound_step", 13.0) == [("sound_step", 8.0)] and inputs.stops == 1
    slow = SteadyInputs(floor_s=5.0)  # a room at speed 0.1: a window each 5 s
    slow.watch("audio")
    for at_s in range(0, 60, 5):
        slow.arrived("audio", float(at_s))
    assert slow.bound_s("audio") == 20.0 and slow.newly_silent(55.0 + 19.0) == []
    assert slow.newly_silent(55.0 + 21.0) == [("audio", 21.0)]
    slower = SteadyInputs(floor_s=5.0)  # speed 0.08: a window each 6.25 s, from the first
    slower.watch("audio")
    slower.arrived("audio", 0.0)
    assert slower.newly_silent(5.5) == [], "one message: its pace is not known yet"
    slower.arrived("audio", 6.25)
    assert slower.newly_silent(6.25 + 6.0) == [] and slower.bound_s("audio") == 25.0

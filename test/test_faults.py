"""Faults between node processes over DDS: restarts, and a smoke test of the others.

The belief node, the controller and the microphone are killed with SIGKILL in turn and
come back. After each restart the belief stream must equal an offline recomputation
from the true bits and decisions (as recorded), step for step: zero counts from the
step a restarted belief node joins at, the timer unknown after the controller's death,
counts kept across the new microphone's stream; the diagnostics name what is not
running. Then one smoke test each of intruding processes (a stray command, a second
mic_node and controller_node) and of big audio messages between processes.

Every fault of real traffic (intruders, a rogue flood, every chunking) is tested on the
in-process graph in test_intruders.py. The test process records the topics on a
hand-stepped executor: every wait is a condition on what was received (with a deadline
as a guard), never a sleep.
"""

from __future__ import annotations

import array
import itertools
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from std_msgs.msg import Float32MultiArray

from exact_beliefs import (
    MEMORY,
    a_stray_command_is_named,
    an_intruder_is_named,
    assert_offline_run,
    assert_same_beliefs,
    last_status,
    offline_beliefs,
    offline_steps,
    status_reported,
    step_pairs,
)
from infomax_contingency.nodes.qos import LOSSLESS_READER_QOS
from infomax_contingency.sim.fake_room import FakeRoom, as_transmitted
from infomax_contingency.sim.room_config import FakeRoomConfig
from infomax_contingency.testing.graph import GraphProcesses, StepRecorder
from infomax_contingency.testing.stepped import Probe, SteppedExecutor

# The graphs that step a room at full speed and rely on timeouts (a silent source is
# replaced after source_timeout_s) run one at a time (on one pytest-xdist worker, with
# `--dist loadgroup`), so that they do not starve each other of CPU. Their rooms run at
# most 50 times real time (ROOM): much of the time they wait on the wall clock.
pytestmark = pytest.mark.slow
NODE_GRAPHS = pytest.mark.xdist_group("node_graphs")

RESTART_TIMEOUT_S = 1.0
"""source_timeout_s here: a silent stream or controller is replaced after this (the
default is 3 s)."""

HOLD = {"fault_hold_s": 1.0, "diagnostics_period_s": 0.25}
"""Diagnostics every 0.25 s, and a fault shows in them for 1 s after it last happened (1 s
and 10 s by default): the test waits for them on the wall clock."""

MIC = {"source": "topic", "bit_source": "energy", "threshold_mode": "fixed", "threshold_db": -40.0,
       "wait_for_listeners": 3, "start_delay_s": 0.2, **HOLD}  # fmt: skip
ROOM = {"room": "responsive", "seed": 3, "wait_for_truth_listeners": 1, "start_delay_s": 0.2,
        "lockstep_timeout_s": 2.0, "lockstep_max_speed": 50.0, **HOLD}  # fmt: skip
"""At most 50 times real time (100 steps/s): the diagnostics, leases and timeouts these
tests wait for come on the wall clock, and a room at full speed spent that time stepping."""
BELIEF = {"memory_steps": MEMORY, "wait_for_listeners": 1, **HOLD}  # the recorder
CONTROLLER: dict[str, Any] = {"wait_for_listeners": 4, **HOLD}  # mic, belief, room, recorder


@dataclass
class FaultGraph:
    """Node processes, and a recorder and probe on the test's hand-stepped executor."""

    processes: GraphProcesses
    recorder: StepRecorder
    probe: Probe
    diagnostics: list[DiagnosticArray]
    steps: SteppedExecutor

    def start(self, nodes: dict[str, dict[str, Any]], clock: str) -> None:
        """Start the nodes, the clock node last, once the others reach the recorder."""
        others = [name for name in nodes if name != clock]
        for name in others:
            self.processes.start(name, nodes[name])
        self.run_until(lambda: self.recorder.sees(others), f"{others} connected")
        self.processes.start(clock, nodes[clock])

    def run_until(self, condition: Any, what: str, deadline_s: float = 90.0) -> None:
        """Step until ``condition``; fail with the nodes' logs if a node died or time ran out."""

        def holds() -> bool:
            dead = self.processes.dead()
            if dead:
                pytest.fail(f"while waiting for {what}: {self.processes.report()}")
            return bool(condition())

        try:
            self.steps.run_until(holds, what, deadline_s)
        except AssertionError as error:
            statuses = {s.name: (s.level, s.message, {v.key: v.value for v in s.values})
                        for a in self.diagnostics[-12:] for s in a.status}  # fmt: skip
            logs = "\n".join(f"--- {name}:\n{self.processes.log(name)[-1500:]}"
                             for name in self.processes.processes)  # fmt: skip
            pytest.fail(f"{error}; received {self.recorder.counts()}; last diagnostics {statuses}"
                        f"\n{logs}")

    def status(self, node: str) -> DiagnosticStatus | None:
        """The last diagnostics of ``node``."""
        return last_status(self.diagnostics, node)

    def wait_status(self, node: str, level: bytes, text: str = "") -> DiagnosticStatus:
        """Step until ``node`` reports ``level`` with ``text`` in its message or values."""
        found: list[DiagnosticStatus] = []
        self.run_until(status_reported(self.diagnostics, node, level, text, found),
                       f"{node} to report level {level!r} with {text!r}")  # fmt: skip
        return found[-1]

    def beliefs_since(self, published_after_ns: int) -> list[float]:
        """Beliefs published after a moment (system-clock ns): one incarnation's."""
        times = self.recorder.times["belief"]
        return [b for b, (_, sent) in zip(self.recorder.belief, times, strict=True)
                if sent > published_after_ns]  # fmt: skip


SHORT_LEASE_PROFILES = """<?xml version="1.0" encoding="UTF-8"?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="short_lease" is_default_profile="true">
    <rtps>
      <builtin>
        <discovery_config>
          <leaseDuration><sec>2</sec><nanosec>0</nanosec></leaseDuration>
          <leaseAnnouncement><sec>0</sec><nanosec>500000000</nanosec></leaseAnnouncement>
        </discovery_config>
      </builtin>
    </rtps>
  </participant>
  <data_writer profile_name="short_lease_writer" is_default_profile="true">
    <times>
      <heartbeatPeriod><sec>0</sec><nanosec>200000000</nanosec></heartbeatPeriod>
    </times>
  </data_writer>
</profiles>
"""
"""The suite's profile (test/fastdds_quick.xml), and participants that count a silent peer
as gone after 2 s (the default: 20 s), for the restart test: a node killed with SIGKILL
says no goodbye, and the room names what is not running only once its peers' discovery
dropped the dead node. Fast DDS reads one profile file, so this one repeats the suite's
heartbeats: without them a node stopped here waited up to 3 s for its readers'
acknowledgments (Fast DDS's default heartbeat period), 5 s of the test in all."""


@pytest.fixture
def graph(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[FaultGraph]:
    """Node processes and the recorder on the test's hand-stepped executor.

    The nodes of a ``kills_nodes`` test run with a 2 s discovery lease. They move data
    through Fast DDS's shared memory like every other test's: under
    ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` Jazzy's rmw_fastrtps chooses the transports
    itself (docs/ENVIRONMENT.md).
    """
    node_env = dict(os.environ)
    if request.node.get_closest_marker("kills_nodes"):
        profiles = tmp_path / "short_lease.xml"
        profiles.write_text(SHORT_LEASE_PROFILES)
        # The nodes only: Fast DDS reads the profile once per process, and this one runs
        # other tests after this one.
        node_env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profiles)
    rclpy.init()
    recorder = StepRecorder(stream_qos=LOSSLESS_READER_QOS, instrument=True)
    probe = Probe()
    diagnostics = probe.listen("/diagnostics", DiagnosticArray, 100)
    steps = SteppedExecutor([recorder, probe])
    processes = GraphProcesses(tmp_path, env=node_env)
    try:
        yield FaultGraph(processes, recorder, probe, diagnostics, steps)
    finally:
        processes.stop_all()
        steps.close()
        rclpy.try_shutdown()


def _room_graph(**extra: Any) -> dict[str, dict[str, Any]]:
    """The lockstep graph; ``extra`` parameters go to controller, belief and room."""
    return {"mic_node": MIC, "controller_node": {**CONTROLLER, **extra},
            "belief_node": {**BELIEF, **extra}, "fake_audio_node": {**ROOM, **extra}}  # fmt: skip


REPAIR_DEADLINE_S = 20.0
"""Seconds the recorder may take to have a lost sample resent (Fast DDS: at the writer's
next heartbeat, every 0.2 s here: SHORT_LEASE_PROFILES) before the test fails."""


def _contiguous(steps: list[int]) -> bool:
    return not steps or sorted(steps) == list(range(min(steps), max(steps) + 1))


def _recorded_whole(recorder: StepRecorder, bits: bool, controllers: bool) -> bool:
    """True when the recorder has no hole in the first stream's steps so far.

    No bit missing between the first and the last received (``bits``), no decision of
    each controller (``controllers``; else of the newest) between its first and last,
    and the newest one's decisions up to the last bit but one.
    Checked before a node is killed: a sample this process lost on the way (its UDP
    buffer overflowed on a loaded machine) is resent only while its writer lives, and
    the belief node may have it. A record with a hole would then make the recomputation
    wrong, not the belief: the likely cause of the one mismatch seen (a recomputation
    that stayed at the prior where the belief node counted, ten steps after its join).
    """
    stream = recorder.sound_step[0][0]
    bit_steps = [s for st, s, *_ in recorder.sound_step if st == stream]
    if bits and not _contiguous(bit_steps):
        return False
    ids = list(dict.fromkeys(c for *_, c in recorder.vocalize_step))
    for controller in ids if controllers else ids[-1:]:
        steps = [s for st, s, _, c in recorder.vocalize_step if st == stream and c == controller]
        # In lockstep the next bit waits for this decision: all but the last bit answered.
        if not _contiguous(steps) or (controller == ids[-1] and steps
                                      and max(steps) < max(bit_steps) - 1):  # fmt: skip
            return False
    return True


def _foreign_messages(graph: FaultGraph) -> int:
    """Messages of foreign streams and controllers the graph's nodes have ignored so far.

    Summed over the belief node, the controller and the room: an intruder's first
    messages may reach some of its listeners and not others (one that matched it late).
    """
    total = 0
    for node, key in (("belief_node", "foreign_messages"), ("controller_node",
                      "foreign_messages"), ("fake_audio_node", "foreign_decisions")):  # fmt: skip
        status = graph.status(node)
        values = {} if status is None else {v.key: v.value for v in status.values}
        total += int(values.get(key, 0))
    return total


UNSEEN = "unseen"
"""A bit or decision this recorder did not receive, which the belief node may have had."""


def _options(value: bool | None | str, ambiguous: bool) -> list:
    """What the belief node may have used where this recorder saw ``value``."""
    if value == UNSEEN:
        return [None, False, True] if ambiguous else [None]
    if not ambiguous:
        return [value]
    return [value, None] if value is not None else [None, False, True]


def _completion_matching(got: list[float], pairs_a: list[tuple], pairs_b: list[tuple],
                         ambiguous: set[int]) -> list[tuple]:  # fmt: skip
    """``pairs_a`` with its ``ambiguous`` steps completed so the beliefs equal ``got``.

    Only the decisions of those steps vary (and the bits of steps this recorder lacks):
    the belief node's stream-A beliefs must be the offline ones of some completion. None
    matching: the recorded pairs as they are (the comparison then fails, naming them).
    """
    ambiguous = {i for i in ambiguous if 0 <= i < len(pairs_a)}
    positions = sorted(ambiguous | {i for i, (y, _) in enumerate(pairs_a) if y == UNSEEN})
    choices = []
    for i in positions:
        y, u = pairs_a[i]
        ys = [False, True] if y == UNSEEN else [y]
        choices.append([(yy, uu) for yy in ys for uu in _options(u, i in ambiguous)])
    for combination in itertools.product(*choices):
        candidate = list(pairs_a)
        for i, pair in zip(positions, combination, strict=True):
            candidate[i] = pair
        expected = offline_beliefs([(candidate, "joined"), (pairs_b, "new stream")])
        if len(expected) == len(got) and np.allclose(expected, got, rtol=0.0, atol=1e-12):
            return candidate
    return [(None if y == UNSEEN else y, None if u == UNSEEN else u) for y, u in pairs_a]


def _settled(graph: FaultGraph, stream: int, since_ns: int) -> DiagnosticStatus:
    """Once the room is stopped: step until the belief node has applied every step.

    That is, until its diagnostics (every 0.25 s: HOLD) report as many steps as
    beliefs were received since ``since_ns``, the last step as the last bit of ``stream``
    received, and no fault lately. Returns that status.
    """
    rec = graph.recorder
    found: list[DiagnosticStatus] = []

    def settled() -> bool:
        status = graph.status("belief_node")
        if status is None or status.level != DiagnosticStatus.OK:
            return False
        values = {v.key: v.value for v in status.values}
        last_bit = max(s for st, s, *_ in rec.sound_step if st == stream)
        found[:] = [status]
        return (values["stream"] == str(stream) and values["last_step"] == str(last_bit)
                and values["steps"] == str(len(graph.beliefs_since(since_ns))))  # fmt: skip

    graph.run_until(settled, "the belief node to apply every step")
    return found[0]


@NODE_GRAPHS
@pytest.mark.kills_nodes
def test_killed_nodes_rejoin_at_the_current_step_and_nothing_is_guessed(
    graph: FaultGraph,
) -> None:
    rec = graph.recorder
    nodes = _room_graph(source_timeout_s=RESTART_TIMEOUT_S)
    graph.start(nodes, clock="fake_audio_node")
    graph.run_until(lambda: len(rec.belief) >= 80, "80 steps")

    # the belief node dies and comes back: zero counts from the step it joins at
    graph.processes.kill("belief_node")
    restarted_ns = rclpy.clock.Clock().now().nanoseconds
    graph.processes.start("belief_node", nodes["belief_node"])
    graph.run_until(lambda: len(graph.beliefs_since(restarted_ns)) >= 60, "60 new beliefs")
    joins = re.findall(r"joined stream \d+ at step (\d+)", graph.processes.log("belief_node"))
    assert len(joins) == 2, graph.processes.log("belief_node")  # its first life, then this
    join_step = int(joins[-1])
    assert join_step > 80

    # the controller dies; a new one starts once the room has timed out waiting for it
    graph.run_until(lambda: _recorded_whole(rec, bits=True, controllers=True),
                    "the recorder to hold every step so far", deadline_s=REPAIR_DEADLINE_S)
    graph.processes.kill("controller_node")
    graph.wait_status("fake_audio_node", DiagnosticStatus.WARN, "controller_node is not running")
    graph.processes.start("controller_node", nodes["controller_node"])
    answered = len(rec.vocalize_step)
    graph.run_until(lambda: len(rec.vocalize_step) > answered + 60, "60 new decisions")

    # the microphone dies; a new one (a new stream) starts once the room has timed out
    graph.run_until(lambda: _recorded_whole(rec, bits=True, controllers=False),
                    "the recorder to hold every step so far", deadline_s=REPAIR_DEADLINE_S)
    graph.processes.kill("mic_node")
    graph.wait_status("fake_audio_node", DiagnosticStatus.WARN, "mic_node is not running")
    graph.processes.start("mic_node", MIC)
    first_stream = rec.sound_step[0][0]
    first_controller = rec.vocalize_step[0][3]

    def new_stream_decisions() -> int:
        return sum(st != first_stream for st, *_ in rec.vocalize_step)

    graph.run_until(lambda: new_stream_decisions() > 60, "60 decisions on the new stream")
    graph.processes.stop("fake_audio_node")
    second_stream = next(st for st, *_ in rec.vocalize_step if st != first_stream)
    belief_status = _settled(graph, second_stream, restarted_ns)
    last_b = max(s for st, s, *_ in rec.sound_step if st == second_stream)

    controllers = {c for *_, c in rec.vocalize_step}
    assert len(controllers) == 2
    # Stream A ends with its last bit: the belief node applies the steps it still awaited
    # a decision for (none can come once the controller answers stream B) without one.
    last_a = max(s for st, s, *_ in rec.sound_step if st == first_stream)
    first_b = min(s for st, s, *_ in rec.vocalize_step if st == second_stream)
    pairs_a = step_pairs(rec, first_stream, controllers, join_step, last_a)
    pairs_b = step_pairs(rec, second_stream, controllers, first_b, last_b)
    got = graph.beliefs_since(restarted_ns)
    # The last bits a killed mic_node published may reach some listeners and not others
    # (it cannot resend them): the belief node, or this recorder, may lack the last step
    # or two of stream A.
    lost_at_kill = len(pairs_a) + len(pairs_b) - len(got)
    assert -2 <= lost_at_kill <= 2, (
        f"A {join_step}..{last_a}, B {first_b}..{last_b}, {len(got)} beliefs;"
        f" {dict((v.key, v.value) for v in graph.status('belief_node').values)}\n"
        + graph.processes.log("belief_node")[-4000:]
    )
    if lost_at_kill >= 0:
        pairs_a = pairs_a[: len(pairs_a) - lost_at_kill]
    else:
        pairs_a = pairs_a + [(UNSEEN, UNSEEN)] * -lost_at_kill
    # The same holds for the last decision a killed controller published. Those steps
    # (the last one the first controller answered here and the one after it, and the
    # last two of stream A) may have been seen by the belief node and not here, or the
    # other way round: each takes any value it can have had.
    answered = [s for st, s, _, c in rec.vocalize_step
                if st == first_stream and c == first_controller]  # fmt: skip
    last_answer = max(answered) - join_step
    ambiguous = {last_answer, last_answer + 1, len(pairs_a) - 2, len(pairs_a) - 1}
    # Exact through all three restarts: zero counts at the belief node's, the timer
    # unknown after the controller's, counts kept across the mic_node's new stream.
    pairs_a = _completion_matching(got, pairs_a, pairs_b, ambiguous)
    expected = offline_beliefs([(pairs_a, "joined"), (pairs_b, "new stream")])
    log = graph.processes.log("belief_node")
    pattern = re.compile(r"joined|never arrived|silent|instead of|ignoring")
    notable = "\n".join(line for line in log.splitlines() if pattern.search(line))
    context = (f"join step {join_step}; A {join_step}..{last_a}, B {first_b}..{last_b};"
               f" messages the recorder lost: {rec.lost}\n{notable[-6000:]}")
    assert_same_beliefs(got, expected, context,
                         pairs_a + pairs_b)  # fmt: skip
    missing = sum(u is None for _, u in pairs_a)
    assert missing >= 1, "the controller's death leaves steps without a decision"
    values = {v.key: v.value for v in belief_status.values}
    assert int(values["missing_decisions"]) >= missing and values["stream_changes"] == "1", values
    controller_values = {v.key: v.value for v in graph.status("controller_node").values}
    assert int(controller_values["missed_steps"]) > 0


@NODE_GRAPHS
def test_intruding_processes_are_named_ignored_and_the_belief_stays_exact(
    graph: FaultGraph,
) -> None:
    """Smoke test between processes: a stray command, a second mic_node and controller.

    test_intruders.py runs these (and a rogue flood) on the in-process graph.
    """
    rec = graph.recorder
    graph.start(_room_graph(), clock="fake_audio_node")
    graph.run_until(lambda: len(rec.belief) >= 50, "50 steps")
    graph.wait_status("belief_node", DiagnosticStatus.OK)

    a_stray_command_is_named(graph)

    # a second mic_node and a second controller_node, each started and stopped
    for node, name, parameters, topic in (
        # The second mic waits for the true mic's listeners (MIC: controller, belief,
        # recorder) as the first did: with none to wait for, its first bits went out
        # before they matched it, it then held its windows for answers that never came
        # (max_steps_ahead), and no listener ever had a message of it to ignore (once).
        ("mic_node", "mic_node_2", MIC, "sound_step"),
        ("controller_node", "controller_node_2", CONTROLLER, "vocalize_step"),
    ):
        foreign_before = _foreign_messages(graph)
        graph.processes.start(node, parameters, name=name)
        an_intruder_is_named(graph, topic, name)
        steps_before = len(rec.belief)
        # Until the graph has had (and ignored) the intruder's messages too.
        graph.run_until(lambda n=steps_before, f=foreign_before: len(rec.belief) > n + 30
                        and _foreign_messages(graph) > f,
                        f"30 steps and messages of {name} meanwhile")  # fmt: skip
        graph.processes.stop(name)
    graph.wait_status("belief_node", DiagnosticStatus.OK)

    # the run ends: every step of the true stream is in the belief, exactly
    graph.processes.stop("fake_audio_node")
    stream, controller = rec.sound_step[0][0], rec.vocalize_step[0][3]
    status = _settled(graph, stream, 0)
    last = max(s for st, s, *_ in rec.sound_step if st == stream)
    # The belief node has them all; the last decisions may still be on their way here.
    graph.run_until(lambda: None not in [u for _, u in step_pairs(rec, stream, {controller},
                                                                   1, last)],
                    "every decision here", deadline_s=REPAIR_DEADLINE_S)  # fmt: skip
    pairs = step_pairs(rec, stream, {controller}, 1, last)
    assert_same_beliefs(rec.belief, offline_beliefs([(pairs, "start")]), pairs=pairs)
    values = {v.key: v.value for v in status.values}
    assert values["missing_bits"] == values["missing_decisions"] == "0", values


def test_audio_in_big_chunks_between_processes_gives_the_offline_beliefs(
    graph: FaultGraph,
) -> None:
    """Smoke test between processes: 30 s of audio in one message, then 10^7 samples.

    The one test of a 10^7-sample message through the nodes: test_intruders.py runs the
    other chunkings (0.01 s to 30 s) on the in-process graph.
    """
    rec = graph.recorder
    nodes = {"mic_node": MIC, "controller_node": {**CONTROLLER, "wait_for_listeners": 3},
             "belief_node": BELIEF}  # fmt: skip
    for name, parameters in nodes.items():
        graph.processes.start(name, parameters)
    audio = graph.probe.talk("audio", Float32MultiArray)
    graph.run_until(lambda: rec.sees(list(nodes)) and audio.get_subscription_count() >= 1,
                    "the graph")  # fmt: skip
    graph.wait_status("mic_node", DiagnosticStatus.OK)
    room = FakeRoom(FakeRoomConfig.preset("noisy", event_rate_hz=1.0), seed=8)
    segments = [np.concatenate([as_transmitted(room.next_window().samples)
                                for _ in range(windows)]) for windows in (60, 1250)]  # fmt: skip
    for samples in segments:
        message = Float32MultiArray()
        message.data = array.array("f", samples.tobytes())
        audio.publish(message)
    samples = np.concatenate(segments)
    steps = offline_steps(samples)
    graph.run_until(lambda: min(len(rec.sound_step), len(rec.vocalize_step), len(rec.belief))
                    >= steps, f"{steps} steps", deadline_s=300)  # fmt: skip
    assert_offline_run(rec, samples)

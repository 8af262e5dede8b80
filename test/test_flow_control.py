"""The flow control and the pace of the step clock, on the graph in the test process.

* A belief_node that gets the CPU only while the rest of the graph waits (as starved as
  a node can be) still applies every step of a burst of audio longer than its queues:
  mic_node publishes no more than ``max_steps_ahead`` steps beyond the last one the belief
  node acknowledged on ``step_applied``, so the graph slows down instead of losing steps.
* One forged message on each stamped topic, with the true stream and controller ids and
  a step 3000 ahead (beyond the pace) or 10 ahead (within it: told apart by the DDS
  numbers of its writer), is named and ignored by every node that reads it, and so is a
  decision with the true controller id on a stream nobody publishes: the graph goes on
  and the belief equals the offline recomputation from the true bits and decisions.

The nodes run on hand-stepped executors (real DDS between them): every wait is a
condition on what was received, with a deadline as a guard, never a sleep.
"""

from __future__ import annotations

import array
import time
from collections.abc import Callable

import numpy as np
import pytest
from std_msgs.msg import Float32MultiArray, Int64MultiArray

from exact_beliefs import (
    MEMORY,
    assert_offline_run,
    assert_same_beliefs,
    offline_beliefs,
    step_pairs,
    true_sources,
)
from infomax_contingency.core.stepclock import MAX_STEP_JUMP
from infomax_contingency.nodes.graph_node import ERROR, WARN
from infomax_contingency.nodes.qos import LOSSLESS_READER_QOS, STREAM_DEPTH
from infomax_contingency.nodes.step_topics import (
    StepBit,
    StepDecision,
    bit_message,
    decision_message,
)
from infomax_contingency.testing.stepped import Probe, SteppedExecutor
from stepped_graph import SteppedGraph, stepped_graph

NO_TIMEOUTS = {"source_timeout_s": 600.0}
"""No node takes another source for a restarted one, and mic_node waits for the belief
node however long it is starved: a stall of the test process (a loaded machine) must not
look like a fault."""

MIC = {"source": "topic", "bit_source": "energy", "threshold_mode": "fixed", "threshold_db": -40.0,
       "wait_for_listeners": 3,  # controller, belief, recorder
       "listener_timeout_s": 600.0}  # fmt: skip
BELIEF = {"memory_steps": MEMORY, "wait_for_listeners": 1, **NO_TIMEOUTS}  # the recorder
CONTROLLER = {"wait_for_listeners": 3, **NO_TIMEOUTS}  # mic, belief, recorder

BURST_WINDOWS = STREAM_DEPTH + 100
"""Windows of the burst: more than the belief node's queues hold (1000 messages each)."""

IDLE_S = 0.02
"""The belief node gets the CPU once the rest of the graph has made no step for this long."""


def _audio(windows: int, seed: int) -> np.ndarray:
    """``windows`` windows of 0.5 s at 16 kHz: quiet noise, a third of them loud."""
    rng = np.random.default_rng(seed)
    levels = np.where(rng.random(windows) < 0.3, 0.1, 0.001)
    return (rng.standard_normal((windows, 8000)) * levels[:, None]).astype(np.float32).ravel()


def _message(samples: np.ndarray) -> Float32MultiArray:
    message = Float32MultiArray()
    message.data = array.array("f", samples.tobytes())
    return message


def _starved(graph: SteppedGraph, belief: SteppedExecutor, condition: Callable[[], bool],
             what: str, deadline_s: float = 180.0) -> None:  # fmt: skip
    """Step the graph until ``condition``; the belief node only while the rest waits."""
    rec = graph.recorder
    deadline = time.monotonic() + deadline_s
    made, made_at = -1, time.monotonic()
    while not condition():
        assert time.monotonic() < deadline, f"{what} did not happen within {deadline_s:g} s"
        graph.executor.executor.spin_once(timeout_sec=IDLE_S)
        now = time.monotonic()
        if len(rec.sound_step) + len(rec.vocalize_step) != made:
            made, made_at = len(rec.sound_step) + len(rec.vocalize_step), now
        elif now - made_at > IDLE_S:
            belief.run_for_callbacks(20)
            made_at = now


def test_a_starved_belief_node_slows_the_graph_and_loses_no_step() -> None:
    nodes = {"mic_node": MIC, "controller_node": CONTROLLER, "belief_node": BELIEF}
    with stepped_graph(nodes, None, recorder_qos=LOSSLESS_READER_QOS) as graph:
        rec, mic, node = graph.recorder, graph.nodes["mic_node"], graph.nodes["belief_node"]
        graph.executor.executor.remove_node(node)  # the belief node on an executor of its own
        graph.executor.nodes.remove(node)
        belief = SteppedExecutor([node])
        try:
            probe = graph.executor.add(Probe())
            audio = probe.talk("audio", Float32MultiArray)

            def served(condition: Callable[[], bool]) -> Callable[[], bool]:
                """``condition``, the belief node served at each check (as the others)."""
                return lambda: belief.run_for_callbacks(5) or condition()

            graph.run_until(served(lambda: audio.get_subscription_count() >= 1 and mic.started),
                            "the mic on 'audio'")  # fmt: skip
            samples = _audio(20 + BURST_WINDOWS, seed=5)
            audio.publish(_message(samples[:20 * 8000]))  # 20 windows, everyone served
            graph.run_until(served(lambda: len(rec.belief) >= 20), "20 steps")
            audio.publish(_message(samples[20 * 8000:]))  # then one burst of 1100 windows
            steps = 20 + BURST_WINDOWS
            _starved(graph, belief, lambda: mic.outbox.last_step == steps
                     and node.joiner.next_step == steps + 1 and len(rec.belief) == steps,
                     f"the belief node to apply the {steps} steps")  # fmt: skip
            counts = node.joiner.counts
            assert (counts.steps, counts.missing_bits, counts.missing_decisions) == (steps, 0, 0)
            assert mic.outbox.dropped == 0 and mic.outbox.given_up == 0
            graph.run_until(lambda: len(rec.vocalize_step) == steps, "every decision recorded")
            assert_offline_run(rec, samples)
        finally:
            belief.executor.remove_node(node)
            graph.executor.add(node)  # destroyed with the graph
            belief.executor.shutdown(timeout_sec=1.0)


ROOM = {"room": "responsive", "seed": 3, "wait_for_truth_listeners": 1,
        "lockstep_max_speed": 50.0, "lockstep_timeout_s": 600.0, **NO_TIMEOUTS}  # fmt: skip
"""At most 50 times real time; each window waits for its decision."""

FORGED_AHEAD = 3000
"""Steps ahead of the true stream that the forged messages claim."""


@pytest.mark.parametrize("ahead", [FORGED_AHEAD, 10])  # beyond the pace, and within it
def test_a_forged_step_far_ahead_is_named_and_ignored_by_every_node(ahead: int) -> None:
    held = {"fault_hold_s": 600.0}  # the faults stay shown however slow the machine
    # the controller waits for the room too (4 listeners)
    nodes = {"mic_node": MIC, "belief_node": {**BELIEF, **held},
             "fake_audio_node": {**ROOM, **held},
             "controller_node": {**CONTROLLER, **held, "wait_for_listeners": 4}}  # fmt: skip
    with stepped_graph(nodes, "fake_audio_node", recorder_qos=LOSSLESS_READER_QOS) as graph:
        rec = graph.recorder
        graph.run_until(lambda: len(rec.belief) >= 50, "50 steps")
        probe = graph.executor.add(Probe("forger"))
        bits = probe.talk("sound_step", Int64MultiArray)
        decisions = probe.talk("vocalize_step", Int64MultiArray)
        graph.run_until(lambda: bits.get_subscription_count() >= 3  # controller, belief, recorder
                        and decisions.get_subscription_count() >= 4,  # + mic and room
                        "the forger connected")  # fmt: skip
        stream, controller = true_sources(rec)
        forged_step = rec.sound_step[-1][1] + ahead
        forged = [bit_message(StepBit(stream, forged_step, True, 500_000)),
                  decision_message(StepDecision(stream, forged_step, True, controller)),
                  # and a decision with the true controller id on a stream that does not exist
                  decision_message(StepDecision(stream + 1, rec.sound_step[-1][1] + 1, True,
                                                controller))]  # fmt: skip
        for message, publisher in zip(forged, (bits, decisions, decisions), strict=True):
            publisher.publish(message)
        # the graph goes on: the controller answers the true bits, the room hears them
        answered = len(rec.vocalize_step)
        graph.run_until(lambda: len(rec.vocalize_step) >= answered + 101, "100 more steps")
        belief, room = graph.nodes["belief_node"], graph.nodes["fake_audio_node"]
        control = graph.nodes["controller_node"]
        far = ahead > MAX_STEP_JUMP  # refused by the pace, else by the writer's numbers
        nodes = (belief.bit_pace, belief.decision_pace, control.pace, room.pace) if far else (
            belief.bit_writer, belief.decision_writer, control.writer, room.writer)
        graph.run_until(lambda: [getattr(x, "jumps", 0) or getattr(x, "refused", 0)
                                 for x in nodes] == [1, 1, 1, 1],
                        "every node to see the forged messages")  # fmt: skip
        level, message, values = belief.diagnostic_status()
        assert level == ERROR and values["jumps_ignored"] == (2 if far else 0), (message, values)
        graph.run_until(lambda: belief.foreign.count == (1 if far else 3), "the belief node to"
                        " name the decision on a stream it never heard")  # fmt: skip
        assert belief.stream == stream and belief.stream_changes == 0
        belief.intruders = {}  # once the forger's publishers are gone, the fault shows
        assert ("pace" if far else "second stream") in belief.diagnostic_status()[1]
        assert control.diagnostic_status()[0] == room.diagnostic_status()[0] == ERROR

        # the run ends: every true step is in the belief, exactly
        graph.remove("fake_audio_node")
        mic = graph.nodes["mic_node"]
        last = mic.outbox.last_step
        graph.run_until(lambda: belief.joiner.next_step == last + 1 and len(rec.belief) == last
                        and len(rec.vocalize_step) == last + 2,  # with the two forged
                        "the belief node to apply every step")  # fmt: skip
        # the offline recomputation from the true messages (a forged one came first)
        rec.sound_step.remove(tuple(forged[0].data))
        for message in forged[1:]:
            rec.vocalize_step.remove(tuple(message.data))
        pairs = step_pairs(rec, stream, {controller}, 1, last)
        assert None not in [value for pair in pairs for value in pair]
        assert_same_beliefs(rec.belief, offline_beliefs([(pairs, "start")]), pairs=pairs)
        counts = belief.joiner.counts
        assert (counts.missing_bits, counts.missing_decisions) == (0, 0)
        assert control.missed_steps == 0 and control.last_step == last


def test_the_graph_goes_on_without_a_belief_node_that_stopped() -> None:
    """A belief node that takes no step for listener_timeout_s is let go: nothing hangs."""
    nodes = {"mic_node": {**MIC, "listener_timeout_s": 0.5, "fault_hold_s": 60.0},
             "controller_node": CONTROLLER, "belief_node": BELIEF}  # fmt: skip
    with stepped_graph(nodes, None, recorder_qos=LOSSLESS_READER_QOS) as graph:
        rec, mic = graph.recorder, graph.nodes["mic_node"]
        probe = graph.executor.add(Probe())
        audio = probe.talk("audio", Float32MultiArray)
        graph.run_until(lambda: audio.get_subscription_count() >= 1 and mic.started,
                        "the mic on 'audio'")  # fmt: skip
        audio.publish(_message(_audio(200, seed=6)))
        graph.run_until(lambda: len(rec.belief) >= 20 and any(
            x.waited_for for x in mic.outbox.listeners.values()), "20 steps, the belief node"
            " waited for")  # fmt: skip
        graph.remove("belief_node")  # as if killed: it takes nothing more
        graph.run_until(lambda: mic.outbox.given_up == 1 and mic.outbox.last_step == 200,
                        "the belief node let go, every window published")  # fmt: skip
        assert mic.outbox.dropped == 0
        graph.run_until(lambda: len(rec.vocalize_step) == 200, "every step answered")
        level, message, _ = mic.diagnostic_status()
        assert level == WARN and "step_applied" in message, message

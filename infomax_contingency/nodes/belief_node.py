"""belief_node: P(S=1 | history) from the bits and the decisions, once per step.

The statistic is the same :class:`~infomax_contingency.core.model.StatisticTracker` the
controller uses, with its own memory: ``memory_steps`` counted observations (0 = the
whole history; a bounded memory lets the belief fall again after a partner leaves).

Step clock: bits (``sound_step``) and decisions (``vocalize_step``) are joined by their
step number (:class:`~infomax_contingency.core.stepclock.StepJoiner`), whatever order and
rate they arrive in. For each step, in order: the bit is counted, **the belief is
published**, the decision advances the timer. The node follows one controller
(:class:`~infomax_contingency.core.stepclock.SourceLock`: a second one is counted and
ignored; a followed one silent for ``source_timeout_s`` is replaced by the next one
heard, a restarted node) and the stream that controller answers (one mic_node run): the
bits of another stream are counted and kept aside, and used if the controller moves to
that stream (a restarted mic_node). The controller is taken to move only to a stream whose
bits this node hears too: its decisions on a stream none of whose bits came are kept
until they come, and named and ignored once it answers the followed stream again (one
decision forged with the controller's id and a new stream id cannot move the node off
its stream), and only once the followed stream has been silent for ``source_timeout_s``,
as the controller's own rule has it (bits and decisions forged for a new stream cannot
either). The fake room hears the same decisions.

A withheld bit (heard while the robot declared its own sound on ``self_sound``, or
right after windows without a step) is not counted: the belief is still published for
its step.

Nothing is guessed: a step whose bit can no longer arrive is applied without it (not
counted), a step whose decision can no longer arrive leaves the timer uncertain until it
is known again (bits meanwhile are counted only where the period is certain), and a new
stream (a restarted mic_node) continues the counts after a gap of unknown length. A
restarted belief_node starts from zero counts at the first step it receives, with the
timer uncertain unless that step is the stream's first. Each case is counted in the
diagnostics and logged.

Flow control: after each step applied the node publishes ``step_applied``
(``[stream, step, listener]``, its own random listener id), and mic_node publishes no
more than ``max_steps_ahead`` steps beyond the last one the node applied: a slow
belief_node slows the graph instead of losing steps from its queues. A node that takes
nothing for mic_node's ``listener_timeout_s`` (killed, hung) is no longer waited for.

Pace: a bit or decision of the followed stream and controller whose step jumps further
ahead of the last one than the stream's pace allows
(:class:`~infomax_contingency.core.stepclock.StepPace`: 64 steps plus the window rate
times the time between the two) is named, ignored and kept aside, and the diagnostics
go to ERROR: a single forged message cannot make the node skip thousands of steps and
refuse the real ones after. If the source goes on from the jump for
``source_timeout_s`` while nothing comes on pace, its messages were lost, not forged:
the run is taken.

Start: the node subscribes ``sound_step`` only once its ``vocalize_step`` subscription
is matched with a publisher (a controller), and ``belief`` has ``wait_for_listeners``
subscribers (default 0; a test that checks every belief counts its recorder).
mic_node's start gate counts the listeners of ``sound_step``, so the graph's first bit
waits until this node also hears the controller: a belief_node whose processes connect
slowly (a loaded machine) does not miss the first decisions and join the stream late.

Subscribes ``sound_step``, ``vocalize_step`` (std_msgs/Int64MultiArray, see
:mod:`~infomax_contingency.nodes.step_topics`); publishes ``belief`` (Float64),
``step_applied`` (Int64MultiArray) and ``/diagnostics``; private service ``~/reset``
(std_srvs/Trigger, e.g. ``/belief_node/reset`` or ``/robot1/belief_node/reset``) forgets
the history.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from typing import Any

from std_msgs.msg import Float64, Int64MultiArray
from std_srvs.srv import Trigger

from infomax_contingency.core.flowcontrol import SOURCE_TIMEOUT_S
from infomax_contingency.core.model import MAX_MEMORY_STEPS, StatisticTracker, Withheld
from infomax_contingency.core.stepclock import (
    Arrival,
    PublicationTimes,
    SourceLock,
    StepJoiner,
    StepPace,
    WriterSequence,
)
from infomax_contingency.nodes.graph_node import (
    ERROR,
    OK,
    WARN,
    GraphNode,
    count_only,
    take_from_writer,
    take_on_pace,
)
from infomax_contingency.nodes.qos import STEP_READER_QOS, STREAM_QOS
from infomax_contingency.nodes.runtime import run_node
from infomax_contingency.nodes.step_topics import (
    NO_STEP,
    SOUND_STEP,
    STEP_APPLIED,
    VOCALIZE_STEP,
    StepApplied,
    StepBit,
    StepDecision,
    applied_message,
    new_source_id,
    parse_bit,
    parse_decision,
    window_us,
)

BITS_GATE_POLL_S = 0.02
"""Seconds between checks for a controller before ``sound_step`` is subscribed."""

HELD_BITS = 1024
"""Bits kept per stream that the controller does not answer (yet)."""

HELD_STREAMS = 8
"""Streams whose bits are kept at once (the oldest is forgotten first)."""


class BeliefNode(GraphNode):
    """Belief: the posterior probability that a responsive partner is present."""

    NODE_NAME = "belief_node"
    WATCHED_TOPICS = ("sound", SOUND_STEP, "vocalize", VOCALIZE_STEP)

    def configure(self) -> None:
        """Declare and check the parameters; the state they set."""
        read = self.parameters
        self.params = read.model()
        memory = read.integer(
            "memory_steps",
            60,
            "Counted observations the statistic keeps (a sliding memory, as the robot"
            " table's M = 60 in config/robot.yaml); 0 = whole history",
            0,
            MAX_MEMORY_STEPS,
        )
        timeout_s = read.number(
            "source_timeout_s", SOURCE_TIMEOUT_S,
            "A followed mic_node stream or controller silent this long is replaced by the"
            " next one heard", 0.1, 3600.0, "s",
        )
        self.max_pending = read.integer(
            "max_pending_steps", 600,
            "Steps that may wait for their decision; older ones are applied without it",
            1, 1_000_000,
        )
        self.wait_for_listeners = read.integer(
            "wait_for_listeners", 0,
            "Subscribers of 'belief' (e.g. posture_node, a recorder) connected before the"
            " node joins a stream, so that they receive every belief",
            0, 100,
        )
        self.window_us = window_us(self.params.dt)
        self.tracker = StatisticTracker(self.params, memory=memory)
        self.joiner = StepJoiner(self._apply, self.max_pending)
        self.controllers = SourceLock(timeout_s)
        self.belief = self.tracker.statistic.belief(self.params)
        self.listener_id = new_source_id()
        """This node's id on ``step_applied``."""
        self.bit_pace = StepPace(1.0 / self.params.dt, timeout_s)
        self.bit_writer = WriterSequence()
        self.decision_writer = WriterSequence()
        """The writers of the stream and the controller followed (a forgery is another)."""
        self.decision_pace = StepPace(1.0 / self.params.dt, timeout_s)
        self.jumps = self.recent_events()
        self.resets = 0
        self.malformed = self.recent_events()
        self.wrong_window = self.recent_events()
        self.foreign = self.recent_events()
        self.gaps = self.recent_events()
        self.stream_changes = 0
        self._stream_started = False
        self.stream: int | None = None
        """The stream followed: the one the followed controller answers."""
        self._held: dict[int, deque[StepBit]] = {}
        self._unheard: deque[tuple[StepDecision, float, int | None]] = deque(maxlen=HELD_BITS)
        """Decisions of the followed controller on a stream none of whose bits came yet
        (with their publication times and DDS numbers): the stream is followed once its bits come; a
        decision on the followed stream first shows they were forged."""
        self._joining = False
        self._bit_times = PublicationTimes(horizon_s=max(10.0, 4 * self.controllers.silence_s))
        """Publication times (s) of the followed stream's recent bits."""

    def activate(self) -> None:
        """Publishers, subscriptions, services and timers."""
        self.belief_pub = self.create_publisher(Float64, "belief", STREAM_QOS)
        self.applied_pub = self.create_publisher(Int64MultiArray, STEP_APPLIED, STREAM_QOS)
        self._decisions_sub = self.subscribe(
            Int64MultiArray, VOCALIZE_STEP, self._on_vocalize_step, STEP_READER_QOS
        )
        self._bits_gate = self.create_timer(BITS_GATE_POLL_S, self._subscribe_bits_when_ready)
        self.create_service(Trigger, "~/reset", self._on_reset)
        count_only(self, Int64MultiArray, NO_STEP)  # steps paused, not stopped
        self.wait_visibly(VOCALIZE_STEP, "the decisions of controller_node: is it running?",
                          companions=(NO_STEP,))  # fmt: skip
        self.wait_visibly(
            SOUND_STEP, "the bits of mic_node, read once a controller publishes decisions",
            companions=(NO_STEP,),
        )

    def _subscribe_bits_when_ready(self) -> None:
        """Subscribe ``sound_step`` once a controller and the belief's listeners are there."""
        if self._decisions_sub.get_publisher_count() == 0:
            return
        if self.belief_pub.get_subscription_count() < self.wait_for_listeners:
            return
        self._bits_gate.cancel()
        self.destroy_timer(self._bits_gate)
        self.subscribe(Int64MultiArray, SOUND_STEP, self._on_sound_step, STEP_READER_QOS)

    # ------------------------------------------------------------------ messages

    def _on_sound_step(self, msg: Int64MultiArray, stamp: int) -> None:
        bit = parse_bit(msg)
        now = self.now_s()
        if bit is None:
            self.malformed.note(now)
            self.warn_intrusion(f"malformed '{SOUND_STEP}' message ignored: {list(msg.data)}")
            return
        if bit.window_us != self.window_us:
            self.wrong_window.note(now)
            self.log_throttled(
                "wrong window",
                "error",
                f"stream {bit.stream} has windows of {bit.window_us / 1e6:g} s but the model's"
                f" dt is {self.params.dt:g} s: its bits are ignored",
            )
            return
        if bit.stream != self.stream:
            self._hold(bit, now)
            return
        sent = self.sent_s(stamp, now)
        source = f"stream {bit.stream}"
        bits = take_on_pace(self, self.bit_pace, self.jumps, bit.step, sent, bit, "bit", source)
        bits = take_from_writer(self, self.bit_writer, self.foreign, bits, bit.step,
                                self.sequence, source)  # fmt: skip
        if bits:
            self._bit_times.note(sent)
        for taken in bits:
            if not self.joiner.bit(taken.step, taken.observation):
                self.warn_intrusion(
                    f"bit for step {taken.step} of stream {taken.stream} repeats or goes"
                    f" backwards (last step {self.joiner.last_bit_step}): ignored"
                )

    def _hold(self, bit: StepBit, now: float) -> None:
        """Keep a bit of a stream the controller does not answer (yet): maybe it will."""
        held = self._held.setdefault(bit.stream, deque(maxlen=HELD_BITS))
        held.append(bit)
        while len(self._held) > HELD_STREAMS:
            del self._held[next(iter(self._held))]
        waiting = [entry for entry in self._unheard if entry[0].stream == bit.stream]
        if waiting:  # the controller moved to this stream before its bits came here
            self._unheard.clear()
            for decision, sent, sequence in waiting:
                self._take_decision(decision, sent, sequence)
            return
        if self.stream is not None:
            self.foreign.note(now)
            self.warn_intrusion(
                f"ignoring bits of stream {bit.stream} (a second mic_node?): the controller"
                f" answers stream {self.stream}"
            )

    def _on_vocalize_step(self, msg: Int64MultiArray, stamp: int) -> None:
        decision = parse_decision(msg)
        now = self.now_s()
        if decision is None:
            self.malformed.note(now)
            self.warn_intrusion(
                f"malformed '{VOCALIZE_STEP}' message ignored: {list(msg.data)}"
            )
            return
        # A decision on the followed stream from another controller replaces the followed
        # one only if that one left the stream's bits unanswered for source_timeout_s: a
        # pause of the whole graph, while a rogue keeps talking, is no silence. The bits
        # counted are those published by the time the decision was, not the newest
        # processed: under a flood the bits' queue may run seconds ahead of the decisions'.
        sent = self.sent_s(stamp, now)
        unanswered = None
        foreign = decision.controller != self.controllers.source
        if foreign and decision.stream == self.stream:
            unanswered = self._bit_times.unanswered_s(self.controllers.last_seen, sent)
        arrival = self.controllers.accept(decision.controller, sent, unanswered_s=unanswered)
        if arrival is Arrival.FOREIGN:
            self.foreign.note(now)
            self.warn_intrusion(
                f"ignoring decisions of controller {decision.controller} (a second"
                f" controller_node?): following controller {self.controllers.source}"
            )
            return
        if arrival is Arrival.SWITCHED:
            self.get_logger().warning(
                f"controller {self.controllers.previous} went silent; following controller"
                f" {decision.controller} (a restarted controller_node?)"
            )
        if arrival is not Arrival.FOLLOWED:
            self.decision_pace.restart()
            self.decision_writer.restart()
        if decision.stream != self.stream and self.stream is not None and not self._held.get(
                decision.stream):  # fmt: skip
            self._unheard.append((decision, sent, self.sequence))  # its bits may be on their way
            return
        if decision.stream == self.stream:
            self._name_unheard(now)
        self._take_decision(decision, sent, self.sequence)

    def _take_decision(self, decision: StepDecision, sent: float, sequence: int | None) -> None:
        """Apply a decision of the followed controller (following its stream).

        The controller moves to another stream only once the one it answers has been
        silent for ``source_timeout_s`` (its own rule): a decision on another stream while
        the followed one still published bits that recently is not its own (forged with
        its id, with bits forged for that stream too), and is named and ignored.
        """
        if decision.stream != self.stream:
            if self.stream is not None and (
                quiet_s := sent - self._bit_times.newest_until(sent)
            ) < self.controllers.silence_s:
                self.foreign.note(self.now_s())
                self.warn_intrusion(
                    f"ignoring a decision for step {decision.step} of stream {decision.stream}"
                    f" with the id of controller {decision.controller}: stream {self.stream}"
                    f" published a bit {max(quiet_s, 0.0):.1f} s before it, and a controller"
                    f" moves only after {self.controllers.silence_s:g} s of silence (forged?)"
                )
                return
            self._follow(decision.stream, decision.step)
            self.decision_pace.restart()
            self.decision_writer.restart()
        source = f"controller {decision.controller}"
        on_pace = take_on_pace(self, self.decision_pace, self.jumps, decision.step, sent,
                               decision, "decision", source)  # fmt: skip
        for taken in take_from_writer(self, self.decision_writer, self.foreign, on_pace,
                                      decision.step, sequence, source):  # fmt: skip
            if not self.joiner.decision(taken.step, taken.vocalize):
                self.warn_intrusion(
                    f"decision for step {taken.step} repeats, goes backwards or answers no"
                    " bit received: ignored"
                )

    def _name_unheard(self, now: float) -> None:
        """Name and drop the decisions kept for a stream whose bits never came.

        The controller still answers the followed stream: they were not its own (forged
        with its id).
        """
        for decision, _, _ in self._unheard:
            self.foreign.note(now)
            self.warn_intrusion(
                f"ignoring a decision for step {decision.step} of stream {decision.stream}"
                f" with the id of controller {decision.controller}: no bit of that stream"
                f" was heard, and the controller answers stream {self.stream} (forged?)"
            )
        self._unheard.clear()

    def _follow(self, stream: int, step: int) -> None:
        """The controller answers ``stream`` from ``step`` on: follow it from there.

        Bits held for that stream from ``step`` on are used; older ones were never
        answered (the controller joined that stream at ``step``).
        """
        held = [bit for bit in self._held.pop(stream, ()) if bit.step >= step]
        if self.stream is None:
            self._joining = True  # announced, and the timer set, at the first step applied
        else:
            self.stream_changes += 1
            self.gaps.note(self.now_s())
            self.joiner.finish()  # the old stream's awaited decisions can never arrive
            self.joiner.restart()
            self.tracker.forget_timer()
            self.get_logger().warning(
                f"the controller answers stream {stream} from step {step} instead of stream"
                f" {self.stream} (a restarted mic_node?): counts kept, the gap between is not"
                " guessed"
            )
        self.stream = stream
        for bit in held:
            self.joiner.bit(bit.step, bit.observation)
        # The stream's pace from its newest bit held (or from its next bit).
        self.bit_pace.restart(held[-1].step if held else None, time.time())
        self.bit_writer.restart()

    # ------------------------------------------------------------------ steps

    def _apply(self, step: int, y: bool | Withheld | None, u: bool | None) -> None:
        """Apply one step in order: count the bit, publish the belief, act."""
        if self._joining:
            self._joining = False
            how = "zero counts" + (", timer unknown until the next vocalization" if step > 1
                                   else "")  # fmt: skip
            self.get_logger().info(f"joined stream {self.stream} at step {step}: {how}")
            if step > 1:  # the decisions before it are unknown
                self.tracker.forget_timer_completely()
        self.tracker.observe_window(y)
        self.belief = self.tracker.statistic.belief(self.params)
        self.belief_pub.publish(Float64(data=self.belief))
        if u is None:
            self.tracker.act_unknown()
        else:
            self.tracker.act(u)
        self.applied_pub.publish(
            applied_message(StepApplied(self.stream, step, self.listener_id))
        )
        if y is None or u is None:
            self.gaps.note(self.now_s())
            missing = "bit" if y is None else "decision"
            missing = "bit and decision" if y is None and u is None else missing
            self.log_throttled(
                "gap", "warning", f"step {step}: the {missing} never arrived; not guessed"
            )

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.tracker.reset()
        self.belief = self.tracker.statistic.belief(self.params)
        self.resets += 1
        response.success = True
        response.message = f"statistic reset after {self.joiner.counts.steps} steps"
        self.get_logger().info(response.message)
        return response

    # ------------------------------------------------------------------ diagnostics


    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Belief, statistic, steps, gaps, intruders and the joining queues."""
        counts = self.joiner.counts
        now = self.now_s()
        values = {
            "belief": self.belief,
            "statistic": tuple(self.tracker.statistic),
            "timer_certain": self.tracker.timer_certain,
            "uncounted_bits": self.tracker.uncounted,
            "withheld_bits": self.tracker.withheld,
            "memory_steps": self.tracker.memory,
            "k2_per_lag": self.params.k2_per_lag,
            "stream": self.stream or "none yet",
            "controller": self.controllers.source or "none yet",
            "steps": counts.steps,
            "last_step": (self.joiner.next_step or 1) - 1,
            "pending_bits": self.joiner.pending_bits,
            "pending_decisions": self.joiner.pending_decisions,
            "missing_bits": counts.missing_bits,
            "missing_decisions": counts.missing_decisions,
            "stale_bits": counts.stale_bits,
            "stale_decisions": counts.stale_decisions,
            "foreign_messages": self.foreign.count,
            "malformed_messages": self.malformed.count,
            "wrong_window_messages": self.wrong_window.count,
            "stream_changes": self.stream_changes,
            "jumps_ignored": self.bit_pace.jumps + self.decision_pace.jumps,
            "listener_id": self.listener_id,
            "resets": self.resets,
            "stale_messages": self.stale_messages,
        }
        if self.intruders:
            topics = ", ".join(f"'{topic}'" for topic in self.intruders)
            return ERROR, f"more than one publisher on {topics}", values
        if self.jumps.recent(now):
            return ERROR, "steps jumping ahead of their source's pace (ignored)", values
        if self.foreign.recent(now) or self.wrong_window.recent(now):
            return ERROR, "messages from a second stream or controller (ignored)", values
        if self.malformed.recent(now):
            return WARN, "malformed step messages (ignored)", values
        if self.gaps.recent(now):
            return WARN, "steps missed lately (not guessed; see values)", values
        if self.joiner.pending_bits > 2:
            return WARN, "bits are waiting for decisions (is the controller running?)", values
        return OK, f"P(S=1) = {self.belief:.4f}", values


def main(args: list[str] | None = None) -> int:
    """Run the belief node."""
    return run_node(BeliefNode, args)


if __name__ == "__main__":
    sys.exit(main())

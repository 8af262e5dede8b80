"""mic_node: audio windows to bits — the step clock of the graph.

Where the windows come from (``source``) and how a window becomes a bit (``bit_source``,
held by :mod:`~infomax_contingency.nodes.mic_bits`) are its configuration
(:mod:`~infomax_contingency.nodes.mic_config`).

Step clock: every bit is a step ``1, 2, ...`` of this run's *stream* (a random id),
published on ``sound`` (Bool) and, with its identity and the window length, on
``sound_step`` (see :mod:`~infomax_contingency.nodes.step_topics`). Windows wait in a
bounded outbox (:class:`~infomax_contingency.core.flowcontrol.StepOutbox`): while a
controller answers on ``vocalize_step``, at most ``max_steps_ahead`` steps are out
unanswered, or not yet taken by a listener that acknowledges every step on
``step_applied`` (belief_node; one that takes nothing for ``listener_timeout_s`` is no
longer waited for), so a burst of audio (a 30 s message, a fast replay) or a slow
belief_node slows the graph and nothing overflows a queue; at most ``max_backlog_s`` of
windows wait (more is dropped and counted). A window is one step of the model: its length
is the model's dt (``params``).

Start: the first bit goes out once ``sound_step`` has ``wait_for_listeners`` subscribers
(and, in lockstep, ``vocalize_step`` a publisher) and every subscriber seen on its topics
is connected, plus ``start_delay_s`` for the rest of the graph to connect; windows of the
``audio`` topic that arrive meanwhile wait, none is lost. ``max_windows > 0`` stops the
node (exit status 0) after that many bits, once the subscribers have acknowledged them.

The ``audio`` topic (:mod:`~infomax_contingency.nodes.audio_topic`): only the first writer's
chunks are windowed; another writer's are counted and ignored, a restarted one is a gap.

Self-sound (:mod:`~infomax_contingency.nodes.self_sound`): a window that overlaps the
robot's own sound declared on ``self_sound`` is published withheld (as are bits after a gap:
``GapWithholding``); while it has a publisher, windows wait ``self_sound_hold_s`` past their end.

Publishes ``sound`` (Bool, once per window), ``sound_energy`` (Float32, dB), ``no_step``
(a window that gave no step, its bit source calibrating: a lockstep room goes on),
``/diagnostics`` (for a live microphone also the device, its state, overflows, dropped
blocks, lost samples, gaps and reconnections). Service ``~/recalibrate``
(std_srvs/Trigger): the bit source's calibration starts again.
"""

from __future__ import annotations

import functools
import sys
import time
from typing import Any

from rclpy.duration import Duration
from std_msgs.msg import Bool, Float32, Int64MultiArray
from std_srvs.srv import Trigger

from infomax_contingency.audio.bitsources.base import OUT_OF_RANGE, UNSEPARATED
from infomax_contingency.audio.contracts import AudioContract
from infomax_contingency.audio.devices import DISCONNECTED
from infomax_contingency.audio.windows import MicrophoneWindows, SourceWindow, TopicWindows
from infomax_contingency.core.flowcontrol import Listening, StepOutbox
from infomax_contingency.core.stepclock import LockstepPacer
from infomax_contingency.nodes import mic_config
from infomax_contingency.nodes.audio_topic import AudioTopicInput
from infomax_contingency.nodes.graph_node import ERROR, OK, RELEASED_WINDOW, WARN, GraphNode
from infomax_contingency.nodes.mic_bits import BitSourceControls
from infomax_contingency.nodes.qos import STEP_READER_QOS, STREAM_QOS
from infomax_contingency.nodes.runtime import run_node
from infomax_contingency.nodes.self_sound import SelfSoundInput
from infomax_contingency.nodes.step_topics import (
    SOUND_STEP,
    STEP_APPLIED,
    VOCALIZE_STEP,
    StepBit,
    bit_message,
    new_source_id,
    parse_applied,
    parse_decision,
    window_us,
)

MICROPHONE_POLL_S = 0.02
"""Seconds between reads of the live microphone's finished windows."""

LISTENER_CHECK_S = 0.5
"""Seconds between checks for a listener on 'step_applied' that stalled (killed, hung)."""
ACK_TIMEOUT_S = 5.0
"""Seconds a finishing node waits for its subscribers to acknowledge the last messages."""

class MicNode(GraphNode):
    """Microphone: audio windows to sound bits."""

    NODE_NAME = "mic_node"
    WATCHED_TOPICS = ("sound", SOUND_STEP)

    def configure(self) -> None:
        """Parameters, the bit source, the window source (a replay calibrated ahead)."""
        self.config = config = mic_config.read_config(self.parameters)
        self.controls = BitSourceControls(self, config)
        self.bits, self.threshold_log = self.controls.bits, self.controls.threshold_log
        self.source = mic_config.open_window_source(config, self.bits.needs_samples, self.log_at)
        self.replay = self.source if self.source.replay else None
        self.controls.use_source(self.source)
        lockstep = self.replay is not None and config.lockstep
        self.pacer = LockstepPacer(config.lockstep_timeout_s) if lockstep else None
        self.stream_id = new_source_id()
        self.window_us = window_us(config.window_s)
        self.outbox = StepOutbox(
            config.max_steps_ahead, max(1, round(config.max_backlog_s / config.window_s)),
            config.listener_timeout_s,
        )
        self.stalled_listeners = self.recent_events()
        self.windows = 0
        self.last_energy_db = float("nan")
        self.started = self.ended = False
        self.losses = self.recent_events()
        self.timeouts = self.recent_events()
        audio = self.resolve_topic_name("audio")
        self.contract = AudioContract(config.audio_rate_hz, self.fault_hold_s, publishers=lambda: [
            info.node_name for info in self.get_publishers_info_by_topic(audio)])
        if self.replay is not None:
            looping = ", looping" if getattr(self.source, "loop", False) else ""
            pace = "lockstep" if self.pacer else "real time"
            self.get_logger().info(f"replaying {self.source.describe()}, {pace}{looping}")

    def activate(self) -> None:
        """Publishers, the decisions (and audio) subscriptions, ~/recalibrate, the start gate."""
        self.sound_pub = self.create_publisher(Bool, "sound", STREAM_QOS)
        self.step_pub = self.create_publisher(Int64MultiArray, SOUND_STEP, STREAM_QOS)
        self.energy_pub = self.create_publisher(Float32, "sound_energy", STREAM_QOS)
        self._decisions_sub = self.subscribe(
            Int64MultiArray, VOCALIZE_STEP, self._on_decision, STEP_READER_QOS
        )
        self.subscribe(Int64MultiArray, STEP_APPLIED, functools.partial(_on_applied, self),
                       STEP_READER_QOS)  # fmt: skip
        self.self_sound = SelfSoundInput(self, self.config.self_sound_hold_s,
                                         self.config.window_s, self._release)  # fmt: skip
        if isinstance(self.source, TopicWindows):
            AudioTopicInput(self, self.source, self.contract, self._on_audio_windows)
        self.create_service(Trigger, "~/recalibrate", self.controls.on_recalibrate)
        self.controls.activate(self.stream_id)
        self._pace_timer = None
        self.awaited = mic_config.start_gate_text(self.config, lockstep=self.pacer is not None)
        """What the step clock waits for before it starts (the start gate), in words."""
        self.start_when_ready(
            self._listeners_ready,
            self.config.start_delay_s,
            self._start,
            self.pacer,
            self._on_timeout,
            "is controller_node running?",
            self.awaited,
        )
        self.get_logger().info(f"stream id {self.stream_id}")
        self.threshold_log(self.bits)

    def destroy_node(self) -> None:
        """Release the microphone, then the node."""
        source = getattr(self, "source", None)
        if source is not None:
            source.close()
        super().destroy_node()

    # ------------------------------------------------------------------ start gate

    def _listeners_ready(self) -> bool:
        listening = self.step_pub.get_subscription_count() >= self.config.wait_for_listeners
        return listening and (self.pacer is None or self._decisions_sub.get_publisher_count() > 0)

    def _start(self) -> None:
        self.started = True
        self.get_logger().info("listeners connected: starting the step clock")
        if self.replay is not None:
            if self.pacer is None:
                self._pace_timer = self.create_timer(self.config.window_s, self._serve_replay)
            self._serve_replay()
        if isinstance(self.source, MicrophoneWindows):
            self.source.start()
            self.create_timer(MICROPHONE_POLL_S, self._read_microphone)
        self.create_timer(LISTENER_CHECK_S, self._release)  # a stalled listener is let go
        self._release()

    def _on_timeout(self) -> None:
        self.timeouts.note(self.now_s())
        missing = ("no controller_node publishes 'vocalize_step'"
                   if self._decisions_sub.get_publisher_count() == 0
                   else "controller_node is there but did not answer")  # fmt: skip
        self.get_logger().warning(
            f"no 'vocalize' within {self.pacer.timeout_s} s of window {self.windows}:"
            f" {missing}; releasing {RELEASED_WINDOW}"
        )
        self._serve_replay()

    # ------------------------------------------------------------------ windows

    def _serve_replay(self) -> None:
        """Serve the replay's next window, and more while they yield no bit (calibration)."""
        while not self.ended:
            taken = self.replay.take()
            if not taken:
                self._end_of_replay()
                return
            if self.pacer is not None:
                self.pacer.sent(time.monotonic())
            if self._window(taken[0]) is not None:
                return

    def _end_of_replay(self) -> None:
        self.ended = True
        if self._pace_timer is not None:
            self._pace_timer.cancel()
        self.get_logger().info(f"end of {self.replay.describe()} after {self.windows} bits")
        if self.config.exit_at_end:
            self._finish_publishing()

    def _on_audio_windows(self) -> None:
        self.controls.hold(self.source.take(), self.outbox.max_backlog)
        self._decide_held()

    def _decide_held(self) -> None:
        """Decide the held windows of 'audio' whose decisions before them are in."""
        for window in self.controls.decidable():
            self._window(window)

    def _read_microphone(self) -> None:
        for window in self.source.take():
            if self.finished.done():
                return
            if window.gap_s > 0 or not window.intact:
                self.losses.note(self.now_s())
            self._window(window)
            self.source.published(window)

    def _window(self, window: SourceWindow) -> bool | None:
        """A window was made: its bit (after calibration) waits in the outbox to go out.

        Returns the bit (None for a calibration window: it gives no step, and says so).
        """
        bit, energy_db = self.controls.bit_of(window)
        self.last_energy_db = energy_db
        if bit is None:  # a calibration window: its energy, and word that it gave no step
            self.energy_pub.publish(Float32(data=energy_db))
            self.controls.say_no_step()
            return None
        self.self_sound.push(window, energy_db, bit, self.controls.gap_before(window))
        self._release()
        return bit

    def _on_decision(self, msg: Int64MultiArray, stamp: int) -> None:
        decision = parse_decision(msg)
        if decision is None or decision.stream != self.stream_id:
            return
        before = self.outbox.last_answered
        self.outbox.answered(decision.step, self.now_s())
        if self.outbox.last_answered == before:
            return  # a repeated answer (a second controller): it releases nothing
        self.controls.decided(before, decision.step, decision.vocalize)
        self._decide_held()
        if (
            self.started
            and self.pacer is not None
            and decision.step == self.outbox.last_step
            and self.pacer.answered()
        ):
            self._serve_replay()
        self._release()

    def _release(self) -> None:
        """Publish the windows the outbox lets go now: energy, bit and stamped bit.

        First the windows whose self-sound is known leave the self-sound gate for the
        outbox.
        """
        dropped = self.outbox.dropped
        for window in self.self_sound.release(replaying_in_lockstep=self.pacer is not None):
            self.outbox.push(window)
        self.controls.dropped(self.outbox.dropped - dropped)
        if self.outbox.dropped > dropped:
            self.losses.note(self.now_s())
            self.log_throttled("windows dropped", "warning",
                               f"{self.outbox.dropped} windows dropped: more than"
                               f" {self.config.max_backlog_s:g} s waited for the controller")
        if not self.started or self.finished.done():
            return
        outbox = self.outbox
        now = self.now_s()
        self.controls.give_up(outbox, now, self._decisions_sub.get_publisher_count)
        # Pacing matters only when more would go out than may be unanswered: only then ask
        # the graph whether a controller answers (one query per window is measurable).
        paced = (
            outbox.in_flight + outbox.backlog > outbox.max_ahead
            and self._decisions_sub.get_publisher_count() > 0
        )
        for step, (energy_db, bit, withheld, gap_before) in self.outbox.release(paced, now):
            self.windows += 1
            withheld = self.controls.released(step, withheld, gap_before)
            self.energy_pub.publish(Float32(data=energy_db))
            self.sound_pub.publish(Bool(data=bit))
            self.step_pub.publish(
                bit_message(StepBit(self.stream_id, step, bit, self.window_us, withheld))
            )
            if self.config.max_windows and self.windows >= self.config.max_windows:
                self.get_logger().info(f"{self.windows} bits published (max_windows): stopping")
                self._finish_publishing()
                return

    def _finish_publishing(self) -> None:
        """Publish the final diagnostics; finish (exit status 0) once all was acknowledged."""
        self.publish_diagnostics()
        for publisher in self.publishers:
            publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
        self.finish(0)

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Threshold, windows, steps, losses, lockstep timeouts, the live device."""
        bits, now = self.bits, self.now_s()
        values: dict[str, Any] = {
            "source": self.config.source,
            "stream": self.stream_id,
            "bits_published": self.windows,
            **self.controls.values(),
            "steps_answered": self.outbox.last_answered,
            "steps_waiting": self.outbox.backlog,
            "windows_dropped": self.outbox.dropped,
            "steps_taken": self.outbox.last_taken,
            "listeners_waited_for": sum(x.waited_for for x in self.outbox.listeners.values()),
            "listeners_given_up": self.outbox.given_up,
            "answers_given_up": self.outbox.answers_given_up,
            "bit_source": self.config.bit_source,
            "last_energy_db": self.last_energy_db,
            **bits.diagnostic_values(),
            **self.source.status(),
            **self.self_sound.values(),
            **self.contract.values(),  # none before the first chunk of 'audio'
        }
        if self.pacer is not None:
            values["lockstep_timeouts"] = self.pacer.timeouts
        if self.intruders:
            return ERROR, f"another publisher on {' and '.join(map(repr, self.intruders))}", values
        if not self.started:
            return WARN, f"waiting for {self.awaited}", values
        if values.get("state") == DISCONNECTED:
            return ERROR, f"microphone disconnected, retrying: {values['last_error']}", values
        if bits.state in (UNSEPARATED, OUT_OF_RANGE):  # no bits; out of range: until it is back
            return (ERROR if bits.state == UNSEPARATED else WARN), bits.problem, values
        if self.controls.silence.dead:
            return WARN, self.controls.silence.message(), values
        if bits.calibrating:
            return OK, "calibrating the threshold", values
        if self.stalled_listeners.recent(now) or self.controls.answers_lost.recent(now):
            return WARN, f"a listener on '{STEP_APPLIED}' or the controller stalled", values
        problem = self.contract.problem()  # the 'audio' contract broken lately
        if problem or self.losses.recent(now) or self.timeouts.recent(now) or (
                self.self_sound.faults.recent(now)):  # fmt: skip
            problem = problem or ("audio lost, lockstep timeouts, or 'self_sound' ranges refused,"
                                  " late or long lately (counts in the values)")  # fmt: skip
            return WARN, problem, values
        return OK, f"{self.windows} bits published", values


def _on_applied(node: MicNode, msg: Int64MultiArray, stamp: int) -> None:
    """A listener (belief_node) took the steps of ``node``'s stream up to one: release more."""
    applied = parse_applied(msg)
    if applied is None or applied.stream != node.stream_id:
        return
    taken = node.outbox.acknowledged(applied.listener, applied.step, node.now_s())
    if taken is Listening.WAITED_FOR:
        node.get_logger().info(f"listener {applied.listener} on '{STEP_APPLIED}' keeps up (step"
                               f" {applied.step}): no step goes more than"
                               f" {node.outbox.max_ahead} ahead of it")
    node._release()  # the node's own subscription (a function: MicNode's size bound)


def main(args: list[str] | None = None) -> int:
    """Run the mic node."""
    return run_node(MicNode, args)


if __name__ == "__main__":
    sys.exit(main())

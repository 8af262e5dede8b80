"""mic_node: audio windows to bits — the step clock of the graph.

Where the windows come from (``source``) and how a window becomes a bit
(``bit_source``) are its configuration (:mod:`~infomax_contingency.nodes.mic_config`); the
node takes windows from its window source, asks the bit source for their bits and
publishes them.

Step clock: every bit is a step ``1, 2, ...`` of this run's *stream* (a random id),
published on ``sound`` (Bool) and, with its identity and the window length, on
``sound_step`` (see :mod:`~infomax_contingency.nodes.step_topics`). Windows wait in a
bounded outbox (:class:`~infomax_contingency.core.stepclock.StepOutbox`): while a
controller answers on ``vocalize_step``, at most ``max_steps_ahead`` steps are out
unanswered, so a burst of audio (a 30 s message, a fast replay) is published as fast as
the controller decides and nothing overflows a queue; at most ``max_backlog_s`` of
windows wait (more is dropped and counted). A window is one step of the model: its length
is the model's dt (``params``).

Start: the first bit goes out once ``sound_step`` has ``wait_for_listeners`` subscribers
(and, in lockstep, ``vocalize_step`` a publisher) and every subscriber seen on its topics
is connected, plus ``start_delay_s`` for the rest of the graph to connect; windows of the
``audio`` topic that arrive meanwhile wait, none is lost. ``max_windows > 0`` stops the
node (exit status 0) after that many bits, once the subscribers have acknowledged them.

Self-sound (:mod:`~infomax_contingency.nodes.self_sound`): a window that overlaps the
robot's own sound declared on ``self_sound`` is published withheld (``sound_step``); while
the topic has a publisher, windows wait ``self_sound_hold_s`` past their end for it.

Publishes ``sound`` (Bool, once per window), ``sound_energy`` (Float32, dB),
``/diagnostics`` (for a live microphone also the device, its state, overflows, dropped
blocks, lost samples, gaps and reconnections). Service ``~/recalibrate``
(std_srvs/Trigger): the bit source's calibration starts again.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
from rclpy.duration import Duration
from std_msgs.msg import Bool, Float32, Float32MultiArray, Int64MultiArray
from std_srvs.srv import Trigger

from infomax_contingency.audio.bitsources import BIT_SOURCES, DEFAULT_BIT_SOURCE
from infomax_contingency.audio.bitsources.base import UNSEPARATED, BitSource, SettingError
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.contracts import AudioContract
from infomax_contingency.audio.devices import DISCONNECTED
from infomax_contingency.audio.windows import MicrophoneWindows, SourceWindow, TopicWindows
from infomax_contingency.core.stepclock import LockstepPacer, StepOutbox
from infomax_contingency.nodes.graph_node import ERROR, OK, RELEASED_WINDOW, WARN, GraphNode
from infomax_contingency.nodes.mic_config import make_bits, open_window_source, read_config
from infomax_contingency.nodes.parameters import ConfigError
from infomax_contingency.nodes.qos import AUDIO_QOS, STEP_READER_QOS, STREAM_QOS
from infomax_contingency.nodes.runtime import run_node
from infomax_contingency.nodes.self_sound import SelfSoundInput
from infomax_contingency.nodes.step_topics import (
    SOUND_STEP,
    VOCALIZE_STEP,
    StepBit,
    bit_message,
    new_source_id,
    parse_decision,
    window_us,
)

MICROPHONE_POLL_S = 0.02
"""Seconds between reads of the live microphone's finished windows."""

ACK_TIMEOUT_S = 5.0
"""Seconds a finishing node waits for its subscribers to acknowledge the last messages."""

NOISE_FLOOR_LOG_STEP_DB = 1.0
"""A threshold that follows the noise floor is logged again once it moved this much, dB."""


class ThresholdLog:
    """Logs (INFO) the threshold in force, and where it came from, when it changed.

    mic_node calls it wherever the threshold can change: at start-up, after each window
    (the end of a calibration, an accepted refit, the noise floor), after a live set and a
    ~/recalibrate. A threshold that follows the noise floor window by window is logged
    again once it moved by :data:`NOISE_FLOOR_LOG_STEP_DB` (diagnostics show every value).
    """

    def __init__(self, logger: Any, bit_source: str) -> None:
        self.logger = logger
        self.bit_source = bit_source
        self.logged_db: float | None = None
        """The threshold last logged, dB (set it when another line named the threshold)."""

    def after_window(self, bits: BitSource, was_calibrating: bool) -> None:
        """After a window: the end of a calibration, or a threshold that changed (a refit).

        The window that completes a calibration (or the noise floor's warm-up) yields no
        bit itself; its end is logged with the source's ready line (the threshold and
        the clusters or floor it came from), which counts as the threshold's line.
        """
        if was_calibrating and not bits.calibrating:
            self.logger.info(bits.ready_message())
            self.logged_db = bits.threshold_db
            return
        self(bits)

    def __call__(self, bits: BitSource) -> None:
        """Log ``bits``' threshold in force if it changed since the last line."""
        threshold_db, last = bits.threshold_db, self.logged_db
        if threshold_db is None or threshold_db == last:
            return  # no threshold (vad, calibrating: its end is logged), or the same one
        origin = bits.threshold_origin()
        if last is not None and origin.startswith("noise floor") and (
            abs(threshold_db - last) < NOISE_FLOOR_LOG_STEP_DB
        ):
            return
        self.logged_db = threshold_db
        self.logger.info(f"threshold in force: {threshold_db:.2f} dB ({origin}; bit_source"
                         f" {self.bit_source})")  # fmt: skip


class MicNode(GraphNode):
    """Microphone: audio windows to sound bits."""

    NODE_NAME = "mic_node"
    WATCHED_TOPICS = ("sound", SOUND_STEP)

    def configure(self) -> None:
        """Parameters, the bit source, the window source (a replay calibrated ahead)."""
        self.config = config = read_config(self.parameters)
        self.threshold_log = ThresholdLog(self.get_logger(), config.bit_source)
        self.bits = make_bits(config, self._calibration_refused)
        if config.bit_source != DEFAULT_BIT_SOURCE:
            summary = BIT_SOURCES[config.bit_source].summary
            self.get_logger().info(f"bit source {config.bit_source}: {summary}")
        self.source = open_window_source(config, self.bits.needs_samples, self.log_at)
        self.replay = self.source if self.source.replay else None
        self.recorded_bits = getattr(self.source, "has_audio", True) is False
        if self.recorded_bits and config.bit_source != DEFAULT_BIT_SOURCE:
            ignored = f"bit_source {config.bit_source} is not applied"
            self.get_logger().warning(f"{ignored}: {self._no_audio}")
        if calibrated := self._calibrate_ahead():
            self.get_logger().info(calibrated)
            self.threshold_log.logged_db = self.bits.threshold_db  # that line names it
        lockstep = self.replay is not None and config.lockstep
        self.pacer = LockstepPacer(config.lockstep_timeout_s) if lockstep else None
        for spec in self.bits.specs():
            if spec.live:
                self._make_live(spec.name)
        self.stream_id = new_source_id()
        self.window_us = window_us(config.window_s)
        self.outbox = StepOutbox(
            config.max_steps_ahead, max(1, round(config.max_backlog_s / config.window_s))
        )
        self.windows = 0
        self.last_energy_db = float("nan")
        self.bad_chunks = 0
        self.started = self.ended = False
        self.losses = self.recent_events()
        self.timeouts = self.recent_events()
        audio = self.resolve_topic_name("audio")
        self.contract = AudioContract(config.audio_rate_hz, self.fault_hold_s, publishers=lambda: [
            info.node_name for info in self.get_publishers_info_by_topic(audio)])
        if self.replay is not None:
            self.get_logger().info(
                f"replaying {self.source.describe()},"
                f" {'lockstep' if self.pacer else 'real time'}"
                f"{', looping' if getattr(self.source, 'loop', False) else ''}"
            )

    def activate(self) -> None:
        """Publishers, the decisions (and audio) subscriptions, ~/recalibrate, the start gate."""
        self.sound_pub = self.create_publisher(Bool, "sound", STREAM_QOS)
        self.step_pub = self.create_publisher(Int64MultiArray, SOUND_STEP, STREAM_QOS)
        self.energy_pub = self.create_publisher(Float32, "sound_energy", STREAM_QOS)
        self._decisions_sub = self.subscribe(
            Int64MultiArray, VOCALIZE_STEP, self._on_decision, STEP_READER_QOS
        )
        self.self_sound = SelfSoundInput(self, self.config.self_sound_hold_s,
                                         self.config.window_s, self._release)  # fmt: skip
        if isinstance(self.source, TopicWindows):
            self.create_subscription(Float32MultiArray, "audio", self._on_audio, AUDIO_QOS)
            self.wait_visibly(
                "audio",
                f"std_msgs/Float32MultiArray, mono samples at {self.source.rate_hz} Hz: start an"
                " audio driver or fake_audio_node (launch use_fake_room:=true), or set source"
                " to wav or sounddevice",
            )
        self.create_service(Trigger, "~/recalibrate", self._on_recalibrate)
        self._pace_timer = None
        self.start_when_ready(
            self._listeners_ready,
            self.config.start_delay_s,
            self._start,
            self.pacer,
            self._on_timeout,
            "is controller_node running?",
            f"{self.config.wait_for_listeners} listeners on '{SOUND_STEP}'",
        )
        self.get_logger().info(f"stream id {self.stream_id}")
        self.threshold_log(self.bits)

    def destroy_node(self) -> None:
        """Release the microphone, then the node."""
        source = getattr(self, "source", None)
        if source is not None:
            source.close()
        super().destroy_node()

    # ------------------------------------------------------------------ bit source

    def _calibration_refused(self, message: str) -> None:
        self.get_logger().warning(message)

    @property
    def _no_audio(self) -> str:
        return f"the session {self.config.bag_dir} holds no audio, its recorded bits are replayed"

    def _calibrate_ahead(self) -> str:
        """Calibrate the bit source on a replay's first seconds if it calibrates; what it did."""
        if self.replay is None or self.recorded_bits or not self.bits.read_ahead_s:
            return ""
        ahead = self.replay.read_ahead(self.bits.read_ahead_s, self.config.window_s)
        return f"{self.bits.calibrate_ahead(*ahead)} of the replay"

    def _make_live(self, name: str) -> None:
        """Let the bit-source setting ``name`` change live, checked by the bit source."""

        def check(value: Any) -> None:
            if self.recorded_bits:
                raise ConfigError(f"parameter {name!r} = {value!r} has no effect: {self._no_audio}")
            try:
                self.bits.check_live(name, value)
            except SettingError as error:
                raise ConfigError(f"parameter {error}") from None

        def apply(value: Any) -> None:
            self.bits.set_live(name, value)
            self.threshold_log(self.bits)

        self.parameters.live(name, apply, check)

    def _on_recalibrate(self, _request: Trigger.Request, response: Trigger.Response) -> Any:
        """Start the bit source's calibration again (a replay's first seconds again)."""
        response.success = False
        if self.recorded_bits:
            response.message = f"nothing to calibrate: {self._no_audio}"
            return response
        try:
            message = self.bits.recalibrate()
            message = self._calibrate_ahead() or message
        except AudioError as error:
            response.message = str(error)
            return response
        self.get_logger().info(f"recalibrate: {message}")
        self.threshold_log(self.bits)
        response.success, response.message = True, message
        return response

    # ------------------------------------------------------------------ start gate

    def _listeners_ready(self) -> bool:
        if self.step_pub.get_subscription_count() < self.config.wait_for_listeners:
            return False
        return self.pacer is None or self._decisions_sub.get_publisher_count() > 0

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
        self.get_logger().info(f"end of {self.replay.describe()} after {self.windows} windows")
        if self.config.exit_at_end:
            self._finish_publishing()

    def _on_audio(self, msg: Float32MultiArray, info: dict[str, Any]) -> None:
        self.count_arrival("audio")
        if 0 < int(info.get("source_timestamp", 0)) < self.started_ns:
            self.stale_messages += 1  # published before this node started
            return
        sent_s = self.sent_s(int(info.get("source_timestamp", 0)), self.contract.clock())
        for warning in self.contract.check(msg.data, msg.layout.dim, sent_s):
            self.get_logger().warning(warning)
        sequence = info.get("publication_sequence_number")
        try:
            missed = self.source.feed(
                np.frombuffer(msg.data, dtype=np.float32),
                sequence if isinstance(sequence, int) else None,
                int(info.get("source_timestamp", 0)) or self.get_clock().now().nanoseconds,
            )
        except AudioError as error:
            self.bad_chunks += 1
            self.losses.note(self.now_s())
            self.log_throttled("bad chunk", "warning", f"audio chunk ignored: {error}")
            return
        if missed:
            self.losses.note(self.now_s())
            self.contract.chunks_lost()
        for window in self.source.take():
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

        A window with a recorded bit (a session bag without audio) keeps it. Returns the
        bit (None for a calibration window).
        """
        if window.recorded_bit is not None:
            bit: bool | None = window.recorded_bit
            energy_db = window.energy_db
        else:
            was_calibrating = self.bits.calibrating
            bit = self.bits.bit_of(window.energy_db, window.samples)
            energy_db = self.bits.last_energy_db
            # a calibration's end, an accepted refit, a moving noise floor
            self.threshold_log.after_window(self.bits, was_calibrating)
        self.last_energy_db = energy_db
        if bit is None:  # a calibration window: its energy only
            self.energy_pub.publish(Float32(data=energy_db))
            return None
        self.self_sound.push(window, energy_db, bit)
        self._release()
        return bit

    def _on_decision(self, msg: Int64MultiArray, stamp: int) -> None:
        decision = parse_decision(msg)
        if decision is None or decision.stream != self.stream_id:
            return
        before = self.outbox.last_answered
        self.outbox.answered(decision.step)
        if self.outbox.last_answered == before:
            return  # a repeated answer (a second controller): it releases nothing
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
        if self.outbox.dropped > dropped:
            self.losses.note(self.now_s())
            self.log_throttled("windows dropped", "warning",
                               f"{self.outbox.dropped} windows dropped: more than"
                               f" {self.config.max_backlog_s:g} s waited for the controller")
        if not self.started or self.finished.done():
            return
        outbox = self.outbox
        # Pacing matters only when more would go out than may be unanswered: only then ask
        # the graph whether a controller answers (one query per window is measurable).
        paced = (
            outbox.in_flight + outbox.backlog > outbox.max_ahead
            and self._decisions_sub.get_publisher_count() > 0
        )
        for step, (energy_db, bit, withheld) in self.outbox.release(paced):
            self.windows += 1
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

    # ------------------------------------------------------------------ diagnostics

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Threshold, windows, steps, losses, lockstep timeouts, the live device."""
        bits, now = self.bits, self.now_s()
        values: dict[str, Any] = {
            "source": self.config.source,
            "stream": self.stream_id,
            "windows": self.windows,
            "steps_answered": self.outbox.last_answered,
            "steps_waiting": self.outbox.backlog,
            "windows_dropped": self.outbox.dropped,
            "bit_source": self.config.bit_source,
            "last_energy_db": self.last_energy_db,
            "dropped_chunks": getattr(self.source, "dropped_chunks", 0),
            "bad_chunks": self.bad_chunks,
            **bits.diagnostic_values(),
            **self.source.status(),
            **self.self_sound.values(),
            **self.contract.values(),  # none before the first chunk of 'audio'
        }
        for topic, names in self.intruders.items():
            values[f"publishers_{topic}"] = ", ".join(names)
        if self.pacer is not None:
            values["lockstep_timeouts"] = self.pacer.timeouts
        if self.intruders:
            return ERROR, "another publisher on 'sound' or 'sound_step'", values
        if not self.started:
            wanted = self.config.wait_for_listeners
            return WARN, f"waiting for {wanted} listeners on '{SOUND_STEP}'", values
        if values.get("state") == DISCONNECTED:
            return ERROR, f"microphone disconnected, retrying: {values['last_error']}", values
        if bits.state == UNSEPARATED:
            return ERROR, bits.problem, values
        if bits.calibrating:
            return OK, "calibrating the threshold", values
        problem = self.contract.problem()  # the 'audio' contract broken lately
        if problem or self.losses.recent(now) or self.timeouts.recent(now) or (
                self.self_sound.faults.recent(now)):  # fmt: skip
            problem = problem or ("audio lost, lockstep timeouts, or 'self_sound' ranges refused"
                                  " or late lately (counts in the values)")  # fmt: skip
            return WARN, problem, values
        return OK, f"{self.windows} windows", values


def main(args: list[str] | None = None) -> int:
    """Run the mic node."""
    return run_node(MicNode, args)


if __name__ == "__main__":
    sys.exit(main())

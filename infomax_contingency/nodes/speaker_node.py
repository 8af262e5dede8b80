"""speaker_node: plays the robot's sound when the controller the graph follows decides so.

The sound is the robot's chirp (:func:`~infomax_contingency.audio.synth.synthesize_chirp`,
``duration_s`` long) or the WAV file ``sound_file``, scaled by ``volume``, played through
:class:`~infomax_contingency.audio.playback.SpeakerOutput` on ``device`` (empty: the system
default output; an index; or a part of the device's name, first match). The output
stream runs all the time (playing silence), so a command starts the sound at the next
10 ms block without blocking the node. Commands never queue up: one that comes while
the sound still plays starts it again (``overlap`` ``restart``) or is ignored
(``skip``). A device that vanishes is reopened on a later command (at most every 2 s).
A device that is not there at start-up stops the node with the list of output devices.

With ``dry_run`` (the default, for machines without a loudspeaker) no device is opened:
vocalizations are only counted and logged at debug level. ``dry_run`` is live: false
opens the loudspeaker at once (a device that cannot be opened refuses the set with the
start-up message), true closes it; the next ``vocalize`` follows the new value.

The command is a decision on ``vocalize_step`` (``[stream, step, vocalize, controller]``,
see :mod:`~infomax_contingency.nodes.step_topics`) with ``vocalize`` 1, so the robot
sounds exactly the decisions the belief node and the fake room follow: the node follows
one controller (:class:`~infomax_contingency.core.stepclock.SourceLock`, as they do: the
first heard; a second one is named, counted and not played; a followed one silent for
``source_timeout_s`` is replaced by the next one heard, a restarted controller_node),
plays each step once (a repeated step is ignored), and ignores a step that jumps further
ahead than the stream's pace allows (:class:`~infomax_contingency.core.stepclock.StepPace`).
The plain ``vocalize`` (Bool) is for people; a second publisher on it is named too.

Subscribes ``vocalize_step`` (Int64MultiArray). Publishes ``speaker_started``
(builtin_interfaces/Time, reliable): for every sound played, the time its first sample
reached the loudspeaker (PortAudio's DAC time, on the node's clock like any message
stamp), so the self-feedback delay can be measured against the microphone; nothing in
dry run. And ``/diagnostics``: device, rate, vocalizations, sounds played, interrupted
and skipped, underflows, output errors, and ``start_delay_s`` (from the last command to
its sound's start).
"""

from __future__ import annotations

import sys
import time
from typing import Any

from builtin_interfaces.msg import Time as TimeMsg
from rclpy.time import Time
from std_msgs.msg import Int64MultiArray

from infomax_contingency.audio.devices import CONNECTED, AudioDeviceError
from infomax_contingency.audio.playback import OVERLAP_POLICIES, SpeakerOutput
from infomax_contingency.audio.wav import read_wav
from infomax_contingency.core.flowcontrol import SOURCE_TIMEOUT_S
from infomax_contingency.core.stepclock import (
    Arrival,
    SourceLock,
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
from infomax_contingency.nodes.parameters import ConfigError, device_parameter
from infomax_contingency.nodes.qos import STEP_READER_QOS, STREAM_QOS
from infomax_contingency.nodes.runtime import run_node
from infomax_contingency.nodes.step_topics import (
    NO_STEP,
    VOCALIZE_STEP,
    StepDecision,
    parse_decision,
)

EVENTS_POLL_S = 0.01
"""Seconds between checks for sounds that started, while a loudspeaker is open (a dry run
plays nothing and does not check: the checks cost an idle node about 7 % of a core)."""


class SpeakerNode(GraphNode):
    """Speaker: the robot's voice."""

    NODE_NAME = "speaker_node"
    WATCHED_TOPICS = ("vocalize", VOCALIZE_STEP)

    def configure(self) -> None:
        """Declare and check the parameters; the state they set."""
        read = self.parameters
        self.dry_run = read.flag(
            "dry_run", True, "Only count vocalizations, play nothing (live)", read_only=False
        )
        self.device = device_parameter(self, "Loudspeaker (without dry_run)")
        sound_file = read.text("sound_file", "", "WAV file to play; empty = the robot's chirp")
        volume = read.number(
            "volume",
            0.5,
            "Gain of the sound (the chirp's peak amplitude; full scale = 1)",
            0.001,
            1.0,
        )
        duration_s = read.number(
            "duration_s", 0.2, "Length of the robot's chirp (without sound_file)", 0.01, 5.0, "s"
        )
        overlap = read.text(
            "overlap",
            "restart",
            "A vocalization while the sound still plays: restart the sound, or skip the command",
            OVERLAP_POLICIES,
        )
        timeout_s = read.number(
            "source_timeout_s", SOURCE_TIMEOUT_S,
            "A followed controller silent this long is replaced by the next one heard",
            0.1, 3600.0, "s",
        )
        self.controllers = SourceLock(timeout_s)
        self.pace = StepPace(1.0 / read.model().dt, timeout_s)  # one step per window: dt
        self.writer = WriterSequence()
        self._answered = (0, 0)
        """The last step played or passed: (stream, step)."""
        self.sound = {
            "sound": sound_file or None,
            "duration_s": duration_s,
            "volume": volume,
            "overlap": overlap,
        }
        self.requests = 0
        self.start_delay_s = float("nan")
        self._errors_reported = 0
        self.speaker: SpeakerOutput | None = None
        self._opened: SpeakerOutput | None = None
        """A loudspeaker opened by a live ``dry_run`` false, until the set applies."""
        if self.dry_run and sound_file:
            read_wav(sound_file)  # a bad file is refused in a dry run too
        self.output_errors = self.recent_events()
        self.foreign = self.recent_events()
        self.jumps = self.recent_events()

    def activate(self) -> None:
        """Publishers, subscriptions, services and timers."""
        self.started_pub = self.create_publisher(TimeMsg, "speaker_started", STREAM_QOS)
        if self.dry_run:
            self.get_logger().info("dry run: vocalizations are counted, not played")
        else:
            self.speaker = self._open_speaker()
        self._starts_timer = self.create_timer(
            EVENTS_POLL_S, self._publish_starts, autostart=self.speaker is not None
        )
        self.parameters.live("dry_run", self._set_dry_run, self._check_dry_run)
        self.subscribe(Int64MultiArray, VOCALIZE_STEP, self._on_decision, STEP_READER_QOS)
        count_only(self, Int64MultiArray, NO_STEP)  # decisions paused, not stopped
        self.wait_visibly(VOCALIZE_STEP, "the decisions of controller_node: is it running?",
                          companions=(NO_STEP,))  # fmt: skip

    def _on_decision(self, msg: Int64MultiArray, stamp: int) -> None:
        decision = parse_decision(msg)
        if decision is None:
            return
        now = self.now_s()
        sent = self.sent_s(stamp, now)
        arrival = self.controllers.accept(decision.controller, sent)
        if arrival is Arrival.FOREIGN:
            self.foreign.note(now)
            self.warn_intrusion(
                f"not playing the decisions of controller {decision.controller} (a second"
                f" controller_node?): following controller {self.controllers.source}"
            )
            return
        if arrival is not Arrival.FOLLOWED or decision.stream != self._answered[0]:
            self.pace.restart()
            self.writer.restart()
        source = f"controller {decision.controller}"
        taken = take_on_pace(self, self.pace, self.jumps, decision.step, sent, decision,
                             "decision", source)  # fmt: skip
        taken = take_from_writer(self, self.writer, self.foreign, taken, decision.step,
                                 self.sequence, source)  # fmt: skip
        if taken:  # a run taken after a jump is in the past: only its newest may sound
            self._obey(taken[-1])

    def _obey(self, decision: StepDecision) -> None:
        """Play the sound if the followed controller decided so for a step not yet heard."""
        stream, step = self._answered
        if decision.stream == stream and decision.step <= step:
            return  # a step repeated
        self._answered = (decision.stream, decision.step)
        if not decision.vocalize:
            return
        self.requests += 1
        if self.speaker is None:
            self.get_logger().debug("vocalize (dry run)")
            return
        if self.speaker.play() is None:
            self.log_throttled(
                "cannot play", "error", f"cannot play: {self.speaker.status().last_error}"
            )

    def _open_speaker(self) -> SpeakerOutput:
        """The loudspeaker ``device``, started; ConfigError (the start-up message) if it fails."""
        speaker = SpeakerOutput(self.device or None, log=self.log_at, **self.sound)
        try:
            return speaker.start()
        except AudioDeviceError as error:
            raise ConfigError(
                f"parameter 'device' = {self.device!r}: {error}\n"
                "(dry_run:=true runs the node without a loudspeaker)"
            ) from None

    def _check_dry_run(self, dry_run: bool) -> None:
        """Leaving the dry run needs the loudspeaker: it is opened here (kept for the set)."""
        if not dry_run and self.speaker is None and self._opened is None:
            self._opened = self._open_speaker()

    def _set_dry_run(self, dry_run: bool) -> None:
        """Dry run (close the loudspeaker) or play (the one opened by the check)."""
        self.dry_run = dry_run
        if dry_run and self.speaker is not None:
            self.speaker.close()
            self.speaker = None
            self._starts_timer.cancel()
            self.get_logger().info("dry run: the loudspeaker is closed")
        elif not dry_run and self.speaker is None:
            self.speaker, self._opened = self._opened, None
            self._starts_timer.reset()
            self.get_logger().info("playing vocalizations on the loudspeaker")

    def _publish_starts(self) -> None:
        """Publish the start time of every sound that started since the last call."""
        if self.speaker is None:
            return
        events = self.speaker.events(0.0)
        if not events:
            return
        now_ns = self.get_clock().now().nanoseconds
        now_s = time.monotonic()
        for event in events:
            started_ns = now_ns - round((now_s - event.start_time) * 1e9)
            self.started_pub.publish(Time(nanoseconds=started_ns).to_msg())
            self.start_delay_s = event.start_time - event.requested_time

    def destroy_node(self) -> None:
        """Release the loudspeaker, then the node."""
        for speaker in (self.speaker, self._opened):
            if speaker is not None:
                speaker.close()
        super().destroy_node()


    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Device, vocalizations, sounds played, output errors, start delay, intruders."""
        values: dict[str, Any] = {
            "dry_run": self.dry_run,
            "requests": self.requests,
            "controller": self.controllers.source or "none yet",
            "foreign_decisions": self.controllers.foreign_messages,
            "jumps_ignored": self.pace.jumps,
        }
        if self.intruders:
            topics = ", ".join(f"'{topic}'" for topic in self.intruders)
            return ERROR, f"more than one publisher on {topics}", values
        if self.foreign.recent(self.now_s()):
            return ERROR, "decisions of a second controller (not played)", values
        if self.jumps.recent(self.now_s()):
            return ERROR, "decisions jumping ahead of the stream's pace (ignored)", values
        if self.speaker is None:
            values["played"] = 0
            return OK, f"{self.requests} vocalizations (dry run)", values
        status = self.speaker.status()
        values.update(status.as_dict())
        values["start_delay_s"] = self.start_delay_s
        self.output_errors.note(self.now_s(), status.errors - self._errors_reported)
        new_errors = status.errors > self._errors_reported
        self._errors_reported = status.errors
        if status.state != CONNECTED:
            return (
                ERROR,
                f"speaker unavailable (retried on a vocalization): {status.last_error}",
                values,
            )
        if new_errors:
            return ERROR, f"output errors: {status.last_error}", values
        if self.output_errors.recent(self.now_s()):
            return WARN, f"{status.errors} output errors, {status.underflows} underflows", values
        return OK, f"{status.played} sounds played for {self.requests} vocalizations", values


def main(args: list[str] | None = None) -> int:
    """Run the speaker node."""
    return run_node(SpeakerNode, args)


if __name__ == "__main__":
    sys.exit(main())

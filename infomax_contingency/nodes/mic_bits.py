"""mic_node's hold on its bit source: how it is made, calibrated ahead, set live, recalibrated.

:class:`BitSourceControls` makes the bit source of mic_node's configuration, calibrates it
on a replay's first seconds, lets its live settings change (``ros2 param set``, checked by
the source), answers ``~/recalibrate`` (std_srvs/Trigger) and logs the threshold in force
whenever it changes (:class:`ThresholdLog`). A session bag without audio replays its
recorded bits: then every one of these is refused, with the reason. It also says each
window that gives no step (the source calibrating or warming up) on ``no_step``
(``[stream, window]``), on which a lockstep room releases its next window; and it holds
the ``audio`` topic's windows of a source that labels windows by the decisions until the
decisions on the bits before them are in (:meth:`BitSourceControls.decidable`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from std_msgs.msg import Int64MultiArray
from std_srvs.srv import Trigger

from infomax_contingency.audio.background import DigitalSilenceWatch
from infomax_contingency.audio.bitsources import BIT_SOURCES, DEFAULT_BIT_SOURCE
from infomax_contingency.audio.bitsources.base import BitSource, SettingError
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.windows import SourceWindow, WindowSource
from infomax_contingency.core.flowcontrol import StepOutbox
from infomax_contingency.core.selfsound import GapWithholding
from infomax_contingency.nodes import mic_config
from infomax_contingency.nodes.graph_node import GraphNode
from infomax_contingency.nodes.parameters import ConfigError
from infomax_contingency.nodes.qos import STREAM_QOS
from infomax_contingency.nodes.step_topics import (
    NO_STEP,
    STEP_APPLIED,
    VOCALIZE_STEP,
    NoStep,
    no_step_message,
)

NOISE_FLOOR_LOG_STEP_DB = 1.0
"""A threshold that follows the room is logged again only once it moved this much, dB."""

ROOM_LOG_PERIOD_S = 60.0
"""A threshold that follows the room is logged again at most this often: seconds of audio
and seconds of the clock alike (a lockstep replay runs many times faster than the audio).
Every value is in the diagnostics (``threshold_db``)."""


class ThresholdLog:
    """Logs (INFO) the threshold in force, and where it came from, when it changed.

    mic_node calls it wherever the threshold can change: at start-up, after each window
    (the end of a calibration, an accepted refit, the noise floor), after a live set and a
    ~/recalibrate. A threshold that follows the room window by window (the noise floor;
    the room's background windows, bit source ``background``, whose threshold swings tens
    of dB in a lively room) is logged again only once it moved by
    :data:`NOISE_FLOOR_LOG_STEP_DB` and at most once per :data:`ROOM_LOG_PERIOD_S` of audio
    and of the clock; the diagnostics show every value (``threshold_db``), and
    :attr:`unsaid` counts the changes not logged.

    Args:
        logger: where the lines go.
        bit_source: the bit source's name, for the line.
        window_s: the window length, seconds (the audio's time).
        clock: monotonic seconds (the clock's time).
    """

    def __init__(self, logger: Any, bit_source: str, window_s: float,
                 clock: Callable[[], float]) -> None:  # fmt: skip
        self.logger = logger
        self.bit_source = bit_source
        self.window_s = window_s
        self.clock = clock
        self.period_s = ROOM_LOG_PERIOD_S
        self.logged_db: float | None = None
        """The threshold last logged, dB (set it when another line named the threshold)."""
        self.unsaid = 0
        """Changes of a threshold that follows the room not logged (too soon, too small)."""
        self._audio_s = 0.0  # audio since the last line, seconds
        self._said_at = -math.inf  # the clock at the last line
        self._seen_db: float | None = None  # the threshold at the last call

    def after_window(self, bits: BitSource, was_calibrating: bool) -> None:
        """After a window: the end of a calibration, or a threshold that changed (a refit).

        The window that completes a calibration (or the noise floor's warm-up) yields no
        bit itself; its end is logged with the source's ready line (the threshold and
        the clusters or floor it came from), which counts as the threshold's line.
        """
        self._audio_s += self.window_s
        if was_calibrating and not bits.calibrating:
            self.logger.info(bits.ready_message())
            self.said(bits.threshold_db)
            return
        self(bits)

    def __call__(self, bits: BitSource) -> None:
        """Log ``bits``' threshold in force if it changed since the last line (see above)."""
        threshold_db, last = bits.threshold_db, self.logged_db
        changed, self._seen_db = threshold_db != self._seen_db, threshold_db
        if threshold_db is None or threshold_db == last:
            return  # no threshold (vad, calibrating: its end is logged), or the same one
        origin = bits.threshold_origin()
        follows_the_room = origin.startswith(("noise floor", "room:"))
        if last is not None and follows_the_room and (
            abs(threshold_db - last) < NOISE_FLOOR_LOG_STEP_DB
            or min(self._audio_s, self.clock() - self._said_at) < self.period_s
        ):
            self.unsaid += changed
            return
        self.said(threshold_db)
        again = (f"; it follows the room: said again at most every {self.period_s:g} s, every"
                 " value in the diagnostics' threshold_db" if follows_the_room else "")
        self.logger.info(f"threshold in force: {threshold_db:.2f} dB ({origin}; bit_source"
                         f" {self.bit_source}{again})")  # fmt: skip

    def said(self, threshold_db: float | None) -> None:
        """A line named ``threshold_db`` (dB) now: the next is measured from it."""
        self.logged_db, self._audio_s, self._said_at = threshold_db, 0.0, self.clock()
        self._seen_db = threshold_db


class BitSourceControls:
    """mic_node's bit source and what acts on it (see the module docstring).

    Args:
        node: the mic_node (its logger and parameters).
        config: its configuration.
    """

    def __init__(self, node: GraphNode, config: mic_config.MicConfig) -> None:
        self.node = node
        self.config = config
        self.threshold_log = ThresholdLog(node.get_logger(), config.bit_source, config.window_s,
                                          lambda: node.now_s())  # fmt: skip
        self.bits: BitSource = mic_config.make_bits(config, node.get_logger().warning)
        if unread := mic_config.unread_threshold_file(node.parameters, config):
            node.get_logger().warning(unread)
        if config.bit_source != DEFAULT_BIT_SOURCE:
            summary = BIT_SOURCES[config.bit_source].summary
            node.get_logger().info(f"bit source {config.bit_source}: {summary}")
        self.replay: WindowSource | None = None
        self.recorded_bits = False
        """True for a session bag without audio: its recorded bits are replayed."""
        self.withheld_steps: set[int] = set()
        """Steps published withheld (the robot's own sound) whose decision is awaited."""
        self.windows = 0
        """Windows made from the source so far, stepped or not (``no_step`` numbers them)."""
        self.windows_without_step = 0
        """Windows that gave no step (calibration, warm-up), each said on ``no_step``."""
        self.stream = 0
        self.no_step_pub: Any = None
        self.held: deque[SourceWindow] = deque()
        """Windows of the ``audio`` topic waiting for the decisions before them."""
        self._held_since: float | None = None
        self._forced = 0  # held windows at the front to be decided without waiting
        self.decided_without_wait = 0
        """Held windows decided before the decisions on the bits before them came."""
        self.answers_lost = node.recent_events()
        """When steps were last taken as answered, their decisions lost (:meth:`give_up`)."""
        self.silence = DigitalSilenceWatch(config.window_s)
        """Says when the input is digital silence (a dead microphone), and when it is not."""
        self.gap = GapWithholding(config.params.ta2 + 1)
        """Bits withheld right after a gap (:meth:`gap_before`, :meth:`released`)."""
        self._gap_next = False  # windows gave no step since the last window with a bit
        self._drop_gap = False  # windows were dropped from the outbox since the last step

    def activate(self, stream: int) -> None:
        """The ``no_step`` publisher of mic_node's ``stream``."""
        self.stream = stream
        self.no_step_pub = self.node.create_publisher(Int64MultiArray, NO_STEP, STREAM_QOS)

    def bit_of(self, window: SourceWindow) -> tuple[bool | None, float]:
        """The window's bit (None: no step, calibration audio) and energy (dB).

        A window with a recorded bit (a session bag without audio) keeps it. A threshold
        that changed (a calibration's end, an accepted refit, a moving noise floor) is
        logged.
        """
        self.windows += 1
        if window.recorded_bit is not None:
            return window.recorded_bit, window.energy_db
        if said := self.silence.push(window.samples, window.energy_db):
            if self.silence.dead:  # rclpy wants one severity per call site
                self.node.get_logger().warning(said)
            else:
                self.node.get_logger().info(said)
        was_calibrating = self.bits.calibrating
        bit = self.bits.bit_of(window.energy_db, window.samples)
        self.threshold_log.after_window(self.bits, was_calibrating)
        return bit, self.bits.last_energy_db

    def hold(self, windows: Iterable[SourceWindow], max_held: int) -> None:
        """Windows of the ``audio`` topic, to be decided in order (:meth:`decidable`).

        Beyond ``max_held`` windows waiting (a burst), the oldest are decided now.
        """
        self.held.extend(windows)
        self._forced = max(self._forced, len(self.held) - max_held)

    def decidable(self) -> Iterator[SourceWindow]:
        """The held windows whose bits may be decided now, one at a time, in order.

        A source that labels windows by the decisions (``background``) decides a window's
        bit with the decisions on the bits before it known, as the offline loop does: in
        lockstep the room's next window may reach mic_node before the decision on the last
        one (DDS orders no topic against another). A window waits for them at most
        ``lockstep_timeout_s``, and not at all while no controller publishes.
        """
        while self.held:
            if self._forced:
                self._forced -= 1
                self._early("more windows waited than max_backlog_s holds")
            elif self._learns_from_decisions and getattr(self.bits, "awaited_decisions", 0):
                now = self.node.now_s()
                self._held_since = now if self._held_since is None else self._held_since
                if self.node.count_publishers(VOCALIZE_STEP) == 0:
                    pass  # no controller: nothing to wait for
                elif now - self._held_since < self.config.lockstep_timeout_s:
                    return
                else:
                    self._early(f"no decision within {self.config.lockstep_timeout_s:g} s")
            self._held_since = None
            yield self.held.popleft()

    def _early(self, why: str) -> None:
        """A held window is decided before the decisions on the bits before it came."""
        self.decided_without_wait += 1
        self.node.log_throttled("decided early", "warning", f"a window's bit decided before"
                                f" the decisions on the bits before it ({why}): its bit may"
                                " differ from the offline loop's")  # fmt: skip

    def values(self) -> dict[str, float]:
        """Diagnostic values: digital silence (s), windows without a step, held, decided early."""
        return {"digital_silence_s": self.silence.silent_run * self.silence.window_s,
                "threshold_changes_unlogged": self.threshold_log.unsaid,
                "windows_without_step": self.windows_without_step,
                "bits_withheld_after_gap": self.gap.withheld,
                "windows_held": len(self.held),
                "windows_decided_early": self.decided_without_wait}  # fmt: skip

    def say_no_step(self) -> None:
        """The last window gave no step: say so on ``no_step`` (a lockstep room goes on)."""
        self.windows_without_step += 1
        self.no_step_pub.publish(no_step_message(NoStep(self.stream, self.windows)))
        if self.gap.bits and not self._gap_next:
            self._log_gap("gave no step (the bit source calibrating, or out of range)")
        self._gap_next = True

    def gap_before(self, window: SourceWindow) -> bool:
        """True if windows gave no step or audio was lost right before ``window`` (a bit)."""
        if window.gap_s > 0 and self.gap.bits:
            lost = ("audio of unknown length: a new writer on 'audio'" if math.isinf(window.gap_s)
                    else f"{window.gap_s:.2f} s of audio")  # fmt: skip
            self._log_gap(f"were lost ({lost})")
        gap, self._gap_next = self._gap_next or window.gap_s > 0, False
        return gap

    def _log_gap(self, what: str) -> None:
        self.node.log_throttled(
            "gap", "info",
            f"windows after step {self.gap.bits} {what}: up to {self.gap.steps} bits after"
            " them go out withheld (a step's timer may lag its window's until then)",
        )  # fmt: skip

    def use_source(self, source: WindowSource) -> None:
        """Take the window source: calibrate on a replay's start, make the settings live."""
        self.replay = source if source.replay else None
        self.recorded_bits = getattr(source, "has_audio", True) is False
        if self.recorded_bits and self.config.bit_source != DEFAULT_BIT_SOURCE:
            ignored = f"bit_source {self.config.bit_source} is not applied"
            self.node.get_logger().warning(f"{ignored}: {self._no_audio}")
        if calibrated := self._calibrate_ahead():
            self.node.get_logger().info(calibrated)
            self.threshold_log.said(self.bits.threshold_db)  # that line names it
        for spec in self.bits.specs():
            if spec.live:
                self._make_live(spec.name)

    @property
    def _learns_from_decisions(self) -> bool:
        return self.bits.needs_decisions and not self.recorded_bits

    def decided(self, last_answered: int, step: int, vocalize: bool | None) -> None:
        """The decision on ``step`` came (the last answered before it: ``last_answered``).

        A source that labels windows by the decisions (``background``) gets each one in
        step order, and so does the withholding after gaps; a step skipped between the two
        lost its decision (None), as every one does with ``vocalize`` None (given up).
        """
        for answered in range(last_answered + 1, step + 1):
            u = None if vocalize is None or answered != step else int(vocalize)
            self.gap.decided(answered, u)
            if self._learns_from_decisions:
                self.bits.note_decision(u, answered in self.withheld_steps)
                self.withheld_steps.discard(answered)

    def give_up(self, outbox: StepOutbox, now: float, controllers: Callable[[], int]) -> None:
        """Stop waiting for listeners that took nothing, and for answers that never come.

        A listener on ``step_applied`` that took nothing for ``listener_timeout_s`` is no
        longer waited for. Steps out that no decision came for in as long, while a
        controller publishes (``controllers()``: its count), are taken as answered with
        their decisions lost: a restarted controller never gets the steps published
        before it joined, and would otherwise wait for the next one while mic_node waits
        for its answers.
        """
        for listener in outbox.give_up_stalled(now):
            self.node.stalled_listeners.note(now)
            self.node.get_logger().warning(
                f"listener {listener} on '{STEP_APPLIED}' took no step for"
                f" {outbox.listener_timeout_s:g} s (after step {outbox.listeners[listener].taken}):"
                " no longer waited for (killed or hung?)"
            )
        if outbox.answers_overdue(now) and controllers() > 0:
            first, last = outbox.give_up_answers()
            self.answers_lost.note(now)
            self.decided(first - 1, last, None)
            self.node.get_logger().warning(
                f"no decision on steps {first}..{last} for {outbox.listener_timeout_s:g} s"
                " (a controller killed or restarted?): taken as lost, the stream goes on"
            )

    def dropped(self, windows: int) -> None:
        """``windows`` dropped from the outbox: they never get a decision (a gap)."""
        self._drop_gap = self._drop_gap or windows > 0
        if self._learns_from_decisions:
            for _ in range(windows):
                self.bits.note_decision(None)

    def released(self, step: int, withheld: bool, gap_before: bool) -> bool:
        """``step`` goes out; True if withheld (the robot's own sound, or right after a gap).

        ``gap_before``: :meth:`gap_before` of its window. A withheld step is not the room's.
        """
        after_gap = self.gap.bit(gap_before or self._drop_gap)
        self._drop_gap = False
        withheld = withheld or after_gap
        if withheld and self._learns_from_decisions:
            self.withheld_steps.add(step)
        return withheld

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

        self.node.parameters.live(name, apply, check)

    def on_recalibrate(self, _request: Trigger.Request, response: Trigger.Response) -> Any:
        """``~/recalibrate``: start the calibration again (a replay's first seconds again)."""
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
        self.node.get_logger().info(f"recalibrate: {message}")
        self.threshold_log(self.bits)
        response.success, response.message = True, message
        return response

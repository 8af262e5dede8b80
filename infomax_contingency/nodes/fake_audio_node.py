"""fake_audio_node: a simulated room that publishes the sound a microphone would hear.

The room (:class:`~infomax_contingency.sim.fake_room.FakeRoom`) is chosen by ``room``
(responsive | silent | noisy) and every one of its parameters can be overridden (noise
floor, background events, the robot's own sound, the partner's arrival, departure,
reply probability, delays and level; see :mod:`infomax_contingency.sim.fake_room`).
Deterministic for a given ``seed``. The room's window is the model's dt (``params``).
Every room parameter but ``rate_hz`` is live (``ros2 param set``): it is checked as at
start-up and applies from the next window on
(:meth:`~infomax_contingency.sim.fake_room.FakeRoom.reconfigure`): the partner's schedule
(``partner_arrive_s``, ``partner_leave_s``, in room time), the reply probability, levels,
delays and the rate of background events; sounds already playing or scheduled play out
as they were made.

Pacing: in **lockstep** (the default) the audio of window t+1 is published once the
decision on window t arrived on ``vocalize_step`` — or, for a window that gave mic_node
no step (its bit source calibrating or warming up on the room's background), once
mic_node said so on ``no_step``; or after ``lockstep_timeout_s`` (the warning then names
what is missing; the timeout applies from the first answer on, so a graph still starting
up is waited for) — so the robot's own
sound and the partner's reply land in the right windows however fast the graph runs
(``lockstep_max_speed`` > 0: the next window waits ``window_s / lockstep_max_speed``
after the decision, so the room runs at most that many times real time);
in real time one window is published every ``window_s / speed`` seconds. One message per
window. Publishing starts ``start_delay_s`` after ``audio`` has ``wait_for_listeners``
subscribers, ``partner_present`` ``wait_for_truth_listeners`` (and, in lockstep,
``vocalize`` a publisher) and every subscriber seen on its topics is connected; it
stops after ``max_windows`` windows (0 = never).

The room's robot may speak after its vocalizations (``robot_speech_probability``, a
TTS-like utterance, see :mod:`~infomax_contingency.sim.fake_room`); with
``declare_self_sound`` (the default) the node declares that speech on ``self_sound``, as a
robot's speech node would: just before the audio of each window the speech overlaps, the
time since the previous window's audio went out, which is the time mic_node gives that
window (:class:`~infomax_contingency.core.selfsound.ChunkClock`: room time runs faster
than the clock in lockstep, so the room declares window by window). mic_node then
publishes the window withheld; with ``declare_self_sound`` false the robot's speech is
heard like anyone's.

The room hears the robot through the decisions of one controller (the first heard on
``vocalize_step``; a second one is counted and ignored, a silent one replaced after
``source_timeout_s``), each step once: the same decisions the belief node follows. A
decision whose step jumps further ahead than the stream's pace allows
(:class:`~infomax_contingency.core.stepclock.StepPace`: a forged message) is named and
ignored (diagnostics ERROR), so it cannot make the room drop the true decisions as
repeats.

Subscribes ``vocalize_step`` and, in lockstep, ``no_step`` (std_msgs/Int64MultiArray);
publishes ``audio``
(Float32MultiArray, mono samples in [-1, 1] at ``rate_hz``), ``partner_present`` (Bool,
the ground truth of each window, right after its audio), ``self_sound``
(Int64MultiArray ``[start_ns, end_ns]``) and ``/diagnostics``.
"""

from __future__ import annotations

import array
import dataclasses
import sys
import time
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.publisher import Publisher
from rclpy.timer import Timer
from std_msgs.msg import Bool, Float32MultiArray, Int64MultiArray

from infomax_contingency.core.flowcontrol import SOURCE_TIMEOUT_S
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.stepclock import (
    Arrival,
    LockstepPacer,
    SourceLock,
    StepPace,
    WriterSequence,
)
from infomax_contingency.nodes.graph_node import (
    ERROR,
    OK,
    RELEASED_WINDOW,
    WARN,
    GraphNode,
    take_from_writer,
    take_on_pace,
)
from infomax_contingency.nodes.parameters import ConfigError, ParameterReader
from infomax_contingency.nodes.qos import AUDIO_QOS, STEP_READER_QOS, STREAM_QOS
from infomax_contingency.nodes.runtime import run_node
from infomax_contingency.nodes.step_topics import (
    NO_STEP,
    SELF_SOUND,
    SOUND_STEP,
    VOCALIZE_STEP,
    NoStep,
    StepDecision,
    parse_decision,
    parse_no_step,
    self_sound_message,
)
from infomax_contingency.sim.fake_room import FakeRoom, as_transmitted
from infomax_contingency.sim.room_config import (
    MAX_EVENT_RATE_HZ,
    MAX_ONE_SOUND_S,
    MAX_SYLLABLE_RATE_HZ,
    PRESETS,
    FakeRoomConfig,
    timing_warnings,
)

ROOM_PARAMETERS: tuple[tuple[str, str, float, float, str], ...] = (
    ("noise_floor_db", "RMS level of the background hiss", -150.0, 0.0, "dB"),
    ("event_rate_hz", "Background sound events per second", 0.0, MAX_EVENT_RATE_HZ, "1/s"),
    ("event_level_db", "RMS level of a background event", -150.0, 0.0, "dB"),
    ("event_min_s", "Shortest background event", 0.001, MAX_ONE_SOUND_S, "s"),
    ("event_max_s", "Longest background event", 0.001, MAX_ONE_SOUND_S, "s"),
    ("self_delay_s", "Delay from the start of the window to the robot's sound", 0.0, 10.0, "s"),
    ("self_level_db", "RMS level of the robot's own sound at the microphone", -150.0, 0.0, "dB"),
    ("partner_arrive_s", "Room time the partner arrives; -1 = no partner", -1.0, 1e9, "s"),
    ("partner_leave_s", "Room time the partner leaves; -1 = never", -1.0, 1e9, "s"),
    ("reply_probability", "Probability that the partner answers a vocalization", 0.0, 1.0, ""),
    ("reply_level_db", "RMS level of a reply", -150.0, 0.0, "dB"),
    ("reply_delay_min_s", "Earliest reply start after a vocalization", 0.0, MAX_ONE_SOUND_S, "s"),
    ("reply_delay_max_s", "Latest reply start after a vocalization", 0.0, MAX_ONE_SOUND_S, "s"),
    ("reply_min_s", "Shortest reply", 0.001, MAX_ONE_SOUND_S, "s"),
    ("reply_max_s", "Longest reply", 0.001, MAX_ONE_SOUND_S, "s"),
    ("syllable_rate_hz", "Syllables per second in a reply", 0.1, MAX_SYLLABLE_RATE_HZ, "1/s"),
    ("robot_speech_probability", "Probability that the robot speaks after a vocalization",
     0.0, 1.0, ""),
    ("robot_speech_rate_hz", "Utterances per second the robot says on its own", 0.0,
     MAX_EVENT_RATE_HZ, "1/s"),
    ("robot_speech_delay_s", "Start of the robot's speech after its vocalization", 0.0,
     MAX_ONE_SOUND_S, "s"),
    ("robot_speech_min_s", "Shortest utterance of the robot", 0.001, MAX_ONE_SOUND_S, "s"),
    ("robot_speech_max_s", "Longest utterance of the robot", 0.001, MAX_ONE_SOUND_S, "s"),
    ("robot_speech_level_db", "RMS level of the robot's speech at the microphone", -150.0,
     0.0, "dB"),
)
"""(name, description, low, high, unit) of the room's floating-point parameters."""



@dataclasses.dataclass(frozen=True)
class FakeAudioConfig:
    """fake_audio_node's parameters (see the module docstring and config/robot.yaml)."""

    params: ModelParams
    room_name: str
    room: FakeRoomConfig
    seed: int
    lockstep: bool
    lockstep_timeout_s: float
    speed: float
    lockstep_max_speed: float
    max_windows: int
    wait_for_listeners: int
    wait_for_truth_listeners: int
    start_delay_s: float
    source_timeout_s: float
    declare_self_sound: bool


def _read_room(read: ParameterReader, window_s: float) -> tuple[str, dict[str, Any]]:
    """The room preset's name and the values that override it (rate_hz, ROOM_PARAMETERS).

    The room's window is ``window_s`` (the model's dt, seconds).
    """
    room_name = read.text(
        "room", "responsive", "Room preset the other parameters start from", tuple(PRESETS)
    )
    defaults = FakeRoomConfig.preset(room_name)
    values: dict[str, Any] = {
        "window_s": window_s,
        "rate_hz": read.integer(
            "rate_hz", defaults.rate_hz, "Sample rate of the audio", 1000, 384000
        ),
    }
    for name, description, low, high, unit in ROOM_PARAMETERS:
        values[name] = read.number(
            name, getattr(defaults, name), description + " (live)", low, high, unit,
            read_only=False,
        )  # fmt: skip
    return room_name, values


def _read_pacing(read: ParameterReader) -> dict[str, Any]:
    """When windows go out: lockstep or real time, the start gate, the end, the source."""
    return {
        "lockstep": read.flag(
            "lockstep", True, "Publish window t+1 after the vocalize for window t"
        ),
        "lockstep_timeout_s": read.number(
            "lockstep_timeout_s", 2.0, "Publish the next window anyway after this long (live)",
            0.01, 3600.0, "s", read_only=False,
        ),
        "speed": read.number(
            "speed", 1.0, "Real-time pacing factor (2 = twice as fast)", 0.01, 1000.0
        ),
        "lockstep_max_speed": read.number(
            "lockstep_max_speed", 0.0,
            "In lockstep, at most this many times real time; 0 = as fast as the graph answers",
            0.0, 100000.0,
        ),
        "max_windows": read.integer(
            "max_windows", 0, "Stop after this many windows; 0 = never", 0, 2**31 - 1
        ),
        "wait_for_listeners": read.integer(
            "wait_for_listeners", 1,
            "Subscribers of 'audio' to wait for before the first window", 0, 1000,
        ),
        "wait_for_truth_listeners": read.integer(
            "wait_for_truth_listeners", 0,
            "Subscribers of 'partner_present' to wait for before the first window", 0, 1000,
        ),
        "start_delay_s": read.number(
            "start_delay_s", 0.5, "Extra wait after the listeners are there", 0.0, 60.0, "s"
        ),
        "source_timeout_s": read.number(
            "source_timeout_s", SOURCE_TIMEOUT_S,
            "A followed controller silent this long is replaced by the next one heard",
            0.1, 3600.0, "s",
        ),
        "declare_self_sound": read.flag(
            "declare_self_sound", True,
            "Declare the robot's speech on 'self_sound' (false: it is heard like a partner's)",
        ),
    }  # fmt: skip


def read_config(node: GraphNode) -> FakeAudioConfig:
    """Declare and check fake_audio_node's parameters."""
    read: ParameterReader = node.parameters
    params = read.model()
    room_name, values = _read_room(read, params.dt)
    seed = read.integer("seed", 0, "Random seed (same seed, same room)", 0, 2**31 - 1)
    pacing = _read_pacing(read)
    try:
        room = FakeRoomConfig.preset(room_name, **values)  # the preset's other sources too
    except ValueError as error:
        raise ConfigError(str(error)) from None
    return FakeAudioConfig(params=params, room_name=room_name, room=room, seed=seed, **pacing)


def pacing_description(config: FakeAudioConfig) -> str:
    """How the room is paced, as the start-up line says it."""
    if not config.lockstep:
        return f"real time x{config.speed:g}"
    if config.lockstep_max_speed > 0:
        return f"lockstep, at most x{config.lockstep_max_speed:g} real time"
    return "lockstep"


class FakeAudioNode(GraphNode):
    """Fake audio: a simulated room with or without a responsive partner."""

    NODE_NAME = "fake_audio_node"

    def configure(self) -> None:
        """Declare and check the parameters; the room they describe."""
        self.config = config = read_config(self)
        for warning in timing_warnings(config.room, config.params):
            self.get_logger().warning(f"room timing vs model parameters: {warning}")
        self.params = config.params
        self.room = FakeRoom(config.room, config.seed)
        self._live_room_parameters()
        self.pacer = LockstepPacer(config.lockstep_timeout_s) if config.lockstep else None
        self.parameters.live("lockstep_timeout_s", self._set_lockstep_timeout)
        self.period_s = config.room.window_s / config.speed
        self.max_windows = config.max_windows
        self.wait_for_listeners = config.wait_for_listeners
        self.wait_for_truth_listeners = config.wait_for_truth_listeners
        self.started = False
        self.controllers = SourceLock(config.source_timeout_s)
        self.pace = StepPace(1.0 / config.room.window_s, config.source_timeout_s)
        self.writer = WriterSequence()
        self.jumps = self.recent_events()
        self._window_sent_s: float | None = None
        """When the newest window was published (s, system clock)."""
        self.timeouts = self.recent_events()
        self.foreign = self.recent_events()
        self._answered: tuple[int, int] = (0, 0)
        self._no_step: NoStep = NoStep(0, 0)
        """The newest window mic_node said gave no step."""
        self.no_step_pace = StepPace(1.0 / config.room.window_s, config.source_timeout_s)
        """The step clock's pace rule on ``no_step``'s windows: a forged window far ahead
        would otherwise make every real one look like a repeat."""
        self.windows_without_step = 0
        """Windows released by a ``no_step`` of the window before."""
        self.declare_self_sound = config.declare_self_sound
        self.self_sound_declared = 0
        self._audio_sent_ns: int | None = None
        """ROS time (ns) just after the newest window's audio was published."""
        self.get_logger().info(
            f"room '{config.room_name}' (seed {config.seed}), {pacing_description(config)}"
        )

    def activate(self) -> None:
        """Publishers, the decisions' subscription, the start gate and the held-window timer."""
        config = self.config
        self._held_window: Timer | None = None
        """The timer that publishes the next window ``window_s / lockstep_max_speed`` after
        its decision (None: no cap, the decision publishes it). It runs on the steady
        clock: the cap is in real time, and the system clock may be slewed or stepped."""
        if config.lockstep and config.lockstep_max_speed > 0:
            self._held_window = self.create_timer(
                config.room.window_s / config.lockstep_max_speed, self._release_held_window,
                clock=Clock(clock_type=ClockType.STEADY_TIME), autostart=False,
            )  # fmt: skip
        self.audio_pub = self.create_publisher(Float32MultiArray, "audio", AUDIO_QOS)
        self.truth_pub = self.create_publisher(Bool, "partner_present", STREAM_QOS)
        self.self_sound_pub: Publisher | None = None
        """On ``self_sound`` once the room's robot may speak (and declares it): mic_node
        holds its windows while the topic has a publisher, so there is none before."""
        self._publish_self_sound_if_needed(config.room)
        self.vocalize_sub = self.subscribe(
            Int64MultiArray, VOCALIZE_STEP, self._on_decision, STEP_READER_QOS
        )
        if self.pacer is not None:
            self.subscribe(Int64MultiArray, NO_STEP, self._on_no_step, STEP_READER_QOS)
        self.start_when_ready(
            self._ready,
            config.start_delay_s,
            self._start,
            self.pacer,
            self._on_timeout,
            "are mic_node and controller_node running? (mic_node answers a window with a"
            " bit, whose decision releases the next one, or on 'no_step' while its bit"
            " source hears the room)",
            f"{config.wait_for_listeners} listeners on 'audio'"
            + (f", {config.wait_for_truth_listeners} on 'partner_present'"
               if config.wait_for_truth_listeners else "")
            + (" and a controller on 'vocalize_step'" if self.pacer is not None else ""),
        )

    def _ready(self) -> bool:
        return (
            self.audio_pub.get_subscription_count() >= self.wait_for_listeners
            and self.truth_pub.get_subscription_count() >= self.wait_for_truth_listeners
            and (self.pacer is None or self.vocalize_sub.get_publisher_count() > 0)
        )

    def _start(self) -> None:
        self.started = True
        if self.pacer is None:
            self.create_timer(self.period_s, self._publish_window)
        self._publish_window()

    def _on_timeout(self) -> None:
        self.timeouts.note(self.now_s())
        self.get_logger().warning(
            f"no decision within {self.pacer.timeout_s} s of window {self.room.windows_made}:"
            f" {self._who_is_missing()}; publishing {RELEASED_WINDOW}"
        )
        self._publish_window()

    def _who_is_missing(self) -> str:
        if self.count_publishers(SOUND_STEP) == 0:
            return "mic_node is not running (nothing publishes 'sound_step')"
        if self.count_publishers(VOCALIZE_STEP) == 0:
            return "controller_node is not running (nothing publishes 'vocalize_step')"
        return "mic_node and controller_node are there, but neither a decision nor 'no_step' came"

    def _on_decision(self, msg: Int64MultiArray, stamp: int) -> None:
        decision = parse_decision(msg)
        if decision is None:
            return
        now = self.now_s()
        # Another controller replaces the followed one only once the room's windows have
        # gone unanswered for source_timeout_s (not while the whole graph is paused).
        arrival = self.controllers.accept(
            decision.controller, self.sent_s(stamp, now), self._window_sent_s
        )
        if arrival is Arrival.FOREIGN:
            self.foreign.note(now)
            self.warn_intrusion(
                f"ignoring decisions of controller {decision.controller} (a second"
                f" controller_node?): the room hears controller {self.controllers.source}"
            )
            return
        if arrival is not Arrival.FOLLOWED or decision.stream != self._answered[0]:
            self.pace.restart()
            self.writer.restart()
        source = f"controller {decision.controller}"
        on_pace = take_on_pace(self, self.pace, self.jumps, decision.step,
                               self.sent_s(stamp, now), decision, "decision", source)
        for taken in take_from_writer(self, self.writer, self.foreign, on_pace, decision.step,
                                      self.sequence, source):  # fmt: skip
            self._hear(taken)

    def _hear(self, decision: StepDecision) -> None:
        """The followed controller's decision on a step: the robot's sound, the next window."""
        stream, step = self._answered
        if decision.stream == stream and decision.step <= step:
            return  # an answer repeated
        self._answered = (decision.stream, decision.step)
        if decision.vocalize:
            self.room.vocalize()
        self._window_answered()

    def _on_no_step(self, msg: Int64MultiArray, stamp: int) -> None:
        """mic_node heard a window and it gave no step: in lockstep, the next window."""
        no_step = parse_no_step(msg)
        if no_step is None:
            return
        if no_step.stream != self._no_step.stream:
            self.no_step_pace.restart()
        on_pace = take_on_pace(self, self.no_step_pace, self.jumps, no_step.window,
                               self.sent_s(stamp, self.now_s()), no_step, "no step",
                               f"the windows of stream {no_step.stream}")  # fmt: skip
        for taken in on_pace:
            self._take_no_step(taken)

    def _take_no_step(self, no_step: NoStep) -> None:
        last = self._no_step
        if no_step.stream == last.stream and no_step.window <= last.window:
            return  # said again
        self._no_step = no_step
        if self._window_answered():
            self.windows_without_step += 1

    def _window_answered(self) -> bool:
        """The window out was answered: release the next (True), at most at the speed cap."""
        if not (self.started and self.pacer is not None and self.pacer.answered()):
            return False
        if self._held_window is not None:
            self._held_window.reset()  # fires once, one period from now
        else:
            self._publish_window()
        return True

    def _release_held_window(self) -> None:
        self._held_window.cancel()
        self._publish_window()

    def _publish_window(self) -> None:
        if self.max_windows and self.room.windows_made >= self.max_windows:
            return
        window = self.room.next_window()
        message = Float32MultiArray()
        message.data = array.array("f", as_transmitted(window.samples).tobytes())
        if self.pacer is not None:
            self.pacer.sent(time.monotonic())
        if window.robot_sound and self.self_sound_pub is not None:
            self._declare_robot_sound()
        self.audio_pub.publish(message)
        self._audio_sent_ns = self.get_clock().now().nanoseconds
        self._window_sent_s = time.time()
        self.truth_pub.publish(Bool(data=window.partner_present))

    def _publish_self_sound_if_needed(self, room: FakeRoomConfig) -> None:
        """The ``self_sound`` publisher, once the robot may speak and its speech is declared.

        Made at start-up when the room's robot speaks; a live set that makes it speak
        makes it then (the first declarations may reach mic_node late: it says so).
        """
        speaks = room.robot_speech_probability > 0 or room.robot_speech_rate_hz > 0
        if self.declare_self_sound and speaks and self.self_sound_pub is None:
            self.self_sound_pub = self.create_publisher(Int64MultiArray, SELF_SOUND, STREAM_QOS)

    def _declare_robot_sound(self) -> None:
        """Declare the window about to go out as the robot's sound (see the module doc).

        The range lies strictly between the previous window's publication and this
        one's: inside the time mic_node gives this window and no other.
        """
        now_ns = self.get_clock().now().nanoseconds
        window_ns = round(self.room.config.window_s * 1e9)
        start_ns = now_ns - window_ns if self._audio_sent_ns is None else self._audio_sent_ns + 1
        end_ns = max(start_ns, now_ns - 1)
        self.self_sound_pub.publish(self_sound_message(start_ns, end_ns))
        self.self_sound_declared += 1

    def _live_room_parameters(self) -> None:
        """Let every room parameter but rate_hz change while the room runs."""
        for name, *_ in ROOM_PARAMETERS:
            self.parameters.live(
                name,
                lambda value, name=name: self._reconfigure(name, value),
                lambda value, name=name: self._room_config(name, value),
            )

    def _room_config(self, name: str, value: float) -> FakeRoomConfig:
        """The room's parameters with ``name`` = ``value``; ConfigError as at start-up.

        The other room parameters of the same set count with their new values (an atomic
        set of ``event_min_s`` and ``event_max_s`` is judged, and applied, as a pair).
        """
        names = {room_name for room_name, *_ in ROOM_PARAMETERS}
        values = {n: v for n, v in self.parameters.the_set.items() if n in names}
        try:
            return dataclasses.replace(self.room.config, **{**values, name: value})
        except ValueError as error:
            raise ConfigError(str(error)) from None

    def _reconfigure(self, name: str, value: float) -> None:
        """The room goes on with ``name`` = ``value`` from the next window on."""
        config = self._room_config(name, value)
        self.room.reconfigure(config)
        self._publish_self_sound_if_needed(config)
        self.get_logger().info(
            f"room: {name} = {value:g} from window {self.room.windows_made + 1} on (room time"
            f" {self.room.now_s:g} s; partner present then:"
            f" {config.partner_present_at(self.room.now_s)})"
        )
        for warning in timing_warnings(config, self.params):
            self.get_logger().warning(f"room timing vs model parameters: {warning}")

    def _set_lockstep_timeout(self, timeout_s: float) -> None:
        """The lockstep timeout (seconds) from the next window on; no effect unpaced."""
        if self.pacer is not None:
            self.pacer.timeout_s = timeout_s

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Windows, vocalizations heard, replies, events, lockstep timeouts."""
        room = self.room
        values: dict[str, Any] = {
            "windows": room.windows_made,
            "room_time_s": room.now_s,
            "partner_present": room.config.partner_present_at(room.now_s),
            "vocalizations": room.vocalizations,
            "replies": room.replies,
            "events": room.events,
            "robot_utterances": room.robot_utterances,
            "self_sound_declared": self.self_sound_declared,
        }
        if self.pacer is not None:
            values["lockstep_timeouts"] = self.pacer.timeouts
            values["windows_without_step"] = self.windows_without_step
        if not self.started:
            return WARN, "waiting for a listener on 'audio'", values
        values["foreign_decisions"] = self.foreign.count
        values["jumps_ignored"] = self.pace.jumps + self.no_step_pace.jumps
        if self.foreign.recent(self.now_s()):
            return ERROR, "decisions from a second controller (ignored)", values
        if self.jumps.recent(self.now_s()):
            return ERROR, "decisions jumping ahead of the stream's pace (ignored)", values
        if self.timeouts.recent(self.now_s()):
            return WARN, f"lockstep timeouts lately: {self._who_is_missing()}", values
        return OK, f"{room.windows_made} windows", values


def main(args: list[str] | None = None) -> int:
    """Run the fake audio node."""
    return run_node(FakeAudioNode, args)


if __name__ == "__main__":
    sys.exit(main())

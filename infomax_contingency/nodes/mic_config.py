"""mic_node's configuration: its parameters, checked at start-up, and what they open.

Sources (parameter ``source``), each a window source of
:mod:`~infomax_contingency.audio.windows`:

* ``wav`` — a WAV file (any PCM/float format, rate and channel count; mixed down or one
  ``channel``, resampled to 16 kHz). Paced in real time (one window every step) or in
  **lockstep** (window t+1 goes out once the decision on window t arrived on
  ``vocalize_step``, or after ``lockstep_timeout_s``). Optional ``loop``;
  ``exit_at_end`` stops the node after the last window.
* ``topic`` — chunks of mono samples on ``audio`` (std_msgs/Float32MultiArray, in
  [-1, 1], at ``audio_rate_hz``), windowed as they come. A gap in the stream (a missing
  publication sequence number) drops the incomplete window and is counted.
* ``bag`` — a recorded session (``bag_dir``, a recorder_node bag), paced like ``wav``:
  its recorded audio windowed again and turned into bits by this node's bit source, or,
  when the bag holds no audio, its recorded bits
  (:mod:`~infomax_contingency.audio.bag_replay`). With controller_node's
  ``controller: recorded:BAG`` the graph replays the session faithfully.
* ``sounddevice`` — a live microphone through PortAudio
  (:class:`~infomax_contingency.audio.capture.MicrophoneStream`): ``device`` is empty (the
  system default), an index, or a part of the device's name; one ``channel`` or the mix
  of all; opened at 16 kHz or at its own rate and resampled exactly. Capture starts with
  the step clock and runs in real time (the PortAudio callback queues up to ``queue_s``
  seconds of audio; more is dropped and counted). A window that lost samples is still
  published and the loss counted; a vanished device is reopened with back-off and the
  step clock goes on after the gap without made-up windows. A device that is not there at
  start-up stops the node with the list of input devices.

Bit source (``bit_source``, one of
:data:`~infomax_contingency.audio.bitsources.BIT_SOURCES`): the chosen source's settings
are parameters of the same names, declared once in the source's settings dataclass
(description, range, whether live); another source's settings are not parameters of the
node. ``sound_energy`` is the full-band window
energy whatever the source. The source sees the audio at ``audio_rate_hz`` (topic and
bag) or at 16 kHz (wav, sounddevice). With a k-means calibration a wav file or a session
bag is calibrated by reading its first seconds ahead, so every window gets a bit; a
stream's calibration windows, and the default ``background``'s warm-up in any source, are
consumed (their ``sound_energy`` is published, but no ``sound``). A bag
without audio replays its recorded bits whatever the bit source.

Live: only the settings declared live (``threshold_db``, in threshold_mode fixed);
``~/recalibrate`` (std_srvs/Trigger) starts the bit source's calibration again (a
replay's first seconds again; a stream's next windows, without bits; threshold_mode file
reads its file again).

Step clock (``max_steps_ahead``, ``max_backlog_s``, ``listener_timeout_s``,
``wait_for_listeners``, ``start_delay_s``, ``max_windows``) and the robot's own sound
(``self_sound_hold_s``): see :mod:`~infomax_contingency.nodes.mic_node`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from infomax_contingency.audio.bitsources import (
    BIT_SOURCES,
    DEFAULT_BIT_SOURCE,
    BitSource,
)
from infomax_contingency.audio.bitsources.base import SettingError
from infomax_contingency.audio.capture import MicrophoneStream
from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError
from infomax_contingency.audio.devices import INPUT, AudioDeviceError, LogFunction, resolve_device
from infomax_contingency.audio.windows import (
    MicrophoneWindows,
    TopicWindows,
    WavReplay,
    WindowSource,
)
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.stepclock import MAX_STEP_JUMP
from infomax_contingency.nodes.parameters import ConfigError, ParameterReader, device_parameter
from infomax_contingency.nodes.step_topics import SOUND_STEP, VOCALIZE_STEP

SOURCES = ("wav", "topic", "sounddevice", "bag")
"""Where mic_node's audio comes from (parameter ``source``)."""


@dataclass(frozen=True)
class MicConfig:
    """mic_node's parameters (see the module docstring and config/robot.yaml).

    ``bit_settings`` is the chosen bit source's settings dataclass.
    """

    params: ModelParams
    source: str
    bit_source: str
    bit_settings: Any
    wait_for_listeners: int
    start_delay_s: float
    max_windows: int
    max_steps_ahead: int
    max_backlog_s: float
    listener_timeout_s: float
    self_sound_hold_s: float
    wav_file: str
    bag_dir: str
    channel: int
    loop: bool
    lockstep: bool
    lockstep_timeout_s: float
    exit_at_end: bool
    audio_rate_hz: int
    device: str
    queue_s: float

    @property
    def window_s(self) -> float:
        """Window (step) length, seconds: the model's dt."""
        return self.params.dt

    @property
    def rate_hz(self) -> int:
        """Sample rate of the windows the bit source sees, Hz.

        The topic's ``audio_rate_hz`` (also the rate of a session bag's recorded audio),
        else 16 kHz (wav and sounddevice are resampled to it).
        """
        return self.audio_rate_hz if self.source in ("topic", "bag") else PROCESSING_RATE_HZ


def _read_step_clock(read: ParameterReader) -> dict[str, Any]:
    return {
        "wait_for_listeners": read.integer(
            "wait_for_listeners", 2,
            "Subscribers of 'sound_step' (controller, belief) to wait for before the first bit",
            0, 1000,
        ),
        "start_delay_s": read.number(
            "start_delay_s", 0.5, "Extra wait after the listeners are there", 0.0, 60.0, "s"
        ),
        "max_windows": read.integer(
            "max_windows", 0, "Stop the node after this many bits; 0 = never", 0, 2**31 - 1
        ),
        "max_steps_ahead": read.integer(
            "max_steps_ahead", 16,
            "Steps that may be out unanswered (by the controller on 'vocalize_step') or not"
            " taken (by a listener on 'step_applied', e.g. belief_node)",
            1, MAX_STEP_JUMP,
        ),
        "listener_timeout_s": read.number(
            "listener_timeout_s", 5.0,
            "A listener on 'step_applied' (belief_node) that takes nothing this long is no"
            " longer waited for (killed, hung) until it keeps up again; steps no decision"
            " came for in as long are taken as lost (a controller restarted)",
            0.1, 3600.0, "s",
        ),
        "max_backlog_s": read.number(
            "max_backlog_s", 3600.0,
            "Audio whose windows may wait for the controller; more is dropped and counted",
            1.0, 86400.0, "s",
        ),
        "self_sound_hold_s": read.number(
            "self_sound_hold_s", 0.15,
            "While 'self_sound' has a publisher, each window waits this long past its end"
            " for the robot's declared sound ranges that overlap it", 0.0, 10.0, "s",
        ),
    }


def _read_sources(read: ParameterReader) -> dict[str, Any]:
    return {
        "wav_file": read.text("wav_file", "", "WAV file to replay (source wav)"),
        "bag_dir": read.text("bag_dir", "", "Session bag to replay (source bag)"),
        "channel": read.integer(
            "channel", -1,
            "Channel of the file or microphone to use; -1 = mix all channels", -1, 1023,
        ),
        "loop": read.flag("loop", False, "Replay the file again and again (source wav)"),
        "lockstep": read.flag(
            "lockstep", True, "Release each window after the 'vocalize_step' on the previous one"
        ),
        "lockstep_timeout_s": read.number(
            "lockstep_timeout_s", 2.0,
            "Release the next window anyway after this long without a 'vocalize_step'",
            0.01, 3600.0, "s",
        ),
        "exit_at_end": read.flag(
            "exit_at_end", False, "Stop the node after the last window of the file"
        ),
        "audio_rate_hz": read.integer(
            "audio_rate_hz", 16000, "Sample rate of the 'audio' topic (source topic)",
            1000, 384000,
        ),
        "device": device_parameter(read.node, "Microphone (source sounddevice)"),
        "queue_s": read.number(
            "queue_s", 4.0,
            "Live audio held for the node's reader (source sounddevice); blocks beyond it"
            " are dropped and counted", 0.1, 600.0, "s",
        ),
    }


def read_config(read: ParameterReader) -> MicConfig:
    """Declare and check mic_node's parameters; ConfigError (one line) for a bad one."""
    params = read.model()
    source = read.text(
        "source", "topic",
        "Where audio comes from: wav (a file), topic (the 'audio' topic),"
        " sounddevice (a live microphone), bag (a recorded session)", SOURCES,
    )  # fmt: skip
    bit_source = read.text(
        "bit_source", DEFAULT_BIT_SOURCE,
        "How a window becomes a bit: "
        + ", ".join(f"{name} ({kind.summary})" for name, kind in BIT_SOURCES.items()),
        tuple(BIT_SOURCES),
    )  # fmt: skip
    kind = BIT_SOURCES[bit_source]
    config = MicConfig(
        params=params,
        source=source,
        bit_source=bit_source,
        bit_settings=kind.make_settings({spec.name: read.declared(spec) for spec in kind.specs()}),
        **_read_step_clock(read),
        **_read_sources(read),
    )
    check_bit_settings(config)
    if config.source == "wav" and not config.wav_file:
        raise ConfigError("parameter 'wav_file' is empty: source 'wav' needs a WAV file")
    if config.source == "bag" and not config.bag_dir:
        raise ConfigError("parameter 'bag_dir' is empty: source 'bag' needs a session bag")
    return config


def check_bit_settings(config: MicConfig) -> None:
    """The bit source's own checks (rate, window, combinations), as a parameter's refusal."""
    try:
        BIT_SOURCES[config.bit_source].check_settings(
            config.bit_settings, config.rate_hz, config.window_s
        )
    except SettingError as error:
        name = "audio_rate_hz" if error.setting == "rate_hz" else error.setting
        raise ConfigError(f"parameter '{name}' {error.reason}") from None


def unread_threshold_file(read: ParameterReader, config: MicConfig) -> str:
    """A warning when ``threshold_file`` is given but the configuration reads no file; "" if not.

    Only ``threshold_mode: file`` of the sources that have the setting reads it (at
    start-up and on ``~/recalibrate``); any other source or mode would drop it unseen.
    """
    path = read.given("threshold_file")
    mode = getattr(config.bit_settings, "threshold_mode", None)
    if not isinstance(path, str) or not path.strip() or mode == "file":
        return ""
    readers = [name for name, kind in BIT_SOURCES.items()
               if any(spec.name == "threshold_file" for spec in kind.specs())]  # fmt: skip
    chosen = f"bit_source {config.bit_source}" + (f" with threshold_mode {mode}" if mode else "")
    return (f"parameter 'threshold_file' = {path!r} is not read: {chosen} reads no threshold"
            f" file; threshold_mode file of bit_source {' or '.join(readers)} reads it")


def make_bits(config: MicConfig, on_problem: Any = None) -> BitSource:
    """The bit source the configuration asks for (a threshold file is read now)."""
    try:
        bits = BIT_SOURCES[config.bit_source](
            config.bit_settings, config.rate_hz, config.window_s, on_problem
        )
    except AudioError as error:
        raise ConfigError(str(error)) from None
    if bits.needs_decisions:  # it labels windows by the model's timer
        bits.follow_model(config.params)
    return bits


def open_window_source(config: MicConfig, samples: bool, log: LogFunction) -> WindowSource:
    """The window source of ``source`` (keeping the windows' samples if ``samples``).

    Raises:
        ConfigError: the bag or device cannot be used (one line; a missing device lists
            the input devices).
        AudioError: the WAV file cannot be read.
    """
    channel = None if config.channel < 0 else config.channel
    if config.source == "wav":
        return WavReplay(config.wav_file, config.window_s, channel, config.loop, samples=samples)
    if config.source == "bag":
        # Imported here: the bag library takes about 0.1 s of CPU to load, and only this
        # source needs it.
        from infomax_contingency.audio.bag_replay import BagReplay

        try:
            replay = BagReplay(Path(config.bag_dir), config.window_s, config.audio_rate_hz,
                               samples)
        except (OSError, AudioError) as error:
            raise ConfigError(f"parameter 'bag_dir' = {config.bag_dir!r}: {error}") from None
        for warning in replay.warnings:  # a bag cut by a killed recorder
            log("warning", warning)
        return replay
    if config.source == "topic":
        return TopicWindows(config.audio_rate_hz, config.window_s, samples)
    return MicrophoneWindows(_microphone(config, channel, log), samples, log)


def _microphone(config: MicConfig, channel: int | None, log: LogFunction) -> MicrophoneStream:
    """The (not yet started) microphone of ``source: sounddevice``; ConfigError if missing."""
    device = config.device
    try:
        found = resolve_device(device, INPUT)
    except AudioDeviceError as error:  # the message lists the input devices
        raise ConfigError(f"parameter 'device' = {device!r}: {error}") from None
    if config.channel >= found.max_input_channels:
        raise ConfigError(
            f"parameter 'channel' = {config.channel}: {found.name} has"
            f" {found.max_input_channels} input channel(s), numbered 0 .."
            f" {found.max_input_channels - 1}; -1 mixes them all"
        )
    chosen = f"device {device!r}" if device else "the system default"
    log("info", f"microphone: {chosen} is {found.describe(INPUT)}; capture starts with the"
                f" step clock, windows of {config.window_s} s in real time")  # fmt: skip
    return MicrophoneStream(device, window_s=config.window_s, channel=channel,
                            queue_s=config.queue_s, log=log)  # fmt: skip


def start_gate_text(config: MicConfig, lockstep: bool) -> str:
    """What mic_node's step clock waits for before it starts (its start gate), in words."""
    awaited = [f"{config.wait_for_listeners} listeners on '{SOUND_STEP}'"] * bool(
        config.wait_for_listeners
    )
    if lockstep:
        awaited.append(f"a controller on '{VOCALIZE_STEP}' (lockstep)")
    return " and ".join(awaited) or "nothing"

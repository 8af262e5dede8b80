"""mic_node: audio windows to bits — the step clock of the graph.

Sources (parameter ``source``):

* ``wav`` — a WAV file (any PCM/float format, rate and channel count; mixed down or one
  ``channel``, resampled to 16 kHz). Paced in real time (one window every ``window_s``)
  or in **lockstep** (window t+1 goes out once ``vocalize`` for window t arrived, or
  after ``lockstep_timeout_s``). Optional ``loop``; ``exit_at_end`` stops the node after
  the last window.
* ``topic`` — chunks of mono samples on ``audio`` (std_msgs/Float32MultiArray, in
  [-1, 1], at ``audio_rate_hz``), windowed as they come. A gap in the stream (a missing
  publication sequence number) drops the incomplete window and is counted.
* ``bag`` — a recorded session (``bag_dir``, a recorder_node bag), paced like ``wav``:
  its recorded audio windowed again and turned into bits by this node's bit source and
  threshold, or, when the bag holds no audio, its recorded bits
  (:mod:`~infomax_contingency.audio.bag_replay`).
  With controller_node's ``controller: recorded:BAG`` answering with the robot's
  recorded decisions, the graph replays the session faithfully (the belief is the
  recorded one when the bits are); with a policy it is a what-if on the same sound.
* ``sounddevice`` — a live microphone through PortAudio
  (:class:`~infomax_contingency.audio.capture.MicrophoneStream`): ``device`` is empty (the
  system default), an index, or a part of the device's name (first match; the match is
  logged); one ``channel`` or the mix of all. The device is opened at 16 kHz, or at its
  own rate and resampled exactly. Capture starts with the step clock (after the start
  gate below) and runs in real time: a 20 ms timer on the node's thread reads the
  finished windows (the PortAudio callback only queues blocks, up to ``queue_s`` seconds
  of audio; more is dropped and counted). A window that lost samples (an input
  overflow, a reader too slow) is still published and the loss counted; if the device
  vanishes, it is reopened with back-off and the step clock goes on after the gap
  without made-up windows. Window times are PortAudio's ADC times
  (``window_delay_s`` in the diagnostics: from a window's last sample to its bit). A
  device that is not there at start-up stops the node with the list of input devices.

Bit source (``bit_source``, :mod:`~infomax_contingency.audio.bitsource`): ``energy``
(the window energy against the threshold; the default), ``speech_band`` (the energy of
the 300-3400 Hz band against the threshold) or ``vad`` (WebRTC's voice-activity
detector: a window is active with at least ``vad_min_voiced_s`` of voiced
``vad_frame_ms`` frames; ``vad_aggressiveness`` 0-3; 8, 16, 32 or 48 kHz audio only; no
threshold). ``sound_energy`` is the full-band window energy whatever the source. The
source sees the audio at ``audio_rate_hz`` (topic and bag) or at 16 kHz (wav,
sounddevice). A session bag with audio goes through the bit source like any audio; a
bag without audio has only its recorded bits, which are replayed as they are whatever
``bit_source`` and the threshold (logged at start-up; live threshold sets are refused).

Threshold (``threshold_mode``, sources energy and speech_band): ``fixed``
(``threshold_db``), ``file`` (a threshold file written by calibration,
``threshold_file``), ``calibrate``: the two-cluster k-means of the first
``calibration_s`` seconds, or ``noise_floor``: ``noise_margin_db`` above the
``noise_percentile``-th percentile of the last ``noise_window_s`` seconds of levels (the
first ``calibration_s`` seconds only start the floor). A wav file or a session bag is
calibrated by reading its first seconds ahead, so every window gets a bit; a stream's
calibration windows are consumed (their ``sound_energy`` is published, but no ``sound``:
the step clock starts after calibration). ``refresh_s > 0`` refits the threshold online
on the last ``refresh_s`` seconds (accepted when the clusters lie ``min_separation_db``
apart; not with noise_floor, which follows the floor by itself).
Live (``ros2 param set``, checked as at start-up): ``threshold_mode`` (fixed and file
apply from the next window; a bad threshold file refuses the set with its error;
calibrate starts a new calibration: a wav file's first seconds again, else the next
``calibration_s`` seconds of windows, without bits; noise_floor starts a new floor on
the next ``calibration_s`` seconds of windows, without bits), ``threshold_file``,
``threshold_db`` (mode fixed) and ``refresh_s`` (a new, empty buffer; the threshold in
force stays). The bit source keeps its kind (``bit_source`` is read-only); with
``bit_source`` vad, which has no threshold, these sets are refused.

Step clock: every bit is a step ``1, 2, ...`` of this run's *stream* (a random id),
published on ``sound`` (Bool) and, with its identity and the window length, on
``sound_step`` (see :mod:`~infomax_contingency.nodes.step_topics`). Windows wait in a
bounded outbox (:class:`~infomax_contingency.core.stepclock.StepOutbox`): while a
controller answers on ``vocalize_step``, at most ``max_steps_ahead`` steps are out
unanswered, so a burst of audio (a 30 s message, a fast replay) is published as fast as
the controller decides and nothing overflows a queue; at most ``max_backlog_s`` of
windows wait (more is dropped and counted). ``window_s`` must equal the model's dt
(``params``): another value is refused at start-up.

Start: the first bit goes out once ``sound_step`` has ``wait_for_listeners`` subscribers
(and, in wav lockstep, ``vocalize`` a publisher) and every subscriber seen on its topics
is connected, plus ``start_delay_s`` for the rest of the graph to connect; windows of the
``audio`` topic that arrive meanwhile wait, none is lost. ``max_windows > 0`` stops the
node (exit status 0) after that many bits, once the subscribers have acknowledged them.

Publishes ``sound`` (Bool, once per window), ``sound_energy`` (Float32, dB),
``/diagnostics`` (for a live microphone also the device, its state, overflows, dropped
blocks, lost samples, gaps and reconnections).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rclpy.duration import Duration
from std_msgs.msg import Bool, Float32, Float32MultiArray, Int64MultiArray

from infomax_contingency.audio.binarizer import UNSEPARATED, WavReplay
from infomax_contingency.audio.bitsource import (
    BIT_SOURCES,
    SPEECH_BAND_HZ,
    THRESHOLD_MODES,
    VAD_FRAMES_MS,
    VAD_RATES_HZ,
    BitSource,
    make_bit_source,
)
from infomax_contingency.audio.capture import MicrophoneStream, Window
from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError
from infomax_contingency.audio.devices import DISCONNECTED, INPUT, AudioDeviceError, resolve_device
from infomax_contingency.audio.energy import WindowAssembler
from infomax_contingency.audio.threshold import load_threshold
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.stepclock import LockstepPacer, StepOutbox
from infomax_contingency.nodes.graph_node import ERROR, OK, RELEASED_WINDOW, WARN, GraphNode
from infomax_contingency.nodes.parameters import ConfigError, ParameterReader, device_parameter
from infomax_contingency.nodes.qos import AUDIO_QOS, STEP_READER_QOS, STREAM_QOS
from infomax_contingency.nodes.runtime import run_node
from infomax_contingency.nodes.step_topics import (
    SOUND_STEP,
    VOCALIZE_STEP,
    StepBit,
    bit_message,
    new_source_id,
    parse_decision,
    window_us,
)

SOURCES = ("wav", "topic", "sounddevice", "bag")

MICROPHONE_POLL_S = 0.02
"""Seconds between reads of the live microphone's finished windows."""

ACK_TIMEOUT_S = 5.0
"""Seconds a finishing node waits for its subscribers to acknowledge the last messages."""

if TYPE_CHECKING:
    from infomax_contingency.audio.bag_replay import BagReplay


@dataclass(frozen=True)
class MicConfig:
    """mic_node's parameters (see the module docstring and config/robot.yaml)."""

    params: ModelParams
    source: str
    window_s: float
    bit_source: str
    threshold_mode: str
    threshold_db: float
    threshold_file: str
    calibration_s: float
    refresh_s: float
    min_separation_db: float
    noise_margin_db: float
    noise_window_s: float
    noise_percentile: float
    false_alarm: float
    background_window_s: float
    warmup_s: float
    background_margin_db: float
    vad_aggressiveness: int
    vad_frame_ms: int
    vad_min_voiced_s: float
    wait_for_listeners: int
    start_delay_s: float
    max_windows: int
    max_steps_ahead: int
    max_backlog_s: float
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


def _read_threshold(read: ParameterReader) -> dict[str, Any]:
    return {
        "threshold_mode": read.text(
            "threshold_mode", "background",
            "How the sound threshold is set (live: fixed and file apply at once, calibrate"
            " starts a new calibration, background and noise_floor start anew)",
            THRESHOLD_MODES, read_only=False,
        ),
        "threshold_db": read.number(
            "threshold_db",
            -40.0,
            "Fixed threshold (threshold_mode fixed; live)",
            -150.0,
            0.0,
            "dB",
            read_only=False,
        ),
        "threshold_file": read.text(
            "threshold_file", "",
            "Threshold file written by calibration (threshold_mode file; live: loaded at once"
            " in mode file)", read_only=False,
        ),
        "calibration_s": read.number(
            "calibration_s", 10.0, "Calibration audio (threshold_mode calibrate)",
            0.02, 3600.0, "s",
        ),
        "refresh_s": read.number(
            "refresh_s", 0.0,
            "Online threshold refresh buffer; 0 = off (live: the buffer starts empty)",
            0.0, 86400.0, "s", read_only=False,
        ),
        "min_separation_db": read.number(
            "min_separation_db", 10.0,
            "Least gap between cluster means to accept a calibration or a refit",
            0.0, 100.0, "dB",
        ),
        "noise_margin_db": read.number(
            "noise_margin_db", 10.0, "Threshold above the noise floor (threshold_mode noise_floor)",
            0.0, 100.0, "dB",
        ),
        "noise_window_s": read.number(
            "noise_window_s", 30.0,
            "Recent audio the noise floor is taken over (threshold_mode noise_floor)",
            0.01, 86400.0, "s",
        ),
        "noise_percentile": read.number(
            "noise_percentile", 10.0,
            "Percentile of recent levels that is the noise floor; 0 = the minimum"
            " (threshold_mode noise_floor)", 0.0, 50.0, "%",
        ),
        "false_alarm": read.number(
            "false_alarm", 0.05,
            "Share of the model's background windows that are active (threshold_mode"
            " background); the model's prior on K3 should match it", 0.001, 0.5,
        ),
        "background_window_s": read.number(
            "background_window_s", 30.0,
            "Background windows of this much audio set the threshold (threshold_mode"
            " background)", 1.0, 86400.0, "s",
        ),
        "warmup_s": read.number(
            "warmup_s", 4.0,
            "Background audio heard before the first bit (threshold_mode background)",
            0.01, 3600.0, "s",
        ),
        "background_margin_db": read.number(
            "background_margin_db", 0.0,
            "Added to the background level (threshold_mode background)", 0.0, 100.0, "dB",
        ),
    }


def _read_vad(read: ParameterReader) -> dict[str, Any]:
    return {
        "vad_aggressiveness": read.integer(
            "vad_aggressiveness", 2,
            "How readily the voice-activity detector calls a frame unvoiced (bit_source vad)",
            0, 3,
        ),
        "vad_frame_ms": read.integer(
            "vad_frame_ms", 30, "Voice-activity frame length: 10, 20 or 30 (bit_source vad)",
            10, 30, "ms",
        ),
        "vad_min_voiced_s": read.number(
            "vad_min_voiced_s", 0.1,
            "Voiced time that makes a window active (bit_source vad; at most window_s)",
            0.001, 10.0, "s",
        ),
    }


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
            "Steps that may be out unanswered while a controller answers on 'vocalize_step'",
            1, 1000,
        ),
        "max_backlog_s": read.number(
            "max_backlog_s", 3600.0,
            "Audio whose windows may wait for the controller; more is dropped and counted",
            1.0, 86400.0, "s",
        ),
    }


def _read_sources(node: GraphNode, read: ParameterReader) -> dict[str, Any]:
    return {
        "wav_file": read.text("wav_file", "", "WAV file to replay (source wav)"),
        "bag_dir": read.text("bag_dir", "", "Session bag to replay (source bag)"),
        "channel": read.integer(
            "channel", -1,
            "Channel of the file or microphone to use; -1 = mix all channels", -1, 1023,
        ),
        "loop": read.flag("loop", False, "Replay the file again and again (source wav)"),
        "lockstep": read.flag(
            "lockstep", True, "Release each window after the 'vocalize' on the previous one"
        ),
        "lockstep_timeout_s": read.number(
            "lockstep_timeout_s", 2.0,
            "Release the next window anyway after this long without a 'vocalize'",
            0.01, 3600.0, "s",
        ),
        "exit_at_end": read.flag(
            "exit_at_end", False, "Stop the node after the last window of the file"
        ),
        "audio_rate_hz": read.integer(
            "audio_rate_hz", 16000, "Sample rate of the 'audio' topic (source topic)",
            1000, 384000,
        ),
        "device": device_parameter(node, "Microphone (source sounddevice)"),
        "queue_s": read.number(
            "queue_s", 4.0,
            "Live audio held for the node's reader (source sounddevice); blocks beyond it"
            " are dropped and counted", 0.1, 600.0, "s",
        ),
    }


def read_config(node: GraphNode) -> MicConfig:
    """Declare and check mic_node's parameters."""
    read: ParameterReader = node.parameters
    params = read.model()
    config = MicConfig(
        params=params,
        source=read.text(
            "source", "topic",
            "Where audio comes from: wav (a file), topic (the 'audio' topic),"
            " sounddevice (a live microphone), bag (a recorded session)", SOURCES,
        ),
        window_s=read.number(
            "window_s", 0.5, "Window (step) length; must equal the model's dt", 0.01, 10.0, "s"
        ),
        bit_source=read.text(
            "bit_source", "energy",
            "How a window becomes a bit: energy (window energy against the threshold),"
            " speech_band (300-3400 Hz energy against the threshold), vad (voice-activity"
            " detector)", tuple(BIT_SOURCES),
        ),
        **_read_threshold(read),
        **_read_vad(read),
        **_read_step_clock(read),
        **_read_sources(node, read),
    )
    if abs(config.window_s - params.dt) > 1e-9:
        raise ConfigError(
            f"parameter 'window_s' = {config.window_s:g} s differs from the model's dt ="
            f" {params.dt:g} s (parameter 'params'): one window must be one step of the"
            " model"
        )
    check_refresh(config.refresh_s, config.window_s)
    _check_bit_source(config)
    if config.bit_source != "vad":
        check_threshold_file(config.threshold_mode, config.threshold_file)
    if config.source == "wav" and not config.wav_file:
        raise ConfigError("parameter 'wav_file' is empty: source 'wav' needs a WAV file")
    if config.source == "bag" and not config.bag_dir:
        raise ConfigError("parameter 'bag_dir' is empty: source 'bag' needs a session bag")
    return config


def check_refresh(refresh_s: float, window_s: float) -> None:
    """``refresh_s`` (seconds) is 0 (off) or at least two windows of ``window_s`` seconds."""
    if refresh_s > 0 and round(refresh_s / window_s) < 2:
        raise ConfigError(
            f"parameter 'refresh_s' = {refresh_s}: must be 0 (off) or at least two"
            f" windows ({2 * window_s:g} s)"
        )


def check_threshold_file(threshold_mode: str, threshold_file: str) -> None:
    """threshold_mode ``file`` needs a ``threshold_file`` path."""
    if threshold_mode == "file" and not threshold_file:
        raise ConfigError(
            "parameter 'threshold_file' is empty: threshold_mode 'file' needs the path"
            " of a threshold file written by calibration"
        )


def bit_rate_hz(config: MicConfig) -> int:
    """Sample rate of the windows the bit source sees, Hz.

    The topic's ``audio_rate_hz`` (also the rate of a session bag's recorded audio), else
    16 kHz (wav and sounddevice are resampled to it).
    """
    return config.audio_rate_hz if config.source in ("topic", "bag") else PROCESSING_RATE_HZ


def _check_bit_source(config: MicConfig) -> None:
    """The checks of the bit-source parameters that a range cannot express."""
    if config.bit_source == "vad":
        rate = bit_rate_hz(config)
        if rate not in VAD_RATES_HZ:
            raise ConfigError(
                f"parameter 'audio_rate_hz' = {rate}: bit_source vad takes audio at"
                f" {', '.join(map(str, VAD_RATES_HZ))} Hz only (webrtcvad)"
            )
        if config.vad_frame_ms not in VAD_FRAMES_MS:
            raise ConfigError(
                f"parameter 'vad_frame_ms' = {config.vad_frame_ms}: must be 10, 20 or 30 ms"
            )
        if config.vad_min_voiced_s > config.window_s:
            raise ConfigError(
                f"parameter 'vad_min_voiced_s' = {config.vad_min_voiced_s:g} s is longer than"
                f" a window (window_s = {config.window_s:g} s): no window could be active"
            )
    if config.bit_source == "speech_band" and not bit_rate_hz(config) > 2 * SPEECH_BAND_HZ[1]:
        raise ConfigError(
            f"parameter 'audio_rate_hz' = {bit_rate_hz(config)}: bit_source speech_band needs"
            f" audio above {2 * SPEECH_BAND_HZ[1]:g} Hz (twice the band's upper edge,"
            f" {SPEECH_BAND_HZ[1]:g} Hz)"
        )
    if config.threshold_mode in ("noise_floor", "background") and config.refresh_s > 0:
        raise ConfigError(
            f"parameter 'refresh_s' = {config.refresh_s:g}: refits a k-means threshold;"
            f" threshold_mode {config.threshold_mode} follows the room by itself: set it to 0"
        )
    if (
        config.threshold_mode == "background"
        and config.bit_source != "vad"
        and config.warmup_s > config.background_window_s
    ):
        raise ConfigError(
            f"parameter 'warmup_s' = {config.warmup_s:g} s: must not exceed"
            f" background_window_s ({config.background_window_s:g} s)"
        )


def make_binarizer(
    config: MicConfig,
    on_refused: Callable[[str], None] | None = None,
    keep_threshold_db: float | None = None,
) -> BitSource:
    """The bit source that ``bit_source`` and ``threshold_mode`` ask for.

    ``on_refused`` is told (one line naming the gap in dB) when a calibration cannot
    separate sound from quiet; no bit comes from such a calibration.
    ``keep_threshold_db`` (dB), if given, is the threshold in force to keep whatever the
    mode (a live change of ``refresh_s``): a fixed threshold rule of the same source.
    """
    if config.bit_source == "vad":
        options: dict[str, Any] = {
            "vad_aggressiveness": config.vad_aggressiveness,
            "vad_frame_ms": config.vad_frame_ms,
            "vad_min_voiced_s": config.vad_min_voiced_s,
        }
    else:
        if keep_threshold_db is not None:
            config = dataclasses.replace(
                config, threshold_mode="fixed", threshold_db=keep_threshold_db
            )
        options = {
            "threshold_mode": config.threshold_mode,
            "threshold_db": config.threshold_db,
            "threshold_file": config.threshold_file,
            "calibration_s": config.calibration_s,
            "refresh_s": config.refresh_s,
            "min_separation_db": config.min_separation_db,
            "noise_margin_db": config.noise_margin_db,
            "noise_window_s": config.noise_window_s,
            "noise_percentile": config.noise_percentile,
            "false_alarm": config.false_alarm,
            "background_window_s": config.background_window_s,
            "warmup_s": config.warmup_s,
            "background_margin_db": config.background_margin_db,
            "periods": (config.params.ts1, config.params.ts2, config.params.ta2),
            "on_calibration_refused": on_refused,
        }
    return make_bit_source(config.bit_source, bit_rate_hz(config), config.window_s, **options)


class MicNode(GraphNode):
    """Microphone: audio windows to sound bits."""

    NODE_NAME = "mic_node"
    WATCHED_TOPICS = ("sound", SOUND_STEP)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NODE_NAME, **kwargs)
        self.config = config = read_config(self)
        self.source = config.source
        self.window_s = config.window_s
        self.wait_for_listeners = config.wait_for_listeners
        self.max_windows = config.max_windows
        self.exit_at_end = config.exit_at_end
        self.bits = make_binarizer(config, self._calibration_refused)
        self._generation = 0  # of self.bits: a live threshold change makes a new one
        self._step_generation: dict[int, int] = {}  # released step -> generation of its bit
        if config.bit_source != "energy":
            self.get_logger().info(
                f"bit source {config.bit_source}: {BIT_SOURCES[config.bit_source]}"
            )
        self._live_threshold_parameters()
        self.stream_id = new_source_id()
        self.window_us = window_us(config.window_s)
        self.outbox = StepOutbox(
            config.max_steps_ahead, max(1, round(config.max_backlog_s / config.window_s))
        )
        self.sound_pub = self.create_publisher(Bool, "sound", STREAM_QOS)
        self.step_pub = self.create_publisher(Int64MultiArray, SOUND_STEP, STREAM_QOS)
        self.energy_pub = self.create_publisher(Float32, "sound_energy", STREAM_QOS)
        self._decisions_sub = self.subscribe(
            Int64MultiArray, VOCALIZE_STEP, self._on_decision, STEP_READER_QOS
        )
        self.windows = 0
        self.last_energy_db = float("nan")
        self.dropped_chunks = 0
        self.bad_chunks = 0
        self.started = False
        self.replay: WavReplay | None = None
        self.bag: BagReplay | None = None
        self.pacer: LockstepPacer | None = None
        self._pace_timer = None
        self.ended = False
        self.microphone: MicrophoneStream | None = None
        self.segment = 0
        self.windows_with_loss = 0
        self.window_delay_s = float("nan")
        self.max_window_delay_s = float("nan")
        self.losses = self.recent_events()
        self.timeouts = self.recent_events()
        if self.source == "wav":
            self._setup_wav(config)
        elif self.source == "bag":
            self._setup_bag(config)
        elif self.source == "topic":
            self._setup_topic(config.audio_rate_hz)
        else:
            self._setup_microphone(config.device, config.channel, config.queue_s)
        self.start_when_ready(
            self._listeners_ready,
            config.start_delay_s,
            self._start,
            self.pacer,
            self._on_timeout,
            "is controller_node running?",
        )
        self.get_logger().info(f"stream id {self.stream_id}")
        self.start_diagnostics()

    @property
    def binarizer(self) -> Any:
        """The threshold rule of sources energy and speech_band (None for vad)."""
        return self.bits.rule

    def _on_audio_message(self, msg: Float32MultiArray, info: dict[str, Any]) -> None:
        self.count_arrival("audio")
        self._on_audio(msg, info)

    def _calibration_refused(self, message: str) -> None:
        self.get_logger().warning(message)

    # ------------------------------------------------------------------ sources

    def _setup_wav(self, config: MicConfig) -> None:
        channel = None if config.channel < 0 else config.channel
        samples = self.bits.needs_samples
        self.replay = WavReplay(config.wav_file, self.window_s, channel, config.loop,
                                samples=samples)  # fmt: skip
        if config.threshold_mode == "calibrate" and self.binarizer is not None:
            self._calibrate_ahead(self.bits, config)
        if config.lockstep:
            self.pacer = LockstepPacer(config.lockstep_timeout_s)
        self.get_logger().info(
            f"replaying {config.wav_file}: {self.replay.n_windows} windows of {self.window_s} s,"
            f" {'lockstep' if config.lockstep else 'real time'}"
            f"{', looping' if config.loop else ''}"
        )

    def _setup_bag(self, config: MicConfig) -> None:
        """Open the session bag of ``source: bag``; calibrate on its audio if asked."""
        self.bag = open_bag_replay(config, self.bits.needs_samples)
        if self.bag.has_audio:
            what = "its audio, through the bit source"
            if config.threshold_mode == "calibrate" and self.binarizer is not None:
                self._calibrate_ahead(self.bits, config)
        else:
            what = "its recorded bits (no audio recorded)"
            if config.bit_source != "energy":
                self.get_logger().warning(
                    f"bit_source {config.bit_source} is not applied: the session"
                    f" {config.bag_dir} holds no audio, its recorded bits are replayed"
                )
        self.pacer = LockstepPacer(config.lockstep_timeout_s) if config.lockstep else None
        self.get_logger().info(f"replaying the session {config.bag_dir}: {self.bag.n_windows}"
                               f" windows of {config.window_s} s from {what}")  # fmt: skip

    def _setup_topic(self, rate: int) -> None:
        self.assembler = WindowAssembler(rate, self.window_s)
        self._last_sequence: int | None = None
        self.create_subscription(
            Float32MultiArray, "audio", self._on_audio_message, AUDIO_QOS
        )
        self.wait_visibly(
            "audio",
            f"std_msgs/Float32MultiArray, mono samples at {rate} Hz: start an audio"
            " driver or fake_audio_node (launch use_fake_room:=true), or set source to wav or"
            " sounddevice",
        )

    def _setup_microphone(self, device: str, channel: int, queue_s: float) -> None:
        try:
            found = resolve_device(device, INPUT)
        except AudioDeviceError as error:  # the message lists the input devices
            raise ConfigError(f"parameter 'device' = {device!r}: {error}") from None
        if channel >= found.max_input_channels:
            raise ConfigError(
                f"parameter 'channel' = {channel}: {found.name} has"
                f" {found.max_input_channels} input channel(s), numbered 0 .."
                f" {found.max_input_channels - 1}; -1 mixes them all"
            )
        self.microphone = MicrophoneStream(
            device,
            window_s=self.window_s,
            channel=None if channel < 0 else channel,
            queue_s=queue_s,
            log=self.log_at,
        )
        chosen = f"device {device!r}" if device else "the system default"
        self.get_logger().info(
            f"microphone: {chosen} is {found.describe(INPUT)}; capture starts with the step"
            f" clock, windows of {self.window_s} s in real time"
        )

    # ------------------------------------------------------------------ start gate

    def _start(self) -> None:
        self.started = True
        self.get_logger().info("listeners connected: starting the step clock")
        if self.replay is not None or self.bag is not None:
            if self.pacer is None:
                self._pace_timer = self.create_timer(self.window_s, self._emit_from_file)
            self._emit_from_file()
        if self.microphone is not None:
            self.microphone.start()
            self.create_timer(MICROPHONE_POLL_S, self._read_microphone)
        self._release()

    def _on_timeout(self) -> None:
        self.timeouts.note(self.now_s())
        self.get_logger().warning(
            f"no 'vocalize' within {self.pacer.timeout_s} s of window {self.windows}:"
            f" {self._who_is_missing()}; releasing {RELEASED_WINDOW}"
        )
        self._emit_from_file()

    def _who_is_missing(self) -> str:
        if self._decisions_sub.get_publisher_count() == 0:
            return "no controller_node publishes 'vocalize_step'"
        return "controller_node is there but did not answer"

    def _listeners_ready(self) -> bool:
        if self.step_pub.get_subscription_count() < self.wait_for_listeners:
            return False
        return self.pacer is None or self._decisions_sub.get_publisher_count() > 0

    # ------------------------------------------------------------------ windows

    def _emit_from_file(self) -> None:
        """Serve the next window of the file or bag (and more, while they yield no bit).

        A window that yields no bit (a bit source warming up) is followed at once by the
        next: no decision will come back for it.
        """
        while self._emit_window_from_file() is None and not self.ended:
            pass

    def _emit_window_from_file(self) -> bool | None:
        """Serve the next window of the file or bag: its bit, or None (no bit, or the end)."""
        samples: np.ndarray | None = None
        recorded_bit: bool | None = None
        if self.bag is not None:
            energy, recorded_bit = self.bag.next_window() or (None, None)
            if energy is not None and recorded_bit is None and self.bits.needs_samples:
                samples = self.bag.last_samples
        elif self.replay.samples:
            samples = self.replay.next_window()
            energy = None if samples is None else 0.0  # the bit source measures it
        else:
            energy = self.replay.next_energy()
        if energy is None:
            if not self.ended:
                self.ended = True
                if self._pace_timer is not None:
                    self._pace_timer.cancel()
                path = self.bag.directory if self.bag is not None else self.replay.path
                self.get_logger().info(f"end of {path} after {self.windows} windows")
                if self.exit_at_end:
                    self._finish_publishing()
            self.ended = True
            return None
        if self.pacer is not None:
            self.pacer.sent(time.monotonic())
        return self._window(energy, samples, recorded_bit)

    def _on_decision(self, msg: Int64MultiArray, stamp: int) -> None:
        decision = parse_decision(msg)
        if decision is None or decision.stream != self.stream_id:
            return
        before = self.outbox.last_answered
        self.outbox.answered(decision.step)
        if self.outbox.last_answered == before:
            return  # a repeated answer (a second controller): it releases nothing
        self._tell_decisions(before, decision.step, decision.vocalize)
        if (
            self.started
            and self.pacer is not None
            and decision.step == self.outbox.last_step
            and self.pacer.answered()
        ):
            self._emit_from_file()
        self._release()

    def _tell_decisions(self, before: int, step: int, vocalize: bool) -> None:
        """Hand the bit source the decisions on steps ``before + 1 .. step`` (in order).

        A threshold that labels windows by the timer (``background``) needs them; the steps
        skipped by this answer (their decisions never came) are lost decisions.
        """
        for answered in range(before + 1, step + 1):
            generation = self._step_generation.pop(answered, None)
            if generation == self._generation and self.bits.needs_decisions:
                self.bits.note_decision(int(vocalize) if answered == step else None)

    def _on_audio(self, msg: Float32MultiArray, info: dict[str, Any]) -> None:
        if 0 < int(info.get("source_timestamp", 0)) < self.started_ns:
            self.stale_messages += 1  # published before this node started
            return
        sequence = info.get("publication_sequence_number")
        if isinstance(sequence, int) and 0 < sequence < 2**63:
            if self._last_sequence is not None and sequence > self._last_sequence + 1:
                self.dropped_chunks += sequence - self._last_sequence - 1
                self.losses.note(self.now_s())
                self.assembler.reset()
            self._last_sequence = sequence
        chunk = np.frombuffer(msg.data, dtype=np.float32)
        try:
            if self.bits.needs_samples:
                windows = self.assembler.push_windows(chunk)
            else:
                energies = self.assembler.push(chunk)
        except AudioError as error:
            self.bad_chunks += 1
            self.losses.note(self.now_s())
            self.log_throttled("bad chunk", "warning", f"audio chunk ignored: {error}")
            return
        if self.bits.needs_samples:
            for samples in windows:
                self._window(0.0, samples)
            return
        for energy in energies:
            self._window(float(energy))

    def _read_microphone(self) -> None:
        for window in self.microphone.read_windows(0.0):
            if self.finished.done():
                return
            self._note_window(window)
            self._window(window.energy_db, window.samples if self.bits.needs_samples else None)
            self.window_delay_s = time.monotonic() - window.end_time
            self.max_window_delay_s = max(self.window_delay_s, self.max_window_delay_s)

    def _note_window(self, window: Window) -> None:
        """Count a live window's losses; log the gap before it, if any."""
        if window.segment != self.segment:
            self.segment = window.segment
            self.losses.note(self.now_s())
            self.get_logger().warning(
                f"audio gap of {window.gap_s:.2f} s before window {window.index}: the step"
                " clock goes on, without bits for the missing time"
            )
        if not window.intact:
            self.windows_with_loss += 1
            self.losses.note(self.now_s())

    def _window(
        self,
        energy_db: float,
        samples: np.ndarray | None = None,
        recorded_bit: bool | None = None,
    ) -> bool | None:
        """A window was made: its bit (after calibration) waits in the outbox to go out.

        ``samples``: the window's samples, for a bit source that needs them (then its
        energy comes from the bit source and ``energy_db`` is not used).
        ``recorded_bit``: the bit a session bag without audio recorded for it (the bit
        source is not applied). Returns the bit (None for a calibration window).
        """
        was_calibrating = self.bits.calibrating and recorded_bit is None
        if recorded_bit is not None:
            bit: bool | None = recorded_bit
        elif samples is None:
            bit = self.bits.push(energy_db)
        else:
            bit = self.bits.push_window(samples)
            energy_db = self.bits.last_energy_db
        self.last_energy_db = energy_db
        if bit is None:  # a calibration window: its energy only
            self.energy_pub.publish(Float32(data=energy_db))
            return None
        if was_calibrating:
            self.get_logger().info(self.bits.ready_message())
        dropped = self.outbox.dropped
        self.outbox.push((energy_db, bit, self._generation if recorded_bit is None else -1))
        if self.outbox.dropped > dropped and self.bits.needs_decisions:
            self.bits.note_decision(None)  # a dropped window gets no decision
        if self.outbox.dropped > dropped:
            self.losses.note(self.now_s())
            self.log_throttled(
                "windows dropped",
                "warning",
                f"{self.outbox.dropped} windows dropped: more than"
                f" {self.config.max_backlog_s:g} s waited for the controller",
            )
        self._release()
        return bit

    def _release(self) -> None:
        """Publish the windows the outbox lets go now: energy, bit and stamped bit."""
        if not self.started or self.finished.done():
            return
        outbox = self.outbox
        # Pacing matters only when more would go out than may be unanswered: only then ask
        # the graph whether a controller answers (one query per window is measurable).
        paced = (
            outbox.in_flight + outbox.backlog > outbox.max_ahead
            and self._decisions_sub.get_publisher_count() > 0
        )
        for step, (energy_db, bit, generation) in self.outbox.release(paced):
            self.windows += 1
            if generation >= 0 and self.bits.needs_decisions:
                self._step_generation[step] = generation
            self.energy_pub.publish(Float32(data=energy_db))
            self.sound_pub.publish(Bool(data=bit))
            self.step_pub.publish(
                bit_message(StepBit(self.stream_id, step, bit, self.window_us))
            )
            if self.max_windows and self.windows >= self.max_windows:
                self.get_logger().info(f"{self.windows} bits published (max_windows): stopping")
                self._finish_publishing()
                return

    def _finish_publishing(self) -> None:
        """Publish the final diagnostics; finish (exit status 0) once all was acknowledged."""
        self.publish_diagnostics()
        for publisher in self.publishers:
            publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
        self.finish(0)

    def destroy_node(self) -> None:
        """Release the microphone, then the node."""
        if self.microphone is not None:
            self.microphone.close()
        super().destroy_node()

    # ------------------------------------------------------------------ live threshold

    def _live_threshold_parameters(self) -> None:
        """Let threshold_db, threshold_mode, threshold_file and refresh_s change live."""
        live = self.parameters.live
        live("threshold_db", self._set_threshold, self._check_fixed_threshold)
        live("threshold_mode", self._set_threshold_mode, self._check_threshold_mode)
        live("threshold_file", self._set_threshold_file, self._check_threshold_file)
        live("refresh_s", self._set_refresh, self._check_refresh)

    def _check_has_threshold(self, name: str, value: Any) -> None:
        """A live threshold parameter needs a threshold that decides the bits."""
        if self.config.bit_source == "vad":
            raise ConfigError(
                f"parameter {name!r} = {value!r} has no effect with bit_source vad (no"
                " threshold)"
            )
        if self.bag is not None and not self.bag.has_audio:
            raise ConfigError(
                f"parameter {name!r} = {value!r} has no effect: the session"
                f" {self.config.bag_dir} holds no audio, its recorded bits are replayed"
            )

    def _calibrate_ahead(self, bits: BitSource, config: MicConfig, log: bool = True) -> None:
        """Calibrate ``bits`` on the first ``calibration_s`` seconds of the wav file or bag."""
        reader = self.replay if self.replay is not None else self.bag
        if bits.needs_samples:
            fit = bits.calibrate_windows(
                reader.calibration_windows(config.calibration_s, self.window_s)
            )
        else:
            fit = bits.rule.calibrate(
                reader.calibration_energies(config.calibration_s, self.window_s)
            )
        if log:
            path = config.wav_file if self.replay is not None else config.bag_dir
            self.get_logger().info(
                f"threshold {fit.threshold_db:.2f} dB from the first"
                f" {fit.n_low + fit.n_high} windows of {path} (quiet"
                f" {fit.low_mean_db:.1f} dB, sound {fit.high_mean_db:.1f} dB)"
            )

    def _use_bits(self, bits: BitSource) -> None:
        """Put ``bits`` (a new threshold rule, same kind) in force from the next window.

        The speech-band filter of the source in force carries over (its state is the
        audio so far, not the threshold), so the next window's band level is unchanged.
        """
        if getattr(self.bits, "band", None) is not None:
            bits.band = self.bits.band
        self.bits = bits
        self._generation += 1  # decisions on the old source's bits are not the new one's
        self._step_generation.clear()

    def _check_threshold_mode(self, mode: str) -> None:
        """A live ``threshold_mode`` must make a bit source (else the set is refused)."""
        self._threshold_bits(mode)

    def _threshold_bits(self, mode: str, log: bool = False) -> BitSource:
        """The bit source of threshold_mode ``mode`` now; ConfigError if it cannot be made.

        The source keeps its kind (``bit_source``): it is made by ``make_bit_source``
        again. ``fixed`` takes the ``threshold_db`` parameter, ``file`` loads and checks
        ``threshold_file`` (its error is the refusal), ``calibrate`` calibrates a wav file
        on its first ``calibration_s`` seconds, any other source on its next windows;
        ``noise_floor`` starts a new floor on the next ``calibration_s`` seconds.
        """
        self._check_has_threshold("threshold_mode", mode)
        config = dataclasses.replace(
            self.config,
            threshold_mode=mode,
            threshold_db=self.get_parameter("threshold_db").value,
            threshold_file=self.get_parameter("threshold_file").value,
        )
        check_threshold_file(mode, config.threshold_file)
        _check_bit_source(config)
        try:
            bits = make_binarizer(config, self._calibration_refused)
            if mode == "calibrate" and self.replay is not None:
                self._calibrate_ahead(bits, config, log)
        except AudioError as error:
            raise ConfigError(str(error)) from None
        return bits

    def _set_threshold_mode(self, mode: str) -> None:
        """Switch to threshold_mode ``mode`` (setting the same mode again starts it anew)."""
        self._use_bits(self._threshold_bits(mode, log=True))
        self.config = dataclasses.replace(self.config, threshold_mode=mode)
        rule = self.binarizer
        if rule.calibrating:
            windows = (
                rule.calibration_windows if mode == "calibrate" else rule.warmup_windows
            )
            what = {
                "noise_floor": "starting the noise floor",
                "background": "hearing the room's background",
            }.get(mode, "calibrating")
            self.get_logger().info(
                f"{what} on the next {windows} windows: no bits until then (their energies"
                " are published)"
            )
        else:
            self.get_logger().info(
                f"threshold_mode {mode}: threshold {rule.threshold_db:.2f} dB from the next"
                " window on"
            )

    def _check_threshold_file(self, path: str) -> None:
        """In threshold_mode file, a new ``threshold_file`` must load (for this source's level)."""
        self._check_has_threshold("threshold_file", path)
        if self.config.threshold_mode != "file":
            return  # kept for a later switch to threshold_mode file
        check_threshold_file("file", path)
        try:
            load_threshold(path, self.config.bit_source)
        except AudioError as error:
            raise ConfigError(str(error)) from None

    def _set_threshold_file(self, path: str) -> None:
        """Use the threshold of ``path`` at once in threshold_mode file; else keep it for later."""
        self.config = dataclasses.replace(self.config, threshold_file=path)
        if self.config.threshold_mode == "file":
            self._use_bits(make_binarizer(self.config, self._calibration_refused))

    def _check_refresh(self, refresh_s: float) -> None:
        self._check_has_threshold("refresh_s", refresh_s)
        check_refresh(refresh_s, self.window_s)
        _check_bit_source(dataclasses.replace(self.config, refresh_s=refresh_s))

    def _set_refresh(self, refresh_s: float) -> None:
        """A new refresh buffer (empty) of ``refresh_s`` seconds; the threshold in force stays.

        During a calibration the calibration starts again with the new buffer. With
        threshold_mode noise_floor (``refresh_s`` 0 only) the floor goes on as it is.
        """
        self.config = dataclasses.replace(self.config, refresh_s=refresh_s)
        if self.config.threshold_mode == "noise_floor":
            return
        keep = self.binarizer.threshold_db
        if keep is None:
            self._use_bits(self._threshold_bits(self.config.threshold_mode))
        else:
            self._use_bits(make_binarizer(self.config, self._calibration_refused, keep))

    def _check_fixed_threshold(self, value: float) -> None:
        """A live ``threshold_db`` needs ``threshold_mode`` fixed (else it would be ignored)."""
        self._check_has_threshold("threshold_db", value)
        mode = self.get_parameter("threshold_mode").value
        if mode != "fixed":
            raise ConfigError(
                f"parameter 'threshold_db' = {value!r} has no effect with threshold_mode"
                f" {mode!r}: set threshold_mode fixed first (live) to set it"
            )

    def _set_threshold(self, value: float) -> None:
        """The next window's bit uses the threshold ``value`` (dB full scale)."""
        self.binarizer.threshold_db = value
        self.config = dataclasses.replace(self.config, threshold_db=value)

    # ------------------------------------------------------------------ diagnostics

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Threshold, windows, steps, losses, lockstep timeouts, the live device."""
        b = self.bits
        now = self.now_s()
        values: dict[str, Any] = {
            "source": self.source,
            "stream": self.stream_id,
            "windows": self.windows,
            "steps_answered": self.outbox.last_answered,
            "steps_waiting": self.outbox.backlog,
            "windows_dropped": self.outbox.dropped,
            "bit_source": self.config.bit_source,
            "last_energy_db": self.last_energy_db,
            "dropped_chunks": self.dropped_chunks,
            "bad_chunks": self.bad_chunks,
            **b.diagnostic_values(),
        }
        for topic, names in self.intruders.items():
            values[f"publishers_{topic}"] = ", ".join(names)
        if self.pacer is not None:
            values["lockstep_timeouts"] = self.pacer.timeouts
        if self.microphone is not None:
            live = self.microphone.status().as_dict()
            live["captured_windows"] = live.pop("windows")
            values.update(live)
            values["windows_with_loss"] = self.windows_with_loss
            values["window_delay_s"] = self.window_delay_s
            values["max_window_delay_s"] = self.max_window_delay_s
        if self.intruders:
            return ERROR, "another publisher on 'sound' or 'sound_step'", values
        if not self.started:
            return (
                WARN,
                f"waiting for {self.wait_for_listeners} listeners on '{SOUND_STEP}'",
                values,
            )
        if values.get("state") == DISCONNECTED:
            return ERROR, f"microphone disconnected, retrying: {values['last_error']}", values
        if b.state == UNSEPARATED:
            return ERROR, b.calibration_problem, values
        if b.calibrating:
            return OK, "calibrating the threshold", values
        if self.losses.recent(now) or self.timeouts.recent(now):
            return WARN, "audio lost or lockstep timeouts lately (counts in the values)", values
        problems = b.problems() if hasattr(b, "problems") else []
        if problems:
            return WARN, problems[0], values
        return OK, f"{self.windows} windows", values


def open_bag_replay(config: MicConfig, samples: bool = False) -> BagReplay:
    """The session bag of ``source: bag`` (keeping its windows' samples if ``samples``)."""
    # Imported here: the bag library takes about 0.1 s of CPU to load, and only this
    # source needs it.
    from infomax_contingency.audio.bag_replay import BagReplay

    try:
        return BagReplay(Path(config.bag_dir), config.window_s, config.audio_rate_hz, samples)
    except (OSError, AudioError) as error:
        raise ConfigError(f"parameter 'bag_dir' = {config.bag_dir!r}: {error}") from None


def main(args: list[str] | None = None) -> int:
    """Run the mic node."""
    return run_node(MicNode, args)


if __name__ == "__main__":
    sys.exit(main())

"""Live audio through PortAudio (sounddevice): microphone windows, the robot's sound, calibration.

The live counterpart of the wav source: a :class:`MicrophoneStream` turns a real
microphone into the same window energies that :func:`~infomax_contingency.audio.signal.load_mono`
plus :func:`~infomax_contingency.audio.signal.window_energies_db` give for a recording of it, and a
:class:`SpeakerOutput` plays the robot's sound and reports when it really started.

Conventions:
    * Devices are chosen with a *spec*: ``None`` or ``""`` (the system default), an index
      (``3`` or ``"3"``), or a case-insensitive part of the device name (first match).
      :func:`resolve_device` turns a spec into a :class:`DeviceInfo`; a spec that matches
      nothing raises :class:`AudioDeviceError` listing the devices there are.
    * Times are ``time.monotonic()`` seconds. PortAudio's stream clock (the ADC time of
      input, the DAC time of output) is mapped onto it once per stream; on Linux/ALSA the
      two clocks are the same (CLOCK_MONOTONIC). To stamp a ROS message, use
      ``now_ros - (time.monotonic() - t)``.
    * Samples are float32 from PortAudio, float64 after mixing; the processing rate is
      :data:`~infomax_contingency.audio.signal.PROCESSING_RATE_HZ`.

Threads: the PortAudio callbacks only copy data into bounded queues and bump counters.
Everything else (resampling, windows, reconnecting) runs in the thread that calls
:meth:`MicrophoneStream.read_windows` (e.g. a node's timer), never in the callback.

``sounddevice`` is imported lazily (:func:`import_sounddevice`), so this module imports on
machines without PortAudio; the error then says to install ``libportaudio2``.

Wiring in a node (the reader runs in the node's own thread, e.g. a 20 ms timer)::

    mic = MicrophoneStream(device, window_s=dt, channel=channel, log=log).start()
    for window in mic.read_windows(0.0):     # in the timer; never blocks
        publish(window.energy_db)            # window.lost_samples / gap_s: diagnostics
    values = mic.status().as_dict()          # diagnostics key/values

    speaker = SpeakerOutput(device, sound=wav_or_none, volume=volume, log=log).start()
    speaker.play()                           # on vocalize: true; never blocks
    for event in speaker.events():           # in a timer: when each sound really started
        publish(event.start_time)
"""

from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.signal import (
    PROCESSING_RATE_HZ,
    AudioError,
    WindowAssembler,
    load_mono,
    read_wav,
    resample,
    synthesize_chirp,
    to_mono,
    window_energies_db,
    window_samples,
)

INPUT = "input"
OUTPUT = "output"
_KINDS = (INPUT, OUTPUT)

FALLBACK_RATES_HZ = (48000, 44100)
"""Rates tried (after the requested one and the device's default) when opening a device."""

CONNECTED = "connected"
DISCONNECTED = "disconnected"
CLOSED = "closed"

_CLOSE_WAIT_S = 1.0
"""How long a reconnect waits for a dead stream to close before abandoning it, seconds."""

_log = logging.getLogger(__name__)

LogFunction = Callable[[str, str], None]
"""``log(level, message)`` with level ``"info"``, ``"warning"`` or ``"error"``."""


class AudioDeviceError(AudioError):
    """An audio device is missing, unusable, or PortAudio itself is not installed."""


def _default_log(level: str, message: str) -> None:
    getattr(_log, level)(message)


# --------------------------------------------------------------------------- PortAudio


def import_sounddevice() -> ModuleType:
    """Import and return ``sounddevice``.

    Raises:
        AudioDeviceError: the PortAudio library (``libportaudio2``) or the sounddevice
            package is missing; the message says how to install it.
    """
    try:
        import sounddevice
    except OSError as exc:  # sounddevice raises OSError when libportaudio is not found
        raise AudioDeviceError(
            f"the PortAudio library is missing ({exc}); install it, e.g. "
            "`sudo apt-get install libportaudio2` (Debian/Ubuntu), then try again"
        ) from exc
    except ImportError as exc:
        raise AudioDeviceError(
            f"the Python package sounddevice is missing ({exc}); install it with "
            "`pip install sounddevice` (and `sudo apt-get install libportaudio2`)"
        ) from exc
    return sounddevice


@dataclasses.dataclass(frozen=True)
class DeviceInfo:
    """One PortAudio device.

    Attributes:
        index: PortAudio device index (valid until the device list is rescanned).
        name: device name as PortAudio reports it.
        hostapi: host API name (ALSA, JACK, ...).
        max_input_channels: input channels (0: not an input device).
        max_output_channels: output channels (0: not an output device).
        default_rate: the device's default sample rate, Hz.
    """

    index: int
    name: str
    hostapi: str
    max_input_channels: int
    max_output_channels: int
    default_rate: int

    def channels(self, kind: str) -> int:
        """Channels of the ``kind`` (``"input"`` or ``"output"``) side."""
        return self.max_input_channels if kind == INPUT else self.max_output_channels

    def describe(self, kind: str) -> str:
        """One line: ``[index] name (host API, channels, default rate)``."""
        return (
            f"[{self.index}] {self.name} ({self.hostapi}, {self.channels(kind)} ch, "
            f"{self.default_rate} Hz)"
        )


class AudioBackend(Protocol):
    """What this module needs from PortAudio; :class:`SoundDeviceBackend` is the real one.

    Streams returned by :meth:`open` have ``start()``, ``close(ignore_errors=True)``, the
    properties ``active`` and ``time`` (the stream clock, seconds), and call
    ``callback(data, frames, time_info, status)`` like sounddevice's callback streams.
    """

    def devices(self) -> list[DeviceInfo]:
        """Every device, in index order."""

    def default_index(self, kind: str) -> int | None:
        """Index of the system default device of ``kind``, or None if there is none."""

    def check(self, kind: str, index: int, rate: int, channels: int) -> None:
        """Raise an exception unless the device opens with these settings."""

    def open(
        self,
        kind: str,
        index: int,
        rate: int,
        channels: int,
        blocksize: int,
        callback: Callable[..., None],
        finished_callback: Callable[[], None],
    ) -> Any:
        """Open a float32 callback stream (not yet started)."""

    def rescan(self) -> None:
        """Re-read the device list (closes every PortAudio stream of the process)."""


class SoundDeviceBackend:
    """:class:`AudioBackend` on the sounddevice package (PortAudio)."""

    def __init__(self) -> None:
        self.sd = import_sounddevice()

    def devices(self) -> list[DeviceInfo]:
        """Every device, in index order."""
        hostapis = self.sd.query_hostapis()
        return [
            DeviceInfo(
                index=int(d["index"]),
                name=str(d["name"]),
                hostapi=str(hostapis[d["hostapi"]]["name"]),
                max_input_channels=int(d["max_input_channels"]),
                max_output_channels=int(d["max_output_channels"]),
                default_rate=int(round(d["default_samplerate"])),
            )
            for d in self.sd.query_devices()
        ]

    def default_index(self, kind: str) -> int | None:
        """Index of the system default device of ``kind``, or None."""
        index = self.sd.default.device[0 if kind == INPUT else 1]
        return None if index is None or int(index) < 0 else int(index)

    def check(self, kind: str, index: int, rate: int, channels: int) -> None:
        """Raise ``sounddevice.PortAudioError`` unless the settings are supported."""
        check = self.sd.check_input_settings if kind == INPUT else self.sd.check_output_settings
        check(device=index, samplerate=rate, channels=channels, dtype="float32")

    def open(
        self,
        kind: str,
        index: int,
        rate: int,
        channels: int,
        blocksize: int,
        callback: Callable[..., None],
        finished_callback: Callable[[], None],
    ) -> Any:
        """Open a float32 sounddevice callback stream (not yet started)."""
        cls = self.sd.InputStream if kind == INPUT else self.sd.OutputStream
        return cls(
            device=index,
            samplerate=rate,
            channels=channels,
            dtype="float32",
            blocksize=blocksize,
            callback=callback,
            finished_callback=finished_callback,
        )

    def rescan(self) -> None:
        """Terminate and re-initialize PortAudio so that it lists the devices anew.

        sounddevice has no public call for this; ``_terminate``/``_initialize`` are the
        documented way (they close every stream of the process).
        """
        self.sd._terminate()
        self.sd._initialize()


def _backend_or_default(backend: AudioBackend | None) -> AudioBackend:
    return SoundDeviceBackend() if backend is None else backend


# --------------------------------------------------------------------------- devices


def _check_kind(kind: str) -> str:
    if kind not in _KINDS:
        raise ValueError(f"kind must be 'input' or 'output', got {kind!r}")
    return kind


def list_devices(kind: str, backend: AudioBackend | None = None) -> list[DeviceInfo]:
    """The devices that have ``kind`` (``"input"`` or ``"output"``) channels."""
    kind = _check_kind(kind)
    return [d for d in _backend_or_default(backend).devices() if d.channels(kind) > 0]


def format_devices(kind: str, backend: AudioBackend | None = None) -> str:
    """A list of the ``kind`` devices, one per line, the system default marked."""
    backend = _backend_or_default(backend)
    devices = list_devices(kind, backend)
    if not devices:
        return f"  (none: PortAudio sees no {kind} device)"
    default = backend.default_index(kind)
    return "\n".join(
        "  " + d.describe(kind) + ("  <- system default" if d.index == default else "")
        for d in devices
    )


def _device_error(what: str, kind: str, backend: AudioBackend) -> AudioDeviceError:
    devices = list_devices(kind, backend)
    if not devices:
        tool = "arecord -l" if kind == INPUT else "aplay -l"
        return AudioDeviceError(
            f"{what}: PortAudio sees no {kind} device at all. Connect one, check that the"
            f" system sees it (`{tool}`), then try again."
        )
    word = (devices[0].name.split() or ["USB"])[0].strip(":,()")
    return AudioDeviceError(
        f"{what}. Available {kind} devices:\n{format_devices(kind, backend)}\n"
        f"Choose one by its index (e.g. {devices[0].index}) or by a part of its name"
        f" (e.g. '{word}'); leave the device empty for the system default."
    )


def resolve_device(
    spec: int | str | None, kind: str = INPUT, backend: AudioBackend | None = None
) -> DeviceInfo:
    """The device a spec names.

    Args:
        spec: ``None`` or ``""`` for the system default; an int or a string of digits for
            a device index; any other string is matched, case-insensitively, against the
            device names and the first device (lowest index) containing it wins.
        kind: ``"input"`` (microphones) or ``"output"`` (loudspeakers); only devices with
            channels of this kind qualify.
        backend: PortAudio access (default: sounddevice).

    Returns:
        The device; log its ``name`` so a substring match is visible.

    Raises:
        AudioDeviceError: nothing matches (the message lists the available devices and
            how to choose one), or PortAudio is not installed.
    """
    kind = _check_kind(kind)
    backend = _backend_or_default(backend)
    devices = backend.devices()
    by_index = {d.index: d for d in devices}
    if isinstance(spec, bool):
        raise AudioDeviceError(f"device must be an index or a name, got {spec!r}")
    if spec is None or (isinstance(spec, str) and not spec.strip()):
        index = backend.default_index(kind)
        if index is None or index not in by_index or by_index[index].channels(kind) == 0:
            raise _device_error(f"there is no default {kind} device", kind, backend)
        return by_index[index]
    if isinstance(spec, int | np.integer) or (isinstance(spec, str) and spec.strip().isdigit()):
        index = int(spec)
        device = by_index.get(index)
        if device is None:
            raise _device_error(f"there is no audio device with index {index}", kind, backend)
        if device.channels(kind) == 0:
            raise _device_error(
                f"device {index} ({device.name}) has no {kind} channels", kind, backend
            )
        return device
    if not isinstance(spec, str):
        raise AudioDeviceError(f"device must be an index or a name, got {spec!r}")
    needle = spec.strip().lower()
    for device in devices:
        if device.channels(kind) > 0 and needle in device.name.lower():
            return device
    raise _device_error(f"no {kind} device name contains {spec.strip()!r}", kind, backend)


def _candidates(*values: int | None) -> list[int]:
    """The positive values in order, without repeats."""
    out: list[int] = []
    for v in values:
        if v is not None and v > 0 and v not in out:
            out.append(int(v))
    return out


def negotiate_format(
    device: DeviceInfo,
    kind: str,
    rate: int | None,
    channels: int,
    backend: AudioBackend,
) -> tuple[int, int, list[str]]:
    """Find a sample rate and channel count the device opens with.

    Rates are tried in the order: ``rate`` (if given), the device's default rate, then
    :data:`FALLBACK_RATES_HZ`; channel counts: ``channels``, then all the device's
    channels (many multi-channel arrays only open with all of them).

    Returns:
        ``(rate, channels, refusals)``: the first combination the device accepts, and one
        line per refused combination (to log why the requested rate was not used).

    Raises:
        AudioDeviceError: no combination works; the message lists every refusal.
    """
    rates = _candidates(rate, device.default_rate, *FALLBACK_RATES_HZ)
    counts = _candidates(channels, device.channels(kind))
    refusals: list[str] = []
    for r in rates:
        for c in counts:
            try:
                backend.check(kind, device.index, r, c)
            except Exception as exc:  # PortAudioError, ValueError: the device says no
                refusals.append(f"{r} Hz x {c} ch: {exc}")
                continue
            return r, c, refusals
    raise AudioDeviceError(
        f"{kind} device {device.describe(kind)} opens with none of the tried formats:\n  "
        + "\n  ".join(refusals)
    )


# --------------------------------------------------------------------------- resampling


class StreamResampler:
    """Streaming polyphase resampler reproducing :func:`~infomax_contingency.audio.signal.resample`.

    ``audio.resample`` is ``scipy.signal.resample_poly`` over a whole signal. This class
    computes exactly the same output samples (bit for bit) from chunks of any size: the
    same FIR filter (``firwin``, Kaiser window beta 5, half-length 10 x max(up, down)) is
    applied with ``upfirdn`` to the buffered input, and an output sample is emitted once
    every input it depends on has arrived (a delay of about ``10 * max(up, down) / up``
    input samples, under 1 ms for 48 kHz -> 16 kHz). The stream start is treated like the
    start of a signal (zeros before it); the end of a stream never comes, so the last few
    outputs wait for more input. :meth:`reset` starts a new signal (after a gap).

    Args:
        from_rate: input rate, Hz.
        to_rate: output rate, Hz.
    """

    def __init__(self, from_rate: int, to_rate: int) -> None:
        g = math.gcd(int(from_rate), int(to_rate))
        self.up, self.down = int(to_rate) // g, int(from_rate) // g
        self.reset()
        if self.up == self.down:
            return
        half_len = 10 * max(self.up, self.down)
        from scipy.signal import firwin, upfirdn  # lazy: scipy.signal takes ~0.5 s to load

        self._upfirdn = upfirdn
        h = firwin(2 * half_len + 1, 1.0 / max(self.up, self.down), window=("kaiser", 5.0))
        pre_pad = self.down - half_len % self.down
        self._h = np.concatenate((np.zeros(pre_pad), h * self.up))
        self._skip = (half_len + pre_pad) // self.down  # leading outputs resample_poly drops

    def reset(self) -> None:
        """Forget the input so far; the next chunk starts a new signal."""
        self._buf = np.empty(0)
        self._buf_start = 0  # input index of _buf[0]
        self._n_in = 0  # inputs received
        self._n_out = 0  # outputs emitted

    def _first_input_needed(self, out_index: int) -> int:
        """Segment start for output ``out_index``: a multiple of ``down`` before its inputs."""
        k = out_index + self._skip
        lowest = max(0, -(-(k * self.down - (self._h.size - 1)) // self.up))
        return lowest // self.down * self.down

    def push(self, chunk: ArrayLike) -> NDArray[np.float64]:
        """Add mono input samples; return the output samples that are now complete."""
        x = np.asarray(chunk, dtype=np.float64)
        if self.up == self.down:
            return x.copy()
        self._buf = np.concatenate((self._buf, x))
        self._n_in += x.size
        end = (self._n_in * self.up - 1) // self.down - self._skip + 1
        if end <= self._n_out:
            return np.empty(0)
        start = self._first_input_needed(self._n_out)
        y = self._upfirdn(self._h, self._buf[start - self._buf_start :], self.up, self.down)
        offset = start * self.up // self.down - self._skip
        out = y[self._n_out - offset : end - offset]
        self._n_out = end
        keep = self._first_input_needed(end)
        self._buf = self._buf[keep - self._buf_start :]
        self._buf_start = keep
        return out


# --------------------------------------------------------------------------- microphone


@dataclasses.dataclass(frozen=True)
class Window:
    """One microphone window.

    Attributes:
        index: windows emitted by this stream before this one.
        energy_db: mean energy, dB (as :func:`..signal.window_energies_db`).
        start_time: ADC time of the window's first sample, ``time.monotonic()`` seconds.
        end_time: ADC time just after its last sample (``start_time + window_s`` plus any
            lost audio inside).
        lost_samples: device-rate samples known to be lost inside the window (blocks the
            reader was too slow to take, plus the estimated length of input overflows).
        overflows: PortAudio input overflows (xruns) reported inside the window.
        segment: 0 for the first stretch of continuous audio, +1 after every gap.
        gap_s: missing audio right before this window, seconds: > 0 only for the first
            window after a gap (a reconnect, or a loss of a whole window or more). No
            window is made up for the missing time.
    """

    index: int
    energy_db: float
    start_time: float
    end_time: float
    lost_samples: int = 0
    overflows: int = 0
    segment: int = 0
    gap_s: float = 0.0

    @property
    def intact(self) -> bool:
        """True if no sample of the window was lost."""
        return self.lost_samples == 0 and self.overflows == 0


@dataclasses.dataclass(frozen=True)
class AudioChunk:
    """Mono samples at the processing rate, as :meth:`MicrophoneStream.read_audio` returns them.

    Attributes:
        samples: float64 mono samples at ``MicrophoneStream.rate``.
        start_time: ADC time of ``samples[0]``, ``time.monotonic()`` seconds.
        lost_samples: device-rate samples lost right before this chunk.
        overflows: input overflows reported with this chunk.
        segment: continuity segment (see :attr:`Window.segment`).
    """

    samples: NDArray[np.float64]
    start_time: float
    lost_samples: int
    overflows: int
    segment: int


@dataclasses.dataclass(frozen=True)
class MicrophoneStatus:
    """Counters and state of a :class:`MicrophoneStream`, for diagnostics.

    Attributes:
        state: ``"connected"``, ``"disconnected"`` (retrying) or ``"closed"``.
        device: name of the device in use (or last used).
        device_index: its PortAudio index.
        device_rate: rate the device is opened at, Hz.
        rate: processing rate of the windows, Hz.
        channels: channels opened.
        windows: windows emitted.
        overflows: PortAudio input overflows (xruns).
        dropped_blocks: callback blocks dropped because the queue was full.
        lost_samples: device-rate samples known lost (dropped blocks, estimated xruns).
        gaps: gaps (reconnects, losses of a window or more).
        gap_total_s: total missing audio over the gaps, seconds.
        disconnects: times the device was found gone or silent.
        reconnects: successful reopenings.
        reconnect_attempts: failed and successful reopening attempts.
        last_error: the latest problem, "" if none.
    """

    state: str
    device: str
    device_index: int | None
    device_rate: int
    rate: int
    channels: int
    windows: int
    overflows: int
    dropped_blocks: int
    lost_samples: int
    gaps: int
    gap_total_s: float
    disconnects: int
    reconnects: int
    reconnect_attempts: int
    last_error: str

    def as_dict(self) -> dict[str, Any]:
        """The fields as a dict (e.g. for diagnostic key/values)."""
        return dataclasses.asdict(self)


class _Block:
    """What the input callback hands to the reader (plain slots, no validation)."""

    __slots__ = ("data", "dropped_before", "generation", "overflow", "time")

    def __init__(
        self, generation: int, data: np.ndarray, t: float, dropped_before: int, overflow: bool
    ) -> None:
        self.generation = generation
        self.data = data
        self.time = t
        self.dropped_before = dropped_before
        self.overflow = overflow


def _check_positive(value: float, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise AudioError(f"{name} must be a positive number, got {value!r}")
    if not math.isfinite(value):
        raise AudioError(f"{name} must be finite, got {value!r}")
    return float(value)


class MicrophoneStream:
    """A live microphone cut into windows, with reconnection when the device vanishes.

    The PortAudio callback copies each block into a bounded queue (a full queue drops the
    block and counts it). The reader thread (:meth:`read_windows` or :meth:`read_audio`)
    mixes the blocks to mono (mean, or one ``channel``), resamples them exactly to
    ``rate`` (:class:`StreamResampler`) when the device runs at another rate, and cuts
    windows with :class:`~infomax_contingency.audio.signal.WindowAssembler`. Uninterrupted
    audio therefore gives exactly the energies of the offline computation on a recording
    of the same samples.

    Window times come from PortAudio's ADC time of the first block of a segment,
    advanced by the samples counted since (plus lost samples), so a late reader does not
    shift them. They follow the device's sample clock: a converter 100 ppm off drifts
    0.36 s per hour from ``time.monotonic()`` (until the next gap re-anchors them).

    Loss: blocks the reader was too slow for are counted exactly; input overflows are
    estimated from the ADC times. A loss shorter than one window is kept inside the
    window it hits (the window is still emitted, with ``lost_samples`` > 0); a longer
    loss is a gap: the partial window is dropped and a new segment starts.

    Vanishing device: a stream that stops (the finished callback fires or it turns
    inactive) or delivers nothing for ``stall_timeout_s`` is closed and the state turns
    ``"disconnected"``. The reader then reopens the device (found again by the same spec)
    with exponential back-off from ``backoff_s[0]`` to ``backoff_s[1]`` seconds and
    resumes; the missing time is a gap (``gap_s`` on the next window), never filled with
    made-up windows. Before reopening, PortAudio rescans the devices when no other stream
    of this module is open in the process (a rescan would close those streams too);
    otherwise the old device list is used.

    Args:
        device: device spec (see :func:`resolve_device`).
        window_s: window length, seconds.
        rate: processing rate of the windows, Hz; the device is opened at this rate when
            it supports it, else at its own rate (resampled).
        channel: ``None`` to average all opened channels, or the 0-based channel to use.
        channels: channels to open; default 1 (or ``channel + 1``); devices that refuse it
            are opened with all their channels.
        block_s: PortAudio block length, seconds.
        queue_s: audio the queue holds before it drops blocks, seconds.
        stall_timeout_s: no data for this long means the device is gone, seconds.
        backoff_s: first and longest wait between reopening attempts, seconds.
        log: ``log(level, message)`` for state changes (default: the logging module).
        backend: PortAudio access (default: sounddevice).
    """

    def __init__(
        self,
        device: int | str | None = None,
        window_s: float = 0.5,
        rate: int = PROCESSING_RATE_HZ,
        channel: int | None = None,
        channels: int | None = None,
        block_s: float = 0.02,
        queue_s: float = 4.0,
        stall_timeout_s: float = 1.5,
        backoff_s: tuple[float, float] = (0.5, 8.0),
        log: LogFunction | None = None,
        backend: AudioBackend | None = None,
    ) -> None:
        self.spec = device
        self.window_s = _check_positive(window_s, "window_s")
        self.rate = int(rate)
        self.samples_per_window = window_samples(self.rate, self.window_s)
        if channel is not None and (isinstance(channel, bool) or not isinstance(channel, int)):
            raise AudioError(f"channel must be None or a 0-based index, got {channel!r}")
        if channel is not None and channel < 0:
            raise AudioError(f"channel must be None or a 0-based index, got {channel!r}")
        self.channel = channel
        wanted = channels if channels is not None else (1 if channel is None else channel + 1)
        if isinstance(wanted, bool) or not isinstance(wanted, int) or wanted < 1:
            raise AudioError(f"channels must be a positive integer, got {channels!r}")
        if channel is not None and channels is not None and channel >= channels:
            raise AudioError(f"channel {channel} does not exist among {channels} channel(s)")
        self._wanted_channels = wanted
        self.block_s = _check_positive(block_s, "block_s")
        self.queue_s = _check_positive(queue_s, "queue_s")
        self.stall_timeout_s = _check_positive(stall_timeout_s, "stall_timeout_s")
        low, high = (_check_positive(b, "backoff_s") for b in backoff_s)
        if high < low:
            raise AudioError(
                f"backoff_s must be (first, longest) with first <= longest: {backoff_s}"
            )
        self.backoff_s = (low, high)
        self._log = log or _default_log
        self._backend_arg = backend
        self._backend: AudioBackend | None = None

        self._lock = threading.Lock()
        self._queue: queue.Queue[_Block] = queue.Queue()
        self._stream: Any = None
        self._generation = 0
        self._state = CLOSED
        self._device: DeviceInfo | None = None
        self._device_rate = 0
        self._open_channels = 0
        self._offset = 0.0  # time.monotonic() - stream clock
        self._closers: list[threading.Thread] = []
        self._backoff = low
        self._next_attempt = 0.0
        # callback-side state (written by the callback thread only)
        self._pending_dropped = 0
        self._last_data = 0.0
        self._finished = False
        # counters
        self._overflows = 0
        self._dropped_blocks = 0
        self._lost_samples = 0
        self._windows = 0
        self._gaps = 0
        self._gap_total_s = 0.0
        self._disconnects = 0
        self._reconnects = 0
        self._attempts = 0
        self._last_error = ""
        # reader-side stream bookkeeping
        self._resampler: StreamResampler | None = None
        self._assembler = WindowAssembler(self.rate, self.window_s)
        self._segment = -1
        self._seg_anchor: float | None = None  # time of the segment's first sample
        self._seg_out = 0  # processing-rate samples of the segment so far
        self._seg_lost_s = 0.0  # lost time inside the segment so far
        self._prev_block_end: float | None = None  # expected time of the next block
        self._win_start = 0  # segment sample index where the filling window starts
        self._win_lost_s_before = 0.0  # lost time before the filling window
        self._win_lost = 0
        self._win_lost_s = 0.0
        self._win_overflows = 0
        self._last_end: float | None = None  # end time of the last window emitted
        self._pending_gap = False

    # ------------------------------------------------------------------ life cycle

    def start(self) -> MicrophoneStream:
        """Open and start the device.

        Raises:
            AudioDeviceError: the device is missing (the message lists the input devices),
                opens with no usable format, or PortAudio is not installed.
        """
        if self._state != CLOSED:
            raise AudioError("the microphone stream is already started")
        self._backend = _backend_or_default(self._backend_arg)
        self._open()
        return self

    def close(self) -> None:
        """Stop capturing and release the device (safe to call twice)."""
        with self._lock:
            self._state = CLOSED
            self._generation += 1
            stream, self._stream = self._stream, None
        _unregister(self)
        if stream is not None:
            _close_stream(stream, wait_s=_CLOSE_WAIT_S)

    def __enter__(self) -> MicrophoneStream:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def device(self) -> DeviceInfo | None:
        """The device in use (None before :meth:`start`)."""
        return self._device

    @property
    def device_rate(self) -> int:
        """Rate the device is opened at, Hz (0 before :meth:`start`)."""
        return self._device_rate

    @property
    def state(self) -> str:
        """``"connected"``, ``"disconnected"`` or ``"closed"``."""
        return self._state

    def status(self) -> MicrophoneStatus:
        """A snapshot of the counters (cheap; call it for every diagnostics message)."""
        d = self._device
        return MicrophoneStatus(
            state=self._state,
            device=d.name if d else "",
            device_index=d.index if d else None,
            device_rate=self._device_rate,
            rate=self.rate,
            channels=self._open_channels,
            windows=self._windows,
            overflows=self._overflows,
            dropped_blocks=self._dropped_blocks,
            lost_samples=self._lost_samples,
            gaps=self._gaps,
            gap_total_s=self._gap_total_s,
            disconnects=self._disconnects,
            reconnects=self._reconnects,
            reconnect_attempts=self._attempts,
            last_error=self._last_error,
        )

    def _open(self) -> None:
        """Resolve the device, pick a format, open and start a stream (raises on failure)."""
        backend = self._backend
        device = resolve_device(self.spec, INPUT, backend)
        rate, channels, refusals = negotiate_format(
            device, INPUT, self.rate, self._wanted_channels, backend
        )
        if self.channel is not None and self.channel >= channels:
            raise AudioDeviceError(
                f"channel {self.channel} does not exist: {device.name} opens with {channels}"
                f" channel(s), numbered 0..{channels - 1}"
            )
        blocksize = max(1, round(self.block_s * rate))
        capacity = max(2, math.ceil(self.queue_s / (blocksize / rate)))
        with self._lock:
            self._generation += 1
            generation = self._generation
            self._queue = queue.Queue(maxsize=capacity)
            self._pending_dropped = 0
            self._finished = False

        def callback(indata: np.ndarray, frames: int, time_info: Any, status: Any) -> None:
            self._on_block(generation, indata, frames, time_info, status)

        def finished() -> None:
            if generation == self._generation:
                self._finished = True

        self._last_data = time.monotonic()
        stream, self._offset = _open_and_start(
            backend, INPUT, device, rate, channels, blocksize, callback, finished
        )
        with self._lock:
            self._stream = stream
            self._device = device
            self._open_channels = channels
            self._state = CONNECTED
        _register(self)
        if rate != self._device_rate or self._resampler is None:
            self._resampler = StreamResampler(rate, self.rate)
        self._device_rate = rate
        self._new_segment()
        if rate != self.rate and refusals:
            self._log(
                "info",
                f"{device.name} does not open at {self.rate} Hz ({refusals[0]}); capturing at"
                f" {rate} Hz and resampling to {self.rate} Hz",
            )
        self._log(
            "info",
            f"microphone: {device.describe(INPUT)} at {rate} Hz, {channels} channel(s)"
            + ("" if self.channel is None else f", using channel {self.channel}"),
        )

    # ------------------------------------------------------------------ callback

    def _on_block(
        self, generation: int, indata: np.ndarray, frames: int, time_info: Any, status: Any
    ) -> None:
        """PortAudio callback: copy the block into the queue; nothing else."""
        if generation != self._generation:
            return
        self._last_data = time.monotonic()
        overflow = bool(status.input_overflow)
        if overflow:
            self._overflows += 1
        t = time_info.inputBufferAdcTime or time_info.currentTime
        try:
            self._queue.put_nowait(
                _Block(generation, indata.copy(), t, self._pending_dropped, overflow)
            )
            self._pending_dropped = 0
        except queue.Full:
            self._pending_dropped += frames
            self._dropped_blocks += 1

    # ------------------------------------------------------------------ reading

    def read_windows(self, timeout: float = 0.0) -> list[Window]:
        """Windows completed since the last call, in order.

        Waits up to ``timeout`` seconds for audio (0: never blocks). Also checks the
        device's health and, while it is disconnected, tries to reopen it when the
        back-off allows, so call it regularly (e.g. from a timer).
        """
        windows: list[Window] = []
        self._read(timeout, lambda block: windows.extend(self._assemble(self._convert(block))))
        return windows

    def read_audio(self, timeout: float = 0.0) -> list[AudioChunk]:
        """Mono processing-rate audio received since the last call, in order.

        Same rules as :meth:`read_windows`; use one or the other on a stream, not both.
        """
        chunks: list[AudioChunk] = []
        self._read(timeout, lambda block: chunks.append(self._convert(block)))
        return chunks

    def _read(self, timeout: float, handle: Callable[[_Block], None]) -> None:
        """Hand every new block of the current stream to ``handle``; keep the device alive."""
        if self._state == CLOSED:
            raise AudioError("the microphone stream is not started (or already closed)")
        deadline = time.monotonic() + max(0.0, timeout)
        got = False
        while True:
            if self._state == DISCONNECTED and time.monotonic() >= self._next_attempt:
                self._reconnect()
            if self._state == CONNECTED:
                generation = self._generation
                for block in self._drain(deadline - time.monotonic()):
                    if block.generation == generation:
                        handle(block)
                        got = True
                self._check_health()
                if got or time.monotonic() >= deadline:
                    return
            elif self._state == CLOSED:
                return
            else:
                now = time.monotonic()
                if now >= deadline:
                    return
                time.sleep(max(0.0, min(deadline, self._next_attempt) - now))

    def _drain(self, wait_s: float) -> list[_Block]:
        """Blocks in the queue; waits up to ``wait_s`` for the first one."""
        blocks: list[_Block] = []
        q = self._queue
        try:
            blocks.append(q.get(timeout=wait_s) if wait_s > 0 else q.get_nowait())
            while True:
                blocks.append(q.get_nowait())
        except queue.Empty:
            pass
        return blocks

    def _check_health(self) -> None:
        stream = self._stream
        if stream is None or self._state != CONNECTED:
            return
        name = self._device.name if self._device else "the microphone"
        if self._finished or not stream.active:
            self._disconnect(f"the audio stream of {name} stopped (device unplugged?)")
        elif time.monotonic() - self._last_data > self.stall_timeout_s:
            self._disconnect(f"no audio from {name} for {self.stall_timeout_s:g} s")

    def _disconnect(self, reason: str) -> None:
        with self._lock:
            self._state = DISCONNECTED
            self._generation += 1
            stream, self._stream = self._stream, None
        _unregister(self)
        self._disconnects += 1
        self._last_error = reason
        self._backoff = self.backoff_s[0]
        self._next_attempt = time.monotonic() + self._backoff
        self._log("warning", f"microphone disconnected: {reason}; retrying")
        if stream is not None:
            closer = _close_stream(stream, wait_s=_CLOSE_WAIT_S)
            if closer is not None:
                self._closers.append(closer)

    def _reconnect(self) -> None:
        self._attempts += 1
        self._closers = [t for t in self._closers if t.is_alive()]
        try:
            if not self._closers and not _other_streams_open(self):
                self._backend.rescan()
            self._open()
        except Exception as exc:  # any failure: wait longer and try again
            self._last_error = f"reconnect failed: {exc}"
            self._next_attempt = time.monotonic() + self._backoff
            self._log(
                "warning",
                f"microphone still unavailable (attempt {self._attempts}, next in"
                f" {self._backoff:g} s): {exc}",
            )
            self._backoff = min(2.0 * self._backoff, self.backoff_s[1])
            return
        self._reconnects += 1
        self._log("info", f"microphone reconnected after {self._attempts} attempt(s)")

    # ------------------------------------------------------------------ assembly

    def _new_segment(self) -> None:
        """Start a continuous stretch of audio: fresh filter, window, time anchor."""
        if self._resampler is not None:
            self._resampler.reset()
        self._assembler.reset()
        self._segment += 1
        self._pending_gap = self._segment > 0
        self._seg_anchor = None
        self._seg_out = 0
        self._seg_lost_s = 0.0
        self._prev_block_end = None
        self._win_start = 0
        self._win_lost_s_before = 0.0
        self._win_lost = 0
        self._win_lost_s = 0.0
        self._win_overflows = 0

    def _convert(self, block: _Block) -> AudioChunk:
        """One queue block to a processing-rate chunk (a long loss starts a new segment)."""
        rate = self._device_rate
        frames = block.data.shape[0]
        t = block.time + self._offset if block.time else None
        lost = block.dropped_before
        if block.overflow and t is not None and self._prev_block_end is not None:
            lost += max(0, round((t - self._prev_block_end) * rate))
        if (
            lost
            and self._seg_anchor is not None
            and lost * self.rate >= (self.samples_per_window * rate)
        ):
            self._lost_samples += lost
            self._new_segment()
            lost = 0
        if self._seg_anchor is None:
            self._seg_anchor = t if t is not None else time.monotonic()
        self._lost_samples += lost
        self._seg_lost_s += lost / rate
        start_time = self._seg_anchor + self._seg_out / self.rate + self._seg_lost_s
        samples = self._resampler.push(to_mono(block.data, self.channel))
        self._seg_out += samples.size
        self._prev_block_end = (t if t is not None else start_time) + frames / rate
        return AudioChunk(samples, start_time, lost, int(block.overflow), self._segment)

    def _assemble(self, chunk: AudioChunk) -> list[Window]:
        """Cut a chunk into windows (losses go to the window being filled)."""
        self._win_lost += chunk.lost_samples
        self._win_lost_s += chunk.lost_samples / self._device_rate
        self._win_overflows += chunk.overflows
        out: list[Window] = []
        n = self.samples_per_window
        for energy in self._assembler.push(chunk.samples):
            start = self._seg_anchor + self._win_start / self.rate + self._win_lost_s_before
            end = start + n / self.rate + self._win_lost_s
            gap = 0.0
            if self._pending_gap:
                gap = max(0.0, start - self._last_end) if self._last_end is not None else 0.0
                self._gaps += 1
                self._gap_total_s += gap
                self._pending_gap = False
            out.append(
                Window(
                    index=self._windows,
                    energy_db=energy,
                    start_time=start,
                    end_time=end,
                    lost_samples=self._win_lost,
                    overflows=self._win_overflows,
                    segment=self._segment,
                    gap_s=gap,
                )
            )
            self._windows += 1
            self._last_end = end
            self._win_start += n
            self._win_lost_s_before += self._win_lost_s
            self._win_lost = 0
            self._win_lost_s = 0.0
            self._win_overflows = 0
        return out


# --------------------------------------------------------------------------- stream registry

_registry_lock = threading.Lock()
_open_owners: set[int] = set()


def _register(owner: object) -> None:
    with _registry_lock:
        _open_owners.add(id(owner))


def _unregister(owner: object) -> None:
    with _registry_lock:
        _open_owners.discard(id(owner))


def _other_streams_open(owner: object) -> bool:
    """True if another object of this module holds an open stream in this process."""
    with _registry_lock:
        return bool(_open_owners - {id(owner)})


def _open_and_start(
    backend: AudioBackend,
    kind: str,
    device: DeviceInfo,
    rate: int,
    channels: int,
    blocksize: int,
    callback: Callable[..., None],
    finished: Callable[[], None],
) -> Any:
    """Open and start a stream.

    Returns:
        ``(stream, offset)``: the running stream and ``time.monotonic()`` minus its clock,
        read before the start (while running, reading the clock can wait for a callback
        blocked in the driver).

    Raises:
        AudioDeviceError: naming the device, if opening or starting fails.
    """
    try:
        stream = backend.open(kind, device.index, rate, channels, blocksize, callback, finished)
        offset = time.monotonic() - float(stream.time)
    except Exception as exc:  # PortAudioError and friends
        raise AudioDeviceError(f"cannot open {kind} device {device.describe(kind)}: {exc}") from exc
    try:
        stream.start()
    except Exception as exc:
        _close_stream(stream, wait_s=_CLOSE_WAIT_S)
        raise AudioDeviceError(
            f"cannot start {kind} device {device.describe(kind)}: {exc}"
        ) from exc
    return stream, offset


def _close_stream(stream: Any, wait_s: float) -> threading.Thread | None:
    """Close a stream in a helper thread; return the thread if it is still busy after ``wait_s``.

    A stream whose device hangs (a blocked read) can take long to close; the caller then
    goes on and the helper finishes (or stays blocked) on its own.
    """

    def close() -> None:
        try:
            stream.close(ignore_errors=True)
        except Exception as exc:  # closing a dead device: nothing more to do
            _log.debug("closing an audio stream failed: %s", exc)

    thread = threading.Thread(target=close, name="audio-stream-close", daemon=True)
    thread.start()
    thread.join(wait_s)
    return thread if thread.is_alive() else None


# --------------------------------------------------------------------------- speaker

OVERLAP_POLICIES = ("restart", "skip")


@dataclasses.dataclass(frozen=True)
class PlayEvent:
    """A sound that started playing.

    Attributes:
        sequence: the number :meth:`SpeakerOutput.play` returned for the command.
        requested_time: when ``play()`` was called, ``time.monotonic()`` seconds.
        start_time: DAC time of the sound's first sample, ``time.monotonic()`` seconds.
        duration_s: length of the sound, seconds.
        interrupted: True if it cut short a sound that was still playing.
    """

    sequence: int
    requested_time: float
    start_time: float
    duration_s: float
    interrupted: bool


@dataclasses.dataclass(frozen=True)
class SpeakerStatus:
    """Counters and state of a :class:`SpeakerOutput`, for diagnostics.

    Attributes:
        state: ``"connected"``, ``"disconnected"`` (reopened on the next play) or ``"closed"``.
        device: name of the device in use (or last used).
        device_index: its PortAudio index.
        device_rate: rate the device is opened at, Hz.
        channels: channels opened (the sound goes to all of them).
        requests: play commands.
        played: sounds started.
        interrupted: sounds cut short by a newer command (policy ``restart``).
        skipped: commands ignored because a sound was playing (policy ``skip``).
        underflows: PortAudio output underflows.
        errors: failed plays and stream failures.
        lost_events: start reports dropped because nobody read them.
        last_error: the latest problem, "" if none.
    """

    state: str
    device: str
    device_index: int | None
    device_rate: int
    channels: int
    requests: int
    played: int
    interrupted: int
    skipped: int
    underflows: int
    errors: int
    lost_events: int
    last_error: str

    def as_dict(self) -> dict[str, Any]:
        """The fields as a dict (e.g. for diagnostic key/values)."""
        return dataclasses.asdict(self)


def load_sound(path: str | Path, rate: int) -> NDArray[np.float64]:
    """A WAV file as mono float64 samples at ``rate`` Hz (channels averaged)."""
    samples, file_rate = read_wav(path)
    return resample(to_mono(samples), file_rate, rate)


class SpeakerOutput:
    """The robot's loudspeaker: plays one sound on command, without blocking.

    An output stream runs continuously and plays silence; :meth:`play` asks the callback
    to start the sound at the beginning of its next block. Commands never queue up: a
    command that arrives while the sound is still playing restarts it from the beginning
    (policy ``"restart"``, the default: the sound then always starts at the latest
    command, as the model's timer assumes) or is ignored (``"skip"``). Several commands
    before the next block count as one.

    For every sound started, a :class:`PlayEvent` with the DAC time of its first sample
    is queued for :meth:`events`. If the stream dies (device unplugged), the next
    :meth:`play` reopens it (at most once per ``retry_s``).

    Args:
        device: output device spec (see :func:`resolve_device`).
        sound: the sound: None for the robot's chirp
            (:func:`~infomax_contingency.audio.signal.synthesize_chirp`, ``duration_s``, made at
            the device rate), a WAV file path, or mono samples at ``sound_rate``.
        sound_rate: rate of ``sound`` samples, Hz (only for arrays).
        duration_s: chirp length, seconds (only for the default sound).
        volume: gain applied to the sound, 0..1.
        overlap: ``"restart"`` or ``"skip"`` (see above).
        rate: device rate to try first, Hz (default: the device's own rate).
        block_s: PortAudio block length, seconds (the start granularity).
        retry_s: least time between reopening attempts after a failure, seconds.
        log: ``log(level, message)`` (default: the logging module).
        backend: PortAudio access (default: sounddevice).
    """

    def __init__(
        self,
        device: int | str | None = None,
        sound: str | Path | ArrayLike | None = None,
        sound_rate: int | None = None,
        duration_s: float = 0.2,
        volume: float = 1.0,
        overlap: str = "restart",
        rate: int | None = None,
        block_s: float = 0.01,
        retry_s: float = 2.0,
        log: LogFunction | None = None,
        backend: AudioBackend | None = None,
    ) -> None:
        if overlap not in OVERLAP_POLICIES:
            raise AudioError(
                f"overlap must be one of {', '.join(OVERLAP_POLICIES)}, got {overlap!r}"
            )
        if sound is not None and not isinstance(sound, str | Path) and sound_rate is None:
            raise AudioError("sound samples need their sound_rate (Hz)")
        self.spec = device
        self.overlap = overlap
        self._sound_arg = sound
        self._sound_rate = sound_rate
        self.duration_s = _check_positive(duration_s, "duration_s")
        self._volume = self._check_volume(volume)
        self._rate_arg = rate
        self.block_s = _check_positive(block_s, "block_s")
        self.retry_s = _check_positive(retry_s, "retry_s")
        self._log = log or _default_log
        self._backend_arg = backend
        self._backend: AudioBackend | None = None
        self._stream: Any = None
        self._state = CLOSED
        self._device: DeviceInfo | None = None
        self._device_rate = 0
        self._channels = 0
        self._offset = 0.0
        self._generation = 0
        self._next_attempt = 0.0
        self._events: queue.Queue[PlayEvent] = queue.Queue(maxsize=256)
        self._source: NDArray[np.float64] = np.empty(0)
        self._sound: NDArray[np.float32] = np.empty(0, np.float32)
        # command handoff: play() bumps _requested (after setting _request_time); the
        # callback serves the latest request it has not served
        self._requested = 0
        self._request_time = 0.0
        self._served = 0
        self._pos = -1  # sample of the sound to play next; -1 = silent
        self._finished = False
        self._requests = 0
        self._played = 0
        self._interrupted = 0
        self._skipped = 0
        self._underflows = 0
        self._errors = 0
        self._lost_events = 0
        self._last_error = ""

    @staticmethod
    def _check_volume(volume: float) -> float:
        if isinstance(volume, bool) or not isinstance(volume, int | float):
            raise AudioError(f"volume must be a number in [0, 1], got {volume!r}")
        if not 0.0 <= volume <= 1.0:
            raise AudioError(f"volume must lie in [0, 1], got {volume!r}")
        return float(volume)

    # ------------------------------------------------------------------ life cycle

    def start(self) -> SpeakerOutput:
        """Open the device and start playing silence.

        Raises:
            AudioDeviceError: the device is missing (the message lists the output devices)
                or unusable, or PortAudio is not installed.
            AudioError: the sound file cannot be read.
        """
        if self._state != CLOSED:
            raise AudioError("the speaker is already started")
        self._backend = _backend_or_default(self._backend_arg)
        self._open()
        return self

    def close(self) -> None:
        """Stop the stream and release the device (safe to call twice)."""
        self._state = CLOSED
        self._drop_stream()

    def _drop_stream(self) -> None:
        self._generation += 1
        stream, self._stream = self._stream, None
        _unregister(self)
        if stream is not None:
            _close_stream(stream, wait_s=_CLOSE_WAIT_S)

    def __enter__(self) -> SpeakerOutput:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def device_rate(self) -> int:
        """Rate the device is opened at, Hz (0 before :meth:`start`)."""
        return self._device_rate

    @property
    def sound(self) -> NDArray[np.float64]:
        """The sound at the device rate, before the volume gain."""
        return self._source

    @property
    def volume(self) -> float:
        """Gain applied to the sound, 0..1."""
        return self._volume

    @volume.setter
    def volume(self, value: float) -> None:
        self._volume = self._check_volume(value)
        self._sound = (self._source * self._volume).astype(np.float32)

    def status(self) -> SpeakerStatus:
        """A snapshot of the counters."""
        d = self._device
        return SpeakerStatus(
            state=self._state,
            device=d.name if d else "",
            device_index=d.index if d else None,
            device_rate=self._device_rate,
            channels=self._channels,
            requests=self._requests,
            played=self._played,
            interrupted=self._interrupted,
            skipped=self._skipped,
            underflows=self._underflows,
            errors=self._errors,
            lost_events=self._lost_events,
            last_error=self._last_error,
        )

    def _make_sound(self, rate: int) -> NDArray[np.float64]:
        if self._sound_arg is None:
            return synthesize_chirp(rate, self.duration_s, amplitude=1.0)
        if isinstance(self._sound_arg, str | Path):
            return load_sound(self._sound_arg, rate)
        samples = to_mono(np.asarray(self._sound_arg, dtype=np.float64))
        return resample(samples, self._sound_rate, rate)

    def _open(self) -> None:
        backend = self._backend
        device = resolve_device(self.spec, OUTPUT, backend)
        rate, channels, _ = negotiate_format(device, OUTPUT, self._rate_arg, 1, backend)
        source = self._make_sound(rate)
        if source.size == 0:
            raise AudioError("the robot's sound is empty")
        self._generation += 1
        generation = self._generation
        self._finished = False

        def callback(outdata: np.ndarray, frames: int, time_info: Any, status: Any) -> None:
            self._on_block(generation, outdata, frames, time_info, status)

        def finished() -> None:
            if generation == self._generation:
                self._finished = True

        blocksize = max(1, round(self.block_s * rate))
        self._source = source
        self._sound = (source * self._volume).astype(np.float32)
        self._pos = -1
        self._served = self._requested
        stream, self._offset = _open_and_start(
            backend, OUTPUT, device, rate, channels, blocksize, callback, finished
        )
        self._stream = stream
        self._device = device
        self._device_rate = rate
        self._channels = channels
        self._state = CONNECTED
        _register(self)
        self._log(
            "info",
            f"speaker: {device.describe(OUTPUT)} at {rate} Hz, {channels} channel(s);"
            f" sound {source.size / rate:.3f} s, volume {self._volume:g}",
        )

    # ------------------------------------------------------------------ playing

    def play(self) -> int | None:
        """Start the sound at the beginning of the next block, without waiting.

        Returns:
            The command's sequence number (see :class:`PlayEvent`), or None if the device
            is unavailable (the error is counted; a later call retries).
        """
        if self._state == CLOSED:
            raise AudioError("the speaker is not started (or already closed)")
        self._requests += 1
        if not self._healthy():
            return None
        self._request_time = time.monotonic()
        self._requested += 1
        return self._requested

    def _healthy(self) -> bool:
        """True if the stream runs; otherwise try to reopen it (rate-limited)."""
        stream = self._stream
        if stream is not None and not self._finished and stream.active:
            return True
        if self._state == CONNECTED:
            self._errors += 1
            self._last_error = "the output stream stopped (device unplugged?)"
            self._log("warning", f"speaker: {self._last_error}")
            self._state = DISCONNECTED
            self._drop_stream()
            self._next_attempt = 0.0
        now = time.monotonic()
        if now < self._next_attempt:
            self._errors += 1
            return False
        self._next_attempt = now + self.retry_s
        try:
            if not _other_streams_open(self):
                self._backend.rescan()
            self._open()
        except Exception as exc:  # device still gone
            self._errors += 1
            self._last_error = f"cannot reopen the speaker: {exc}"
            self._log("warning", self._last_error)
            return False
        return True

    def events(self, timeout: float = 0.0) -> list[PlayEvent]:
        """Sounds started since the last call; waits up to ``timeout`` s for the first."""
        out: list[PlayEvent] = []
        try:
            out.append(
                self._events.get(timeout=timeout) if timeout > 0 else self._events.get_nowait()
            )
            while True:
                out.append(self._events.get_nowait())
        except queue.Empty:
            pass
        return out

    def _on_block(
        self, generation: int, outdata: np.ndarray, frames: int, time_info: Any, status: Any
    ) -> None:
        """PortAudio callback: copy the next part of the sound (or silence) into the block."""
        if status.output_underflow:
            self._underflows += 1
        requested = self._requested
        if requested != self._served and generation == self._generation:
            self._served = requested
            playing = self._pos >= 0
            if playing and self.overlap == "skip":
                self._skipped += 1
            else:
                if playing:
                    self._interrupted += 1
                self._pos = 0
                self._played += 1
                t = time_info.outputBufferDacTime or time_info.currentTime
                start = t + self._offset if t else time.monotonic()
                event = PlayEvent(
                    requested,
                    self._request_time,
                    start,
                    self._sound.size / self._device_rate,
                    playing,
                )
                try:
                    self._events.put_nowait(event)
                except queue.Full:
                    self._lost_events += 1
        if self._pos < 0:
            outdata.fill(0)
            return
        sound = self._sound
        n = min(frames, sound.size - self._pos)
        outdata[:n] = sound[self._pos : self._pos + n, np.newaxis]
        outdata[n:] = 0
        self._pos += n
        if self._pos >= sound.size:
            self._pos = -1


# --------------------------------------------------------------------------- calibration


def energies_from_wav(
    path: str | Path,
    window_s: float,
    channel: int | None = None,
    rate: int = PROCESSING_RATE_HZ,
) -> NDArray[np.float64]:
    """Window energies (dB) of a WAV file, exactly as the wav source computes them."""
    return window_energies_db(load_mono(path, rate, channel), rate, window_s)


@dataclasses.dataclass(frozen=True)
class Recording:
    """Window energies recorded from a live device.

    Attributes:
        energies_db: one energy per window, dB.
        device: name of the device.
        device_rate: rate the device ran at, Hz.
        lost_samples: device-rate samples lost during the recording.
        gaps: gaps (reconnects) during the recording.
    """

    energies_db: NDArray[np.float64]
    device: str
    device_rate: int
    lost_samples: int
    gaps: int


def record_energies(
    device: int | str | None,
    seconds: float,
    window_s: float,
    channel: int | None = None,
    log: LogFunction | None = None,
    backend: AudioBackend | None = None,
) -> Recording:
    """Record ``seconds`` of live audio and return its window energies.

    Records ``floor(seconds / window_s)`` windows (at least 2). The queue holds the whole
    recording, so a slow reader loses nothing.

    Raises:
        AudioDeviceError: the device is missing, or delivers no audio for more than
            ``seconds + 5`` seconds in all.
    """
    seconds = _check_positive(seconds, "seconds")
    n = max(2, int(seconds / _check_positive(window_s, "window_s") + 1e-9))
    mic = MicrophoneStream(
        device,
        window_s=window_s,
        channel=channel,
        queue_s=n * window_s + 2.0,
        log=log,
        backend=backend,
    )
    energies: list[float] = []
    with mic:
        deadline = time.monotonic() + n * window_s + 5.0
        while len(energies) < n:
            if time.monotonic() > deadline:
                raise AudioDeviceError(
                    f"recorded only {len(energies)} of {n} windows from {mic.status().device}"
                    f" in {n * window_s + 5.0:g} s: {mic.status().last_error or 'no audio'}"
                )
            energies.extend(w.energy_db for w in mic.read_windows(0.1))
        status = mic.status()
    return Recording(
        energies_db=np.asarray(energies[:n]),
        device=status.device,
        device_rate=status.device_rate,
        lost_samples=status.lost_samples,
        gaps=status.gaps,
    )


def energy_histogram(
    energies_db: ArrayLike,
    threshold_db: float,
    bin_db: float = 3.0,
    width: int = 40,
    max_bins: int = 30,
) -> str:
    """A text histogram of window energies with the threshold marked.

    Bin edges are placed at ``threshold_db + k * bin_db``, so the threshold falls between
    two bins and a marker line separates the quiet bins from the sound bins. Bins widen
    (to whole dB) when the range would need more than ``max_bins`` bins.

    Returns:
        Lines ``"  -63.0 .. -60.0 dB | ####### 12"``, lowest energies first.
    """
    x = np.asarray(energies_db, dtype=np.float64).ravel()
    if x.size == 0:
        return "(no windows)"
    bin_db = _check_positive(bin_db, "bin_db")
    lo = min(float(x.min()), threshold_db)
    hi = max(float(x.max()), threshold_db)
    if (hi - lo) / bin_db > max_bins:
        bin_db = float(math.ceil((hi - lo) / max_bins))
    k_lo = math.floor((lo - threshold_db) / bin_db)
    k_hi = max(math.floor((hi - threshold_db) / bin_db) + 1, k_lo + 1)
    edges = threshold_db + bin_db * np.arange(k_lo, k_hi + 1)
    counts, _ = np.histogram(x, bins=edges)
    # np.histogram puts a value equal to an inner edge in the upper bin; the bit rule is
    # energy > threshold, so recount the windows exactly at the threshold as quiet.
    at_threshold = int(np.count_nonzero(x == threshold_db))
    zero = -k_lo  # index of the first bin above the threshold
    if at_threshold and 0 < zero < counts.size:
        counts[zero] -= at_threshold
        counts[zero - 1] += at_threshold
    peak = max(int(counts.max()), 1)
    lines = []
    for i, c in enumerate(counts):
        if i == zero:
            lines.append(f"  {'-' * 20} threshold {threshold_db:.1f} dB {'-' * 10}")
        bar = "#" * math.ceil(width * c / peak) if c else ""
        lines.append(f"  {edges[i]:6.1f} .. {edges[i + 1]:6.1f} dB | {bar} {c}")
    return "\n".join(lines)


# --------------------------------------------------------------------------- latency


def find_onset(
    recording: ArrayLike, template: ArrayLike, min_score: float = 0.2
) -> tuple[int, float] | None:
    """Where a known sound starts in a recording (normalized cross-correlation).

    Args:
        recording: mono samples.
        template: the sound, mono, at the recording's rate (shorter than the recording).
        min_score: least normalized correlation (0..1) to accept.

    Returns:
        ``(index, score)``: the sample of ``recording`` where the template matches best
        and the normalized correlation there; None if the recording is too short or
        nothing matches with at least ``min_score``.
    """
    x = np.asarray(recording, dtype=np.float64)
    h = np.asarray(template, dtype=np.float64)
    n = h.size
    if n == 0 or x.size < n:
        return None
    from scipy.signal import correlate  # lazy: scipy.signal takes ~0.5 s to load

    raw = correlate(x, h, mode="valid", method="fft")
    c = np.concatenate(([0.0], np.cumsum(x * x)))
    local = np.sqrt(np.maximum(c[n:] - c[:-n], 0.0)) * math.sqrt(float(h @ h))
    score = np.divide(raw, local, out=np.zeros_like(raw), where=local > 1e-12)
    i = int(np.argmax(score))
    if score[i] < min_score:
        return None
    return i, float(score[i])


def self_period_windows(
    delay_min_s: float, delay_max_s: float, sound_s: float, window_s: float
) -> tuple[int, int]:
    """The self-feedback period ``(ts1, ts2)`` implied by a measured delay.

    Step convention (MODEL.md): the robot decides at the end of window t and its sound
    starts "at the start of the next step"; the window after the decision has timer
    ``z = 0``, the next ``z = 1``, and so on, window ``z`` covering
    ``[z * window_s, (z + 1) * window_s)`` seconds after the play command. The
    microphone hears the sound during ``[d, d + sound_s]``, with ``d`` the delay from the
    play command to the sound's onset at the microphone (output latency + flight + input
    latency). The self period is every window that overlaps that interval for any
    measured ``d`` in ``[delay_min_s, delay_max_s]``::

        ts1 = floor(delay_min_s / window_s)
        ts2 = ceil((delay_max_s + sound_s) / window_s) - 1

    Add room reverberation to ``sound_s`` when it is audible above the threshold.
    """
    if not 0 <= delay_min_s <= delay_max_s:
        raise AudioError(f"delays must satisfy 0 <= min <= max, got {delay_min_s}, {delay_max_s}")
    window_s = _check_positive(window_s, "window_s")
    sound_s = _check_positive(sound_s, "sound_s")
    ts1 = math.floor(delay_min_s / window_s + 1e-9)
    ts2 = math.ceil((delay_max_s + sound_s) / window_s - 1e-9) - 1
    return ts1, max(ts1, ts2)


@dataclasses.dataclass(frozen=True)
class LatencyTrial:
    """One play-and-listen measurement (times in seconds).

    Attributes:
        delay_s: from the play command to the sound's onset at the microphone.
        output_s: from the play command to the DAC start of the sound.
        score: normalized correlation of the match (0..1).
    """

    delay_s: float
    output_s: float
    score: float


@dataclasses.dataclass(frozen=True)
class LatencyReport:
    """Result of :func:`measure_latency`.

    Attributes:
        trials: the successful repeats.
        failures: one reason per repeat where the sound was not found.
        sound_s: length of the sound, seconds.
        input_device: microphone name.
        output_device: loudspeaker name.
    """

    trials: tuple[LatencyTrial, ...]
    failures: tuple[str, ...]
    sound_s: float
    input_device: str
    output_device: str

    @property
    def delays_s(self) -> NDArray[np.float64]:
        """The measured delays, seconds."""
        return np.array([t.delay_s for t in self.trials])


def measure_latency(
    input_device: int | str | None = None,
    output_device: int | str | None = None,
    repeats: int = 5,
    interval_s: float = 1.0,
    volume: float = 1.0,
    sound: str | Path | None = None,
    duration_s: float = 0.2,
    min_score: float = 0.2,
    log: LogFunction | None = None,
    backend: AudioBackend | None = None,
) -> LatencyReport:
    """Play the robot's sound and find it on the microphone, ``repeats`` times.

    Each repeat plays the sound once and records ``interval_s`` seconds from the play
    command (make it longer than the delay plus the sound, or the sound is cut off). The
    onset is where the sound (resampled to the processing rate) correlates best with the
    recording (:func:`find_onset`). The delay runs from the play command to the onset,
    both on the ``time.monotonic()`` clock (ADC time of the recording, request time of
    the command).

    Raises:
        AudioDeviceError: a device is missing or unusable.
        AudioError: bad arguments.
    """
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise AudioError(f"repeats must be a positive integer, got {repeats!r}")
    interval_s = _check_positive(interval_s, "interval_s")
    backend = _backend_or_default(backend)
    rate = PROCESSING_RATE_HZ
    speaker = SpeakerOutput(
        output_device, sound=sound, duration_s=duration_s, volume=volume, log=log, backend=backend
    )
    mic = MicrophoneStream(
        input_device, window_s=0.1, queue_s=interval_s + 4.0, log=log, backend=backend
    )
    trials: list[LatencyTrial] = []
    failures: list[str] = []
    with speaker, mic:
        template = resample(speaker.sound, speaker.device_rate, rate)
        if interval_s <= template.size / rate:
            raise AudioError(
                f"interval_s ({interval_s} s) must be longer than the sound"
                f" ({template.size / rate:.3f} s)"
            )
        mic.read_audio(0.2)  # let the stream settle; drop what came so far
        for repeat in range(1, repeats + 1):
            mic.read_audio(0.0)
            speaker.events(0.0)
            sequence = speaker.play()
            if sequence is None:
                failures.append(f"repeat {repeat}: the speaker is unavailable")
                continue
            chunks: list[AudioChunk] = []
            started: list[PlayEvent] = []
            deadline = time.monotonic() + interval_s + 2.0
            event = None
            while time.monotonic() < deadline:
                chunks.extend(mic.read_audio(0.05))
                started.extend(speaker.events(0.0))
                event = next((e for e in started if e.sequence == sequence), None)
                if event is not None and chunks and _covered(chunks, event, interval_s, rate):
                    break
            trial = _analyse(chunks, event, template, rate, min_score, repeat)
            if isinstance(trial, str):
                failures.append(trial)
            else:
                trials.append(trial)
    return LatencyReport(
        tuple(trials),
        tuple(failures),
        template.size / rate,
        mic.status().device,
        speaker.status().device,
    )


def _covered(chunks: Sequence[AudioChunk], event: PlayEvent, interval_s: float, rate: int) -> bool:
    """True once the recording reaches ``interval_s`` after the play command."""
    last = chunks[-1]
    return last.start_time + last.samples.size / rate >= event.requested_time + interval_s


def _analyse(
    chunks: Sequence[AudioChunk],
    event: PlayEvent | None,
    template: NDArray[np.float64],
    rate: int,
    min_score: float,
    repeat: int,
) -> LatencyTrial | str:
    """One repeat's trial, or the reason it failed."""
    if event is None:
        return f"repeat {repeat}: the sound did not start"
    chunks = [c for c in chunks if c.segment == chunks[-1].segment] if chunks else []
    if not chunks:
        return f"repeat {repeat}: no audio from the microphone"
    if any(c.lost_samples or c.overflows for c in chunks[1:]):
        return f"repeat {repeat}: microphone audio was lost during the repeat (overflow)"
    x = np.concatenate([c.samples for c in chunks])
    t0 = chunks[0].start_time
    # only what was recorded after the command can be the sound
    first = max(0, math.floor((event.requested_time - t0) * rate))
    found = find_onset(x[first:], template, min_score)
    if found is None:
        return f"repeat {repeat}: the sound was not heard (raise the volume or move the microphone)"
    index, score = found
    onset = t0 + (first + index) / rate
    return LatencyTrial(
        delay_s=onset - event.requested_time,
        output_s=event.start_time - event.requested_time,
        score=score,
    )

"""Audio devices through PortAudio (sounddevice): listing, choosing, formats, opening streams.

Conventions:
    * Devices are chosen with a *spec*: ``None`` or ``""`` (the system default), an index
      (``3`` or ``"3"``), or a case-insensitive part of the device name (first match).
      :func:`resolve_device` turns a spec into a :class:`DeviceInfo`; a spec that matches
      nothing raises :class:`AudioDeviceError` listing the devices there are.
    * :class:`AudioBackend` is everything the capture and playback modules need from
      PortAudio; :class:`SoundDeviceBackend` is the real one, tests pass a fake.
    * Stream times are mapped onto the caller's monotonic clock once per stream
      (:func:`open_and_start`); on Linux/ALSA the two clocks are the same.

``sounddevice`` is imported lazily (:func:`import_sounddevice`), so this module imports on
machines without PortAudio; the error then says to install ``libportaudio2``.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from types import ModuleType
from typing import Any, Protocol

import numpy as np

from infomax_contingency.audio.common import AudioError

INPUT = "input"
OUTPUT = "output"
_KINDS = (INPUT, OUTPUT)

FALLBACK_RATES_HZ = (48000, 44100)
"""Rates tried (after the requested one and the device's default) when opening a device."""

CONNECTED = "connected"
DISCONNECTED = "disconnected"
CLOSED = "closed"

CLOSE_WAIT_S = 1.0
"""How long a reconnect waits for a dead stream to close before abandoning it, seconds."""

_log = logging.getLogger(__name__)

LogFunction = Callable[[str, str], None]
"""``log(level, message)`` with level ``"info"``, ``"warning"`` or ``"error"``."""


class AudioDeviceError(AudioError):
    """An audio device is missing, unusable, or PortAudio itself is not installed."""


def default_log(level: str, message: str) -> None:
    """A :data:`LogFunction` on the logging module."""
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
    """What capture and playback need from PortAudio; :class:`SoundDeviceBackend` is the real one.

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


def backend_or_default(backend: AudioBackend | None) -> AudioBackend:
    """``backend``, or the real sounddevice backend when it is None."""
    return SoundDeviceBackend() if backend is None else backend


# --------------------------------------------------------------------------- devices


def _check_kind(kind: str) -> str:
    if kind not in _KINDS:
        raise ValueError(f"kind must be 'input' or 'output', got {kind!r}")
    return kind


def list_devices(kind: str, backend: AudioBackend | None = None) -> list[DeviceInfo]:
    """The devices that have ``kind`` (``"input"`` or ``"output"``) channels."""
    kind = _check_kind(kind)
    return [d for d in backend_or_default(backend).devices() if d.channels(kind) > 0]


def format_devices(kind: str, backend: AudioBackend | None = None) -> str:
    """A list of the ``kind`` devices, one per line, the system default marked."""
    backend = backend_or_default(backend)
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
    backend = backend_or_default(backend)
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


# --------------------------------------------------------------------------- stream registry

_registry_lock = threading.Lock()
_open_owners: set[int] = set()


def register_stream(owner: object) -> None:
    """Note that ``owner`` holds an open stream (see :func:`other_streams_open`)."""
    with _registry_lock:
        _open_owners.add(id(owner))


def unregister_stream(owner: object) -> None:
    """Note that ``owner`` holds no open stream any more."""
    with _registry_lock:
        _open_owners.discard(id(owner))


def other_streams_open(owner: object) -> bool:
    """True if another capture or playback object holds an open stream in this process."""
    with _registry_lock:
        return bool(_open_owners - {id(owner)})


OFFSET_READINGS = 5
"""Readings of the stream clock between two readings of the caller's clock, per offset."""


def clock_offset(clock: Callable[[], float], stream_time: Callable[[], float]) -> float:
    """``clock()`` minus ``stream_time()`` (seconds), from the tightest of a few readings.

    Each reading of the stream clock is bracketed by two of ``clock``, and the midpoint is
    taken: the error is at most half the bracket. Of :data:`OFFSET_READINGS` the one with
    the smallest bracket counts, so a thread preempted between two readings (a loaded
    machine: milliseconds) does not shift every time stamp of the stream.
    """
    best_bracket, offset = float("inf"), 0.0
    for _ in range(OFFSET_READINGS):
        before = clock()
        stream_s = stream_time()
        after = clock()
        if after - before < best_bracket:
            best_bracket, offset = after - before, (before + after) / 2 - stream_s
    return offset


def open_and_start(
    backend: AudioBackend,
    kind: str,
    device: DeviceInfo,
    rate: int,
    channels: int,
    blocksize: int,
    callback: Callable[..., None],
    finished: Callable[[], None],
    clock: Callable[[], float] = time.monotonic,
) -> Any:
    """Open and start a stream.

    Returns:
        ``(stream, offset)``: the running stream and ``clock()`` minus its stream clock,
        read before the start (while running, reading the clock can wait for a callback
        blocked in the driver).

    Raises:
        AudioDeviceError: naming the device, if opening or starting fails.
    """
    try:
        stream = backend.open(kind, device.index, rate, channels, blocksize, callback, finished)
        offset = clock_offset(clock, lambda: float(stream.time))
    except Exception as exc:  # PortAudioError and friends
        raise AudioDeviceError(f"cannot open {kind} device {device.describe(kind)}: {exc}") from exc
    try:
        stream.start()
    except Exception as exc:
        close_stream(stream, wait_s=CLOSE_WAIT_S)
        raise AudioDeviceError(
            f"cannot start {kind} device {device.describe(kind)}: {exc}"
        ) from exc
    return stream, offset


def close_stream(stream: Any, wait_s: float) -> threading.Thread | None:
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

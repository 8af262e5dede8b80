"""A fake PortAudio for tests of live_audio.

Devices that come and go, streams driven by hand or by a real-time thread, and a "room"
that feeds the loudspeaker back into the microphone.

It implements live_audio.AudioBackend. Callbacks get the same arguments as sounddevice's
(``data, frames, time_info, status``), with times on the ``time.monotonic()`` clock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from infomax_contingency.audio.devices import INPUT, DeviceInfo


@dataclass
class FakeTime:
    inputBufferAdcTime: float = 0.0  # noqa: N815 (sounddevice's names)
    outputBufferDacTime: float = 0.0  # noqa: N815
    currentTime: float = 0.0  # noqa: N815


@dataclass
class FakeStatus:
    input_overflow: bool = False
    output_underflow: bool = False


def device(
    index: int, name: str, inputs: int = 1, outputs: int = 0, rate: int = 48000
) -> DeviceInfo:
    return DeviceInfo(index, name, "Fake", inputs, outputs, rate)


@dataclass
class Rule:
    """Formats a device accepts (None: any)."""

    rates: set[int] | None = None
    channels: set[int] | None = None


class FakeStream:
    """A callback stream; ``pump`` runs the callback once (or a thread runs it in real time)."""

    def __init__(self, backend, kind, index, rate, channels, blocksize, callback, finished):
        self.backend = backend
        self.kind = kind
        self.index = index
        self.rate = rate
        self.channels = channels
        self.blocksize = blocksize
        self.callback = callback
        self.finished = finished
        self.started = False
        self.closed = False
        self.dead = False
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    @property
    def active(self) -> bool:
        return self.started and not self.closed and not self.dead

    @property
    def time(self) -> float:
        return time.monotonic()

    def start(self) -> None:
        self.started = True
        if self.backend.realtime:
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()

    def close(self, ignore_errors: bool = True) -> None:
        self.closed = True
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)

    def die(self) -> None:
        """The device vanished: PortAudio stops the stream and calls finished_callback."""
        self.dead = True
        self._stop.set()
        self.finished()

    def pump(
        self,
        data: np.ndarray | None = None,
        t: float = 0.0,
        overflow: bool = False,
        frames: int | None = None,
    ) -> np.ndarray | None:
        """Run the callback once: input ``data`` (frames x channels), or an output block."""
        if self.kind == INPUT:
            data = np.asarray(data, dtype=np.float32)
            if data.ndim == 1:
                data = data[:, np.newaxis]
            self.callback(data, data.shape[0], FakeTime(inputBufferAdcTime=t), FakeStatus(overflow))
            return None
        out = np.full((frames or self.blocksize, self.channels), np.nan, dtype=np.float32)
        self.callback(out, out.shape[0], FakeTime(outputBufferDacTime=t), FakeStatus())
        return out

    def _run(self) -> None:
        period = self.blocksize / self.rate
        t0 = time.monotonic()
        n = 0
        while not self._stop.is_set():
            due = t0 + n * period
            delay = due - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                return
            if self.backend.stalled.get(self.index):
                n += 1
                continue
            if self.kind == INPUT:
                block = self.backend.source(self, due, self.blocksize)
                self.pump(block, t=due)
            else:
                dac = due + self.backend.output_latency_s
                out = self.pump(t=dac)
                self.backend.sink(self, dac, out)
            n += 1


@dataclass
class FakeBackend:
    """Devices, their accepted formats, and the streams opened on them.

    ``visible`` is what a rescan shows; ``devices()`` returns the list as of the last
    rescan (like PortAudio, whose list is fixed between initializations).
    """

    visible: list[DeviceInfo]
    default_input: int | None = None
    default_output: int | None = None
    rules: dict[int, Rule] = field(default_factory=dict)
    realtime: bool = False
    source: Callable[[FakeStream, float, int], np.ndarray] | None = None
    sink: Callable[[FakeStream, float, np.ndarray], None] | None = None
    output_latency_s: float = 0.0
    stalled: dict[int, bool] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.listed = list(self.visible)
        self.streams: list[FakeStream] = []
        self.rescans = 0
        self.open_attempts = 0

    # AudioBackend
    def devices(self) -> list[DeviceInfo]:
        return list(self.listed)

    def default_index(self, kind: str) -> int | None:
        index = self.default_input if kind == INPUT else self.default_output
        return index if any(d.index == index for d in self.listed) else None

    def check(self, kind: str, index: int, rate: int, channels: int) -> None:
        if not any(d.index == index for d in self.listed):
            raise RuntimeError(f"Invalid device [PaErrorCode -9996] ({index})")
        rule = self.rules.get(index, Rule())
        if rule.rates is not None and rate not in rule.rates:
            raise RuntimeError("Invalid sample rate [PaErrorCode -9997]")
        if rule.channels is not None and channels not in rule.channels:
            raise RuntimeError("Invalid number of channels [PaErrorCode -9998]")

    def open(self, kind, index, rate, channels, blocksize, callback, finished):
        self.open_attempts += 1
        if not any(d.index == index for d in self.visible):
            raise RuntimeError("Device unavailable [PaErrorCode -9985]")
        stream = FakeStream(self, kind, index, rate, channels, blocksize, callback, finished)
        self.streams.append(stream)
        return stream

    def rescan(self) -> None:
        self.rescans += 1
        self.listed = list(self.visible)

    # test controls
    def last(self, kind: str = INPUT) -> FakeStream:
        return [s for s in self.streams if s.kind == kind][-1]

    def unplug(self, index: int) -> None:
        """The device disappears: its open streams die, a rescan no longer lists it."""
        self.visible = [d for d in self.visible if d.index != index]
        for s in self.streams:
            if s.index == index and s.active:
                s.die()

    def plug(self, info: DeviceInfo) -> None:
        self.visible = sorted([*self.visible, info], key=lambda d: d.index)


class Room:
    """Feeds what the loudspeaker plays back into the microphone after ``delay_s``.

    Time is cut into samples at ``rate`` from ``t0``; output blocks are written at their
    DAC time, input blocks read at their ADC time minus the delay (plus quiet noise).
    """

    def __init__(self, rate: int, delay_s: float, seconds: float = 60.0, noise: float = 1e-3):
        self.rate = rate
        self.delay_s = delay_s
        self.t0 = time.monotonic()
        self.signal = np.zeros(int(seconds * rate))
        self.rng = np.random.default_rng(0)
        self.noise = noise
        self.lock = threading.Lock()

    def _index(self, t: float) -> int:
        return round((t - self.t0) * self.rate)

    def sink(self, stream: FakeStream, dac: float, out: np.ndarray) -> None:
        assert stream.rate == self.rate
        i = self._index(dac)
        with self.lock:
            seg = self.signal[i : i + out.shape[0]]
            seg += out[: seg.size, 0]

    def source(self, stream: FakeStream, adc: float, frames: int) -> np.ndarray:
        assert stream.rate == self.rate
        i = self._index(adc - self.delay_s)
        with self.lock:
            x = np.zeros(frames)
            if i >= 0:
                part = self.signal[i : i + frames]
                x[: part.size] = part
        return x + self.noise * self.rng.standard_normal(frames)

"""A fake PortAudio for tests of the live audio modules (capture, playback, latency).

Devices that come and go, streams driven by hand or by a :class:`FakeClock`, and a
"room" that feeds the loudspeaker back into the microphone. Nothing runs in a thread.

It implements ``infomax_contingency.audio.devices.AudioBackend``. Callbacks get the same
arguments as sounddevice's (``data, frames, time_info, status``), with times on the
backend's clock (``time.monotonic()``, or a :class:`FakeClock`).

With a :class:`FakeClock`, nothing sleeps: give the same clock (and its ``sleep``) to the
stream under test; whenever it sleeps, the clock moves on and every running stream
delivers the blocks that fell due meanwhile, at their exact times.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from infomax_contingency.audio.devices import INPUT, DeviceInfo


class FakeClock:
    """Monotonic seconds that move only by :meth:`sleep` / :meth:`advance`.

    Timers (the running fake streams: ``next_due`` seconds and ``fire()``) fire in time
    order as the clock passes their due times; while one fires, the clock reads its due
    time.
    """

    def __init__(self, start: float = 1000.0) -> None:
        self.now = start
        self.timers: list = []
        self.slept = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept += max(0.0, seconds)
        self.advance(seconds)

    def advance(self, seconds: float) -> None:
        target = self.now + max(0.0, seconds)
        while self.timers:
            timer = min(self.timers, key=lambda t: t.next_due)
            if timer.next_due > target:
                break
            self.now = timer.next_due
            timer.fire()
        self.now = target


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
    """A callback stream; ``pump`` runs the callback once (a FakeClock runs it when due)."""

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
        self._t0 = 0.0
        self._blocks_due = 0

    @property
    def active(self) -> bool:
        return self.started and not self.closed and not self.dead

    @property
    def time(self) -> float:
        return self.backend.now()

    def start(self) -> None:
        self.started = True
        if self.backend.clock is not None:
            self._t0 = self.backend.clock()
            self.backend.clock.timers.append(self)

    @property
    def next_due(self) -> float:
        """FakeClock timer: the time of the next block."""
        return self._t0 + self._blocks_due * self.blocksize / self.rate

    def fire(self) -> None:
        """FakeClock timer: deliver the block due now."""
        due = self.next_due
        self._blocks_due += 1
        self._deliver(due)

    def _stop_timer(self) -> None:
        clock = self.backend.clock
        if clock is not None and self in clock.timers:
            clock.timers.remove(self)

    def close(self, ignore_errors: bool = True) -> None:
        self.closed = True
        self._stop_timer()

    def die(self) -> None:
        """The device vanished: PortAudio stops the stream and calls finished_callback."""
        self.dead = True
        self._stop_timer()
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

    def _deliver(self, due: float) -> None:
        """One block at ``due``: from the source (input) or to the sink (output)."""
        if self.backend.stalled.get(self.index):
            return
        if self.kind == INPUT:
            self.pump(self.backend.source(self, due, self.blocksize), t=due)
        else:
            dac = due + self.backend.output_latency_s
            out = self.pump(t=dac)
            if self.backend.sink is not None:
                self.backend.sink(self, dac, out)


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
    source: Callable[[FakeStream, float, int], np.ndarray] | None = None
    sink: Callable[[FakeStream, float, np.ndarray], None] | None = None
    output_latency_s: float = 0.0
    stalled: dict[int, bool] = field(default_factory=dict)
    clock: FakeClock | None = None

    def __post_init__(self) -> None:
        self.listed = list(self.visible)
        self.streams: list[FakeStream] = []
        self.rescans = 0
        self.open_attempts = 0

    def now(self) -> float:
        """The backend's clock: the FakeClock if there is one, else time.monotonic()."""
        return self.clock() if self.clock is not None else time.monotonic()

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

    def __init__(
        self,
        rate: int,
        delay_s: float,
        seconds: float = 60.0,
        noise: float = 1e-3,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.rate = rate  # the room's time 0 is clock() now
        self.delay_s = delay_s
        self.t0 = clock()
        self.signal = np.zeros(int(seconds * rate))
        self.rng = np.random.default_rng(0)
        self.noise = noise

    def _index(self, t: float) -> int:
        return round((t - self.t0) * self.rate)

    def sink(self, stream: FakeStream, dac: float, out: np.ndarray) -> None:
        assert stream.rate == self.rate
        i = self._index(dac)
        seg = self.signal[i : i + out.shape[0]]
        seg += out[: seg.size, 0]

    def source(self, stream: FakeStream, adc: float, frames: int) -> np.ndarray:
        assert stream.rate == self.rate
        i = self._index(adc - self.delay_s)
        x = np.zeros(frames)
        if i >= 0:
            part = self.signal[i : i + frames]
            x[: part.size] = part
        return x + self.noise * self.rng.standard_normal(frames)

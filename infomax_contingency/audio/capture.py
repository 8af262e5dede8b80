"""Live microphone capture: a PortAudio input stream cut into timed windows, with reconnection.

Threads: the PortAudio callback only copies data into a bounded queue and bumps
counters. Everything else (mixdown, resampling, windows, reconnecting) runs in the
thread that calls :meth:`MicrophoneStream.read_windows` (e.g. a node's timer). The
timing rules live in :class:`~infomax_contingency.audio.timeline.WindowTimeline`.

Times are on the stream's clock (``time.monotonic()`` unless a ``clock`` is given);
PortAudio's ADC time is mapped onto it once per stream. To stamp a ROS message, use
``now_ros - (clock() - t)``.

Wiring in a node (the reader runs in the node's own thread, e.g. a 20 ms timer)::

    mic = MicrophoneStream(device, window_s=dt, channel=channel, log=log).start()
    for window in mic.read_windows(0.0):     # in the timer; never blocks
        publish(window.energy_db)            # window.lost_samples / gap_s: diagnostics
    values = mic.status().as_dict()          # diagnostics key/values
"""

from __future__ import annotations

import dataclasses
import math
import queue
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError, check_positive
from infomax_contingency.audio.device_stream import Clock, DeviceStream, Sleep
from infomax_contingency.audio.devices import (
    CLOSED,
    CONNECTED,
    DISCONNECTED,
    INPUT,
    AudioBackend,
    AudioDeviceError,
    DeviceInfo,
    LogFunction,
    negotiate_format,
    resolve_device,
)
from infomax_contingency.audio.timeline import AudioChunk, Window, WindowTimeline

__all__ = ["AudioChunk", "MicrophoneStatus", "MicrophoneStream", "Window"]


def check_channels(channel: int | None, channels: int | None) -> int:
    """Channels to open for ``channel``/``channels`` (see :class:`MicrophoneStream`)."""
    if channel is not None and (isinstance(channel, bool) or not isinstance(channel, int)):
        raise AudioError(f"channel must be None or a 0-based index, got {channel!r}")
    if channel is not None and channel < 0:
        raise AudioError(f"channel must be None or a 0-based index, got {channel!r}")
    wanted = channels if channels is not None else (1 if channel is None else channel + 1)
    if isinstance(wanted, bool) or not isinstance(wanted, int) or wanted < 1:
        raise AudioError(f"channels must be a positive integer, got {channels!r}")
    if channel is not None and channels is not None and channel >= channels:
        raise AudioError(f"channel {channel} does not exist among {channels} channel(s)")
    return wanted


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


class MicrophoneStream(DeviceStream):
    """A live microphone cut into windows, with reconnection when the device vanishes.

    The PortAudio callback copies each block into a bounded queue (a full queue drops the
    block and counts it). The reader thread (:meth:`read_windows` or :meth:`read_audio`)
    mixes the blocks to mono (mean, or one ``channel``), resamples them exactly to
    ``rate`` (:class:`~infomax_contingency.audio.resample.StreamResampler`) when the device
    runs at another rate, and cuts windows
    (:class:`~infomax_contingency.audio.timeline.WindowTimeline`). Uninterrupted
    audio therefore gives exactly the energies of the offline computation on a recording
    of the same samples.

    Window times come from PortAudio's ADC time of the first block of a segment,
    advanced by the samples counted since (plus lost samples), so a late reader does not
    shift them. They follow the device's sample clock: a converter 100 ppm off drifts
    0.36 s per hour from the clock (until the next gap re-anchors them).

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
    of the audio modules is open in the process (a rescan would close those streams too);
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
        clock: monotonic seconds now (default ``time.monotonic``); ADC times are mapped
            onto it and every timeout, back-off and stall is measured on it.
        sleep: ``sleep(seconds)`` for every wait (then the queue is polled without
            blocking); default None: wait on the queue and ``time.sleep``. A test passes a
            fake clock's advance so that nothing really sleeps.
    """

    kind = "microphone stream"

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
        clock: Clock = time.monotonic,
        sleep: Sleep | None = None,
    ) -> None:
        super().__init__(device, backoff_s, log, backend, clock, sleep)
        self.window_s = check_positive(window_s, "window_s")
        self.rate = int(rate)
        self._timeline = WindowTimeline(self.rate, self.window_s)
        self.samples_per_window = self._timeline.samples_per_window
        self._wanted_channels = check_channels(channel, channels)
        self.channel = channel
        self.block_s = check_positive(block_s, "block_s")
        self.queue_s = check_positive(queue_s, "queue_s")
        self.stall_timeout_s = check_positive(stall_timeout_s, "stall_timeout_s")
        self._queue: queue.Queue[_Block] = queue.Queue()
        self._open_channels = 0
        # callback-side state (written by the callback thread only)
        self._pending_dropped = 0
        self._last_data = 0.0
        self._overflows = 0
        self._dropped_blocks = 0
        # reader-side counters
        self._disconnects = 0
        self._reconnects = 0
        self._attempts = 0

    @property
    def device_rate(self) -> int:
        """Rate the device is opened at, Hz (0 before :meth:`start`)."""
        return self._timeline.device_rate

    def status(self) -> MicrophoneStatus:
        """A snapshot of the counters (cheap; call it for every diagnostics message)."""
        d, timeline = self._device, self._timeline
        return MicrophoneStatus(
            state=self._state,
            device=d.name if d else "",
            device_index=d.index if d else None,
            device_rate=timeline.device_rate,
            rate=self.rate,
            channels=self._open_channels,
            windows=timeline.windows,
            overflows=self._overflows,
            dropped_blocks=self._dropped_blocks,
            lost_samples=timeline.lost_samples,
            gaps=timeline.gaps,
            gap_total_s=timeline.gap_total_s,
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
            self._queue = queue.Queue(maxsize=capacity)
            self._pending_dropped = 0
        self._last_data = self._clock()
        self._start_stream(INPUT, device, rate, channels, blocksize, self._on_block)
        self._open_channels = channels
        self._timeline.start_stream(rate)
        self._log_opened(device, rate, channels, refusals)

    def _log_opened(
        self, device: DeviceInfo, rate: int, channels: int, refusals: list[str]
    ) -> None:
        """Log the format the device opened with (and why, if not at the processing rate)."""
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
        self._last_data = self._clock()
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
        timeline = self._timeline
        self._read(timeout, lambda block: windows.extend(timeline.assemble(self._convert(block))))
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
        deadline = self._clock() + max(0.0, timeout)
        got = False
        while True:
            if self._state == DISCONNECTED and self._retry_due():
                self._reconnect()
            if self._state == CONNECTED:
                generation = self._generation
                for block in self._drain(deadline - self._clock()):
                    if block.generation == generation:
                        handle(block)
                        got = True
                self._check_health()
                if got or self._clock() >= deadline:
                    return
            elif self._state == CLOSED:
                return
            else:
                now = self._clock()
                if now >= deadline:
                    return
                self._wait(max(0.0, min(deadline, self._next_attempt) - now))

    def _wait(self, seconds: float) -> None:
        """Sleep ``seconds`` on the stream's clock."""
        (self._sleep or time.sleep)(seconds)

    def _drain(self, wait_s: float) -> list[_Block]:
        """Blocks in the queue; waits up to ``wait_s`` for the first one."""
        blocks: list[_Block] = []
        q = self._queue
        try:
            if wait_s > 0 and self._sleep is None:
                blocks.append(q.get(timeout=wait_s))
            elif wait_s > 0 and q.empty():
                self._sleep(wait_s)
            while True:
                blocks.append(q.get_nowait())
        except queue.Empty:
            pass
        return blocks

    def _check_health(self) -> None:
        if self._stream is None or self._state != CONNECTED:
            return
        name = self._device.name if self._device else "the microphone"
        if self._stream_stopped():
            self._disconnect(f"the audio stream of {name} stopped (device unplugged?)")
        elif self._clock() - self._last_data > self.stall_timeout_s:
            self._disconnect(f"no audio from {name} for {self.stall_timeout_s:g} s")

    def _disconnect(self, reason: str) -> None:
        self._lose(reason)
        self._disconnects += 1
        self._log("warning", f"microphone disconnected: {reason}; retrying")

    def _reconnect(self) -> None:
        self._attempts += 1
        failure = self._try_reopen()
        if failure is not None:
            self._last_error = f"reconnect failed: {failure}"
            self._log(
                "warning",
                f"microphone still unavailable (attempt {self._attempts}, next in"
                f" {self._backoff:g} s): {failure}",
            )
            return
        self._reconnects += 1
        self._log("info", f"microphone reconnected after {self._attempts} attempt(s)")

    # ------------------------------------------------------------------ conversion

    def _convert(self, block: _Block) -> AudioChunk:
        """One queue block to a processing-rate chunk (a long loss starts a new segment)."""
        t = block.time + self._offset if block.time else None
        return self._timeline.convert(
            block.data, t, block.dropped_before, block.overflow, self.channel, self._clock()
        )

"""Window sources: where mic_node's windows come from, behind one small interface.

A :class:`WindowSource` serves windows (:class:`SourceWindow`: the full-band energy, the
samples when the bit source needs them, a recorded bit) in one of two ways:

* a **replay** (:attr:`WindowSource.replay` True: :class:`WavReplay`, a WAV file; and
  :class:`~infomax_contingency.audio.bag_replay.BagReplay`, a session bag) serves one
  window per :meth:`WindowSource.take` when its reader asks (paced in real time or in
  lockstep with the decisions), and can :meth:`WindowSource.read_ahead` its first
  seconds for a calibration;
* a **stream** (:class:`TopicWindows`, chunks of samples as they arrive;
  :class:`MicrophoneWindows`, a live device) serves the windows that are complete when
  :meth:`WindowSource.take` is called.

No rclpy: a node hands a stream's chunks in (:meth:`TopicWindows.feed`) and publishes
what comes out. Energies are dB (:mod:`infomax_contingency.audio.energy`); times seconds.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Hashable, Iterator
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from infomax_contingency.audio.capture import MicrophoneStream
from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError, as_mono
from infomax_contingency.audio.devices import LogFunction, default_log
from infomax_contingency.audio.energy import (
    WindowAssembler,
    frame_energies_db,
    iter_wav_energies,
    iter_wav_windows,
    wav_energies,
    wav_window_count,
)
from infomax_contingency.audio.threshold import calibration_window_count
from infomax_contingency.audio.wav import WavReader, to_mono
from infomax_contingency.core.flowcontrol import SOURCE_TIMEOUT_S, WriterFollower, Writing
from infomax_contingency.core.selfsound import ChunkClock


@dataclasses.dataclass(frozen=True)
class SourceWindow:
    """One window from a window source.

    Attributes:
        energy_db: full-band energy, dB.
        samples: mono samples (float64) when the source keeps them, else None.
        recorded_bit: the bit a session without audio recorded for it (None: binarize).
        end_time: monotonic time just after its last sample (a live device), else None.
        gap_s: audio missing right before it, seconds (> 0: a gap; a live device).
        intact: False if samples were lost inside it (a live device).
        index: windows the source made before it (a live device), else 0.
        start_time: monotonic time of its first sample (a live device), else None.
        span_ns: its time range ``[start, end)`` on the clock of the chunks'
            publication times, ns (the ``audio`` topic:
            :class:`~infomax_contingency.core.selfsound.ChunkClock`), else None.
        withheld: a session recorded it withheld (the robot's own sound, or right after
            windows without a step).
    """

    energy_db: float
    samples: NDArray[np.float64] | None = dataclasses.field(default=None, repr=False)
    recorded_bit: bool | None = None
    end_time: float | None = None
    gap_s: float = 0.0
    intact: bool = True
    index: int = 0
    start_time: float | None = None
    span_ns: tuple[int, int] | None = None
    withheld: bool = False

    def time_range_ns(self, now_ns: int, monotonic_now_ns: int,
                      window_s: float) -> tuple[int, int]:  # fmt: skip
        """The window's time range ``[start, end)`` on the clock of ``now_ns`` (ns).

        For the robot's own sound (:mod:`~infomax_contingency.core.selfsound`): the
        chunks' publication times (:attr:`span_ns`), else a live device's ADC times moved
        from the monotonic clock (``monotonic_now_ns`` is that clock's now), else the
        ``window_s`` up to now (a replay: the window is served now).
        """
        if self.span_ns is not None:
            return self.span_ns
        if self.start_time is not None and self.end_time is not None:
            offset_ns = now_ns - monotonic_now_ns
            return (round(self.start_time * 1e9) + offset_ns,
                    round(self.end_time * 1e9) + offset_ns)  # fmt: skip
        return now_ns - round(window_s * 1e9), now_ns


class WindowSource:
    """The interface of every window source (see the module docstring)."""

    replay: ClassVar[bool] = False
    """True: one window per :meth:`take`, when the reader asks; False: a stream."""

    def start(self) -> None:
        """Start serving (a live device opens here)."""

    def take(self) -> list[SourceWindow]:
        """A replay's next window ([] at the end); a stream's windows completed so far."""
        raise NotImplementedError

    @property
    def finished(self) -> bool:
        """True once a replay served its last window (a stream never finishes)."""
        return False

    def read_ahead(self, seconds: float, window_s: float) -> tuple[NDArray[np.float64],
                                                                   NDArray[np.float64] | None]:
        """Energies (dB) and samples (rows, or None) of a replay's first ``seconds``."""
        raise AudioError("only a replay is read ahead")

    def describe(self) -> str:
        """One line for the log at start-up."""
        return type(self).__name__

    def status(self) -> dict[str, Any]:
        """Values for the diagnostics."""
        return {}

    def close(self) -> None:
        """Release what the source holds (a device)."""


class TopicWindows(WindowSource):
    """Chunks of mono samples (the ``audio`` topic) windowed as they come, from one writer.

    Only the chunks of one writer are windowed: the first writer whose chunk was taken,
    told apart from any other by :class:`~infomax_contingency.core.flowcontrol.WriterFollower`
    (the writer's name where the middleware gives it, else its DDS numbers); another
    writer's chunks are counted (:attr:`foreign_chunks`) and ignored. A chunk found missing
    (the followed writer's numbers skip some) drops the incomplete window: the next window
    starts with the next chunk, its ``gap_s`` the audio missed. A writer that replaces the
    followed one after ``switch_s`` of its silence (a restarted room, numbering from 1
    again) is such a gap too, of unknown length (``gap_s`` infinite). A chunk refused for
    its samples changes nothing: neither the windows nor the writers' numbers. Each window
    gets its time range from the chunks' publication times
    (:class:`~infomax_contingency.core.selfsound.ChunkClock`), when they are given.

    Args:
        rate_hz: sample rate of the chunks, Hz.
        window_s: window length, seconds.
        samples: keep each window's samples (a bit source that needs them).
        switch_s: seconds of the followed writer's silence (between publication times)
            after which another writer is followed.
    """

    def __init__(self, rate_hz: int, window_s: float, samples: bool = False,
                 switch_s: float = SOURCE_TIMEOUT_S) -> None:  # fmt: skip
        self.rate_hz = rate_hz
        self.samples = samples
        self._assembler = WindowAssembler(rate_hz, window_s)
        self._clock = ChunkClock(rate_hz)
        self._windows_since_gap = 0
        self.writers = WriterFollower(switch_s)
        """Which writer's chunks are windowed."""
        self._ready: list[SourceWindow] = []
        self.dropped_chunks = 0
        """Chunks of the followed writer found missing."""
        self._lost_s = 0.0  # audio missed before the next window (its ``gap_s``)
        self.bad_chunks = 0
        """Chunks of bad samples, ignored."""
        self.foreign_chunks = 0
        """Chunks of another writer than the one followed, ignored."""

    def feed(self, chunk: NDArray[np.float32], sequence: int | None = None,
             published_ns: int | None = None, writer: Hashable | None = None,
             alone: Callable[[], bool] = lambda: True) -> Writing:  # fmt: skip
        """Add one chunk numbered ``sequence`` by its ``writer`` (DDS; None: not given).

        ``published_ns``: when the chunk was published (ns; its windows' time ranges, and
        the clock of the writers' silence). ``alone()``: True if the topic has one
        publisher (asked only when the numbers skip some:
        :meth:`~infomax_contingency.core.flowcontrol.WriterFollower.judge`). Returns what
        the chunk was: the followed writer's (:attr:`WriterFollower.missed` of its chunks
        lost before it), a new writer's after the followed one fell silent, or another
        writer's (ignored, bad samples or not).

        Raises:
            AudioError: a chunk of bad samples that another writer's would not be (it is
                ignored; nothing else changes: the next chunk's number shows it lost).
        """
        now_s = time.time() if published_ns is None else published_ns / 1e9
        try:
            samples = as_mono(chunk, "chunk")
        except AudioError:
            if self.writers.would_refuse(sequence, now_s, writer, alone):
                self.foreign_chunks += 1
                return Writing.FOREIGN
            self.bad_chunks += 1
            raise
        writing = self.writers.judge(sequence, now_s, writer, alone)
        if writing is Writing.FOREIGN:
            self.foreign_chunks += 1
            return writing
        if writing is Writing.SWITCHED:
            self._gap(math.inf)
        elif missed := self.writers.missed:
            self.dropped_chunks += missed
            self._gap(max(missed * len(samples), 1) / self.rate_hz)  # chunks as this one
        windows = self._assembler.push_windows(samples)
        energies = frame_energies_db(windows)
        if published_ns is not None:
            self._clock.add(len(samples), published_ns)
        n = self._assembler.samples_per_window
        for e, w in zip(energies, windows, strict=True):
            first = self._windows_since_gap * n
            self._windows_since_gap += 1
            span = self._clock.window_ns(first, n) if published_ns is not None else None
            self._ready.append(SourceWindow(float(e), w if self.samples else None, span_ns=span,
                                            gap_s=self._lost_s))  # fmt: skip
            self._lost_s = 0.0
        return writing

    def _gap(self, lost_s: float) -> None:
        """Audio was lost (``lost_s`` seconds, inf: unknown): the next window starts anew."""
        self._assembler.reset()
        self._clock.reset()
        self._windows_since_gap = 0
        self._lost_s = lost_s

    def take(self) -> list[SourceWindow]:
        ready, self._ready = self._ready, []
        return ready

    def describe(self) -> str:
        return f"the 'audio' topic at {self.rate_hz} Hz"

    def status(self) -> dict[str, Any]:
        return {"dropped_chunks": self.dropped_chunks, "bad_chunks": self.bad_chunks,
                "foreign_chunks": self.foreign_chunks,
                "audio_writer_changes": self.writers.switches}  # fmt: skip


class MicrophoneWindows(WindowSource):
    """A live microphone (:class:`~infomax_contingency.audio.capture.MicrophoneStream`).

    A gap before a window is logged (the step clock goes on without bits for the missing
    time); windows that lost samples are counted; :meth:`published` measures the delay from
    a window's last sample to its bit.

    Args:
        stream: the (not yet started) stream.
        samples: keep each window's samples.
        log: ``log(level, message)``; default: the stream's.
        clock: the stream's clock (monotonic seconds).
    """

    def __init__(
        self,
        stream: MicrophoneStream,
        samples: bool = False,
        log: LogFunction | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.stream = stream
        self.samples = samples
        self._log = log or default_log
        self._clock = clock
        self.windows_with_loss = 0
        self.window_delay_s = self.max_window_delay_s = float("nan")

    def start(self) -> None:
        self.stream.start()

    def take(self) -> list[SourceWindow]:
        taken = []
        for w in self.stream.read_windows(0.0):
            if w.gap_s > 0:
                self._log("warning", f"audio gap of {w.gap_s:.2f} s before window {w.index}: the"
                          " step clock goes on, without bits for the missing time")  # fmt: skip
            self.windows_with_loss += not w.intact
            taken.append(SourceWindow(w.energy_db, w.samples if self.samples else None, None,
                                      w.end_time, w.gap_s, w.intact, w.index,
                                      w.start_time))  # fmt: skip
        return taken

    def published(self, window: SourceWindow) -> None:
        """``window``'s bit went out now: the delay from its last sample, seconds."""
        self.window_delay_s = self._clock() - window.end_time
        self.max_window_delay_s = max(self.window_delay_s, self.max_window_delay_s)

    def status(self) -> dict[str, Any]:
        values = self.stream.status().as_dict()
        values["captured_windows"] = values.pop("windows")
        values["windows_with_loss"] = self.windows_with_loss
        values["window_delay_s"] = self.window_delay_s
        values["max_window_delay_s"] = self.max_window_delay_s
        return values

    def close(self) -> None:
        self.stream.close()


class WavReplay(WindowSource):
    """The window energies of a WAV file, served one at a time, optionally looping.

    The file is read block by block as windows are served (and read again from the
    start when looping), so memory does not depend on its length.

    Args:
        path: the WAV file.
        window_s: window length, seconds.
        channel: ``None`` to mix all channels, or the 0-based channel to use.
        loop: start again from the first window after the last one.
        rate: processing rate the file is resampled to, Hz.
        samples: serve each window's samples (:meth:`next_window`) instead of its
            energy (:meth:`next_energy`), for bit sources that look at the samples.

    Raises:
        AudioError: the file cannot be read, the channel does not exist, or the file
            holds less than one window.
    """

    def __init__(
        self,
        path: str | Path,
        window_s: float,
        channel: int | None = None,
        loop: bool = False,
        rate: int = PROCESSING_RATE_HZ,
        samples: bool = False,
    ) -> None:
        self.path = Path(path)
        self.samples = samples
        self.loop = loop
        self.window_s = window_s
        self.channel = channel
        self.rate = rate
        with WavReader(self.path) as reader:
            info = reader.info
        to_mono(np.empty((0, info.channels)), channel)  # a missing channel fails here
        self._n_windows = wav_window_count(info, window_s, rate)
        if self._n_windows == 0:
            raise AudioError(
                f"{self.path} lasts {info.duration_s:.3f} s, shorter than one window"
                f" ({window_s} s)"
            )
        self._blocks: Iterator[np.ndarray] | None = None
        self._block = np.empty(0)
        self._in_block = 0
        self.position = 0
        """Windows served so far (counting every loop)."""

    @property
    def n_windows(self) -> int:
        """Complete windows in the file (a trailing partial window is dropped)."""
        return self._n_windows

    @property
    def finished(self) -> bool:
        """True once every window was served (never, when looping)."""
        return not self.loop and self.position >= self.n_windows

    def next_energy(self) -> float | None:
        """Energy (dB) of the next window, or None at the end of a non-looping file."""
        if self.samples:
            raise AudioError("this replay serves samples (samples=True): use next_window()")
        item = self._next_item()
        return None if item is None else float(item)

    def next_window(self) -> np.ndarray | None:
        """Samples of the next window (float64, mono), or None at the end of a non-looping file."""
        if not self.samples:
            raise AudioError("this replay serves energies (samples=False): use next_energy()")
        return self._next_item()

    def _next_item(self) -> np.ndarray | float | None:
        """The next window's energy or samples (as the replay serves), None at the end."""
        if self.finished:
            return None
        if self.position % self.n_windows == 0:
            blocks = iter_wav_windows if self.samples else iter_wav_energies
            self._blocks = blocks(self.path, self.window_s, self.channel, self.rate)
            self._block, self._in_block = np.empty(0), 0
        while self._in_block >= len(self._block):
            block = next(self._blocks, None)
            if block is None:
                raise AudioError(
                    f"{self.path} ended after {self.position % self.n_windows} of its"
                    f" {self.n_windows} windows: the file changed while it was replayed"
                )
            self._block, self._in_block = block, 0
        item = self._block[self._in_block]
        self._in_block += 1
        self.position += 1
        return item

    replay = True

    def take(self) -> list[SourceWindow]:
        """The next window (its samples if the replay serves samples); [] at the end."""
        if self.samples:
            window = self.next_window()
            return [] if window is None else [SourceWindow(float(frame_energies_db(
                window.reshape(1, -1))[0]), window)]  # fmt: skip
        energy = self.next_energy()
        return [] if energy is None else [SourceWindow(energy)]

    def read_ahead(self, seconds: float, window_s: float) -> tuple[NDArray[np.float64],
                                                                   NDArray[np.float64] | None]:
        if not self.samples:
            return self.calibration_energies(seconds, window_s), None
        windows = self.calibration_windows(seconds, window_s)
        return frame_energies_db(windows), windows

    def describe(self) -> str:
        return f"{self.path}: {self.n_windows} windows of {self.window_s} s"

    def calibration_energies(self, calibration_s: float, window_s: float) -> np.ndarray:
        """Energies of the first ``calibration_s`` seconds (the whole file if shorter).

        Reads only the start of the file (block by block), whatever its length.
        """
        count = calibration_window_count(calibration_s, window_s)
        return wav_energies(self.path, self.window_s, self.channel, self.rate, max_windows=count)

    def calibration_windows(self, calibration_s: float, window_s: float) -> np.ndarray:
        """Samples of the first ``calibration_s`` seconds, one window per row.

        The whole file if shorter; reads only the start of the file, block by block.
        """
        count = calibration_window_count(calibration_s, window_s)
        parts: list[np.ndarray] = []
        rows = 0
        for windows in iter_wav_windows(self.path, self.window_s, self.channel, self.rate):
            parts.append(windows)
            rows += len(windows)
            if rows >= count:
                break
        return np.concatenate(parts)[:count]

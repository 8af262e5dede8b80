"""Window timing of a live capture: ADC times, losses, segments and gaps, as a plain class.

:class:`WindowTimeline` is the bookkeeping behind
:class:`~infomax_contingency.audio.capture.MicrophoneStream`, with no threads, no clock
and no device: device-rate blocks (their ADC time on the caller's monotonic clock, the
samples dropped before them, an overflow flag) go in; processing-rate
:class:`AudioChunk` s and :class:`Window` s come out.

Rules:
    * Times follow the device's sample clock: a segment's first block anchors it; every
      later sample is ``anchor + samples / rate + lost time``, so a late reader does not
      shift them.
    * Loss: dropped blocks are counted exactly; an overflow's length is estimated from
      the ADC times (the block starts later than the previous one ended). A loss shorter
      than one window stays inside the window it hits (``lost_samples`` > 0); a loss of a
      window or more starts a new segment: the partial window is dropped.
    * Gap: the first window of every segment after the first carries ``gap_s``, the
      missing time since the previous window ended; no window is made up for it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from infomax_contingency.audio.energy import WindowAssembler, frame_energies_db, window_samples
from infomax_contingency.audio.resample import StreamResampler
from infomax_contingency.audio.wav import to_mono


@dataclasses.dataclass(frozen=True)
class Window:
    """One microphone window.

    Attributes:
        index: windows emitted by this stream before this one.
        energy_db: mean energy, dB (as :func:`..energy.window_energies_db`).
        start_time: ADC time of the window's first sample, monotonic-clock seconds.
        end_time: ADC time just after its last sample (``start_time + window_s`` plus any
            lost audio inside).
        lost_samples: device-rate samples known to be lost inside the window (blocks the
            reader was too slow to take, plus the estimated length of input overflows).
        overflows: PortAudio input overflows (xruns) reported inside the window.
        segment: 0 for the first stretch of continuous audio, +1 after every gap.
        gap_s: missing audio right before this window, seconds: > 0 only for the first
            window after a gap (a reconnect, or a loss of a whole window or more). No
            window is made up for the missing time.
        samples: the window's mono samples at the processing rate (for bit sources that
            look at more than the energy); not compared or printed.
    """

    index: int
    energy_db: float
    start_time: float
    end_time: float
    lost_samples: int = 0
    overflows: int = 0
    segment: int = 0
    gap_s: float = 0.0
    samples: NDArray[np.float64] | None = dataclasses.field(
        default=None, compare=False, repr=False
    )

    @property
    def intact(self) -> bool:
        """True if no sample of the window was lost."""
        return self.lost_samples == 0 and self.overflows == 0


@dataclasses.dataclass(frozen=True)
class AudioChunk:
    """Mono samples at the processing rate, as ``MicrophoneStream.read_audio`` returns them.

    Attributes:
        samples: float64 mono samples at the processing rate.
        start_time: ADC time of ``samples[0]``, monotonic-clock seconds.
        lost_samples: device-rate samples lost right before this chunk.
        overflows: input overflows reported with this chunk.
        segment: continuity segment (see :attr:`Window.segment`).
    """

    samples: NDArray[np.float64]
    start_time: float
    lost_samples: int
    overflows: int
    segment: int


class WindowTimeline:
    """Device blocks to timed processing-rate chunks and windows (see the module docstring).

    Call :meth:`start_stream` whenever a device stream (re)opens, then :meth:`convert`
    every block in order and :meth:`assemble` the chunks into windows.

    Args:
        rate: processing rate, Hz.
        window_s: window length, seconds.
    """

    def __init__(self, rate: int, window_s: float) -> None:
        self.rate = int(rate)
        self.samples_per_window = window_samples(self.rate, window_s)
        self.device_rate = 0
        self.windows = 0
        """Windows emitted."""
        self.lost_samples = 0
        """Device-rate samples known lost (dropped blocks, estimated overflows)."""
        self.gaps = 0
        """Gaps (reconnects, losses of a window or more) seen by a window."""
        self.gap_total_s = 0.0
        """Total missing time over the gaps, seconds."""
        self.segment = -1
        self._resampler: StreamResampler | None = None
        self._assembler = WindowAssembler(self.rate, window_s)
        self._last_end: float | None = None  # end time of the last window emitted
        self._pending_gap = False
        self._clear_segment()

    def start_stream(self, device_rate: int) -> None:
        """A device stream (re)opened at ``device_rate`` Hz: a new segment begins."""
        if device_rate != self.device_rate or self._resampler is None:
            self._resampler = StreamResampler(device_rate, self.rate)
        self.device_rate = int(device_rate)
        self.new_segment()

    def new_segment(self) -> None:
        """Start a continuous stretch of audio: fresh filter, window, time anchor."""
        if self._resampler is not None:
            self._resampler.reset()
        self._assembler.reset()
        self.segment += 1
        self._pending_gap = self.segment > 0
        self._clear_segment()

    def _clear_segment(self) -> None:
        """Per-segment times and losses back to their start values."""
        self._anchor: float | None = None  # time of the segment's first sample
        self._seg_out = 0  # processing-rate samples of the segment so far
        self._seg_lost_s = 0.0  # lost time inside the segment so far
        self._prev_block_end: float | None = None  # expected time of the next block
        self._win_start = 0  # segment sample index where the filling window starts
        self._win_lost_s_before = 0.0  # lost time before the filling window
        self._win_lost = 0
        self._win_lost_s = 0.0
        self._win_overflows = 0

    def _block_loss(self, t: float | None, dropped_before: int, overflow: bool) -> int:
        """Device samples lost before a block starting at ``t``; a long loss starts a segment."""
        lost = dropped_before
        if overflow and t is not None and self._prev_block_end is not None:
            lost += max(0, round((t - self._prev_block_end) * self.device_rate))
        long_loss = lost * self.rate >= self.samples_per_window * self.device_rate
        if lost and self._anchor is not None and long_loss:
            self.lost_samples += lost
            self.new_segment()
            return 0
        return lost

    def convert(
        self,
        data: np.ndarray,
        t: float | None,
        dropped_before: int,
        overflow: bool,
        channel: int | None,
        now: float,
    ) -> AudioChunk:
        """One device block to a processing-rate chunk.

        Args:
            data: device samples, ``(frames, channels)``.
            t: ADC time of ``data[0]`` on the caller's clock, None if the device gave none.
            dropped_before: device samples dropped right before this block.
            overflow: the device reported an input overflow with this block.
            channel: channel to keep, None to average them.
            now: the caller's clock now (anchors a segment whose blocks have no time).
        """
        frames = data.shape[0]
        lost = self._block_loss(t, dropped_before, overflow)
        if self._anchor is None:
            self._anchor = t if t is not None else now
        self.lost_samples += lost
        self._seg_lost_s += lost / self.device_rate
        start_time = self._anchor + self._seg_out / self.rate + self._seg_lost_s
        samples = self._resampler.push(to_mono(data, channel))
        self._seg_out += samples.size
        self._prev_block_end = (t if t is not None else start_time) + frames / self.device_rate
        return AudioChunk(samples, start_time, lost, int(overflow), self.segment)

    def assemble(self, chunk: AudioChunk) -> list[Window]:
        """Cut a chunk into windows (losses go to the window being filled)."""
        self._win_lost += chunk.lost_samples
        self._win_lost_s += chunk.lost_samples / self.device_rate
        self._win_overflows += chunk.overflows
        windows = self._assembler.push_windows(chunk.samples)
        energies = frame_energies_db(windows).tolist()
        return [
            self._window(energy, samples)
            for energy, samples in zip(energies, windows, strict=True)
        ]

    def _window(self, energy: float, samples: NDArray[np.float64]) -> Window:
        """The window just completed, with its times, losses and gap."""
        n = self.samples_per_window
        start = self._anchor + self._win_start / self.rate + self._win_lost_s_before
        end = start + n / self.rate + self._win_lost_s
        gap = 0.0
        if self._pending_gap:
            gap = max(0.0, start - self._last_end) if self._last_end is not None else 0.0
            self.gaps += 1
            self.gap_total_s += gap
            self._pending_gap = False
        window = Window(
            index=self.windows,
            energy_db=energy,
            start_time=start,
            end_time=end,
            lost_samples=self._win_lost,
            overflows=self._win_overflows,
            segment=self.segment,
            gap_s=gap,
            samples=samples,
        )
        self.windows += 1
        self._last_end = end
        self._win_start += n
        self._win_lost_s_before += self._win_lost_s
        self._win_lost = 0
        self._win_lost_s = 0.0
        self._win_overflows = 0
        return window

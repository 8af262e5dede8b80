"""Window energies: whole signals, streams of chunks, and WAV files read block by block.

Each window of ``window_s`` seconds of mono audio is reduced to its mean energy (mean
square amplitude) in dB: ``10 * log10(mean_square + ENERGY_FLOOR)`` relative to full
scale, so a full-scale sine is -3.01 dB and digital silence is ``ENERGY_FLOOR_DB``
(-120 dB). A trailing partial window is dropped.

:func:`iter_wav_energies` is the one path from a WAV file to window energies (used by
the wav replay, the calibrate command and the offline tools): blocks of the file are
mixed down, resampled (:class:`~infomax_contingency.audio.resample.StreamResampler`) and
windowed (:class:`WindowAssembler`) as they are read, so memory does not grow with the
file, and the energies equal :func:`window_energies_db` of
:func:`~infomax_contingency.audio.resample.load_mono` of the file exactly.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.common import (
    PROCESSING_RATE_HZ,
    AudioError,
    as_mono,
    check_positive_seconds,
    check_rate,
)
from infomax_contingency.audio.resample import (
    StreamResampler,
    input_block_frames,
    resampled_length,
)
from infomax_contingency.audio.wav import DEFAULT_BLOCK_FRAMES, WavInfo, WavReader, to_mono

ENERGY_FLOOR = 1e-12
"""Added to every window's mean square before the log, so silence maps to a finite dB."""

ENERGY_FLOOR_DB = -120.0
"""Energy of a digitally silent window, dB (``10 * log10(ENERGY_FLOOR)``)."""


def window_samples(rate: int, window_s: float) -> int:
    """Number of samples in one window: ``round(window_s * rate)`` (at least 1)."""
    rate = check_rate(rate)
    window_s = check_positive_seconds(window_s, "window_s")
    n = round(window_s * rate)
    if n < 1:
        raise AudioError(
            f"window_s={window_s} s holds no sample at {rate} Hz; use at least {1 / rate:.3g} s"
        )
    return n


def frame_energies_db(frames: NDArray[np.float64]) -> NDArray[np.float64]:
    """Energy in dB of each row of ``frames`` (one window per row), as in the module docstring."""
    return 10.0 * np.log10(np.mean(frames * frames, axis=1) + ENERGY_FLOOR)


def window_energies_db(samples: ArrayLike, rate: int, window_s: float) -> NDArray[np.float64]:
    """Mean energy of each complete window, in dB.

    The signal is cut into consecutive windows of :func:`window_samples` samples; each
    window's energy is ``10 * log10(mean(x**2) + ENERGY_FLOOR)`` (silence gives
    ``ENERGY_FLOOR_DB``). A trailing partial window is dropped.

    Args:
        samples: mono samples in [-1, 1], shaped ``(n,)``.
        rate: sample rate, Hz.
        window_s: window length, seconds.

    Returns:
        float64 energies shaped ``(n // window_samples,)``; empty if the signal is
        shorter than one window.
    """
    n = window_samples(rate, window_s)
    x = as_mono(samples)
    n_windows = x.size // n
    return frame_energies_db(x[: n_windows * n].reshape(n_windows, n))


class WindowAssembler:
    """Streaming version of :func:`window_energies_db`.

    Chunks of any size go in; the energies of the windows they complete come out, and the
    leftover samples wait for the next chunk. The energies equal those of
    :func:`window_energies_db` on the concatenated stream, whatever the chunking.

    Args:
        rate: sample rate of the chunks, Hz.
        window_s: window length, seconds.
    """

    def __init__(self, rate: int, window_s: float) -> None:
        self._n = window_samples(rate, window_s)
        self._rest = np.empty(0)

    @property
    def samples_per_window(self) -> int:
        """Number of samples in one window."""
        return self._n

    def push_windows(self, chunk: ArrayLike) -> NDArray[np.float64]:
        """Add mono samples; return the windows they complete, one per row.

        Shaped ``(windows, samples_per_window)`` (no row when no window is complete).
        """
        buf = np.concatenate((self._rest, as_mono(chunk, "chunk")))
        n_windows = buf.size // self._n
        end = n_windows * self._n
        self._rest = buf[end:].copy()
        return buf[:end].reshape(n_windows, self._n)

    def push_array(self, chunk: ArrayLike) -> NDArray[np.float64]:
        """Add mono samples; return the energies (dB) of the windows they complete, as an array."""
        return frame_energies_db(self.push_windows(chunk))

    def push(self, chunk: ArrayLike) -> list[float]:
        """Add mono samples; return the energies (dB) of the windows they complete, in order."""
        return self.push_array(chunk).tolist()

    def reset(self) -> None:
        """Drop the samples of the incomplete window (e.g. after a gap in the stream)."""
        self._rest = np.empty(0)


def wav_window_count(info: WavInfo, window_s: float, rate: int = PROCESSING_RATE_HZ) -> int:
    """Complete windows of ``window_s`` s in the file once resampled to ``rate`` Hz."""
    frames = resampled_length(info.frames, info.rate, check_rate(rate))
    return frames // window_samples(rate, window_s)


def iter_wav_windows(
    path: str | os.PathLike[str],
    window_s: float,
    channel: int | None = None,
    rate: int = PROCESSING_RATE_HZ,
    block_frames: int = DEFAULT_BLOCK_FRAMES,
) -> Iterator[NDArray[np.float64]]:
    """The windows of a WAV file's samples, yielded block by block.

    Each yielded array is shaped ``(windows, samples_per_window)`` with at least one row:
    the file read ``block_frames`` frames at a time, mixed down (mean of the channels, or
    ``channel``), resampled to ``rate`` Hz and cut into windows as it goes; memory stays
    that of one block whatever the file length. The concatenated rows equal the windows
    of ``load_mono(path, rate, channel)`` exactly (a trailing partial window is dropped).

    Raises:
        AudioError: the file cannot be read, or ``channel`` does not exist in it (both
            raised at the first ``next()``; use :class:`WavReader` first to check early).
    """
    rate = check_rate(rate)
    assembler = WindowAssembler(rate, window_s)
    with WavReader(path) as reader:
        info = reader.info
        to_mono(np.empty((0, info.channels)), channel)  # a missing channel fails now
        resampler = StreamResampler(info.rate, rate, str(info.path))
        for block in reader.blocks(input_block_frames(block_frames, info.rate, rate)):
            windows = assembler.push_windows(resampler.push(to_mono(block, channel)))
            if windows.size:
                yield windows
        windows = assembler.push_windows(resampler.finish())
        if windows.size:
            yield windows


def iter_wav_energies(
    path: str | os.PathLike[str],
    window_s: float,
    channel: int | None = None,
    rate: int = PROCESSING_RATE_HZ,
    block_frames: int = DEFAULT_BLOCK_FRAMES,
) -> Iterator[NDArray[np.float64]]:
    """Window energies (dB) of a WAV file, yielded block by block (each a non-empty array).

    The energies of :func:`iter_wav_windows`' blocks (:func:`frame_energies_db`): the
    concatenated arrays equal
    ``window_energies_db(load_mono(path, rate, channel), rate, window_s)`` exactly.

    Raises:
        AudioError: the file cannot be read, or ``channel`` does not exist in it (both
            raised at the first ``next()``; use :class:`WavReader` first to check early).
    """
    for windows in iter_wav_windows(path, window_s, channel, rate, block_frames):
        yield frame_energies_db(windows)


def wav_energies(
    path: str | os.PathLike[str],
    window_s: float,
    channel: int | None = None,
    rate: int = PROCESSING_RATE_HZ,
    max_windows: int | None = None,
) -> NDArray[np.float64]:
    """All window energies (dB) of a WAV file, or only its first ``max_windows``.

    Reads the file block by block (:func:`iter_wav_energies`) and stops once
    ``max_windows`` are in, so the start of a 10-hour file costs what it costs.
    """
    parts: list[NDArray[np.float64]] = []
    count = 0
    for energies in iter_wav_energies(path, window_s, channel, rate):
        parts.append(energies)
        count += energies.size
        if max_windows is not None and count >= max_windows:
            break
    out = np.concatenate(parts) if parts else np.empty(0)
    return out if max_windows is None else out[:max_windows]

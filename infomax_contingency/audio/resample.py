"""Sample-rate conversion: whole signals (:func:`resample`) and streams (:class:`StreamResampler`).

Both are the same polyphase filter (``scipy.signal.resample_poly``: the ratio reduced by
the gcd, a ``firwin`` Kaiser (beta 5) low-pass of half-length 10 x max(up, down)), and
give the same samples bit for bit: a stream pushed in chunks of any size and then
:meth:`StreamResampler.finish`-ed equals :func:`resample` of the whole signal.
"""

from __future__ import annotations

import math
import os

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError, check_rate
from infomax_contingency.audio.wav import open_wav_info, read_wav, to_mono
from infomax_contingency.limits import refuse_over_budget

MAX_RATIO_TERM = 100_000
"""Largest term of the reduced rate ratio resampled (``max(up, down)``): the filter has
20 x that many taps. Real rates stay far below (44.1 -> 48 kHz: 160; 44,056 Hz -> 16 kHz:
5,507); a prime rate of 15,485,863 Hz would need 3 * 10^8 taps (7 GB)."""
FILTER_BYTES_PER_TAP = 48
"""Peak memory of building and applying the filter, bytes per tap (measured 47 with
999,983 Hz -> 16 kHz: 2.1 * 10^7 taps, 1.0 GB)."""


def rate_ratio(from_rate: int, to_rate: int) -> tuple[int, int]:
    """``(up, down)``: ``to_rate / from_rate`` reduced by their gcd (rates in Hz)."""
    g = math.gcd(int(from_rate), int(to_rate))
    return int(to_rate) // g, int(from_rate) // g


def check_resampling(from_rate: int, to_rate: int, what: str = "audio") -> None:
    """Refuse a resampling whose filter is too long or too large for the memory budget.

    Args:
        from_rate: input rate, Hz.
        to_rate: output rate, Hz.
        what: the audio, for the message (``"x.wav"``).

    Raises:
        AudioError: one line, saying how to convert the file first (``sox``).
    """
    up, down = rate_ratio(from_rate, to_rate)
    term = max(up, down)
    if term == 1:
        return
    doing = f"resample {what} from {int(from_rate):,} Hz to {int(to_rate):,} Hz"
    advice = f"convert it first, e.g. `sox in.wav -r {int(to_rate)} out.wav`"
    if term > MAX_RATIO_TERM:
        raise AudioError(f"refusing to {doing}: the ratio of the rates reduces to"
                         f" {up:,}/{down:,}, a filter of"
                         f" {20 * term + 1:,} taps (at most {20 * MAX_RATIO_TERM + 1:,});"
                         f" {advice}")
    refuse_over_budget(FILTER_BYTES_PER_TAP * (20 * term + 1), doing, advice, AudioError)


def resample(samples: ArrayLike, from_rate: int, to_rate: int) -> NDArray[np.float64]:
    """Resample along the first axis from ``from_rate`` to ``to_rate`` Hz (polyphase).

    Uses ``scipy.signal.resample_poly`` with the ratio reduced by the gcd; the output has
    ``ceil(frames * to_rate / from_rate)`` frames. Equal rates return a float64 copy.
    A filter too long is refused first (:func:`check_resampling`).
    """
    from_rate = check_rate(from_rate, "from_rate")
    to_rate = check_rate(to_rate, "to_rate")
    x = np.asarray(samples, dtype=np.float64)
    if from_rate == to_rate:
        return x.copy()
    check_resampling(from_rate, to_rate)
    from scipy.signal import resample_poly  # lazy: ~1 s of CPU to load

    return resample_poly(x, *rate_ratio(from_rate, to_rate), axis=0)


def resampled_length(frames: int, from_rate: int, to_rate: int) -> int:
    """Frames :func:`resample` outputs for ``frames`` input frames: ``ceil(frames * to / from)``."""
    up, down = rate_ratio(from_rate, to_rate)
    return -(-frames * up // down)


def load_mono(
    path: str | os.PathLike[str], rate: int = PROCESSING_RATE_HZ, channel: int | None = None
) -> NDArray[np.float64]:
    """Read a whole WAV file, reduce it to mono (see :func:`to_mono`) and resample to ``rate``.

    Returns:
        float64 mono samples shaped ``(frames,)`` at ``rate`` Hz.
    """
    rate = check_rate(rate)
    info = open_wav_info(path)
    check_resampling(info.rate, rate, str(info.path))
    refuse_over_budget(
        4 * resampled_length(info.frames, info.rate, rate) * np.dtype(np.float64).itemsize,
        f"resample all of {info.path} at once to {rate} Hz", "give a shorter file", AudioError,
    )
    samples, file_rate = read_wav(path)
    return resample(to_mono(samples, channel), file_rate, rate)


def input_block_frames(output_frames: int, from_rate: int, to_rate: int) -> int:
    """Input frames per block so that the block resampled to ``to_rate`` is ``output_frames``.

    At least 1: a 1 Hz file upsampled to 16 kHz is read a few frames at a time, not 65536
    (10^9 output samples).
    """
    return max(1, output_frames * int(from_rate) // max(int(from_rate), int(to_rate)))


class StreamResampler:
    """Streaming polyphase resampler reproducing :func:`resample`.

    :func:`resample` is ``scipy.signal.resample_poly`` over a whole signal. This class
    computes exactly the same output samples (bit for bit) from chunks of any size: the
    same FIR filter is applied with ``upfirdn`` to the buffered input, and an output
    sample is emitted once every input it depends on has arrived (a delay of about
    ``10 * max(up, down) / up`` input samples, under 1 ms for 48 kHz -> 16 kHz). The
    stream start is treated like the start of a signal (zeros before it). A live stream
    never ends, so its last few outputs wait for more input; a file does:
    :meth:`finish` then emits the rest as if zeros followed, as ``resample_poly`` does.
    :meth:`reset` starts a new signal (after a gap).

    Args:
        from_rate: input rate, Hz.
        to_rate: output rate, Hz.
        what: the audio, for a refusal (:func:`check_resampling`: a filter too long).
    """

    def __init__(self, from_rate: int, to_rate: int, what: str = "audio") -> None:
        check_resampling(from_rate, to_rate, what)
        self.up, self.down = rate_ratio(from_rate, to_rate)
        self.reset()
        if self.up == self.down:
            return
        half_len = 10 * max(self.up, self.down)
        from scipy.signal import firwin, upfirdn  # lazy: ~1 s of CPU to load

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

    def _emit(self, end: int) -> NDArray[np.float64]:
        """Outputs ``_n_out`` .. ``end - 1`` from the buffered input; drop what no longer counts."""
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

    def push(self, chunk: ArrayLike) -> NDArray[np.float64]:
        """Add mono input samples; return the output samples that are now complete."""
        x = np.asarray(chunk, dtype=np.float64)
        if self.up == self.down:
            return x.copy()
        self._buf = np.concatenate((self._buf, x))
        self._n_in += x.size
        return self._emit((self._n_in * self.up - 1) // self.down - self._skip + 1)

    def finish(self) -> NDArray[np.float64]:
        """End the signal: the outputs still owed, so the total is ``ceil(n_in * up / down)``.

        The stream then starts over as after :meth:`reset`.
        """
        if self.up == self.down:
            self.reset()
            return np.empty(0)
        total = -(-self._n_in * self.up // self.down)
        # zeros after the end up to the last input the last output depends on; upfirdn's
        # full convolution treats what follows as zeros (a pad of h.size inputs would be
        # h.size * up outputs: 3 * 10^8 for a 4 Hz file resampled to 16 kHz)
        needed = -(-((total + self._skip - 1) * self.down + 1) // self.up)
        pad = max(0, needed - self._n_in)
        self._buf = np.concatenate((self._buf, np.zeros(pad)))
        out = self._emit(total)
        self.reset()
        return out

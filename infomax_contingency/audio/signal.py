"""From audio to bits: window energies, the k-means threshold and the binarizer.

This is the one implementation of MODEL.md section 6, used by the mic node, the offline
tools, the calibrate command and the tests. Each window of ``window_s`` seconds of mono
audio is reduced to its mean energy (mean square amplitude) in dB; the threshold theta is
the boundary of an exact two-cluster k-means of calibration energies; the bit is
``y = energy > theta``.

Conventions:
    * Samples are float64 in [-1, 1] (full scale = 1). Multi-channel arrays are shaped
      ``(frames, channels)``; mono arrays are 1-D.
    * Sample rates are positive integers in Hz; durations are in seconds.
    * Energies are ``10 * log10(mean_square + ENERGY_FLOOR)`` dB relative to full scale:
      a full-scale sine is -3.01 dB, digital silence is ``ENERGY_FLOOR_DB`` (-120 dB).
"""

from __future__ import annotations

import dataclasses
import datetime
import math
import os
import struct
import warnings
from collections import deque
from pathlib import Path

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray
from scipy.io import wavfile

PROCESSING_RATE_HZ = 16000
"""Sample rate (Hz) at which audio is windowed and measured."""

ENERGY_FLOOR = 1e-12
"""Added to every window's mean square before the log, so silence maps to a finite dB."""

ENERGY_FLOOR_DB = -120.0
"""Energy of a digitally silent window, dB (``10 * log10(ENERGY_FLOOR)``)."""

THRESHOLD_FORMAT_VERSION = 1
"""Version of the threshold file layout written by :func:`save_threshold`."""

_TIE_RTOL = 1e-9
"""k-means splits whose squared error differs by less than this fraction of the total
sum of squares count as tied (the lowest one wins)."""

_FADE_S = 0.01
"""Fade-in / fade-out length of the synthesized chirp, seconds."""

_WAV_MAGICS = (b"RIFF", b"RIFX", b"RF64")


class AudioError(ValueError):
    """A user-facing audio problem: unreadable file, bad samples, unusable calibration."""


# --------------------------------------------------------------------------- validation


def _check_rate(rate: int, name: str = "rate") -> int:
    """Return ``rate`` as an int, or raise AudioError unless it is a positive integer (Hz)."""
    if isinstance(rate, bool) or not isinstance(rate, int | float | np.integer | np.floating):
        raise AudioError(f"{name} must be a positive integer in Hz, got {rate!r}")
    if not math.isfinite(rate) or rate <= 0 or int(rate) != rate:
        raise AudioError(f"{name} must be a positive integer in Hz, got {rate!r}")
    return int(rate)


def _check_positive_seconds(value: float, name: str) -> float:
    """Return ``value`` as a float, or raise AudioError unless it is finite and > 0."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise AudioError(f"{name} must be a positive number of seconds, got {value!r}")
    if not math.isfinite(value) or value <= 0:
        raise AudioError(f"{name} must be a positive number of seconds, got {value!r}")
    return float(value)


def _float_samples(samples: ArrayLike, name: str) -> NDArray[np.float64]:
    """Return finite float64 samples, or raise AudioError (integer PCM arrays are refused)."""
    if isinstance(samples, np.ndarray) and samples.dtype.kind in "iu":
        raise AudioError(
            f"{name} are {samples.dtype} integers; scale them to floats in [-1, 1] first "
            "(e.g. divide int16 by 32768), or read files with read_wav()"
        )
    x = np.asarray(samples, dtype=np.float64)
    if not np.isfinite(x).all():
        raise AudioError(f"{name} contain NaN or infinite values")
    return x


def _as_mono(samples: ArrayLike, name: str = "samples") -> NDArray[np.float64]:
    """Return a 1-D finite float64 array, or raise AudioError saying what is wrong."""
    x = _float_samples(samples, name)
    if x.ndim != 1:
        raise AudioError(
            f"{name} must be mono, shaped (n,); got shape {x.shape}. Mix down with to_mono()."
        )
    return x


# --------------------------------------------------------------------------- reading wavs


def read_wav(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], int]:
    """Read a WAV file as float samples.

    Reads PCM 8-bit (unsigned), 16/24/32-bit (signed) integer and 32/64-bit float WAVs
    with any channel count and sample rate. Integer data is scaled to [-1, 1) (8-bit is
    offset by 128); float data is returned as stored (nominally [-1, 1], not clipped).
    Harmless format warnings (unknown or padding chunks) are suppressed.

    Args:
        path: the WAV file.

    Returns:
        ``(samples, rate)``: float64 samples shaped ``(frames, channels)`` and the sample
        rate in Hz.

    Raises:
        AudioError: the file is missing, a directory, not a RIFF/WAVE file, truncated or
            corrupt, uses an unsupported encoding, holds no frames, has a 0 Hz rate, or
            holds NaN/infinite float samples.
    """
    path = Path(path)
    if not path.exists():
        raise AudioError(f"audio file {path} does not exist")
    if path.is_dir():
        raise AudioError(f"{path} is a directory, not a WAV file")
    try:
        with path.open("rb") as f:
            head = f.read(12)
    except OSError as exc:
        raise AudioError(f"cannot read audio file {path}: {exc.strerror or exc}") from exc
    if not head:
        raise AudioError(f"{path} is a 0-byte file, not a WAV file")
    if head[:4] not in _WAV_MAGICS or (len(head) == 12 and head[8:12] != b"WAVE"):
        raise AudioError(
            f"{path} is not a WAV file (no RIFF/WAVE header; starts with {head[:12]!r}). "
            "Convert it to WAV, e.g. `ffmpeg -i input output.wav`."
        )
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", wavfile.WavFileWarning)
            rate, data = wavfile.read(path)
    except ValueError as exc:
        text = str(exc)
        if text.startswith(("Unknown wave file format", "Unsupported bit depth")):
            raise AudioError(
                f"{path} uses an unsupported WAV encoding ({text}). Convert it to PCM, "
                "e.g. `ffmpeg -i input -c:a pcm_s16le output.wav`."
            ) from exc
        raise AudioError(f"{path} is a corrupt or truncated WAV file ({text})") from exc
    except (EOFError, ArithmeticError, struct.error) as exc:
        raise AudioError(f"{path} is a corrupt or truncated WAV file ({exc})") from exc
    for w in caught:
        if not issubclass(w.category, wavfile.WavFileWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        elif str(w.message).startswith("Reached EOF prematurely"):
            raise AudioError(
                f"{path} is a truncated WAV file ({w.message}). If it was recorded to a "
                "stream, rewrite its header, e.g. `sox input.wav output.wav`."
            )
    if rate <= 0:
        raise AudioError(f"{path} has a sample rate of {rate} Hz in its header (corrupt file)")
    if data.ndim == 1:
        data = data[:, np.newaxis]
    if data.shape[0] == 0:
        raise AudioError(f"{path} is empty: it holds no audio frames")
    if data.dtype == np.uint8:
        samples = (data.astype(np.float64) - 128.0) / 128.0
    elif np.issubdtype(data.dtype, np.signedinteger):
        samples = data.astype(np.float64) / float(-np.iinfo(data.dtype).min)
    else:
        samples = data.astype(np.float64)
        if not np.isfinite(samples).all():
            raise AudioError(f"{path} holds NaN or infinite float samples")
    return samples, int(rate)


def to_mono(samples: ArrayLike, channel: int | None = None) -> NDArray[np.float64]:
    """Reduce ``(frames, channels)`` samples to mono.

    Args:
        samples: shaped ``(frames, channels)``, or 1-D (already mono, one channel).
        channel: ``None`` for the mean of all channels, or the 0-based channel to keep.

    Returns:
        float64 samples shaped ``(frames,)``.
    """
    x = np.asarray(samples, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, np.newaxis]
    elif x.ndim != 2:
        raise AudioError(f"samples must be shaped (frames, channels), got shape {x.shape}")
    n_channels = x.shape[1]
    if n_channels == 0:
        raise AudioError("samples have no channels (shape (frames, 0))")
    if channel is None:
        return x.mean(axis=1)
    if isinstance(channel, bool) or not isinstance(channel, int | np.integer):
        raise AudioError(f"channel must be an integer index or None, got {channel!r}")
    if not 0 <= channel < n_channels:
        raise AudioError(
            f"channel {channel} does not exist: the audio has {n_channels} channel(s), "
            f"numbered 0..{n_channels - 1}"
        )
    return x[:, int(channel)].copy()


def resample(samples: ArrayLike, from_rate: int, to_rate: int) -> NDArray[np.float64]:
    """Resample along the first axis from ``from_rate`` to ``to_rate`` Hz (polyphase).

    Uses ``scipy.signal.resample_poly`` with the ratio reduced by the gcd; the output has
    ``ceil(frames * to_rate / from_rate)`` frames. Equal rates return a float64 copy.
    """
    from_rate = _check_rate(from_rate, "from_rate")
    to_rate = _check_rate(to_rate, "to_rate")
    x = np.asarray(samples, dtype=np.float64)
    if from_rate == to_rate:
        return x.copy()
    from scipy.signal import resample_poly  # imported here: scipy.signal costs ~0.5 s to load

    g = math.gcd(from_rate, to_rate)
    return resample_poly(x, to_rate // g, from_rate // g, axis=0)


def load_mono(
    path: str | os.PathLike[str], rate: int = PROCESSING_RATE_HZ, channel: int | None = None
) -> NDArray[np.float64]:
    """Read a WAV file, reduce it to mono (see :func:`to_mono`) and resample to ``rate`` Hz.

    Returns:
        float64 mono samples shaped ``(frames,)`` at ``rate`` Hz.
    """
    rate = _check_rate(rate)
    samples, file_rate = read_wav(path)
    return resample(to_mono(samples, channel), file_rate, rate)


# --------------------------------------------------------------------------- energies


def window_samples(rate: int, window_s: float) -> int:
    """Number of samples in one window: ``round(window_s * rate)`` (at least 1)."""
    rate = _check_rate(rate)
    window_s = _check_positive_seconds(window_s, "window_s")
    n = round(window_s * rate)
    if n < 1:
        raise AudioError(
            f"window_s={window_s} s holds no sample at {rate} Hz; use at least {1 / rate:.3g} s"
        )
    return n


def _frame_energies_db(frames: NDArray[np.float64]) -> NDArray[np.float64]:
    """Energy in dB of each row of ``frames`` (one window per row)."""
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
    x = _as_mono(samples)
    n_windows = x.size // n
    return _frame_energies_db(x[: n_windows * n].reshape(n_windows, n))


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

    def push(self, chunk: ArrayLike) -> list[float]:
        """Add mono samples; return the energies (dB) of the windows they complete, in order."""
        buf = np.concatenate((self._rest, _as_mono(chunk, "chunk")))
        n_windows = buf.size // self._n
        end = n_windows * self._n
        self._rest = buf[end:].copy()
        return _frame_energies_db(buf[:end].reshape(n_windows, self._n)).tolist()

    def reset(self) -> None:
        """Drop the samples of the incomplete window (e.g. after a gap in the stream)."""
        self._rest = np.empty(0)


# --------------------------------------------------------------------------- threshold


@dataclasses.dataclass(frozen=True)
class ThresholdFit:
    """Result of the two-cluster k-means of window energies.

    Attributes:
        threshold_db: theta, halfway between the two cluster means, dB.
        low_mean_db: mean energy of the quiet cluster, dB.
        high_mean_db: mean energy of the loud cluster, dB.
        n_low: number of windows in the quiet cluster.
        n_high: number of windows in the loud cluster.
    """

    threshold_db: float
    low_mean_db: float
    high_mean_db: float
    n_low: int
    n_high: int


def kmeans_split(energies_db: ArrayLike) -> ThresholdFit:
    """Exact two-cluster k-means of 1-D energies.

    The values are sorted and every split into "lowest k" / "the rest" is scored at once
    with cumulative sums; the split with the least within-cluster squared error wins.
    Ties go to the lowest split, i.e. the lowest threshold; errors within 1e-9 times the
    total sum of squares of each other count as tied, so rounding cannot break a tie. (A
    split inside a run of equal values is never optimal, so equal energies get the same bit.)

    Args:
        energies_db: window energies, dB (any shape; flattened).

    Returns:
        The fit; its threshold is halfway between the two cluster means.

    Raises:
        AudioError: fewer than 2 values, non-finite values, or all values equal.
    """
    x = np.sort(np.asarray(energies_db, dtype=np.float64).ravel())
    n = x.size
    if n < 2:
        raise AudioError(f"need at least 2 window energies to fit a threshold, got {n}")
    if not np.isfinite(x).all():
        raise AudioError("window energies contain NaN or infinite values")
    if x[0] == x[-1]:
        raise AudioError(
            f"all {n} window energies equal {x[0]:.2f} dB, so there is no boundary between "
            "quiet and sound; calibrate on audio that contains both quiet and sound"
        )
    c = x - x.mean()
    low_sums = np.cumsum(c)[:-1]  # sum of the k lowest centred values, k = 1 .. n-1
    k = np.arange(1, n)
    # Between-cluster sum of squares; within-cluster error = total - between.
    between = low_sums * low_sums * n / (k * (n - k))
    best = np.flatnonzero(between >= between.max() - _TIE_RTOL * float(c @ c))[0]
    n_low = int(best) + 1
    low_mean = float(x[:n_low].mean())
    high_mean = float(x[n_low:].mean())
    return ThresholdFit(
        threshold_db=0.5 * (low_mean + high_mean),
        low_mean_db=low_mean,
        high_mean_db=high_mean,
        n_low=n_low,
        n_high=n - n_low,
    )


def kmeans_threshold(energies_db: ArrayLike) -> float:
    """Threshold theta (dB) of the exact two-cluster k-means; see :func:`kmeans_split`."""
    return kmeans_split(energies_db).threshold_db


def bits_from_energies(energies_db: ArrayLike, threshold_db: float) -> NDArray[np.bool_]:
    """Bits ``y = energy > threshold`` (strict), elementwise."""
    if not math.isfinite(threshold_db):
        raise AudioError(f"threshold_db must be finite, got {threshold_db!r}")
    return np.asarray(energies_db, dtype=np.float64) > threshold_db


class OnlineThreshold:
    """Rolling buffer of the last ``capacity`` window energies for refreshing theta online.

    The caller decides when to :meth:`refit` and whether to accept the new fit (a buffer
    of pure silence or pure sound still splits, into two noise clusters).

    Args:
        capacity: number of most recent windows kept (at least 2).
    """

    def __init__(self, capacity: int) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 2:
            raise AudioError(f"capacity must be an integer >= 2 windows, got {capacity!r}")
        self._energies: deque[float] = deque(maxlen=capacity)

    def __len__(self) -> int:
        return len(self._energies)

    def add(self, energy_db: float) -> None:
        """Append one window energy (dB), dropping the oldest when full."""
        if not math.isfinite(energy_db):
            raise AudioError(f"window energy must be finite, got {energy_db!r}")
        self._energies.append(float(energy_db))

    def refit(self) -> ThresholdFit:
        """Two-cluster k-means of the buffered energies; AudioError if they have no boundary."""
        return kmeans_split(np.fromiter(self._energies, dtype=np.float64))


# --------------------------------------------------------------------------- threshold file

_REQUIRED_FIELDS = ("format_version", "threshold_db")


def save_threshold(
    path: str | os.PathLike[str],
    fit: ThresholdFit,
    *,
    window_s: float,
    rate: int,
    source: str,
) -> None:
    """Write a calibrated threshold to a small YAML file (replaced atomically).

    Args:
        path: file to write; missing parent directories are created.
        fit: the k-means fit.
        window_s: window length used for the energies, seconds.
        rate: processing sample rate, Hz.
        source: where the calibration audio came from (file name, device, ...).
    """
    window_s = _check_positive_seconds(window_s, "window_s")
    rate = _check_rate(rate)
    values = (fit.threshold_db, fit.low_mean_db, fit.high_mean_db)
    if not all(math.isfinite(v) for v in values):
        raise AudioError(f"cannot save a threshold fit with non-finite values: {fit}")
    record = {
        "format_version": THRESHOLD_FORMAT_VERSION,
        "threshold_db": float(fit.threshold_db),
        "window_s": window_s,
        "sample_rate_hz": rate,
        "low_mean_db": float(fit.low_mean_db),
        "high_mean_db": float(fit.high_mean_db),
        "n_low": int(fit.n_low),
        "n_high": int(fit.n_high),
        "source": str(source),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(
        "# Sound threshold: a window is 'sound' (y = 1) iff its energy > threshold_db.\n"
        + yaml.safe_dump(record, sort_keys=False),
        encoding="utf-8",
    )
    tmp.replace(path)


def load_threshold(path: str | os.PathLike[str]) -> float:
    """Read the threshold (dB) from a file written by :func:`save_threshold`.

    Raises:
        AudioError: the file is missing, is not a YAML mapping, has another format
            version, lacks ``format_version`` or ``threshold_db``, or the threshold is
            not a finite number.
    """
    path = Path(path)
    if not path.is_file():
        what = "is a directory" if path.is_dir() else "does not exist"
        raise AudioError(
            f"threshold file {path} {what}; create it by calibrating on audio that "
            "contains both quiet and sound"
        )
    try:
        record = yaml.safe_load(path.read_bytes())
    except OSError as exc:
        raise AudioError(f"cannot read threshold file {path}: {exc.strerror or exc}") from exc
    except yaml.YAMLError as exc:
        raise AudioError(f"threshold file {path} is not valid YAML: {exc}") from exc
    if not isinstance(record, dict):
        raise AudioError(
            f"threshold file {path} must hold a YAML mapping with {', '.join(_REQUIRED_FIELDS)}; "
            f"got {type(record).__name__}"
        )
    for field in _REQUIRED_FIELDS:
        if field not in record:
            raise AudioError(f"threshold file {path} is missing the field '{field}'")
    version = record["format_version"]
    if isinstance(version, bool) or version != THRESHOLD_FORMAT_VERSION:
        raise AudioError(
            f"threshold file {path} has format_version {version!r}; this package reads "
            f"format_version {THRESHOLD_FORMAT_VERSION}. Recalibrate to rewrite it."
        )
    value = record["threshold_db"]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise AudioError(f"threshold file {path}: threshold_db must be a number, got {value!r}")
    if not math.isfinite(value):
        raise AudioError(f"threshold file {path}: threshold_db must be finite, got {value!r}")
    return float(value)


# --------------------------------------------------------------------------- sound synthesis


def synthesize_chirp(
    rate: int,
    duration_s: float = 0.2,
    f0: float = 800.0,
    f1: float = 2400.0,
    amplitude: float = 0.5,
) -> NDArray[np.float64]:
    """A linear frequency sweep from ``f0`` to ``f1`` Hz: the robot's default vocalization.

    The first and last 10 ms (at most half the sound each) are faded in and out with a
    raised cosine, so the sound starts and stops without clicks.

    Args:
        rate: sample rate, Hz.
        duration_s: length, seconds.
        f0: start frequency, Hz (below the Nyquist frequency ``rate / 2``).
        f1: end frequency, Hz (below the Nyquist frequency).
        amplitude: peak amplitude, in (0, 1].

    Returns:
        float64 mono samples, ``round(duration_s * rate)`` of them.
    """
    rate = _check_rate(rate)
    n = round(_check_positive_seconds(duration_s, "duration_s") * rate)
    if n < 1:
        raise AudioError(f"duration_s={duration_s} s holds no sample at {rate} Hz")
    for name, f in (("f0", f0), ("f1", f1)):
        if not 0 < f < rate / 2:
            raise AudioError(f"{name}={f} Hz must lie in (0, {rate / 2}) Hz at {rate} Hz")
    if not 0 < amplitude <= 1:
        raise AudioError(f"amplitude must lie in (0, 1], got {amplitude!r}")
    t = np.arange(n) / rate
    length = n / rate
    phase = 2.0 * np.pi * (f0 * t + 0.5 * (f1 - f0) / length * t * t)
    x = amplitude * np.sin(phase)
    m = min(round(_FADE_S * rate), n // 2)
    ramp = 0.5 - 0.5 * np.cos(np.pi * (np.arange(m) + 0.5) / m)
    x[:m] *= ramp
    x[n - m :] *= ramp[::-1]
    return x


def write_wav_int16(path: str | os.PathLike[str], samples: ArrayLike, rate: int) -> None:
    """Write samples in [-1, 1] as a 16-bit PCM WAV (values outside are clipped).

    Args:
        path: file to write (its directory must exist).
        samples: shaped ``(frames,)`` or ``(frames, channels)``.
        rate: sample rate, Hz.
    """
    rate = _check_rate(rate)
    x = _float_samples(samples, "samples")
    if x.ndim not in (1, 2):
        raise AudioError(f"samples must be shaped (frames,) or (frames, channels), got {x.shape}")
    data = np.round(np.clip(x, -1.0, 1.0) * 32767.0).astype(np.int16)
    try:
        wavfile.write(path, rate, data)
    except OSError as exc:
        raise AudioError(f"cannot write {path}: {exc.strerror or exc}") from exc

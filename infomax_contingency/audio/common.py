"""What every audio module shares: the error type, the processing rate and argument checks.

Conventions (all audio modules):
    * Samples are float64 in [-1, 1] (full scale = 1). Multi-channel arrays are shaped
      ``(frames, channels)``; mono arrays are 1-D.
    * Sample rates are positive integers in Hz; durations are in seconds.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.limits import finite, short_repr

PROCESSING_RATE_HZ = 16000
"""Sample rate (Hz) at which audio is windowed and measured."""


class AudioError(ValueError):
    """A user-facing audio problem: unreadable file, bad samples, unusable calibration."""


def check_rate(rate: int, name: str = "rate") -> int:
    """Return ``rate`` as an int, or raise AudioError unless it is a positive integer (Hz)."""
    if isinstance(rate, bool) or not isinstance(rate, int | float | np.integer | np.floating):
        raise AudioError(f"{name} must be a positive integer in Hz, got {rate!r}")
    if not finite(rate) or rate <= 0 or int(rate) != rate:
        raise AudioError(f"{name} must be a positive integer in Hz, got {short_repr(rate)}")
    return int(rate)


def check_positive_seconds(value: float, name: str) -> float:
    """Return ``value`` as a float, or raise AudioError unless it is finite and > 0 (s)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise AudioError(f"{name} must be a positive number of seconds, got {value!r}")
    if not finite(value) or value <= 0:
        raise AudioError(f"{name} must be a positive number of seconds, got {short_repr(value)}")
    return float(value)


def check_positive(value: float, name: str) -> float:
    """Return ``value`` as a float, or raise AudioError unless it is a finite number > 0."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise AudioError(f"{name} must be a positive number, got {value!r}")
    if not finite(value):
        raise AudioError(f"{name} must be finite, got {short_repr(value)}")
    return float(value)


MAX_SAMPLE_MAGNITUDE = 1e100
"""Float samples beyond this are refused: far past any unscaled audio (a float wav written
with int16 values reaches 32768), and an energy would overflow."""


def float_samples(samples: ArrayLike, name: str) -> NDArray[np.float64]:
    """Return finite float64 samples, or raise AudioError (integer PCM arrays are refused)."""
    if isinstance(samples, np.ndarray) and samples.dtype.kind in "iu":
        raise AudioError(
            f"{name} are {samples.dtype} integers; scale them to floats in [-1, 1] first "
            "(e.g. divide int16 by 32768), or read files with read_wav()"
        )
    x = np.asarray(samples, dtype=np.float64)
    if not np.isfinite(x).all():
        raise AudioError(f"{name} contain NaN or infinite values")
    if x.size and (peak := float(np.abs(x).max())) > MAX_SAMPLE_MAGNITUDE:
        raise AudioError(f"{name}: a sample of {peak:.3g} is not audio (samples belong in"
                         " [-1, 1]; this is far beyond any scaling of them)")  # fmt: skip
    return x


def as_mono(samples: ArrayLike, name: str = "samples") -> NDArray[np.float64]:
    """Return a 1-D finite float64 array, or raise AudioError saying what is wrong."""
    x = float_samples(samples, name)
    if x.ndim != 1:
        raise AudioError(
            f"{name} must be mono, shaped (n,); got shape {x.shape}. Mix down with to_mono()."
        )
    return x

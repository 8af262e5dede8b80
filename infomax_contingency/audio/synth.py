"""Synthesized sounds: the robot's default vocalization (a chirp)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from infomax_contingency.audio.common import AudioError, check_positive_seconds, check_rate

_FADE_S = 0.01
"""Fade-in / fade-out length of the synthesized chirp, seconds."""


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
    rate = check_rate(rate)
    n = round(check_positive_seconds(duration_s, "duration_s") * rate)
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

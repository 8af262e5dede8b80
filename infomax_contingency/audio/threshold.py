"""The sound threshold's mathematics: exact two-cluster k-means, the bit rule, the noise floor.

The threshold theta is the boundary (halfway between the means) of an exact two-cluster
k-means of calibration window energies (dB); the bit of a window is ``energy > theta``
(:func:`bits_from_energies`, the one bit rule). A calibration whose cluster means lie
closer than a least separation cannot tell sound from quiet (:func:`require_separation`).
:class:`NoiseFloorTracker` follows the noise floor (a low percentile of recent levels).
No I/O: threshold files are :mod:`infomax_contingency.audio.threshold_file`; the rules that
use this to give bits are :mod:`infomax_contingency.audio.bitsources`.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections import deque
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.common import AudioError

THRESHOLD_MIN_DB, THRESHOLD_MAX_DB = -150.0, 0.0
"""The thresholds allowed, dB (0 dB: a full-scale window of samples in [-1, 1]); one range
for mic_node's ``threshold_db`` parameter, threshold files and the offline tools
(:func:`check_threshold_db`)."""

DEFAULT_MIN_SEPARATION_DB = 10.0
"""Least distance between the two cluster means (dB) for a calibration to be used."""

_TIE_RTOL = 1e-9
"""k-means splits whose squared error differs by less than this fraction of the total
sum of squares count as tied (the lowest one wins)."""


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

    @property
    def separation_db(self) -> float:
        """Distance between the two cluster means, dB (``high_mean_db - low_mean_db``)."""
        return self.high_mean_db - self.low_mean_db


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
    """The bit rule, elementwise: ``y = energy > threshold`` (strict).

    This is the one place the rule lives (the threshold rules of
    :mod:`infomax_contingency.audio.bitsources.rules` call it for every window). Tie
    convention: an energy exactly equal to the threshold is quiet (``y = 0``).

    Args:
        energies_db: window energies, dB (scalar or any shape).
        threshold_db: theta, dB (finite).

    Returns:
        Booleans shaped like ``energies_db`` (a 0-d array for a scalar).
    """
    if not math.isfinite(threshold_db):
        raise AudioError(f"threshold_db must be finite, got {threshold_db!r}")
    return np.asarray(energies_db, dtype=np.float64) > threshold_db


def calibration_window_count(calibration_s: float, window_s: float) -> int:
    """Windows in ``calibration_s`` seconds of audio.

    That is ``round(calibration_s / window_s)``, at least 2 (k-means needs two values).
    """
    if not calibration_s > 0 or not window_s > 0:
        raise AudioError(
            f"calibration_s and window_s must be > 0 seconds, got {calibration_s} and {window_s}"
        )
    return max(2, round(calibration_s / window_s))


class UnseparatedError(AudioError):
    """A calibration whose two cluster means lie closer than the least separation.

    Attributes:
        fit: the refused fit.
        separation_db: distance between its cluster means, dB.
        min_separation_db: the least distance required, dB.
    """

    def __init__(self, fit: ThresholdFit, min_separation_db: float) -> None:
        self.fit = fit
        self.separation_db = fit.separation_db
        self.min_separation_db = min_separation_db
        super().__init__(
            f"calibration cannot separate sound from quiet: the two clusters lie only"
            f" {fit.separation_db:.1f} dB apart (quiet {fit.low_mean_db:.1f} dB, sound"
            f" {fit.high_mean_db:.1f} dB; at least {min_separation_db:g} dB needed);"
            " the audio may lack quiet or sound"
        )


def require_separation(fit: ThresholdFit, min_separation_db: float) -> ThresholdFit:
    """Return ``fit`` if its cluster means lie at least ``min_separation_db`` apart.

    Its threshold must also lie in the range of thresholds allowed (a threshold file's or
    the ``threshold_db`` parameter's), so that a calibration in mic_node or ``replay``
    never uses a threshold the node would refuse from a file.

    Raises:
        AudioError: the threshold lies outside ``THRESHOLD_MIN_DB .. THRESHOLD_MAX_DB``
            (above 0 dB: windows louder than full scale, float audio stored unscaled).
        UnseparatedError: the means lie closer (the message names the gap in dB).
    """
    if not THRESHOLD_MIN_DB <= fit.threshold_db <= THRESHOLD_MAX_DB:
        raise AudioError(
            f"calibration refused: its threshold {fit.threshold_db:.2f} dB (quiet"
            f" {fit.low_mean_db:.1f} dB, sound {fit.high_mean_db:.1f} dB) lies outside"
            f" {THRESHOLD_MIN_DB:g} .. {THRESHOLD_MAX_DB:g} dB; windows louder than 0 dB hold"
            " samples outside [-1, 1]: scale the audio to [-1, 1] (float samples stored"
            " unscaled?)"
        )
    if not fit.separation_db >= min_separation_db:
        raise UnseparatedError(fit, min_separation_db)
    return fit


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


# --------------------------------------------------------------------------- noise floor


class NoiseFloorTracker:
    """A slow estimate of the noise floor: a low percentile of the last window levels.

    The floor is the ``percentile``-th percentile (lower nearest rank: the
    ``floor(percentile / 100 * (n - 1))``-th smallest, from 0) of the last ``capacity``
    window levels (dB); ``percentile = 0`` is the minimum (minimum statistics). Sounds
    shorter than a ``1 - percentile / 100`` share of the buffer do not move it, so a
    partner's replies stay above it while a slowly louder room raises it.

    Args:
        capacity: number of most recent windows kept (at least 1).
        percentile: 0 .. 50.
    """

    def __init__(self, capacity: int, percentile: float) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise AudioError(f"noise-floor capacity must be an integer >= 1, got {capacity!r}")
        if isinstance(percentile, bool) or not isinstance(percentile, int | float):
            raise AudioError(f"noise_percentile must be a number in [0, 50], got {percentile!r}")
        if not 0.0 <= percentile <= 50.0:
            raise AudioError(f"noise_percentile must be in [0, 50], got {percentile!r}")
        self.capacity = capacity
        self.percentile = float(percentile)
        self._order: deque[float] = deque()  # levels in arrival order
        self._sorted: list[float] = []  # the same levels, sorted

    def __len__(self) -> int:
        return len(self._order)

    def add(self, level_db: float) -> None:
        """Append one window level (dB), dropping the oldest when full."""
        if not math.isfinite(level_db):
            raise AudioError(f"window level must be finite, got {level_db!r}")
        level = float(level_db)
        if len(self._order) == self.capacity:
            oldest = self._order.popleft()
            del self._sorted[bisect.bisect_left(self._sorted, oldest)]
        self._order.append(level)
        bisect.insort(self._sorted, level)

    @property
    def floor_db(self) -> float | None:
        """The current floor estimate, dB; None before the first window."""
        if not self._sorted:
            return None
        rank = math.floor(self.percentile / 100.0 * (len(self._sorted) - 1))
        return self._sorted[rank]


def threshold_range_problem(value: float, what: str) -> str:
    """"" if ``value`` (dB) lies in ``THRESHOLD_MIN_DB .. THRESHOLD_MAX_DB``, else why not.

    ``what`` names the value in the one-line message (``"threshold file x.yaml"``).
    """
    if THRESHOLD_MIN_DB <= value <= THRESHOLD_MAX_DB:
        return ""
    return (f"{what}: threshold_db {value:g} dB is not allowed: {THRESHOLD_MIN_DB:g} .."
            f" {THRESHOLD_MAX_DB:g} dB (0 dB is a full-scale window of samples in [-1, 1])")


def check_threshold_db(value: float, what: str) -> float:
    """``value`` if it lies in ``THRESHOLD_MIN_DB .. THRESHOLD_MAX_DB``, else AudioError.

    ``what`` names the value in the one-line message (``"threshold file x.yaml"``).
    """
    if problem := threshold_range_problem(value, what):
        raise AudioError(problem)
    return float(value)


class ThresholdRangeGuard:
    """Holds a threshold a rule computes itself to the range of the ``threshold_db`` parameter.

    A noise floor plus its margin, or the background's k-th loudest level, lies above
    0 dB when the audio is not scaled to [-1, 1] (float samples stored unscaled): every
    bit would be 0, which says "quiet" about a room nobody measured. A window whose
    threshold lies outside :data:`THRESHOLD_MIN_DB` .. :data:`THRESHOLD_MAX_DB` gets no
    bit instead (as a threshold file outside the range is refused), is counted, and
    :attr:`problem` says why until a threshold is in range again; ``on_problem`` is
    called with it once each time the threshold leaves the range.

    Args:
        origin: what computes the threshold, for the message (``"noise-floor threshold"``).
        on_problem: called with :attr:`problem` when the threshold leaves the range.
    """

    def __init__(self, origin: str, on_problem: Callable[[str], None] | None = None) -> None:
        self.origin = origin
        self.on_problem = on_problem
        self.windows_out_of_range = 0
        """Windows that got no bit because their threshold lay outside the range."""
        self.problem = ""
        """Why windows get no bit now ("" while the threshold lies in the range)."""

    def allows(self, threshold_db: float) -> bool:
        """True if a bit may be decided on ``threshold_db``; else count the window."""
        problem = threshold_range_problem(threshold_db, self.origin)
        if not problem:
            self.problem = ""
            return True
        self.windows_out_of_range += 1
        if not self.problem:
            self.problem = (f"{problem}; its windows give no bit until it is back in range"
                            " (audio not scaled to [-1, 1]?)")  # fmt: skip
            if self.on_problem is not None:
                self.on_problem(self.problem)
        return False

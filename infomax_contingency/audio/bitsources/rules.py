"""Threshold rules: a window level (dB) to a bit with a threshold that is kept up to date.

* :class:`Binarizer` — ``y = level > threshold`` with a threshold that is given, or
  calibrated by k-means on the first windows, optionally refreshed online on a rolling
  buffer. A calibration whose clusters lie closer than ``min_separation_db`` is refused
  (:attr:`Binarizer.state` ``"unseparated"``).
* :class:`NoiseFloorBinarizer` — a margin above a tracked noise floor.

The mathematics (k-means, the bit rule, the floor tracker) is
:mod:`infomax_contingency.audio.threshold`; the bit sources that use these rules are
:mod:`infomax_contingency.audio.bitsources.level`. Levels are in dB.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence

import numpy as np

from infomax_contingency.audio.bitsources.base import (
    CALIBRATING,
    OUT_OF_RANGE,
    READY,
    UNSEPARATED,
)
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.threshold import (
    DEFAULT_MIN_SEPARATION_DB,
    NoiseFloorTracker,
    OnlineThreshold,
    ThresholdFit,
    ThresholdRangeGuard,
    UnseparatedError,
    bits_from_energies,
    kmeans_split,
    require_separation,
)


class Binarizer:
    """Window energy to bit, ``y = energy > threshold`` (strict), with calibration and refresh.

    Three ways to get the threshold: give it (``threshold_db``), or let the first
    ``calibration_windows`` energies pushed be the calibration audio: those windows
    yield no bit (``push`` returns None) and, once they are all in, the threshold is
    their two-cluster k-means boundary.

    A calibration is refused when its windows cannot separate sound from quiet: all
    energies equal (e.g. digital silence), or the two cluster means lie closer than
    ``min_separation_db``. Then :attr:`state` is ``"unseparated"``,
    :attr:`calibration_problem` says why (naming the gap in dB), :attr:`rejected_fit`
    holds the refused fit, :attr:`calibration_failures` counts up,
    ``on_calibration_refused(message)`` is called, no bit comes from it, and
    calibration starts again on the next ``calibration_windows`` windows. A node shows
    this as an ERROR diagnostic while :attr:`state` is ``"unseparated"`` (message
    :attr:`calibration_problem`) and logs ``on_calibration_refused``'s message as a
    warning.

    With ``refresh_windows > 0`` every energy also goes into a rolling buffer of that
    many windows; once the buffer is full the threshold is refitted after every window
    and the new fit is accepted only if its two cluster means lie at least
    ``min_separation_db`` apart (a buffer of pure silence still "splits", into two
    clusters of noise, and must not move the threshold). Each window's bit uses the
    threshold in force before that window was added.

    Args:
        threshold_db: a fixed threshold, dB; None to calibrate.
        calibration_windows: windows of calibration audio (>= 2; used when
            ``threshold_db`` is None).
        refresh_windows: rolling-buffer length for the online refresh (0 = off, else >= 2).
        min_separation_db: least distance between cluster means to accept a calibration
            or a refit, dB.
        on_calibration_refused: called with :attr:`calibration_problem` (one line naming
            the gap in dB) whenever a calibration is refused; None: not called.
    """

    def __init__(
        self,
        threshold_db: float | None = None,
        calibration_windows: int = 20,
        refresh_windows: int = 0,
        min_separation_db: float = DEFAULT_MIN_SEPARATION_DB,
        on_calibration_refused: Callable[[str], None] | None = None,
    ) -> None:
        if threshold_db is not None and not math.isfinite(threshold_db):
            raise AudioError(f"threshold_db must be finite, got {threshold_db!r}")
        if threshold_db is None and calibration_windows < 2:
            raise AudioError(f"calibration needs at least 2 windows, got {calibration_windows}")
        if refresh_windows != 0 and refresh_windows < 2:
            raise AudioError(f"refresh_windows must be 0 (off) or >= 2, got {refresh_windows}")
        if not min_separation_db >= 0:
            raise AudioError(f"min_separation_db must be >= 0 dB, got {min_separation_db}")
        self.threshold_db = None if threshold_db is None else float(threshold_db)
        self.fit: ThresholdFit | None = None
        """The k-means fit behind the current threshold (None for a given threshold)."""
        self.calibration_windows = calibration_windows
        self.min_separation_db = min_separation_db
        self._calibration: list[float] = []
        self.refresh_windows = refresh_windows
        self._online = OnlineThreshold(refresh_windows) if refresh_windows else None
        self.refits_accepted = 0
        self.refits_rejected = 0
        self.calibration_failures = 0
        """Calibrations refused so far."""
        self.calibration_problem = ""
        """Why the last calibration was refused ("" once one succeeds, or before any)."""
        self.rejected_fit: ThresholdFit | None = None
        """The last refused fit (None if it had no boundary at all, or none was refused)."""
        self._on_refused = on_calibration_refused

    @property
    def calibrating(self) -> bool:
        """True until a threshold exists."""
        return self.threshold_db is None

    @property
    def state(self) -> str:
        """``"ready"``, ``"calibrating"`` or ``"unseparated"`` (see the class docstring)."""
        if self.threshold_db is not None:
            return READY
        return UNSEPARATED if self.calibration_problem else CALIBRATING

    def calibrate(self, energies_db: Sequence[float] | np.ndarray) -> ThresholdFit:
        """Set the threshold from calibration energies read ahead (e.g. a file's start).

        Raises:
            UnseparatedError: the two cluster means lie closer than ``min_separation_db``
                (the threshold is not set; :attr:`state` turns ``"unseparated"``).
            AudioError: the energies have no boundary (see
                :func:`~infomax_contingency.audio.threshold.kmeans_split`).
        """
        return self._fit_calibration(np.array(energies_db, dtype=np.float64), retry=False)

    def _fit_calibration(self, energies: np.ndarray, retry: bool) -> ThresholdFit:
        """Set the threshold from ``energies``, or record the refusal and raise it."""
        self._calibration.clear()
        try:
            fit = require_separation(kmeans_split(energies), self.min_separation_db)
        except AudioError as exc:
            self._refuse(exc, retry)
            raise
        self.fit, self.threshold_db = fit, fit.threshold_db
        self.calibration_problem = ""
        return fit

    def push(self, energy_db: float) -> bool | None:
        """The bit of one window; None while the window is calibration audio."""
        if not math.isfinite(energy_db):
            raise AudioError(f"window energy must be finite, got {energy_db!r}")
        if self.threshold_db is None:
            self._calibration.append(float(energy_db))
            if len(self._calibration) >= self.calibration_windows:
                energies = np.array(self._calibration)
                with contextlib.suppress(AudioError):  # recorded; retried on the next windows
                    self._fit_calibration(energies, retry=True)
            if self._online is not None:
                self._online.add(energy_db)
            return None
        bit = bool(bits_from_energies(energy_db, self.threshold_db))
        if self._online is not None:
            self._online.add(energy_db)
            if len(self._online) == self.refresh_windows:
                self._refit()
        return bit

    def _refuse(self, exc: AudioError, retry: bool) -> None:
        """Record a refused calibration, say why, and report it."""
        self.calibration_failures += 1
        self.rejected_fit = exc.fit if isinstance(exc, UnseparatedError) else None
        self.calibration_problem = str(exc)
        if retry:
            self.calibration_problem += (
                f"; calibrating again on the next {self.calibration_windows} windows"
            )
        if self._on_refused is not None:
            self._on_refused(self.calibration_problem)

    def _refit(self) -> None:
        """Refit on the rolling buffer; keep the new threshold only if it separates."""
        try:
            fit = require_separation(self._online.refit(), self.min_separation_db)
        except AudioError:
            self.refits_rejected += 1
            return
        self.fit, self.threshold_db = fit, fit.threshold_db
        self.refits_accepted += 1


class NoiseFloorBinarizer:
    """Window level to bit against a tracked noise floor: ``y = level > floor + margin``.

    The floor is a :class:`~infomax_contingency.audio.threshold.NoiseFloorTracker` (a low
    percentile of the last ``floor_windows`` levels); the threshold is the floor plus
    ``margin_db``, and each window's bit uses the threshold in force before the window
    was added (the strict rule of
    :func:`~infomax_contingency.audio.threshold.bits_from_energies`). The first
    ``warmup_windows`` levels only start the floor: they yield no bit (``push`` returns
    None, :attr:`state` ``"calibrating"``), as a calibration does.

    It has the attributes of :class:`Binarizer` that a node reports (``threshold_db``,
    ``state``, ``calibrating``, ``calibration_problem``, the refit and failure counts,
    which stay 0); ``fit`` is always None.

    Args:
        margin_db: threshold above the floor, dB (>= 0).
        floor_windows: windows the floor is taken over (>= 1).
        percentile: the floor's percentile, 0 (minimum) .. 50.
        warmup_windows: windows that only start the floor (>= 1).
        on_problem: called with :attr:`calibration_problem` when the threshold leaves the
            ``threshold_db`` parameter's range (its windows then give no bit).
    """

    def __init__(
        self,
        margin_db: float,
        floor_windows: int,
        percentile: float,
        warmup_windows: int,
        on_problem: Callable[[str], None] | None = None,
    ) -> None:
        if (
            isinstance(margin_db, bool)
            or not isinstance(margin_db, int | float)
            or not (math.isfinite(margin_db) and margin_db >= 0)
        ):
            raise AudioError(f"noise_margin_db must be a finite number >= 0 dB, got {margin_db!r}")
        if (
            isinstance(warmup_windows, bool)
            or not isinstance(warmup_windows, int)
            or warmup_windows < 1
        ):
            raise AudioError(f"warm-up must be a whole number >= 1, got {warmup_windows!r}")
        self.margin_db = float(margin_db)
        self.warmup_windows = warmup_windows
        self.tracker = NoiseFloorTracker(floor_windows, percentile)
        self.range_guard = ThresholdRangeGuard("noise-floor threshold", on_problem)
        self.fit: ThresholdFit | None = None
        self.refits_accepted = 0
        self.refits_rejected = 0
        self.calibration_failures = 0

    @property
    def floor_db(self) -> float | None:
        """The noise floor now, dB; None before the first window."""
        return self.tracker.floor_db

    @property
    def threshold_db(self) -> float | None:
        """Floor plus margin, dB: the next window's threshold; None while warming up."""
        floor = self.tracker.floor_db
        return None if self.calibrating or floor is None else floor + self.margin_db

    @property
    def calibrating(self) -> bool:
        """True while the first ``warmup_windows`` levels come in."""
        return len(self.tracker) < self.warmup_windows

    @property
    def state(self) -> str:
        """``"calibrating"`` (warm-up), ``"out_of_range"`` (no bits: range_guard), ``"ready"``."""
        if self.range_guard.problem:
            return OUT_OF_RANGE
        return CALIBRATING if len(self.tracker) < self.warmup_windows else READY

    @property
    def calibration_problem(self) -> str:
        """Why windows give no bit now ("" if they do, or while warming up)."""
        return self.range_guard.problem

    @property
    def windows_out_of_range(self) -> int:
        """Windows that got no bit: their threshold lay outside the parameter's range."""
        return self.range_guard.windows_out_of_range

    def push(self, level_db: float) -> bool | None:
        """The bit of one window; None during the warm-up and while out of range."""
        if not math.isfinite(level_db):
            raise AudioError(f"window level must be finite, got {level_db!r}")
        threshold = self.threshold_db
        self.tracker.add(level_db)
        if threshold is None or not self.range_guard.allows(threshold):
            return None
        return bool(bits_from_energies(level_db, threshold))

"""The microphone's side of the step clock: where windows come from and how they become bits.

* :class:`WavReplay` — a WAV file (any PCM/float format, rate and channel count) read
  with :func:`~infomax_contingency.audio.signal.load_mono`, resampled to the processing rate
  and cut into windows by :func:`~infomax_contingency.audio.signal.window_energies_db`, so a
  replay yields exactly the energies of the offline computation on the same file.
* :class:`Binarizer` — window energy to bit with a threshold that is fixed, loaded from
  a threshold file, or calibrated by k-means on the first windows, optionally refreshed
  online on a rolling buffer.

Energies are in dB (see :mod:`infomax_contingency.audio.signal`); durations in seconds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from infomax_contingency.audio.signal import (
    PROCESSING_RATE_HZ,
    AudioError,
    OnlineThreshold,
    ThresholdFit,
    kmeans_split,
    load_mono,
    window_energies_db,
)


def calibration_window_count(calibration_s: float, window_s: float) -> int:
    """Windows in ``calibration_s`` seconds of audio.

    That is ``round(calibration_s / window_s)``, at least 2 (k-means needs two values).
    """
    if not calibration_s > 0 or not window_s > 0:
        raise AudioError(
            f"calibration_s and window_s must be > 0 seconds, got {calibration_s} and {window_s}"
        )
    return max(2, round(calibration_s / window_s))


class WavReplay:
    """The window energies of a WAV file, served one at a time, optionally looping.

    Args:
        path: the WAV file.
        window_s: window length, seconds.
        channel: ``None`` to mix all channels, or the 0-based channel to use.
        loop: start again from the first window after the last one.
        rate: processing rate the file is resampled to, Hz.

    Raises:
        AudioError: the file cannot be read, or holds less than one window.
    """

    def __init__(
        self,
        path: str | Path,
        window_s: float,
        channel: int | None = None,
        loop: bool = False,
        rate: int = PROCESSING_RATE_HZ,
    ) -> None:
        self.path = Path(path)
        self.loop = loop
        samples = load_mono(self.path, rate=rate, channel=channel)
        self.energies_db = window_energies_db(samples, rate, window_s)
        if self.energies_db.size == 0:
            raise AudioError(
                f"{self.path} lasts {samples.size / rate:.3f} s, shorter than one window"
                f" ({window_s} s)"
            )
        self.position = 0
        """Windows served so far (counting every loop)."""

    @property
    def n_windows(self) -> int:
        """Complete windows in the file (a trailing partial window is dropped)."""
        return int(self.energies_db.size)

    @property
    def finished(self) -> bool:
        """True once every window was served (never, when looping)."""
        return not self.loop and self.position >= self.n_windows

    def next_energy(self) -> float | None:
        """Energy (dB) of the next window, or None at the end of a non-looping file."""
        if self.finished:
            return None
        energy = float(self.energies_db[self.position % self.n_windows])
        self.position += 1
        return energy

    def calibration_energies(self, calibration_s: float, window_s: float) -> np.ndarray:
        """Energies of the first ``calibration_s`` seconds (the whole file if shorter)."""
        return self.energies_db[: calibration_window_count(calibration_s, window_s)]


class Binarizer:
    """Window energy to bit, ``y = energy > threshold`` (strict), with calibration and refresh.

    Three ways to get the threshold: give it (``threshold_db``), or let the first
    ``calibration_windows`` energies pushed be the calibration audio: those windows
    yield no bit (``push`` returns None) and, once they are all in, the threshold is
    their two-cluster k-means boundary. If they have no boundary (all equal, e.g.
    digital silence), calibration starts again on the next windows.

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
        min_separation_db: least distance between cluster means to accept a refit, dB.
    """

    def __init__(
        self,
        threshold_db: float | None = None,
        calibration_windows: int = 20,
        refresh_windows: int = 0,
        min_separation_db: float = 10.0,
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

    @property
    def calibrating(self) -> bool:
        """True until a threshold exists."""
        return self.threshold_db is None

    def calibrate(self, energies_db: Sequence[float] | np.ndarray) -> ThresholdFit:
        """Set the threshold from calibration energies read ahead (e.g. a file's start).

        Raises:
            AudioError: the energies have no boundary (see
                :func:`~infomax_contingency.audio.signal.kmeans_split`).
        """
        fit = kmeans_split(energies_db)
        self.fit, self.threshold_db = fit, fit.threshold_db
        self._calibration.clear()
        return fit

    def push(self, energy_db: float) -> bool | None:
        """The bit of one window; None while the window is calibration audio."""
        if not math.isfinite(energy_db):
            raise AudioError(f"window energy must be finite, got {energy_db!r}")
        if self.threshold_db is None:
            self._calibration.append(float(energy_db))
            if len(self._calibration) >= self.calibration_windows:
                try:
                    self.calibrate(self._calibration)
                except AudioError:
                    self.calibration_failures += 1
                    self._calibration.clear()
            if self._online is not None:
                self._online.add(energy_db)
            return None
        bit = bool(energy_db > self.threshold_db)
        if self._online is not None:
            self._online.add(energy_db)
            if len(self._online) == self.refresh_windows:
                self._refit()
        return bit

    def _refit(self) -> None:
        try:
            fit = self._online.refit()
        except AudioError:
            self.refits_rejected += 1
            return
        if fit.high_mean_db - fit.low_mean_db >= self.min_separation_db:
            self.fit, self.threshold_db = fit, fit.threshold_db
            self.refits_accepted += 1
        else:
            self.refits_rejected += 1

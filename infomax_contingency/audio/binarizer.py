"""The microphone's side of the step clock: where windows come from and how they become bits.

* :class:`WavReplay` — the window energies of a WAV file (any PCM/float format, rate and
  channel count), read block by block through
  :func:`~infomax_contingency.audio.energy.iter_wav_energies` (constant memory whatever
  the file length), so a replay yields exactly the energies of the offline computation.
* :class:`Binarizer` — window energy to bit with a threshold that is fixed, loaded from
  a threshold file, or calibrated by k-means on the first windows, optionally refreshed
  online on a rolling buffer. A calibration whose clusters lie closer than
  ``min_separation_db`` is refused (:attr:`Binarizer.state` ``"unseparated"``).

Energies are in dB (see :mod:`infomax_contingency.audio.energy`); durations in seconds.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np

from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError
from infomax_contingency.audio.energy import iter_wav_energies, wav_energies, wav_window_count
from infomax_contingency.audio.threshold import (
    DEFAULT_MIN_SEPARATION_DB,
    OnlineThreshold,
    ThresholdFit,
    UnseparatedError,
    bits_from_energies,
    kmeans_split,
    require_separation,
)
from infomax_contingency.audio.wav import WavReader, to_mono

CALIBRATING = "calibrating"
"""Binarizer state: collecting calibration windows, no threshold yet."""
UNSEPARATED = "unseparated"
"""Binarizer state: the last calibration could not separate sound from quiet; collecting
the next calibration windows (no bits until one succeeds)."""
READY = "ready"
"""Binarizer state: a threshold is in force; every window gets a bit."""


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

    The file is read block by block as windows are served (and read again from the
    start when looping), so memory does not depend on its length.

    Args:
        path: the WAV file.
        window_s: window length, seconds.
        channel: ``None`` to mix all channels, or the 0-based channel to use.
        loop: start again from the first window after the last one.
        rate: processing rate the file is resampled to, Hz.

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
    ) -> None:
        self.path = Path(path)
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
        if self.finished:
            return None
        if self.position % self.n_windows == 0:
            self._blocks = iter_wav_energies(self.path, self.window_s, self.channel, self.rate)
            self._block, self._in_block = np.empty(0), 0
        while self._in_block >= self._block.size:
            block = next(self._blocks, None)
            if block is None:
                raise AudioError(
                    f"{self.path} ended after {self.position % self.n_windows} of its"
                    f" {self.n_windows} windows: the file changed while it was replayed"
                )
            self._block, self._in_block = block, 0
        energy = float(self._block[self._in_block])
        self._in_block += 1
        self.position += 1
        return energy

    def calibration_energies(self, calibration_s: float, window_s: float) -> np.ndarray:
        """Energies of the first ``calibration_s`` seconds (the whole file if shorter).

        Reads only the start of the file (block by block), whatever its length.
        """
        count = calibration_window_count(calibration_s, window_s)
        return wav_energies(self.path, self.window_s, self.channel, self.rate, max_windows=count)


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

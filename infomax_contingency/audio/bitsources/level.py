"""Bit sources that compare a window level (dB) with a threshold: ``energy``, ``speech_band``.

* ``energy`` — the paper's rule: the window's full-band energy against the threshold.
* ``speech_band`` — the energy of the 300-3400 Hz band only (a 4th-order Butterworth
  band-pass, :func:`scipy.signal.sosfilt`, its state carried from window to window).

How the threshold is set (``threshold_mode``, :data:`THRESHOLD_MODES`): ``fixed``
(``threshold_db``), ``file`` (a threshold file of the source's level), ``calibrate``
(k-means of the first ``calibration_s`` seconds, optionally refreshed online:
:class:`~infomax_contingency.audio.bitsources.rules.Binarizer`) or ``noise_floor``
(``noise_margin_db`` above a tracked floor:
:class:`~infomax_contingency.audio.bitsources.rules.NoiseFloorBinarizer`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.bitsources.base import (
    BitSource,
    NameArgument,
    SettingError,
    setting,
    window_energy_db,
)
from infomax_contingency.audio.bitsources.rules import Binarizer, NoiseFloorBinarizer
from infomax_contingency.audio.common import AudioError, as_mono, check_rate
from infomax_contingency.audio.energy import frame_energies_db
from infomax_contingency.audio.threshold import (
    DEFAULT_MIN_SEPARATION_DB,
    THRESHOLD_MAX_DB,
    THRESHOLD_MIN_DB,
    calibration_window_count,
)
from infomax_contingency.audio.threshold_file import load_threshold

THRESHOLD_MODES = ("calibrate", "fixed", "file", "noise_floor")
"""How ``energy`` and ``speech_band`` set their threshold."""

SPEECH_BAND_HZ = (300.0, 3400.0)
"""The speech band of ``speech_band``: lower and upper edge, Hz (telephone band)."""

SPEECH_BAND_ORDER = 4
"""Butterworth order of each edge of the speech-band filter."""


@dataclasses.dataclass(frozen=True)
class ThresholdSettings:
    """Settings of the threshold sources (mic_node parameters of the same names)."""

    threshold_mode: str = setting(
        "calibrate",
        "How the sound threshold is set: calibrate (k-means of the first calibration_s),"
        " fixed (threshold_db), file (threshold_file), noise_floor (noise_margin_db above"
        " the noise floor); ~/recalibrate starts it again",
        choices=THRESHOLD_MODES,
    )
    threshold_db: float = setting(
        -40.0, "Fixed threshold (threshold_mode fixed; live)", low=THRESHOLD_MIN_DB,
        high=THRESHOLD_MAX_DB, unit="dB",
        live=True,
    )
    threshold_file: str = setting(
        "", "Threshold file written by calibration (threshold_mode file; ~/recalibrate reads"
        " it again)",
    )
    calibration_s: float = setting(
        10.0, "Calibration audio (threshold_mode calibrate; the noise floor's warm-up)",
        low=0.02, high=3600.0, unit="s",
    )
    refresh_s: float = setting(
        0.0, "Online threshold refresh buffer; 0 = off", low=0.0, high=86400.0, unit="s"
    )
    min_separation_db: float = setting(
        DEFAULT_MIN_SEPARATION_DB,
        "Least gap between cluster means to accept a calibration or a refit",
        low=0.0, high=100.0, unit="dB",
    )
    noise_margin_db: float = setting(
        10.0, "Threshold above the noise floor (threshold_mode noise_floor)",
        low=0.0, high=100.0, unit="dB",
    )
    noise_window_s: float = setting(
        30.0, "Recent audio the noise floor is taken over (threshold_mode noise_floor)",
        low=0.01, high=86400.0, unit="s",
    )
    noise_percentile: float = setting(
        10.0, "Percentile of recent levels that is the noise floor; 0 = the minimum"
        " (threshold_mode noise_floor)", low=0.0, high=50.0, unit="%",
    )


class SpeechBandLevel:
    """Energy (dB) of the speech band of consecutive windows; the filter state carries over.

    Args:
        rate_hz: sample rate, Hz (above twice the band's upper edge).
        band_hz: lower and upper edge, Hz.
    """

    def __init__(self, rate_hz: int, band_hz: tuple[float, float] = SPEECH_BAND_HZ) -> None:
        rate_hz = check_rate(rate_hz, "rate_hz")
        low, high = band_hz
        if not 0 < low < high:
            raise AudioError(f"speech band must have 0 < low < high Hz, got {low} .. {high}")
        if not high < rate_hz / 2:
            raise AudioError(
                f"speech band up to {high:g} Hz needs a sample rate above {2 * high:g} Hz,"
                f" got {rate_hz} Hz"
            )
        from scipy.signal import butter, sosfilt, sosfilt_zi  # lazy: ~1 s of CPU to load

        self._sosfilt = sosfilt
        self.rate_hz = rate_hz
        self.band_hz = (float(low), float(high))
        self._sos = butter(SPEECH_BAND_ORDER, self.band_hz, btype="bandpass", fs=rate_hz,
                           output="sos")  # fmt: skip
        self._steady_state = sosfilt_zi(self._sos)  # per unit of a constant input
        self._state: NDArray[np.float64] | None = None

    def level_db(self, x: NDArray[np.float64]) -> float:
        """Band energy of the next window (mono samples), dB.

        The filter starts as if the first window's mean had always been there (a DC offset
        gives no step into the first window); a window whose band energy is not finite (NaN
        or infinite samples) starts it again on the next window, so it spoils no other.
        """
        if x.size == 0:
            return window_energy_db(x)
        state = self._steady_state * float(np.mean(x)) if self._state is None else self._state
        y, self._state = self._sosfilt(self._sos, x, zi=state)
        level = window_energy_db(y)
        if not np.isfinite(level) or not np.all(np.isfinite(self._state)):
            self._state = None
        return level


ThresholdRule = Binarizer | NoiseFloorBinarizer
"""The rule a level source compares its level with."""

_MODES = {
    "calibrate": (NameArgument("calibration_s", "S"),),
    "fixed": (NameArgument("threshold_db", "DB", required=True),),
    "noise_floor": (NameArgument("noise_margin_db", "MARGIN_DB"),
                    NameArgument("calibration_s", "WARMUP_S")),  # fmt: skip
    "file": (NameArgument("threshold_file", "PATH", required=True),),
}


class LevelSource(BitSource):
    """A window level (dB) against a threshold rule; the level is :meth:`level_db`'s."""

    Settings = ThresholdSettings
    mode_setting = "threshold_mode"
    name_modes = _MODES

    def __init__(
        self,
        settings: ThresholdSettings,
        rate_hz: int,
        window_s: float,
        on_problem: Callable[[str], None] | None = None,
    ) -> None:
        super().__init__(settings, rate_hz, window_s, on_problem)
        self.rule: ThresholdRule = self._new_rule()
        self.last_level_db = float("nan")
        """The level the last bit was decided on (energy or band energy), dB."""

    @classmethod
    def check_settings(cls, settings: ThresholdSettings, rate_hz: int, window_s: float) -> None:
        """refresh_s of two windows at least, and not with noise_floor; a file needs a path."""
        refresh_s = settings.refresh_s
        if refresh_s > 0 and round(refresh_s / window_s) < 2:
            raise SettingError("refresh_s", f"= {refresh_s:g}: must be 0 (off) or at least two"
                               f" windows ({2 * window_s:g} s)")  # fmt: skip
        if settings.threshold_mode == "noise_floor" and refresh_s > 0:
            raise SettingError("refresh_s", f"= {refresh_s:g}: refits a k-means threshold;"
                               " threshold_mode noise_floor follows the noise floor by itself:"
                               " set it to 0")  # fmt: skip
        if settings.threshold_mode == "file" and not settings.threshold_file:
            raise SettingError("threshold_file", "is empty: threshold_mode 'file' needs the path"
                               " of a threshold file written by calibration")  # fmt: skip

    def _new_rule(self) -> ThresholdRule:
        """The rule that the settings ask for, from scratch (a file is read now)."""
        s, window_s = self.settings, self.window_s
        refresh = round(s.refresh_s / window_s) if s.refresh_s > 0 else 0
        if s.threshold_mode == "noise_floor":
            return NoiseFloorBinarizer(
                s.noise_margin_db,
                max(1, round(s.noise_window_s / window_s)),
                s.noise_percentile,
                calibration_window_count(s.calibration_s, window_s),
                self.on_problem,
            )
        if s.threshold_mode == "calibrate":
            windows = calibration_window_count(s.calibration_s, window_s)
            return Binarizer(None, windows, refresh, s.min_separation_db, self.on_problem)
        threshold = s.threshold_db
        if s.threshold_mode == "file":
            threshold = load_threshold(s.threshold_file, self.name)
        return Binarizer(threshold, 0, refresh, s.min_separation_db, self.on_problem)

    def level_db(self, x: NDArray[np.float64]) -> float:
        """The level of a window the threshold applies to, dB (the energy here)."""
        return self.last_energy_db

    @classmethod
    def window_levels(cls, rate_hz: int) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
        """A level meter for windows in order (rows; a fresh filter), for calibration audio."""
        return frame_energies_db

    def decide(self, x: NDArray[np.float64]) -> bool | None:
        self.last_level_db = self.level_db(x)
        return self.rule.push(self.last_level_db)

    # ------------------------------------------------------------------ state

    @property
    def state(self) -> str:
        return self.rule.state

    @property
    def problem(self) -> str:
        return self.rule.calibration_problem

    @property
    def threshold_db(self) -> float | None:
        return self.rule.threshold_db

    @property
    def read_ahead_s(self) -> float:
        """``calibration_s`` in threshold_mode calibrate, else 0."""
        return self.settings.calibration_s if self.settings.threshold_mode == "calibrate" else 0.0

    def calibrate_ahead(self, energies_db: ArrayLike, windows: NDArray[np.float64] | None) -> str:
        """Set the k-means threshold from windows read ahead: their energies (dB) and samples.

        The speech band's levels are taken with a filter from rest, as the same windows
        get when they are pushed.
        """
        if not isinstance(self.rule, Binarizer):
            raise AudioError("only threshold_mode calibrate is calibrated ahead")
        if self.needs_samples:
            levels = levels_db(self.window_levels(self.rate_hz), windows)
        else:
            levels = np.asarray(energies_db, dtype=np.float64)
        fit = self.rule.calibrate(levels)
        return (
            f"threshold {fit.threshold_db:.2f} dB from the first {fit.n_low + fit.n_high}"
            f" windows (quiet {fit.low_mean_db:.1f} dB, sound {fit.high_mean_db:.1f} dB)"
        )

    def recalibrate(self) -> str:
        """A new rule from the settings: a new calibration, floor, or the file read again."""
        self.rule = self._new_rule()
        mode = self.settings.threshold_mode
        if not self.rule.calibrating:
            threshold = self.rule.threshold_db
            return f"threshold_mode {mode}: threshold {threshold:.2f} dB from the next window on"
        if mode == "noise_floor":
            return (f"starting the noise floor on the next {self.rule.warmup_windows} windows: no"
                    " bits until then (their energies are published)")  # fmt: skip
        return (f"calibrating on the next {self.rule.calibration_windows} windows: no bits"
                " until then (their energies are published)")  # fmt: skip

    def check_live(self, name: str, value: Any) -> None:
        """``threshold_db`` is live in threshold_mode fixed only."""
        mode = self.settings.threshold_mode
        if name != "threshold_db" or mode != "fixed":
            raise SettingError(name, f"= {value!r} has no effect with threshold_mode {mode!r}:"
                               " it is live in threshold_mode fixed only")  # fmt: skip

    def set_live(self, name: str, value: Any) -> None:
        """The next window's bit uses the threshold ``value`` (dB)."""
        self.check_live(name, value)
        self.settings = dataclasses.replace(self.settings, threshold_db=value)
        self.rule.threshold_db = value

    def ready_message(self) -> str:
        rule = self.rule
        if isinstance(rule, NoiseFloorBinarizer):
            return (
                f"noise floor {rule.floor_db:.2f} dB after {rule.warmup_windows} windows:"
                f" threshold {rule.threshold_db:.2f} dB (margin {rule.margin_db:g} dB)"
            )
        fit = rule.fit
        return (
            f"calibrated: threshold {fit.threshold_db:.2f} dB (quiet {fit.low_mean_db:.1f}"
            f" dB, sound {fit.high_mean_db:.1f} dB)"
        )

    def threshold_origin(self) -> str:
        """The floor and margin, the k-means clusters, the file or the fixed value."""
        rule, settings = self.rule, self.settings
        if isinstance(rule, NoiseFloorBinarizer):
            return f"noise floor {rule.floor_db:.1f} dB + margin {rule.margin_db:g} dB"
        if rule.fit is not None:
            fit = rule.fit
            return (f"k-means of {fit.n_low + fit.n_high} windows: quiet {fit.low_mean_db:.1f}"
                    f" dB, sound {fit.high_mean_db:.1f} dB")  # fmt: skip
        if settings.threshold_mode == "file":
            return f"threshold_file {settings.threshold_file}"
        return f"threshold_db, threshold_mode {settings.threshold_mode}"

    def diagnostic_values(self) -> dict[str, Any]:
        """Threshold, refits and calibration state (and the floor)."""
        rule = self.rule
        values: dict[str, Any] = {
            "threshold_db": rule.threshold_db if rule.threshold_db is not None else "calibrating",
            "refits_accepted": rule.refits_accepted,
            "refits_rejected": rule.refits_rejected,
            "calibration_failures": rule.calibration_failures,
            "calibration_state": rule.state,
        }
        if isinstance(rule, NoiseFloorBinarizer):
            floor = rule.floor_db
            values["noise_floor_db"] = floor if floor is not None else "none yet"
        return values


class EnergySource(LevelSource):
    """The window's full-band energy against the threshold (the paper's rule)."""

    name = "energy"
    summary = "window energy against a threshold (the paper's rule)"
    needs_samples = False

    def push(self, energy_db: float) -> bool | None:
        """The bit of a window from its energy (dB)."""
        self.last_energy_db = self.last_level_db = float(energy_db)
        return self.rule.push(energy_db)


class SpeechBandSource(LevelSource):
    """The energy of the 300-3400 Hz band against the threshold."""

    name = "speech_band"
    summary = "energy of the 300-3400 Hz band against a threshold"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.band = SpeechBandLevel(self.rate_hz)

    @classmethod
    def check_settings(cls, settings: ThresholdSettings, rate_hz: int, window_s: float) -> None:
        """The threshold settings, and a rate above twice the band's upper edge."""
        if not rate_hz > 2 * SPEECH_BAND_HZ[1]:
            raise SettingError("rate_hz", f"= {rate_hz}: bit_source speech_band needs audio above"
                               f" {2 * SPEECH_BAND_HZ[1]:g} Hz (twice the band's upper edge,"
                               f" {SPEECH_BAND_HZ[1]:g} Hz)")  # fmt: skip
        super().check_settings(settings, rate_hz, window_s)

    def level_db(self, x: NDArray[np.float64]) -> float:
        """The band energy of the window, dB (the filter state carries over)."""
        return self.band.level_db(x)

    @classmethod
    def window_levels(cls, rate_hz: int) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
        band = SpeechBandLevel(rate_hz)
        return lambda rows: np.array([band.level_db(row) for row in rows])

    def diagnostic_values(self) -> dict[str, Any]:
        return {**super().diagnostic_values(), "last_band_db": self.last_level_db}


def levels_db(
    meter: Callable[[NDArray[np.float64]], NDArray[np.float64]], windows: ArrayLike
) -> NDArray[np.float64]:
    """Levels of windows in order (one per row) through ``meter``, dB; AudioError: bad samples."""
    rows = np.asarray(windows, dtype=np.float64)
    if rows.ndim != 2:
        raise AudioError(f"windows must be shaped (windows, samples), got {rows.shape}")
    rows = as_mono(rows.ravel(), "window samples").reshape(rows.shape)
    return np.asarray(meter(rows), dtype=np.float64).reshape(rows.shape[0])

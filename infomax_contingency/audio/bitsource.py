"""Bit sources: one window of audio to one bit, by name — the registry of binarizers.

Every bit source turns consecutive windows of mono samples (float64 in [-1, 1], at
``rate_hz``) into bits, one per window, with ``push_window(samples) -> bit | None``
(None: the window is calibration or warm-up audio and yields no step). The window's
full-band energy (dB, as :func:`~infomax_contingency.audio.energy.window_energies_db`)
is :attr:`last_energy_db`; a source that decides on the energy alone also takes the
energy directly, ``push(energy_db) -> bit | None``, the interface of
:class:`~infomax_contingency.audio.binarizer.Binarizer`.

Sources (:data:`BIT_SOURCES`, made by :func:`make_bit_source`):

* ``energy`` — the paper's rule: the window energy against a threshold (the default).
* ``speech_band`` — the energy of the 300-3400 Hz band only (a 4th-order Butterworth
  band-pass, :func:`scipy.signal.sosfilt`, its state carried from window to window),
  against a threshold.
* ``vad`` — WebRTC's voice-activity detector (``webrtcvad``) on frames of 10, 20 or
  30 ms: the bit is 1 when the frames that end in the window and are voiced add up to
  at least ``vad_min_voiced_s``. It takes 8, 16, 32 or 48 kHz only.

Threshold modes of ``energy`` and ``speech_band`` (:data:`THRESHOLD_MODES`): ``fixed``,
``file`` and ``calibrate`` (k-means, optional online refresh: :class:`Binarizer`),
``noise_floor``: a margin above a tracked floor
(:class:`~infomax_contingency.audio.binarizer.NoiseFloorBinarizer`), and ``background``:
a constant false-alarm rate on the windows the model calls background
(:class:`~infomax_contingency.audio.background.BackgroundThreshold`), which needs the
decisions (:meth:`LevelBitSource.note_decision`, :attr:`LevelBitSource.needs_decisions`).

A window with NaN or infinite samples, or of the wrong length, is refused (AudioError);
samples beyond [-1, 1] (clipping) are measured as they are, and clipped to full scale
for the VAD's 16-bit frames. Digital silence has energy -120 dB and is never voiced.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.background import BackgroundThreshold, window_faults
from infomax_contingency.audio.binarizer import (
    Binarizer,
    NoiseFloorBinarizer,
    calibration_window_count,
)
from infomax_contingency.audio.common import AudioError, as_mono, check_positive_seconds, check_rate
from infomax_contingency.audio.energy import frame_energies_db, window_samples
from infomax_contingency.audio.threshold import (
    DEFAULT_MIN_SEPARATION_DB,
    ThresholdFit,
    load_threshold,
)

THRESHOLD_MODES = ("calibrate", "fixed", "file", "noise_floor", "background")
"""How ``energy`` and ``speech_band`` set their threshold."""

SPEECH_BAND_HZ = (300.0, 3400.0)
"""The speech band of ``speech_band``: lower and upper edge, Hz (telephone band)."""

SPEECH_BAND_ORDER = 4
"""Butterworth order of each edge of the speech-band filter."""

VAD_RATES_HZ = (8000, 16000, 32000, 48000)
"""Sample rates webrtcvad accepts."""

VAD_FRAMES_MS = (10, 20, 30)
"""Frame lengths webrtcvad accepts, ms."""

_THRESHOLD_OPTIONS = {
    "threshold_mode": "calibrate",
    "threshold_db": -40.0,
    "threshold_file": "",
    "calibration_s": 10.0,
    "refresh_s": 0.0,
    "min_separation_db": DEFAULT_MIN_SEPARATION_DB,
    "noise_margin_db": 10.0,
    "noise_window_s": 30.0,
    "noise_percentile": 10.0,
    "false_alarm": 0.05,
    "background_window_s": 30.0,
    "warmup_s": 4.0,
    "background_margin_db": 0.0,
    "reference_margin_db": 3.0,
    "periods": (0, 1, 4),
    "on_calibration_refused": None,
}
_VAD_OPTIONS = {"vad_aggressiveness": 2, "vad_frame_ms": 30, "vad_min_voiced_s": 0.1}

BIT_SOURCES: dict[str, str] = {
    "energy": "window energy against a threshold (the paper's rule; the default)",
    "speech_band": "energy of the 300-3400 Hz band against a threshold",
    "vad": "WebRTC voice-activity detector: at least vad_min_voiced_s of voiced frames",
}
"""Every bit source's name and what it does."""

BIT_SOURCE_OPTIONS: dict[str, dict[str, Any]] = {
    "energy": _THRESHOLD_OPTIONS,
    "speech_band": _THRESHOLD_OPTIONS,
    "vad": _VAD_OPTIONS,
}
"""The options :func:`make_bit_source` takes for each source, with their defaults (the
defaults of mic_node's parameters of the same names)."""


def _window(samples: ArrayLike, n: int) -> NDArray[np.float64]:
    """One window of mono finite samples of length ``n``, or AudioError."""
    x = as_mono(samples, "window samples")
    if x.size != n:
        raise AudioError(f"a window must hold {n} samples, got {x.size}")
    return x


def _energy_db(x: NDArray[np.float64]) -> float:
    """Energy of one window, dB (the one energy rule, :func:`frame_energies_db`)."""
    return float(frame_energies_db(x.reshape(1, x.size))[0])


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
        from scipy.signal import butter, sosfilt  # lazy: ~1 s of CPU to load

        self._sosfilt = sosfilt
        self.rate_hz = rate_hz
        self.band_hz = (float(low), float(high))
        self._sos = butter(SPEECH_BAND_ORDER, self.band_hz, btype="bandpass", fs=rate_hz,
                           output="sos")  # fmt: skip
        self._state = np.zeros((self._sos.shape[0], 2))

    def level_db(self, x: NDArray[np.float64]) -> float:
        """Band energy of the next window (mono samples), dB."""
        y, self._state = self._sosfilt(self._sos, x, zi=self._state)
        return _energy_db(y)


class LevelBitSource:
    """A window level (dB) against a threshold rule: ``energy`` and ``speech_band``.

    Args:
        name: the source's name.
        rate_hz: sample rate of the windows, Hz.
        window_s: window length, seconds.
        rule: the threshold rule (:class:`Binarizer` or :class:`NoiseFloorBinarizer`).
        band: the speech-band level, or None for the full-band energy.
    """

    def __init__(
        self,
        name: str,
        rate_hz: int,
        window_s: float,
        rule: Binarizer | NoiseFloorBinarizer | BackgroundThreshold,
        band: SpeechBandLevel | None = None,
    ) -> None:
        self.name = name
        self.rate_hz = rate_hz
        self.window_s = window_s
        self.samples_per_window = window_samples(rate_hz, window_s)
        self.rule = rule
        self.band = band
        self.last_energy_db = math.nan
        """Full-band energy of the last window, dB."""
        self.last_level_db = math.nan
        """The level the last bit was decided on (energy or band energy), dB."""
        self.clipped_windows = 0
        """Windows with clipped samples (only counted from samples: :meth:`push_window`)."""
        self.dc_offset_windows = 0
        """Windows whose mean carried most of their energy (:meth:`push_window`)."""

    @property
    def needs_decisions(self) -> bool:
        """True if the threshold needs the decision on every bit (:meth:`note_decision`)."""
        return isinstance(self.rule, BackgroundThreshold)

    def note_decision(self, u: int | None) -> None:
        """The decision taken on the oldest bit that had none yet (1 = vocalize; None: lost).

        Only the ``background`` threshold uses it (it labels windows by the timer); the
        other rules ignore it.
        """
        if isinstance(self.rule, BackgroundThreshold):
            self.rule.note_decision(u)

    @property
    def needs_samples(self) -> bool:
        """True if a window's energy alone does not decide its bit."""
        return self.band is not None

    @property
    def calibrating(self) -> bool:
        """True while windows yield no bit (calibration or warm-up)."""
        return self.rule.calibrating

    @property
    def state(self) -> str:
        """The rule's state: ``"ready"``, ``"calibrating"`` or ``"unseparated"``."""
        return self.rule.state

    @property
    def calibration_problem(self) -> str:
        """Why the last calibration was refused ("" if none was)."""
        return self.rule.calibration_problem

    @property
    def threshold_db(self) -> float | None:
        """The threshold in force, dB (None while calibrating)."""
        return self.rule.threshold_db

    def push(self, energy_db: float) -> bool | None:
        """The bit of a window from its energy (dB); only for ``energy``."""
        if self.band is not None:
            raise AudioError(f"bit source {self.name!r} needs the window's samples: push_window()")
        self.last_energy_db = self.last_level_db = float(energy_db)
        return self.rule.push(energy_db)

    def push_window(self, samples: ArrayLike) -> bool | None:
        """The bit of one window of mono samples; None while calibrating."""
        x = _window(samples, self.samples_per_window)
        if isinstance(self.rule, BackgroundThreshold):
            faults = window_faults(x)
            self.clipped_windows += faults.clipped
            self.dc_offset_windows += faults.dc_offset
        self.last_energy_db = _energy_db(x)
        self.last_level_db = self.last_energy_db if self.band is None else self.band.level_db(x)
        return self.rule.push(self.last_level_db)

    def problems(self) -> list[str]:
        """One line per problem seen in the input (the ``background`` rule's, clipping, DC)."""
        out = []
        if self.clipped_windows:
            out.append(
                f"{self.clipped_windows} windows were clipped (samples at full scale): lower"
                " the input gain"
            )
        if self.dc_offset_windows:
            advice = (
                "the speech band removes it"
                if self.band is not None
                else "bit_source speech_band removes it"
            )
            out.append(f"{self.dc_offset_windows} windows had a DC offset ({advice})")
        if isinstance(self.rule, BackgroundThreshold):
            out.extend(self.rule.problems())
        return out

    def calibrate_windows(self, windows: NDArray[np.float64]) -> ThresholdFit:
        """Set a k-means threshold from windows read ahead (rows), e.g. a file's start.

        Their levels are taken with a filter from rest, as the same windows will be when
        they are pushed. Raises AudioError (or UnseparatedError) as
        :meth:`Binarizer.calibrate`.
        """
        if not isinstance(self.rule, Binarizer):
            raise AudioError("only threshold_mode calibrate is calibrated ahead")
        return self.rule.calibrate(window_levels_db(self.name, windows, self.rate_hz))

    def ready_message(self) -> str:
        """One line for the log once the first bit comes (after calibration or warm-up)."""
        rule = self.rule
        if isinstance(rule, BackgroundThreshold):
            return (
                f"threshold {rule.threshold_db:.2f} dB after {len(rule.background)} background"
                f" windows: {rule.rank}-th loudest of them (false alarms"
                f" {rule.false_alarm_now:.3f}, target {rule.false_alarm:g})"
            )
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

    def diagnostic_values(self) -> dict[str, Any]:
        """Threshold, refits and calibration state (and the floor / band level), for diagnostics."""
        rule = self.rule
        if isinstance(rule, BackgroundThreshold):
            values = rule.diagnostic_values()
            values["clipped_windows"] = self.clipped_windows
            values["dc_offset_windows"] = self.dc_offset_windows
            values["problems"] = "; ".join(self.problems()) or "none"
            if self.band is not None:
                values["last_band_db"] = self.last_level_db
            return values
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
        if self.band is not None:
            values["last_band_db"] = self.last_level_db
        return values


class VadBitSource:
    """WebRTC voice-activity detection: a window is active with ``min_voiced_s`` of voice.

    Samples are clipped to [-1, 1] and rounded to 16-bit PCM; frames of ``frame_ms`` run
    on without regard to window edges (a frame counts for the window it ends in; the
    samples of an unfinished frame wait for the next window), so any window length
    works and no audio is skipped.

    Args:
        rate_hz: sample rate, Hz: 8000, 16000, 32000 or 48000.
        window_s: window length, seconds.
        aggressiveness: 0 (least) .. 3 (most aggressive in calling frames unvoiced).
        frame_ms: 10, 20 or 30.
        min_voiced_s: voiced time a window needs to be active, seconds (0 < it <= window_s).
    """

    name = "vad"
    needs_samples = True
    needs_decisions = False
    calibrating = False
    state = "ready"
    calibration_problem = ""
    threshold_db = None
    rule = None

    def __init__(
        self,
        rate_hz: int,
        window_s: float,
        aggressiveness: int = 2,
        frame_ms: int = 30,
        min_voiced_s: float = 0.1,
    ) -> None:
        import webrtcvad  # here, so the other sources need no webrtcvad

        rate_hz = check_rate(rate_hz, "rate_hz")
        if rate_hz not in VAD_RATES_HZ:
            raise AudioError(
                f"bit source 'vad' takes audio at {', '.join(map(str, VAD_RATES_HZ))} Hz"
                f" (webrtcvad); got {rate_hz} Hz"
            )
        if isinstance(aggressiveness, bool) or aggressiveness not in (0, 1, 2, 3):
            raise AudioError(f"vad_aggressiveness must be 0, 1, 2 or 3, got {aggressiveness!r}")
        if isinstance(frame_ms, bool) or frame_ms not in VAD_FRAMES_MS:
            raise AudioError(f"vad_frame_ms must be 10, 20 or 30 ms, got {frame_ms!r}")
        window_s = check_positive_seconds(window_s, "window_s")
        min_voiced_s = check_positive_seconds(min_voiced_s, "vad_min_voiced_s")
        if min_voiced_s > window_s:
            raise AudioError(
                f"vad_min_voiced_s = {min_voiced_s:g} s is longer than a window ({window_s:g} s):"
                " no window could be active"
            )
        self.rate_hz = rate_hz
        self.window_s = window_s
        self.samples_per_window = window_samples(rate_hz, window_s)
        self.aggressiveness = int(aggressiveness)
        self.frame_ms = int(frame_ms)
        self.min_voiced_s = min_voiced_s
        self._frame = rate_hz * self.frame_ms // 1000
        self._vad = webrtcvad.Vad(self.aggressiveness)
        self._rest = np.empty(0, dtype=np.int16)
        self.last_energy_db = math.nan
        """Full-band energy of the last window, dB."""
        self.last_voiced_s = math.nan
        """Voiced time found in the last window, seconds."""
        self.voiced_windows = 0
        """Windows found active so far."""

    def push(self, energy_db: float) -> bool | None:
        """Refused: the VAD needs the samples (:meth:`push_window`)."""
        raise AudioError("bit source 'vad' needs the window's samples: push_window()")

    def push_window(self, samples: ArrayLike) -> bool:
        """The bit of one window of mono samples: voiced time >= ``min_voiced_s``."""
        x = _window(samples, self.samples_per_window)
        self.last_energy_db = _energy_db(x)
        pcm = np.round(np.clip(x, -1.0, 1.0) * 32767.0).astype(np.int16)
        pcm = np.concatenate((self._rest, pcm))
        n_frames = pcm.size // self._frame
        voiced = sum(
            self._vad.is_speech(frame.tobytes(), self.rate_hz)
            for frame in pcm[: n_frames * self._frame].reshape(n_frames, self._frame)
        )
        self._rest = pcm[n_frames * self._frame :].copy()
        self.last_voiced_s = voiced * self.frame_ms / 1000.0
        bit = self.last_voiced_s >= self.min_voiced_s - 1e-9
        self.voiced_windows += bit
        return bit

    def note_decision(self, u: int | None) -> None:
        """Decisions do not change the VAD's bits (the interface of :class:`LevelBitSource`)."""

    def problems(self) -> list[str]:
        """Problems seen in the input: none the VAD can tell."""
        return []

    def ready_message(self) -> str:
        """One line for the log (the VAD needs no calibration)."""
        return f"voice-activity detection ready (aggressiveness {self.aggressiveness})"

    def diagnostic_values(self) -> dict[str, Any]:
        """The VAD's settings and last window, for diagnostics."""
        return {
            "vad_aggressiveness": self.aggressiveness,
            "vad_frame_ms": self.frame_ms,
            "vad_min_voiced_s": self.min_voiced_s,
            "last_voiced_s": self.last_voiced_s,
            "voiced_windows": self.voiced_windows,
            "calibration_state": self.state,
        }


BitSource = LevelBitSource | VadBitSource
"""What :func:`make_bit_source` returns."""


def _background_rule(window_s: float, options: dict[str, Any]) -> BackgroundThreshold:
    """The ``background`` threshold from the options (seconds -> windows)."""
    if options["refresh_s"]:
        raise AudioError(
            "refresh_s refits a k-means threshold; threshold_mode background follows the"
            " room by itself: set refresh_s to 0"
        )
    periods = options["periods"]
    if not (isinstance(periods, tuple | list) and len(periods) == 3):
        raise AudioError(f"periods must be (ts1, ts2, ta2) in steps, got {periods!r}")
    history_s = check_positive_seconds(options["background_window_s"], "background_window_s")
    warmup_s = check_positive_seconds(options["warmup_s"], "warmup_s")
    ts1, ts2, ta2 = (int(v) for v in periods)
    return BackgroundThreshold(
        ts1,
        ts2,
        ta2,
        options["false_alarm"],
        max(2, round(history_s / window_s)),
        max(1, round(warmup_s / window_s)),
        options["background_margin_db"],
        reference_margin_db=options["reference_margin_db"],
    )


def _threshold_rule(
    level: str, window_s: float, options: dict[str, Any]
) -> Binarizer | NoiseFloorBinarizer | BackgroundThreshold:
    """The threshold rule that ``options['threshold_mode']`` asks for.

    ``level`` is the source's name: a threshold file must hold a threshold of its level.
    """
    mode = options["threshold_mode"]
    if mode == "background":
        return _background_rule(window_s, options)
    refresh_s = options["refresh_s"]
    if isinstance(refresh_s, bool) or not isinstance(refresh_s, int | float) or not refresh_s >= 0:
        raise AudioError(f"refresh_s must be a number of seconds >= 0, got {refresh_s!r}")
    refresh = round(refresh_s / window_s) if refresh_s > 0 else 0
    separation = options["min_separation_db"]
    on_refused: Callable[[str], None] | None = options["on_calibration_refused"]
    if mode == "noise_floor":
        if refresh:
            raise AudioError(
                "refresh_s refits a k-means threshold; threshold_mode noise_floor follows the"
                " floor by itself: set refresh_s to 0"
            )
        noise_window_s = check_positive_seconds(options["noise_window_s"], "noise_window_s")
        return NoiseFloorBinarizer(
            options["noise_margin_db"],
            max(1, round(noise_window_s / window_s)),
            options["noise_percentile"],
            calibration_window_count(options["calibration_s"], window_s),
        )
    if mode == "fixed":
        return Binarizer(options["threshold_db"], 0, refresh, separation, on_refused)
    if mode == "file":
        threshold = load_threshold(options["threshold_file"], level)
        return Binarizer(threshold, 0, refresh, separation, on_refused)
    if mode == "calibrate":
        windows = calibration_window_count(options["calibration_s"], window_s)
        return Binarizer(None, windows, refresh, separation, on_refused)
    raise AudioError(f"threshold_mode must be one of {', '.join(THRESHOLD_MODES)}; got {mode!r}")


def make_bit_source(name: str, rate_hz: int, window_s: float, **options: Any) -> BitSource:
    """The bit source ``name`` (:data:`BIT_SOURCES`) for windows of ``window_s`` at ``rate_hz``.

    Args:
        name: ``energy``, ``speech_band`` or ``vad``.
        rate_hz: sample rate of the windows, Hz.
        window_s: window length, seconds.
        **options: the source's options (:data:`BIT_SOURCE_OPTIONS`, named as mic_node's
            parameters; ``on_calibration_refused`` is a callable told why a calibration
            was refused); missing ones take their defaults.

    Raises:
        AudioError: an unknown source or option, or a bad value (one line naming it).
    """
    if name not in BIT_SOURCES:
        raise AudioError(f"unknown bit source {name!r}; bit sources: {', '.join(BIT_SOURCES)}")
    allowed = BIT_SOURCE_OPTIONS[name]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise AudioError(
            f"bit source {name!r} takes no option {', '.join(unknown)}; its options:"
            f" {', '.join(allowed)}"
        )
    rate_hz = check_rate(rate_hz, "rate_hz")
    window_s = check_positive_seconds(window_s, "window_s")
    chosen = {**allowed, **options}
    if name == "vad":
        return VadBitSource(
            rate_hz,
            window_s,
            chosen["vad_aggressiveness"],
            chosen["vad_frame_ms"],
            chosen["vad_min_voiced_s"],
        )
    band = SpeechBandLevel(rate_hz) if name == "speech_band" else None
    return LevelBitSource(name, rate_hz, window_s, _threshold_rule(name, window_s, chosen), band)


class WindowLevels:
    """The levels (dB) a threshold of source ``name`` applies to, for windows in order.

    ``energy``: the window energies; ``speech_band``: the band energies, the filter
    starting from rest and carried from call to call (as in a stream). For calibration
    audio read ahead (a file, a recording).

    Raises:
        AudioError: ``name`` has no threshold (``vad``) or is unknown.
    """

    def __init__(self, name: str, rate_hz: int) -> None:
        if name not in ("energy", "speech_band"):
            raise AudioError(
                f"bit source {name!r} has no threshold to calibrate; energy and speech_band"
                " have"
            )
        self.name = name
        self._band = SpeechBandLevel(rate_hz) if name == "speech_band" else None

    def levels_db(self, windows: ArrayLike) -> NDArray[np.float64]:
        """Levels of the next windows (one per row), dB; AudioError for bad samples."""
        rows = np.asarray(windows, dtype=np.float64)
        if rows.ndim != 2:
            raise AudioError(f"windows must be shaped (windows, samples), got {rows.shape}")
        rows = as_mono(rows.ravel(), "window samples").reshape(rows.shape)
        if self._band is None:
            return frame_energies_db(rows)
        return np.array([self._band.level_db(row) for row in rows])


def window_levels_db(name: str, windows: ArrayLike, rate_hz: int) -> NDArray[np.float64]:
    """:class:`WindowLevels` of windows read ahead (one per row), from a filter at rest."""
    return WindowLevels(name, rate_hz).levels_db(windows)

"""The bit source the model calibrates itself: ``background``.

A window is active when its level is above the level that only a chosen share
(``false_alarm``) of the room's recent *background* windows exceed — the windows whose
timer is past the agent period, which the model says are background whatever S is — and,
for every window alike, more than ``reference_margin_db`` above the level of the window
the robot's last sound followed (:class:`~infomax_contingency.audio.background.BackgroundThreshold`:
the mathematics, the labels and the diagnostics). Nothing is tuned per room: the
threshold follows each room, and the model's background rate K3 is held near
``false_alarm`` in every room (a matching Beta prior on K3 lets the belief use that).

The source needs the decisions (:attr:`needs_decisions`): mic_node hands it each
decision of ``vocalize_step``, the offline loop
(:class:`~infomax_contingency.sim.audio_loop.AudioWorld`) each of its decisions, a replay
of a recording its recorded actions. It needs the
model's periods (:meth:`follow_model`), which mic_node, the offline loop and ``replay``
give it from their ``params``.

The level is the energy of the window's speech band, 300-3400 Hz (``level_band``
``speech``, the default: where a partner's voice is, while a room's rumble of traffic,
engines and air conditioning and its hiss lie mostly outside it), or of the whole window
with its mean removed (``full``); a DC offset neither raises the level nor hides a sound
(it is reported). The first ``warmup_s`` seconds of background (plus the threshold's
delay, ``ta2 + 1`` windows) yield no bit.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.background import (
    SILENCE_DB,
    BackgroundThreshold,
    level_and_faults,
    ordinal,
)
from infomax_contingency.audio.bitsources.base import (
    CALIBRATING,
    OUT_OF_RANGE,
    READY,
    BitSource,
    NameArgument,
    SettingError,
    setting,
    window_energy_db,
)
from infomax_contingency.audio.bitsources.level import SPEECH_BAND_HZ, SpeechBandLevel
from infomax_contingency.audio.common import AudioError, as_mono
from infomax_contingency.core.model import ModelParams

LEAST_RANK = 2
"""The threshold is at least the 2nd loudest background window: one loud event (a door
slam) does not raise it above a partner's voice for the whole history."""

QUIETEST_SOUND_DB = 0.5
"""A window with sound but (almost) none in the speech band is this far above
:data:`~infomax_contingency.audio.background.SILENCE_DB`: quiet, not digital silence."""

ROBOT_PERIODS = (0, 1, 2, 4)
"""``(ts1, ts2, ta1, ta2)`` used until :meth:`BackgroundSource.follow_model` (the robot's)."""


def band_name(level_band: str) -> str:
    """What a ``level_band`` takes the level over, in words (``speech-band``, ``whole-window``)."""
    return "speech-band" if level_band == "speech" else "whole-window"


@dataclasses.dataclass(frozen=True)
class BackgroundSettings:
    """Settings of ``background`` (mic_node parameters of the same names)."""

    false_alarm: float = setting(
        0.05,
        "Share of the room's background windows (timer past the agent period) above the"
        " threshold; the model's Beta prior on K3 (b31, b32) should match it",
        low=0.005, high=0.5,
    )
    background_window_s: float = setting(
        30.0,
        "The threshold is taken over the room's last background windows, this much sound"
        " of them (windows of the robot's sound and of the agent period are skipped: it"
        " reaches further back while the robot asks)",
        low=1.0, high=86400.0, unit="s",
    )
    warmup_s: float = setting(
        4.0, "Background audio heard before the first bit", low=0.5, high=3600.0, unit="s"
    )
    reference_margin_db: float = setting(
        3.0,
        "A window must also be this much louder than the window the robot's last sound"
        " followed (background windows: as far back, never to the robot's own sound)",
        low=0.0, high=60.0, unit="dB",
    )
    level_band: str = setting(
        "speech",
        "The band of the window level: speech (300-3400 Hz, where a voice is; most of a"
        " room's rumble and hiss lie outside it) or full (the whole window, the paper's energy)",
        choices=("speech", "full"),
    )


class BackgroundSource(BitSource):
    """The window level against the room's own background, at a constant false-alarm rate."""

    name = "background"
    summary = (
        "window level (of the speech band: level_band) above the room's background windows"
        " (a share false_alarm of them), the model's own calibration"
    )
    Settings = BackgroundSettings
    needs_decisions = True
    name_modes = {
        "": (
            NameArgument("false_alarm", "FALSE_ALARM"),
            NameArgument("reference_margin_db", "MARGIN_DB"),
            NameArgument("level_band", "BAND"),
        )
    }

    def __init__(
        self,
        settings: BackgroundSettings,
        rate_hz: int,
        window_s: float,
        on_problem: Callable[[str], None] | None = None,
    ) -> None:
        super().__init__(settings, rate_hz, window_s, on_problem)
        self.periods = ROBOT_PERIODS
        self.rule = self._new_rule()
        self._band = SpeechBandLevel(rate_hz) if settings.level_band == "speech" else None
        self._stale_decisions = 0  # decisions still due on bits of a rule replaced
        self.last_level_db = float("nan")
        """The level the last bit was decided on (``level_band``'s energy), dB."""
        self.clipped_windows = 0
        self.dc_offset_windows = 0

    @classmethod
    def check_settings(cls, settings: BackgroundSettings, rate_hz: int, window_s: float) -> None:
        """The warm-up fits in the threshold's history; the speech band fits the rate."""
        if settings.level_band == "speech" and not rate_hz > 2 * SPEECH_BAND_HZ[1]:
            raise SettingError("rate_hz", f"= {rate_hz}: bit_source background with level_band"
                               f" speech needs audio above {2 * SPEECH_BAND_HZ[1]:g} Hz (twice"
                               " the band's upper edge); give such audio, or set level_band:"
                               " full")  # fmt: skip
        if settings.warmup_s > settings.background_window_s:
            history = settings.background_window_s
            raise SettingError("warmup_s", f"= {settings.warmup_s:g} s: must not exceed"
                               f" background_window_s ({history:g} s)")  # fmt: skip

    def _new_rule(self, timer_known: bool = True) -> BackgroundThreshold:
        s, window_s = self.settings, self.window_s
        ts1, ts2, ta1, ta2 = self.periods
        return BackgroundThreshold(
            ts1, ts2, ta2,
            false_alarm=s.false_alarm,
            history=max(2, round(s.background_window_s / window_s)),
            warmup_windows=max(1, round(s.warmup_s / window_s)),
            ta1=ta1,
            reference_margin_db=s.reference_margin_db,
            least_rank=LEAST_RANK,
            on_problem=self.on_problem,
            timer_known=timer_known,
        )  # fmt: skip

    def follow_model(self, params: ModelParams) -> None:
        """Label windows by the periods of ``params`` (before the first window)."""
        periods = (params.ts1, params.ts2, params.ta1, params.ta2)
        if periods != self.periods:
            if self.rule.windows:
                raise RuntimeError("follow_model() comes before the first window")
            self.periods = periods
            self.rule = self._new_rule()

    def note_decision(self, u: int | None, withheld: bool = False) -> None:
        """The decision on the oldest bit that had none yet (1: vocalize; None: lost).

        ``withheld``: that window was withheld for the robot's own sound; it never sets
        the threshold. Decisions on bits given before :meth:`recalibrate` are not the new
        rule's: they are passed over.
        """
        if self._stale_decisions:
            self._stale_decisions -= 1
            return
        self.rule.note_decision(u, withheld)

    @property
    def awaited_decisions(self) -> int:
        """Bits given whose decisions have not come yet (those of a rule replaced aside).

        The next window's bit is the offline loop's once they are in: an agent-period
        window is held to the level of the window its vocalization was decided on.
        """
        return self.rule.awaited_decisions

    def decide(self, x: NDArray[np.float64]) -> bool | None:
        return self.rule.push(self._level(x))

    def push_recorded(self, samples: ArrayLike, decision: int) -> bool | None:
        """The bit of a recording's window whose decision (taken after it) is known.

        For replays with the recording's actions: the window is labelled without waiting
        for :meth:`note_decision` (warm-up windows included, which yield no bit).
        """
        x = as_mono(samples, "window samples")
        if x.size != self.samples_per_window:
            raise AudioError(f"a window must hold {self.samples_per_window} samples, got {x.size}")
        self.last_energy_db = window_energy_db(x)
        return self.rule.push(self._level(x), decision=decision)

    def _level(self, x: NDArray[np.float64]) -> float:
        """The window's level (``level_band``), dB; counts clipping and DC offset.

        A window is digital silence in both bands alike: all zeros, or nothing but a DC
        offset (a dead input); a window with sound is never as quiet as that, whatever its band.
        """
        level, faults = level_and_faults(x)
        if self._band is not None:
            band_db = self._band.level_db(x)  # every window: the filter's state runs on
            if level > SILENCE_DB:  # else digital silence, or nothing but DC: as full
                level = max(band_db, SILENCE_DB + QUIETEST_SOUND_DB)
        self.last_level_db = level
        self.clipped_windows += faults.clipped
        self.dc_offset_windows += faults.dc_offset
        return level

    # ------------------------------------------------------------------ state

    @property
    def state(self) -> str:
        if self.rule.range_guard.problem:
            return OUT_OF_RANGE
        return CALIBRATING if self.rule.calibrating else READY

    @property
    def problem(self) -> str:
        return self.rule.calibration_problem

    @property
    def threshold_db(self) -> float | None:
        return self.rule.threshold_db

    def threshold_origin(self) -> str:
        """The rank, the background windows it was taken over and the false alarms it gives."""
        rule = self.rule
        return (f"room: the {ordinal(rule.rank)} loudest of {len(rule.background)} background"
                f" windows' {self.band_name} levels, false alarms"
                f" {rule.false_alarm_now:.3f}")  # fmt: skip

    @property
    def band_name(self) -> str:
        """What the level is taken over, in words (:func:`band_name`)."""
        return band_name(self.settings.level_band)

    def problems(self) -> list[str]:
        """One line per problem seen in the input (clipping, DC offset, the rule's)."""
        out = []
        if self.clipped_windows:
            out.append(f"{self.clipped_windows} windows were clipped (samples at full scale):"
                       " lower the input gain")  # fmt: skip
        if self.dc_offset_windows:
            out.append(f"{self.dc_offset_windows} windows had a DC offset (removed from the"
                       " level; check the microphone)")  # fmt: skip
        return out + self.rule.problems()

    def recalibrate(self) -> str:
        """Forget the room: a new warm-up on the next windows."""
        self._stale_decisions += self.rule.awaited_decisions
        self.rule = self._new_rule(timer_known=False)  # a sound decided before may follow
        return (f"hearing the room again: no bits for the next {self.rule.warmup_windows}"
                " background windows (and the threshold's delay)")  # fmt: skip

    def ready_message(self) -> str:
        rule = self.rule
        return (
            f"threshold {rule.threshold_db:.2f} dB ({self.band_name} level) from"
            f" {len(rule.background)} background windows ({ordinal(rule.rank)} loudest: false"
            f" alarms {rule.false_alarm_now:.3f},"
            f" target {rule.false_alarm:g})"
        )

    def diagnostic_values(self) -> dict[str, Any]:
        values = self.rule.diagnostic_values()
        values["clipped_windows"] = self.clipped_windows
        values["dc_offset_windows"] = self.dc_offset_windows
        values["problems"] = "; ".join(self.problems()) or "none"
        values["last_level_db"] = self.last_level_db
        values["level_band"] = self.settings.level_band
        return values


class SilentRobotMeter:
    """The default source on a room heard with the robot silent (``calibrate``).

    Every window is then a background window, decided on (silence) as it comes, as in a
    replay with its actions. Its :meth:`levels_db` gives the windows' levels as the source
    computes them (``level_band``; digital silence, clipping and DC offset counted) and
    keeps their bits.
    """

    def __init__(self, params: ModelParams, rate_hz: int,
                 settings: BackgroundSettings | None = None) -> None:
        self.source = BackgroundSource(settings or BackgroundSettings(), rate_hz, params.dt)
        self.source.follow_model(params)
        self.bits: list[int] = []
        """The bits of the windows after the warm-up (1: active)."""
        self.windows = 0

    def levels_db(self, windows: ArrayLike) -> NDArray[np.float64]:
        """The next windows' levels (one window per row), dB; their bits are kept."""
        levels = []
        for window in np.atleast_2d(np.asarray(windows, dtype=np.float64)):
            bit = self.source.push_recorded(window, 0)
            if bit is not None:
                self.bits.append(int(bit))
            levels.append(self.source.last_level_db)
            self.windows += 1
        return np.asarray(levels)

    @property
    def windows_without_bit(self) -> int:
        """Windows heard before the first bit can come (warm-up and the threshold's delay)."""
        return self.source.rule.windows_before_first_bit

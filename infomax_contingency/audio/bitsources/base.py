"""What every bit source is: the :class:`BitSource` interface and its declared settings.

A bit source turns consecutive windows of mono samples (float64 in [-1, 1], at
``rate_hz``) into bits, one per window (None: the window is calibration or warm-up audio
and yields no step). Its settings are a frozen dataclass whose fields are made by
:func:`setting`: name, default, description, range or choices, unit and whether it may
change while running are declared there once, and read by mic_node's parameter
declarations, by :func:`~infomax_contingency.audio.bitsources.make_bit_source` (the
offline loop, the CLI) and by the name grammar of ``experiment rooms``.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.common import AudioError, as_mono
from infomax_contingency.audio.energy import frame_energies_db, window_samples

READY = "ready"
"""State: every window gets a bit."""
CALIBRATING = "calibrating"
"""State: collecting calibration (or warm-up) windows; no bits yet."""
UNSEPARATED = "unseparated"
"""State: the last calibration could not separate sound from quiet; collecting the next
calibration windows (no bits until one succeeds)."""
OUT_OF_RANGE = "out_of_range"
"""State: the threshold the source computed lies outside the ``threshold_db`` parameter's
range (:class:`~infomax_contingency.audio.threshold.ThresholdRangeGuard`); no bits until it
is back in range."""


class SettingError(AudioError):
    """A setting this rate, window or mode cannot use: ``'name' <reason>`` in one line.

    Attributes:
        setting: the setting's name (``rate_hz`` for the sample rate).
        reason: the rest of the message (``= 0.6 s is longer than a window ...``).
    """

    def __init__(self, setting: str, reason: str) -> None:
        self.setting = setting
        self.reason = reason
        super().__init__(f"'{setting}' {reason}")


@dataclasses.dataclass(frozen=True)
class SettingSpec:
    """One declared setting of a bit source (a mic_node parameter of the same name).

    Attributes:
        name: the setting's (and parameter's) name.
        default: its default value; its type is the setting's type (float, int, str).
        description: one line for ``ros2 param describe`` and the docs.
        low: least value (numbers), or None.
        high: greatest value (numbers), or None.
        unit: unit of a number (``s``, ``dB``, ...), or "".
        choices: the allowed strings (a text setting), or None for any.
        live: True if it may change while the node runs (``ros2 param set``).
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    unit: str = ""
    choices: tuple[str, ...] | None = None
    live: bool = False

    @property
    def allowed(self) -> str:
        """What values are allowed, in words (the end of a refusal)."""
        if isinstance(self.default, str):
            return f"one of {', '.join(self.choices)}" if self.choices else "a string"
        if isinstance(self.default, int):
            return f"a whole number in [{self.low:g}, {self.high:g}]"
        return f"a number in [{self.low:g}, {self.high:g}]" + (f" {self.unit}" if self.unit else "")

    def check(self, value: Any) -> Any:
        """``value`` in the setting's type, or AudioError naming the setting and what is allowed."""
        refused = AudioError(f"{self.name} = {value!r} is not allowed: {self.allowed}")
        if isinstance(self.default, str):
            if not isinstance(value, str) or (self.choices and value not in self.choices):
                raise refused
            return value
        if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
            raise refused
        if isinstance(self.default, int) and int(value) != value:
            raise refused
        if not math.isfinite(value) or not self.low <= value <= self.high:
            raise refused
        return int(value) if isinstance(self.default, int) else float(value)


def setting(
    default: Any,
    description: str,
    *,
    low: float | None = None,
    high: float | None = None,
    unit: str = "",
    choices: tuple[str, ...] | None = None,
    live: bool = False,
) -> Any:
    """A field of a bit source's settings dataclass, with its declaration (:class:`SettingSpec`).

    Numbers need ``low`` and ``high``; the name is the field's.
    """
    if not isinstance(default, str) and (low is None or high is None):
        raise TypeError("a number setting needs low and high")
    declared = {"default": default, "description": description, "low": low, "high": high,
                "unit": unit, "choices": choices, "live": live}  # fmt: skip
    return dataclasses.field(default=default, metadata={"setting": declared})


def setting_specs(settings_class: type) -> tuple[SettingSpec, ...]:
    """The declared settings of a settings dataclass, in field order."""
    return tuple(
        SettingSpec(name=field.name, **field.metadata["setting"])
        for field in dataclasses.fields(settings_class)
    )


@dataclasses.dataclass(frozen=True)
class NameArgument:
    """One argument of a bit source's name in ``experiment rooms`` (``vad:2:0.1``).

    Attributes:
        setting: the setting it gives.
        placeholder: how the grammar shows it (``DB``, ``S``).
        required: True if the name must give it.
    """

    setting: str
    placeholder: str
    required: bool = False


def window_energy_db(x: NDArray[np.float64]) -> float:
    """Energy of one window of mono samples, dB (the one energy rule, :func:`frame_energies_db`)."""
    return float(frame_energies_db(x.reshape(1, x.size))[0])


class BitSource(ABC):
    """One window of audio to one bit; a subclass is one registered source.

    A subclass sets :attr:`name`, :attr:`summary`, :attr:`Settings` (a frozen dataclass
    of :func:`setting` fields) and :attr:`name_modes`, implements :meth:`decide`, and may
    refine :meth:`check_settings` (checks a range cannot express), the state
    (:attr:`state`, :attr:`problem`, :attr:`threshold_db`), :meth:`calibrate_ahead`,
    :meth:`recalibrate`, :meth:`set_live` and :meth:`diagnostic_values`.

    Args:
        settings: an instance of :attr:`Settings` (checked by :meth:`check_settings`).
        rate_hz: sample rate of the windows, Hz.
        window_s: window length, seconds.
        on_problem: told (one line) when the source cannot give bits for a while (a
            refused calibration); None: not told.
    """

    name: ClassVar[str]
    """The registered name (mic_node's ``bit_source``)."""
    summary: ClassVar[str]
    """What it does, one line."""
    Settings: ClassVar[type]
    """Its settings dataclass."""
    needs_samples: ClassVar[bool] = True
    """False if a window's full-band energy alone decides its bit (:meth:`push` works)."""
    needs_decisions: ClassVar[bool] = False
    """True if the source labels windows by the model's timer: it then has
    ``note_decision(u)``, to be called with every decision in order (None: lost),
    ``awaited_decisions`` (bits given whose decisions have not come yet: the next window's
    bit is the offline loop's only once they are in) and ``follow_model(params)``, called
    before the first window with the model whose periods label them."""
    mode_setting: ClassVar[str | None] = None
    """The setting a name's first word after the source gives (``threshold_mode``), if any."""
    name_modes: ClassVar[Mapping[str, tuple[NameArgument, ...]]] = {"": ()}
    """The arguments of the source's name per mode word ("" when it has no mode)."""

    def __init__(
        self,
        settings: Any,
        rate_hz: int,
        window_s: float,
        on_problem: Callable[[str], None] | None = None,
    ) -> None:
        self.settings = settings
        self.rate_hz = rate_hz
        self.window_s = window_s
        self.samples_per_window = window_samples(rate_hz, window_s)
        self.on_problem = on_problem
        self.last_energy_db = math.nan
        """Full-band energy of the last window, dB."""

    # ------------------------------------------------------------------ declaration

    @classmethod
    def specs(cls) -> tuple[SettingSpec, ...]:
        """The source's declared settings."""
        return setting_specs(cls.Settings)

    @classmethod
    def make_settings(cls, options: Mapping[str, Any]) -> Any:
        """:attr:`Settings` from ``options`` (missing ones take their defaults), each checked.

        Raises:
            AudioError: an unknown option or a value outside its declaration.
        """
        specs = {spec.name: spec for spec in cls.specs()}
        unknown = sorted(set(options) - set(specs))
        if unknown:
            raise AudioError(
                f"bit source {cls.name!r} takes no option {', '.join(unknown)}; its options:"
                f" {', '.join(specs)}"
            )
        return cls.Settings(**{name: specs[name].check(value) for name, value in options.items()})

    @classmethod
    def check_settings(cls, settings: Any, rate_hz: int, window_s: float) -> None:
        """Raise AudioError (naming the setting) for settings this rate and window cannot use.

        Nothing to check by default (every setting's range is checked on its own).
        """
        return

    # ------------------------------------------------------------------ windows

    @abstractmethod
    def decide(self, x: NDArray[np.float64]) -> bool | None:
        """The bit of one checked window (mono, ``samples_per_window`` long); None: no bit."""

    def push_window(self, samples: ArrayLike) -> bool | None:
        """The bit of one window of mono samples; None while it yields no bit."""
        x = as_mono(samples, "window samples")
        if x.size != self.samples_per_window:
            raise AudioError(f"a window must hold {self.samples_per_window} samples, got {x.size}")
        self.last_energy_db = window_energy_db(x)
        return self.decide(x)

    def push(self, energy_db: float) -> bool | None:
        """The bit of a window from its full-band energy (dB); only if not :attr:`needs_samples`."""
        raise AudioError(f"bit source {self.name!r} needs the window's samples: push_window()")

    def bit_of(self, energy_db: float, samples: ArrayLike | None) -> bool | None:
        """The bit of one window: from its samples if given, else from its energy (dB)."""
        if samples is None:
            return self.push(energy_db)
        return self.push_window(samples)

    # ------------------------------------------------------------------ state

    @property
    def state(self) -> str:
        """:data:`READY`, :data:`CALIBRATING`, :data:`UNSEPARATED` or :data:`OUT_OF_RANGE`."""
        return READY

    @property
    def calibrating(self) -> bool:
        """True while windows yield no bit."""
        return self.state != READY

    @property
    def problem(self) -> str:
        """Why the source gives no bits now ("" if nothing is wrong)."""
        return ""

    @property
    def threshold_db(self) -> float | None:
        """The threshold in force, dB (None: the source has none, or not yet)."""
        return None

    @property
    def read_ahead_s(self) -> float:
        """Seconds of a replay's start to :meth:`calibrate_ahead` on; 0: none."""
        return 0.0

    def calibrate_ahead(self, energies_db: ArrayLike, windows: NDArray[np.float64] | None) -> str:
        """Calibrate on windows read ahead (a file's start); a line for the log.

        ``energies_db``: their full-band energies; ``windows``: their samples, one per row
        (None when the source does not :attr:`needs_samples`).

        Raises:
            AudioError: the calibration is refused (the source keeps calibrating).
        """
        raise AudioError(f"bit source {self.name!r} is not calibrated ahead")

    def recalibrate(self) -> str:
        """Start the source's calibration again (``~/recalibrate``); a line for the log.

        Raises:
            AudioError: the source has nothing to calibrate.
        """
        raise AudioError(f"bit source {self.name!r} has nothing to calibrate")

    def check_live(self, name: str, value: Any) -> None:
        """Raise SettingError if the live setting ``name`` cannot take ``value`` now.

        By default any setting declared ``live=True`` may change (its range is checked
        where it is declared).
        """
        spec = {spec.name: spec for spec in self.specs()}.get(name)
        if spec is None or not spec.live:
            raise SettingError(name, f"= {value!r} cannot change while bit_source {self.name}"
                               " runs")  # fmt: skip

    def set_live(self, name: str, value: Any) -> None:
        """Apply a live setting checked by :meth:`check_live`: the next window uses it.

        By default the settings are replaced (a source that reads :attr:`settings` for
        every window needs nothing more).
        """
        self.check_live(name, value)
        self.settings = dataclasses.replace(self.settings, **{name: value})

    def ready_message(self) -> str:
        """One line for the log when a calibration (or warm-up) ends: mic_node logs it then."""
        return f"bit source {self.name} ready"

    def threshold_origin(self) -> str:
        """Where :attr:`threshold_db` came from, for the log ("" for a source without one)."""
        return ""

    def diagnostic_values(self) -> dict[str, Any]:
        """The source's state for diagnostics."""
        return {"calibration_state": self.state}

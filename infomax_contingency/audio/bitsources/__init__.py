"""Bit sources by name: the one registry of the rules that turn a window of audio into a bit.

A bit source is one class (:class:`~infomax_contingency.audio.bitsources.base.BitSource`)
with its settings dataclass; registering it is one line in :data:`BIT_SOURCES`. Then it
is mic_node's ``bit_source`` (its settings become mic_node parameters), the offline
loop's (:func:`make_bit_source`) and a name of ``experiment rooms --binarizer``.

* ``energy`` — the window energy against a threshold (the paper's rule).
* ``speech_band`` — the 300-3400 Hz band's energy against a threshold.
* ``vad`` — WebRTC's voice-activity detector.
* ``background`` — the window level above the room's own background windows, at a chosen
  false-alarm share: the threshold the model calibrates itself.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from infomax_contingency.audio.bitsources.background import BackgroundSource
from infomax_contingency.audio.bitsources.base import BitSource, SettingSpec
from infomax_contingency.audio.bitsources.level import (
    EnergySource,
    LevelSource,
    SpeechBandSource,
    levels_db,
)
from infomax_contingency.audio.bitsources.vad import VadSource
from infomax_contingency.audio.common import AudioError, check_positive_seconds, check_rate

BIT_SOURCES: dict[str, type[BitSource]] = {
    source.name: source
    for source in (
        EnergySource,
        SpeechBandSource,
        VadSource,
        BackgroundSource,
    )
}
"""Every bit source by name (the order of the docs and of the parameter declarations)."""

DEFAULT_BIT_SOURCE = "background"
"""mic_node's ``bit_source`` by default."""


def bit_source_class(name: str) -> type[BitSource]:
    """The registered class of ``name``; AudioError naming the registered ones."""
    try:
        return BIT_SOURCES[name]
    except KeyError:
        raise AudioError(
            f"unknown bit source {name!r}; bit sources: {', '.join(BIT_SOURCES)}"
        ) from None


def all_setting_specs() -> tuple[SettingSpec, ...]:
    """The settings of every registered source, each name once (mic_node's parameters).

    Sources that share a setting name share its declaration (AssertionError otherwise).
    """
    specs: dict[str, SettingSpec] = {}
    for source in BIT_SOURCES.values():
        for spec in source.specs():
            assert specs.setdefault(spec.name, spec) == spec, f"two declarations of {spec.name}"
    return tuple(specs.values())


def sources_with_setting(name: str) -> tuple[str, ...]:
    """The registered sources that take the setting ``name`` (none: no source's)."""
    return tuple(
        source for source, kind in BIT_SOURCES.items() if any(s.name == name for s in kind.specs())
    )


def make_bit_source(
    name: str,
    rate_hz: int,
    window_s: float,
    on_problem: Callable[[str], None] | None = None,
    **options: Any,
) -> BitSource:
    """The bit source ``name`` for windows of ``window_s`` seconds at ``rate_hz``.

    Args:
        name: a registered name (:data:`BIT_SOURCES`).
        rate_hz: sample rate of the windows, Hz.
        window_s: window length, seconds.
        on_problem: told (one line) why a calibration was refused; None: not told.
        **options: the source's settings (named as mic_node's parameters); missing ones
            take their defaults.

    Raises:
        AudioError: an unknown source or option, or a bad value (one line naming it).
    """
    source = bit_source_class(name)
    rate_hz = check_rate(rate_hz, "rate_hz")
    window_s = check_positive_seconds(window_s, "window_s")
    settings = source.make_settings(options)
    source.check_settings(settings, rate_hz, window_s)
    return source(settings, rate_hz, window_s, on_problem)


def level_source_class(name: str) -> type[LevelSource]:
    """The registered threshold source ``name``; AudioError if it has no threshold."""
    source = bit_source_class(name)
    if not issubclass(source, LevelSource):
        levels = [n for n, s in BIT_SOURCES.items() if issubclass(s, LevelSource)]
        raise AudioError(
            f"bit source {name!r} has no threshold to calibrate; {' and '.join(levels)} have"
        )
    return source


class WindowLevels:
    """The levels (dB) a threshold of source ``name`` applies to, for windows in order.

    For calibration audio (a file, a recording): a speech-band filter starts from rest and
    carries over from call to call, as in a stream.

    Raises:
        AudioError: ``name`` has no threshold (``vad``) or is unknown.
    """

    def __init__(self, name: str, rate_hz: int) -> None:
        self.name = name
        self._meter = level_source_class(name).window_levels(rate_hz)

    def levels_db(self, windows: ArrayLike) -> NDArray[np.float64]:
        """Levels of the next windows (one per row), dB; AudioError for bad samples."""
        return levels_db(self._meter, windows)


def window_levels_db(name: str, windows: ArrayLike, rate_hz: int) -> NDArray[np.float64]:
    """:class:`WindowLevels` of windows read ahead (one per row), from a filter at rest."""
    return WindowLevels(name, rate_hz).levels_db(windows)


__all__ = [
    "BIT_SOURCES",
    "DEFAULT_BIT_SOURCE",
    "BitSource",
    "WindowLevels",
    "all_setting_specs",
    "bit_source_class",
    "make_bit_source",
    "window_levels_db",
]

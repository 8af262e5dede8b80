"""A bit source written as docs/ARCHITECTURE.md says a new one is: one class, one registry line.

``toy``: a window is sound when its energy is above ``toy_level_db`` (a live setting).
Tests register it with ``registered_toy`` (the one line, undone afterwards) and check
that mic_node, the offline loop and ``experiment rooms``' names take it unchanged.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from numpy.typing import NDArray

from infomax_contingency.audio.bitsources import BIT_SOURCES
from infomax_contingency.audio.bitsources.base import BitSource, NameArgument, setting


@dataclasses.dataclass(frozen=True)
class ToySettings:
    """The toy's one setting."""

    toy_level_db: float = setting(
        -30.0, "Energy above which a window is sound (bit_source toy; live)", low=-150.0,
        high=0.0, unit="dB", live=True,
    )


class ToySource(BitSource):
    """A window is sound when its energy is above ``toy_level_db``."""

    name = "toy"
    summary = "window energy above toy_level_db"
    Settings = ToySettings
    name_modes = {"": (NameArgument("toy_level_db", "DB"),)}

    def decide(self, x: NDArray[np.float64]) -> bool:
        return self.last_energy_db > self.settings.toy_level_db


@contextmanager
def registered_toy() -> Iterator[type[ToySource]]:
    """The toy in the registry (one line), for the time of a test."""
    BIT_SOURCES[ToySource.name] = ToySource
    try:
        yield ToySource
    finally:
        del BIT_SOURCES[ToySource.name]

"""The fields of the stamped step messages and their validity rules (no ROS).

``sound_step`` carries ``[stream, step, bit, window_us, withheld]`` and ``vocalize_step``
``[stream, step, vocalize, controller]`` (see :mod:`~infomax_contingency.nodes.step_topics`,
which wraps these rules for the live nodes). A message that breaks them (too few or too
many fields, an id or step not positive, a bit not 0 or 1, a window not positive) is
malformed: the live nodes ignore it, and so do the readers of recorded sessions
(:func:`valid_messages`), which say how many they skipped.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import NamedTuple, TypeVar

from infomax_contingency.core.model import Withheld

SOUND_FIELDS = ("stream", "step", "bit", "window_us", "withheld")
"""The fields of a ``sound_step`` message (the last may be absent: an old recording)."""
VOCALIZE_FIELDS = ("stream", "step", "vocalize", "controller")
"""The fields of a ``vocalize_step`` message."""

T = TypeVar("T")


class StepBit(NamedTuple):
    """A bit with its identity; ``withheld``: the robot's own sound, or right after a gap."""

    stream: int
    step: int
    bit: bool
    window_us: int
    withheld: bool = False

    @property
    def observation(self) -> bool | Withheld:
        """What a statistic takes: the bit, or the bit :class:`Withheld`."""
        return Withheld(self.bit) if self.withheld else self.bit


class StepDecision(NamedTuple):
    """A decision with the identity of the bit it answers."""

    stream: int
    step: int
    vocalize: bool
    controller: int


def window_us(window_s: float) -> int:
    """A window length in whole microseconds (how ``sound_step`` carries it)."""
    return round(window_s * 1e6)


def _fields(values: Sequence[int], *sizes: int) -> list[int] | None:
    data = [int(v) for v in values]
    if len(data) not in sizes or data[0] <= 0 or data[1] <= 0 or data[2] not in (0, 1):
        return None
    return data


def bit_of(values: Sequence[int]) -> StepBit | None:
    """The bit in a ``sound_step`` message's fields, or None if they are malformed.

    Four fields (a recording made before ``withheld``) are a window not withheld.
    """
    data = _fields(values, len(SOUND_FIELDS) - 1, len(SOUND_FIELDS))
    if data is None or data[3] <= 0 or data[4:] not in ([], [0], [1]):
        return None
    return StepBit(data[0], data[1], bool(data[2]), data[3], bool(data[4:] == [1]))


def decision_of(values: Sequence[int]) -> StepDecision | None:
    """The decision in a ``vocalize_step`` message's fields, or None if they are malformed."""
    data = _fields(values, len(VOCALIZE_FIELDS))
    if data is None or data[3] <= 0:
        return None
    return StepDecision(data[0], data[1], bool(data[2]), data[3])


def valid_messages(messages: Iterable[tuple[int, Sequence[int]]],
                   parse: Callable[[Sequence[int]], T | None], topic: str,
                   warn: Callable[[str], None] | None) -> list[tuple[int, T]]:
    """``(stamp, parsed)`` of the well-formed messages among ``(stamp, fields)``, in order.

    ``parse`` is :func:`bit_of` or :func:`decision_of`; the malformed messages are
    skipped, as the live nodes ignore them, and ``warn`` is told how many (one line).
    """
    taken: list[tuple[int, T]] = []
    skipped = 0
    for stamp, values in messages:
        parsed = parse(values)
        if parsed is None:
            skipped += 1
        else:
            taken.append((stamp, parsed))
    if skipped and warn is not None:
        fields = SOUND_FIELDS if parse is bit_of else VOCALIZE_FIELDS
        warn(f"{topic}: skipped {skipped} malformed message(s) (not [{', '.join(fields)}]"
             " with valid values), as the live nodes ignore them")
    return taken

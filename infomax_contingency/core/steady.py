"""Inputs that arrive steadily: when one that came stops, and when it is back.

A node's steady inputs (mic_node's ``audio``, the step topics, ``belief``) come every
window or faster once they have started. :class:`SteadyInputs` tells, from the arrival
times a node gives it (seconds of any monotonic clock), when one of them has been silent
longer than its bound, and when it came back. The bound is ``floor_s`` (a few seconds),
or :data:`SILENCE_INTERVALS` times the input's usual interval when that is longer (the
median of its recent intervals: a room paced slower than real time, audio in chunks of
many seconds), so that the pace of a healthy input never looks like a stop. Before its
second message an input is not judged here (the node's notice of what it waits for says
what has not come). Messages on an input's companions count as its own once its own
first came: mic_node says on ``no_step`` each window that gives no step (its bit source
calibrating or warming up), so the steps that pause meanwhile have not stopped; before,
they say its source is alive (:meth:`SteadyInputs.heard`).

No clock, no I/O: the node asks with its own times and logs what it is told.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field

SILENCE_INTERVALS = 4.0
"""An input is silent after this many usual intervals without a message (if over the floor)."""

USUAL_INTERVALS = 16
"""The usual interval of an input is the median of this many of its recent intervals."""



@dataclass
class _Input:
    """One watched input: its last message and recent intervals (s)."""

    last_s: float | None = None
    """Its last message (or a companion's, once its own first came)."""
    intervals: deque[float] = field(default_factory=lambda: deque(maxlen=USUAL_INTERVALS))
    silent: bool = False
    """Said to be silent, and nothing has come since."""
    companion_heard: bool = False
    """A companion's message came (its source is alive), whether or not its own did."""


class SteadyInputs:
    """The steady inputs of one node: which have stopped (see the module docstring).

    Args:
        floor_s: seconds without a message after which an input is silent at the least.
    """

    def __init__(self, floor_s: float) -> None:
        self.floor_s = floor_s
        self._inputs: dict[str, _Input] = {}
        self._of: dict[str, list[str]] = {}
        """Topic -> the watched inputs a message on it counts for."""
        self.stops = 0
        """Times an input was said to be silent."""

    def watch(self, topic: str, companions: tuple[str, ...] = ()) -> None:
        """Watch ``topic``; a message on one of ``companions`` counts as one of its own."""
        self._inputs.setdefault(topic, _Input())
        for name in (topic, *companions):
            self._of.setdefault(name, []).append(topic)

    def arrived(self, topic: str, now_s: float) -> list[tuple[str, float]]:
        """Note a message on ``topic`` at ``now_s``.

        Returns the watched inputs it counts for that had been said to be silent, each
        with the seconds it was silent (their messages are back).
        """
        back = []
        for name in self._of.get(topic, ()):
            watched = self._inputs[name]
            if name != topic:
                watched.companion_heard = True
                if watched.last_s is None:  # not judged before its own first message
                    continue
            if watched.last_s is not None:
                gap_s = now_s - watched.last_s
                watched.intervals.append(gap_s)  # a pace that slowed for good is learnt
                if watched.silent:
                    back.append((name, gap_s))
            watched.last_s, watched.silent = now_s, False
        return back

    def bound_s(self, topic: str) -> float:
        """Seconds without a message after which ``topic`` is silent (inf: not judged yet).

        Judged from its second message on: one interval already shows its pace.
        """
        intervals = self._inputs[topic].intervals
        if not intervals:
            return math.inf
        return max(self.floor_s, SILENCE_INTERVALS * statistics.median(intervals))

    def heard(self, topic: str) -> bool:
        """A message came on ``topic`` or on one of its companions (its source is alive)."""
        watched = self._inputs.get(topic)
        return watched is not None and (watched.last_s is not None or watched.companion_heard)

    def newly_silent(self, now_s: float) -> list[tuple[str, float]]:
        """Inputs silent past their bound at ``now_s`` and not said before: (topic, seconds)."""
        found = []
        for topic, watched in self._inputs.items():
            if watched.silent or watched.last_s is None:
                continue
            silent_s = now_s - watched.last_s
            if silent_s > self.bound_s(topic):
                watched.silent = True
                self.stops += 1
                found.append((topic, silent_s))
        return found

    def silent(self, now_s: float) -> dict[str, float]:
        """Inputs said to be silent -> seconds since their last message at ``now_s``."""
        return {topic: now_s - watched.last_s for topic, watched in self._inputs.items()
                if watched.silent and watched.last_s is not None}  # fmt: skip

"""The actions file: the moments the robot's sound was commanded, as CSV.

One column with the header ``time_s``, one row per vocalization: seconds of room time
(0 at the start of the first window) at which the sound was commanded — the start of the
window after the one whose decision it was (the room plays it ``self_delay_s`` later).
Rows are in increasing order. ``room-wav`` writes it beside the room's wav, so the two
can be listened to and read together.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable

HEADER = "time_s"
"""The column's name (the file's first line)."""


def write_actions_csv(path: str | os.PathLike[str], times_s: Iterable[float]) -> None:
    """Write the vocalization times (seconds, increasing) to ``path``."""
    times = [float(t) for t in times_s]
    for earlier, later in zip(times, times[1:], strict=False):
        if not later > earlier:
            raise ValueError(f"actions must be in increasing time order: {later} after {earlier}")
    try:
        with open(path, "w", encoding="ascii") as out:
            out.write(HEADER + "\n")
            out.writelines(f"{t:.6f}\n" for t in times)
    except OSError as error:
        raise OSError(f"cannot write the actions file {path}: {error.strerror or error}") from None


def read_actions_csv(path: str | os.PathLike[str]) -> list[float]:
    """The vocalization times of an actions file; ValueError naming the file and line."""
    try:
        with open(path, encoding="ascii", errors="replace") as source:
            lines = source.read().splitlines()
    except OSError as error:
        raise OSError(f"cannot read the actions file {path}: {error.strerror or error}") from None
    if not lines or lines[0].strip() != HEADER:
        raise ValueError(f"actions file {path}: the first line must be the header {HEADER!r}")
    times: list[float] = []
    for number, line in enumerate(lines[1:], start=2):
        text = line.strip()
        if not text:
            continue
        try:
            value = float(text)
        except ValueError:
            raise ValueError(
                f"actions file {path}, line {number}: {text!r} is not a number"
            ) from None
        if not math.isfinite(value) or value < 0 or (times and value <= times[-1]):
            raise ValueError(
                f"actions file {path}, line {number}: {text} must be a finite time >= 0 s,"
                " later than the line before"
            )
        times.append(value)
    return times

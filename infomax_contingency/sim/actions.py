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

from infomax_contingency.limits import read_text_capped, written_atomically

HEADER = "time_s"
"""The column's name (the file's first line)."""
MAX_ACTIONS_BYTES = 16 << 20
"""Largest actions file read, bytes: a day of a vocalization every 0.1 s takes 11 MB."""


def write_actions_csv(path: str | os.PathLike[str], times_s: Iterable[float]) -> None:
    """Write the vocalization times (seconds, increasing) to ``path``.

    Nothing but a regular file is written over, and the file is replaced whole
    (``limits.written_atomically``: a FIFO, device or symbolic link is refused, ValueError).
    """
    times = [float(t) for t in times_s]
    for earlier, later in zip(times, times[1:], strict=False):
        if not later > earlier:
            raise ValueError(f"actions must be in increasing time order: {later} after {earlier}")
    with written_atomically(path, "actions file") as out:
        out.write("".join([HEADER + "\n", *(f"{t:.6f}\n" for t in times)]).encode("ascii"))


def read_actions_csv(path: str | os.PathLike[str]) -> list[float]:
    """The ``time_s`` column of an actions file (seconds, strictly increasing, >= 0).

    Blank lines are skipped; a byte-order mark before the header is allowed.

    Raises:
        ValueError: a missing or unreadable file, one that is not a regular file (a
            device, a FIFO) or holds more than :data:`MAX_ACTIONS_BYTES`, a header other
            than ``time_s``, a value that is not a finite number >= 0, or times that do
            not increase; the message names the file and the line.
    """
    try:
        lines = read_text_capped(path, "actions file", MAX_ACTIONS_BYTES).splitlines()
    except FileNotFoundError:
        raise ValueError(f"actions file {path} does not exist") from None
    rows = [(number, line.strip()) for number, line in enumerate(lines, 1) if line.strip()]
    if not rows or rows[0][1].lstrip("\ufeff") != HEADER:
        found = rows[0][1][:40] if rows else "an empty file"
        raise ValueError(f"actions file {path}: the first line must be the header"
                         f" '{HEADER}' (one column), found {found!r}")
    times: list[float] = []
    for number, text in rows[1:]:
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"actions file {path} line {number}: {text[:40]!r} is not a"
                             f" time in seconds (one column, {HEADER})") from None
        if not math.isfinite(value) or value < 0:
            raise ValueError(f"actions file {path} line {number}: {HEADER} must be a finite"
                             f" number >= 0, got {text[:40]!r}")
        if times and value <= times[-1]:
            raise ValueError(f"actions file {path} line {number}: {HEADER} {value:g} does not"
                             f" come after the previous {times[-1]:g} (times must increase,"
                             " each later than the one before)")
        times.append(value)
    return times

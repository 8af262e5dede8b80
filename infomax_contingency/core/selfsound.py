"""Sound the robot makes itself (speech, motors, moving its head): windows withheld.

Any node of the robot declares the sound it makes on the ``self_sound`` topic as a time
range ``[start_ns, end_ns]`` on the ROS clock (nanoseconds, ``node.get_clock().now()``;
a range may be declared ahead, e.g. a whole utterance or a head movement when it is
planned, or again and again for a sound of unknown length). A microphone window whose
time range overlaps a declared range is *withheld*: its bit is observed and published
but is no evidence (:class:`~infomax_contingency.core.model.Withheld`; exact, like a
missing bit).

Why a time range and not a Bool that is true while the sound lasts: the overlap of a
window with a range stamped by the node that makes the sound is a matter of
timestamps, so it does not depend on when the message arrives. A Bool would take effect
when it arrives, late by the DDS latency (and by any resend): the windows at the edges
would be withheld or not by chance. The microphone node holds each window's bit
``hold_s`` past the window's end (while someone publishes on ``self_sound``), so a range
published as the sound starts still reaches it in time; a range that comes later than
that cannot change a bit already published: it is counted and reported as late, never
applied silently to the wrong windows.

:class:`SelfSoundGate` holds the windows and decides; :class:`ChunkClock` gives the
windows of an audio stream that carries no timestamps (the ``audio`` topic) their time
ranges from the chunks' publication times. Times are integers in nanoseconds on one
clock, passed in by the caller: nothing here reads a clock. :class:`GapWithholding`
withholds the bits right after windows that gave no step, for another reason (the
steps' timer lagging the windows').

A withheld window is no evidence of any kind: a rule that learns from the windows
(e.g. a threshold that takes the windows the model counts as background for the
background's level) must leave withheld windows out too, as it leaves out the
self-feedback windows.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Sequence
from typing import Any, Generic, TypeVar

NS_PER_S = 1_000_000_000

MAX_RANGE_S = 600.0
"""A declared range may last at most this long (seconds): longer is taken for nonsense."""

LONG_RANGE_S = 30.0
"""A declared range longer than this (seconds) is accepted but said (WARN): every window in
it is withheld, so a wrong publisher on ``self_sound`` would silence the evidence."""

CLOCK_TOLERANCE_S = 120.0
"""A range that ends this long before, or starts this long after, the receiver's clock
(seconds) is taken as stamped on another clock (a steady clock, sim time)."""

ItemT = TypeVar("ItemT")


@dataclasses.dataclass(frozen=True)
class Withheld:
    """The bit of a window withheld from the statistic: observed, but not evidence.

    A window that overlaps sound the robot declared as its own (its speech, its motors:
    the ``self_sound`` topic) is driven by the robot, not by the room: its bit has a
    likelihood that does not depend on S, so leaving it out of the counts gives exactly
    the posterior given the other bits — the same case as a missing bit
    (:meth:`StatisticTracker.skip_observation`). The bit itself is kept for people and
    recordings. ``bool()`` of it is refused, so no code counts it by mistake.

    Attributes:
        bit: the bit the window's sound gave (True: above the threshold).
    """

    bit: bool

    def __bool__(self) -> bool:
        raise TypeError("a withheld window's bit is not evidence: use .bit to read it")


@dataclasses.dataclass(frozen=True)
class Verdict:
    """What :meth:`SelfSoundGate.declare` made of a declared range.

    Attributes:
        accepted: the range applies to the windows it overlaps that are not out yet.
        problems: ``(kind, line)`` for each thing wrong with it, one line each: refused
            (kind ``malformed``, ``reversed``, ``too long`` or ``other clock``), or accepted
            but ``long`` (over :data:`LONG_RANGE_S`) or ``late`` (or both).
        late_windows: windows already published that the range overlaps (taken as
            evidence: they cannot be withheld any more).
    """

    accepted: bool
    problems: tuple[tuple[str, str], ...] = ()
    late_windows: int = 0

    @property
    def problem(self) -> str:
        """The problems' lines in one line ("" when none)."""
        return "; ".join(line for _, line in self.problems)


@dataclasses.dataclass
class _Held(Generic[ItemT]):
    start_ns: int
    end_ns: int
    item: ItemT


class SelfSoundGate(Generic[ItemT]):
    """Windows wait here until it is known whether the robot made their sound.

    Push every window with its time range; :meth:`release` hands them back, in order,
    with ``withheld`` True where a declared range overlaps the window (ranges are
    closed ``[start, end]``, windows half-open ``[start, end)``). While ``holding`` (a
    node publishes on ``self_sound``) a window waits until ``hold_ns`` past its end;
    otherwise it goes at once.

    A window released withheld is no evidence for anything downstream: a threshold that
    learns the background's level from the windows the model counts as background (a
    self-calibrating threshold) must not take it either.

    Args:
        hold_s: seconds a window waits past its end for ranges that overlap it (the
            latency allowed from the sound's start to its declaration's arrival).
        max_range_s, clock_tolerance_s: the checks of :meth:`declare`.

    Attributes:
        declared, refused, late: counts of ranges accepted, refused and arrived late.
        withheld: windows released withheld.
        problems: the latest problems (refused or late ranges), one line each, oldest
            first.
    """

    def __init__(self, hold_s: float, max_range_s: float = MAX_RANGE_S,
                 clock_tolerance_s: float = CLOCK_TOLERANCE_S) -> None:  # fmt: skip
        if not hold_s >= 0:
            raise ValueError(f"hold_s must be >= 0 seconds, got {hold_s}")
        self.hold_ns = round(hold_s * NS_PER_S)
        self.max_range_ns = round(max_range_s * NS_PER_S)
        self.tolerance_ns = round(clock_tolerance_s * NS_PER_S)
        self._ranges: list[tuple[int, int]] = []
        self._waiting: deque[_Held[ItemT]] = deque()
        self._released: deque[tuple[int, int]] = deque(maxlen=4096)
        """Time ranges of the windows released lately (to tell how late a range is)."""
        self.declared = 0
        self.refused = 0
        self.late = 0
        self.long = 0
        """Ranges accepted that last longer than :data:`LONG_RANGE_S` (each said)."""
        self.withheld = 0
        self.problems: deque[str] = deque(maxlen=16)

    @property
    def waiting(self) -> int:
        """Windows held."""
        return len(self._waiting)

    def declare_fields(self, fields: Sequence[int], now_ns: int) -> Verdict:
        """A ``self_sound`` message's fields (``[start_ns, end_ns]``), received at ``now_ns``."""
        if len(fields) != 2:
            return self._refuse("malformed", f"'self_sound' message refused: {list(fields)}"
                                " (expected [start_ns, end_ns] on the ROS clock)")  # fmt: skip
        return self.declare(int(fields[0]), int(fields[1]), now_ns)

    def _refuse(self, kind: str, problem: str) -> Verdict:
        self.refused += 1
        self.problems.append(problem)
        return Verdict(False, ((kind, problem),))

    def declare(self, start_ns: int, end_ns: int, now_ns: int) -> Verdict:
        """A node declared the robot's sound over ``[start_ns, end_ns]``, received at ``now_ns``.

        A range both long and late is said as both (and counted as both).
        """
        refusal = self._check(start_ns, end_ns, now_ns)
        if refusal:
            return self._refuse(*refusal)
        self.declared += 1
        self._ranges.append((start_ns, end_ns))
        problems = []
        if end_ns - start_ns > LONG_RANGE_S * NS_PER_S:
            self.long += 1
            problems.append(("long", (
                f"self-sound [{start_ns}, {end_ns}] ns declares"
                f" {(end_ns - start_ns) / NS_PER_S:.1f} s of the robot's own sound: every"
                " window in it is withheld, counted by no one (if that is not the robot's"
                " sound, a publisher on 'self_sound' is wrong)")))  # fmt: skip
        late = sum(1 for ws, we in self._released if start_ns < we and ws <= end_ns)
        if late:
            self.late += 1
            overlap_end = self._first_overlap_end(start_ns, end_ns)
            delay_s = (now_ns - max(start_ns, overlap_end)) / NS_PER_S
            problems.append(("late", (
                f"self-sound [{start_ns}, {end_ns}] ns arrived {delay_s:.3f} s after the end of"
                f" a window it overlaps: {late} window(s) already published were counted as"
                f" evidence (declare the sound when it starts, or raise the hold of"
                f" {self.hold_ns / NS_PER_S:g} s)")))  # fmt: skip
        self.problems.extend(line for _, line in problems)
        return Verdict(True, tuple(problems), late)

    def _first_overlap_end(self, start_ns: int, end_ns: int) -> int:
        return min(we for ws, we in self._released if start_ns < we and ws <= end_ns)

    def _check(self, start_ns: int, end_ns: int, now_ns: int) -> tuple[str, str] | None:
        """None for a range that may be applied, else ``(kind, line)`` of why it is refused."""
        if start_ns <= 0 or end_ns < start_ns:
            return "reversed", (f"self-sound range [{start_ns}, {end_ns}] ns refused: it must"
                                " be [start_ns, end_ns] with 0 < start_ns <= end_ns")  # fmt: skip
        if end_ns - start_ns > self.max_range_ns:
            return "too long", (
                f"self-sound range [{start_ns}, {end_ns}] ns refused: it lasts"
                f" {(end_ns - start_ns) / NS_PER_S:g} s, more than"
                f" {self.max_range_ns / NS_PER_S:g} s (declare a long sound again and"
                " again, a few seconds ahead)")  # fmt: skip
        if end_ns < now_ns - self.tolerance_ns or start_ns > now_ns + self.tolerance_ns:
            off_s = ((start_ns if start_ns > now_ns else end_ns) - now_ns) / NS_PER_S
            return "other clock", (
                f"self-sound range [{start_ns}, {end_ns}] ns refused: it lies {off_s:+.1f} s"
                " from this node's ROS clock: stamped on another clock? Stamp it with"
                " node.get_clock().now() (ROS time; sim time only if every node uses it)")
        return None

    def push(self, start_ns: int, end_ns: int, item: ItemT) -> None:
        """A window of ``[start_ns, end_ns)`` was made; it waits in order."""
        self._waiting.append(_Held(start_ns, end_ns, item))

    def release(self, now_ns: int, holding: bool) -> list[tuple[ItemT, bool]]:
        """The windows that may go now, oldest first, each with ``withheld``.

        ``holding``: wait ``hold_s`` past a window's end (someone declares self-sound);
        False releases every window at once.
        """
        out: list[tuple[ItemT, bool]] = []
        while self._waiting:
            window = self._waiting[0]
            if holding and now_ns < window.end_ns + self.hold_ns:
                break
            self._waiting.popleft()
            withheld = self.overlaps(window.start_ns, window.end_ns)
            self.withheld += withheld
            self._released.append((window.start_ns, window.end_ns))
            out.append((window.item, withheld))
            self._ranges = [(s, e) for s, e in self._ranges if e >= window.start_ns]
        return out

    def overlaps(self, start_ns: int, end_ns: int) -> bool:
        """Does a declared range overlap the window ``[start_ns, end_ns)``."""
        return any(s < end_ns and start_ns <= e for s, e in self._ranges)


class ChunkClock:
    """Time ranges of the windows of a stream of chunks that carry no timestamps.

    A chunk published at ``end_ns`` (its publication time: an audio driver publishes a
    chunk right after its last sample) is taken to hold the sound since the previous
    chunk's publication, its samples spread evenly over that time; the first chunk (and
    the first after :meth:`reset`, a gap) covers its own length at the sample rate
    before ``end_ns``. So a live driver's windows get their capture times, and a
    simulated room that publishes one window at a time, faster than real time, gets
    windows that follow each other without overlap.

    Args:
        rate_hz: samples per second of the stream.
    """

    def __init__(self, rate_hz: int) -> None:
        self.rate_hz = rate_hz
        self.reset()

    def reset(self) -> None:
        """A gap in the stream: sample counting starts again from 0."""
        self._chunks: deque[tuple[int, int, int, int]] = deque()
        """(first sample, samples, start ns, end ns) of the recent chunks."""
        self._next_sample = 0
        self._last_end_ns: int | None = None

    def add(self, samples: int, end_ns: int) -> None:
        """A chunk of ``samples`` published at ``end_ns``."""
        if samples <= 0:
            return
        own_ns = round(samples * NS_PER_S / self.rate_hz)
        start_ns = end_ns - own_ns if self._last_end_ns is None else self._last_end_ns
        start_ns = min(start_ns, end_ns)
        self._chunks.append((self._next_sample, samples, start_ns, end_ns))
        self._next_sample += samples
        self._last_end_ns = max(end_ns, self._last_end_ns or end_ns)

    def time_ns(self, sample: int) -> int:
        """The time at the start of ``sample`` (sample counts since the last reset)."""
        for first, count, start_ns, end_ns in self._chunks:
            if first <= sample <= first + count:
                return start_ns + (end_ns - start_ns) * (sample - first) // count
        raise ValueError(f"sample {sample} is not in the chunks kept")

    def window_ns(self, first_sample: int, samples: int) -> tuple[int, int]:
        """``[start_ns, end_ns)`` of the window of ``samples`` from ``first_sample``.

        Chunks that end before the window are forgotten (windows are asked in order).
        """
        while self._chunks and self._chunks[0][0] + self._chunks[0][1] <= first_sample:
            if len(self._chunks) == 1:
                break
            self._chunks.popleft()
        return self.time_ns(first_sample), self.time_ns(first_sample + samples)


def describe(gate: SelfSoundGate[Any]) -> dict[str, Any]:
    """The gate's counts (and its latest problem, if any) for diagnostics."""
    values = {"self_sound_declared": gate.declared, "self_sound_refused": gate.refused,
              "self_sound_late": gate.late, "self_sound_long": gate.long,
              "withheld_windows": gate.withheld,
              "windows_held": gate.waiting}  # fmt: skip
    if gate.problems:
        values["self_sound_last_problem"] = gate.problems[-1]
    return values


class GapWithholding:
    """Bits withheld right after a gap: windows without a step, lost or dropped.

    The controller and the belief count steps; the model's timer counts windows. After
    windows that gave no step (a bit source calibrating again, a threshold out of range),
    audio lost between windows, or windows dropped before they got a step, a step's timer
    lags its window's: a step within ``steps`` (``ta2 + 1``) of a vocalization decided
    before the gap would be counted in the robot's own sound or the agent period though
    its window is later. Those bits are withheld (no one counts them, exactly as the
    robot's own sound); from then on the steps' timer is the windows' again.

    Call :meth:`bit` for each step in order (``gap_before``: a gap came right before its
    window; or :meth:`no_step` for each window without a step, where windows are handled
    in their order) and :meth:`decided` with each decision when it is known. With the decisions
    on every step before the gap known, exactly the steps whose timer could lag are
    withheld (none if no vocalization came in the last ``steps`` steps); otherwise
    ``steps`` bits. A vocalization decided on a step after the gap ends the withholding
    (both timers are 0 after it). A gap before the first bit is none: both timers are
    "long ago" then.

    Pure bookkeeping: mic_node and the offline loop
    (:class:`~infomax_contingency.sim.audio_loop.AudioWorld`) use it alike.
    """

    def __init__(self, steps: int) -> None:
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ValueError(f"steps must be a whole number >= 1, got {steps!r}")
        self.steps = steps
        self.bits = 0
        """Steps given so far (the last one's number)."""
        self.withheld = 0
        """Bits withheld because they came right after a gap."""
        self.gaps = 0
        """Gaps after the first bit."""
        self._left = 0  # bits still to withhold
        self._first_after_gap = 0  # the step of the first bit after the last gap
        self._decided = 0  # the highest step whose decision came
        self._vocalized: int | None = None  # the last step decided with a vocalization
        self._lost: int | None = None  # the last step whose decision was lost
        self._no_step = False  # a window gave no step since the last bit

    def no_step(self) -> None:
        """A window gave no step: a gap before the next bit."""
        self._no_step = True

    def bit(self, gap_before: bool = False) -> bool:
        """The next step's bit; True if it is withheld.

        ``gap_before``: windows gave no step, were lost or dropped right before its window
        (also true after :meth:`no_step`).
        """
        gap_before, self._no_step = gap_before or self._no_step, False
        if gap_before and self.bits:
            self.gaps += 1
            self._first_after_gap = self.bits + 1
            self._left = self._lagging_steps()
        self.bits += 1
        if not self._left:
            return False
        self._left -= 1
        self.withheld += 1
        return True

    def decided(self, step: int, u: int | None) -> None:
        """The decision on ``step`` (1: vocalize, 0: not, None: lost), in step order."""
        if u is None:
            self._lost = step
        elif u:
            self._vocalized = step
            if self._first_after_gap and step >= self._first_after_gap:
                self._left = 0  # both timers are 0 from the next step on
        self._decided = max(self._decided, step)

    def _lagging_steps(self) -> int:
        """Steps from the next one whose timer may lag their window's."""
        known = self._decided >= self.bits and (
            self._lost is None or (self._vocalized is not None and self._lost < self._vocalized)
        )
        if not known:
            return self.steps
        if self._vocalized is None:
            return 0
        # the step after a vocalization decided on step v has timer 0: step s has s - v - 1,
        # which lags while it is at most ta2 (s <= v + steps)
        return max(0, self._vocalized + self.steps - self.bits)

"""A threshold the model calibrates itself: a constant false-alarm rate on background windows.

The model already says which windows are *background* whatever S is: the windows whose
timer is past the agent period (``z > ta2``; the timer starts "long ago", so every window
before the first vocalization is one). Their levels are labelled data about the room, in
every room, with nobody speaking on cue. :class:`BackgroundThreshold` sets the threshold
of window ``t`` at the ``k``-th largest level of the last ``history`` background windows
among windows ``t - delay`` and earlier (labelled before ``t``). For exchangeable
background levels (a steady room) a new background window exceeds the ``k``-th largest
of ``n`` others with probability exactly ``k / (n + 1)`` (ties only lower it): the
false-alarm rate — the model's K3 — is chosen, not found, in every room. ``k`` is the
largest whole number with ``k / (n + 1) <= false_alarm`` (at least 1, so while fewer
than ``1 / false_alarm - 1`` background windows are known the rate is ``1 / (n + 1)``,
higher than asked: :attr:`false_alarm_now`).
When the room gets louder the threshold follows within ``delay + k`` windows; when it
gets quieter, once the loud windows have left the last ``history``.

Why the delay (``ta2 + 1`` windows by default): an agent-period window's threshold can
only come from background windows before the vocalization, ``z + 1`` windows back; if a
background window's came from the window just before it, the threshold would catch up
with a sound that starts (a burst of typing, a TV stretch) during background windows but
not during agent windows, and agent windows would be active more often than background
windows *in an empty room*: evidence for a partner that is not there. With every
window's threshold equally old, the sound's onsets fall alike on both.

Labels come from the decisions. :meth:`BackgroundThreshold.note_decision` takes each
decision (1 = vocalize) on the windows that gave a bit, in order; a window that gave no
bit (the warm-up) had none (the timer runs on). A window is labelled once every decision
before it is known, so its label never depends on a guess: in the lockstep loop (the
offline loop, a wav or bag replay, the fake room) the decision on window t arrives
before window t + 1, and a window is labelled when it comes; live, a late decision only
delays the labels of the windows after it. A lost decision (``None``) leaves the timer
unknown until the next vocalization, or until ``ta2 + 1`` silent decisions put any
vocalization before them past the agent period; windows of unknown timer are never used.
A rule made anew in a session (:meth:`BackgroundSource.recalibrate`) starts so too.
Self-feedback windows (``ts1 <= z <= ts2``) and agent-period windows never set the
threshold; self-feedback windows are watched for one diagnostic (below).

Diagnostics (:meth:`BackgroundThreshold.problems`: one line each; the bits are never
made up): digital silence (a window of level <= :data:`SILENCE_DB`: bit 0; as a background
window it counts at its level, so a noise-gated microphone, all zeros between sounds,
gets a threshold: while fewer than a ``false_alarm`` share of the background windows hold
sound, any sound the gate lets through is active; else the threshold is their loudest
share's level, as in any room. Before the first window with sound it is not the room: a
recording that starts with zeros, an input not yet live; those windows never set the
threshold, so the warm-up is heard on sound, and an input that is dead from the start
gives no bit at all); a room as loud as
the robot's own sound (the robot's self-feedback windows exceed the threshold in less
than half of the last ones: its chirps are not heard above the room, detection will be
slow or impossible); decisions that never came. A level that is NaN or infinite is
refused (AudioError). Clipping and DC offset are properties of samples:
:func:`window_faults`.

Pure computation (no clocks, no I/O, no rclpy). Levels in dB full scale.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.energy import ENERGY_FLOOR, ENERGY_FLOOR_DB
from infomax_contingency.audio.threshold import ThresholdRangeGuard

SILENCE_DB = ENERGY_FLOOR_DB + 1.0
"""Window levels at or below this are digital silence (all samples zero, or one constant), dB."""

CLIPPED_SAMPLE = 0.999
"""A sample at or beyond this magnitude (full scale 1) counts as clipped."""
CLIPPED_SHARE = 0.001
"""A window with more than this share of clipped samples is clipping."""
DC_SHARE = 0.5
"""A window whose mean carries more than this share of its energy has a DC offset."""
SELF_WINDOWS_WATCHED = 10
"""Self-feedback windows the "room louder than the robot" diagnostic looks at."""

WARMING_UP = "calibrating"
"""State while too few background windows are known (no bit)."""
READY = "ready"
"""State once the threshold is set (every window gets a bit)."""
OUT_OF_RANGE = "out_of_range"
"""State while the threshold lies outside the ``threshold_db`` parameter's range (no bit)."""


class WindowFaults(NamedTuple):
    """What is wrong with a window's samples (all False: nothing).

    Attributes:
        clipped: more than :data:`CLIPPED_SHARE` of the samples at full scale.
        dc_offset: the window's mean carries more than :data:`DC_SHARE` of its energy.
        silent: every sample is zero.
    """

    clipped: bool
    dc_offset: bool
    silent: bool


def window_faults(samples: NDArray[np.float64]) -> WindowFaults:
    """Clipping, DC offset and digital silence of one window of mono samples."""
    return level_and_faults(samples)[1]


def level_and_faults(samples: NDArray[np.float64]) -> tuple[float, WindowFaults]:
    """The window's energy without its mean, dB, and its faults (one pass of sums).

    The level is ``10 log10(mean(x**2) - mean(x)**2 + ENERGY_FLOOR)``: the energy of the
    window with its DC removed (:data:`~infomax_contingency.audio.energy.ENERGY_FLOOR` as
    in every energy).
    """
    n = samples.size
    if n == 0:
        return ENERGY_FLOOR_DB, WindowFaults(False, False, True)
    mean_square = float(np.dot(samples, samples)) / n
    mean = float(samples.sum()) / n
    clipped = False
    if samples.max() >= CLIPPED_SAMPLE or samples.min() <= -CLIPPED_SAMPLE:
        clipped = np.count_nonzero(np.abs(samples) >= CLIPPED_SAMPLE) > CLIPPED_SHARE * n
    alternating = max(mean_square - mean * mean, 0.0)
    faults = WindowFaults(
        bool(clipped), mean_square > 0 and mean * mean > DC_SHARE * mean_square, mean_square == 0
    )
    return 10.0 * math.log10(alternating + ENERGY_FLOOR), faults


DEAD_INPUT_S = 10.0
"""Digital silence this long (s) is said: a muted or unplugged microphone, a dead stream."""


class DigitalSilenceWatch:
    """Says when the input turns to digital silence for a while, and when sound comes back.

    Digital silence: a window whose level without its mean is at most :data:`SILENCE_DB`
    (every sample zero, or one constant value). A noise gate closed that long is said too.

    Args:
        window_s: window length, s.
        after_s: consecutive seconds of digital silence that make the input dead.
    """

    def __init__(self, window_s: float, after_s: float = DEAD_INPUT_S) -> None:
        self.window_s = window_s
        self.after_windows = max(1, round(after_s / window_s))
        self.silent_run = 0
        """Consecutive windows of digital silence up to the last one."""

    @property
    def dead(self) -> bool:
        """True while the last :attr:`after_windows` windows or more were digital silence."""
        return self.silent_run >= self.after_windows

    def message(self) -> str:
        """What the silence means, in one line (while :attr:`dead`)."""
        return (f"the input has been digital silence for {self.silent_run * self.window_s:g} s"
                " (every sample zero or one constant value): a muted or unplugged microphone,"
                " a dead audio stream, or a noise gate closed")  # fmt: skip

    def push(self, samples: NDArray[np.float64] | None, energy_db: float) -> str | None:
        """Watch a window (its samples, or only its energy in dB when they are not kept).

        Returns a line when the input just turned dead (:meth:`message`) or sound came
        back after it had; else None.
        """
        level = energy_db if samples is None else level_and_faults(samples)[0]
        if level <= SILENCE_DB:
            self.silent_run += 1
            return self.message() if self.silent_run == self.after_windows else None
        silence_s, was_dead = self.silent_run * self.window_s, self.dead
        self.silent_run = 0
        return f"sound again after {silence_s:g} s of digital silence" if was_dead else None


def _check_settings(false_alarm: float, history: int, warmup_windows: int, max_undecided: int
                    ) -> None:
    """AudioError naming the first setting of :class:`BackgroundThreshold` that is wrong."""
    if isinstance(false_alarm, bool) or not isinstance(false_alarm, int | float):
        raise AudioError(f"false_alarm must be a number in (0, 0.5], got {false_alarm!r}")
    if not 0.0 < false_alarm <= 0.5:
        raise AudioError(f"false_alarm must be in (0, 0.5], got {false_alarm!r}")
    for name, value, least in (
        ("history", history, 2),
        ("warmup_windows", warmup_windows, 1),
        ("max_undecided", max_undecided, 1),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or value < least:
            raise AudioError(f"{name} must be a whole number >= {least}, got {value!r}")
    if warmup_windows > history:
        raise AudioError(f"warmup_windows ({warmup_windows}) must not exceed history ({history})")


def _check_margin(name: str, margin_db: float) -> None:
    """AudioError unless ``margin_db`` is a finite number >= 0."""
    if isinstance(margin_db, bool) or not isinstance(margin_db, int | float):
        raise AudioError(f"{name} must be a finite number >= 0 dB, got {margin_db!r}")
    if not (math.isfinite(margin_db) and margin_db >= 0):
        raise AudioError(f"{name} must be a finite number >= 0 dB, got {margin_db!r}")


def ordinal(k: int) -> str:
    """``1st``, ``2nd``, ``3rd``, ``4th``, ... ``11th``, ``21st``."""
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"


def rank_for(false_alarm: float, known: int, least: int = 1) -> int:
    """``k`` of the threshold among ``known`` background windows.

    The largest whole number with ``k / (known + 1) <= false_alarm``, at least ``least``
    (and at most ``known``).
    """
    return min(max(1, known), max(least, math.floor(false_alarm * (known + 1) + 1e-9)))


class BackgroundThreshold:
    """Window level to bit at a constant false-alarm rate on the model's background windows.

    Args:
        ts1, ts2: the self-feedback period (timer values), steps.
        ta2: the last timer value of the agent period, steps; background is ``z > ta2``.
        delay: window ``t``'s threshold uses background windows ``t - delay`` and earlier
            (default ``ta2 + 1``: as old for every window as for the last agent window).
        false_alarm: the share of background windows that should be active (0 < it < 1).
        history: background windows the threshold is taken over (the last ones).
        warmup_windows: background windows needed before the first bit (>= 1).
        margin_db: added to the order statistic, dB (>= 0; 0: the pure rank rule).
        max_undecided: windows that may wait for their decisions; beyond it the oldest
            awaited decision is taken as lost (counted in :attr:`decisions_lost`).
        ta1: the first timer value of the agent period (default ``ts2 + 1``).
        reference: hold every window to the level of an earlier window too
            (:meth:`reference_db`).
        reference_margin_db: by this much, dB.
        least_rank: ``k`` is at least this (2: the loudest background window alone, a
            door slam, never sets the threshold; the false-alarm share is then
            ``2 / (n + 1)`` until ``n + 1 >= 2 / false_alarm``).
        timer_known: False for a rule made in a session (a recalibration): the timer is
            unknown until a vocalization or ``ta2 + 1`` silent decisions.

    It has the attributes of :class:`~infomax_contingency.audio.bitsources.rules.Binarizer` a
    node reports (``threshold_db``, ``state``, ``calibrating``, ``calibration_problem``,
    refit and failure counts, which stay 0).
    """

    def __init__(
        self,
        ts1: int,
        ts2: int,
        ta2: int,
        false_alarm: float = 0.05,
        history: int = 60,
        warmup_windows: int = 8,
        margin_db: float = 0.0,
        max_undecided: int = 240,
        delay: int | None = None,
        ta1: int | None = None,
        reference: bool = True,
        reference_margin_db: float = 0.0,
        least_rank: int = 1,
        on_problem: Callable[[str], None] | None = None,
        timer_known: bool = True,
    ) -> None:
        _check_settings(false_alarm, history, warmup_windows, max_undecided)
        _check_margin("margin_db", margin_db)
        _check_margin("reference_margin_db", reference_margin_db)
        if not 0 <= ts1 <= ts2 < ta2:
            raise AudioError(f"need 0 <= ts1 <= ts2 < ta2, got {ts1}, {ts2}, {ta2}")
        self.ts1, self.ts2, self.ta2 = ts1, ts2, ta2
        delay = ta2 + 1 if delay is None else delay
        if isinstance(delay, bool) or not isinstance(delay, int) or delay < 1:
            raise AudioError(f"delay must be a whole number of windows >= 1, got {delay!r}")
        self.delay = delay
        self.ta1 = ts2 + 1 if ta1 is None else ta1
        if not ts2 < self.ta1 <= ta2:
            raise AudioError(f"need ts2 < ta1 <= ta2, got {ts2}, {self.ta1}, {ta2}")
        self.reference = bool(reference)
        self.reference_margin_db = float(reference_margin_db)
        if isinstance(least_rank, bool) or not isinstance(least_rank, int) or least_rank < 1:
            raise AudioError(f"least_rank must be a whole number >= 1, got {least_rank!r}")
        self.least_rank = least_rank
        self._recent: deque[tuple[float, int | None]] = deque(maxlen=ta2 + ts2 + 3)  # level, z
        self.false_alarm = float(false_alarm)
        self.history = history
        self.warmup_windows = warmup_windows
        self.margin_db = float(margin_db)
        self.max_undecided = max_undecided
        self._labelled_background: deque[tuple[int, float]] = deque(maxlen=history + delay)
        self._index = 0  # index of the next window pushed
        self._first_waiting = 0  # index of the first window not yet done with
        self._z: int | None = ta2 + 1 if timer_known else None  # the next label's timer
        self._silent_since_unknown = 0
        # (level, awaits a decision, labelled, the decision if given with the window)
        self._waiting: deque[tuple[float, bool, bool, int | None]] = deque()
        self._decisions: deque[int | None] = deque()
        self._withheld: set[int] = set()  # windows of the robot's own sound, not yet labelled
        self._self_exceeded: deque[bool] = deque(maxlen=SELF_WINDOWS_WATCHED)
        self._first_sound: int | None = None  # index of the first window above SILENCE_DB
        self.windows = self.silent_windows = self.decisions_lost = 0
        self.labelled = {"background": 0, "agent": 0, "self": 0, "unknown": 0}
        """Windows labelled so far, by what their timer said."""
        self.range_guard = ThresholdRangeGuard("background threshold", on_problem)
        """Holds the threshold to the ``threshold_db`` parameter's range (no bit outside)."""
        self.fit = None
        self.refits_accepted = self.refits_rejected = self.calibration_failures = 0

    @property
    def calibration_problem(self) -> str:
        """Why windows give no bit now ("" if they do, or while warming up)."""
        return self.range_guard.problem

    # ---------------------------------------------------------------- the threshold

    @property
    def background(self) -> list[float]:
        """Levels (dB) the next window's threshold is taken from, oldest first.

        The last ``history`` background windows among those ``delay`` or more windows
        before it.
        """
        last = self._index - self.delay
        usable = [level for index, level in self._labelled_background if index <= last]
        return usable[-self.history :]

    @property
    def rank(self) -> int:
        """``k`` of the threshold now (:func:`rank_for` of the background windows known)."""
        return rank_for(self.false_alarm, len(self.background), self.least_rank)

    @property
    def false_alarm_now(self) -> float | None:
        """``k / (n + 1)``: the false-alarm rate the threshold now gives a steady room."""
        if self.calibrating:
            return None
        return self.rank / (len(self.background) + 1)

    @property
    def threshold_db(self) -> float | None:
        """The next window's threshold, dB; None while warming up."""
        if self.calibrating:
            return None
        known = self.background
        kth = heapq.nlargest(rank_for(self.false_alarm, len(known), self.least_rank), known)[-1]
        return kth + self.margin_db

    @property
    def windows_before_first_bit(self) -> int:
        """Windows that give no bit when every one is background: the warm-up, then the delay."""
        return self.warmup_windows + self.delay - 1

    @property
    def calibrating(self) -> bool:
        """True until ``warmup_windows`` background windows are known."""
        return len(self.background) < self.warmup_windows

    @property
    def state(self) -> str:
        """``"calibrating"`` (warm-up), ``"out_of_range"`` (no bits: range_guard), ``"ready"``."""
        if self.range_guard.problem:
            return OUT_OF_RANGE
        return WARMING_UP if self.calibrating else READY

    def push(self, level_db: float, decision: int | None = None) -> bool | None:
        """The bit of the next window from its level (dB); None during the warm-up.

        The threshold is that of the background windows labelled before this one; the
        window itself is labelled now or, live, once the decisions before it are known.
        ``decision``: the decision taken after this window when it is known already (a
        recording replayed with its actions: then every window, warm-up included, has
        one and :meth:`note_decision` is not called for it).
        """
        if decision is not None and decision not in (0, 1):
            raise AudioError(f"a decision is 0 or 1, got {decision!r}")
        if isinstance(level_db, bool) or not isinstance(level_db, int | float | np.floating):
            raise AudioError(f"window level must be a number of dB, got {level_db!r}")
        level = float(level_db)
        if not math.isfinite(level):
            raise AudioError(f"window level must be finite, got {level_db!r}: no bit made")
        self.windows += 1
        threshold = self.threshold_db
        silent = level <= SILENCE_DB
        self.silent_windows += silent
        if not silent and self._first_sound is None:
            self._first_sound = self._index
        if threshold is not None and not self.range_guard.allows(threshold):
            threshold = None  # no bit rather than one decided on an impossible threshold
        bit = None if threshold is None else (False if silent else level > threshold)
        timer = self._z if not self._waiting else None
        if bit and self.reference:
            reference = self.reference_db(timer)
            bit = level > reference + self.reference_margin_db
        self._recent.append((level, timer))
        awaits = bit is not None and decision is None
        self._waiting.append((level, awaits, False, None if decision is None else int(decision)))
        self._index += 1
        self._label()
        while len(self._waiting) > self.max_undecided:
            self._decisions.append(None)  # the oldest awaited decision is taken as lost
            self.decisions_lost += 1
            self._label()
        return bit

    def reference_db(self, z: int | None) -> float:
        """The level (dB) the next window must also exceed (``reference``): what came before.

        For an agent-period window (timer ``z`` known, ``ta1 <= z <= ta2``), the level of
        the window on which the vocalization was decided, ``z + 1`` windows back: a reply
        must be louder than the room the robot spoke into. For any other window, the level
        ``j`` windows back with ``j`` running through ``ta1 + 1 .. ta2 + 1`` (the agent
        windows' lags) by the window's index, so background windows are held to the same
        comparison; where that window held the robot's own sound (timer ``ts1 .. ts2``), the
        window its vocalization was decided on, as for an agent window (else the robot's
        sound, far louder than the room, would silence the background windows after it and
        none of the agent windows: a contrast with nobody there). ``-inf`` when that window
        is not there (the first windows).
        """
        if z is not None and self.ta1 <= z <= self.ta2:
            back = z + 1
        else:
            span = self.ta2 - self.ta1 + 1
            back = self.ta1 + 1 + self._index % span
            held = self._recent[-back][1] if back <= len(self._recent) else None
            if held is not None and self.ts1 <= held <= self.ts2:
                back += held + 1  # not the robot's own sound: the window it was decided on
        if back > len(self._recent):
            return -math.inf
        return self._recent[-back][0]

    @property
    def awaited_decisions(self) -> int:
        """Bits given whose decisions have not come yet."""
        awaiting = sum(awaits for _, awaits, _, _ in self._waiting)
        return awaiting - len(self._decisions)

    def note_decision(self, u: int | None, withheld: bool = False) -> None:
        """The decision on the oldest window that gave a bit and had none yet.

        ``u`` is 1 (vocalize) or 0; None: the decision was lost (the timer is unknown
        until the next vocalization). ``withheld``: that window overlapped the robot's own
        declared sound (a withheld step): it never sets the threshold.
        """
        if u is not None and u not in (0, 1):
            raise AudioError(f"a decision is 0, 1 or None (lost), got {u!r}")
        awaiting = sum(awaits for _, awaits, _, _ in self._waiting)
        if len(self._decisions) >= awaiting:
            raise AudioError("a decision came for no window that gave a bit")
        if withheld:
            index = self._first_waiting + next(
                k for k, entry in enumerate(self._waiting)
                if entry[1] and sum(e[1] for e in list(self._waiting)[:k]) == len(self._decisions)
            )
            self._withheld.add(index)
            self._labelled_background = deque(
                ((i, level) for i, level in self._labelled_background if i != index),
                maxlen=self.history + self.delay,
            )
        self._decisions.append(None if u is None else int(u))
        self._label()

    # ---------------------------------------------------------------- labels

    def _label(self) -> None:
        """Label every waiting window whose timer is known; keep the levels of background."""
        while self._waiting:
            level, awaits, labelled, given = self._waiting[0]
            if not labelled:
                self._file(level, self._z, self._first_waiting)
                self._waiting[0] = (level, awaits, True, given)
            if given is not None:
                u: int | None = given
            elif awaits:
                if not self._decisions:
                    return
                u = self._decisions.popleft()
            else:
                u = 0
            self._waiting.popleft()
            self._first_waiting += 1
            if u == 1:
                self._z = 0
            elif u is None:
                self._z, self._silent_since_unknown = None, 0
            elif self._z is not None:
                self._z = min(self._z + 1, self.ta2 + 1)
            else:  # silent while unknown: ta2 + 1 of them put any vocalization past the agent
                self._silent_since_unknown += 1
                if self._silent_since_unknown > self.ta2:
                    self._z = self.ta2 + 1

    def _file(self, level: float, z: int | None, index: int) -> None:
        """Use a labelled window: background sets the threshold; self-feedback is watched.

        Its timer is also kept with its level among the recent windows (a late decision:
        it was not known when the window came), for the references of the windows after.
        """
        recent = index - (self._index - len(self._recent))
        if 0 <= recent < len(self._recent):
            self._recent[recent] = (self._recent[recent][0], z)
        if z is None:
            self.labelled["unknown"] += 1
        elif z > self.ta2:
            self.labelled["background"] += 1
            before_any_sound = self._first_sound is None or index < self._first_sound
            if index not in self._withheld and not (level <= SILENCE_DB and before_any_sound):
                self._labelled_background.append((index, level))
            self._withheld.discard(index)
        elif self.ts1 <= z <= self.ts2:
            self.labelled["self"] += 1
            threshold = self.threshold_db
            if threshold is not None and level > SILENCE_DB:  # silence tells nothing of it
                self._self_exceeded.append(level > threshold)
        else:
            self.labelled["agent"] += 1

    # ---------------------------------------------------------------- diagnostics

    def problems(self) -> list[str]:
        """One line per problem seen in the input (empty: none)."""
        out = []
        if self.silent_windows:
            first = self._first_sound
            before = (
                "; no window held sound yet: no threshold, no bit" if first is None
                else f"; the first {first}, before any sound, were not taken as the room"
                if first else ""
            )  # fmt: skip
            out.append(
                f"{self.silent_windows} of {self.windows} windows were digital silence (every"
                " sample zero or one constant value: a muted or unplugged microphone, or a noise"
                f" gate?){before}"
            )
        watched = len(self._self_exceeded)
        if watched == SELF_WINDOWS_WATCHED and sum(self._self_exceeded) < watched / 2:
            out.append(
                f"the room is as loud as the robot's own sound: only {sum(self._self_exceeded)}"
                f" of the last {watched} self-feedback windows rose above the room's threshold;"
                " the partner's replies will hardly stand out (louder robot sound, closer"
                " microphone)"
            )
        if self.range_guard.windows_out_of_range:
            out.append(
                f"{self.range_guard.windows_out_of_range} windows gave no bit: their threshold"
                " lay outside the threshold_db parameter's range (audio not scaled to [-1, 1]?)"
            )
        if self.decisions_lost:
            out.append(
                f"{self.decisions_lost} decisions never came (no controller answering?):"
                " windows after them were not used until the next vocalization"
            )
        return out

    def diagnostic_values(self) -> dict[str, Any]:
        """Threshold, rank and labels, for diagnostics."""
        threshold = self.threshold_db
        return {
            "threshold_db": threshold if threshold is not None else "calibrating",
            "calibration_state": self.state,
            "false_alarm_target": self.false_alarm,
            "false_alarm_now": self.false_alarm_now
            if self.false_alarm_now is not None
            else "calibrating",
            "background_windows": len(self.background),
            "labelled_background": self.labelled["background"],
            "labelled_self": self.labelled["self"],
            "labelled_agent": self.labelled["agent"],
            "labelled_unknown": self.labelled["unknown"],
            "silent_windows": self.silent_windows,
            "decisions_lost": self.decisions_lost,
            "windows_threshold_out_of_range": self.range_guard.windows_out_of_range,
            "problems": "; ".join(self.problems()) or "none",
        }

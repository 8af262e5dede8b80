"""The contract of the ``audio`` topic, checked chunk by chunk: mono, in [-1, 1], at its rate.

mic_node (source ``topic``) windows whatever arrives; audio that breaks the contract
would give wrong energies and bits without a word. :class:`AudioContract` finds three
breaches, counts them, words each one once (the caller logs it) and keeps a problem line
for the diagnostics while it lasts:

* **samples outside [-1, 1]** (an integer driver's raw values, a gain gone wrong, 3e38):
  counted per chunk and per sample; the problem shows for ``hold_s`` after the last one.
* **a multi-channel layout** (``layout.dim`` describing two or more dimensions longer than
  one, e.g. 800 frames x 2 channels): the samples are interleaved channels, not one
  signal; counted per chunk, shown for ``hold_s``.
* **a sample rate that disagrees with the wall clock** (48 kHz audio into a node told 16
  kHz): the audio's duration (samples / stated rate) is compared with the wall time
  over which it was published.

What a rate check can tell apart, and what it cannot. A live driver is paced by its
sound card: its audio advances at (true rate / stated rate) times the wall clock,
steadily (a card's clock drifts by less than 0.1 %; delivery jitter of up to a second
averages out over :data:`RATE_SPAN_S`). Other sources legitimately run at other paces:
a lockstep replay (the fake room, a wav file through the graph) goes as fast as the
graph answers, hundreds of times real time on a quiet machine and slower than real time
on a loaded one, never steadily; a burst (a single message of 10^7 samples) is a jump;
a paused driver leaves gaps, and lost chunks (:meth:`AudioContract.chunks_lost`) shorten
the audio. So a mismatch is reported only when, over
:data:`RATE_SUBSPANS` consecutive spans of :data:`RATE_SPAN_S` seconds each without a
gap longer than :data:`MAX_GAP_S`, the pace (audio seconds per wall second) stayed
within :data:`RATE_TOLERANCE` of one value, and that pace times the stated rate is a
common sample rate (:data:`COMMON_RATES_HZ`) other than the stated one: what a live
driver at another rate does. A replay or simulation at a steady speed that happens to be
such a ratio (``ros2 bag play --rate 3`` into a 16 kHz node, the fake room in lockstep
with ``lockstep_max_speed: 2``) looks exactly like such audio: the audio cannot tell them
apart, its publisher can. Audio whose publisher is one of :data:`PACED_SOURCES` is not
judged; from any other, a steady pace at such a ratio is reported, and the warning names
both readings. The
problem clears once a steady pace of 1 (real time) is measured again.

No rclpy, no clock of its own: times are passed in (a chunk's publication time, which a
backlog in the reader does not shift), or read from the injected ``clock``; both are
wall seconds on one origin (by default the system clock, as DDS publication stamps).
"""

from __future__ import annotations

import array
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from infomax_contingency.core.stepclock import RecentEvents

SAMPLE_LIMIT = 1.0
"""Largest magnitude a sample of the ``audio`` topic may have."""

RATE_SPAN_S = 10.0
"""Wall seconds of one span of the rate check."""

RATE_SUBSPANS = 3
"""Consecutive spans whose paces must agree before the rate is judged (30 s in all)."""

MAX_GAP_S = 2.0
"""Longest wall-time gap between two chunks within a span of the rate check; a longer one
(a paused driver, a lockstep graph waiting) starts the check again."""

RATE_TOLERANCE = 0.03
"""Relative tolerance of the rate check: of the spans' paces among themselves, of a pace
of 1, and of the implied rate to a common rate (44.1 vs 48 kHz differ by 8.8 %)."""

PACED_SOURCES = ("fake_audio_node", "rosbag2_player")
"""Publishers of ``audio`` that set its pace themselves, on purpose: the simulated room (in
lockstep with ``lockstep_max_speed``, or in real time times ``speed``) and ``ros2 bag
play`` (``--rate``). A steady pace of theirs is not a rate mismatch."""

COMMON_RATES_HZ = (8000, 11025, 12000, 16000, 22050, 24000, 32000, 44100, 48000, 88200,
                   96000, 176400, 192000, 352800, 384000)  # fmt: skip
"""Sample rates that audio hardware and drivers use."""


def channel_dims(dims: Sequence[Any]) -> list[tuple[str, int]]:
    """The dimensions of a ``Float32MultiArray`` layout longer than one: ``(label, size)``.

    ``dims``: ``(label, size)`` pairs, or objects with ``label`` and ``size`` (the
    message's ``layout.dim``). Mono audio has at most one (the samples); a second one
    (channels) means interleaved multi-channel audio.
    """
    pairs = [(d.label, d.size) if hasattr(d, "size") else tuple(d) for d in dims]
    return [(str(label), int(size)) for label, size in pairs if int(size) > 1]


def common_rate_near(rate_hz: float, tolerance: float = RATE_TOLERANCE) -> int | None:
    """The common sample rate within ``tolerance`` (relative) of ``rate_hz``, or None."""
    for common in COMMON_RATES_HZ:
        if abs(rate_hz / common - 1.0) <= tolerance:
            return common
    return None


@dataclass
class RateCheck:
    """Compares audio time with wall time over steady spans (see the module's docstring).

    ``observe(samples, at_s)`` after every chunk: ``samples`` the chunk's length,
    ``at_s`` when it was published (wall seconds, any monotonic origin). Judges once per
    span; :attr:`mismatch_rate_hz` is the implied true rate while a mismatch holds.
    """

    stated_rate_hz: int
    span_s: float = RATE_SPAN_S
    subspans: int = RATE_SUBSPANS
    max_gap_s: float = MAX_GAP_S
    tolerance: float = RATE_TOLERANCE
    paced_by_source: Callable[[], bool] = lambda: False
    """True while the audio comes from a source that sets its own pace (asked before a
    mismatch is declared: a simulated room at twice real time is not 32 kHz audio)."""
    mismatch_rate_hz: int | None = None
    """The common rate the audio arrives at, while it is not the stated one."""
    mismatches: int = 0
    """Spans that ended a steady run at another common rate."""
    last_pace: float = math.nan
    """Audio seconds per wall second over the last complete span."""
    _audio_s: float = 0.0
    _last_at: float | None = None
    _span_start: tuple[float, float] | None = None
    _paces: list[float] = field(default_factory=list)

    def restart(self) -> None:
        """Judge only spans from the next chunk on (chunks were lost: audio time is short)."""
        self._paces.clear()
        self._span_start = None

    def observe(self, samples: int, at_s: float) -> bool:
        """Account one chunk; True when this chunk started a mismatch (word it once)."""
        if self._last_at is not None and not 0 <= at_s - self._last_at <= self.max_gap_s:
            self.restart()  # a gap (or a clock going back)
        self._last_at = at_s
        if self._span_start is None:
            # The span starts at this chunk's publication: its samples were recorded
            # before it, so they do not count towards the span.
            self._span_start = (at_s, self._audio_s + samples / self.stated_rate_hz)
        self._audio_s += samples / self.stated_rate_hz
        start_at, start_audio = self._span_start
        if at_s - start_at < self.span_s:
            return False
        self.last_pace = (self._audio_s - start_audio) / (at_s - start_at)
        self._span_start = (at_s, self._audio_s)
        self._paces = [*self._paces, self.last_pace][-self.subspans:]
        return self._judge()

    def _judge(self) -> bool:
        if len(self._paces) < self.subspans:
            return False
        mean = sum(self._paces) / len(self._paces)
        if not all(abs(pace / mean - 1.0) <= self.tolerance for pace in self._paces):
            return False  # not steady: a lockstep replay, bursts
        if abs(mean - 1.0) <= self.tolerance:
            self.mismatch_rate_hz = None  # real time: the stated rate is right
            return False
        common = common_rate_near(mean * self.stated_rate_hz, self.tolerance)
        if common is None or common == self.stated_rate_hz:
            return False  # a steady pace no sound card has: a paced replay
        if self.paced_by_source():
            self.mismatch_rate_hz = None
            return False
        started = self.mismatch_rate_hz is None
        self.mismatch_rate_hz = common
        self.mismatches += 1
        return started


class AudioContract:
    """Checks the chunks of the ``audio`` topic: range, channels and rate.

    Args:
        rate_hz: the rate the audio is stated to have (mic_node's ``audio_rate_hz``).
        hold_s: a range or layout problem shows for this long after its last chunk.
        clock: wall seconds, on the origin of the publication times passed to
            :meth:`check` (default: the system clock, as DDS publication stamps); read for
            a chunk whose publication time is unknown, and by :meth:`problem`.
        publishers: the names of the nodes that publish the audio; asked only when a
            steady pace would be a rate mismatch: one of :data:`PACED_SOURCES` sets its
            own pace, which is then not one.
    """

    def __init__(self, rate_hz: int, hold_s: float = 10.0,
                 clock: Callable[[], float] = time.time,
                 publishers: Callable[[], Sequence[str]] = tuple) -> None:  # fmt: skip
        self.rate_hz = rate_hz
        self.clock = clock
        self.out_of_range = RecentEvents(hold_s=hold_s)
        """Chunks holding a sample outside [-1, 1]."""
        self.out_of_range_samples = 0
        self.largest_magnitude = 0.0
        """Largest sample magnitude seen outside [-1, 1] (0 while none)."""
        self.multichannel = RecentEvents(hold_s=hold_s)
        """Chunks whose layout describes more than one channel."""
        self.layout = ""
        """The last multi-channel layout seen, as ``label=size x label=size``."""
        self.rate = RateCheck(
            rate_hz, paced_by_source=lambda: any(name in PACED_SOURCES for name in publishers())
        )
        self._worded: set[str] = set()
        self._checked = False

    def check(self, samples: ArrayLike, dims: Sequence[Any] = (),
              at_s: float | None = None) -> list[str]:  # fmt: skip
        """Check one chunk; the warnings to log now (each kind once per node).

        Args:
            samples: the chunk's samples, as received (float32 bytes, ``array('f')`` or
                an array).
            dims: its layout's dimensions (:func:`channel_dims`; empty: no layout).
            at_s: when it was published, wall seconds on the clock's origin (None: now).
        """
        now = self.clock() if at_s is None else at_s
        x = np.frombuffer(samples, np.float32) if isinstance(samples, bytes | array.array) \
            else np.asarray(samples)  # fmt: skip
        self._checked = True
        warnings = []
        # max and min first: no temporary array for a chunk within range (10^7 samples)
        loud = x.size > 0 and (x.max() > SAMPLE_LIMIT or x.min() < -SAMPLE_LIMIT)
        outside = int(np.count_nonzero(np.abs(x) > SAMPLE_LIMIT)) if loud else 0
        if outside:
            self.out_of_range.note(now)
            self.out_of_range_samples += outside
            peak = float(np.nanmax(np.abs(x)))
            self.largest_magnitude = max(self.largest_magnitude, peak)
            warnings.append(self._once("range", (
                f"audio samples outside [-1, 1] ({outside} of {x.size} in a chunk, largest"
                f" magnitude {peak:.3g}): the 'audio' topic carries float samples in [-1, 1];"
                " energies and bits from this audio are wrong (scale it at the driver)")))
        channels = channel_dims(dims)
        if len(channels) > 1:
            self.multichannel.note(now)
            self.layout = " x ".join(f"{label or '?'}={size}" for label, size in channels)
            warnings.append(self._once("layout", (
                f"multi-channel audio on 'audio' (layout {self.layout}): the topic carries"
                " mono samples; interleaved channels are windowed as one signal (send one"
                " channel, or mix down at the driver)")))
        if self.rate.observe(int(x.size), now):
            warnings.append(self._once("rate", self.rate_problem()))
        return [warning for warning in warnings if warning]

    def chunks_lost(self) -> None:
        """Chunks were lost on the way (the caller counts them): the rate check restarts.

        Their audio, missing, would make the pace look slower than it is.
        """
        self.rate.restart()

    def _once(self, kind: str, message: str) -> str:
        if kind in self._worded:
            return ""
        self._worded.add(kind)
        return message

    def rate_problem(self) -> str:
        """The rate mismatch in words ("" while none)."""
        true_hz = self.rate.mismatch_rate_hz
        if true_hz is None:
            return ""
        return (
            f"the audio advances {self.rate.last_pace:.3g} times as fast as the wall clock,"
            f" steadily: {true_hz} Hz audio while audio_rate_hz is {self.rate_hz} (or a"
            f" replay at a steady {self.rate.last_pace:.3g}x real time); set audio_rate_hz"
            " to the driver's rate"
        )

    def problem(self, now: float | None = None) -> str:
        """What is wrong with the audio lately, for a WARN diagnostic ("" when nothing)."""
        now = self.clock() if now is None else now
        problems = []
        if self.out_of_range.recent(now):
            problems.append(f"audio samples outside [-1, 1] (up to {self.largest_magnitude:.3g})")
        if self.multichannel.recent(now):
            problems.append(f"multi-channel audio layout ({self.layout})")
        if self.rate.mismatch_rate_hz is not None:
            problems.append(
                f"audio at {self.rate.mismatch_rate_hz} Hz, not audio_rate_hz {self.rate_hz}"
            )
        return "; ".join(problems)

    def values(self) -> dict[str, Any]:
        """Counts for the diagnostics' values (none before the first chunk)."""
        if not self._checked:
            return {}
        return {
            "chunks_out_of_range": self.out_of_range.count,
            "samples_out_of_range": self.out_of_range_samples,
            "chunks_multichannel": self.multichannel.count,
            "audio_pace": self.rate.last_pace,
            "rate_mismatches": self.rate.mismatches,
        }

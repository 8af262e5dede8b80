"""The step clock of the node graph: step identity, joining, following one source, pacing.

One window of audio is one step t (1, 2, ... within a *stream*: one run of one
microphone node). Every bit travels with ``(stream, t)`` and every decision with the
``(stream, t)`` of the bit it answers and the id of the controller that made it, so a
listener joins ``y_t`` with ``u_t`` exactly, whatever order and rate they arrive in:

* :class:`SourceLock` follows one source (a stream, or a controller) among those that
  publish on a topic: an intruder is counted and ignored; a followed source that has
  been silent for a while is replaced by the next one (a restarted node).
* :class:`PublicationTimes` remembers when a source's recent messages were published,
  so that a listener can ask which of them had been sent by a given moment (the due
  times a :class:`SourceLock` judges silence by, whatever its queues hold back).
* :class:`StepJoiner` applies the steps of one stream in order, each once both of its
  messages are in, and resolves steps whose bit or decision can no longer arrive (a
  later one from the same in-order source did) as *missing*: never guessed (see
  :class:`~infomax_contingency.core.model.StatisticTracker` for the exact treatment).
* the flow control of a microphone node's windows is
  :class:`~infomax_contingency.core.flowcontrol.StepOutbox`.
* :class:`StepPace` refuses a step that jumps further ahead of a source's last one than
  its pace allows (:data:`MAX_STEP_JUMP` plus its window rate times the time between the
  two): a single forged message cannot make a listener skip, or wait for, thousands of
  steps.
* :class:`LockstepPacer` releases the next window of a file or simulated room only once
  the decision on the last one came back, or word that it gave no step (or a timeout
  passed).
* :class:`WriterSequence` tells a source's own messages from forged ones with its id by
  their DDS sequence numbers.
* :class:`RecentEvents` remembers when a fault last happened, so a diagnostic returns to
  OK once the fault is over while its count is kept.

Times are seconds on any monotonic clock, passed in by the caller: nothing here sleeps
or reads a clock.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from infomax_contingency.core.model import Withheld

MAX_STEP_JUMP = 64
"""Steps a source's message may lie ahead of its last one, beyond what the time between
the two allows at the source's window rate (:class:`StepPace`). In a healthy graph the
steps a listener receives are consecutive (the flow control loses none); a gap comes
from a fault, and the microphone never has more than ``max_steps_ahead`` (at most this)
steps out unanswered."""


class Arrival(Enum):
    """What :meth:`SourceLock.accept` made of a message."""

    FIRST = "first"
    """The first source seen: now followed."""
    FOLLOWED = "followed"
    """From the source followed."""
    SWITCHED = "switched"
    """From a new source that replaces a followed one that went silent."""
    FOREIGN = "foreign"
    """From another source while the followed one is alive: ignored."""


class SourceLock:
    """Follow one source among several that publish on one topic.

    Messages of other sources are foreign. The caller may :meth:`hold` them (a bounded
    number per source): when a followed source falls silent and another replaces it (a
    restarted node), :meth:`take_held` hands back what the new source sent before the
    switch, so nothing it said is lost.

    Args:
        silence_s: a followed source silent for this long (seconds) is replaced by the
            next source heard; until then every other source is foreign.
        held_per_source: foreign messages kept per source (the newest).
    """

    MAX_SOURCES = 64
    """Foreign sources remembered at once (the longest silent is forgotten first)."""

    def __init__(self, silence_s: float, held_per_source: int = 256) -> None:
        if not silence_s > 0:
            raise ValueError(f"silence_s must be > 0 seconds, got {silence_s}")
        self.silence_s = silence_s
        self.held_per_source = held_per_source
        self.source: int | None = None
        """The source followed (None before the first message)."""
        self.previous: int | None = None
        """The source followed before the last switch."""
        self.last_seen = -math.inf
        self.switches = 0
        """Times a silent source was replaced."""
        self.foreign_messages = 0
        """Messages ignored because they came from another source."""
        self.foreign_sources: dict[int, float] = {}
        """Foreign source -> when it was last heard."""
        self._held: dict[int, deque[Any]] = {}

    def accept(
        self,
        source: int,
        now: float,
        due_since: float | None = None,
        unanswered_s: float | None = None,
    ) -> Arrival:
        """Classify a message from ``source`` sent (or received) at ``now``.

        The followed source is silent, and ``source`` replaces it, when:

        * ``unanswered_s`` is given: it is at least ``silence_s``. For a listener that
          measures how long the followed source left messages unanswered by ``now``
          (:meth:`PublicationTimes.unanswered_s` from :attr:`last_seen`); ``-inf``:
          nothing was due.
        * else ``due_since`` is given: it lies ``silence_s`` or more after the followed
          source was last heard. For a listener that knows when the followed source
          should have spoken (the publication time of the newest message it has not
          answered), so a pause of the whole graph (a loaded machine) is no silence,
          however long another source keeps talking meanwhile.
        * else ``now`` does (silence is the time since the followed source was last heard).
        """
        if self.source is None:
            self.source, self.last_seen = source, now
            return Arrival.FIRST
        if source == self.source:
            self.last_seen = now
            return Arrival.FOLLOWED
        if unanswered_s is not None:
            silent = unanswered_s >= self.silence_s
        else:
            reference = now if due_since is None else due_since
            silent = reference - self.last_seen >= self.silence_s
        if silent:
            self.previous, self.source, self.last_seen = self.source, source, now
            self.foreign_sources.pop(source, None)
            self.switches += 1
            return Arrival.SWITCHED
        self.foreign_messages += 1
        self.foreign_sources[source] = now
        if len(self.foreign_sources) > self.MAX_SOURCES:
            oldest = min(self.foreign_sources, key=self.foreign_sources.get)
            del self.foreign_sources[oldest]
            self._held.pop(oldest, None)
        return Arrival.FOREIGN

    def hold(self, source: int, item: Any) -> None:
        """Keep a foreign message of ``source`` in case it replaces the followed one."""
        if source in self.foreign_sources:
            queue = self._held.setdefault(source, deque(maxlen=self.held_per_source))
            queue.append(item)

    def take_held(self, source: int) -> list[Any]:
        """The messages held for ``source``, oldest first (forgotten here)."""
        return list(self._held.pop(source, ()))

    def intruders(self, now: float) -> list[int]:
        """Foreign sources heard within the last ``silence_s`` seconds."""
        return sorted(s for s, t in self.foreign_sources.items() if now - t < self.silence_s)


class PublicationTimes:
    """Publication times of one in-order source's recent messages (seconds, non-decreasing).

    A listener that reads two topics processes each one's queue on its own: under a
    flood, the bits of one topic may be processed seconds ahead of the decisions on the
    other. Judging a decision published at ``t`` against the newest bit processed would
    then find its controller "silent" for the length of the backlog. :meth:`unanswered_s`
    answers what was really due by ``t``: for how long bits published after the followed
    controller's last answer, and at or before ``t``, had been waiting. A pause of the
    whole graph leaves no bits unanswered (the first bit after it is answered at once).

    Args:
        horizon_s: times older than the newest by more than this are forgotten (seconds).
        max_kept: at most this many times are kept (the newest).
    """

    def __init__(self, horizon_s: float, max_kept: int = 10_000) -> None:
        if not horizon_s > 0:
            raise ValueError(f"horizon_s must be > 0 seconds, got {horizon_s}")
        if max_kept < 1:
            raise ValueError(f"max_kept must be >= 1, got {max_kept}")
        self.horizon_s = horizon_s
        self._times: deque[float] = deque(maxlen=max_kept)

    def note(self, sent_s: float) -> None:
        """A message published at ``sent_s`` (a time before the newest counts as the newest)."""
        newest = max(sent_s, self._times[-1]) if self._times else sent_s
        self._times.append(newest)
        while self._times[0] < newest - self.horizon_s:
            self._times.popleft()

    def newest_until(self, t: float) -> float:
        """The newest publication time at or before ``t``; ``-inf`` if none kept is that old."""
        index = bisect.bisect_right(self._times, t)
        return self._times[index - 1] if index else -math.inf

    def unanswered_s(self, answered_s: float, t: float) -> float:
        """Seconds from the first time after ``answered_s`` to the newest at or before ``t``.

        That is how long messages had gone unanswered by ``t`` if the last answer came at
        ``answered_s``; ``-inf`` if none was published in between (nothing was due).
        """
        first = bisect.bisect_right(self._times, answered_s)
        last = bisect.bisect_right(self._times, t) - 1
        if first > last:
            return -math.inf
        return self._times[last] - self._times[first]

    def __len__(self) -> int:
        return len(self._times)


@dataclass
class JoinCounts:
    """What a :class:`StepJoiner` saw, cumulative (diagnostics)."""

    steps: int = 0
    """Steps applied (complete or with a missing message)."""
    missing_bits: int = 0
    """Steps applied without their bit (it can no longer arrive)."""
    missing_decisions: int = 0
    """Steps applied without their decision."""
    stale_bits: int = 0
    """Bits for a step already applied or received: repeated or going backwards."""
    stale_decisions: int = 0
    """Decisions for a step already applied or answered: repeated or going backwards."""
    early_decisions: int = 0
    """Decisions for steps before the join (dropped at the join)."""
    early_bits: int = 0
    """Bits for steps before the join (dropped at the join)."""
    unknown_step_decisions: int = 0
    """Decisions for a step far beyond every bit received (never seen)."""
    forced: int = 0
    """Steps resolved because too many later steps were waiting."""


class StepJoiner:
    """Apply the bits and decisions of one stream in step order, each step exactly once.

    ``apply(step, y, u)`` is called for steps ``s, s + 1, ...`` from the join: the first
    step ``s`` whose bit and decision have both arrived (messages for earlier steps are
    dropped). Until then they are taken in any order: a listener that connects in the
    middle of a stream may receive a source's first messages out of order (DDS repairs
    the samples sent while it was connecting). After the join ``y`` or ``u`` is None when
    that message can no longer arrive: the bits come from one microphone and the
    decisions from one controller, each in order, so a later message from the same
    source proves an earlier one lost. At most ``max_pending`` steps wait; beyond that
    the oldest is applied without its decision. A bit may be
    :class:`~infomax_contingency.core.model.Withheld` (heard during the robot's own
    sound): it is passed on as it came.

    Args:
        apply: called with ``(step, y, u)`` in step order.
        max_pending: steps that may wait for their decision (bounded memory).
    """

    def __init__(
        self, apply: Callable[[int, Any, bool | None], None], max_pending: int = 600
    ) -> None:
        if max_pending < 1:
            raise ValueError(f"max_pending must be >= 1 steps, got {max_pending}")
        self._apply = apply
        self.max_pending = max_pending
        self.counts = JoinCounts()
        self.restart()

    def restart(self) -> None:
        """Forget the pending steps: a new stream begins (its steps count from 1 again)."""
        self._bits: dict[int, bool | Withheld] = {}
        self._decisions: dict[int, bool] = {}
        self.next_step: int | None = None
        """The next step to apply (None before the first bit)."""
        self.last_bit_step = 0
        self.last_decision_step = 0

    @property
    def pending_bits(self) -> int:
        """Bits received whose step has not been applied yet."""
        return len(self._bits)

    @property
    def pending_decisions(self) -> int:
        """Decisions received whose step has not been applied yet."""
        return len(self._decisions)

    def bit(self, step: int, y: bool | Withheld) -> bool:
        """Bit ``y`` of ``step`` arrived; False if it was stale (repeated or backwards)."""
        y = y if isinstance(y, Withheld) else bool(y)
        if self.next_step is None:
            return self._before_join(self._bits, step, y)
        if step <= self.last_bit_step or step < self.next_step:
            self.counts.stale_bits += 1
            return False
        self._bits[step] = y
        self.last_bit_step = step
        self._drain()
        return True

    def _before_join(self, store: dict[int, Any], step: int, value: Any) -> bool:
        """Keep a message that came before the join (any order); join once a step is whole."""
        is_bit = store is self._bits
        if step in store:
            if is_bit:
                self.counts.stale_bits += 1
            else:
                self.counts.stale_decisions += 1
            return False
        store[step] = value
        if len(store) > self.max_pending:
            del store[min(store)]
            if is_bit:
                self.counts.early_bits += 1
            else:
                self.counts.early_decisions += 1
        whole = self._bits.keys() & self._decisions.keys()
        if whole:
            first = min(whole)
            early_bits = [s for s in self._bits if s < first]
            early_decisions = [s for s in self._decisions if s < first]
            for s in early_bits:
                del self._bits[s]
            for s in early_decisions:
                del self._decisions[s]
            self.counts.early_bits += len(early_bits)
            self.counts.early_decisions += len(early_decisions)
            self.next_step = first
            self.last_bit_step = max(self._bits)
            self.last_decision_step = max(self._decisions)
            self._drain()
        return True

    def decision(self, step: int, u: bool) -> bool:
        """Decision ``u`` on ``step`` arrived; False if it was stale or for no known step."""
        if self.next_step is None:
            return self._before_join(self._decisions, step, u)
        if step <= self.last_decision_step or step < self.next_step:
            self.counts.stale_decisions += 1
            return False
        if step > self.last_bit_step + self.max_pending:
            self.counts.unknown_step_decisions += 1
            return False
        self._decisions[step] = bool(u)
        self.last_decision_step = step
        self._drain()
        return True

    def finish(self) -> None:
        """The stream ends here: apply every step up to the last bit, missing ones as None.

        For a stream the controller no longer answers (it answers a new one): the
        decisions still awaited can never arrive. Decisions beyond the last bit are
        dropped. Afterwards :meth:`restart` begins the next stream.
        """
        self._drain(finish=True)
        self._decisions.clear()

    def _drain(self, finish: bool = False) -> None:
        while self.next_step is not None and self.next_step <= self.last_bit_step:
            step = self.next_step
            bit_known = step in self._bits or self.last_bit_step > step
            decision_known = step in self._decisions or self.last_decision_step > step
            if not (bit_known and decision_known or finish):
                if self.last_bit_step - step < self.max_pending:
                    return
                self.counts.forced += 1
            y = self._bits.pop(step, None)
            u = self._decisions.pop(step, None)
            self.counts.steps += 1
            self.counts.missing_bits += y is None
            self.counts.missing_decisions += u is None
            self.next_step = step + 1
            self._apply(step, y, u)


class Pace(Enum):
    """What :meth:`StepPace.check` made of a step."""

    ON_PACE = "on pace"
    """Plausible (or not ahead at all): take it."""
    JUMP = "jump"
    """Further ahead than the source's pace allows: ignored (kept aside)."""
    CONFIRMED = "confirmed"
    """The source really went on from a jump: take :meth:`StepPace.take_confirmed`."""


class StepPace:
    """Refuse steps that jump further ahead of a source's last one than its pace allows.

    A step ``s`` published at ``t`` is on pace after the last step ``s0`` taken (published
    at ``t0``) when ``s <= s0 + max_jump + rate_hz * (t - t0)``; steps at or before
    ``s0`` are left to the caller's rules (repeats, going backwards). A jump beyond is
    refused and kept aside with the messages that go on from it (each on pace after the
    one before): if the source keeps going from there for ``confirm_s`` seconds
    (publication time) while no message on pace with ``s0`` comes, it really jumped
    (messages were lost) and the run is taken; a message on pace forgets the run (it was
    forged). The first step of a source (or after :meth:`restart`) is taken.

    Args:
        rate_hz: steps the source makes per second of real time (1 / window length).
        confirm_s: seconds a run from a jump must last, alone, to be taken.
        max_jump: steps a message may lie ahead whatever the time between.
        held: messages of a run kept (the newest).
    """

    def __init__(self, rate_hz: float, confirm_s: float, max_jump: int = MAX_STEP_JUMP,
                 held: int = 1024) -> None:  # fmt: skip
        if not rate_hz > 0 or not confirm_s > 0 or max_jump < 1:
            raise ValueError(f"rate_hz and confirm_s must be > 0 and max_jump >= 1, got"
                             f" {rate_hz}, {confirm_s} and {max_jump}")  # fmt: skip
        self.rate_hz = rate_hz
        self.confirm_s = confirm_s
        self.max_jump = max_jump
        self._run: deque[Any] = deque(maxlen=held)
        self._confirmed: list[Any] = []
        self.jumps = 0
        """Messages refused as jumps (cumulative)."""
        self.last_jump: int | None = None
        """The step of the last message refused."""
        self.runs_taken = 0
        """Jumps taken after all (the source went on from them)."""
        self.restart()

    def restart(self, step: int | None = None, sent_s: float = -math.inf) -> None:
        """A new source (or stream): its next step is taken, or the last one is ``step``."""
        self.last_step = step
        self.last_sent_s = sent_s
        self._run.clear()

    def furthest(self, after: int, after_sent_s: float, sent_s: float) -> int:
        """The furthest step on pace at ``sent_s`` after step ``after`` sent at ``after_sent_s``."""
        elapsed = sent_s - after_sent_s
        allowance = 0 if not elapsed > 0 else min(int(self.rate_hz * elapsed), 2**62)
        return after + self.max_jump + allowance

    def check(self, step: int, sent_s: float, item: Any = None) -> Pace:
        """Judge ``step`` published at ``sent_s`` (s); ``item``: its message, kept if refused."""
        if self.last_step is None or step <= self.last_step:
            if self.last_step is None:
                self.last_step, self.last_sent_s = step, sent_s
            return Pace.ON_PACE
        if step <= self.furthest(self.last_step, self.last_sent_s, sent_s):
            self.last_step, self.last_sent_s = step, sent_s
            self._run.clear()
            return Pace.ON_PACE
        self.jumps += 1
        self.last_jump = step
        if not (self._run and self._run_last < step
                <= self.furthest(self._run_last, self._run_last_sent_s, sent_s)):  # fmt: skip
            self._run.clear()
            self._run_first_sent_s = sent_s
        self._run.append(item)
        self._run_last, self._run_last_sent_s = step, sent_s
        if sent_s - self._run_first_sent_s < self.confirm_s:
            return Pace.JUMP
        self.last_step, self.last_sent_s = step, sent_s
        self._confirmed = list(self._run)
        self._run.clear()
        self.runs_taken += 1
        return Pace.CONFIRMED

    def jump_message(self, what: str) -> str:
        """The line that names a refused jump: ``what`` (e.g. "bit for step 9 of stream 4")."""
        return (f"{what} ignored: it jumps ahead of step {self.last_step} further than the"
                " source's pace allows (a forged message?)")  # fmt: skip

    def run_message(self, source: str, first_step: int) -> str:
        """The line that says a run from a jump was taken: ``source`` went on from it."""
        return (f"{source} went on from step {first_step} for {self.confirm_s:g} s with nothing"
                " on pace meanwhile: messages were lost, not forged; taking them from there")

    def take_confirmed(self) -> list[Any]:
        """The run taken by the last :attr:`Pace.CONFIRMED`, oldest first (forgotten here)."""
        confirmed, self._confirmed = self._confirmed, []
        return confirmed


class WriterSequence:
    """Whether step messages come from the writer of the source followed (DDS numbers).

    DDS numbers the messages of each writer 1, 2, 3, ... (``publication_sequence_number``)
    and a source publishes at most one message per step, in order: from one message of
    the writer to its next, the number grows by at least 1 and by no more than the step.
    A message with the true source's id from another writer (forged) fails that unless
    its writer has sent more messages than the true one (a flood). The caller calls
    :meth:`restart` when it follows another source or stream.
    """

    def __init__(self) -> None:
        self.last: tuple[int, int] | None = None
        """(step, sequence number) of the last message taken."""
        self.refused = 0

    def restart(self) -> None:
        """Follow a new writer: its next message is taken."""
        self.last = None

    def same_writer(self, step: int, sequence: int | None) -> bool:
        """True if ``step``, numbered ``sequence`` by DDS (None, 0: unknown), may be its.

        A step not ahead of the last one is not judged (the caller ignores a repeated or
        older step anyway); its number is kept if it is newer (the writer repeated it).
        """
        if not sequence or sequence >= 2**63:  # none given (rmw_cyclonedds: UINT64_MAX)
            return True
        if self.last is not None and step <= self.last[0]:
            self.last = (self.last[0], max(sequence, self.last[1]))
            return True
        if self.last is None or 0 < sequence - self.last[1] <= step - self.last[0]:
            self.last = (step, sequence)
            return True
        self.refused += 1
        return False


@dataclass
class RecentEvents:
    """A count of events of one kind and whether one happened lately.

    Args:
        hold_s: an event is *recent* for this many seconds.
    """

    hold_s: float = 10.0
    count: int = 0
    last_at: float = field(default=-math.inf)

    def note(self, now: float, n: int = 1) -> None:
        """``n`` events happened at ``now``."""
        if n > 0:
            self.count += n
            self.last_at = now

    def recent(self, now: float) -> bool:
        """True if an event happened within the last ``hold_s`` seconds."""
        return now - self.last_at < self.hold_s


class LockstepPacer:
    """Release the next window when the last one was answered, or on timeout.

    A window is answered by the decision on it, or (a window that gave the microphone no
    step: its bit source calibrating or warming up) by the microphone's word that it gave
    none. The timeout is a fault guard for a running loop (a controller that died or a
    lost message): it only applies once a first answer came back, so a graph that is
    still starting up (a listener not connected yet) is waited for, not overtaken.
    Times are seconds on any monotonic clock, passed in by the caller.

    Args:
        timeout_s: release the next window anyway after this long without a decision
            (> 0; ``math.inf`` waits forever).
    """

    def __init__(self, timeout_s: float) -> None:
        if not timeout_s > 0:
            raise ValueError(f"lockstep timeout must be > 0 seconds, got {timeout_s}")
        self.timeout_s = timeout_s
        self._sent_at: float | None = None
        self.answers = 0
        """Answers (decisions, or word of no step) that released a window."""
        self.timeouts = 0
        """Windows released by the timeout rather than by a decision."""
        self.stray_decisions = 0
        """Answers that arrived while no window was waiting for one (e.g. after a timeout)."""

    @property
    def awaiting(self) -> bool:
        """True while a window is out and its decision has not come back."""
        return self._sent_at is not None

    def waited_s(self, now: float) -> float:
        """Seconds the window out has been waiting for its decision at ``now`` (0: none)."""
        return 0.0 if self._sent_at is None else now - self._sent_at

    def sent(self, now: float) -> None:
        """A window went out at time ``now``: wait for its decision."""
        self._sent_at = now

    def answered(self) -> bool:
        """An answer (a decision, or word of no step) arrived; True if it releases the next."""
        if self._sent_at is None:
            self.stray_decisions += 1
            return False
        self._sent_at = None
        self.answers += 1
        return True

    def timed_out(self, now: float) -> bool:
        """True (and the next window is released) if the decision is overdue at ``now``."""
        if self._sent_at is None or self.answers == 0 or math.isinf(self.timeout_s):
            return False
        if now - self._sent_at < self.timeout_s:
            return False
        self._sent_at = None
        self.timeouts += 1
        return True

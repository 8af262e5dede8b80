"""The flow control of the step clock: a microphone node's windows wait for the graph.

:class:`StepOutbox` holds the windows a microphone node has made and releases them as
steps at most ``max_ahead`` steps ahead of the last one answered by the controller and
taken by every listener that needs every step (belief_node acknowledges each step it
applied on ``step_applied``), so a burst of audio (one 30 s message, a replay) or a slow
listener cannot make a queue overflow: the graph slows down instead. A listener that
takes nothing for ``listener_timeout_s`` (killed, hung) is no longer waited for, so
nothing hangs; one that is absent is never waited for.

Times are seconds on any monotonic clock, passed in by the caller: nothing here sleeps
or reads a clock.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from enum import Enum
from typing import Any


@dataclass
class StepListener:
    """A listener that acknowledges the steps it took (e.g. belief_node), as an outbox sees it."""

    taken: int
    """The highest step it acknowledged."""
    busy_since: float
    """When it last took a step, or last had nothing left to take (seconds)."""
    waited_for: bool = True
    """True while the outbox waits for it (it has not stalled)."""


SOURCE_TIMEOUT_S = 3.0
"""The nodes' default ``source_timeout_s``: a followed source silent this long is replaced,
and a run of steps from a jump that lasts this long is taken (messages were lost)."""


UNNUMBERED = 2**63
"""DDS numbers at or above this mean "no number" (rmw_cyclonedds gives UINT64_MAX)."""


class Writing(Enum):
    """What :meth:`WriterFollower.judge` made of a message."""

    FOLLOWED = "followed"
    """From the writer followed (the first writer's first message too); messages of it lost
    right before are in :attr:`WriterFollower.missed`."""
    SWITCHED = "switched"
    """From another writer, followed from now on: the one followed had been silent for
    ``switch_s`` (restarted?). What it sent in between is unknown."""
    FOREIGN = "foreign"
    """From another writer while the one followed speaks: refused."""


class WriterFollower:
    """Whether a message of a topic without identity comes from the writer followed.

    DDS numbers each writer's messages 1, 2, 3, ... (``publication_sequence_number``).
    Where the middleware also names the writer of each message (``publisher_gid``: rclpy
    from 9.1 on, not Jazzy's 7.1), :meth:`judge` tells writers apart by that name. Else
    by the numbers: the writer followed numbers its next message above its last; a
    message numbered at or below that comes from another writer (``ros2 topic pub``
    numbers from 1) and is refused. A number that skips some is the followed writer's,
    its messages in between lost, when the topic has no other publisher (``alone``);
    with another one it may be that one's, and is refused. When nothing from the
    followed writer came for ``switch_s`` while others did (it was restarted: it numbers
    from 1 again), the next message's writer is followed. A message without a number
    (0, None: the middleware gives none) and without a writer's name is taken.
    """

    def __init__(self, switch_s: float) -> None:
        if not switch_s > 0:
            raise ValueError(f"switch_s must be > 0 seconds, got {switch_s}")
        self.switch_s = switch_s
        self.last: int | None = None
        """The number of the followed writer's last message."""
        self.writer: Hashable | None = None
        """The followed writer's name, where the middleware gives names."""
        self.last_taken_s = -math.inf
        self.refused = 0
        """Messages refused as another writer's."""
        self.switches = 0
        """Times another writer was followed after the followed one fell silent."""
        self.missed = 0
        """Messages of the followed writer lost right before the last one judged."""
        self.silent_s = 0.0
        """How long the writer followed before the last switch had been silent, seconds."""

    def take(self, sequence: int | None, now: float) -> bool:
        """True if the message numbered ``sequence``, arriving at ``now`` (s), is taken."""
        return self.judge(sequence, now) is not Writing.FOREIGN

    def judge(self, sequence: int | None, now: float, writer: Hashable | None = None,
              alone: Callable[[], bool] = lambda: True) -> Writing:  # fmt: skip
        """Judge a message numbered ``sequence`` by ``writer`` (None: unnamed) at ``now`` (s).

        ``alone()``: True if the topic has no publisher but the followed writer (asked only
        when the numbers skip some).
        """
        self.missed = 0
        numbered = bool(sequence) and sequence < UNNUMBERED
        same = self._from_followed(sequence, writer, alone)
        if same is None:
            return Writing.FOLLOWED  # nothing to tell writers apart by
        if same:
            if numbered and self.last is not None:
                self.missed = max(0, sequence - self.last - 1)
            self._follow(sequence if numbered else None, writer, now)
            return Writing.FOLLOWED
        if now - self.last_taken_s >= self.switch_s:
            self.silent_s, self.last = now - self.last_taken_s, None
            self._follow(sequence if numbered else None, writer, now)
            self.switches += 1
            return Writing.SWITCHED
        self.refused += 1
        return Writing.FOREIGN

    def would_refuse(self, sequence: int | None, now: float, writer: Hashable | None = None,
                     alone: Callable[[], bool] = lambda: True) -> bool:  # fmt: skip
        """True if :meth:`judge` would refuse this message as another writer's; nothing changes.

        For a message that is dropped whatever its writer (bad samples): another writer's
        is no loss of the followed one's.
        """
        same = self._from_followed(sequence, writer, alone)
        return same is False and now - self.last_taken_s < self.switch_s

    def _from_followed(self, sequence: int | None, writer: Hashable | None,
                       alone: Callable[[], bool]) -> bool | None:  # fmt: skip
        """Whether the message is the followed writer's; None: nothing tells writers apart."""
        numbered = bool(sequence) and sequence < UNNUMBERED
        if self.last_taken_s == -math.inf:
            return True  # the first writer
        if writer is not None and self.writer is not None:
            return writer == self.writer
        if not numbered:
            return None
        if self.last is None:
            return True
        return sequence == self.last + 1 or (sequence > self.last + 1 and alone())

    def _follow(self, sequence: int | None, writer: Hashable | None, now: float) -> None:
        if sequence is not None:
            self.last = sequence if self.last is None else max(sequence, self.last)
        self.writer, self.last_taken_s = writer, now


class Listening(Enum):
    """What :meth:`StepOutbox.acknowledged` made of an acknowledgment."""

    TAKEN = "taken"
    """A step taken (or an old one repeated)."""
    WAITED_FOR = "waited for"
    """A listener's step after its first acknowledged (a new listener), or one given up
    that takes steps again: the outbox waits for it."""
    NOTED = "noted"
    """A new listener's first acknowledgment: waited for once it takes a later step."""
    REFUSED = "refused"
    """A step never handed out (a forgery): ignored."""


class StepOutbox:
    """Windows made but not yet published, released as steps 1, 2, ... under flow control.

    A microphone node pushes every window it makes; :meth:`release` hands out those that
    may be published now: while a controller paces the stream (``paced``), no more than
    ``max_ahead`` steps beyond the last one it answered **and** every waited-for listener
    took; otherwise all. At most ``max_backlog`` windows wait; more are dropped (oldest
    first) and counted.

    Listeners (:meth:`acknowledged`) are the nodes that need every step: a listener is
    waited for from its second acknowledgment on, once it took a step after the first
    one it acknowledged (so a single forged acknowledgment, of a listener that does not
    exist, cannot stall the graph; a graph without one runs at the controller's pace);
    one that took nothing for ``listener_timeout_s`` while it had
    steps to take is no longer waited for (:meth:`give_up_stalled`: killed, hung) until
    it takes a step again (then the outbox waits until it has caught up: the steps it
    has not taken are in its queue, or it counts them as lost).

    Args:
        max_ahead: steps that may be published and not yet answered and taken (>= 1).
        max_backlog: windows that may wait (>= 1).
        listener_timeout_s: seconds a waited-for listener may take nothing (> 0).
    """

    MAX_LISTENERS = 16
    """Listeners remembered at once (the one that took nothing longest is forgotten)."""

    def __init__(self, max_ahead: int, max_backlog: int,
                 listener_timeout_s: float = math.inf) -> None:  # fmt: skip
        if max_ahead < 1 or max_backlog < 1:
            raise ValueError(
                f"max_ahead and max_backlog must be >= 1, got {max_ahead} and {max_backlog}"
            )
        if not listener_timeout_s > 0:
            raise ValueError(f"listener_timeout_s must be > 0 seconds, got {listener_timeout_s}")
        self.max_ahead = max_ahead
        self.max_backlog = max_backlog
        self.listener_timeout_s = listener_timeout_s
        self._waiting: deque[Any] = deque()
        self.last_step = 0
        """The last step handed out."""
        self.last_answered = 0
        """The highest step a decision came back for."""
        self.dropped = 0
        """Windows dropped because the backlog was full."""
        self.listeners: dict[int, StepListener] = {}
        """Listener id -> what it took."""
        self.given_up = 0
        """Times a waited-for listener stalled and was no longer waited for."""
        self.refused_acknowledgments = 0
        """Acknowledgments of steps never handed out."""
        self.answers_given_up = 0
        """Steps taken as answered, their decisions lost (:meth:`give_up_answers`)."""
        self._unanswered_since: float | None = None  # no answer came since then

    @property
    def backlog(self) -> int:
        """Windows waiting."""
        return len(self._waiting)

    @property
    def last_taken(self) -> int:
        """The highest step answered and taken by every waited-for listener."""
        taken = [listener.taken for listener in self.listeners.values() if listener.waited_for]
        return min([self.last_answered, *taken])

    @property
    def in_flight(self) -> int:
        """Steps handed out and not yet answered, or not yet taken by a waited-for listener."""
        return self.last_step - self.last_taken

    def push(self, window: Any) -> None:
        """A window was made."""
        self._waiting.append(window)
        if len(self._waiting) > self.max_backlog:
            self._waiting.popleft()
            self.dropped += 1

    def answered(self, step: int, now: float = 0.0) -> None:
        """A decision on ``step`` came back at ``now`` (duplicates and old steps change nothing)."""
        if self.last_answered < step <= self.last_step:
            self.last_answered = step
            self._unanswered_since = None if step == self.last_step else now

    def answers_overdue(self, now: float) -> bool:
        """True if steps are out and no decision came for ``listener_timeout_s``.

        Never before the first answer: a controller waits for its listeners before it
        answers at all, and a replay in lockstep is paced by that first answer.
        """
        since = self._unanswered_since
        return (self.last_answered > 0 and since is not None
                and now - since >= self.listener_timeout_s)  # fmt: skip

    def give_up_answers(self) -> tuple[int, int]:
        """Take every step out as answered, its decision lost; ``(first, last)`` of them.

        For a controller that answers nothing (killed; or restarted, and DDS gives a
        late joiner none of the steps already published, so it waits for the next one
        while the outbox waits for its answers): without this the stream would stall
        for good. Call it when :meth:`answers_overdue` says so.
        """
        first, last = self.last_answered + 1, self.last_step
        self.last_answered = last
        self._unanswered_since = None
        self.answers_given_up += last - first + 1
        return first, last

    def acknowledged(self, listener: int, step: int, now: float) -> Listening:
        """Listener ``listener`` took ``step`` (and every step before it) at ``now``."""
        if step > self.last_step:
            self.refused_acknowledgments += 1
            return Listening.REFUSED
        known = self.listeners.get(listener)
        if known is None:
            if len(self.listeners) >= self.MAX_LISTENERS:  # forget one not waited for first
                idle = min(self.listeners, key=lambda key: (self.listeners[key].waited_for,
                                                            self.listeners[key].busy_since))
                del self.listeners[idle]
            # Not waited for until it takes a later step: one message (a forged
            # acknowledgment) cannot make the graph wait listener_timeout_s for nobody.
            self.listeners[listener] = StepListener(step, now, waited_for=False)
            return Listening.NOTED
        if step <= known.taken:
            return Listening.TAKEN  # an old step again: no news
        known.taken, known.busy_since = step, now
        if known.waited_for:
            return Listening.TAKEN
        known.waited_for = True
        return Listening.WAITED_FOR

    def give_up_stalled(self, now: float) -> list[int]:
        """Stop waiting for listeners that took nothing for ``listener_timeout_s``; their ids."""
        stalled = [
            key for key, listener in self.listeners.items()
            if listener.waited_for and listener.taken < self.last_step
            and now - listener.busy_since >= self.listener_timeout_s
        ]  # fmt: skip
        for key in stalled:
            self.listeners[key].waited_for = False
        self.given_up += len(stalled)
        return stalled

    def release(self, paced: bool, now: float = 0.0) -> list[tuple[int, Any]]:
        """``(step, window)`` pairs to publish now (at ``now``, seconds), in order."""
        out = []
        while self._waiting and (not paced or self.in_flight < self.max_ahead):
            if not out:  # a listener that had taken everything has steps to take from now
                for listener in self.listeners.values():
                    if listener.taken >= self.last_step:
                        listener.busy_since = now
            if self._unanswered_since is None:
                self._unanswered_since = now  # the first step out since all were answered
            self.last_step += 1
            out.append((self.last_step, self._waiting.popleft()))
        return out

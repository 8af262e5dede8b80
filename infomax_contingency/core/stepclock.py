"""The step clock of the node graph: pairing bits with decisions, and lockstep pacing.

One window of audio is one step t. The microphone publishes the bit ``y_t``; the
controller answers it with the decision ``u_t``. They travel on two topics from two
publishers, so a listener may receive them out of order; :class:`StepPairer` restores
the order of MODEL.md's step clock (observe ``y_t``, then act ``u_t``) by pairing the
k-th decision with the k-th bit.

When audio comes from a file or a simulated room the graph can run faster than real
time, in *lockstep*: the next window is released only once the decision on the previous
one came back. :class:`LockstepPacer` holds that rule, with a timeout so a missing
controller slows the graph down instead of stopping it.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable


class StepPairer:
    """Apply bits and decisions in step-clock order: bit 1, decision 1, bit 2, ...

    The decision on window k is the first one published after that window's bit. With
    publication stamps (DDS source timestamps, one clock on one machine) the pairing is
    exact even for a listener that starts in the middle of a run, whose two
    subscriptions may connect at different steps: decisions stamped before the oldest
    waiting bit answer windows this listener never saw and are dropped; a bit whose
    decision never came (a later decision overtook it) is skipped, not guessed. A step
    is applied (``on_bit``, then ``on_decision``) once both of its messages are in.

    Without stamps (all 0) messages pair by position (the k-th decision with the k-th
    bit), and decisions that arrive before the first bit are dropped.

    Args:
        on_bit: called with each bit ``y_t``, in order.
        on_decision: called with each decision ``u_t``, right after the call for its bit.
    """

    def __init__(self, on_bit: Callable[[bool], None], on_decision: Callable[[bool], None]):
        self._on_bit = on_bit
        self._on_decision = on_decision
        self._bits: deque[tuple[int, bool]] = deque()
        self._decisions: deque[tuple[int, bool]] = deque()
        self.steps = 0
        """Steps applied so far."""
        self.dropped_decisions = 0
        """Decisions dropped: they answered windows whose bit this listener never saw."""
        self.skipped_bits = 0
        """Bits dropped because their decision never arrived."""

    @property
    def pending_bits(self) -> int:
        """Bits received whose decision has not arrived yet."""
        return len(self._bits)

    @property
    def pending_decisions(self) -> int:
        """Decisions received before their bit."""
        return len(self._decisions)

    def bit(self, y: bool, stamp: int = 0) -> None:
        """A bit arrived, published at ``stamp`` (ns; 0 = unknown)."""
        self._bits.append((stamp, bool(y)))
        self._drain()

    def decision(self, u: bool, stamp: int = 0) -> None:
        """A decision arrived, published at ``stamp`` (ns; 0 = unknown)."""
        if not stamp and self.steps == 0 and not self._bits:
            self.dropped_decisions += 1
            return
        self._decisions.append((stamp, bool(u)))
        self._drain()

    def _drain(self) -> None:
        bits, decisions = self._bits, self._decisions
        while bits:
            bit_stamp, y = bits[0]
            while decisions and decisions[0][0] < bit_stamp:
                decisions.popleft()
                self.dropped_decisions += 1
            if not decisions:
                return
            decision_stamp, u = decisions[0]
            if len(bits) > 1 and decision_stamp > bits[1][0] > 0:
                bits.popleft()  # its decision was overtaken: it never reached us
                self.skipped_bits += 1
                continue
            bits.popleft()
            decisions.popleft()
            self.steps += 1
            self._on_bit(y)
            self._on_decision(u)


class LockstepPacer:
    """Release the next window when the decision on the last one arrived, or on timeout.

    The timeout is a fault guard for a running loop (a controller that died or a lost
    message): it only applies once a first decision came back, so a graph that is still
    starting up (a listener not connected yet) is waited for, not overtaken.
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
        """Decisions that released a window."""
        self.timeouts = 0
        """Windows released by the timeout rather than by a decision."""
        self.stray_decisions = 0
        """Decisions that arrived while no window was waiting for one (e.g. after a timeout)."""

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
        """A decision arrived; True if it releases the next window."""
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

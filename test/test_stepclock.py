"""Step clock: joining by step, following one source, flow control, pacing; gaps exact."""

import itertools
import math

import numpy as np
import pytest

from infomax_contingency.core.flowcontrol import Listening, StepOutbox, WriterFollower
from infomax_contingency.core.model import (
    AGENT,
    BACKGROUND,
    ModelParams,
    StatisticTracker,
    advance_timer,
    period_of,
)
from infomax_contingency.core.stepclock import (
    MAX_STEP_JUMP,
    Arrival,
    LockstepPacer,
    Pace,
    PublicationTimes,
    RecentEvents,
    SourceLock,
    StepJoiner,
    StepPace,
    WriterSequence,
)

ROBOT = ModelParams.named("robot")


def _joiner(max_pending: int = 600) -> tuple[StepJoiner, list[tuple]]:
    applied: list[tuple] = []
    return StepJoiner(lambda s, y, u: applied.append((s, y, u)), max_pending), applied


# ---------------------------------------------------------------------- StepJoiner


def test_steps_apply_in_order_once_both_messages_are_in() -> None:
    joiner, applied = _joiner()
    joiner.bit(1, True)
    joiner.bit(2, False)
    assert applied == [] and joiner.pending_bits == 2
    joiner.decision(1, False)
    assert applied == [(1, True, False)]
    joiner.decision(2, True)
    assert applied == [(1, True, False), (2, False, True)]
    assert joiner.pending_bits == joiner.pending_decisions == 0


def test_decisions_may_arrive_long_before_their_bits() -> None:
    joiner, applied = _joiner()
    for step in range(1, 51):
        joiner.decision(step, step % 7 == 0)
    for step in range(1, 51):
        joiner.bit(step, step % 3 == 0)
    assert applied == [(s, s % 3 == 0, s % 7 == 0) for s in range(1, 51)]


def test_a_later_message_from_the_same_source_proves_an_earlier_one_lost() -> None:
    joiner, applied = _joiner()
    joiner.bit(1, True)
    joiner.decision(1, False)
    joiner.decision(2, True)  # the bit of step 2 is lost ...
    joiner.bit(3, True)  # ... which bit 3 proves
    joiner.bit(4, False)  # and the decision on 3 is lost, which decision 4 proves
    joiner.decision(4, False)
    assert applied == [(1, True, False), (2, None, True), (3, True, None), (4, False, False)]
    assert (joiner.counts.missing_bits, joiner.counts.missing_decisions) == (1, 1)


def test_repeated_backward_and_unknown_steps_are_refused() -> None:
    joiner, applied = _joiner(max_pending=10)
    assert joiner.bit(5, True) and joiner.decision(5, True)  # joins at step 5
    assert not joiner.bit(5, False) and not joiner.bit(3, True)
    assert not joiner.decision(5, False)
    assert not joiner.decision(4, True)
    assert not joiner.decision(500, True)  # answers no bit received
    counts = joiner.counts
    assert (counts.stale_bits, counts.stale_decisions, counts.unknown_step_decisions) == (2, 2, 1)
    assert applied == [(5, True, True)]


def test_decisions_before_the_join_are_dropped() -> None:
    joiner, applied = _joiner()
    joiner.decision(3, True)
    joiner.decision(4, False)
    joiner.bit(4, True)
    assert applied == [(4, True, False)] and joiner.counts.early_decisions == 1


def test_the_join_is_the_first_whole_step_whatever_the_order_before_it() -> None:
    # A listener connecting mid-stream: the sources' first messages arrive out of order.
    joiner, applied = _joiner()
    joiner.bit(267, True)
    joiner.decision(268, False)
    joiner.decision(267, True)  # repaired after the later one: still joins at 267
    joiner.bit(268, False)
    assert applied == [(267, True, True), (268, False, False)]
    assert joiner.counts.missing_decisions == joiner.counts.stale_decisions == 0

    joiner, applied = _joiner()
    joiner.bit(12, True)
    joiner.decision(11, True)  # its bit never comes: not a step of this listener
    joiner.bit(13, False)
    joiner.decision(12, False)
    joiner.decision(13, True)
    assert applied == [(12, True, False), (13, False, True)]
    assert joiner.counts.early_decisions == 1 and joiner.counts.missing_bits == 0
    assert not joiner.bit(11, True)  # older than the join: stale


def test_pending_steps_are_bounded() -> None:
    joiner, applied = _joiner(max_pending=5)
    joiner.decision(1, False)
    for step in range(1, 13):
        joiner.bit(step, False)  # the controller answers step 1, then no more
    assert [s for s, _, u in applied] == list(range(1, 8))
    assert all(u is None for *_, u in applied[1:])
    assert joiner.pending_bits == 5 and joiner.counts.forced == 6
    before_join, _ = _joiner(max_pending=5)
    for step in range(1, 13):
        before_join.bit(step, False)  # no decision at all: nothing joins, 5 bits kept
    assert before_join.pending_bits == 5 and before_join.counts.early_bits == 7


def test_restart_begins_a_new_stream() -> None:
    joiner, applied = _joiner()
    joiner.bit(1, True)
    joiner.decision(1, True)
    joiner.bit(2, True)
    joiner.restart()
    joiner.bit(1, False)
    joiner.decision(1, False)
    assert applied == [(1, True, True), (1, False, False)]


def test_finish_applies_the_awaited_steps_without_their_decisions() -> None:
    joiner, applied = _joiner()
    joiner.bit(1, True)
    joiner.decision(1, False)
    joiner.bit(2, True)
    joiner.bit(3, False)
    joiner.decision(3, True)
    joiner.bit(4, False)
    joiner.finish()
    assert applied == [(1, True, False), (2, True, None), (3, False, True), (4, False, None)]
    assert joiner.counts.missing_decisions == 2 and joiner.pending_bits == 0
    joiner.finish()  # nothing left: nothing applied twice
    assert len(applied) == 4


# ---------------------------------------------------------------------- SourceLock, outbox


def test_source_lock_follows_the_first_source_until_it_falls_silent() -> None:
    lock = SourceLock(silence_s=3.0)
    assert lock.accept(10, now=0.0) is Arrival.FIRST
    assert lock.accept(11, now=1.0) is Arrival.FOREIGN
    assert lock.accept(10, now=2.0) is Arrival.FOLLOWED
    assert lock.accept(11, now=4.9) is Arrival.FOREIGN and lock.intruders(4.9) == [11]
    assert lock.accept(11, now=5.0) is Arrival.SWITCHED
    assert (lock.source, lock.previous, lock.switches, lock.foreign_messages) == (11, 10, 1, 2)
    assert lock.accept(10, now=5.1) is Arrival.FOREIGN
    assert lock.intruders(now=100.0) == []
    with pytest.raises(ValueError, match="silence_s"):
        SourceLock(0.0)


def test_outbox_releases_at_most_max_ahead_unanswered_steps() -> None:
    outbox = StepOutbox(max_ahead=3, max_backlog=100)
    for window in "abcdefg":
        outbox.push(window)
    assert outbox.release(paced=True) == [(1, "a"), (2, "b"), (3, "c")]
    assert outbox.release(paced=True) == [] and outbox.in_flight == 3
    outbox.answered(2)
    outbox.answered(1)  # an older answer changes nothing
    assert outbox.release(paced=True) == [(4, "d"), (5, "e")]
    outbox.answered(99)  # a step never handed out
    assert outbox.last_answered == 2
    assert outbox.release(paced=False) == [(6, "f"), (7, "g")]


def test_a_writer_follower_refuses_another_writers_numbers_and_follows_a_restart() -> None:
    follower = WriterFollower(switch_s=3.0)
    assert all(follower.take(n, now=n * 0.5) for n in range(1, 11))  # belief_node: 1 .. 10
    assert not follower.take(1, now=5.1)  # `ros2 topic pub --once`: numbered from 1
    assert follower.take(11, now=5.5) and follower.refused == 1
    assert follower.take(None, now=5.6) and follower.take(0, now=5.6)  # no numbers: taken
    # belief_node restarted: numbers from 1 again, refused until 3 s without the old one
    assert not follower.take(1, now=6.0) and not follower.take(2, now=8.4)
    assert follower.take(3, now=8.5) and follower.take(4, now=9.0)
    with pytest.raises(ValueError, match="switch_s"):
        WriterFollower(0.0)


def test_outbox_takes_steps_no_decision_came_for_as_lost_and_goes_on() -> None:
    """A restarted controller gets none of the steps out before it joined: no deadlock."""
    outbox = StepOutbox(max_ahead=3, max_backlog=100, listener_timeout_s=5.0)
    for window in range(10):
        outbox.push(window)
    assert [s for s, _ in outbox.release(paced=True, now=0.0)] == [1, 2, 3]
    assert not outbox.answers_overdue(now=60.0)  # never before a first answer (start-up)
    outbox.answered(1, now=1.0)  # then the controller dies
    assert not outbox.answers_overdue(now=5.9)  # 5 s from the last answer, not the first step
    assert outbox.answers_overdue(now=6.0)
    assert outbox.give_up_answers() == (2, 3) and outbox.answers_given_up == 2
    assert not outbox.answers_overdue(now=100.0)  # nothing out
    assert [s for s, _ in outbox.release(paced=True, now=100.0)] == [4, 5, 6]
    assert not outbox.answers_overdue(now=104.9) and outbox.answers_overdue(now=105.0)
    outbox.answered(6, now=104.0)  # the new controller answers: nothing overdue
    assert not outbox.answers_overdue(now=1000.0)


def test_outbox_waits_for_a_listener_that_keeps_up_and_lets_a_stalled_one_go() -> None:
    outbox = StepOutbox(max_ahead=2, max_backlog=100, listener_timeout_s=5.0)
    for window in range(20):
        outbox.push(window)
    assert [s for s, _ in outbox.release(paced=True, now=0.0)] == [1, 2]
    assert outbox.acknowledged(7, 3, now=0.0) is Listening.REFUSED  # never handed out
    assert outbox.acknowledged(7, 1, now=0.1) is Listening.NOTED  # its first: maybe forged
    outbox.answered(2)
    assert [s for s, _ in outbox.release(paced=True, now=0.2)] == [3, 4]  # the controller's pace
    assert outbox.acknowledged(7, 2, now=0.3) is Listening.WAITED_FOR  # it takes steps
    outbox.answered(4)
    # the controller answered all, the listener took two: nothing more may go
    assert outbox.release(paced=True, now=0.3) == []
    assert outbox.in_flight == 2 and outbox.last_taken == 2
    assert outbox.acknowledged(7, 4, now=1.0) is Listening.TAKEN
    assert [s for s, _ in outbox.release(paced=True, now=1.0)] == [5, 6]
    outbox.answered(6)
    # the listener takes nothing more: waited for until listener_timeout_s has passed
    # since it had steps to take (from the release at 1.0)
    assert outbox.give_up_stalled(now=5.9) == [] and outbox.release(paced=True, now=5.9) == []
    assert outbox.give_up_stalled(now=6.0) == [7] and outbox.given_up == 1
    assert [s for s, _ in outbox.release(paced=True, now=6.0)] == [7, 8]
    outbox.answered(8)
    assert [s for s, _ in outbox.release(paced=True, now=6.1)] == [9, 10]
    # it takes a step again: waited for until it has caught up
    assert outbox.acknowledged(7, 4, now=6.2) is Listening.TAKEN  # an old one: no news
    assert outbox.acknowledged(7, 5, now=6.2) is Listening.WAITED_FOR
    outbox.answered(10)
    assert outbox.release(paced=True, now=6.3) == [] and outbox.in_flight == 5
    assert outbox.acknowledged(7, 9, now=6.4) is Listening.TAKEN
    assert [s for s, _ in outbox.release(paced=True, now=6.4)] == [11]


def test_one_forged_acknowledgment_does_not_stall_the_graph() -> None:
    """A step_applied of a listener that does not exist is no reason to wait (it was 5 s)."""
    outbox = StepOutbox(max_ahead=2, max_backlog=100, listener_timeout_s=5.0)
    for window in range(40):
        outbox.push(window)
    outbox.release(paced=True, now=0.0)
    assert outbox.acknowledged(1, 1, now=0.0) is Listening.NOTED  # the true belief node
    assert outbox.acknowledged(1, 2, now=0.0) is Listening.WAITED_FOR
    outbox.answered(2)
    assert [s for s, _ in outbox.release(paced=True, now=0.1)] == [3, 4]
    assert outbox.acknowledged(666, 3, now=0.1) is Listening.NOTED  # forged, never again
    outbox.answered(4)
    assert outbox.acknowledged(1, 4, now=0.2) is Listening.TAKEN
    assert [s for s, _ in outbox.release(paced=True, now=0.2)] == [5, 6]  # no wait for 666
    # a flood of forged listener ids does not make the outbox forget the true one
    for forged in range(100, 100 + 2 * StepOutbox.MAX_LISTENERS):
        outbox.acknowledged(forged, 5, now=0.3)
    assert outbox.listeners[1].waited_for and outbox.in_flight == 2


def test_a_listener_that_had_taken_everything_is_not_stalled_by_a_pause() -> None:
    outbox = StepOutbox(max_ahead=2, max_backlog=100, listener_timeout_s=5.0)
    outbox.push("a")
    outbox.push("b")
    outbox.release(paced=True, now=0.0)
    outbox.answered(2)
    assert outbox.acknowledged(3, 1, now=0.0) is Listening.NOTED
    assert outbox.acknowledged(3, 2, now=0.0) is Listening.WAITED_FOR
    outbox.push("c")  # the next window comes a minute later
    assert outbox.release(paced=True, now=60.0) == [(3, "c")]
    assert outbox.give_up_stalled(now=64.9) == [] and outbox.give_up_stalled(now=65.0) == [3]


def test_pace_refuses_a_forged_jump_and_keeps_the_source_going() -> None:
    pace = StepPace(rate_hz=2.0, confirm_s=3.0)
    assert pace.check(10, 100.0) is Pace.ON_PACE  # the first step: any
    assert pace.check(11, 100.0) is Pace.ON_PACE
    assert pace.check(11 + MAX_STEP_JUMP, 100.0) is Pace.ON_PACE  # lost messages, bounded
    last = 11 + MAX_STEP_JUMP
    assert pace.check(last + MAX_STEP_JUMP + 1, 100.0, "forged") is Pace.JUMP
    assert (pace.jumps, pace.last_jump, pace.last_step) == (1, last + MAX_STEP_JUMP + 1, last)
    assert pace.check(last + 1, 100.1) is Pace.ON_PACE  # the true source goes on
    assert pace.check(last - 5, 100.1) is Pace.ON_PACE  # behind: the caller's rules
    assert pace.last_step == last + 1
    # time allows steps at the window rate: 10 s later, 20 more
    assert pace.check(last + 1 + MAX_STEP_JUMP + 20, 110.1) is Pace.ON_PACE
    assert pace.check(10**12, 111.0, "forged") is Pace.JUMP
    assert "jumps ahead of step" in pace.jump_message("bit for step 9")


def test_pace_takes_a_run_that_goes_on_alone_from_a_jump() -> None:
    pace = StepPace(rate_hz=2.0, confirm_s=3.0)
    pace.check(1, 0.0)
    # messages 2..999 were lost: the source goes on from 1000, nothing comes on pace
    verdicts = [pace.check(1000 + i, 0.1 * i, 1000 + i) for i in range(31)]
    assert set(verdicts[:-1]) == {Pace.JUMP} and verdicts[-1] is Pace.CONFIRMED
    assert pace.take_confirmed() == list(range(1000, 1031)) and pace.take_confirmed() == []
    assert pace.last_step == 1030 and pace.runs_taken == 1
    assert pace.check(1031, 3.1) is Pace.ON_PACE
    # a run broken by a message on pace is forgotten (it was forged)
    pace.check(5000, 4.0)
    assert pace.check(1032, 5.0) is Pace.ON_PACE
    assert pace.check(5001, 8.0) is Pace.JUMP  # a new run starts here, not at 4.0
    with pytest.raises(ValueError):
        StepPace(rate_hz=0.0, confirm_s=1.0)


def test_outbox_backlog_is_bounded_and_counted() -> None:
    outbox = StepOutbox(max_ahead=1, max_backlog=3)
    for window in range(6):
        outbox.push(window)
    assert outbox.backlog == 3 and outbox.dropped == 3
    assert outbox.release(paced=False) == [(1, 3), (2, 4), (3, 5)]
    with pytest.raises(ValueError):
        StepOutbox(0, 1)


def test_recent_events_return_to_quiet_and_keep_their_count() -> None:
    events = RecentEvents(hold_s=10.0)
    assert not events.recent(0.0)
    events.note(5.0, n=2)
    events.note(6.0, n=0)
    assert events.recent(14.9) and not events.recent(15.0) and events.count == 2


# ---------------------------------------------------------------------- gaps, exactly


def _brute_force_counts(
    params: ModelParams, bits: list, decisions: list, z_start: set[int]
) -> tuple[int, int, int, int]:
    """Counts over the windows whose period every completion of the history agrees on.

    ``None`` marks a missing bit or decision. Every assignment of the missing decisions
    and every starting timer in ``z_start`` is enumerated; a window is counted when all
    of them give it the same period (and its bit is known), with ``k2_per_lag`` an agent
    window when all give it the same timer (each timer value its own rate).
    """
    unknown = [i for i, u in enumerate(decisions) if u is None]
    periods_per_window: list[set[int]] = [set() for _ in bits]
    for z0 in z_start:
        for filling in itertools.product((0, 1), repeat=len(unknown)):
            us = list(decisions)
            for index, value in zip(unknown, filling, strict=True):
                us[index] = value
            z = z0
            for t, u in enumerate(us):
                agent_lag = params.k2_per_lag and period_of(params, z) == AGENT
                periods_per_window[t].add(-z if agent_lag else period_of(params, z))
                z = advance_timer(params, z, u)
    counts = [0, 0, 0, 0]
    for y, periods in zip(bits, periods_per_window, strict=True):
        if y is None or len(periods) > 1:
            continue
        (period,) = periods
        if period == AGENT or period < 0:
            counts[0 if y else 1] += 1
        elif period == BACKGROUND:
            counts[2 if y else 3] += 1
    return tuple(counts)


@pytest.mark.parametrize("seed", range(40))
def test_missing_bits_and_decisions_count_exactly_what_is_certain(seed: int) -> None:
    rng = np.random.default_rng(seed)
    params = ROBOT if seed % 2 else ModelParams.named("paper")
    n = int(rng.integers(5, 30))
    bits: list = [bool(b) for b in rng.random(n) < 0.5]
    decisions: list = [bool(u) for u in rng.random(n) < 0.25]
    for t in rng.choice(n, size=int(rng.integers(0, 4)), replace=False):
        decisions[t] = None
    for t in rng.choice(n, size=int(rng.integers(0, 4)), replace=False):
        bits[t] = None
    joined_midway = seed % 3 == 0
    tracker = StatisticTracker(params)
    if joined_midway:
        tracker.forget_timer_completely()
    for y, u in zip(bits, decisions, strict=True):
        tracker.skip_observation() if y is None else tracker.observe(y)
        tracker.act_unknown() if u is None else tracker.act(u)
    z_start = set(range(params.n_timer_values)) if joined_midway else {params.timer_long_ago}
    assert tracker.statistic.counts == _brute_force_counts(params, bits, decisions, z_start)


def test_forget_timer_allows_any_number_of_silent_windows() -> None:
    tracker = StatisticTracker(ROBOT)
    tracker.observe(True)
    tracker.act(True)  # vocalized: timer 0
    tracker.forget_timer()  # then an unknown number of unseen, silent windows
    expected = {min(k, ROBOT.timer_long_ago) for k in range(1, ROBOT.timer_long_ago + 1)}
    assert tracker.possible_timers == expected and not tracker.timer_certain
    for _ in range(ROBOT.timer_long_ago):
        tracker.act(False)
    assert tracker.timer_certain and tracker.statistic.z == ROBOT.timer_long_ago
    tracker.forget_timer()
    assert tracker.timer_certain  # long ago stays long ago
    tracker.act_unknown()
    tracker.act(True)
    assert tracker.timer_certain and tracker.statistic.z == 0


def test_pacer_releases_on_the_answer() -> None:
    pacer = LockstepPacer(timeout_s=2.0)
    assert not pacer.awaiting and not pacer.answered()  # nothing was out: a stray
    assert pacer.stray_decisions == 1
    pacer.sent(now=10.0)
    assert pacer.awaiting and pacer.answered() and not pacer.awaiting


def test_pacer_timeout_applies_once_the_loop_runs() -> None:
    pacer = LockstepPacer(timeout_s=2.0)
    pacer.sent(now=0.0)
    assert not pacer.timed_out(now=100.0), "before the first answer the graph is starting"
    assert pacer.answered()
    pacer.sent(now=200.0)
    assert not pacer.timed_out(now=201.9)
    assert pacer.timed_out(now=202.0) and not pacer.awaiting and pacer.timeouts == 1
    assert not pacer.timed_out(now=300.0)


def test_pacer_without_timeout_waits_forever() -> None:
    pacer = LockstepPacer(timeout_s=math.inf)
    pacer.sent(0.0)
    pacer.answered()
    pacer.sent(1.0)
    assert not pacer.timed_out(1e12)


def test_pacer_refuses_a_non_positive_timeout() -> None:
    with pytest.raises(ValueError, match="timeout"):
        LockstepPacer(0.0)


def test_source_lock_with_due_times_is_not_fooled_by_a_pause_of_the_graph() -> None:
    lock = SourceLock(silence_s=3.0)
    assert lock.accept(1, 10.0) is Arrival.FIRST
    # The graph pauses (no bit is due after 10.5 s) while a rogue talks for 20 s: foreign.
    assert all(lock.accept(2, t, due_since=10.5) is Arrival.FOREIGN for t in (14.0, 30.0))
    # Bits keep coming and the followed source leaves them unanswered for 3 s: replaced.
    assert lock.accept(2, 31.0, due_since=13.0) is Arrival.SWITCHED and lock.source == 2


def test_publication_times_answer_what_was_sent_by_a_moment() -> None:
    times = PublicationTimes(horizon_s=10.0, max_kept=100)
    assert times.newest_until(5.0) == -math.inf  # nothing sent yet
    for sent in (1.0, 1.5, 2.0, 1.9, 30.0):  # 1.9 after 2.0: counts as 2.0 (in order)
        times.note(sent)
    assert times.newest_until(1.7) == -math.inf  # forgotten: older than 30 - 10 s
    assert times.newest_until(29.9) == -math.inf and times.newest_until(30.0) == 30.0
    assert len(times) == 1
    for sent in np.arange(31.0, 400.0, 0.5):
        times.note(float(sent))
    assert len(times) == 21  # the last 10 s
    assert times.newest_until(395.2) == 395.0 and times.newest_until(1e9) == 399.5
    with pytest.raises(ValueError, match="horizon_s"):
        PublicationTimes(0.0)
    with pytest.raises(ValueError, match="max_kept"):
        PublicationTimes(1.0, max_kept=0)


def test_a_backlog_or_a_pause_does_not_make_a_controller_look_silent() -> None:
    """The belief node's rule: the bits left unanswered by the foreign decision's time.

    A flood (a rogue answering the followed stream) delays the decisions' queue: the bits
    up to 20 s have been processed, the decisions only up to 10 s. The rogue's decision
    published at 10.2 s finds no bit unanswered for long; judged against the newest bit
    processed (the rule for one queue, ``due_since``) it would replace the followed one.
    """
    bits = PublicationTimes(horizon_s=30.0)
    lock = SourceLock(silence_s=3.0)
    assert lock.accept(1, 0.0) is Arrival.FIRST
    for t in np.arange(0.0, 10.01, 0.5):  # bits and their answers, in step
        bits.note(float(t))
        assert lock.accept(1, float(t)) is Arrival.FOLLOWED
    for t in np.arange(10.5, 20.01, 0.5):  # bits processed ahead of the decisions
        bits.note(float(t))
    assert bits.unanswered_s(lock.last_seen, 10.2) == -math.inf  # none due yet
    assert lock.accept(99, 10.2, unanswered_s=bits.unanswered_s(lock.last_seen, 10.2)) \
        is Arrival.FOREIGN
    assert lock.accept(99, 10.2, due_since=20.0) is Arrival.SWITCHED  # the one-queue rule
    # The whole graph pauses 10 s after the bit of 10 s was answered; on resume a bit at
    # 20 s, and a rogue's decision 1 ms later, before the followed controller's answer:
    # one bit is due, for 0 s. Not silent.
    lock = SourceLock(silence_s=3.0)
    assert lock.accept(1, 10.0) is Arrival.FIRST
    paused = PublicationTimes(horizon_s=30.0)
    for t in (9.5, 10.0, 20.0):
        paused.note(t)
    assert paused.unanswered_s(10.0, 20.001) == 0.0
    assert lock.accept(99, 20.001, unanswered_s=0.0) is Arrival.FOREIGN
    assert lock.accept(99, 20.001, due_since=20.0) is Arrival.SWITCHED  # the one-queue rule
    # A controller that really died at 10 s: bits went on (lockstep timeouts) for 4 s
    # unanswered, then another one answers; it replaces the dead one.
    lock = SourceLock(silence_s=3.0)
    assert lock.accept(1, 10.0) is Arrival.FIRST
    assert bits.unanswered_s(10.0, 14.6) == 4.0  # bits of 10.5 .. 14.5 s
    assert lock.accept(2, 14.6, unanswered_s=4.0) is Arrival.SWITCHED and lock.source == 2


def test_a_writers_numbers_tell_its_steps_from_forged_ones_with_its_id() -> None:
    writer = WriterSequence()
    assert writer.same_writer(5, 105)  # the first message: any
    assert writer.same_writer(6, 106) and writer.same_writer(9, 107)  # messages lost: fine
    assert not writer.same_writer(19, 1)  # another writer's first message, 10 steps ahead
    assert not writer.same_writer(10, 107)  # a number repeated: another writer
    assert not writer.same_writer(11, 200)  # more messages than steps since: another writer
    assert writer.same_writer(10, 108) and writer.refused == 3
    assert writer.same_writer(10, 109)  # a step repeated: not judged (the caller's rules)
    assert writer.same_writer(11, 110) and not writer.same_writer(12, 110)
    assert writer.same_writer(11, None)  # no numbers from the middleware: nothing to tell
    writer.restart()  # a new stream or controller followed
    assert writer.same_writer(1, 1) and writer.same_writer(2, 2)


def test_a_forged_decision_for_the_next_step_needs_the_next_number_and_costs_one_step() -> None:
    """docs/LIMITS.md: its writer's numbering tells it apart, unless it is the next number."""
    writer = WriterSequence()
    assert writer.same_writer(7, 40)  # the controller's decision on step 7, its 40th message
    assert not writer.same_writer(8, 1)  # a forger's own first message: refused
    assert not writer.same_writer(8, 300)  # a flood's, far ahead in numbers: refused
    assert writer.same_writer(8, 41)  # a forger with exactly the next number: taken
    assert writer.same_writer(8, 41)  # the controller's own: a repeat, left to the caller
    assert writer.same_writer(9, 42)  # and the controller's next decision is taken again

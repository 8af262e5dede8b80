"""Step clock: bits and decisions paired in order; lockstep release and timeout."""

import math

import pytest

from infomax_contingency.core.stepclock import LockstepPacer, StepPairer


def _pairer() -> tuple[StepPairer, list[str]]:
    events: list[str] = []
    pairer = StepPairer(
        lambda y: events.append(f"y{int(y)}"), lambda u: events.append(f"u{int(u)}")
    )
    return pairer, events


def test_in_order_messages_apply_at_once() -> None:
    pairer, events = _pairer()
    for y, u in ((1, 0), (0, 1), (1, 1)):
        pairer.bit(y)
        pairer.decision(u)
    assert events == ["y1", "u0", "y0", "u1", "y1", "u1"]
    assert pairer.steps == 3 and pairer.pending_bits == pairer.pending_decisions == 0


def test_a_step_is_applied_once_both_messages_are_in() -> None:
    pairer, events = _pairer()
    pairer.bit(1)
    pairer.bit(0)  # arrived before the decision on bit 1
    assert events == [] and pairer.pending_bits == 2
    pairer.decision(1)
    assert events == ["y1", "u1"] and pairer.pending_bits == 1
    pairer.decision(0)
    assert events == ["y1", "u1", "y0", "u0"]


def test_a_decision_waits_for_its_bit() -> None:
    pairer, events = _pairer()
    pairer.bit(1)
    pairer.decision(0)
    pairer.decision(1)  # the decision on bit 2, ahead of bit 2
    assert events == ["y1", "u0"] and pairer.pending_decisions == 1
    pairer.bit(0)
    assert events == ["y1", "u0", "y0", "u1"]


def test_unstamped_decisions_before_the_first_bit_are_dropped() -> None:
    pairer, events = _pairer()
    pairer.decision(1)  # answers a window this listener never saw
    pairer.bit(0)
    pairer.decision(0)
    assert events == ["y0", "u0"] and pairer.dropped_decisions == 1


def test_stamps_pair_a_listener_that_joins_mid_run() -> None:
    # Bits stamped 10, 20, 30, ...; the decision on bit k is stamped 10 k + 5. This
    # listener's 'vocalize' subscription connected late: decisions 5 and 15 never came,
    # and the bit stamped 10 arrived after the decision stamped 25.
    pairer, events = _pairer()
    pairer.decision(1, stamp=5)  # answers an earlier window: dropped
    pairer.bit(0, stamp=20)
    pairer.decision(1, stamp=25)
    assert events == ["y0", "u1"] and pairer.dropped_decisions == 1
    pairer.bit(1, stamp=30)
    pairer.bit(0, stamp=40)
    pairer.decision(0, stamp=45)  # the decision stamped 35 was lost: bit 30 is skipped
    assert events == ["y0", "u1", "y0", "u0"] and pairer.skipped_bits == 1
    pairer.bit(1, stamp=50)
    pairer.decision(1, stamp=55)
    assert events[-2:] == ["y1", "u1"] and pairer.steps == 3


def test_stamped_decision_ahead_of_its_bit_is_kept() -> None:
    pairer, events = _pairer()
    pairer.decision(1, stamp=15)  # overtook its own bit on the way
    pairer.bit(1, stamp=10)
    assert events == ["y1", "u1"] and pairer.dropped_decisions == 0


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

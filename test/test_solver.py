"""The DP solver against plain expectimax over every action/observation history."""

from __future__ import annotations

import numpy as np
import pytest

import brute_force
from infomax_contingency.core.model import TIE_TOLERANCE, ModelParams, Statistic
from infomax_contingency.core.solver import solve_episodic, solve_receding
from infomax_contingency.core.statespace import (
    count_index,
    count_index_array,
    count_tuples,
    n_count_tuples,
)
from test_model import PARAM_SETS


def statistic_of(params: ModelParams, z: int, events: tuple) -> Statistic:
    """The statistic of a brute-force history (counted directly)."""
    return Statistic(
        z,
        events.count(("agent", 1)),
        events.count(("agent", 0)),
        events.count(("background", 1)),
        events.count(("background", 0)),
    )


def test_count_index_is_a_bijection_ordered_by_total() -> None:
    tuples = count_tuples(9)
    assert len(tuples) == n_count_tuples(9) == 715
    assert np.array_equal(count_index_array(*tuples.T), np.arange(len(tuples)))
    assert len({tuple(t) for t in tuples}) == len(tuples)
    totals = tuples.sum(axis=1)
    assert np.all(np.diff(totals) >= 0) and totals.max() == 9
    assert all(count_index(*map(int, tuples[i])) == i for i in range(0, len(tuples), 37))


@pytest.mark.parametrize("name", sorted(PARAM_SETS))
@pytest.mark.parametrize("horizon", [2, 4, 6])
def test_episodic_dp_equals_expectimax(name: str, horizon: int) -> None:
    params = PARAM_SETS[name]
    table = solve_episodic(params, horizon, keep_values=True)
    checked = 0
    for z_first in range(params.n_timer_values):
        first_period = brute_force.period(params, z_first)
        for y_first in (0, 1):
            events = [] if first_period == "self" else [(first_period, y_first)]
            _, _, record = brute_force.expectimax(
                params, events, z_first, horizon - 1, TIE_TOLERANCE
            )
            for (steps_to_go, z, history), (value, action) in record.items():
                if steps_to_go == 0:
                    continue
                step = horizon - steps_to_go
                statistic = statistic_of(params, z, history)
                dp_value = table.values[step - 1][z, count_index(*statistic.counts)]
                assert dp_value == pytest.approx(value, abs=1e-11), (step, statistic)
                assert table.action(statistic, step=step) == action, (step, statistic)
                checked += 1
    assert checked > 0


@pytest.mark.parametrize("name", sorted(PARAM_SETS))
def test_receding_dp_equals_expectimax_from_every_statistic(name: str) -> None:
    params = PARAM_SETS[name]
    horizon, memory = 3, 3
    table = solve_receding(params, horizon, memory, keep_values=True)
    vocalizations = 0
    for counts in count_tuples(memory):
        p2, q2, p3, q3 = (int(c) for c in counts)
        events = [("agent", 1)] * p2 + [("agent", 0)] * q2
        events += [("background", 1)] * p3 + [("background", 0)] * q3
        for z in range(params.n_timer_values):
            value, action, _ = brute_force.expectimax(params, events, z, horizon, TIE_TOLERANCE)
            statistic = Statistic(z, p2, q2, p3, q3)
            assert table.values[0][z, count_index(p2, q2, p3, q3)] == pytest.approx(
                value, abs=1e-11
            )
            assert table.action(statistic) == action, statistic
            vocalizations += action
    assert vocalizations > 0  # the comparison covers both actions


def test_paper_table_listens_first_then_asks() -> None:
    """Qualitative anchors of the paper's controller.

    With no data it first listens to the background; once the background is known and
    the agent period is not, it asks; inside the agent period it waits for the answer.
    """
    params = ModelParams.named("paper")
    table = solve_episodic(params, 12)
    assert table.action(Statistic(params.timer_long_ago), step=1) == 0
    assert table.action(Statistic(params.timer_long_ago, 0, 0, 0, 5), step=6) == 1
    assert table.action(Statistic(1, 0, 0, 0, 5), step=7) == 0
    assert table.action(Statistic(2, 1, 0, 0, 5), step=8) == 0


def test_ties_go_to_silence() -> None:
    # Last decision of an episode whose both choices land in the self period: the
    # robot set's timer 0 moves to 1 (self) when silent and to 0 (self) when vocalizing.
    params = ModelParams.named("robot")
    table = solve_episodic(params, 2, keep_values=True)
    for counts in count_tuples(1):
        assert table.action(Statistic(0, *map(int, counts)), step=1) == 0


def test_bad_arguments() -> None:
    params = ModelParams.named("paper")
    with pytest.raises(ValueError, match="horizon"):
        solve_episodic(params, 1)
    with pytest.raises(ValueError, match="memory"):
        solve_receding(params, 3, 0)
    table = solve_episodic(params, 5)
    with pytest.raises(IndexError, match="steps 1 .. 4"):
        table.action(Statistic(4), step=5)
    with pytest.raises(IndexError, match="outside the table"):
        table.action(Statistic(4, 2, 0, 0, 0), step=1)

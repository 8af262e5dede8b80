"""The committed tables in policies/ are exactly what a fresh solve gives."""

from __future__ import annotations

import pytest

from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.core.solver import solve
from infomax_contingency.resources import resource_path

COMMITTED = [
    ("paper_episodic_T40.npz", "paper", "episodic", 40, 0),
    ("robot_receding_H24_M60.npz", "robot", "receding", 24, 60),
]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "params", "mode", "horizon", "memory"), COMMITTED)
def test_committed_table_equals_fresh_solve(
    name: str, params: str, mode: str, horizon: int, memory: int
) -> None:
    model = ModelParams.named(params)
    committed = PolicyTable.load(resource_path("policies", name), expected_params=model)
    fresh = solve(model, mode, horizon, memory)
    assert committed.metadata() == fresh.metadata()
    assert committed.same_policy_as(fresh)

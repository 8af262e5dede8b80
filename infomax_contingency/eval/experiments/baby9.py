"""Experiment 1 (MODEL.md section 5): baby-9, a partner who answers every vocalization."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from infomax_contingency.core.controllers import PolicyController
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import RECEDING, PolicyTable
from infomax_contingency.eval.experiments.tables import obtain_table
from infomax_contingency.sim.simulation import StepRecord, simulate
from infomax_contingency.sim.world import make_room


@dataclasses.dataclass(frozen=True)
class Baby9Config:
    """Settings of the baby-9 experiment.

    Attributes:
        params_name: parameter set.
        horizon: receding horizon H of the optimal table, steps.
        memory: the table's memory M, counted observations (must be >= steps).
        steps: steps of each run (windows of dt seconds).
        replies: reply conventions of the room: ``all`` (every agent-period step) or a
            timer value of the agent period.
    """

    params_name: str = "paper"
    horizon: int = 24
    memory: int = 60
    steps: int = 54
    replies: tuple[str, ...] = ("all", "1", "2", "3")


def baby9_session(
    params: ModelParams, table: PolicyTable, reply: str, steps: int
) -> list[StepRecord]:
    """One run of the optimal table in the baby-9 room with reply convention ``reply``."""
    rng = np.random.default_rng(0)  # the room is deterministic (rates 0 or 1)
    room = make_room(f"baby9:reply={reply}", params, rng)
    return simulate(params, PolicyController(table, params), room, steps, rng, memory=0)


def baby9_run_summary(params: ModelParams, reply: str, records: Sequence[StepRecord]) -> dict:
    """The vocalizations of one baby-9 run: steps, times (``t * dt`` s), beliefs, ratios."""
    vocalizations = [r for r in records if r.u]
    times = [round(r.t * params.dt, 9) for r in vocalizations]
    return {
        "reply": reply,
        "vocalization_steps": [r.t for r in vocalizations],
        "vocalization_times_s": times,
        "intervals_s": [round(b - a, 9) for a, b in zip(times, times[1:], strict=False)],
        "ratio_at_vocalization": [r.ratio for r in vocalizations],
        "belief_at_vocalization": [r.belief for r in vocalizations],
        "final_belief": records[-1].belief,
        "final_entropy_bits": records[-1].entropy,
        "beliefs": [r.belief for r in records],
    }


def experiment_baby9(config: Baby9Config | None = None, cache_dir: Path | None = None) -> dict:
    """MODEL.md section 5: a partner who answers every vocalization, receding horizon H.

    The controller's memory M must hold every counted observation of the run (``M >=
    steps``), so its sliding memory never drops one and the statistic is the unbounded
    one. A vocalization decided at step t is played at the start of step t + 1, so its
    time is ``t * dt`` seconds from the start of the run.
    """
    config = config or Baby9Config()
    params = ModelParams.load(config.params_name)
    if config.memory < config.steps:
        raise ValueError(
            f"memory M = {config.memory} < {config.steps} steps: the controller would forget"
            " observations; use M >= steps for the unbounded memory of the scenario"
        )
    table, path = obtain_table(params, RECEDING, config.horizon, config.memory, cache_dir)
    runs = [
        baby9_run_summary(params, reply, baby9_session(params, table, reply, config.steps))
        for reply in config.replies
    ]
    return {
        "experiment": "baby9",
        "params": config.params_name,
        "dt": params.dt,
        "horizon": config.horizon,
        "memory": config.memory,
        "steps": config.steps,
        "duration_s": round(config.steps * params.dt, 9),
        "table": str(path),
        "runs": runs,
    }

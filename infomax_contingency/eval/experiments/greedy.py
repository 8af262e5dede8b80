"""Experiment 3: what greedy (one-step, H = 1) infomax control does."""

from __future__ import annotations

import dataclasses

import numpy as np

from infomax_contingency.core import model
from infomax_contingency.core.controllers import make_controller
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.scoring import (
    greedy_actions,
    receding_layers,
    receding_layers_cost,
)
from infomax_contingency.core.statespace import n_count_tuples
from infomax_contingency.limits import refuse_over_budget
from infomax_contingency.sim.simulation import RECORD_BYTES, simulate
from infomax_contingency.sim.world import make_room


@dataclasses.dataclass(frozen=True)
class GreedyConfig:
    """Settings of the greedy experiment.

    Attributes:
        param_names: parameter sets.
        max_count: statistics with counts summing to at most this are checked.
        longest_horizon: horizons 1 .. this are searched for the first that vocalizes.
        steps: steps of the example run in a responsive room.
        seed: its random seed.
    """

    param_names: tuple[str, ...] = ("paper", "robot")
    max_count: int = 60
    longest_horizon: int = 8
    steps: int = 80
    seed: int = 0


def refuse_oversized_greedy(config: GreedyConfig) -> None:
    """Refuse, before any work, sizes that cannot run or would not fit in memory (one line).

    The estimate of each set is the backward induction of
    :func:`~infomax_contingency.core.scoring.receding_layers_cost` (horizons 1 ..
    ``longest_horizon``, counts up to ``max_count``; ``greedy_actions`` sweeps less), the
    greedy actions kept and the example run's records.
    """
    if config.max_count < 0:
        raise ValueError(f"--max-count must be >= 0, got {config.max_count}")
    if config.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {config.steps}")
    for name in config.param_names:
        params = ModelParams.load(name)
        needed = (receding_layers_cost(params, config.longest_horizon, config.max_count).peak_bytes
                  + params.n_timer_values * n_count_tuples(config.max_count)
                  + RECORD_BYTES * config.steps)  # fmt: skip
        refuse_over_budget(needed, f"run experiment greedy on {name} with --max-count"
                           f" {config.max_count} and --steps {config.steps}",
                           "give a smaller --max-count or fewer --steps")


def greedy_set(config: GreedyConfig, name: str) -> dict:
    """The greedy experiment for one parameter set (see :func:`experiment_greedy`).

    It compares the one-step rule with the tables, so it runs on the model they are
    solved for (one K2: :meth:`~infomax_contingency.core.model.ModelParams.for_table`).
    """
    params = ModelParams.load(name).for_table()
    greedy = greedy_actions(params, config.max_count)
    layers = receding_layers(params, range(1, config.longest_horizon + 1), config.max_count)
    first_vocalizing = next((h for h in sorted(layers) if layers[h].any()), None)
    example = model.Statistic(params.timer_long_ago, 1, 2, 0, 6)
    rng = np.random.default_rng(config.seed)
    room = make_room("responsive", params, rng)
    records = simulate(params, make_controller("greedy", params, rng), room, config.steps, rng)
    return {
        "params": name,
        "statistics": int(greedy.size),
        "greedy_vocalizing_statistics": int(greedy.sum()),
        "vocalizing_statistics_by_horizon": {h: int(a.sum()) for h, a in layers.items()},
        "smallest_vocalizing_horizon": first_vocalizing,
        "example_statistic": list(example),
        "example_entropy_bits": example.entropy(params),
        "example_next_entropy_silent_bits": model.expected_next_entropy(params, example, 0),
        "example_next_entropy_vocalize_bits": model.expected_next_entropy(params, example, 1),
        "run_steps": config.steps,
        "run_vocalizations": sum(r.u for r in records),
        "run_final_belief": records[-1].belief,
        "prior": params.pi,
    }


def experiment_greedy(config: GreedyConfig | None = None) -> dict:
    """What one-step infomax control does: its actions over every statistic, and a run.

    For each parameter set: the number of statistics (counts summing to <= max_count,
    every timer value) where ``policy_1`` vocalizes; the smallest horizon H (up to
    ``longest_horizon``) whose ``policy_H`` vocalizes anywhere on that domain; the
    one-step look-ahead of both actions at a typical statistic; and a run of the greedy
    controller in a responsive room.
    """
    config = config or GreedyConfig()
    refuse_oversized_greedy(config)
    results = [greedy_set(config, name) for name in config.param_names]
    return {"experiment": "greedy", "max_count": config.max_count, "sets": results}

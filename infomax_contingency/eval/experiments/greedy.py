"""Experiment 3: what greedy (one-step, H = 1) infomax control does."""

from __future__ import annotations

import dataclasses

import numpy as np

from infomax_contingency.core import model
from infomax_contingency.core.controllers import make_controller
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.scoring import greedy_actions, receding_layers
from infomax_contingency.sim.simulation import simulate
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


def greedy_set(config: GreedyConfig, name: str) -> dict:
    """The greedy experiment for one parameter set (see :func:`experiment_greedy`)."""
    params = ModelParams.load(name)
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
    results = [greedy_set(config, name) for name in config.param_names]
    return {"experiment": "greedy", "max_count": config.max_count, "sets": results}

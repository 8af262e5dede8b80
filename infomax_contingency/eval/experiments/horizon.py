"""Experiment 4: how the optimal receding action map depends on the horizon H."""

from __future__ import annotations

import dataclasses

import numpy as np

from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.scoring import receding_layers, receding_layers_cost
from infomax_contingency.core.statespace import count_tuples
from infomax_contingency.limits import refuse_over_budget


@dataclasses.dataclass(frozen=True)
class HorizonConfig:
    """Settings of the horizon experiment.

    Attributes:
        param_names: parameter sets.
        horizons: the horizons H listed and compared.
        domain_max_count: maps are compared on counts with n2 + n3 <= this.
        longest_horizon: every horizon 1 .. this is solved (>= every listed one).
    """

    param_names: tuple[str, ...] = ("paper", "robot")
    horizons: tuple[int, ...] = (4, 8, 12, 16, 24, 40)
    domain_max_count: int = 12
    longest_horizon: int = 60


def _vocalizing_fraction_map(
    actions: np.ndarray, z: int, domain_max_count: int
) -> list[list[float | None]]:
    """Fraction of count tuples with each ``(n2, n3)`` where ``actions[z]`` vocalizes.

    Rows n2, columns n3, ``0 .. domain_max_count``; None where no tuple has those counts.
    """
    counts = count_tuples(domain_max_count)
    n2 = counts[:, 0] + counts[:, 1]
    n3 = counts[:, 2] + counts[:, 3]
    size = domain_max_count + 1
    cells, vocal = np.zeros((size, size)), np.zeros((size, size))
    np.add.at(cells, (n2, n3), 1.0)
    np.add.at(vocal, (n2, n3), actions[z].astype(float))
    with np.errstate(invalid="ignore"):
        fraction = np.where(cells > 0, vocal / np.maximum(cells, 1), np.nan)
    return [[None if np.isnan(v) else float(v) for v in row] for row in fraction]


def refuse_oversized_horizon(config: HorizonConfig) -> None:
    """Refuse, before any work, sizes that cannot run or would not fit in memory (one line).

    The estimate of each set is :func:`~infomax_contingency.core.scoring.receding_layers_cost`
    of horizons 1 .. ``longest_horizon`` on counts up to ``domain_max_count``.
    """
    if not config.horizons or min(config.horizons) < 1:
        raise ValueError(f"--horizons must be >= 1, got {list(config.horizons)}")
    if config.domain_max_count < 0:
        raise ValueError(f"--domain must be >= 0, got {config.domain_max_count}")
    if config.longest_horizon < max(config.horizons):
        raise ValueError("the longest horizon must be >= every listed horizon")
    for name in config.param_names:
        cost = receding_layers_cost(ModelParams.load(name), config.longest_horizon,
                                    config.domain_max_count)  # fmt: skip
        refuse_over_budget(cost.peak_bytes, f"solve horizons 1 .. {config.longest_horizon} of"
                           f" {name} on counts up to {config.domain_max_count}",
                           "give a smaller --longest or --domain")


def horizon_set(config: HorizonConfig, name: str) -> dict:
    """The horizon experiment for one parameter set (see :func:`experiment_horizon`)."""
    params = ModelParams.load(name).for_table()  # the tables' model: one K2
    longest = config.longest_horizon
    layers = receding_layers(params, range(1, longest + 1), config.domain_max_count)
    stable_from = longest
    while stable_from > 1 and np.array_equal(layers[stable_from - 1], layers[longest]):
        stable_from -= 1
    listed = []
    for position, horizon in enumerate(config.horizons):
        actions = layers[horizon]
        previous = config.horizons[position - 1] if position else None
        listed.append(
            {
                "horizon": horizon,
                "vocalizing_statistics": int(actions.sum()),
                "differs_from_previous": None
                if previous is None
                else int(np.count_nonzero(actions != layers[previous])),
                "differs_from_largest_listed": int(
                    np.count_nonzero(actions != layers[max(config.horizons)])
                ),
                "differs_from_longest": int(np.count_nonzero(actions != layers[longest])),
                "map_long_ago": _vocalizing_fraction_map(
                    actions, params.timer_long_ago, config.domain_max_count
                ),
            }
        )
    changes = [h for h in range(2, longest + 1) if not np.array_equal(layers[h], layers[h - 1])]
    return {
        "params": name,
        "statistics": int(layers[1].size),
        "horizons": listed,
        "stable_from": stable_from,
        "last_change_at": changes[-1] if changes else None,
    }


def experiment_horizon(config: HorizonConfig | None = None) -> dict:
    """Receding ``policy_H`` maps on a common domain (counts summing to <= domain_max_count).

    Every horizon 1 .. ``longest_horizon`` is solved (one backward induction); for the
    listed horizons the map is compared with the previous listed one and with the
    largest listed one, and ``stable_from`` is the smallest H from which every map up to
    ``longest_horizon`` is identical. ``maps`` gives, at the timer value "long ago", the
    fraction of count tuples with the given ``(n2, n3)`` where the policy vocalizes.
    """
    config = config or HorizonConfig()
    refuse_oversized_horizon(config)
    return {
        "experiment": "horizon",
        "domain_max_count": config.domain_max_count,
        "longest_horizon": config.longest_horizon,
        "sets": [horizon_set(config, name) for name in config.param_names],
    }

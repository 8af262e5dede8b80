"""Experiment 5: infomax TD learning curves, the learned policy scored exactly."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from infomax_contingency.core import learning
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.scoring import Scorer
from infomax_contingency.limits import refuse_over_budget


@dataclasses.dataclass(frozen=True)
class LearnConfig:
    """Settings of the learning curves (``learn``).

    Attributes:
        params_name: parameter set.
        horizon: episode length T, steps.
        methods: ``NAME[@BUDGET]`` or ``epsilon=E,backup=B,initial=I[@BUDGET]`` each
            (see :func:`parse_method`).
        budget: vocalizations per run, where a method names none.
        seeds: one run per method and seed.
        evaluate_every: the learned policy is scored every this many vocalizations.
        evaluate_growth: and only once the vocalizations grew by this fraction (0: off).
        target: the score a run should reach (0 = never vocalize, 1 = optimal), in
            (0, 1]: no policy scores above the optimum, and never vocalizing reaches 0.
    """

    params_name: str = "paper"
    horizon: int = 12
    methods: tuple[str, ...] = ("plain",)
    budget: int = 60_000
    seeds: tuple[int, ...] = (1,)
    evaluate_every: int = 1000
    evaluate_growth: float = 0.0
    target: float = 0.995


def _learning_settings(text: str, spec: str) -> learning.LearningSettings:
    """``epsilon=E,backup=B,initial=I`` (any of them) as settings; ``text`` names the method."""
    fields: dict[str, Any] = {}
    for item in spec.split(","):
        key, _, value = item.partition("=")
        if key not in ("epsilon", "backup", "initial"):
            raise ValueError(f"method {text!r}: unknown setting {key!r} (epsilon, backup, initial)")
        if key != "epsilon":
            fields[key] = value
            continue
        try:
            fields[key] = float(value)
        except ValueError:
            raise ValueError(f"method {text!r}: epsilon must be a number, got {value!r}") from None
    return learning.LearningSettings(**fields)


def parse_method(text: str, default_budget: int) -> tuple[str, learning.LearningSettings, int]:
    """``NAME[@BUDGET]`` or ``epsilon=E,backup=B,initial=I[@BUDGET]``: label, settings, budget."""
    spec, _, budget_text = text.partition("@")
    try:
        budget = int(budget_text) if budget_text else default_budget
    except ValueError:
        raise ValueError(f"method {text!r}: the budget after @ must be a whole number") from None
    if "=" not in spec:
        if spec not in learning.METHODS:
            raise ValueError(
                f"unknown learning method {spec!r}; use one of {sorted(learning.METHODS)} or"
                " epsilon=E,backup=B,initial=I"
            )
        return spec, learning.METHODS[spec], budget
    settings = _learning_settings(text, spec)
    name = f"eps={settings.epsilon:g}, {settings.backup} backup, {settings.initial} init"
    return name, settings, budget


LEARN_BYTES_PER_STATISTIC = 64
"""Memory of TD learning per statistic of its horizon, bytes: the value tables are lists
of Python floats (measured: about 23 bytes, peak 228 MB for the paper set at T = 40)."""
LEARN_BASE_BYTES = 200 * 2**20
"""Memory of learning on a short horizon (the interpreter, numpy, the scorer), bytes."""
LEARN_CURVE_POINT_BYTES = 256
"""Memory of one point of a learning curve (vocalizations, trials, score: three Python
numbers in lists, and their copy in the result's record), bytes."""


def learning_cost_bytes(params: ModelParams, horizon: int) -> int:
    """Peak memory of :func:`experiment_learn` at ``horizon`` (bytes, exact integers)."""
    statistics = params.n_timer_values * (math.comb(horizon + 4, 5) - 1)
    return LEARN_BASE_BYTES + LEARN_BYTES_PER_STATISTIC * statistics


def experiment_learn(config: LearnConfig | None = None) -> dict:
    """Learning curves: every method with every seed, the greedy policy scored exactly.

    Returns the parameter set, the horizon and one
    :meth:`~infomax_contingency.core.learning.LearningCurve.to_dict` record per run (its
    ``method`` the method's label), methods first, then seeds.
    """
    config = config or LearnConfig()
    params = ModelParams.load(config.params_name).for_table()  # learns the tables' policy
    if config.horizon < 2:
        raise ValueError(f"learning horizon must be >= 2 steps, got {config.horizon}")
    if not 0 < config.target <= 1:  # also NaN
        raise ValueError(f"--target must be a score in (0, 1], got {config.target}: 1 is the"
                         " optimal policy's, which none exceeds; never vocalizing scores 0")
    methods = [parse_method(text, config.budget) for text in config.methods]
    if config.evaluate_every < 1 or min(budget for _, _, budget in methods) < 1:
        raise ValueError("the budget and --evaluate-every must be >= 1 vocalization")
    # at most one evaluation every evaluate_every vocalizations, and one at the end
    points = len(config.seeds) * sum(budget // config.evaluate_every + 1
                                     for _, _, budget in methods)  # fmt: skip
    needed = learning_cost_bytes(params, config.horizon) + LEARN_CURVE_POINT_BYTES * points
    refuse_over_budget(needed,
                       f"learn with horizon {config.horizon} and {points:,} evaluations",
                       "give a shorter --horizon, a smaller --budget or a larger"
                       " --evaluate-every")  # fmt: skip
    scorer = Scorer(params, config.horizon)
    curves = []
    for name, settings, budget in methods:
        for seed in config.seeds:
            curve, _ = learning.learn(
                params,
                config.horizon,
                settings,
                budget,
                seed,
                evaluate_every=config.evaluate_every,
                evaluate_growth=config.evaluate_growth,
                target=config.target,
                scorer=scorer,
            )
            curve.method = name
            curves.append(curve.to_dict())
    return {"params": config.params_name, "horizon": config.horizon, "curves": curves}

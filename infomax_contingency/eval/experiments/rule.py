"""Experiment 2: the interpretable rule against the optimal episodic controller.

How often the rule's action is the optimal one, under three measures over the statistics
of a range of steps, the best constant c for each, and the rule's exact episode score.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from infomax_contingency.core import model
from infomax_contingency.core.controllers import check_rule_constant, rule_decisions
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import EPISODIC
from infomax_contingency.core.scoring import (
    ActionsByStep,
    Scorer,
    reachable_statistics,
    rule_actions,
    table_actions,
    visit_distributions,
)
from infomax_contingency.core.statespace import count_tuples
from infomax_contingency.eval.experiments.tables import obtain_table


def _best_threshold(ratio: np.ndarray, optimal: np.ndarray, weight: np.ndarray) -> dict:
    """The c maximising sum_i w_i [(ratio_i > c) == optimal_i] (exact scan over breakpoints).

    Returns the best open interval of c (``low < c < high``), a value inside it and the
    weighted agreement gained on these statistics.
    """
    values, inverse = np.unique(ratio, return_inverse=True)
    vocal_weight = np.bincount(inverse, weights=weight * optimal, minlength=len(values))
    silent_weight = np.bincount(inverse, weights=weight * ~optimal, minlength=len(values))
    # c below values[0]: everyone vocalizes; each breakpoint passed turns a group silent.
    agreement = vocal_weight.sum() + np.concatenate(
        ([0.0], np.cumsum(silent_weight - vocal_weight))
    )
    best = int(np.argmax(agreement))
    low = 0.0 if best == 0 else float(values[best - 1])
    high = math.inf if best == len(values) else float(values[best])
    if math.isinf(high):
        inside = 2.0 * low if low > 0 else 1.0
    elif low == 0.0:
        inside = high / 2.0
    else:
        inside = math.sqrt(low * high)
    return {"low": low, "high": high, "c": inside, "agreement": float(agreement[best])}


@dataclasses.dataclass(frozen=True)
class RuleConfig:
    """Settings of the rule experiment.

    Attributes:
        params_name: parameter set.
        horizon: episodic horizon T of the optimal table, steps.
        first_step, last_step: the steps t (1-based, ``last_step < horizon``) compared.
        c: the rule's constant.
    """

    params_name: str = "paper"
    horizon: int = 40
    first_step: int = 18
    last_step: int = 24
    c: float = 9.0


RULE_STATISTIC_FIELDS = ("optimal", "rule", "ratio", "z", "p2", "q2", "p3", "q3")
"""Per-statistic arrays of :func:`rule_statistics` besides the three measures' weights."""


def rule_statistics(
    params: ModelParams, config: RuleConfig, optimal_actions: ActionsByStep
) -> dict[str, np.ndarray]:
    """Every statistic ``(t, a)`` of steps first..last, flattened step after step.

    Arrays: ``optimal`` and ``rule`` (their actions), ``ratio`` (the variance ratio, nan
    or inf where a count is zero), the timer ``z`` and counts ``p2, q2, p3, q3``;
    ``any`` (reachable under some policy), ``visited`` (reached by the optimal policy)
    and ``weight`` (the optimal policy's visit probability, each step weighing
    ``1 / (number of steps)``).
    """
    reachable = reachable_statistics(params, config.horizon)
    visits = visit_distributions(params, config.horizon, optimal_actions)
    n_steps = config.last_step - config.first_step + 1
    fields = (*RULE_STATISTIC_FIELDS, "any", "visited", "weight")
    parts: dict[str, list[np.ndarray]] = {field: [] for field in fields}
    for t in range(config.first_step, config.last_step + 1):
        counts = count_tuples(t).T
        z = np.broadcast_to(
            np.arange(params.n_timer_values)[:, None], (params.n_timer_values, counts.shape[1])
        )
        p2, q2, p3, q3 = (np.broadcast_to(column, z.shape) for column in counts)
        var2, var3 = model.rate_variances(params, p2, q2, p3, q3)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = (var2 / (p2 + q2)) / (var3 / (p3 + q3))
        step = {
            "optimal": optimal_actions(t),
            "rule": rule_decisions(params, config.c, z, p2, q2, p3, q3),
            "ratio": ratio,
            **dict(zip(("z", "p2", "q2", "p3", "q3"), (z, p2, q2, p3, q3), strict=True)),
            "any": reachable[t - 1],
            "visited": visits[t - 1] > 0,
            "weight": visits[t - 1] / n_steps,
        }
        for field in fields:
            parts[field].append(np.ravel(step[field]))
    return {field: np.concatenate(arrays) for field, arrays in parts.items()}


def rule_agreement(params: ModelParams, data: dict[str, np.ndarray], weight: np.ndarray) -> dict:
    """How the rule agrees with the optimal actions on ``data``, under one measure ``weight``.

    Also the best c for this measure: the rule's decision depends on c only past the
    agent period with n2 > 0 and n3 > 0, so the best threshold is scanned on those
    statistics and the agreement elsewhere is fixed.
    """
    optimal, rule = data["optimal"], data["rule"]
    agree = rule == optimal
    past_agent = data["z"] > params.ta2
    depends = past_agent & np.isfinite(data["ratio"]) & (data["ratio"] > 0)
    total = weight.sum()
    fixed_agreement = float(np.sum(weight[~depends] * agree[~depends]))
    best = _best_threshold(data["ratio"][depends], optimal[depends], weight[depends])
    counts = (data["p2"], data["q2"], data["p3"], data["q3"])
    best_rule = rule_decisions(params, best["c"], data["z"], *counts)
    return {
        "statistics": int(np.count_nonzero(weight)),
        "agreement": float(np.sum(weight * agree) / total),
        "agreement_timer_past_agent_period": float(
            np.sum(weight * agree * past_agent) / np.sum(weight * past_agent)
        ),
        "optimal_vocalizes": float(np.sum(weight * optimal) / total),
        "rule_vocalizes": float(np.sum(weight * rule) / total),
        "optimal_vocalizes_rule_silent": float(np.sum(weight * (optimal & ~rule)) / total),
        "rule_vocalizes_optimal_silent": float(np.sum(weight * (~optimal & rule)) / total),
        "best_c": best["c"],
        "best_c_interval": [best["low"], best["high"]],
        "best_c_agreement": (fixed_agreement + best["agreement"]) / total,
        "best_c_agreement_checked": float(np.sum(weight * (best_rule == optimal)) / total),
    }


def experiment_rule(config: RuleConfig | None = None, cache_dir: Path | None = None) -> dict:
    """How often the rule picks the optimal episodic action at steps first..last.

    Three measures over the statistics ``(t, a)`` of those steps: uniform over those
    reachable under *some* policy, uniform over those the optimal policy reaches (with
    positive probability), and weighted by the optimal policy's visit probability with
    rooms drawn from the prior (each step's distribution sums to 1; steps weigh equally).
    Also the best c for each measure, and the exact episode score of the rule (c and the
    best weighted c) over the whole episode.
    """
    config = config or RuleConfig()
    params = ModelParams.load(config.params_name).for_table()  # the tables' model: one K2
    if not 1 <= config.first_step <= config.last_step < config.horizon:
        raise ValueError(f"need 1 <= first step <= last step < T = {config.horizon}")
    check_rule_constant(config.c)  # as rule:C is checked (nan and -1 printed results)
    table, path = obtain_table(params, EPISODIC, config.horizon, 0, cache_dir)
    data = rule_statistics(params, config, table_actions(table))
    measures = {
        "uniform_reachable_any_policy": data["any"].astype(float),
        "uniform_reachable_optimal_policy": data["visited"].astype(float),
        "weighted_optimal_visits": data["weight"],
    }
    results = {label: rule_agreement(params, data, weight) for label, weight in measures.items()}
    scorer = Scorer(params, config.horizon)
    best_weighted_c = results["weighted_optimal_visits"]["best_c"]
    return {
        "experiment": "rule",
        "params": config.params_name,
        "horizon": config.horizon,
        "steps": [config.first_step, config.last_step],
        "c": config.c,
        "table": str(path),
        "measures": results,
        "episode_score_rule_c": scorer.score(rule_actions(params, config.c)),
        "episode_score_rule_best_weighted_c": scorer.score(rule_actions(params, best_weighted_c)),
    }

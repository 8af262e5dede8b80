"""Evaluation of infomax controllers: exact episode scores, visit distributions, experiments.

Everything here is offline and reproducible. The exact parts run on the solver's
vectorised machinery over the whole finite state space (no sampling):

* **Policy score** (episodic, horizon T): the expected sum of ``-H(a_t)`` over
  ``t = 1 .. T`` from the episode start, computed by backward induction of the policy's own
  actions (:func:`infomax_contingency.core.solver.backward_induction` with ``fixed_actions``),
  normalised so that never vocalizing scores 0 and the DP optimum 1. Because the entropy
  at the start is fixed, the score is equally the expected information gained about S,
  summed over the episode, relative to the optimum's.
* **Episode start** (MODEL.md section 4): zero counts, ``z_1`` uniform in
  ``1 .. ta2 + 1``, then ``y_1`` from the prior predictive (counted in ``a_1`` unless
  ``z_1`` is a self-feedback timer value).
* **Visit distributions**: the probability of each statistic at each step when rooms are
  drawn from the prior, by forward propagation (with rooms drawn from the prior, the next
  bit given the history has exactly the model's predictive probability).
* **Reachable statistics**: those with positive probability at step t under *some*
  policy (every bit has a predictive probability strictly between 0 and 1, so this is
  reachability under both actions), or under one given policy.

An episodic policy is given as a function of the step ``t`` (1 .. T-1) returning its
boolean actions, shape ``(n_timer_values, n_count_tuples(t))``, rows the timer z, columns
:func:`~infomax_contingency.core.statespace.count_index` (the layout of policy-table layers).

The experiment functions (``experiment_*``) return plain JSON-serialisable dicts; the
command line (:mod:`infomax_contingency.cli.experiments`) prints them.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import tempfile
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from infomax_contingency.core import learning, model
from infomax_contingency.core.controllers import (
    Controller,
    PolicyController,
    make_controller,
    rule_decisions,
)
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import EPISODIC, RECEDING, PolicyTable, PolicyTableError
from infomax_contingency.core.scoring import (
    ActionsByStep,
    Scorer,
    greedy_actions,
    reachable_statistics,
    receding_layers,
    rule_actions,
    table_actions,
    visit_distributions,
)
from infomax_contingency.core.solver import (
    SOLVER_VERSION,
    solve,
)
from infomax_contingency.core.statespace import count_tuples, n_count_tuples
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.rooms import NAMED_BACKGROUNDS, PARTNER_REPLY, SELF_HEARING
from infomax_contingency.sim.simulation import StepRecord, simulate
from infomax_contingency.sim.world import Room, make_room, named_room

# --------------------------------------------------------------------------------------
# Policy tables: committed, cached, or solved now


def table_name(params: ModelParams, mode: str, horizon: int, memory: int = 0) -> str:
    """File name of a table: ``<set>_episodic_T<T>.npz`` or ``<set>_receding_H<H>_M<M>.npz``.

    ``<set>`` is the name of a reference parameter set, or ``params-<first 12 hex digits of
    the parameter hash>`` for other parameters.
    """
    label = next(
        (name for name, named in model.NAMED_PARAMS.items() if named == params),
        f"params-{params.digest()[:12]}",
    )
    if mode == EPISODIC:
        return f"{label}_episodic_T{horizon}.npz"
    return f"{label}_receding_H{horizon}_M{memory}.npz"


def default_cache_dir() -> Path:
    """Where solved tables are cached: ``$INFOMAX_CACHE_DIR`` or a directory under the temp dir."""
    configured = os.environ.get("INFOMAX_CACHE_DIR")
    if configured:
        return Path(configured)
    return Path(tempfile.gettempdir()) / "infomax_contingency_tables"


def obtain_table(
    params: ModelParams,
    mode: str,
    horizon: int,
    memory: int = 0,
    cache_dir: Path | None = None,
) -> tuple[PolicyTable, Path]:
    """A solved table and its file.

    The committed one in ``policies/`` if it exists, else one cached earlier, else solved
    now (a few seconds at most) and cached. A cached table from another solver version is
    solved again.
    """
    name = table_name(params, mode, horizon, memory)
    try:
        committed = resource_path("policies", name)
    except FileNotFoundError:
        committed = None
    if committed is not None:
        return PolicyTable.load(committed, expected_params=params), committed
    directory = cache_dir or default_cache_dir()
    path = directory / name
    if path.is_file():
        try:
            cached = PolicyTable.load(path, expected_params=params)
        except PolicyTableError:
            cached = None  # a damaged cache entry: solve again and overwrite it
        if cached is not None and cached.solver_version == SOLVER_VERSION:
            return cached, path
    table = solve(params, mode, horizon, memory)
    directory.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(f".{os.getpid()}.tmp")
    table.save(partial)
    partial.replace(path)
    return table, path


# --------------------------------------------------------------------------------------
# Experiment 1: the baby-9 scenario


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
    return simulate(params, PolicyController(table), room, steps, rng, memory=0)


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


# --------------------------------------------------------------------------------------
# Experiment 2: the interpretable rule against the optimal controller


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
    params = ModelParams.load(config.params_name)
    if not 1 <= config.first_step <= config.last_step < config.horizon:
        raise ValueError(f"need 1 <= first step <= last step < T = {config.horizon}")
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


# --------------------------------------------------------------------------------------
# Experiment 3: greedy (one-step) control


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


# --------------------------------------------------------------------------------------
# Experiment 4: how the optimal action map depends on the horizon


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


def horizon_set(config: HorizonConfig, name: str) -> dict:
    """The horizon experiment for one parameter set (see :func:`experiment_horizon`)."""
    params = ModelParams.load(name)
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
    if config.longest_horizon < max(config.horizons):
        raise ValueError("the longest horizon must be >= every listed horizon")
    return {
        "experiment": "horizon",
        "domain_max_count": config.domain_max_count,
        "longest_horizon": config.longest_horizon,
        "sets": [horizon_set(config, name) for name in config.param_names],
    }


# --------------------------------------------------------------------------------------
# Experiment 5: infomax TD learning curves


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
        target: the score a run should reach (0 = never vocalize, 1 = optimal).
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


def experiment_learn(config: LearnConfig | None = None) -> dict:
    """Learning curves: every method with every seed, the greedy policy scored exactly.

    Returns the parameter set, the horizon and one
    :meth:`~infomax_contingency.core.learning.LearningCurve.to_dict` record per run (its
    ``method`` the method's label), methods first, then seeds.
    """
    config = config or LearnConfig()
    params = ModelParams.load(config.params_name)
    scorer = Scorer(params, config.horizon)
    methods = [parse_method(text, config.budget) for text in config.methods]
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


# --------------------------------------------------------------------------------------
# Experiment 6: detection efficiency in simulated rooms

PRIOR_ROOM_SPEC = "prior:pi=0.5"
"""Rooms drawn from the model's priors, with a partner in half of them (in expectation)."""

SWITCHES = {"leaves": ("office+partner", "office"), "arrives": ("office", "office+partner")}
"""Scenarios of a changing room: (room before, room after) the switch."""


@dataclasses.dataclass
class SwitchingRoom:
    """A room that becomes another one after ``switch_step`` steps.

    A partner arrives or leaves. It draws bits like a
    :class:`~infomax_contingency.sim.world.Room`, so
    :func:`~infomax_contingency.sim.simulation.simulate` runs it; use a fresh one per run.
    """

    name: str
    before: Room
    after: Room
    switch_step: int
    steps_drawn: int = 0

    @property
    def partner_present(self) -> bool:
        """The truth after the switch."""
        return self.after.partner_present

    def draw_bit(self, z: int, rng: np.random.Generator) -> int:
        """One window's bit at timer value z (from the room of the current step)."""
        self.steps_drawn += 1
        room = self.before if self.steps_drawn <= self.switch_step else self.after
        return room.draw_bit(z, rng)


def efficiency_room(
    params: ModelParams, spec: str, rng: np.random.Generator
) -> Room | SwitchingRoom:
    """A room of the efficiency experiment.

    ``prior[:pi=P]`` (drawn), a named room, or ``leaves@S`` / ``arrives@S`` (office with a
    partner who leaves, or arrives, after S steps).
    """
    if spec.startswith("prior"):
        return make_room(spec, params, rng)
    scenario, at, step = spec.partition("@")
    if at:
        if scenario not in SWITCHES or not step.isdigit():
            raise ValueError(f"switching room {spec!r}: use leaves@STEP or arrives@STEP")
        before, after = SWITCHES[scenario]
        return SwitchingRoom(spec, named_room(params, before), named_room(params, after), int(step))
    return named_room(params, spec)


@functools.lru_cache(maxsize=32)
def _load_table(path: str, params: ModelParams) -> PolicyTable:
    return PolicyTable.load(path, expected_params=params)


def experiment_controller(spec: str, params: ModelParams, rng: np.random.Generator) -> Controller:
    """A controller from its spec (``make_controller``'s, or ``policy:FILE``).

    Policy tables are read once per process.
    """
    kind, _, argument = spec.partition(":")
    if kind == "policy":
        return PolicyController(_load_table(argument, params))
    return make_controller(spec, params, rng)


def beliefs_with_memory(params: ModelParams, records: Sequence, memory: int) -> np.ndarray:
    """P(S=1) after each step of a run, from a statistic with a sliding memory of M."""
    tracker = model.StatisticTracker(params, memory=memory)
    beliefs = []
    for record in records:
        beliefs.append(tracker.observe(record.y).belief(params))
        tracker.act(record.u)
    return np.array(beliefs)


def _first(condition: np.ndarray, start: int = 0) -> int | None:
    """1-based step of the first True at or after index ``start``, or None."""
    hits = np.flatnonzero(condition[start:])
    return int(hits[0]) + start + 1 if hits.size else None


def run_metrics(
    params: ModelParams,
    records: Sequence,
    room: Room | SwitchingRoom,
    memory: int,
    checkpoints: Sequence[int],
    confident: float,
) -> dict:
    """Figures of one simulated run.

    With the whole-history belief (the same observer for every controller): whether the
    decision (belief > 0.5 iff partner) is correct at each checkpoint step, the mean
    entropy per step, the vocalizations; in a partner room the step at which P(S=1)
    first reached ``confident`` and the vocalizations before it (None: never), in an
    empty room whether it ever did (a false alarm). With ``memory`` M > 0, the same
    detection step for the robot's own belief (sliding memory M, as the belief node
    keeps it). In a switching room (own belief), if the robot was confidently right just
    before the switch: steps from the switch until the belief falls below 0.5 (partner
    left) or reaches ``confident`` (partner arrived).
    """
    beliefs = np.array([r.belief for r in records])
    actions = np.array([r.u for r in records])
    partner = room.partner_present
    own = beliefs_with_memory(params, records, memory) if memory else beliefs
    result: dict[str, Any] = {
        "correct": [bool((beliefs[n - 1] > 0.5) == partner) for n in checkpoints],
        "mean_entropy": float(np.mean([r.entropy for r in records])),
        "vocalizations": int(actions.sum()),
        "detection_step": None,
        "detection_vocalizations": None,
        "own_detection_step": None,
        "false_alarm": None,
    }
    if isinstance(room, SwitchingRoom):
        # Only runs whose robot was confidently right just before the switch measure a
        # response to it: P(S=1) >= confident before a partner leaves, <= 1 - confident
        # before one arrives.
        before = own[room.switch_step - 1]
        sure = before <= 1.0 - confident if partner else before >= confident
        after = own[room.switch_step :]
        response = _first(after >= confident) if partner else _first(after < 0.5)
        result["sure_before_switch"] = bool(sure)
        result["switch_response_steps"] = response if sure else None
    elif partner:
        step = _first(beliefs >= confident)
        result["detection_step"] = step
        result["detection_vocalizations"] = int(actions[: step - 1].sum()) if step else None
        result["own_detection_step"] = _first(own >= confident)
    else:
        result["false_alarm"] = bool(np.any(beliefs >= confident))
    return result


@dataclasses.dataclass(frozen=True)
class Entry:
    """A controller of the experiment: label, controller spec, and the robot's memory M."""

    label: str
    spec: str
    memory: int = 0


def _simulate_rooms(
    params: ModelParams,
    entries: Sequence[Entry],
    rooms: Sequence[tuple[int, str]],
    steps: int,
    seed: int,
    checkpoints: Sequence[int],
    confident: float,
) -> list[dict]:
    """Every controller in every room; a room's bits use the same seed for every controller."""
    results = []
    for index, spec in rooms:
        for entry in entries:
            room = efficiency_room(params, spec, np.random.default_rng([seed, 0, index]))
            rng = np.random.default_rng([seed, 1, index])
            controller = experiment_controller(entry.spec, params, rng)
            records = simulate(params, controller, room, steps, rng)
            metrics = run_metrics(params, records, room, entry.memory, checkpoints, confident)
            results.append(
                {
                    "room": index,
                    "spec": spec,
                    "partner": room.partner_present,
                    "controller": entry.label,
                    **metrics,
                }
            )
    return results


def simulate_rooms(
    params: ModelParams,
    entries: Sequence[Entry],
    room_specs: Sequence[str],
    steps: int,
    seed: int,
    checkpoints: Sequence[int] = (10, 20, 40),
    confident: float = 0.95,
    workers: int = 1,
) -> list[dict]:
    """Run every controller in every room, in ``workers`` processes (same results for any)."""
    rooms = list(enumerate(room_specs))
    arguments = (params, entries)
    rest = (steps, seed, checkpoints, confident)
    if workers <= 1 or len(rooms) < 2:
        return _simulate_rooms(*arguments, rooms, *rest)
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = [
            pool.submit(_simulate_rooms, *arguments, rooms[i::workers], *rest)
            for i in range(workers)
        ]
        rows = [row for future in futures for row in future.result()]
    order = {entry.label: position for position, entry in enumerate(entries)}
    return sorted(rows, key=lambda row: (row["room"], order[row["controller"]]))


def wilson_interval(successes: int, total: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion."""
    if total == 0:
        return (math.nan, math.nan)
    p = successes / total
    centre = (p + z * z / (2 * total)) / (1 + z * z / total)
    half = z * math.sqrt(p * (1 - p) / total + z * z / (4 * total * total)) / (1 + z * z / total)
    return (max(0.0, centre - half), min(1.0, centre + half))


def mean_interval(values: np.ndarray) -> tuple[float, tuple[float, float]]:
    """Mean and its 95 % normal-approximation interval."""
    if values.size == 0:
        return (math.nan, (math.nan, math.nan))
    mean = float(values.mean())
    half = 1.96 * float(values.std(ddof=1)) / math.sqrt(values.size) if values.size > 1 else 0.0
    return (mean, (mean - half, mean + half))


def bootstrap_median(
    values: np.ndarray, rng: np.random.Generator, resamples: int = 2000
) -> tuple[float, tuple[float, float]]:
    """Median and its 95 % percentile-bootstrap interval (``inf`` entries: censored runs)."""
    if values.size == 0:
        return (math.nan, (math.nan, math.nan))
    draws = rng.integers(0, values.size, size=(resamples, values.size))
    medians = np.median(values[draws], axis=1)
    low = float(np.percentile(medians, 2.5, method="lower"))
    high = float(np.percentile(medians, 97.5, method="higher"))
    return (float(np.median(values)), (low, high))


def prior_weighted_entropy(rows: Sequence[dict], pi: float) -> tuple[float, tuple[float, float]]:
    """Mean entropy per step in rooms drawn from the prior with P(partner) = pi, and its 95 % CI.

    The rooms were drawn with a partner in about half of them; given the partner (or its
    absence) they follow the prior, so the expectation under the model's own prior is
    ``pi * mean(partner rooms) + (1 - pi) * mean(empty rooms)``: the quantity an infomax
    controller minimises.
    """
    groups = [
        np.array([row["mean_entropy"] for row in rows if row["partner"] == present])
        for present in (True, False)
    ]
    if any(group.size < 2 for group in groups):
        raise ValueError(
            "need at least two prior rooms with and two without a partner (use more prior rooms)"
        )
    weights = (pi, 1.0 - pi)
    mean = sum(w * g.mean() for w, g in zip(weights, groups, strict=True))
    half = 1.96 * math.sqrt(
        sum(w * w * g.var(ddof=1) / g.size for w, g in zip(weights, groups, strict=True))
    )
    return float(mean), (float(mean - half), float(mean + half))


def paired_entropy_difference(
    rows: Sequence[dict], reference: Sequence[dict], pi: float
) -> tuple[float, tuple[float, float]]:
    """Prior-weighted mean entropy per step minus a reference controller's, in the same rooms.

    Pairing each room with itself removes the spread between rooms (their rates), so the
    95 % interval is much narrower than the difference of two separate intervals.
    """
    by_room = {row["room"]: row for row in reference}
    paired = [
        {
            "partner": row["partner"],
            "mean_entropy": row["mean_entropy"] - by_room[row["room"]]["mean_entropy"],
        }
        for row in rows
    ]
    return prior_weighted_entropy(paired, pi)


def _steps_to_seconds(steps: Sequence[int | None], dt: float) -> np.ndarray:
    return np.array([math.inf if s is None else s * dt for s in steps], dtype=float)


def summarise(
    rows: Sequence[dict], dt: float, steps: int, checkpoints: Sequence[int], seed: int
) -> dict:
    """Figures with 95 % intervals for one controller in one group of rooms.

    Detection times are seconds from the start of the run to the end of the window at
    which the belief first reached the confidence level; runs that never reached it are
    censored: they count as infinite in the median and as the run's length in the
    restricted mean.
    """
    n = len(rows)
    summary: dict[str, Any] = {"runs": n}
    rng = np.random.default_rng(seed)
    for position, step in enumerate(checkpoints):
        correct = sum(row["correct"][position] for row in rows)
        summary[f"accuracy_{step}"] = correct / n if n else math.nan
        summary[f"accuracy_{step}_ci"] = wilson_interval(correct, n)
    summary["mean_entropy"], summary["mean_entropy_ci"] = mean_interval(
        np.array([row["mean_entropy"] for row in rows])
    )
    summary["vocalizations_per_run"] = float(np.mean([row["vocalizations"] for row in rows]))
    partner = [row for row in rows if row["partner"]]
    switching = [row for row in rows if "@" in row["spec"] and row["sure_before_switch"]]
    if any("@" in row["spec"] for row in rows):
        summary["sure_before_switch"] = len(switching) / n
        seconds = _steps_to_seconds([row["switch_response_steps"] for row in switching], dt)
        summary["switch_response_s_median"], summary["switch_response_s_ci"] = bootstrap_median(
            seconds, rng
        )
        responded = int(np.isfinite(seconds).sum())
        summary["switch_responded"] = responded / len(switching) if switching else math.nan
        summary["switch_responded_ci"] = wilson_interval(responded, len(switching))
        return summary
    if partner:
        for prefix, key in (("", "detection_step"), ("own_", "own_detection_step")):
            seconds = _steps_to_seconds([row[key] for row in partner], dt)
            detected = int(np.isfinite(seconds).sum())
            summary[f"{prefix}detected"] = detected / len(partner)
            summary[f"{prefix}detected_ci"] = wilson_interval(detected, len(partner))
            summary[f"{prefix}detection_s_median"], summary[f"{prefix}detection_s_ci"] = (
                bootstrap_median(seconds, rng)
            )
            (
                summary[f"{prefix}detection_s_restricted_mean"],
                summary[f"{prefix}detection_s_restricted_mean_ci"],
            ) = mean_interval(np.minimum(seconds, steps * dt))
        vocalizations = np.array(
            [
                math.inf if row["detection_step"] is None else row["detection_vocalizations"]
                for row in partner
            ],
            dtype=float,
        )
        summary["detection_vocalizations_median"], summary["detection_vocalizations_ci"] = (
            bootstrap_median(vocalizations, rng)
        )
    empty = [row for row in rows if not row["partner"]]
    if empty:
        alarms = sum(bool(row["false_alarm"]) for row in empty)
        summary["false_alarm_rate"] = alarms / len(empty)
        summary["false_alarm_ci"] = wilson_interval(alarms, len(empty))
    return summary


@dataclasses.dataclass(frozen=True)
class EfficiencyConfig:
    """Size and settings of the efficiency experiment.

    Attributes:
        params_name: parameter set.
        prior_rooms: rooms drawn from the prior (a partner with probability 1/2).
        named_runs: runs in each of the six named rooms.
        switch_runs: runs of each switching scenario (receding controllers only).
        switch_step: the step at which the partner leaves or arrives.
        tuning_rooms: prior rooms (other seeds) on which the fixed interval K is chosen.
        steps: steps per run.
        seed: master seed.
        episodic_horizon: T of the optimal episodic controller.
        receding: (H, M) candidates of the optimal receding controller.
        reference: the (H, M) candidate the others' entropy is compared with, pairwise.
        intervals: fixed intervals K tried.
        confident: the confidence level of a decision.
        workers: processes.
    """

    params_name: str = "robot"
    prior_rooms: int = 400
    named_runs: int = 50
    switch_runs: int = 100
    switch_step: int = 120
    tuning_rooms: int = 200
    steps: int = 240
    seed: int = 0
    episodic_horizon: int = 40
    receding: tuple[tuple[int, int], ...] = (
        (8, 60),
        (16, 60),
        (24, 60),
        (40, 60),
        (24, 20),
        (24, 40),
        (24, 80),
    )
    reference: tuple[int, int] = (24, 60)
    intervals: tuple[int, ...] = tuple(range(3, 13))
    confident: float = 0.95
    workers: int = 2


@dataclasses.dataclass(frozen=True)
class _Contenders:
    """The controllers of the efficiency experiment and the tables behind them.

    Attributes:
        entries: every controller, in the order of the tables.
        receding: the optimal receding candidates (also run in the switching rooms).
        reference: label of the receding candidate the others' entropy is compared with.
        episodic_table: the optimal episodic table.
        receding_tables: label -> table of each receding candidate.
    """

    entries: list[Entry]
    receding: list[Entry]
    reference: str
    episodic_table: PolicyTable
    receding_tables: dict[str, PolicyTable]


def _tune_fixed_interval(
    params: ModelParams, config: EfficiencyConfig, common: dict
) -> tuple[dict[int, float], int]:
    """Restricted mean detection seconds of each fixed interval K on the tuning rooms; best K."""
    tuning = simulate_rooms(
        params,
        [Entry(f"fixed:{k}", f"fixed:{k}") for k in config.intervals],
        [PRIOR_ROOM_SPEC] * config.tuning_rooms,
        config.steps,
        config.seed + 1,
        **common,
    )
    tuning_seconds = {}
    for k in config.intervals:
        partner = [r for r in tuning if r["controller"] == f"fixed:{k}" and r["partner"]]
        if not partner:
            raise ValueError("the tuning rooms hold no partner room: use more tuning rooms")
        seconds = _steps_to_seconds([r["detection_step"] for r in partner], params.dt)
        tuning_seconds[k] = float(np.minimum(seconds, config.steps * params.dt).mean())
    return tuning_seconds, min(tuning_seconds, key=tuning_seconds.get)


def _contenders(
    params: ModelParams, config: EfficiencyConfig, best_k: int, cache_dir: Path | None
) -> _Contenders:
    """The optimal tables (committed or solved now), rule, greedy, fixed K and random 1/K."""
    episodic_table, path = obtain_table(params, EPISODIC, config.episodic_horizon, 0, cache_dir)
    entries = [Entry(f"optimal episodic T={config.episodic_horizon}", f"policy:{path}")]
    receding, receding_tables = [], {}
    for horizon, memory in config.receding:
        table, path = obtain_table(params, RECEDING, horizon, memory, cache_dir)
        label = f"optimal receding H={horizon} M={memory}"
        receding.append(Entry(label, f"policy:{path}", memory))
        receding_tables[label] = table
    entries += receding + [
        Entry("rule c=9", "rule:9"),
        Entry("greedy", "greedy"),
        Entry(f"fixed K={best_k}", f"fixed:{best_k}"),
        Entry(f"random P=1/{best_k}", f"random:{1.0 / best_k!r}"),
    ]
    reference = f"optimal receding H={config.reference[0]} M={config.reference[1]}"
    return _Contenders(entries, receding, reference, episodic_table, receding_tables)


def _efficiency_rows(
    params: ModelParams, config: EfficiencyConfig, contenders: _Contenders, common: dict
) -> list[dict]:
    """Every controller in the prior and named rooms; the receding ones in switching rooms."""
    rooms = [PRIOR_ROOM_SPEC] * config.prior_rooms
    for name in NAMED_BACKGROUNDS:
        rooms += [name] * config.named_runs + [f"{name}+partner"] * config.named_runs
    rows = simulate_rooms(params, contenders.entries, rooms, config.steps, config.seed, **common)
    switch_specs = [
        f"{scenario}@{config.switch_step}"
        for scenario in SWITCHES
        for _ in range(config.switch_runs)
    ]
    rows += simulate_rooms(
        params, contenders.receding, switch_specs, config.steps, config.seed + 2, **common
    )
    return rows


def _room_groups() -> dict[str, Callable[[dict], bool]]:
    """The groups of rooms a controller is summarised over: name -> which rows it holds."""
    groups: dict[str, Callable[[dict], bool]] = {
        "prior, partner": lambda row: row["spec"] == PRIOR_ROOM_SPEC and row["partner"],
        "prior, no partner": lambda row: row["spec"] == PRIOR_ROOM_SPEC and not row["partner"],
    }
    for name in NAMED_BACKGROUNDS:
        for room_name in (name, f"{name}+partner"):
            groups[room_name] = lambda row, room_name=room_name: row["spec"] == room_name
    for scenario in SWITCHES:
        groups[f"partner {scenario}"] = lambda row, s=scenario: row["spec"].startswith(f"{s}@")
    return groups


def _efficiency_summaries(
    params: ModelParams,
    config: EfficiencyConfig,
    contenders: _Contenders,
    rows: Sequence[dict],
    checkpoints: Sequence[int],
) -> dict[str, dict]:
    """Per controller: prior-weighted entropy (and minus the reference's), each group's figures."""
    groups = _room_groups()
    reference_rows = [
        row
        for row in rows
        if row["controller"] == contenders.reference and row["spec"] == PRIOR_ROOM_SPEC
    ]
    summaries = {}
    for entry in contenders.entries:
        mine = [row for row in rows if row["controller"] == entry.label]
        prior_rows = [row for row in mine if row["spec"] == PRIOR_ROOM_SPEC]
        weighted = prior_weighted_entropy(prior_rows, params.pi)
        difference = paired_entropy_difference(prior_rows, reference_rows, params.pi)
        summaries[entry.label] = {
            "prior_weighted_entropy": weighted[0],
            "prior_weighted_entropy_ci": weighted[1],
            "entropy_minus_reference": difference[0],
            "entropy_minus_reference_ci": difference[1],
        }
        for group, keep in groups.items():
            selected = [row for row in mine if keep(row)]
            if selected:
                summaries[entry.label][group] = summarise(
                    selected, params.dt, config.steps, checkpoints, config.seed
                )
    return summaries


def _exact_episode_scores(
    params: ModelParams, config: EfficiencyConfig, contenders: _Contenders, best_k: int
) -> dict[str, float | None]:
    """The exact episode score of each controller that is a deterministic policy of (t, a)."""
    horizon = config.episodic_horizon
    policies: dict[str, ActionsByStep | None] = {
        contenders.entries[0].label: table_actions(contenders.episodic_table)
    }
    for label, table in contenders.receding_tables.items():
        layer = table.layer(0)
        policies[label] = (
            (lambda t, layer=layer: layer[:, : n_count_tuples(t)])
            if table.memory >= horizon
            else None  # its sliding memory forgets within an episode: not a policy on a_t
        )
    greedy = greedy_actions(params, horizon)
    policies.update(
        {
            "rule c=9": rule_actions(params, 9.0),
            "greedy": lambda t: greedy[:, : n_count_tuples(t)],
            f"fixed K={best_k}": lambda t: np.full(
                (params.n_timer_values, n_count_tuples(t)), t % best_k == 0
            ),
            f"random P=1/{best_k}": None,  # randomised: not a deterministic policy
        }
    )
    scorer = Scorer(params, horizon)
    return {
        label: None if actions is None else scorer.score(actions)
        for label, actions in policies.items()
    }


def experiment_efficiency(config: EfficiencyConfig, cache_dir: Path | None = None) -> dict:
    """Detection efficiency of every controller in prior, named and switching rooms.

    The fixed interval K is the one with the least restricted mean detection time in the
    partner rooms of a separate set of prior rooms; the random controller vocalizes with
    probability 1/K (the same rate). Tables are the committed ones or solved now.
    """
    params = ModelParams.load(config.params_name)
    if config.switch_step >= config.steps:
        raise ValueError("the switch step must fall inside the run (switch_step < steps)")
    if config.reference not in config.receding:
        raise ValueError(f"the reference {config.reference} must be one of the (H, M) candidates")
    checkpoints = tuple(n for n in (10, 20, 40) if n <= config.steps)
    common = {"checkpoints": checkpoints, "confident": config.confident, "workers": config.workers}
    tuning_seconds, best_k = _tune_fixed_interval(params, config, common)
    contenders = _contenders(params, config, best_k, cache_dir)
    rows = _efficiency_rows(params, config, contenders, common)
    return {
        "experiment": "efficiency",
        "reference": contenders.reference,
        "exact_episode_scores": _exact_episode_scores(params, config, contenders, best_k),
        "config": dataclasses.asdict(config),
        "dt": params.dt,
        "checkpoints": list(checkpoints),
        "rooms": {
            "backgrounds_k3": NAMED_BACKGROUNDS,
            "partner_reply": PARTNER_REPLY,
            "self_hearing_k1": SELF_HEARING,
            "prior": PRIOR_ROOM_SPEC,
            "switches": {k: list(v) for k, v in SWITCHES.items()},
        },
        "fixed_interval_tuning_restricted_mean_s": tuning_seconds,
        "best_fixed_interval": best_k,
        "controllers": [entry.label for entry in contenders.entries],
        "receding_memories": {entry.label: entry.memory for entry in contenders.receding},
        "summaries": _efficiency_summaries(params, config, contenders, rows, checkpoints),
    }

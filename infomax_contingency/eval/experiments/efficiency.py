"""Experiment 6: detection efficiency of every controller in simulated rooms.

Rooms drawn from the prior, the named rooms and switching rooms (:mod:`.runs`); the fixed
interval K tuned on separate prior rooms; figures with 95 % intervals per controller and
group of rooms (:mod:`.summaries`) and the exact episode score of each deterministic
controller.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import EPISODIC, RECEDING, PolicyTable
from infomax_contingency.core.scoring import (
    ActionsByStep,
    Scorer,
    greedy_actions,
    rule_actions,
    table_actions,
)
from infomax_contingency.core.statespace import n_count_tuples
from infomax_contingency.eval.experiments.runs import (
    PRIOR_ROOM_SPEC,
    SWITCHES,
    Entry,
    simulate_rooms,
)
from infomax_contingency.eval.experiments.summaries import (
    paired_entropy_difference,
    prior_weighted_entropy,
    steps_to_seconds,
    summarise,
)
from infomax_contingency.eval.experiments.tables import obtain_table
from infomax_contingency.eval.workers import WORKER_BYTES, check_workers
from infomax_contingency.limits import refuse_over_budget
from infomax_contingency.sim.rooms import NAMED_BACKGROUNDS, PARTNER_REPLY, SELF_HEARING
from infomax_contingency.sim.simulation import RECORD_BYTES


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


EFFICIENCY_BASE_BYTES = 2**30
"""Memory of the experiment apart from its runs (the tables, the exact scorer of T = 40),
bytes: measured 0.9 GB peak resident for a handful of runs in one process."""
EFFICIENCY_ROW_BYTES = 2 * 2**10
"""Memory of one run's figures kept until the summaries, bytes (measured 0.8-1.2 KiB)."""


def efficiency_runs(config: EfficiencyConfig) -> int:
    """Runs of the experiment (tuning, every controller in the rooms, the switching rooms)."""
    controllers = 1 + len(config.receding) + 4  # episodic, receding, rule, greedy, fixed, random
    rooms = config.prior_rooms + 2 * len(NAMED_BACKGROUNDS) * config.named_runs
    return (config.tuning_rooms * len(config.intervals) + rooms * controllers
            + len(SWITCHES) * config.switch_runs * len(config.receding))  # fmt: skip


def refuse_oversized_efficiency(config: EfficiencyConfig) -> None:
    """Refuse, before any run, sizes that cannot run or would not fit in memory (one line).

    The estimate: :data:`EFFICIENCY_BASE_BYTES`, each worker process with the records of
    the run it holds (``steps`` records of
    :data:`~infomax_contingency.sim.simulation.RECORD_BYTES`), and every run's figures
    twice (a worker's are copied to this process at once).
    """
    check_workers(config.workers, "--workers")
    for name, least in (("prior_rooms", 0), ("named_runs", 1), ("switch_runs", 1),
                        ("tuning_rooms", 0)):  # fmt: skip
        if (count := getattr(config, name)) < least:  # the report compares named rooms
            raise ValueError(f"--{name.replace('_', '-')} must be >= {least}, got {count}")
    if config.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {config.steps}")
    runs = efficiency_runs(config)
    needed = (EFFICIENCY_BASE_BYTES + config.workers * (WORKER_BYTES + RECORD_BYTES * config.steps)
              + 2 * EFFICIENCY_ROW_BYTES * runs)  # fmt: skip
    refuse_over_budget(needed, f"run experiment efficiency: {runs:,} runs of {config.steps:,}"
                       f" steps in {config.workers} processes",
                       "give fewer runs or rooms, fewer --steps or fewer --workers")


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
        seconds = steps_to_seconds([r["detection_step"] for r in partner], params.dt)
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
    refuse_oversized_efficiency(config)
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

"""Evaluation of infomax controllers: the experiments, one module each.

* :mod:`.baby9` — experiment 1, the baby-9 scenario (MODEL.md section 5);
* :mod:`.rule` — experiment 2, the interpretable rule against the optimal controller;
* :mod:`.greedy` — experiment 3, what one-step (H = 1) infomax control does;
* :mod:`.horizon` — experiment 4, how the optimal action map depends on the horizon;
* :mod:`.learn` — experiment 5, infomax TD learning curves;
* :mod:`.efficiency` — experiment 6, detection efficiency in simulated rooms, run by
  :mod:`.runs` (its rooms, controllers and per-run figures) and summarised by
  :mod:`.summaries` (95 % intervals);
* :mod:`.tables` — the policy tables they use: committed, cached, or solved now.

The audio-level rooms experiment (``experiment rooms``) is :mod:`infomax_contingency.eval.rooms`.

Everything here is offline and reproducible. The exact parts run on the solver's
vectorised machinery over the whole finite state space (no sampling,
:mod:`infomax_contingency.core.scoring`):

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
command line (:mod:`infomax_contingency.cli.experiments`) prints them. The public names
of every module are importable from this package.
"""

from __future__ import annotations

from infomax_contingency.eval.experiments.baby9 import (
    Baby9Config,
    baby9_run_summary,
    baby9_session,
    experiment_baby9,
)
from infomax_contingency.eval.experiments.efficiency import (
    EFFICIENCY_BASE_BYTES,
    EFFICIENCY_ROW_BYTES,
    EfficiencyConfig,
    efficiency_runs,
    experiment_efficiency,
    refuse_oversized_efficiency,
)
from infomax_contingency.eval.experiments.greedy import (
    GreedyConfig,
    experiment_greedy,
    greedy_set,
    refuse_oversized_greedy,
)
from infomax_contingency.eval.experiments.horizon import (
    HorizonConfig,
    experiment_horizon,
    horizon_set,
    refuse_oversized_horizon,
)
from infomax_contingency.eval.experiments.learn import (
    LEARN_BASE_BYTES,
    LEARN_BYTES_PER_STATISTIC,
    LEARN_CURVE_POINT_BYTES,
    LearnConfig,
    experiment_learn,
    learning_cost_bytes,
    parse_method,
)
from infomax_contingency.eval.experiments.rule import (
    RULE_STATISTIC_FIELDS,
    RuleConfig,
    experiment_rule,
    rule_agreement,
    rule_statistics,
)
from infomax_contingency.eval.experiments.runs import (
    PRIOR_ROOM_SPEC,
    SWITCHES,
    Entry,
    SwitchingRoom,
    beliefs_with_memory,
    efficiency_room,
    experiment_controller,
    run_metrics,
    simulate_rooms,
)
from infomax_contingency.eval.experiments.summaries import (
    bootstrap_median,
    detection_figures,
    mean_interval,
    paired_entropy_difference,
    prior_weighted_entropy,
    steps_to_seconds,
    summarise,
    wilson_interval,
)
from infomax_contingency.eval.experiments.tables import (
    default_cache_dir,
    obtain_table,
    table_name,
)

__all__ = [
    "EFFICIENCY_BASE_BYTES",
    "EFFICIENCY_ROW_BYTES",
    "LEARN_BASE_BYTES",
    "LEARN_BYTES_PER_STATISTIC",
    "LEARN_CURVE_POINT_BYTES",
    "PRIOR_ROOM_SPEC",
    "RULE_STATISTIC_FIELDS",
    "SWITCHES",
    "Baby9Config",
    "EfficiencyConfig",
    "Entry",
    "GreedyConfig",
    "HorizonConfig",
    "LearnConfig",
    "RuleConfig",
    "SwitchingRoom",
    "baby9_run_summary",
    "baby9_session",
    "beliefs_with_memory",
    "bootstrap_median",
    "default_cache_dir",
    "detection_figures",
    "efficiency_room",
    "efficiency_runs",
    "experiment_baby9",
    "experiment_controller",
    "experiment_efficiency",
    "experiment_greedy",
    "experiment_horizon",
    "experiment_learn",
    "experiment_rule",
    "greedy_set",
    "horizon_set",
    "learning_cost_bytes",
    "mean_interval",
    "obtain_table",
    "paired_entropy_difference",
    "parse_method",
    "prior_weighted_entropy",
    "refuse_oversized_efficiency",
    "refuse_oversized_greedy",
    "refuse_oversized_horizon",
    "rule_agreement",
    "rule_statistics",
    "run_metrics",
    "simulate_rooms",
    "steps_to_seconds",
    "summarise",
    "table_name",
    "wilson_interval",
]

"""``experiment NAME``: one sub-command per experiment, with the options they all take."""

from __future__ import annotations

import argparse
from collections.abc import Callable

from infomax_contingency.cli.experiments.baby9 import add_baby9_arguments, run_baby9
from infomax_contingency.cli.experiments.efficiency import (
    add_efficiency_arguments,
    run_efficiency,
)
from infomax_contingency.cli.experiments.greedy import add_greedy_arguments, run_greedy
from infomax_contingency.cli.experiments.horizon import add_horizon_arguments, run_horizon
from infomax_contingency.cli.experiments.rule import add_rule_arguments, run_rule
from infomax_contingency.cli.rooms import add_experiment_rooms_arguments, run_experiment_rooms

ExperimentCommand = tuple[
    str, str, Callable[[argparse.Namespace], int], Callable[[argparse.ArgumentParser], None]
]
"""An experiment sub-command: name, help, run function, function adding its own options."""

EXPERIMENTS: tuple[ExperimentCommand, ...] = (
    ("baby9", "the baby-9 scenario (MODEL.md section 5)", run_baby9, add_baby9_arguments),
    (
        "rule",
        "the interpretable rule against the optimal controller",
        run_rule,
        add_rule_arguments,
    ),
    ("greedy", "what one-step (H = 1) infomax control does", run_greedy, add_greedy_arguments),
    (
        "horizon",
        "how the optimal action map changes with the horizon",
        run_horizon,
        add_horizon_arguments,
    ),
    (
        "efficiency",
        "detection efficiency of all controllers",
        run_efficiency,
        add_efficiency_arguments,
    ),
    (
        "rooms",
        "from a room's sound to the posture: audio rooms, controllers, operating curves",
        run_experiment_rooms,
        add_experiment_rooms_arguments,
    ),
)
"""The experiment sub-commands, in the order of ``experiment --help``."""


def register_experiment(subparsers: argparse._SubParsersAction) -> None:
    """``experiment NAME``: the evaluation experiments (docs/RESULTS.md)."""
    parser = subparsers.add_parser(
        "experiment",
        help="run an evaluation experiment (baby9, rule, greedy, horizon, efficiency, rooms)",
    )
    names = parser.add_subparsers(dest="experiment", required=True, metavar="NAME")
    for name, help_text, run, add_arguments in EXPERIMENTS:
        sub = names.add_parser(name, help=help_text)
        sub.add_argument("--json", action="store_true", help="print the result as JSON")
        sub.add_argument(
            "--cache-dir",
            help="where tables solved at run time are cached (default: $INFOMAX_CACHE_DIR or"
            " a directory under the system temp dir)",
        )
        sub.set_defaults(run=run)
        add_arguments(sub)

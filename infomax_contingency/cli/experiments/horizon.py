"""``experiment horizon``: the optimal action map against the horizon H.

The experiment is :mod:`infomax_contingency.eval.experiments.horizon`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from infomax_contingency.cli.experiments.options import (
    add_parameter_sets_option,
    commas,
    int_list,
    print_json,
)
from infomax_contingency.cli.formatting import number
from infomax_contingency.eval import plots
from infomax_contingency.eval.experiments.horizon import HorizonConfig, experiment_horizon
from infomax_contingency.limits import check_output_files


def run_horizon(args: argparse.Namespace) -> int:
    """Run ``experiment horizon``; print its table (or JSON), write the maps if asked."""
    config = HorizonConfig(tuple(args.params), tuple(args.horizons), args.domain, args.longest)
    targets = {name: Path(args.plot) for name in args.params} if args.plot is not None else {}
    if len(targets) > 1:  # one figure per set: NAME_SET.png
        targets = {name: path.with_name(f"{path.stem}_{name}{path.suffix}")
                   for name, path in targets.items()}
    check_output_files(*(("--plot", path, "figure") for path in targets.values()))
    result = experiment_horizon(config)
    if args.plot:
        for name, target in targets.items():
            plots.plot_horizon_maps(result, target, name)
            print(f"wrote {target}", file=sys.stderr if args.json else sys.stdout)
    if args.json:
        print_json(result)
        return 0
    print(
        f"receding policy_H on counts n2 + n3 <= {result['domain_max_count']} (every z),"
        f" horizons 1..{result['longest_horizon']} solved"
    )
    for entry in result["sets"]:
        print(f"{entry['params']} ({entry['statistics']:,} statistics):")
        print(f"  {'H':>4} {'vocalize':>9} {'vs prev':>8} {'vs last':>8} {'vs H_max':>8}")
        for item in entry["horizons"]:
            print(
                f"  {item['horizon']:>4} {item['vocalizing_statistics']:>9}"
                f" {number(item['differs_from_previous'])!s:>8}"
                f" {item['differs_from_largest_listed']:>8} {item['differs_from_longest']:>8}"
            )
        print(
            f"  the map stops changing from H = {entry['stable_from']} on (identical up to"
            f" H = {result['longest_horizon']})"
        )
    return 0


def add_horizon_arguments(sub: argparse.ArgumentParser) -> None:
    """The options of ``experiment horizon`` (defaults: :class:`HorizonConfig`)."""
    d = HorizonConfig()
    add_parameter_sets_option(sub, d.param_names)
    sub.add_argument(
        "--horizons",
        type=int_list,
        default=list(d.horizons),
        help=f"horizons to list (default {commas(d.horizons)})",
    )
    sub.add_argument(
        "--domain",
        type=int,
        default=d.domain_max_count,
        help=f"compare on counts n2 + n3 <= this (default {d.domain_max_count})",
    )
    sub.add_argument(
        "--longest",
        type=int,
        default=d.longest_horizon,
        help=f"solve horizons up to this one (default {d.longest_horizon})",
    )
    sub.add_argument("--plot", help="write the action maps to this PNG (one per set)")

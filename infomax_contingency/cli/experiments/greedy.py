"""``experiment greedy``: what one-step infomax control does.

The experiment is :mod:`infomax_contingency.eval.experiments.greedy`.
"""

from __future__ import annotations

import argparse
import dataclasses

from infomax_contingency.cli.experiments.options import add_parameter_sets_option, print_json
from infomax_contingency.eval.experiments.greedy import GreedyConfig, experiment_greedy


def run_greedy(args: argparse.Namespace) -> int:
    """Run ``experiment greedy``; print what it found per parameter set (or JSON)."""
    config = dataclasses.replace(
        GreedyConfig(),
        param_names=tuple(args.params),
        max_count=args.max_count,
        steps=args.steps,
    )
    result = experiment_greedy(config)
    if args.json:
        print_json(result)
        return 0
    for entry in result["sets"]:
        print(f"{entry['params']}:")
        print(
            f"  greedy (H = 1) vocalizes at {entry['greedy_vocalizing_statistics']} of"
            f" {entry['statistics']:,} statistics (counts n <= {result['max_count']}, every z)"
        )
        by_horizon = ", ".join(
            f"H={h}: {n:,}" for h, n in entry["vocalizing_statistics_by_horizon"].items()
        )
        print(f"  vocalizing statistics by horizon: {by_horizon}")
        print(f"  smallest horizon that ever vocalizes: {entry['smallest_vocalizing_horizon']}")
        print(
            f"  at a = {tuple(entry['example_statistic'])}: H(a) ="
            f" {entry['example_entropy_bits']:.6f} bits; expected next entropy if silent"
            f" {entry['example_next_entropy_silent_bits']:.6f}, if vocalizing"
            f" {entry['example_next_entropy_vocalize_bits']:.6f} (the next window is"
            " self-feedback: nothing is learned)"
        )
        print(
            f"  greedy in a responsive room, {entry['run_steps']} steps:"
            f" {entry['run_vocalizations']} vocalizations, final P(S=1) ="
            f" {entry['run_final_belief']:.6f} (prior {entry['prior']})"
        )
    return 0


def add_greedy_arguments(sub: argparse.ArgumentParser) -> None:
    """The options of ``experiment greedy`` (defaults: :class:`GreedyConfig`)."""
    d = GreedyConfig()
    add_parameter_sets_option(sub, d.param_names)
    sub.add_argument(
        "--max-count",
        type=int,
        default=d.max_count,
        help=f"check statistics with n <= this (default {d.max_count})",
    )
    sub.add_argument(
        "--steps", type=int, default=d.steps, help=f"steps of the example run (default {d.steps})"
    )

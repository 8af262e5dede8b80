"""``experiment baby9``: the baby-9 scenario.

The experiment is :mod:`infomax_contingency.eval.experiments.baby9`.
"""

from __future__ import annotations

import argparse

from infomax_contingency.cli.experiments.options import (
    cache_dir_of,
    commas,
    name_list,
    print_json,
)
from infomax_contingency.cli.formatting import number
from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval import plots
from infomax_contingency.eval.experiments.baby9 import Baby9Config, baby9_session, experiment_baby9
from infomax_contingency.eval.experiments.tables import obtain_table
from infomax_contingency.limits import check_output_files


def run_baby9(args: argparse.Namespace) -> int:
    """Run ``experiment baby9``; print its table (or JSON), write the figure if asked."""
    check_output_files(("--plot", args.plot, "figure"))  # before the work
    config = Baby9Config(args.params, args.horizon, args.memory, args.steps, tuple(args.replies))
    result = experiment_baby9(config, cache_dir_of(args))
    if args.plot:
        params = ModelParams.load(args.params)
        table, _ = obtain_table(params, "receding", args.horizon, args.memory, cache_dir_of(args))
        records = baby9_session(params, table, args.replies[0], args.steps)
        plots.plot_session(
            params,
            [r.__dict__ for r in records],
            args.plot,
            title=f"baby-9 (reply={args.replies[0]}): {args.params} parameters,"
            f" receding H={args.horizon}",
        )
        result["plot"] = args.plot
    if args.json:
        print_json(result)
        return 0
    print(
        f"baby-9: {result['params']} parameters (dt = {result['dt']} s), receding H ="
        f" {result['horizon']}, memory M = {result['memory']} (>= {result['steps']} steps:"
        f" unbounded), {result['steps']} steps = {result['duration_s']:g} s"
    )
    print("(a vocalization decided at step t is played at t * dt seconds)")
    for run in result["runs"]:
        print(f"\nreply = {run['reply']}:")
        print(f"  {'step':>4} {'time_s':>7} {'belief':>10} {'ratio':>8}")
        for step, when, belief, ratio in zip(
            run["vocalization_steps"],
            run["vocalization_times_s"],
            run["belief_at_vocalization"],
            run["ratio_at_vocalization"],
            strict=True,
        ):
            print(f"  {step:>4} {when:>7.1f} {belief:>10.6f} {number(ratio, 4):>8}")
        intervals = ", ".join(f"{i:g}" for i in run["intervals_s"])
        print(f"  intervals (s): {intervals}")
        print(f"  final P(S=1) = {run['final_belief']:.10f}")
    if args.plot:
        print(f"\nwrote {args.plot}")
    return 0


def add_baby9_arguments(sub: argparse.ArgumentParser) -> None:
    """The options of ``experiment baby9`` (defaults: :class:`Baby9Config`)."""
    d = Baby9Config()
    seconds = round(d.steps * ModelParams.named(d.params_name).dt, 9)
    sub.add_argument(
        "--params", default=d.params_name, help=f"parameter set (default: {d.params_name})"
    )
    sub.add_argument(
        "--horizon", type=int, default=d.horizon, help=f"receding horizon H (default {d.horizon})"
    )
    sub.add_argument(
        "--memory", type=int, default=d.memory, help=f"table memory M >= steps (default {d.memory})"
    )
    sub.add_argument(
        "--steps", type=int, default=d.steps, help=f"steps (default {d.steps} = {seconds:g} s)"
    )
    sub.add_argument(
        "--replies",
        type=name_list,
        default=list(d.replies),
        help="reply conventions: all, or a timer value of the agent period"
        f" (default {commas(d.replies)})",
    )
    sub.add_argument("--plot", help="write the session figure of the first reply to this PNG")

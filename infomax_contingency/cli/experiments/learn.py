"""``learn``: infomax TD learning curves.

The experiment is :mod:`infomax_contingency.eval.experiments.learn`.
"""

from __future__ import annotations

import argparse

from infomax_contingency.cli.experiments.options import commas, int_list, print_json
from infomax_contingency.core import learning
from infomax_contingency.eval import plots
from infomax_contingency.eval.experiments.learn import LearnConfig, experiment_learn
from infomax_contingency.limits import check_output_files


def _run_learn(args: argparse.Namespace) -> int:
    check_output_files(("--plot", args.plot, "figure"))  # before the work
    config = LearnConfig(
        params_name=args.params,
        horizon=args.horizon,
        methods=tuple(args.method or LearnConfig().methods),
        budget=args.budget,
        seeds=tuple(args.seeds),
        evaluate_every=args.evaluate_every,
        evaluate_growth=args.evaluate_growth,
        target=args.target,
    )
    result = experiment_learn(config)
    curves = result["curves"]
    if args.plot:
        plots.plot_learning_curves(curves, args.plot, args.target)
    if args.json:
        print_json(result)
        return 0
    print(
        f"infomax TD learning, {args.params} parameters, T = {args.horizon}; score of the"
        f" greedy learned policy (exact; 0 = never vocalize, 1 = optimal), target {args.target}"
    )
    print(
        f"{'method':44} {'seed':>5} {'budget':>10} {'trials':>9} {'final':>7} {'max':>7}"
        f" {'first >= target':>16} {'stays from':>12} {'time':>7}"
    )
    for curve in curves:
        print(
            f"{curve['method']:44} {curve['seed']:>5} {curve['vocalizations'][-1]:>10,}"
            f" {curve['trials'][-1]:>9,} {curve['scores'][-1]:>7.4f} {max(curve['scores']):>7.4f}"
            f" {learning.format_vocalizations(curve['first_reaching']):>16}"
            f" {learning.format_vocalizations(curve['staying_from']):>12}"
            f" {curve['seconds']:>6.1f}s"
        )
    if args.plot:
        print(f"wrote {args.plot}")
    return 0


def register_learn(subparsers: argparse._SubParsersAction) -> None:
    """``learn``: infomax TD learning curves, scored exactly."""
    d = LearnConfig()
    parser = subparsers.add_parser(
        "learn", help="learn the episodic policy by infomax TD learning; exact learning curves"
    )
    parser.add_argument(
        "--params", default=d.params_name, help=f"parameter set (default: {d.params_name})"
    )
    parser.add_argument(
        "--horizon", type=int, default=d.horizon, help=f"episode length T (default {d.horizon})"
    )
    parser.add_argument(
        "--method",
        action="append",
        help="NAME[@BUDGET] with NAME plain (MODEL.md) or improved, or"
        " epsilon=E,backup=taken|best,initial=zero|entropy|listening[@BUDGET];"
        f" repeat for several (default: {commas(d.methods)})",
    )
    parser.add_argument(
        "--budget", type=int, default=d.budget, help=f"vocalizations per run (default {d.budget})"
    )
    parser.add_argument(
        "--seeds",
        type=int_list,
        default=list(d.seeds),
        help=f"seeds, e.g. 1,2,3 (default {commas(d.seeds)})",
    )
    parser.add_argument(
        "--evaluate-every",
        type=int,
        default=d.evaluate_every,
        help=f"score every N vocalizations ({d.evaluate_every})",
    )
    parser.add_argument(
        "--evaluate-growth",
        type=float,
        default=d.evaluate_growth,
        help="also wait until the vocalizations grew by this fraction (e.g. 0.05: log-spaced"
        f" points on long runs; default {d.evaluate_growth:g})",
    )
    parser.add_argument(
        "--target", type=float, default=d.target, help=f"score target ({d.target:g})"
    )
    parser.add_argument("--plot", help="write the learning curves to this PNG")
    parser.add_argument("--json", action="store_true", help="print the curves as JSON")
    parser.set_defaults(run=_run_learn)

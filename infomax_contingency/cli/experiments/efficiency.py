"""Command-line sub-commands of the evaluation suite: ``experiment``, ``learn``, ``plot``.

* ``experiment baby9 | rule | greedy | horizon | efficiency`` — the experiments of
  :mod:`infomax_contingency.eval.experiments` (readable tables, or ``--json``);
  ``experiment rooms`` — :mod:`infomax_contingency.eval.rooms` (:mod:`.rooms`).
* ``learn`` — infomax TD learning curves (:mod:`infomax_contingency.core.learning`).
* ``plot`` — the four-panel figure of a simulated or recorded session.

Every command is deterministic given its seeds; docs/RESULTS.md lists the commands that
produced every reported number and figure.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from infomax_contingency.cli.formatting import json_default, number
from infomax_contingency.cli.rooms import add_experiment_rooms_arguments, run_experiment_rooms
from infomax_contingency.core import learning
from infomax_contingency.core.controllers import CONTROLLER_KINDS, make_controller
from infomax_contingency.core.model import NAMED_PARAMS, ModelParams
from infomax_contingency.eval import experiments as evaluation
from infomax_contingency.eval import plots
from infomax_contingency.eval.experiments import parse_method

__all__ = [
    "parse_method",
    "print_efficiency",
    "register_experiment",
    "register_learn",
    "register_plot",
]
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.simulation import simulate
from infomax_contingency.sim.world import BIT_ROOM_NAMES, make_room


def _int_list(text: str) -> list[int]:
    try:
        values = [int(item) for item in text.split(",") if item.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected integers separated by commas, got {text!r}"
        ) from None
    if not values:
        raise argparse.ArgumentTypeError("expected at least one integer")
    return values


def _name_list(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def _step_range(text: str) -> tuple[int, int]:
    first, _, last = text.partition("-")
    try:
        return int(first), int(last or first)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected FIRST-LAST steps, e.g. 18-24, got {text!r}"
        ) from None


def _dump(result: Any) -> None:
    print(json.dumps(result, indent=1, default=json_default))


def _cache_dir(args: argparse.Namespace) -> Path | None:
    return Path(args.cache_dir) if args.cache_dir else None


# --------------------------------------------------------------------------------------
# experiment NAME


def _run_baby9(args: argparse.Namespace) -> int:
    config = evaluation.Baby9Config(
        args.params, args.horizon, args.memory, args.steps, tuple(args.replies)
    )
    result = evaluation.experiment_baby9(config, _cache_dir(args))
    if args.plot:
        params = ModelParams.load(args.params)
        table, _ = evaluation.obtain_table(
            params, "receding", args.horizon, args.memory, _cache_dir(args)
        )
        records = evaluation.baby9_session(params, table, args.replies[0], args.steps)
        plots.plot_session(
            params,
            [r.__dict__ for r in records],
            args.plot,
            title=f"baby-9 (reply={args.replies[0]}): {args.params} parameters,"
            f" receding H={args.horizon}",
        )
        result["plot"] = args.plot
    if args.json:
        _dump(result)
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


def _run_rule(args: argparse.Namespace) -> int:
    first, last = args.steps
    config = evaluation.RuleConfig(args.params, args.horizon, first, last, args.c)
    result = evaluation.experiment_rule(config, _cache_dir(args))
    if args.json:
        _dump(result)
        return 0
    print(
        f"rule (c = {args.c:g}) vs optimal episodic table, {args.params} parameters, T ="
        f" {args.horizon}, steps {first}..{last}"
    )
    print(
        f"{'measure':36} {'statistics':>10} {'agree':>7} {'z>ta2':>7} {'opt1/rule0':>10}"
        f" {'opt0/rule1':>10} {'best c':>8} {'agree@best':>10}"
    )
    for name, m in result["measures"].items():
        low, high = m["best_c_interval"]
        print(
            f"{name:36} {m['statistics']:>10} {m['agreement']:>7.2%}"
            f" {m['agreement_timer_past_agent_period']:>7.2%}"
            f" {m['optimal_vocalizes_rule_silent']:>10.2%}"
            f" {m['rule_vocalizes_optimal_silent']:>10.3%} {m['best_c']:>8.3f}"
            f" {m['best_c_agreement']:>10.2%}   (best c in ({low:.4g}, {high:.4g}))"
        )
    for name, m in result["measures"].items():
        print(
            f"{name}: the optimal controller vocalizes at {m['optimal_vocalizes']:.2%} of the"
            f" measure, the rule at {m['rule_vocalizes']:.3%}"
        )
    print(
        f"exact episode score (0 = never vocalize, 1 = optimal): rule c = {args.c:g}:"
        f" {result['episode_score_rule_c']:.4f}; rule with the best weighted c:"
        f" {result['episode_score_rule_best_weighted_c']:.4f}"
    )
    return 0


def _run_greedy(args: argparse.Namespace) -> int:
    config = dataclasses.replace(
        evaluation.GreedyConfig(),
        param_names=tuple(args.params),
        max_count=args.max_count,
        steps=args.steps,
    )
    result = evaluation.experiment_greedy(config)
    if args.json:
        _dump(result)
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


def _run_horizon(args: argparse.Namespace) -> int:
    config = evaluation.HorizonConfig(
        tuple(args.params), tuple(args.horizons), args.domain, args.longest
    )
    result = evaluation.experiment_horizon(config)
    if args.plot:
        for name in args.params:
            target = Path(args.plot)
            if len(args.params) > 1:
                target = target.with_name(f"{target.stem}_{name}{target.suffix}")
            plots.plot_horizon_maps(result, target, name)
            print(f"wrote {target}", file=sys.stderr if args.json else sys.stdout)
    if args.json:
        _dump(result)
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


def _run_efficiency(args: argparse.Namespace) -> int:
    config = evaluation.EfficiencyConfig(
        params_name=args.params,
        prior_rooms=args.prior_rooms,
        named_runs=args.named_runs,
        switch_runs=args.switch_runs,
        switch_step=args.switch_step,
        tuning_rooms=args.tuning_rooms,
        steps=args.steps,
        seed=args.seed,
        workers=args.workers,
    )
    started = time.perf_counter()
    result = evaluation.experiment_efficiency(config, _cache_dir(args))
    result["seconds"] = time.perf_counter() - started
    if args.plot:
        plots.plot_efficiency(result, args.plot)
    if args.json:
        _dump(result)
        return 0
    print_efficiency(result)
    if args.plot:
        print(f"wrote {args.plot}")
    return 0


def _ci(pair: Any, digits: int = 3) -> str:
    return f"[{number(pair[0], digits)}, {number(pair[1], digits)}]"


def _print_prior_rooms(result: dict) -> None:
    """Table A: rooms drawn from the prior (entropy, accuracy, detection, false alarms)."""
    summaries = result["summaries"]
    print(
        f"\nA. rooms drawn from the prior (partner in half of them); 95 % intervals;"
        f" entropy/step weighted to the model's prior, and minus {result['reference']}'s"
        " in the same rooms; detection within the run"
    )
    print(
        f"{'controller':28} {'entropy/step (prior)':>26} {'minus reference':>27} {'acc@10':>6}"
        f" {'acc@20':>6} {'acc@40':>6} {'detected':>8} {'restr.mean s':>19} {'false al.':>9}"
    )
    for label in result["controllers"]:
        s = summaries[label]
        partner, empty = s["prior, partner"], s["prior, no partner"]
        both = partner["runs"] + empty["runs"]
        accuracy = [
            (partner[f"accuracy_{n}"] * partner["runs"] + empty[f"accuracy_{n}"] * empty["runs"])
            / both
            for n in result["checkpoints"]
        ]
        entropy_ci = _ci(s["prior_weighted_entropy_ci"], 4)
        difference_ci = _ci(s["entropy_minus_reference_ci"], 2)
        print(
            f"{label:28} {s['prior_weighted_entropy']:.4f} {entropy_ci:>19}"
            f" {s['entropy_minus_reference']:>+9.5f} {difference_ci:>17}"
            + "".join(f" {a:>6.1%}" for a in accuracy)
            + f" {partner['detected']:>8.1%} {partner['detection_s_restricted_mean']:>5.1f}"
            f" {_ci(partner['detection_s_restricted_mean_ci']):>13}"
            f" {empty['false_alarm_rate']:>9.1%}"
        )


def _partner_rooms(result: dict) -> list[str]:
    """The named rooms with a partner, in table order."""
    return [f"{name}+partner" for name in result["rooms"]["backgrounds_k3"]]


def _print_named_rooms(result: dict) -> None:
    """Table B: named partner rooms, median seconds and vocalizations to a confident belief."""
    summaries = result["summaries"]
    print(
        "\nB. named rooms with a partner: median seconds [95 % CI] and vocalizations to"
        " P(S=1) >= 0.95 (whole-history belief)"
    )
    rooms = _partner_rooms(result)
    print(f"{'controller':28}" + "".join(f" {room:>30}" for room in rooms))
    for label in result["controllers"]:
        cells = []
        for room in rooms:
            r = summaries[label][room]
            cells.append(
                f"{number(r['detection_s_median'])} s {_ci(r['detection_s_ci'])}"
                f" {number(r['detection_vocalizations_median'])} voc"
            )
        print(f"{label:28}" + "".join(f" {cell:>30}" for cell in cells))


def _print_own_belief(result: dict) -> None:
    """Table C: the robot's own (sliding-memory) belief in named and switching rooms."""
    summaries = result["summaries"]
    print(
        "\nC. the robot's own belief (sliding memory M, as deployed): median s to P(S=1) >="
        " 0.95 in named partner rooms (detected within the run); a partner who leaves or"
        " arrives at the middle of the run, in the runs where the robot was sure before"
    )
    rooms = _partner_rooms(result)
    print(
        f"{'controller':28}"
        + "".join(f" {room:>22}" for room in rooms)
        + f" {'leaves: s to <0.5':>24} {'arrives: s to >=0.95':>24}"
    )
    for label in result["receding_memories"]:
        s = summaries[label]
        cells = [
            f"{number(s[room]['own_detection_s_median'])} s ({s[room]['own_detected']:.0%})"
            for room in rooms
        ]
        switches = [
            f"{number(s[g]['switch_response_s_median'])} s {_ci(s[g]['switch_response_s_ci'])}"
            for g in ("partner leaves", "partner arrives")
        ]
        print(
            f"{label:28}"
            + "".join(f" {cell:>22}" for cell in cells)
            + "".join(f" {cell:>24}" for cell in switches)
        )


def _print_exact_scores(result: dict) -> None:
    """Table D: the exact episode score of each deterministic controller."""
    print(
        f"\nD. exact episode score, T = {result['config']['episodic_horizon']} (0 = never"
        " vocalize, 1 = optimal; as episodic policies on the statistic, from the episode start)"
    )
    for label, score in result["exact_episode_scores"].items():
        text = "not a deterministic policy of (t, a)" if score is None else f"{score:.4f}"
        print(f"{label:28} {text}")


def print_efficiency(result: dict) -> None:
    """The efficiency tables, readable."""
    config, dt = result["config"], result["dt"]
    print(
        f"detection efficiency: {config['params_name']} parameters (dt = {dt} s), runs of"
        f" {config['steps']} windows ({config['steps'] * dt:g} s), seed {config['seed']}"
    )
    print(
        f"best fixed interval K = {result['best_fixed_interval']} (least restricted mean"
        f" detection time on {config['tuning_rooms']} tuning rooms)"
    )
    _print_prior_rooms(result)
    _print_named_rooms(result)
    _print_own_belief(result)
    _print_exact_scores(result)
    print(f"\n({result.get('seconds', 0.0):.0f} s)")


def _commas(values: Any) -> str:
    """A list default as it is typed on the command line: ``a,b,c``."""
    return ",".join(str(value) for value in values)


def _add_baby9_arguments(sub: argparse.ArgumentParser) -> None:
    d = evaluation.Baby9Config()
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
        type=_name_list,
        default=list(d.replies),
        help="reply conventions: all, or a timer value of the agent period"
        f" (default {_commas(d.replies)})",
    )
    sub.add_argument("--plot", help="write the session figure of the first reply to this PNG")


def _add_rule_arguments(sub: argparse.ArgumentParser) -> None:
    d = evaluation.RuleConfig()
    sub.add_argument(
        "--params", default=d.params_name, help=f"parameter set (default: {d.params_name})"
    )
    sub.add_argument(
        "--horizon", type=int, default=d.horizon, help=f"episodic horizon T (default {d.horizon})"
    )
    sub.add_argument(
        "--steps",
        type=_step_range,
        default=(d.first_step, d.last_step),
        help=f"steps FIRST-LAST (default {d.first_step}-{d.last_step})",
    )
    sub.add_argument("--c", type=float, default=d.c, help=f"the rule's constant (default {d.c:g})")


def _add_greedy_arguments(sub: argparse.ArgumentParser) -> None:
    d = evaluation.GreedyConfig()
    sub.add_argument(
        "--params",
        type=_name_list,
        default=list(d.param_names),
        help=f"sets (default {_commas(d.param_names)})",
    )
    sub.add_argument(
        "--max-count",
        type=int,
        default=d.max_count,
        help=f"check statistics with n <= this (default {d.max_count})",
    )
    sub.add_argument(
        "--steps", type=int, default=d.steps, help=f"steps of the example run (default {d.steps})"
    )


def _add_horizon_arguments(sub: argparse.ArgumentParser) -> None:
    d = evaluation.HorizonConfig()
    sub.add_argument(
        "--params",
        type=_name_list,
        default=list(d.param_names),
        help=f"sets (default {_commas(d.param_names)})",
    )
    sub.add_argument(
        "--horizons",
        type=_int_list,
        default=list(d.horizons),
        help=f"horizons to list (default {_commas(d.horizons)})",
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


def _add_efficiency_arguments(sub: argparse.ArgumentParser) -> None:
    d = evaluation.EfficiencyConfig()
    sub.add_argument("--params", default=d.params_name, help=f"parameter set ({d.params_name})")
    for option, default, text in (
        ("--prior-rooms", d.prior_rooms, "rooms drawn from the prior"),
        ("--named-runs", d.named_runs, "runs per named room"),
        ("--switch-runs", d.switch_runs, "runs per switching scenario"),
        ("--switch-step", d.switch_step, "step at which the partner leaves/arrives"),
        ("--tuning-rooms", d.tuning_rooms, "prior rooms for choosing the fixed K"),
        ("--steps", d.steps, "steps per run"),
        ("--seed", d.seed, "master seed"),
        ("--workers", d.workers, "processes"),
    ):
        sub.add_argument(option, type=int, default=default, help=f"{text} (default {default})")
    sub.add_argument("--plot", help="write the comparison figure to this PNG")


ExperimentCommand = tuple[
    str, str, Callable[[argparse.Namespace], int], Callable[[argparse.ArgumentParser], None]
]
"""An experiment sub-command: name, help, run function, function adding its own options."""

EXPERIMENTS: tuple[ExperimentCommand, ...] = (
    ("baby9", "the baby-9 scenario (MODEL.md section 5)", _run_baby9, _add_baby9_arguments),
    (
        "rule",
        "the interpretable rule against the optimal controller",
        _run_rule,
        _add_rule_arguments,
    ),
    ("greedy", "what one-step (H = 1) infomax control does", _run_greedy, _add_greedy_arguments),
    (
        "horizon",
        "how the optimal action map changes with the horizon",
        _run_horizon,
        _add_horizon_arguments,
    ),
    (
        "efficiency",
        "detection efficiency of all controllers",
        _run_efficiency,
        _add_efficiency_arguments,
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


# --------------------------------------------------------------------------------------
# learn


def _run_learn(args: argparse.Namespace) -> int:
    config = evaluation.LearnConfig(
        params_name=args.params,
        horizon=args.horizon,
        methods=tuple(args.method or evaluation.LearnConfig().methods),
        budget=args.budget,
        seeds=tuple(args.seeds),
        evaluate_every=args.evaluate_every,
        evaluate_growth=args.evaluate_growth,
        target=args.target,
    )
    result = evaluation.experiment_learn(config)
    curves = result["curves"]
    if args.plot:
        plots.plot_learning_curves(curves, args.plot, args.target)
    if args.json:
        _dump(result)
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
    d = evaluation.LearnConfig()
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
        f" repeat for several (default: {_commas(d.methods)})",
    )
    parser.add_argument(
        "--budget", type=int, default=d.budget, help=f"vocalizations per run (default {d.budget})"
    )
    parser.add_argument(
        "--seeds",
        type=_int_list,
        default=list(d.seeds),
        help=f"seeds, e.g. 1,2,3 (default {_commas(d.seeds)})",
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


# --------------------------------------------------------------------------------------
# plot


DEFAULT_TABLES = {"robot": "robot_receding_H24_M60.npz", "paper": "paper_episodic_T40.npz"}


def _default_controller(params: ModelParams) -> str:
    """The committed optimal table of a reference set, else the rule."""
    for name, file_name in DEFAULT_TABLES.items():
        if NAMED_PARAMS[name] == params:
            return f"policy:{resource_path('policies', file_name)}"
    return "rule"


def _run_plot(args: argparse.Namespace) -> int:
    params = ModelParams.load(args.params)
    memory = args.memory
    if args.session and Path(args.session).is_dir():  # a recorded session (bag)
        from infomax_contingency.eval.sessions import load_session, replay_recorded

        session = load_session(Path(args.session))
        memory = memory or session.memory_steps
        records = [record.__dict__ for record in replay_recorded(session, params, memory)]
        title = args.title or f"recorded session {Path(args.session).name}"
    elif args.session:
        records = plots.read_session(args.session)
        title = args.title or f"session {Path(args.session).name}"
    else:
        rng = np.random.default_rng(args.seed)
        room = make_room(args.world, params, rng)
        controller = make_controller(
            args.controller or _default_controller(params), params, rng, memory=args.memory
        )
        steps = simulate(params, controller, room, args.steps, rng, memory=args.memory)
        records = [record.__dict__ for record in steps]
        title = args.title or (
            f"{args.params} parameters, {controller.name} in room {room.name}, seed {args.seed}"
        )
    path = plots.plot_session(params, records, args.out, title=title, memory=memory)
    print(f"wrote {path} ({path.stat().st_size:,} bytes, {len(records)} steps)")
    return 0


def register_plot(subparsers: argparse._SubParsersAction) -> None:
    """``plot``: the four-panel figure of a simulated or recorded session."""
    parser = subparsers.add_parser(
        "plot", help="plot a session (simulated now, or a `simulate --json` file) to a PNG"
    )
    parser.add_argument("--out", required=True, help="PNG file to write")
    parser.add_argument(
        "--session",
        help="a session bag (recorder_node; replayed with its recorded actions) or a"
        " JSON-lines file (`simulate --json` output); else simulate",
    )
    parser.add_argument(
        "--params", default="robot", help="parameter set of the session (default: robot)"
    )
    parser.add_argument(
        "--controller",
        help=f"controller to simulate: {', '.join(CONTROLLER_KINDS)} (default: the committed"
        " optimal table of the paper or robot set, else the rule)",
    )
    parser.add_argument(
        "--world",
        default="responsive",
        help=f"room to simulate: {' | '.join(BIT_ROOM_NAMES)}[:key=value,...] (default responsive)",
    )
    parser.add_argument("--steps", type=int, default=120, help="steps to simulate (default 120)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--memory",
        type=int,
        default=0,
        help="sliding memory of the replayed counts (and of rule/greedy); 0 = all (default;"
        " for a bag: belief_node's memory, from the bag)",
    )
    parser.add_argument("--title", help="figure title")
    parser.set_defaults(run=_run_plot)

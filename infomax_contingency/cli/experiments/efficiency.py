"""``experiment efficiency``: detection efficiency of every controller, its four tables.

The experiment is :mod:`infomax_contingency.eval.experiments.efficiency`.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from infomax_contingency.cli.experiments.options import cache_dir_of, print_json
from infomax_contingency.cli.formatting import number, seed
from infomax_contingency.eval import plots
from infomax_contingency.eval.experiments.efficiency import EfficiencyConfig, experiment_efficiency
from infomax_contingency.limits import check_output_files


def run_efficiency(args: argparse.Namespace) -> int:
    """Run ``experiment efficiency``; print its tables (or JSON), write the figure if asked."""
    check_output_files(("--plot", args.plot, "figure"))  # before the work
    config = EfficiencyConfig(
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
    result = experiment_efficiency(config, cache_dir_of(args))
    result["seconds"] = time.perf_counter() - started
    if args.plot:
        plots.plot_efficiency(result, args.plot)
    if args.json:
        print_json(result)
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


def add_efficiency_arguments(sub: argparse.ArgumentParser) -> None:
    """The options of ``experiment efficiency`` (defaults: :class:`EfficiencyConfig`)."""
    d = EfficiencyConfig()
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
        kind = seed if option == "--seed" else int
        sub.add_argument(option, type=kind, default=default, help=f"{text} (default {default})")
    sub.add_argument("--plot", help="write the comparison figure to this PNG")

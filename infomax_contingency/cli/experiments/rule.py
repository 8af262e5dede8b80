"""``experiment rule``: the interpretable rule against the optimal controller.

The experiment is :mod:`infomax_contingency.eval.experiments.rule`.
"""

from __future__ import annotations

import argparse

from infomax_contingency.cli.experiments.options import cache_dir_of, print_json, step_range
from infomax_contingency.eval.experiments.rule import RuleConfig, experiment_rule


def run_rule(args: argparse.Namespace) -> int:
    """Run ``experiment rule``; print its table (or JSON)."""
    first, last = args.steps
    config = RuleConfig(args.params, args.horizon, first, last, args.c)
    result = experiment_rule(config, cache_dir_of(args))
    if args.json:
        print_json(result)
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


def add_rule_arguments(sub: argparse.ArgumentParser) -> None:
    """The options of ``experiment rule`` (defaults: :class:`RuleConfig`)."""
    d = RuleConfig()
    sub.add_argument(
        "--params", default=d.params_name, help=f"parameter set (default: {d.params_name})"
    )
    sub.add_argument(
        "--horizon", type=int, default=d.horizon, help=f"episodic horizon T (default {d.horizon})"
    )
    sub.add_argument(
        "--steps",
        type=step_range,
        default=(d.first_step, d.last_step),
        help=f"steps FIRST-LAST (default {d.first_step}-{d.last_step})",
    )
    sub.add_argument("--c", type=float, default=d.c, help=f"the rule's constant (default {d.c:g})")

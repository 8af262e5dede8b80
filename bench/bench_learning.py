"""Speed of infomax TD learning and of exact policy scoring (prints figures).

Usage (from the repository root, after ``make setup``)::

    .venv/bin/python bench/bench_learning.py                # T = 12, 16, 20
    .venv/bin/python bench/bench_learning.py --horizons 12  # one horizon

For each horizon: trials and vocalizations per second of the plain and the improved
learner (learning only, no scoring), and the time to score one policy exactly (read the
greedy policy off the learned values, then evaluate it by backward induction).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from infomax_contingency.core import learning
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.scoring import Scorer


def main() -> None:
    """Print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--params", default="paper")
    parser.add_argument("--horizons", default="12,16,20")
    parser.add_argument("--seconds", type=float, default=3.0, help="learning time per method")
    args = parser.parse_args()
    params = ModelParams.load(args.params)
    print(f"{'T':>3} {'method':>9} {'trials/s':>10} {'vocal./s':>10} {'score once':>11}")
    for horizon in (int(h) for h in args.horizons.split(",")):
        start = time.perf_counter()
        scorer = Scorer(params, horizon)
        setup = time.perf_counter() - start
        for name, settings in learning.METHODS.items():
            learner = learning.TDLearner(params, horizon, settings, np.random.default_rng(0))
            start = time.perf_counter()
            while time.perf_counter() - start < args.seconds:
                for _ in range(200):
                    learner.trial()
            elapsed = time.perf_counter() - start
            start = time.perf_counter()
            scorer.score(learner.greedy_actions())
            scoring = time.perf_counter() - start
            print(
                f"{horizon:>3} {name:>9} {learner.trials / elapsed:>10,.0f}"
                f" {learner.vocalizations / elapsed:>10,.0f} {scoring * 1000:>9.1f}ms"
            )
        print(f"    (scorer set-up: optimal and never-vocalize values, {setup * 1000:.0f} ms)")


if __name__ == "__main__":
    main()

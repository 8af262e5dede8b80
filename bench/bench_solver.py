"""Speed and memory of the exact DP solver and of table lookups (prints figures).

Usage (from the repository root, after ``make setup``)::

    .venv/bin/python bench/bench_solver.py                 # T = 12 .. 100, lookups, T = 24 ratio
    .venv/bin/python bench/bench_solver.py --largest       # also solve the largest T for 16 GiB
    .venv/bin/python bench/bench_solver.py --only-estimates  # cost model vs measured only

Each solve runs in a fresh child process so that its peak resident memory (ru_maxrss)
is its own. The largest horizon that fits in 16 GiB is extrapolated from the measured
peaks (memory grows as the number of count tuples, C(T + 4, 4)); ``--largest`` solves
it to confirm.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from infomax_contingency.core.model import ModelParams, Statistic
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.core.solver import solve_cost, solve_episodic
from infomax_contingency.core.statespace import count_index, n_count_tuples

CHILD = """
import json, resource, sys, time
from pathlib import Path
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.solver import solve_cost, solve_episodic
horizon, out = int(sys.argv[1]), Path(sys.argv[2])
start = time.perf_counter()
table = solve_episodic(ModelParams.named("paper"), horizon)
elapsed = time.perf_counter() - start
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
table.save(out)
print(json.dumps({"seconds": elapsed, "peak_bytes": peak, "statistics": table.n_statistics}))
"""
BUDGET_BYTES = 16 * 2**30


def solve_in_child(horizon: int, folder: Path) -> dict:
    """Solve the paper set episodically in a child process; time, peak memory, file size."""
    out = folder / f"paper_T{horizon}.npz"
    result = subprocess.run(
        [sys.executable, "-c", CHILD, str(horizon), str(out)],
        check=True,
        capture_output=True,
        text=True,
    )
    figures = json.loads(result.stdout)
    figures["file_bytes"] = out.stat().st_size
    out.unlink()
    return figures


def pure_python_solve(params: ModelParams, horizon: int) -> tuple[float, int]:
    """A straightforward memoised recursive DP in pure Python (the baseline).

    Returns the value at the episode start from the timer "long ago" with no data
    (summed over the first bit) and the number of memoised states.
    """
    log_prior = math.log(params.pi / (1 - params.pi))

    def lnbeta(a: float, b: float) -> float:
        return math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)

    def period(z: int) -> int:
        if params.ts1 <= z <= params.ts2:
            return 1
        return 2 if params.ta1 <= z <= params.ta2 else 3

    def counts_entropy(p2: int, q2: int, p3: int, q3: int) -> tuple[float, float]:
        lam = (
            log_prior
            + lnbeta(1 + p2, 1 + q2)
            + lnbeta(1 + p3, 1 + q3)
            - lnbeta(1 + p2 + p3, 1 + q2 + q3)
        )
        b = 1 / (1 + math.exp(-lam))
        h = -sum(x * math.log2(x) for x in (b, 1 - b) if x > 0)
        return b, h

    @functools.cache
    def value(k: int, z: int, p2: int, q2: int, p3: int, q3: int) -> float:
        b, h = counts_entropy(p2, q2, p3, q3)
        if k == 0:
            return -h
        best = -math.inf
        for u in (0, 1):
            z_next = 0 if u else min(z + 1, params.ta2 + 1)
            where = period(z_next)
            if where == 1:
                expected = value(k - 1, z_next, p2, q2, p3, q3)
            else:
                pooled = (1 + p2 + p3) / (2 + p2 + q2 + p3 + q3)
                own = (1 + p2) / (2 + p2 + q2) if where == 2 else (1 + p3) / (2 + p3 + q3)
                p_one = b * own + (1 - b) * pooled
                if where == 2:
                    after = (
                        value(k - 1, z_next, p2 + 1, q2, p3, q3),
                        value(k - 1, z_next, p2, q2 + 1, p3, q3),
                    )
                else:
                    after = (
                        value(k - 1, z_next, p2, q2, p3 + 1, q3),
                        value(k - 1, z_next, p2, q2, p3, q3 + 1),
                    )
                expected = p_one * after[0] + (1 - p_one) * after[1]
            best = max(best, expected)
        return -h + best

    z = params.ta2 + 1
    total = 0.5 * value(horizon - 1, z, 0, 0, 0, 1) + 0.5 * value(horizon - 1, z, 0, 0, 1, 0)
    return total, value.cache_info().currsize


def lookup_microseconds(table: PolicyTable, count: int = 200_000) -> float:
    """Mean time of one ``table.action`` call over random in-table statistics."""
    rng = np.random.default_rng(0)
    steps = rng.integers(1, table.horizon, size=count)
    statistics = []
    for step in steps:
        cuts = np.sort(rng.integers(0, step + 1, size=4))
        counts = np.diff(np.concatenate([[0], cuts]))
        z = int(rng.integers(0, table.params.n_timer_values))
        statistics.append((Statistic(z, *map(int, counts)), int(step)))
    start = time.perf_counter()
    for statistic, step in statistics:
        table.action(statistic, step=step)
    return (time.perf_counter() - start) / count * 1e6


def print_estimates(params: ModelParams, horizons: list[int]) -> None:
    """The cost model of ``solve`` (core.solver.solve_cost) against measured solves."""
    print("cost model (solve_cost) vs measured, paper set, episodic:")
    print(
        f"{'T':>4} {'est. s':>8} {'solve s':>8} {'ratio':>6}"
        f" {'est. MiB':>9} {'peak MiB':>9} {'ratio':>6}"
    )
    worst = 1.0
    with tempfile.TemporaryDirectory() as folder:
        for horizon in horizons:
            cost = solve_cost(params, "episodic", horizon)
            f = solve_in_child(horizon, Path(folder))
            time_ratio = cost.seconds / f["seconds"]
            memory_ratio = cost.peak_bytes / f["peak_bytes"]
            worst = max(worst, time_ratio, 1 / time_ratio, memory_ratio, 1 / memory_ratio)
            print(
                f"{horizon:>4} {cost.seconds:>8.3f} {f['seconds']:>8.3f} {time_ratio:>6.2f}"
                f" {cost.peak_bytes / 2**20:>9.0f} {f['peak_bytes'] / 2**20:>9.0f}"
                f" {memory_ratio:>6.2f}"
            )
    print(f"worst estimate off by a factor {worst:.2f} (the model aims at 2 or better)")


def main() -> None:
    """Print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--horizons", type=int, nargs="+", default=[12, 24, 40, 60, 80, 100])
    parser.add_argument("--largest", action="store_true", help="also solve the 16 GiB horizon")
    parser.add_argument("--estimate-horizons", type=int, nargs="+", default=[40, 60, 80, 100, 120])
    parser.add_argument(
        "--only-estimates", action="store_true", help="only the cost model vs measured section"
    )
    args = parser.parse_args()
    params = ModelParams.named("paper")
    if args.only_estimates:
        print_estimates(params, args.estimate_horizons)
        return
    print(f"machine: {os.cpu_count()} cores; paper parameter set, episodic tables")
    print(f"{'T':>4} {'solve s':>9} {'peak MiB':>9} {'statistics':>13} {'file KiB':>9}")
    bytes_per_tuple = []
    with tempfile.TemporaryDirectory() as folder:
        for horizon in args.horizons:
            f = solve_in_child(horizon, Path(folder))
            packed_actions = f["statistics"] / 8
            bytes_per_tuple.append((f["peak_bytes"] - packed_actions) / n_count_tuples(horizon))
            print(
                f"{horizon:>4} {f['seconds']:>9.3f} {f['peak_bytes'] / 2**20:>9.0f}"
                f" {f['statistics']:>13,} {f['file_bytes'] / 1024:>9.0f}"
            )
        per_tuple = bytes_per_tuple[-1]

        def predicted_peak(horizon: int) -> float:
            """Working arrays per count tuple plus the packed actions of all layers."""
            statistics = params.n_timer_values * (math.comb(horizon + 4, 5) - 1)
            return per_tuple * n_count_tuples(horizon) + statistics / 8

        largest = max(args.horizons)
        while predicted_peak(largest + 1) <= BUDGET_BYTES:
            largest += 1
        print(
            f"largest T within 16 GiB: {largest} (extrapolated: {per_tuple:.0f} bytes per count"
            f" tuple at the largest measured T, plus 1 bit per statistic for the table)"
        )
        if args.largest:
            f = solve_in_child(largest, Path(folder))
            print(
                f"measured T = {largest}: {f['seconds']:.1f} s, peak"
                f" {f['peak_bytes'] / 2**30:.2f} GiB, file {f['file_bytes'] / 2**20:.0f} MiB"
            )

    table = solve_episodic(params, 40)
    print(f"table lookup (T = 40, random statistics): {lookup_microseconds(table):.2f} us/decision")

    start = time.perf_counter()
    fast = solve_episodic(params, 24, keep_values=True)
    vectorised = time.perf_counter() - start
    start = time.perf_counter()
    slow_value, states = pure_python_solve(params, 24)
    pure = time.perf_counter() - start
    z = params.timer_long_ago
    fast_value = (
        0.5 * fast.values[0][z, count_index(0, 0, 0, 1)]
        + 0.5 * fast.values[0][z, count_index(0, 0, 1, 0)]
    )
    print(
        f"T = 24: vectorised {vectorised:.3f} s, memoised pure Python {pure:.2f} s"
        f" ({states:,} states) -> ratio {pure / vectorised:.0f}x;"
        f" start values agree to {abs(fast_value - slow_value):.1e}"
    )
    print_estimates(params, args.estimate_horizons)


if __name__ == "__main__":
    main()

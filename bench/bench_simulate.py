"""Memory and speed of a streamed ``simulate`` run against its number of steps.

For each step count, ``infomax-contingency simulate --steps N --json`` runs in a child
process with its output going to /dev/null; the figures are the child's peak resident
memory (``ru_maxrss`` from ``wait4``, MB) and its steps per second (wall clock). The
streamed run holds one record at a time, so its peak memory should not grow with N.
With ``--collected`` each count is also run through :func:`simulate` (every record kept
in a list), for contrast.

Run from the repository root::

    .venv/bin/python bench/bench_simulate.py [--steps 10000,1000000] [--collected]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

COLLECTED_RUN = (
    "import sys, numpy as np;"
    "from infomax_contingency.core.controllers import make_controller;"
    "from infomax_contingency.core.model import ModelParams;"
    "from infomax_contingency.sim.simulation import simulate;"
    "from infomax_contingency.sim.world import make_room;"
    "params = ModelParams.named('robot'); rng = np.random.default_rng(0);"
    "room = make_room('responsive', params, rng);"
    "records = simulate(params, make_controller('rule', params, rng), room, int(sys.argv[1]), rng);"
    "print(len(records))"
)
"""A child program that keeps every record of a run in a list (the non-streamed way)."""


def measure(argv: list[str]) -> tuple[float, float]:
    """Peak RSS (MB) and wall-clock seconds of a child process run to its end."""
    started = time.perf_counter()
    with open(os.devnull, "wb") as devnull:
        child = subprocess.Popen(argv, stdout=devnull)
        _, status, usage = os.wait4(child.pid, 0)
        child.returncode = os.waitstatus_to_exitcode(status)
    elapsed = time.perf_counter() - started
    if child.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} ended with status {child.returncode}")
    return usage.ru_maxrss / 1024.0, elapsed  # ru_maxrss is in KiB on Linux


def main() -> int:
    """Print one line per run: mode, steps, peak RSS, steps per second."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--steps",
        default="10000,1000000",
        help="step counts, separated by commas (default 10000,1000000)",
    )
    parser.add_argument(
        "--collected", action="store_true", help="also run each count collected into a list"
    )
    args = parser.parse_args()
    counts = [int(text) for text in args.steps.split(",") if text.strip()]
    runs = [("streamed", [sys.executable, "-m", "infomax_contingency.cli", "simulate", "--json"])]
    if args.collected:
        runs.append(("collected", [sys.executable, "-c", COLLECTED_RUN]))
    print(f"{'run':>10} {'steps':>10} {'peak RSS MB':>12} {'steps/s':>9}")
    for label, argv in runs:
        for steps in counts:
            extra = ["--steps", str(steps)] if label == "streamed" else [str(steps)]
            peak_mb, seconds = measure(argv + extra)
            print(f"{label:>10} {steps:>10,} {peak_mb:>12.1f} {steps / seconds:>9,.0f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

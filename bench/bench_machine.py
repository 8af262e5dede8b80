"""How fast this machine is at the suite's kind of work, to compare ``make test`` times.

The suite's wall time on 2 cores follows its CPU time (it is CPU-bound), and machines of
the same kind here differ by about two times in speed. A ``make test`` time means
something only beside a figure of the machine it ran on; this prints three, each the best
of ``--repeats`` (CPU seconds, user + system, so a busy machine inflates them less than
wall time):

* **interpreter**: ``--runs`` runs of the rooms experiment's offline loop (the nodes' own
  parts: the ``office+partner`` room's audio, the bit source, the optimal table, the
  belief), 60 s of room time each, in this process. Pure Python and numpy on small
  arrays, as most of the suite.
* **node process**: a child Python that imports rclpy and the belief node's module,
  brings up one node on its own DDS participant and shuts down: the cost of each node
  process the graph tests start (several hundred per run).
* **suite CPU**: not measured here; ``/usr/bin/time make test`` gives it (user + sys).

Run from the repository root, on a quiet machine (DDS stays on loopback, on a domain of its
own unless ``ROS_DOMAIN_ID`` is set)::

    .venv/bin/python bench/bench_machine.py [--runs 20] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import subprocess
import sys
import time

from infomax_contingency.cli.demo import isolate_dds
from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.rooms import controller_specs, run_room

NODE_PROCESS = """
import rclpy
from infomax_contingency.nodes.belief_node import BeliefNode
rclpy.init()
node = BeliefNode()
node.destroy_node()
rclpy.shutdown()
"""
"""What each node process of the graph tests does at the least: import, one node, stop."""


def cpu_seconds(who: int) -> float:
    """User + system CPU seconds of ``resource.RUSAGE_SELF`` or ``RUSAGE_CHILDREN``."""
    usage = resource.getrusage(who)
    return usage.ru_utime + usage.ru_stime


def interpreter_seconds(runs: int) -> float:
    """CPU seconds of ``runs`` 60-s runs of the optimal table in ``office+partner``."""
    params = ModelParams.named("robot")
    [(_, spec)] = controller_specs(params, ["optimal"])
    start = cpu_seconds(resource.RUSAGE_SELF)
    for run in range(runs):
        run_room(params, "office+partner", spec, "fixed:-40", 60.0, 0, run, 60)
    return cpu_seconds(resource.RUSAGE_SELF) - start


def node_process_seconds() -> float:
    """CPU seconds of one child process that brings up a belief node and stops."""
    start = cpu_seconds(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-c", NODE_PROCESS], check=True)
    return cpu_seconds(resource.RUSAGE_CHILDREN) - start


def main() -> int:
    """Print the machine's figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="60-s loop runs (default 20)")
    parser.add_argument("--repeats", type=int, default=5, help="best of (default 5)")
    args = parser.parse_args()
    domain = isolate_dds()
    print(f"# bench_machine: {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"load {os.getloadavg()[0]:.2f} at start, ROS_DOMAIN_ID={domain}")  # fmt: skip
    interpreter_seconds(1)  # the table's first load and the imports are not timed
    loop = min(interpreter_seconds(args.runs) for _ in range(args.repeats))
    print(f"interpreter:  {loop:6.3f} s CPU for {args.runs} runs of 60 s (120 windows each)")
    started = time.monotonic()
    node = min(node_process_seconds() for _ in range(args.repeats))
    print(f"node process: {node:6.3f} s CPU (import, one node, shutdown; "
          f"{(time.monotonic() - started) / args.repeats:.2f} s wall on average)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

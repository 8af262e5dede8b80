"""Soak: the lockstep graph for a long run, every node's resident memory sampled.

The whole graph runs as separate processes (fake_audio_node in lockstep, mic_node,
controller_node, belief_node, posture_node, speaker_node in dry run) as fast as it goes,
for ``--minutes`` (default 30: about 500,000 steps on a quiet 2-core machine). This
process only counts beliefs (it keeps no messages). Every ``--sample-s`` seconds it reads
each node's resident set size (``VmRSS`` in /proc). After the warm-up (``--warmup-min``)
it prints, per node, the RSS then and at the end, the growth, and the growth per 100,000
steps (target: under 5 MB per node over the run after warm-up).

Run from the repository root::

    .venv/bin/python bench/bench_soak.py [--minutes 30] [--sample-s 30] [--warmup-min 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from infomax_contingency.cli.demo import isolate_dds

NODES = {
    "mic_node": {"source": "topic", "bit_source": "energy", "threshold_mode": "fixed",
                 "threshold_db": -40.0, "wait_for_listeners": 2},
    "controller_node": {},
    "belief_node": {"memory_steps": 60},
    "posture_node": {},
    "speaker_node": {"dry_run": True},
}  # fmt: skip
ROOM = {"room": "responsive", "seed": 1, "partner_leave_s": 3600.0, "max_windows": 0}


def rss_mb(pid: int) -> float:
    """Resident set size of a process, MB (1e6 bytes), from /proc/<pid>/status."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024 / 1e6
    raise RuntimeError(f"no VmRSS for process {pid}")


def soak(workdir: Path, minutes: float, sample_s: float, warmup_min: float) -> int:
    """Run the graph, sample memory, print the figures; returns an exit status."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import Float64

    from infomax_contingency.nodes.qos import STREAM_QOS
    from infomax_contingency.testing.graph import GraphProcesses

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    counter = Node("soak_counter")
    steps = [0]
    counter.create_subscription(Float64, "belief", lambda _: steps.__setitem__(0, steps[0] + 1),
                                STREAM_QOS)  # fmt: skip
    executor = SingleThreadedExecutor()
    executor.add_node(counter)
    processes = GraphProcesses(workdir)
    samples: list[tuple[float, int, dict[str, float]]] = []
    try:
        for name, parameters in NODES.items():
            processes.start(name, parameters)
        processes.start("fake_audio_node", ROOM)
        start = time.monotonic()
        next_sample = start
        while time.monotonic() - start < minutes * 60:
            executor.spin_once(timeout_sec=0.05)
            if processes.dead():
                print(f"soak: a node died\n{processes.report()}", file=sys.stderr)
                return 1
            now = time.monotonic()
            if now >= next_sample:
                rss = {name: rss_mb(p.pid) for name, p in processes.processes.items()}
                samples.append((now - start, steps[0], rss))
                print(f"  {now - start:7.0f} s {steps[0]:9d} steps  "
                      + " ".join(f"{n.split('_')[0]} {v:6.1f}" for n, v in rss.items()),
                      flush=True)  # fmt: skip
                next_sample += sample_s
    finally:
        processes.stop_all()
        executor.shutdown()
        counter.destroy_node()
        rclpy.try_shutdown()
    report(samples, warmup_min * 60)
    return 0


def report(samples: list[tuple[float, int, dict[str, float]]], warmup_s: float) -> None:
    """Print the memory growth per node after the warm-up."""
    after = [s for s in samples if s[0] >= warmup_s] or samples[-1:]
    (t0, steps0, rss0), (t1, steps1, rss1) = after[0], samples[-1]
    run_steps = max(steps1 - steps0, 1)
    print(f"soak: {steps1} steps in {t1:.0f} s ({steps1 / max(t1, 1e-9):.0f} steps/s);"
          f" after {t0:.0f} s of warm-up: {run_steps} steps in {t1 - t0:.0f} s")  # fmt: skip
    print(f"{'node':<16} {'RSS after warm-up':>18} {'RSS at end':>11} {'growth':>9}"
          f" {'per 100k steps':>15} {'peak':>8}")  # fmt: skip
    for name in rss1:
        growth = rss1[name] - rss0[name]
        peak = max(s[2][name] for s in samples)
        print(f"{name:<16} {rss0[name]:15.1f} MB {rss1[name]:8.1f} MB {growth:+6.1f} MB"
              f" {growth * 1e5 / run_steps:+12.2f} MB {peak:5.1f} MB")  # fmt: skip


def main() -> int:
    """Parse the options and run the soak."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--sample-s", type=float, default=30.0)
    parser.add_argument("--warmup-min", type=float, default=3.0)
    args = parser.parse_args()
    domain = isolate_dds()
    print(f"# bench_soak: {args.minutes:g} min, ROS_DOMAIN_ID={domain}", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench-soak-") as workdir:
        return soak(Path(workdir), args.minutes, args.sample_s, args.warmup_min)


if __name__ == "__main__":
    sys.exit(main())

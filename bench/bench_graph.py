"""Speed of the node graph over DDS: lockstep throughput, real-time latency, CPU per node.

The whole graph runs as separate processes (fake_audio_node, mic_node, controller_node,
belief_node, posture_node, speaker_node in dry run) with a recorder in this process:

1. **Lockstep** (``--steps`` windows as fast as the graph goes): steps per second, from
   the first to the last belief received (target: >= 200 steps/s, 100x real time with
   0.5 s windows).
2. **Real time** (the room publishes one 0.5 s window every 0.5 s for ``--realtime-s``
   seconds): latency from the end of each window (the moment its audio is published) to
   its ``vocalize`` and its ``belief`` reaching a listener, p50 / p99 / max (target: p99
   under 10 ms), and the CPU share of each node process (percent of one core).

Run from the repository root::

    .venv/bin/python bench/bench_graph.py [--steps 2000] [--realtime-s 60]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from infomax_contingency.cli.demo import isolate_dds

NODES = ("mic_node", "controller_node", "belief_node", "posture_node", "speaker_node")
TIMEOUT_S = 300.0


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far, seconds (from /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def graph_nodes(room: dict, audio: bool) -> dict[str, dict]:
    """The graph against the fake room; the recorder listens to 'sound' (and 'audio')."""
    return {
        "mic_node": {
            "source": "topic",
            "bit_source": "energy",
            "threshold_mode": "fixed",
            "threshold_db": -40.0,
            "wait_for_listeners": 2,  # controller and belief (the recorder reads 'sound')
        },
        "controller_node": {},
        "belief_node": {"memory_steps": 60},
        "posture_node": {},
        "speaker_node": {"dry_run": True},
        "fake_audio_node": {**room, "wait_for_listeners": 2 if audio else 1},
    }


def run_graph(workdir: Path, room: dict, steps: int, audio: bool):
    """Start the graph, wait for ``steps`` beliefs; returns (recorder, cpu seconds, wall s)."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from infomax_contingency.testing.graph import (
        GraphError,
        GraphProcesses,
        SpinThread,
        StepRecorder,
        start_graph,
        wait_until,
    )

    processes = GraphProcesses(workdir)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    recorder = StepRecorder("bench_recorder", audio=audio, step_topics=False,
                            instrument=True)
    try:
        with SpinThread(recorder):
            nodes = graph_nodes(room, audio)
            start_graph(processes, recorder, nodes, "fake_audio_node", TIMEOUT_S)
            # Measure CPU from the first step on (start-up is not the steady state).
            if not wait_until(lambda: len(recorder.belief) >= 1, TIMEOUT_S, processes):
                raise GraphError(f"no step within {TIMEOUT_S} s\n{processes.report()}")
            pids = {name: p.pid for name, p in processes.processes.items()}
            cpu_start = {name: cpu_seconds(pid) for name, pid in pids.items()}
            wall_start = time.monotonic()
            if not wait_until(lambda: len(recorder.belief) >= steps, TIMEOUT_S, processes):
                raise GraphError(f"{recorder.counts()} after {TIMEOUT_S} s\n{processes.report()}")
            wall = time.monotonic() - wall_start
            cpu = {name: cpu_seconds(pid) - cpu_start[name] for name, pid in pids.items()}
    finally:
        processes.stop_all()
        recorder.destroy_node()
        rclpy.try_shutdown()
    return recorder, cpu, wall


def percentiles(values_ms: np.ndarray) -> str:
    """p50 / p99 / max of latencies in ms."""
    p50, p99 = np.percentile(values_ms, [50, 99])
    return f"p50 {p50:6.2f} ms   p99 {p99:6.2f} ms   max {values_ms.max():6.2f} ms"


def main() -> int:
    """Run both benchmarks and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=2000, help="lockstep windows (default 2000)")
    parser.add_argument(
        "--realtime-s", type=float, default=60.0, help="seconds of real-time run (default 60)"
    )
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    domain = isolate_dds()
    print(f"# bench_graph: {os.cpu_count()} CPUs, ROS_DOMAIN_ID={domain}")

    with tempfile.TemporaryDirectory(prefix="bench-graph-") as workdir:
        room = {"room": "responsive", "seed": args.seed, "max_windows": args.steps}
        recorder, cpu, wall = run_graph(Path(workdir) / "lockstep", room, args.steps, False)
        received = np.array([t for t, _ in recorder.times["belief"][: args.steps]]) / 1e9
        rate = (args.steps - 1) / (received[-1] - received[0])
        print(
            f"lockstep: {args.steps} steps in {received[-1] - received[0]:.2f} s ="
            f" {rate:.0f} steps/s ({rate * 0.5:.0f}x real time with 0.5 s windows;"
            f" target >= 200 steps/s)"
        )
        print(
            "  CPU per process while stepping (% of one core): "
            + ", ".join(f"{name} {100 * seconds / wall:.0f}%" for name, seconds in cpu.items())
        )

        windows = max(2, int(args.realtime_s / 0.5))
        room = {"room": "responsive", "seed": args.seed, "lockstep": False, "max_windows": windows}
        recorder, cpu, wall = run_graph(Path(workdir) / "realtime", room, windows, True)
        ends = np.array([published for _, published in recorder.times["audio"][:windows]])
        n = min(len(ends), len(recorder.times["vocalize"]), len(recorder.times["belief"]))
        for topic in ("sound", "vocalize", "belief"):
            arrived = np.array([received for received, _ in recorder.times[topic][:n]])
            latency_ms = (arrived - ends[:n]) / 1e6
            print(
                f"real time: end of window -> {topic:<8} received ({n} windows): "
                + percentiles(latency_ms)
            )
        print(
            f"  CPU per process in real time over {wall:.0f} s (% of one core): "
            + ", ".join(f"{name} {100 * seconds / wall:.1f}%" for name, seconds in cpu.items())
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

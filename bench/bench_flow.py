"""Steps lost by a healthy graph under load: the flow control against busy CPUs.

The whole graph runs as separate processes (mic_node, controller_node, belief_node,
posture_node, speaker_node in dry run) beside ``--busy-loops`` processes that spin
without end (default 2: both cores of the 2-core machine taken), for ``--minutes``. The
audio comes from:

* ``--source room`` (default): fake_audio_node in lockstep, as fast as the graph goes;
* ``--source bursts``: this process publishes messages of ``--burst-samples`` samples
  (default 10^7: 625 s of audio, 1250 windows, in one message), each once mic_node has
  published every window of the one before (a driver that keeps pace with its reader).

No fault is injected, so every step should reach the belief: it prints belief_node's
counts (steps applied, steps applied without their bit / without their decision),
mic_node's windows dropped and listeners it stopped waiting for, and the room's lockstep
timeouts. The figures are printed, not asserted (test_flow_control.py asserts 0 lost on
the stepped graph).

Run from the repository root::

    .venv/bin/python bench/bench_flow.py [--minutes 10] [--busy-loops 2] [--source room]
"""

from __future__ import annotations

import argparse
import array
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from infomax_contingency.cli.demo import isolate_dds

MIC = {"source": "topic", "bit_source": "energy", "threshold_mode": "fixed",
       "threshold_db": -40.0, "wait_for_listeners": 2}  # controller, belief  # fmt: skip
NODES = {
    "controller_node": {"wait_for_listeners": 3},  # mic, belief, speaker (+ the room: below)
    "belief_node": {"memory_steps": 60},
    "posture_node": {},
    "speaker_node": {"dry_run": True},
}
ROOM = {"room": "responsive", "seed": 1, "partner_leave_s": 1e6, "max_windows": 0}
REPORTED = {
    "belief_node": ("steps", "missing_bits", "missing_decisions", "jumps_ignored"),
    "mic_node": ("windows", "windows_dropped", "listeners_given_up", "lockstep_timeouts"),
    "controller_node": ("steps", "missed_steps"),
    "fake_audio_node": ("windows", "lockstep_timeouts"),
}
"""Node -> the diagnostic values printed."""


def busy_loops(count: int) -> list[subprocess.Popen]:
    """``count`` processes that spin the CPU until killed."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def run(workdir: Path, minutes: float, loops: int, source: str, burst_samples: int) -> int:
    """Run the graph under load, print the figures; returns an exit status."""
    import numpy as np
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import Float32MultiArray, Float64

    from infomax_contingency.nodes.qos import AUDIO_QOS, LOSSLESS_READER_QOS
    from infomax_contingency.testing.graph import GraphProcesses

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    bench = Node("bench_flow")
    beliefs = [0]
    statuses: dict[str, dict[str, str]] = {}

    def on_diagnostics(message: Any) -> None:
        for status in message.status:
            statuses[status.name.split(":")[0]] = {v.key: v.value for v in status.values}

    bench.create_subscription(Float64, "belief", lambda _: beliefs.__setitem__(0, beliefs[0] + 1),
                              LOSSLESS_READER_QOS)  # fmt: skip
    bench.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 100)
    audio = bench.create_publisher(Float32MultiArray, "audio", AUDIO_QOS)
    executor = SingleThreadedExecutor()
    executor.add_node(bench)
    processes = GraphProcesses(workdir)
    loads = busy_loops(loops)
    rng = np.random.default_rng(1)
    windows_sent = 0
    try:
        processes.start("mic_node", MIC)
        for name, parameters in NODES.items():
            extra = {"wait_for_listeners": 4} if name == "controller_node" and source == "room" \
                else {}  # fmt: skip
            processes.start(name, {**parameters, **extra})
        if source == "room":
            processes.start("fake_audio_node", ROOM)
        start = time.monotonic()
        next_line = start + 30.0
        while time.monotonic() - start < minutes * 60:
            executor.spin_once(timeout_sec=0.05)
            if processes.dead():
                print(f"bench_flow: a node died\n{processes.report()}", file=sys.stderr)
                return 1
            # The driver keeps pace with its reader, mic_node: the next burst once the mic
            # has published every window of the last one (not once the belief has them).
            published = int(statuses.get("mic_node", {}).get("windows", -1))
            if source == "bursts" and audio.get_subscription_count() and published == windows_sent:
                windows = burst_samples // 8000
                levels = np.where(rng.random(windows) < 0.3, 0.1, 0.001)
                samples = rng.standard_normal((windows, 8000)) * levels[:, None]
                message = Float32MultiArray()
                message.data = array.array("f", samples.astype(np.float32).tobytes())
                audio.publish(message)
                windows_sent += windows
            if time.monotonic() >= next_line:
                print(f"  {time.monotonic() - start:5.0f} s {beliefs[0]:8d} beliefs  "
                      + _line(statuses), flush=True)  # fmt: skip
                next_line += 30.0
        if source == "room":
            processes.stop("fake_audio_node")
        # the last steps (at most 60 s), and a diagnostics message after them
        settle = time.monotonic() + 60.0
        while time.monotonic() < settle and not _settled(statuses):
            executor.spin_once(timeout_sec=0.05)
        settle = time.monotonic() + 2.0
        while time.monotonic() < settle:
            executor.spin_once(timeout_sec=0.05)
        elapsed = time.monotonic() - start
    finally:
        for load in loads:
            load.kill()
            load.wait()
        processes.stop_all()
        executor.shutdown()
        bench.destroy_node()
        rclpy.try_shutdown()
    belief = statuses.get("belief_node", {})
    lost = int(belief.get("missing_bits", 0)) + int(belief.get("missing_decisions", 0))
    print(f"bench_flow: source {source}, {loops} busy loops, {elapsed:.0f} s:"
          f" {beliefs[0]} beliefs received here")  # fmt: skip
    print(f"  {_line(statuses)}")
    print(f"  steps lost (belief_node: applied without their bit + without their decision):"
          f" {lost}")  # fmt: skip
    return 0


def _settled(statuses: dict[str, dict[str, str]]) -> bool:
    """True once the belief node has applied every step mic_node published, none waiting."""
    mic, belief = statuses.get("mic_node", {}), statuses.get("belief_node", {})
    return (mic.get("steps_waiting") == "0" and "windows" in mic
            and belief.get("last_step") == mic["windows"])  # fmt: skip


def _line(statuses: dict[str, dict[str, str]]) -> str:
    """The reported values of each node's last diagnostics, on one line."""
    return "; ".join(
        f"{node.split('_')[0]} " + " ".join(f"{key}={values[key]}" for key in keys if key in values)
        for node, keys in REPORTED.items() if (values := statuses.get(node))
    )  # fmt: skip


def main() -> int:
    """Parse the options and run the bench."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--busy-loops", type=int, default=2)
    parser.add_argument("--source", choices=("room", "bursts"), default="room")
    parser.add_argument("--burst-samples", type=int, default=10**7)
    args = parser.parse_args()
    domain = isolate_dds()
    print(f"# bench_flow: {args.minutes:g} min, source {args.source}, {args.busy_loops} busy"
          f" loops, ROS_DOMAIN_ID={domain}", flush=True)  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="bench-flow-") as workdir:
        return run(Path(workdir), args.minutes, args.busy_loops, args.source, args.burst_samples)


if __name__ == "__main__":
    sys.exit(main())

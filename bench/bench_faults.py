"""Faults against the running lockstep graph: steps lost and recovery time per kind.

The graph runs as separate processes (fake_audio_node in lockstep, mic_node,
controller_node, belief_node). For each fault, in turn:

* **second mic_node / second controller_node** (started for ``--intrusion-s``, then
  stopped): seconds until belief_node's diagnostics name it (ERROR), seconds from its end
  until they are OK again;
* **belief_node / controller_node / mic_node killed with SIGKILL and started again**:
  seconds from the kill until the graph publishes beliefs again.

Steps lost: belief_node's counts of steps applied without their bit and without their
decision (cumulative over the run, as ``missing_bits + missing_decisions``).

Run from the repository root::

    .venv/bin/python bench/bench_faults.py [--intrusion-s 5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from infomax_contingency.cli.demo import isolate_dds

HOLD_S = 2.0
MIC = {"source": "topic", "bit_source": "energy", "threshold_mode": "fixed",
       "threshold_db": -40.0, "wait_for_listeners": 3, "start_delay_s": 0.2,
       "fault_hold_s": HOLD_S}  # fmt: skip
COMMON = {"fault_hold_s": HOLD_S, "source_timeout_s": 1.0}
NODES = {"mic_node": MIC, "controller_node": COMMON, "belief_node": {"memory_steps": 60,
         **COMMON}}  # fmt: skip
ROOM = {"room": "responsive", "seed": 2, "wait_for_truth_listeners": 1, "start_delay_s": 0.2,
        "lockstep_timeout_s": 2.0, "partner_leave_s": 1e6, **COMMON}  # fmt: skip


def main() -> int:
    """Run every fault once and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--intrusion-s", type=float, default=5.0)
    args = parser.parse_args()
    domain = isolate_dds()
    print(f"# bench_faults: ROS_DOMAIN_ID={domain}", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench-faults-") as workdir:
        return run(Path(workdir), args.intrusion_s)


def run(workdir: Path, intrusion_s: float) -> int:
    """Start the graph, inject the faults, print the figures."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.signals import SignalHandlerOptions

    from infomax_contingency.nodes.qos import LOSSLESS_READER_QOS
    from infomax_contingency.testing.graph import GraphProcesses, StepRecorder
    from infomax_contingency.testing.stepped import Probe, SteppedExecutor

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    recorder = StepRecorder("bench_recorder", stream_qos=LOSSLESS_READER_QOS, instrument=True)
    probe = Probe("bench_probe")
    diagnostics = probe.listen("/diagnostics", DiagnosticArray, 100)
    steps = SteppedExecutor([recorder, probe])
    processes = GraphProcesses(workdir)

    def belief_level() -> int | None:
        for message in reversed(diagnostics):
            for status in message.status:
                if status.name.startswith("belief_node:"):
                    return status.level[0] if isinstance(status.level, bytes) else status.level
        return None

    def wait(condition, what: str, deadline_s: float = 120.0) -> float:
        start = time.monotonic()
        steps.run_until(condition, what, deadline_s)
        return time.monotonic() - start

    def beliefs_for(seconds: float) -> None:
        end = time.monotonic() + seconds
        steps.run_until(lambda: time.monotonic() >= end, "time", seconds + 10)

    rows = []
    try:
        for name, parameters in NODES.items():
            processes.start(name, parameters)
        wait(lambda: recorder.sees(list(NODES)), "the graph")
        processes.start("fake_audio_node", ROOM)
        wait(lambda: len(recorder.belief) >= 100, "100 steps")
        for node, second, parameters in (
            ("mic_node", "mic_node_2", {**MIC, "wait_for_listeners": 0}),
            ("controller_node", "controller_node_2", COMMON),
        ):
            processes.start(node, parameters, name=second)
            detected = wait(lambda: belief_level() == 2, f"{second} named")
            beliefs_for(intrusion_s)
            processes.stop(second)
            recovered = wait(lambda: belief_level() == 0, "OK again")
            rows.append((f"second {node}", detected, recovered, _missing(diagnostics)))
        for node in ("belief_node", "controller_node", "mic_node"):
            rows.append((f"{node} killed, restarted", float("nan"),
                         _kill_and_restart(node, processes, recorder, wait),
                         _missing(diagnostics)))  # fmt: skip
    finally:
        processes.stop_all()
        steps.close()
        rclpy.try_shutdown()
    print(f"{'fault':<30} {'named after':>12} {'recovered after':>16} {'steps lost':>11}")
    for fault, detected, recovered, lost in rows:
        print(f"{fault:<30} {detected:10.2f} s {recovered:14.2f} s {lost:>11}")
    print(f"(diagnostics at 1 Hz, faults shown {HOLD_S:g} s after they end; a killed node is"
          " restarted after the room's 2 s lockstep timeout; steps lost: the belief node's"
          " count of steps applied without their bit + without their decision, cumulative)")
    return 0


def _kill_and_restart(node: str, processes, recorder, wait) -> float:
    """Kill ``node``, start it again; seconds from the kill to the next belief published."""
    beliefs_before = len(recorder.belief)
    killed_at = time.monotonic()
    processes.kill(node)
    if node != "belief_node":  # a new one once the room has timed out waiting for it
        wait(lambda: time.monotonic() - killed_at > 2.5, "the room's timeout")
    restarted_ns = time.time_ns()
    processes.start(node, NODES[node])

    def published_since_restart() -> bool:
        times = recorder.times["belief"]
        return bool(times) and times[-1][1] > restarted_ns

    wait(published_since_restart, "a belief published after the restart")
    back = time.monotonic() - killed_at
    wait(lambda: len(recorder.belief) > beliefs_before + 60, "60 more steps")
    return back


def _missing(diagnostics) -> str:
    """The belief node's counts of steps applied without their bit or decision."""
    for message in reversed(diagnostics):
        for status in message.status:
            if status.name.startswith("belief_node:"):
                values = {v.key: v.value for v in status.values}
                return f"{values.get('missing_bits')}+{values.get('missing_decisions')}"
    return "?"


if __name__ == "__main__":
    sys.exit(main())

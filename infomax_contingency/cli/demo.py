"""``infomax-contingency demo``: the whole node graph against a simulated room, in lockstep.

Starts mic_node, controller_node, belief_node, posture_node, speaker_node (dry run) and
fake_audio_node as separate processes, as the launch file would, with the installed
``config/robot.yaml`` and ``config/fake_room.yaml``, and watches them from this
process: one line per step (room time, bit, vocalization, belief, posture, ground truth)
and a verdict. By default a partner answers for the first 60 s and then leaves; the
graph runs in lockstep, so 120 s of room time take a few seconds.

``--wav FILE`` replays a recording through mic_node instead of the simulated room (the
threshold is the k-means calibration on the first ``--calibration-s`` seconds).

DDS stays on this machine: ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a random
``ROS_DOMAIN_ID`` unless the environment sets them. This module imports rclpy only when
the demo runs, so the command line stays light.
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from infomax_contingency.core.posture import BORED, PostureHysteresis
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.fake_room import PRESETS

RUN_TIMEOUT_S = 180.0
"""Seconds the graph may take to come up and finish before the demo gives up."""

ATTENTIVE_ABOVE, BORED_BELOW = 0.9, 0.2
"""The posture node's thresholds in the demo (as in config/robot.yaml)."""


def register_demo(subparsers: argparse._SubParsersAction) -> None:
    """``demo``: the node graph against the simulated room (or a wav file), in lockstep."""
    parser = subparsers.add_parser(
        "demo",
        help="run the whole node graph against a simulated room (or a wav file), in lockstep",
        description=__doc__.split("\n\n")[0] + " " + __doc__.split("\n\n")[1],
    )
    parser.add_argument("--steps", type=int, default=240, help="windows of room time (default 240)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the room (default 1)")
    parser.add_argument(
        "--room", choices=tuple(PRESETS), default="responsive", help="room (default responsive)"
    )
    parser.add_argument(
        "--leave-at",
        type=float,
        default=60.0,
        metavar="SECONDS",
        help="room time the partner leaves; negative: stays (default 60)",
    )
    parser.add_argument(
        "--memory",
        type=int,
        default=60,
        help="observations the belief remembers; 0 = all (default 60)",
    )
    parser.add_argument(
        "--wav", metavar="FILE", help="replay this WAV file instead of the simulated room"
    )
    parser.add_argument(
        "--calibration-s",
        type=float,
        default=10.0,
        help="seconds of the wav file to calibrate the threshold on (default 10)",
    )
    parser.set_defaults(run=run_demo)


def isolate_dds() -> str:
    """Keep DDS on this machine and off the default domain unless the user chose."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if not os.environ.get("ROS_DOMAIN_ID", "").strip():
        os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(100, 199))
    return os.environ["ROS_DOMAIN_ID"]


def _nodes(args: argparse.Namespace) -> tuple[dict[str, dict[str, Any]], str]:
    """Per-node parameters (over the config files) and the node that sets the pace."""
    listeners = 3  # controller, belief and this monitor
    nodes: dict[str, dict[str, Any]] = {
        "controller_node": {},
        "belief_node": {"memory_steps": args.memory},
        "posture_node": {"attentive_above": ATTENTIVE_ABOVE, "bored_below": BORED_BELOW},
        "speaker_node": {"dry_run": True},
    }
    if args.wav:
        nodes["mic_node"] = {
            "source": "wav",
            "wav_file": str(Path(args.wav).resolve()),
            "lockstep": True,
            "exit_at_end": True,
            "threshold_mode": "calibrate",
            "calibration_s": args.calibration_s,
            "wait_for_listeners": listeners,
        }
        return nodes, "mic_node"
    room: dict[str, Any] = {"room": args.room, "seed": args.seed, "max_windows": args.steps}
    room["wait_for_truth_listeners"] = 1  # this monitor
    room["partner_leave_s"] = args.leave_at if args.leave_at >= 0 else -1.0
    if args.room != "responsive":
        room["partner_arrive_s"] = -1.0
    nodes["mic_node"] = {"source": "topic", "wait_for_listeners": listeners}
    nodes["fake_audio_node"] = room
    return nodes, "fake_audio_node"


def _check(args: argparse.Namespace) -> None:
    if args.steps < 1:
        raise ValueError(f"--steps must be >= 1, got {args.steps}")
    if args.memory < 0:
        raise ValueError(f"--memory must be >= 0 (0 = all), got {args.memory}")
    if args.wav and not Path(args.wav).is_file():
        raise ValueError(f"--wav {args.wav}: no such file")
    if not args.calibration_s > 0:
        raise ValueError(f"--calibration-s must be > 0 seconds, got {args.calibration_s}")


def run_demo(args: argparse.Namespace) -> int:
    """Run the graph, print one line per step and the verdict; returns the exit status."""
    _check(args)
    domain = isolate_dds()
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

    window_s = 0.5
    nodes, clock = _nodes(args)
    files = [resource_path("config", "robot.yaml")]
    if not args.wav:
        files.append(resource_path("config", "fake_room.yaml"))
    source = (
        f"replaying {args.wav}" if args.wav else f"simulated {args.room} room, seed {args.seed}"
    )
    print(
        f"# demo: starting the node graph ({', '.join(nodes)}) in lockstep, {source}"
        f" (ROS_DOMAIN_ID={domain})",
        flush=True,
    )
    with tempfile.TemporaryDirectory(prefix="infomax-demo-") as workdir:
        processes = GraphProcesses(workdir, parameter_files=files)
        # Ctrl-C raises KeyboardInterrupt here; the nodes are stopped in `finally`.
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        recorder = StepRecorder("demo_monitor")
        try:
            with SpinThread(recorder):
                start = time.monotonic()
                start_graph(processes, recorder, nodes, clock, timeout_s=RUN_TIMEOUT_S)
                if args.wav:
                    mic = processes.processes["mic_node"]
                    done = wait_until(lambda: mic.poll() is not None, RUN_TIMEOUT_S, processes)
                    done = done and mic.returncode == 0
                    steps = len(recorder.sound)
                    done = done and wait_until(
                        lambda: min(len(recorder.vocalize), len(recorder.belief)) >= steps, 10.0
                    )
                else:
                    steps = args.steps
                    done = wait_until(
                        lambda: min(len(recorder.belief), len(recorder.partner_present)) >= steps,
                        RUN_TIMEOUT_S,
                        processes,
                    )
                elapsed = time.monotonic() - start
                if not done:
                    raise GraphError(
                        f"the graph stopped after {recorder.counts()} messages\n"
                        f"{processes.report()}"
                    )
                wait_until(lambda: len(recorder.posture) >= 1, 5.0)
        except GraphError as error:
            print(f"infomax-contingency demo: error: {error}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print("infomax-contingency demo: interrupted; nodes stopped", file=sys.stderr)
            return 130
        finally:
            processes.stop_all()
            recorder.destroy_node()
            rclpy.try_shutdown()
    _print_run(recorder, steps, window_s, truth=not args.wav)
    _print_verdict(recorder, steps, window_s, args, elapsed)
    return 0


def _postures(beliefs: list[float], received: list[str]) -> list[str]:
    """The posture after each step.

    The posture node publishes a change in answer to the belief that crossed a
    threshold; the same hysteresis on the recorded beliefs says which step that was. If
    the changes it finds are not the ones the node published (other thresholds in a
    parameter file), the node's changes are shown at the steps the monitor received them.
    """
    hysteresis = PostureHysteresis(ATTENTIVE_ABOVE, BORED_BELOW, received[0] if received else BORED)
    per_step = []
    for belief in beliefs:
        hysteresis.update(belief)
        per_step.append(hysteresis.posture)
    changes = [p for i, p in enumerate(per_step) if i == 0 or p != per_step[i - 1]]
    return per_step if changes[1:] == received[1:] else []


def _print_run(recorder: Any, steps: int, window_s: float, truth: bool) -> None:
    beliefs = recorder.belief[:steps]
    received = [posture for _, posture in recorder.posture]
    postures = _postures(beliefs, received)
    if not postures:  # fall back to the arrival order
        postures, current, changes = [], received[0] if received else "?", list(recorder.posture)
        for step in range(1, steps + 1):
            while changes and changes[0][0] <= step:
                current = changes.pop(0)[1]
            postures.append(current)
    header = f"{'step':>5} {'time_s':>7} {'bit':>3} {'vocalize':>8} {'belief':>9}  {'posture':<9}"
    print((header + (" partner" if truth else "")).rstrip())
    for k in range(steps):
        line = (
            f"{k + 1:>5} {k * window_s:>7.1f} {int(recorder.sound[k]):>3}"
            f" {'yes' if recorder.vocalize[k] else '-':>8} {beliefs[k]:>9.4f}  {postures[k]:<9}"
        )
        if truth:
            line += " present" if recorder.partner_present[k] else " absent"
        print(line.rstrip())


def _print_verdict(
    recorder: Any, steps: int, window_s: float, args: argparse.Namespace, elapsed: float
) -> None:
    beliefs = recorder.belief[:steps]
    final = beliefs[-1]
    thinks = "partner present" if final > 0.5 else "no partner"
    received = [t for t, _ in recorder.times["belief"][:steps]]
    run_s = (received[-1] - received[0]) / 1e9 if len(received) > 1 else 0.0
    rate = f" ({(steps - 1) / run_s:.0f} steps/s)" if run_s > 0 else ""
    print(
        f"# {steps} steps ({steps * window_s:g} s of audio) in {run_s:.2f} s{rate}, after"
        f" {elapsed - run_s:.1f} s of start-up; {sum(recorder.vocalize[:steps])} vocalizations;"
        f" final P(S=1) = {final:.4f} -> {thinks}"
    )
    if args.wav:
        print(f"# verdict: the robot thinks: {thinks} (a recording has no ground truth)")
        return
    truth = recorder.partner_present[:steps]
    present_steps = [k for k, present in enumerate(truth) if present]
    verdicts = []
    if present_steps:
        arrive, leave = present_steps[0], present_steps[-1] + 1
        found = next((k for k in range(arrive, leave) if beliefs[k] > ATTENTIVE_ABOVE), None)
        if found is None:
            verdicts.append("MISSED the partner")
        else:
            delay = (found - arrive + 1) * window_s
            verdicts.append(
                f"found the partner {delay:.1f} s after they arrived (step {found + 1})"
            )
        if leave < steps:
            gone = next((k for k in range(leave, steps) if beliefs[k] < BORED_BELOW), None)
            if gone is None:
                verdicts.append("did NOT notice that the partner left")
            else:
                delay = (gone - leave + 1) * window_s
                verdicts.append(f"noticed they left {delay:.1f} s later (step {gone + 1})")
    else:
        ok = max(beliefs) <= ATTENTIVE_ABOVE
        verdicts.append(
            "never took the room for a partner" if ok else "WRONGLY took the room for a partner"
        )
    right = (final > 0.5) == bool(truth[-1])
    verdicts.append(f"final answer {'correct' if right else 'WRONG'}")
    print("# verdict: " + "; ".join(verdicts))

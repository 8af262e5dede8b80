"""``infomax-contingency calibration-session``: the paper's calibration protocol, recorded.

For ``--minutes`` of room time the robot sounds at random intervals, uniform over
``--min-interval-s`` .. ``--max-interval-s`` seconds, whatever it hears (controller_node
with ``controller: interval:MIN_S-MAX_S``), while a person answers; recorder_node writes
the session to ``--out``, a bag for ``infomax-contingency analyze`` (the Fig. 4 study),
which turns it into a parameter file for ``solve``.

``--fake-room`` runs it against the simulated room (lockstep: minutes of room time take
seconds; its reply delays are those of config/fake_room.yaml); without it the graph runs
live: the microphone (``--device``, the threshold from ``--threshold-file`` or calibrated
on the first ``--calibration-s`` seconds) and the loudspeaker, in real time, and the
session ends after ``--minutes``. The bits are the paper's (energy against that
threshold), not mic_node's default ``background``, which labels windows by the very
periods this session measures. The launch file records the same protocol with
``record:=true controller:=interval:MIN_S-MAX_S`` and a ``params_file`` that sets
mic_node's ``bit_source: energy`` and its threshold.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from infomax_contingency.cli import demo
from infomax_contingency.cli.demo_checks import (
    MAX_SEED,
    MAX_STEPS,
    check_calibration_s,
    check_record_directory,
)
from infomax_contingency.cli.formatting import seed
from infomax_contingency.core.controllers import interval_steps
from infomax_contingency.core.model import ModelParams

DEFAULT_INTERVAL_S = (3.0, 6.0)
"""Default range of the random intervals between the robot's sounds, seconds."""


def register_calibration_session(subparsers: argparse._SubParsersAction) -> None:
    """``calibration-session``: record the random-interval protocol for ``analyze``."""
    parser = subparsers.add_parser(
        "calibration-session",
        help="record the paper's calibration protocol (sounds at random intervals) for analyze",
        description=__doc__.split("\n\n")[1],
    )
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="bag directory to write (must not exist)")
    parser.add_argument("--minutes", type=float, default=5.0,
                        help="length of the session, minutes of room time (default 5)")
    parser.add_argument("--min-interval-s", type=float, default=DEFAULT_INTERVAL_S[0],
                        help=f"shortest interval between sounds, s (default"
                        f" {DEFAULT_INTERVAL_S[0]:g})")
    parser.add_argument("--max-interval-s", type=float, default=DEFAULT_INTERVAL_S[1],
                        help=f"longest interval between sounds, s (default"
                        f" {DEFAULT_INTERVAL_S[1]:g})")
    parser.add_argument("--fake-room", action="store_true",
                        help="against the simulated room (lockstep) instead of live audio")
    parser.add_argument("--seed", type=seed, default=1, help="fake room: its seed (default 1)")
    parser.add_argument("--device", default="", help="live: the microphone (index or name)")
    parser.add_argument("--threshold-file", default="",
                        help="live: a threshold file written by calibrate (default: calibrate"
                        " on the first --calibration-s seconds)")
    parser.add_argument("--calibration-s", type=float, default=10.0,
                        help="live: seconds to calibrate the threshold on (default 10)")
    parser.add_argument("--no-record-audio", action="store_true",
                        help="leave the 'audio' topic out of the bag")
    parser.set_defaults(run=run_calibration_session)


def _check(args: argparse.Namespace) -> int:
    """The session's steps after checking the arguments (ValueError: one line).

    Every value a node would refuse (the room's and mic's ``max_windows``, the room's
    ``seed``, mic_node's ``calibration_s``) is refused here, before any node starts.
    """
    if not (math.isfinite(args.minutes) and args.minutes > 0):
        raise ValueError(f"--minutes must be > 0, got {args.minutes:g}")
    longest_min = MAX_STEPS * demo.WINDOW_S / 60
    if args.minutes > longest_min:
        raise ValueError(f"--minutes must be at most {longest_min:.3g} ({MAX_STEPS} windows of"
                         f" {demo.WINDOW_S:g} s: the nodes' max_windows), got {args.minutes:g}")
    if not 0 <= args.seed <= MAX_SEED:
        raise ValueError(f"--seed must be in [0, {MAX_SEED}], got {args.seed}")
    # the steps controller_node will draw: its check, before any node starts
    interval_steps(ModelParams.named("robot"), args.min_interval_s, args.max_interval_s,
                   ("--min-interval-s", "--max-interval-s"))
    check_calibration_s(args.calibration_s)
    if args.threshold_file and args.fake_room:
        raise ValueError("--threshold-file is read by live audio only: the simulated room's"
                         " mic_node uses config/fake_room.yaml's fixed threshold")
    if args.threshold_file and not Path(args.threshold_file).is_file():
        what = "not a regular file" if Path(args.threshold_file).exists() else "no such file"
        raise ValueError(f"--threshold-file {args.threshold_file}: {what}")
    check_record_directory(args.out, "--out")
    return max(1, round(args.minutes * 60 / demo.WINDOW_S))


def _graph(args: argparse.Namespace, steps: int) -> tuple[argparse.Namespace,
                                                          dict[str, dict[str, Any]], str]:
    """The demo's arguments, the nodes and the clock node of the session."""
    run = argparse.Namespace(
        steps=steps, seed=args.seed, room="responsive", leave_at=-1.0, memory=60, wav=None,
        calibration_s=args.calibration_s, record=args.out,
        no_record_audio=args.no_record_audio, bit_source="energy",
    )
    nodes, clock = demo._nodes(run)
    controller = nodes["controller_node"]
    controller["controller"] = f"interval:{args.min_interval_s:g}-{args.max_interval_s:g}"
    if not args.fake_room:
        del nodes["fake_audio_node"]
        controller["wait_for_listeners"] -= 1  # no room hears the decisions
        threshold = ({"threshold_mode": "file", "threshold_file": args.threshold_file}
                     if args.threshold_file else
                     {"threshold_mode": "calibrate", "calibration_s": args.calibration_s})
        nodes["mic_node"] = {"source": "sounddevice", "device": args.device,
                             "max_windows": steps, "wait_for_listeners": 4, **threshold}
        nodes["speaker_node"] = {"dry_run": False}
        clock = "mic_node"
    return run, nodes, clock


def run_calibration_session(args: argparse.Namespace) -> int:
    """Record the session; 0 after it, 1 if the graph failed, 2 for bad arguments."""
    steps = _check(args)
    demo.isolate_dds()
    demo.demo_dds_profile()  # its own graph starts as fast as the demo's
    run, nodes, clock = _graph(args, steps)
    where = "the simulated room" if args.fake_room else "live audio"
    print(f"# calibration-session: {args.minutes:g} min ({steps} windows) against {where},"
          f" a sound every {args.min_interval_s:g}-{args.max_interval_s:g} s; recording to"
          f" {args.out}", flush=True)
    outcome = demo._run_graph(run, nodes, clock)
    if isinstance(outcome, str):
        print(f"infomax-contingency calibration-session: error: {outcome}", file=sys.stderr)
        return 1
    monitor, steps_run, elapsed, released, mic_warnings = outcome
    demo.print_notes(clock, released, mic_warnings)
    print(f"# recorded {steps_run} steps, {sum(monitor.vocalize[:steps_run])} sounds, in"
          f" {elapsed:.1f} s; next: infomax-contingency analyze {args.out} --out params.yaml")
    return 0

"""The ``infomax-contingency`` command line: solve tables, simulate, inspect.

Every sub-command lives in a ``register_*`` function that adds its parser; user
errors (bad parameters, bad files, bad specifications) end with one line on stderr and
exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from infomax_contingency.cli.demo import register_demo
from infomax_contingency.cli.experiments import register_experiment, register_learn, register_plot
from infomax_contingency.cli.live import (
    register_calibrate,
    register_devices,
    register_measure_latency,
)
from infomax_contingency.core.controllers import CONTROLLER_KINDS, make_controller
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import EPISODIC, RECEDING, PolicyTable
from infomax_contingency.core.solver import solve
from infomax_contingency.errors import USER_ERRORS
from infomax_contingency.sim.simulation import RunSummary, StepRecord, iter_simulate
from infomax_contingency.sim.world import ROOM_NAMES, make_room


def _params_argument(parser: argparse.ArgumentParser, default: str = "robot") -> None:
    parser.add_argument(
        "--params",
        default=default,
        metavar="NAME|FILE",
        help=f"model parameters: a named set (paper, robot) or a YAML file (default: {default})",
    )


def _run_solve(args: argparse.Namespace) -> int:
    params = ModelParams.load(args.params)
    if args.mode == RECEDING and args.memory is None:
        raise ValueError("--mode receding needs --memory M (counted observations)")
    start = time.perf_counter()
    table = solve(params, args.mode, args.horizon, args.memory or 0)
    elapsed = time.perf_counter() - start
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    table.save(out)
    print(
        f"solved {args.mode} table (horizon {args.horizon}"
        + (f", memory {args.memory}" if args.mode == RECEDING else "")
        + f") for {args.params}: {table.n_statistics} statistics in {elapsed:.2f} s;"
        f" wrote {out} ({out.stat().st_size} bytes)"
    )
    return 0


def register_solve(subparsers: argparse._SubParsersAction) -> None:
    """``solve``: build a policy table by exact dynamic programming."""
    parser = subparsers.add_parser("solve", help="solve an optimal policy table (exact DP)")
    _params_argument(parser)
    parser.add_argument("--mode", choices=[EPISODIC, RECEDING], required=True)
    parser.add_argument("--horizon", type=int, required=True, help="T (episodic) or H (receding)")
    parser.add_argument("--memory", type=int, help="M: counted observations kept (receding)")
    parser.add_argument("--out", required=True, help="table file to write (.npz)")
    parser.set_defaults(run=_run_solve)


def _format_ratio(ratio: float | None) -> str:
    return "-" if ratio is None else f"{ratio:.4g}"


def _write_line(text: str) -> None:
    """One line on stdout, flushed at once (a streamed run shows each step as it happens)."""
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _stop_writing_stdout() -> None:
    """After a closed pipe (``... | head``): point stdout at /dev/null.

    Python flushes stdout again at exit; on the closed pipe that would print an
    "Exception ignored" message. Nothing more is written, so nothing is lost.
    """
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    finally:
        os.close(devnull)


SIMULATE_HEADER = (
    f"{'t':>5} {'time_s':>8} {'z':>2} {'y':>1} {'u':>1} {'belief':>10} {'entropy':>9} ratio"
)


def _simulate_row(r: StepRecord) -> str:
    """One step of the ``simulate`` table (columns of :data:`SIMULATE_HEADER`)."""
    return (
        f"{r.t:>5} {r.time_s:>8.2f} {r.z:>2} {r.y:>1} {r.u:>1} {r.belief:>10.6f}"
        f" {r.entropy:>9.5f} {_format_ratio(r.ratio)}"
    )


def _stream_simulation(args: argparse.Namespace) -> None:
    """Run the simulation, writing each step as it is computed (constant memory)."""
    params = ModelParams.load(args.params)
    rng = np.random.default_rng(args.seed)
    room = make_room(args.world, params, rng)
    controller = make_controller(args.controller, params, rng, memory=args.memory)
    records = iter_simulate(params, controller, room, args.steps, rng, memory=args.memory)
    if args.json:
        for record in records:
            _write_line(json.dumps(record.__dict__))
        return
    _write_line(SIMULATE_HEADER)
    summary = RunSummary()
    for record in records:
        summary.add(record)
        _write_line(_simulate_row(record))
    truth = "partner present" if room.partner_present else "no partner"
    _write_line(
        f"# room {room.name} ({truth}), controller {controller.name}:"
        f" {summary.vocalizations} vocalizations in {summary.steps} steps;"
        f" final P(S=1) = {summary.final_belief:.6f} -> {summary.verdict}"
        f" ({'correct' if summary.verdict == truth else 'wrong'})"
    )


def _run_simulate(args: argparse.Namespace) -> int:
    try:
        _stream_simulation(args)
    except BrokenPipeError:  # the reader stopped early (`... | head`): a normal end
        _stop_writing_stdout()
    return 0


def register_simulate(subparsers: argparse._SubParsersAction) -> None:
    """``simulate``: a controller against a simulated room, offline."""
    parser = subparsers.add_parser(
        "simulate", help="run a controller against a simulated room (offline, fast)"
    )
    _params_argument(parser)
    parser.add_argument(
        "--controller",
        default="rule",
        help=f"one of {', '.join(CONTROLLER_KINDS)} (default: rule, c = 9)",
    )
    parser.add_argument(
        "--world",
        default="responsive",
        help=f"{' | '.join(ROOM_NAMES)}, optionally NAME:key=value,... (default: responsive)",
    )
    parser.add_argument("--steps", type=int, default=40, help="number of windows (default 40)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--memory",
        type=int,
        default=0,
        help="observations the reported belief (and rule/greedy) keep; 0 = all (default)",
    )
    parser.add_argument("--json", action="store_true", help="one JSON object per step")
    parser.set_defaults(run=_run_simulate)


def _run_info(args: argparse.Namespace) -> int:
    table = PolicyTable.load(args.table)
    print(json.dumps(table.metadata(), indent=2))
    return 0


def register_info(subparsers: argparse._SubParsersAction) -> None:
    """``info``: validate a policy table and print its metadata."""
    parser = subparsers.add_parser("info", help="validate a policy table and print its metadata")
    parser.add_argument("table", help="table file (.npz)")
    parser.set_defaults(run=_run_info)


REGISTRARS: list[Callable[[argparse._SubParsersAction], None]] = [
    register_solve,
    register_simulate,
    register_info,
    register_devices,
    register_calibrate,
    register_measure_latency,
    register_experiment,
    register_learn,
    register_plot,
    register_demo,
]


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser."""
    parser = argparse.ArgumentParser(
        prog="infomax-contingency",
        description="Infomax contingency detection: solve policies, simulate, evaluate.",
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for register in REGISTRARS:
        register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except USER_ERRORS as error:
        print(f"infomax-contingency {args.command}: error: {error}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. `... | head`
        return 0


if __name__ == "__main__":
    sys.exit(main())

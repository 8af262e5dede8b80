"""The ``infomax-contingency`` command line: solve tables, simulate, inspect.

Every sub-command lives in a ``register_*`` function that adds its parser; user
errors (bad parameters, bad files, bad specifications) end with one line on stderr and
exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from infomax_contingency.cli import INTERRUPTED_STATUS
from infomax_contingency.cli.calibration_session import register_calibration_session
from infomax_contingency.cli.demo import register_demo
from infomax_contingency.cli.experiments import register_experiment, register_learn, register_plot
from infomax_contingency.cli.formatting import seed
from infomax_contingency.cli.live import (
    register_calibrate,
    register_devices,
    register_measure_latency,
)
from infomax_contingency.cli.rooms import register_room_wav
from infomax_contingency.cli.sessions import register_analyze, register_replay
from infomax_contingency.core.controllers import CONTROLLER_KINDS, make_controller
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import EPISODIC, RECEDING, PolicyTable
from infomax_contingency.core.solver import SolveCost, solve, solve_cost
from infomax_contingency.errors import USER_ERRORS
from infomax_contingency.limits import (
    check_output_file,
    format_bytes,
    format_number,
    memory_budget,
    refuse_writing_over_inputs,
)
from infomax_contingency.sim.simulation import RunSummary, StepRecord, iter_simulate
from infomax_contingency.sim.world import BIT_ROOM_NAMES, make_room


def _params_argument(parser: argparse.ArgumentParser, default: str = "robot") -> None:
    parser.add_argument(
        "--params",
        default=default,
        metavar="NAME|FILE",
        help=f"model parameters: a named set (paper, robot) or a YAML file (default: {default})",
    )


SIZE_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
"""Suffixes of ``--max-memory`` (binary: 4G = 4 GiB)."""
PROGRESS_EVERY_S = 1.0
"""Least interval between two progress lines of a solve, seconds."""


def parse_size(text: str) -> int:
    """Bytes from ``4G``, ``500M``, ``64k``, ``1.5GiB`` or a plain number of bytes.

    ValueError (one line, without the option's name) for anything else.
    """
    match = re.fullmatch(r"\s*(\d+(?:\.\d*)?)\s*([kKmMgGtT]?)(?:i?[bB])?\s*", text)
    if not match:
        raise ValueError(f"give bytes or a size such as 500M or 4G, got {text!r}")
    return int(float(match[1]) * SIZE_UNITS[match[2].upper()])


def memory_size(text: str) -> int:
    """A ``--max-memory`` option's value in bytes (:func:`parse_size`).

    An option type: a malformed size is argparse's one-line error naming the option, for
    every command that takes it, before the command does anything else.
    """
    try:
        return parse_size(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def format_count(count: int) -> str:
    """``5.43M``, ``460M``, ``4.17e+18``: 3 significant digits (any size)."""
    for power, suffix in ((9, "G"), (6, "M"), (3, "k")):
        if 10**power <= count < 10**12:
            return f"{count / 10**power:.3g}{suffix}"
    return str(count) if count < 1000 else format_number(count)


def format_seconds(seconds: float) -> str:
    """``0.06 s``, ``5.5 s``, ``3.2 min``, ``4.1 h``, ``2.3 days``, ``1.26e+03 years``."""
    if math.isinf(seconds):
        return "longer than the age of the universe"
    for unit, size in (("years", 365.25 * 86400), ("days", 86400), ("h", 3600), ("min", 60)):
        if seconds >= 2 * size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.2g} s" if seconds < 10 else f"{seconds:.0f} s"


def describe_cost(cost: SolveCost) -> str:
    """``5.43M statistics, about 70 MiB of memory and 0.06 s``."""
    return (
        f"{format_count(cost.statistics)} statistics, about {format_bytes(cost.peak_bytes)}"
        f" of memory and {format_seconds(cost.seconds)}"
    )


def memory_limit(args: argparse.Namespace) -> tuple[int, str]:
    """The memory a solve may use (bytes) and where that figure comes from.

    ``--max-memory`` (bytes, :func:`memory_size`), but never more than the process may
    take (:func:`~infomax_contingency.limits.memory_budget`: available memory,
    ``ulimit -v``, the cgroup's limit).
    """
    budget = memory_budget()
    if args.max_memory is not None and args.max_memory <= budget.bytes:
        return args.max_memory, "--max-memory"
    return budget.bytes, f"{budget.source}; --max-memory sets a lower limit"


def refuse_if_too_big(cost: SolveCost, args: argparse.Namespace, what: str) -> None:
    """ValueError (one line, with the estimate) when the solve would not fit in memory."""
    limit, source = memory_limit(args)
    if cost.peak_bytes > limit:
        raise ValueError(
            f"refusing to {what}: it needs {describe_cost(cost)}, more memory than"
            f" {format_bytes(limit)} ({source})"
        )


class ProgressPrinter:
    """Solve progress on stderr, at most once per :data:`PROGRESS_EVERY_S`.

    The expected total is the set-up time plus the sweep time so far divided by the
    fraction of the sweep done (before the first layer: the cost model's estimate).
    """

    def __init__(self, estimate_s: float) -> None:
        self.start = self.last = time.monotonic()
        self.sweep_start: float | None = None
        self.estimate_s = estimate_s

    def __call__(self, done: int, layers: int, fraction: float) -> None:
        now = time.monotonic()
        if self.sweep_start is None:
            self.sweep_start = now
        if now - self.last < PROGRESS_EVERY_S or done == layers:
            return
        self.last = now
        elapsed = now - self.start
        expected = self.estimate_s
        if fraction > 0:
            setup = self.sweep_start - self.start
            expected = setup + (now - self.sweep_start) / fraction
        print(
            f"solve: layer {done} of {layers}, {format_seconds(elapsed)} elapsed,"
            f" about {format_seconds(expected)} in all",
            file=sys.stderr,
            flush=True,
        )


def _run_solve(args: argparse.Namespace) -> int:
    params = ModelParams.load(args.params)
    if args.mode == RECEDING and args.memory is None:
        raise ValueError("--mode receding needs --memory M (counted observations)")
    memory = args.memory or 0
    cost = solve_cost(params, args.mode, args.horizon, memory)
    refuse_if_too_big(cost, args, f"solve horizon {args.horizon}")
    out = Path(args.out)
    check_output_file(out, "--out", "table file")
    refuse_writing_over_inputs((("--out", out),), (("--params", args.params),))
    print(f"solve: {describe_cost(cost)} (estimate)", flush=True)
    start = time.perf_counter()
    table = solve(params, args.mode, args.horizon, memory, ProgressPrinter(cost.seconds))
    elapsed = time.perf_counter() - start
    table.save(out)
    print(
        f"solved {args.mode} table (horizon {args.horizon}"
        + (f", memory {args.memory}" if args.mode == RECEDING else "")
        + f") for {args.params}: {table.n_statistics} statistics in {elapsed:.2f} s;"
        f" wrote {out} ({out.stat().st_size} bytes)"
    )
    return 0


def _max_memory_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--max-memory",
        type=memory_size,
        metavar="SIZE",
        help="refuse a solve expected to need more memory than this, e.g. 500M or 4G"
        " (default: the memory available now)",
    )


def register_solve(subparsers: argparse._SubParsersAction) -> None:
    """``solve``: build a policy table by exact dynamic programming."""
    parser = subparsers.add_parser("solve", help="solve an optimal policy table (exact DP)")
    _params_argument(parser)
    parser.add_argument("--mode", choices=[EPISODIC, RECEDING], required=True)
    parser.add_argument("--horizon", type=int, required=True, help="T (episodic) or H (receding)")
    parser.add_argument("--memory", type=int, help="M: counted observations kept (receding)")
    parser.add_argument("--out", required=True, help="table file to write (.npz)")
    _max_memory_argument(parser)
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
        help=f"{' | '.join(BIT_ROOM_NAMES)}, optionally NAME:key=value,... (default: responsive)",
    )
    parser.add_argument("--steps", type=int, default=40, help="number of windows (default 40)")
    parser.add_argument("--seed", type=seed, default=0, help="random seed (default 0)")
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
    print(json.dumps(table.metadata(), indent=2), flush=True)
    return _verify(table, args) if args.verify else 0


def _verify(table: PolicyTable, args: argparse.Namespace) -> int:
    """Solve the table again and compare every action bit; 0 if equal, 1 if not."""
    cost = solve_cost(table.params, table.mode, table.horizon, table.memory)
    refuse_if_too_big(cost, args, f"verify {args.table}")
    print(f"verify: solving again, {describe_cost(cost)} (estimate)", flush=True)
    start = time.perf_counter()
    fresh = solve(
        table.params, table.mode, table.horizon, table.memory, ProgressPrinter(cost.seconds)
    )
    elapsed = time.perf_counter() - start
    differing = int(np.unpackbits(table.packed_actions ^ fresh.packed_actions).sum())
    if differing == 0 and table.same_policy_as(fresh):
        print(
            f"verified: all {table.n_statistics:,} action bits equal a fresh solve"
            f" ({elapsed:.2f} s)"
        )
        return 0
    fields = sorted(k for k, v in fresh.metadata().items() if table.metadata().get(k) != v)
    print(
        f"MISMATCH: {differing:,} of {table.n_statistics:,} action bits differ from a fresh"
        f" solve; metadata fields that differ: {', '.join(fields) or 'none'}"
    )
    return 1


def register_info(subparsers: argparse._SubParsersAction) -> None:
    """``info``: validate a policy table and print its metadata."""
    parser = subparsers.add_parser("info", help="validate a policy table and print its metadata")
    parser.add_argument("table", help="table file (.npz)")
    parser.add_argument(
        "--verify",
        action="store_true",
        help="also solve the table again and compare every action bit (exit 1 if any differs)",
    )
    _max_memory_argument(parser)
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
    register_room_wav,
    register_replay,
    register_analyze,
    register_calibration_session,
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


def _named(argv: Sequence[str] | None) -> str:
    """``infomax-contingency COMMAND``, the command the arguments' first word names.

    For a message before the arguments are parsed; the program alone if there is none.
    """
    words = sys.argv[1:] if argv is None else list(argv)
    command = words[0] if words and not words[0].startswith("-") else ""
    return f"infomax-contingency {command}".strip()


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status.

    One line on stderr for a user error or memory running out (status 2) and for a
    Ctrl-C (status 130), never a traceback — also while the parser is being built.
    """
    name = _named(argv)
    try:
        args = build_parser().parse_args(argv)
        name = f"infomax-contingency {args.command}"
        return args.run(args)
    except BrokenPipeError:  # e.g. `... | head` (an OSError: before USER_ERRORS)
        devnull = os.open(os.devnull, os.O_WRONLY)  # nothing more to write at exit either
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    except USER_ERRORS as error:
        print(f"{name}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return INTERRUPTED_STATUS
    except MemoryError:  # a size no cost check foresaw: one line, not a traceback
        print(f"{name}: error: out of memory: the sizes asked for need more memory than"
              " this process may use (docs/LIMITS.md)", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

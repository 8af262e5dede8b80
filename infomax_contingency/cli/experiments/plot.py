"""``plot``: the four-panel figure of a simulated or recorded session.

The figure is drawn by :mod:`infomax_contingency.eval.plots`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from infomax_contingency.cli.formatting import GivenOption, seed
from infomax_contingency.core.controllers import CONTROLLER_KINDS, make_controller
from infomax_contingency.core.model import NAMED_PARAMS, ModelParams
from infomax_contingency.eval import plots
from infomax_contingency.limits import (
    check_output_file,
    refuse_over_budget,
    refuse_writing_over_inputs,
)
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.simulation import simulate
from infomax_contingency.sim.world import BIT_ROOM_NAMES, make_room

DEFAULT_TABLES = {"robot": "robot_receding_H24_M60.npz", "paper": "paper_episodic_T40.npz"}
PLOT_BASE_BYTES = 400 * 2**20
"""Memory of a plot of a few steps (the interpreter, numpy, matplotlib, a table), bytes."""
PLOT_BYTES_PER_STEP = 16 * 2**10
"""Memory a simulated plot takes per step, bytes (measured: 11.5 KiB; /usr/bin/time of
``plot --steps 20000`` and ``--steps 200000``: 377 MB and 2.45 GB peak)."""


def _default_controller(params: ModelParams) -> str:
    """The committed optimal table of a reference set, else the rule."""
    for name, file_name in DEFAULT_TABLES.items():
        if NAMED_PARAMS[name] == params:
            return f"policy:{resource_path('policies', file_name)}"
    return "rule"


def _run_plot(args: argparse.Namespace) -> int:
    check_output_file(args.out, "--out", "figure")  # before the work
    if args.session and args.given:
        options = ", ".join(f"--{name}" for name in sorted(args.given))
        raise ValueError(f"{options}: for a simulated session only; --session {args.session}"
                         " is drawn as it was recorded")
    inputs = (("--session", args.session), ("--params", args.params))
    refuse_writing_over_inputs((("--out", args.out),), inputs)
    params = ModelParams.load(args.params)
    memory = args.memory
    if args.session and Path(args.session).is_dir():  # a recorded session (bag)
        from infomax_contingency.cli.sessions import warn
        from infomax_contingency.eval.sessions import (
            check_belief_model,
            check_window,
            load_session,
            replay_recorded,
            session_memory,
            with_session_model,
        )

        session = load_session(Path(args.session), warn=warn)
        check_window(session, params, args.params, args.session)
        check_belief_model(session, params, args.params, args.session)
        memory = session_memory(session, memory or None)  # 0: belief_node's, from the bag

        def replay(model: ModelParams) -> tuple[bool, list[dict]]:
            rows = [record.__dict__ for record in replay_recorded(session, model, memory)]
            beliefs = [row["belief"] for row in rows][:len(session.beliefs)]
            return bool(beliefs) and beliefs == session.beliefs[:len(beliefs)], rows

        params, records, _ = with_session_model(session, params, replay)  # the recorded one
        if not records:
            raise ValueError(f"the session {args.session} has no step to plot: no recorded"
                             " bit was answered by a recorded decision")
        title = args.title or f"recorded session {Path(args.session).name}"
    elif args.session:
        records = plots.read_session(args.session)
        title = args.title or f"session {Path(args.session).name}"
    else:
        if args.steps < 1:
            raise ValueError(f"--steps must be >= 1, got {args.steps}")
        refuse_over_budget(PLOT_BASE_BYTES + PLOT_BYTES_PER_STEP * args.steps,
                           f"plot {args.steps:,} steps", "give fewer --steps")
        rng = np.random.default_rng(args.seed)
        room = make_room(args.world, params, rng)
        controller = make_controller(
            args.controller or _default_controller(params), params, rng, memory=args.memory
        )
        steps = simulate(params, controller, room, args.steps, rng, memory=args.memory)
        records = [record.__dict__ for record in steps]
        title = args.title or (
            f"{args.params} parameters, {controller.name} in room {room.name}, seed {args.seed}"
        )
    path = plots.plot_session(params, records, args.out, title=title, memory=memory)
    print(f"wrote {path} ({path.stat().st_size:,} bytes, {len(records)} steps)")
    return 0


def register_plot(subparsers: argparse._SubParsersAction) -> None:
    """``plot``: the four-panel figure of a simulated or recorded session."""
    parser = subparsers.add_parser(
        "plot", help="plot a session (simulated now, or a `simulate --json` file) to a PNG"
    )
    parser.add_argument("--out", required=True, help="PNG file to write")
    parser.add_argument(
        "--session",
        help="a session bag (recorder_node; replayed with its recorded actions) or a"
        " JSON-lines file (`simulate --json` output); else simulate",
    )
    parser.add_argument(
        "--params", default="robot", help="parameter set of the session (default: robot)"
    )
    # the simulation's options note that they were given: with --session they are refused
    parser.set_defaults(given=frozenset())
    parser.add_argument(
        "--controller",
        action=GivenOption,
        help=f"controller to simulate: {', '.join(CONTROLLER_KINDS)} (default: the committed"
        " optimal table of the paper or robot set, else the rule)",
    )
    parser.add_argument(
        "--world",
        default="responsive",
        action=GivenOption,
        help=f"room to simulate: {' | '.join(BIT_ROOM_NAMES)}[:key=value,...] (default responsive)",
    )
    parser.add_argument("--steps", type=int, default=120, action=GivenOption,
                        help="steps to simulate (default 120)")  # fmt: skip
    parser.add_argument("--seed", type=seed, default=0, action=GivenOption,
                        help="random seed (default 0)")  # fmt: skip
    parser.add_argument(
        "--memory",
        type=int,
        default=0,
        help="sliding memory of the replayed counts (and of rule/greedy); 0 = all (default;"
        " for a bag: belief_node's memory, from the bag)",
    )
    parser.add_argument("--title", help="figure title, shown as written ($ is no math)")
    parser.set_defaults(run=_run_plot)

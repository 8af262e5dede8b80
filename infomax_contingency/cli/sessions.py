"""``replay``: a recorded session (a recorder_node bag) computed again offline.

``--actions recorded`` (the default) drives the statistic with the robot's recorded
decisions, no policy in the loop: the replayed belief equals the recorded one step for
step, and the command says whether it does (exit status 1 if not). ``--json`` prints
one line per step with the keys of ``simulate --json`` (t, z, y, u, belief, entropy,
ratio), streamed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.sessions import load_session, replay_recorded

ACTION_SOURCES = ("recorded",)
"""The ``--actions`` values implemented (policy:FILE, FILE.csv and channel:N are not yet)."""


def register_replay(subparsers: argparse._SubParsersAction) -> None:
    """``replay SESSION``: the belief of a recorded session, computed again."""
    parser = subparsers.add_parser(
        "replay", help="replay a recorded session (bag) offline with its recorded actions"
    )
    parser.add_argument("session", metavar="SESSION", help="bag directory written by recorder_node")
    parser.add_argument(
        "--actions", default="recorded",
        help="where the robot's actions come from: recorded (default; the only one so far)",
    )
    parser.add_argument(
        "--params", default="robot", metavar="NAME|FILE",
        help="model parameters the session ran with (default: robot)",
    )
    parser.add_argument(
        "--memory", type=int, default=None,
        help="observations the belief keeps; default: belief_node's, from the bag",
    )
    parser.add_argument("--json", action="store_true", help="one JSON object per step")
    parser.set_defaults(run=run_replay)


def run_replay(args: argparse.Namespace) -> int:
    """Replay; 0 when the replayed belief equals the recorded one, 1 when it does not."""
    if args.actions not in ACTION_SOURCES:
        raise ValueError(
            f"--actions {args.actions}: not supported yet; use one of {', '.join(ACTION_SOURCES)}"
        )
    if args.memory is not None and args.memory < 0:
        raise ValueError(f"--memory must be >= 0 (0 = all), got {args.memory}")
    session = load_session(Path(args.session))
    params = ModelParams.load(args.params)
    replayed = []
    for record in replay_recorded(session, params, args.memory):
        replayed.append(record.belief)
        if args.json:
            sys.stdout.write(json.dumps(record.__dict__) + "\n")
            sys.stdout.flush()
    same = replayed == session.beliefs
    first_difference = next(
        (i for i, (a, b) in enumerate(zip(replayed, session.beliefs, strict=False)) if a != b),
        min(len(replayed), len(session.beliefs)),
    )
    verdict = (
        f"replayed belief equals the recorded belief at all {len(replayed)} steps" if same else
        f"replayed belief DIFFERS from the recorded one from step {first_difference + 1}"
        f" ({len(replayed)} steps replayed, {len(session.beliefs)} beliefs recorded)"
    )
    print(f"# replay {args.session}: {verdict}", file=sys.stderr if args.json else sys.stdout)
    return 0 if same else 1

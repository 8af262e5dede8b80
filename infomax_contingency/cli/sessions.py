"""``replay`` and ``analyze``: recorded sessions (recorder_node bags) studied offline.

``replay``: a recorded session (a recorder_node bag) computed again offline.

``--actions recorded`` (the default) drives the statistic with the robot's recorded
decisions, no policy in the loop: the replayed belief equals the recorded one step for
step, and the command says whether it does (exit status 1 if not). ``--json`` prints
one line per step with the keys of ``simulate --json`` (t, z, y, u, belief, entropy,
ratio), streamed. ``analyze``: the Fig. 4 study (:mod:`infomax_contingency.eval.fig4`)
of one or more sessions, and a parameter file for ``solve --params``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.fig4 import Rate, fig4_study_of_runs, trial_raster
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


def register_analyze(subparsers: argparse._SubParsersAction) -> None:
    """``analyze SESSION...``: the Fig. 4 study of recorded sessions."""
    parser = subparsers.add_parser(
        "analyze",
        help="P(sound) against time since the robot's sound in recorded sessions (Fig. 4);"
        " the self and reply periods as a parameter file",
    )
    parser.add_argument("sessions", nargs="+", metavar="SESSION", help="bag directories")
    parser.add_argument(
        "--params", default="robot", metavar="NAME|FILE",
        help="model parameters the sessions ran with; the base of --out (default: robot)",
    )
    parser.add_argument("--out", metavar="FILE", help="write a parameter file for solve --params")
    parser.add_argument("--plot", metavar="FIG.png", help="draw the raster and P(active) here")
    parser.add_argument(
        "--max-lag-s", type=float, default=10.0, help="longest lag shown, seconds (default 10)"
    )
    parser.add_argument(
        "--background-from-s", type=float, default=3.0,
        help="lags from this many seconds on count as background (default 3)",
    )
    parser.set_defaults(run=run_analyze)


def _rate_text(rate: Rate | None) -> str:
    if rate is None or rate.total == 0:
        return "-"
    low, high = rate.interval
    return f"{rate.value:.3f} [{low:.3f}, {high:.3f}] ({rate.active}/{rate.total})"


def run_analyze(args: argparse.Namespace) -> int:
    """Print the study; write ``--out`` when both peaks are found. 0, or 1 if data lack."""
    params = ModelParams.load(args.params)
    max_lag = max(1, round(args.max_lag_s / params.dt))
    background_from = max(1, min(max_lag, round(args.background_from_s / params.dt)))
    runs = []
    for directory in args.sessions:
        records = list(replay_recorded(load_session(Path(directory)), params))
        runs.append(([bool(r.y) for r in records], [bool(r.u) for r in records]))
    study = fig4_study_of_runs(runs, max_lag, background_from)
    if args.plot:
        from infomax_contingency.eval.fig4_plot import fig4_figure

        print(f"wrote {fig4_figure(study, trial_raster(runs, max_lag), params.dt, args.plot)}")
    print(f"# {len(args.sessions)} session(s), {study.vocalizations} vocalizations,"
          f" windows of {params.dt:g} s (lag 0 = the window right after the decision)")
    print("lag  time_s  P(active) [95 %]")
    for lag, rate in enumerate(study.by_lag):
        print(f"{lag:3d}  {lag * params.dt:6.2f}  {_rate_text(rate)}")
    print(f"background rate: {_rate_text(study.background)}")
    print(f"self-feedback period (ts1, ts2): {study.self_period or 'not found'},"
          f" rate {_rate_text(study.self_rate)}")
    print(f"reply period (ta1, ta2): {study.agent_period or 'not found'},"
          f" rate {_rate_text(study.reply_rate)}")
    shortcomings = study.shortcomings()
    for line in shortcomings:
        print(f"too little data: {line}")
    if args.out:
        if study.self_period is None or study.agent_period is None:
            print(f"--out {args.out}: not written (both peaks are needed)")
            return 1
        values = {**params.__dict__, "ts1": study.self_period[0], "ts2": study.self_period[1],
                  "ta1": study.agent_period[0], "ta2": study.agent_period[1]}
        ModelParams(**values)  # refuses an inconsistent set before anything is written
        Path(args.out).write_text(yaml.safe_dump(values, sort_keys=False))
        print(f"wrote {args.out}: infomax-contingency solve --params {args.out} ...")
    return 1 if shortcomings else 0

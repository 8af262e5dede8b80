"""``replay`` and ``analyze``: recorded sessions (recorder_node bags) studied offline.

``replay``: a recorded session (a recorder_node bag) computed again offline.

``--actions recorded`` (the default) drives the statistic with the robot's recorded
decisions, no policy in the loop: the replayed belief equals the recorded one step for
step, and the command says whether it does (exit status 1 if not). ``--actions
policy:FILE`` (or any ``simulate --controller``) puts a table or rule in the loop on the
recorded bits (a what-if). A plain wav file replays with ``--actions FILE.csv`` (column
``time_s``) or ``--actions channel:N`` (the robot's own output on channel N); see
:mod:`infomax_contingency.eval.sessions` for how times and onsets map to steps. ``--json`` prints
one line per step with the keys of ``simulate --json`` (t, z, y, u, belief, entropy,
ratio), streamed. ``analyze``: the Fig. 4 study (:mod:`infomax_contingency.eval.fig4`)
of one or more sessions, and a parameter file for ``solve --params``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import yaml

from infomax_contingency.audio.bitsources.background import BackgroundSettings, band_name
from infomax_contingency.audio.energy import wav_window_count
from infomax_contingency.audio.wav import open_wav_info
from infomax_contingency.audio.windows import WavReplay
from infomax_contingency.cli.formatting import seed
from infomax_contingency.core.controllers import ReplayedDecisions, make_controller
from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.fig4 import Rate, fig4_study_of_runs, trial_raster
from infomax_contingency.eval.session_verdict import replay_with_its_model, restarted_belief_nodes
from infomax_contingency.eval.sessions import (
    RecordedSession,
    check_belief_model,
    check_same_windows,
    check_window,
    decisions_from_reference,
    decisions_from_times,
    load_session,
    recorded_bits,
    replay_bits,
    replay_recorded,
    replay_windows,
    session_memory,
    wav_background_bits,
    wav_background_loop,
    wav_bits,
)
from infomax_contingency.limits import (
    check_output_files,
    refuse_writing_over_inputs,
    written_atomically,
)
from infomax_contingency.sim.actions import read_actions_csv
from infomax_contingency.sim.simulation import RunSummary

DEFAULT_CALIBRATION_S = 10.0
"""s at a wav file's start that ``replay --calibrate`` calibrates its threshold on."""

ACTION_KINDS = ("recorded", "policy:FILE", "rule[:C]", "FILE.csv", "channel:N")
"""The ``--actions`` values: recorded (a bag's own), a controller (policy:FILE, or any
``simulate --controller``), an actions CSV file or a reference channel (a wav file)."""


def register_replay(subparsers: argparse._SubParsersAction) -> None:
    """``replay SESSION``: the belief of a recorded session, computed again."""
    parser = subparsers.add_parser(
        "replay", help="replay a recorded session (bag) or a wav file offline",
        description="Replay a session bag with its recorded actions (the default) or with"
        " a policy in the loop (what-if), or a plain wav file with its actions from a CSV"
        " file (column time_s: when the robot's sound was commanded) or from a channel"
        " carrying the robot's own output.",
    )
    parser.add_argument("session", metavar="SESSION",
                        help="bag directory written by recorder_node, or a .wav file")
    parser.add_argument(
        "--actions", default=None,
        help="recorded (default for a bag), policy:FILE or another controller (what-if),"
        " FILE.csv or channel:N (for a wav file)",
    )
    parser.add_argument(
        "--params", default="robot", metavar="NAME|FILE",
        help="model parameters the session ran with (default: robot)",
    )
    parser.add_argument(
        "--memory", type=int, default=None,
        help="observations the belief keeps; default: belief_node's, from the bag (a wav"
        " file: all)",
    )
    parser.add_argument("--seed", type=seed, default=0, help="seed of a random controller")
    parser.add_argument("--mic-channel", type=int, default=None, metavar="C",
                        help="wav: the microphone's channel (default: the mix of all; with"
                        " channel:N the lowest channel other than N)")
    parser.add_argument("--threshold-db", type=float, default=None,
                        help="wav: a fixed sound threshold, dB (default: the self-calibrating"
                        " threshold of mic_node, bit_source background)")
    parser.add_argument("--calibrate", action="store_true",
                        help="wav: the k-means threshold of the first --calibration-s seconds"
                        " instead")
    parser.add_argument("--calibration-s", type=float, default=None,
                        help="wav: seconds at its start to calibrate the threshold on"
                        f" (--calibrate; default {DEFAULT_CALIBRATION_S:g})")
    parser.add_argument("--false-alarm", type=float,
                        help="wav: the share of background windows above the self-calibrating"
                        " threshold (mic_node's false_alarm; default 0.05)")
    parser.add_argument("--level-band", choices=("speech", "full"),
                        help="wav: the band of the self-calibrating threshold's level"
                        " (mic_node's level_band; default speech, 300-3400 Hz)")
    parser.add_argument("--json", action="store_true", help="one JSON object per step")
    parser.set_defaults(run=run_replay)


def _check_replay(args: argparse.Namespace, is_wav: bool) -> str:  # noqa: C901
    """The ``--actions`` kind after checking the arguments (ValueError: one line)."""
    if args.memory is not None and args.memory < 0:
        raise ValueError(f"--memory must be >= 0 (0 = all), got {args.memory}")
    wav_only = [option for option, value in (("--mic-channel", args.mic_channel),
                                             ("--threshold-db", args.threshold_db),
                                             ("--calibrate", args.calibrate or None))
                if value is not None]
    if wav_only and not is_wav:
        raise ValueError(f"{wav_only[0]} applies to a wav file: a recorded session replays the"
                         " bits it recorded")  # fmt: skip
    if args.calibration_s is not None and not args.calibrate:
        raise ValueError("--calibration-s is the length of --calibrate's k-means calibration:"
                         " give --calibrate too")  # fmt: skip
    if args.calibration_s is None:
        args.calibration_s = DEFAULT_CALIBRATION_S
    if not (math.isfinite(args.calibration_s) and args.calibration_s > 0):
        raise ValueError(f"--calibration-s must be > 0 seconds, got {args.calibration_s}")
    if args.calibrate and args.threshold_db is not None:
        raise ValueError("--calibrate or --threshold-db: a wav file's threshold is one of them")
    if args.threshold_db is not None and not -150.0 <= args.threshold_db <= 0.0:
        raise ValueError(f"--threshold-db must lie in -150 .. 0 dB, got {args.threshold_db}")
    if args.mic_channel is not None and args.mic_channel < 0:
        raise ValueError(f"--mic-channel must be >= 0, got {args.mic_channel}")
    given = [option for option, value in (("--false-alarm", args.false_alarm),
                                          ("--level-band", args.level_band)) if value is not None]
    if given and (not is_wav or args.threshold_db is not None or args.calibrate):
        raise ValueError(f"{given[0]} sets a wav file's self-calibrating threshold: not with a"
                         " recorded session, --threshold-db or --calibrate")  # fmt: skip
    actions = args.actions or ("recorded" if not is_wav else "")
    if actions.startswith("channel:"):
        kind = "channel"
    elif actions.lower().endswith(".csv"):
        kind = "csv"
    elif actions == "recorded":
        kind = "recorded"
    elif actions:
        kind = "controller"
    else:
        raise ValueError(f"{args.session} is a wav file: it has no recorded actions; give"
                         " --actions FILE.csv, channel:N or policy:FILE")
    if is_wav and kind == "recorded":
        raise ValueError(f"--actions recorded: {args.session} is a wav file: it has no"
                         " recorded actions; give --actions FILE.csv, channel:N or policy:FILE")
    if not is_wav and kind in ("csv", "channel"):
        raise ValueError(f"--actions {actions}: an actions file or channel goes with a wav"
                         f" file; the session {args.session} has its recorded actions")
    return kind


def _reference_channel(text: str) -> int:
    number = text.partition(":")[2]
    if not number.isdigit():
        raise ValueError(f"--actions {text}: the channel must be a whole number >= 0,"
                         " e.g. channel:1")
    return int(number)


def _wav_records(args: argparse.Namespace, kind: str, params: ModelParams
                 ) -> tuple[Iterator, str, list[str]]:
    """A wav file's replayed steps, where its actions came from, and its bit source's problems.

    The problems of a what-if are filled in once its steps are done.
    """
    path = Path(args.session)
    mic = args.mic_channel
    reference = _reference_channel(args.actions) if kind == "channel" else None
    if reference is not None:
        channels = open_wav_info(path).channels
        if reference >= channels:
            raise ValueError(f"--actions {args.actions}: {path} has {channels} channel(s),"
                             f" numbered 0 .. {channels - 1}")
        if channels < 2:
            raise ValueError(f"--actions {args.actions}: {path} has one channel; the robot's"
                             " output must be a channel beside the microphone's")
        mic = (0 if reference != 0 else 1) if mic is None else mic
        if mic == reference:
            raise ValueError(f"--mic-channel {mic} is the reference channel of --actions"
                             f" {args.actions}")
    memory = args.memory or 0
    if args.threshold_db is None and not args.calibrate:
        return _wav_background_records(args, kind, params, path, mic, reference, memory)
    bits, threshold, problems = wav_bits(path, params.dt, mic, args.threshold_db,
                                         args.calibration_s)
    if kind == "controller":
        controller = make_controller(args.actions, params, np.random.default_rng(args.seed),
                                     memory=memory)
        what = f"controller {controller.name} deciding on the recorded bits (what-if)"
    else:
        if kind == "csv":
            times = read_actions_csv(Path(args.actions))
            decisions = decisions_from_times(times, len(bits), params.dt,
                                             f"actions file {args.actions}")
            what = f"actions from {args.actions}"
        else:
            decisions, level = decisions_from_reference(path, reference, params.dt)
            what = f"actions from the onsets of channel {reference} (threshold {level:.1f} dB)"
        controller = ReplayedDecisions(params, decisions)
    return (replay_bits(bits, controller, memory), f"{what}; sound threshold {threshold:.1f} dB",
            problems)


def _wav_background_records(args: argparse.Namespace, kind: str, params: ModelParams,
                            path: Path, mic: int | None, reference: int | None, memory: int
                            ) -> tuple[Iterator, str, list[str]]:
    """A wav file's steps with mic_node's default threshold (``background``)."""
    given = (("false_alarm", args.false_alarm), ("level_band", args.level_band))
    options = {name: value for name, value in given if value is not None}
    levels = band_name(args.level_band or BackgroundSettings.level_band)
    if kind == "controller":
        WavReplay(path, params.dt, mic)  # the file and its channel first (one-line errors)
        controller = make_controller(args.actions, params, np.random.default_rng(args.seed),
                                     memory=memory)
        problems: list[str] = []
        records = wav_background_loop(path, params, mic, controller, memory, problems, **options)
        return records, (f"controller {controller.name} deciding on the recorded bits (what-if);"
                         f" self-calibrating sound threshold ({levels} levels)"), problems
    WavReplay(path, params.dt, mic)  # the file, its rate and channel first (one-line errors)
    windows = wav_window_count(open_wav_info(path), params.dt)
    if kind == "csv":
        decisions = decisions_from_times(read_actions_csv(Path(args.actions)), windows,
                                         params.dt, f"actions file {args.actions}")
        what = f"actions from {args.actions}"
    else:
        decisions, level = decisions_from_reference(path, reference, params.dt)
        what = f"actions from the onsets of channel {reference} (threshold {level:.1f} dB)"
    bits, threshold = wav_background_bits(path, params, mic, decisions, **options)
    records = replay_windows(bits, decisions, params, memory)
    first = next((k for k, bit in enumerate(bits) if bit is not None), len(bits))
    later = sum(bit is None for bit in bits[first:])
    more = f", {later} later windows gave no step either" if later else ""
    return records, (f"{what}; {threshold}; the first {first} windows heard the room (no step)"
                     f"{more}"), []  # fmt: skip


def run_replay(args: argparse.Namespace) -> int:
    """Replay; with recorded actions 0 when the belief equals the recorded one, else 1."""
    is_wav = Path(args.session).suffix.lower() == ".wav" and not Path(args.session).is_dir()
    kind = _check_replay(args, is_wav)
    params = ModelParams.load(args.params)
    if is_wav:
        records, what, problems = _wav_records(args, kind, params)
        return _print_what_if(args, records, what, problems)
    session = load_session(Path(args.session), warn=warn)
    check_window(session, params, args.params, args.session)
    check_belief_model(session, params, args.params, args.session)
    if kind == "controller":
        memory = session_memory(session, args.memory)
        controller = make_controller(args.actions, params, np.random.default_rng(args.seed),
                                     memory=memory)
        records = replay_bits(recorded_bits(session), controller, memory)
        return _print_what_if(args, records, f"controller {controller.name} deciding on the"
                              " recorded bits (what-if)")
    params, records, same, verdict = replay_with_its_model(session, params, args.memory)
    for record in records if args.json else ():
        _write_line(json.dumps(record.__dict__))
    if same and session.belief_restarts:
        same, verdict = restarted_belief_nodes(session, params, args.memory, records, verdict)
    print(f"# replay {args.session}: {verdict}", file=sys.stderr if args.json else sys.stdout)
    return 0 if same else 1


def warn(message: str) -> None:
    """A warning about the input (a bag cut by a killed recorder): one line on stderr."""
    print(f"warning: {message}", file=sys.stderr, flush=True)


def _write_line(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _print_what_if(args: argparse.Namespace, records: Iterator, what: str,
                   problems: Sequence[str] = ()) -> int:
    """Stream the steps (``--json``) and print a summary line; 0 (1: there was no step).

    ``problems``: lines the summary adds once the steps are done (they fill it).
    """
    summary = RunSummary()
    for record in records:
        summary.add(record)
        if args.json:
            _write_line(json.dumps(record.__dict__))
    final = "-" if summary.final_belief is None else f"{summary.final_belief:.6f}"
    what += "".join(f"; {problem}" for problem in problems)
    print(f"# replay {args.session}, {what}: {summary.steps} steps, {summary.vocalizations}"
          f" vocalizations; final P(S=1) = {final} -> {summary.verdict}",
          file=sys.stderr if args.json else sys.stdout)
    return 0 if summary.steps else 1


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


def _refuse_twice(sessions: Sequence[str]) -> None:
    """Refuse a session given twice (the same directory, however named): its evidence once."""
    seen: dict[Path, str] = {}
    for name in sessions:
        resolved = Path(name).resolve()
        if resolved in seen:
            same = "" if seen[resolved] == name else f" (as {seen[resolved]} and {name})"
            raise ValueError(f"the session {resolved} is given twice{same}: each session's"
                             " evidence counts once, give it once")
        seen[resolved] = name


def _refuse_copies(sessions: Sequence[tuple[str, RecordedSession]]) -> None:
    """Refuse two sessions that are one recording (a copy): its stream, bits and decisions."""
    seen: dict[tuple, str] = {}
    for name, session in sessions:
        key = (session.stream, tuple(session.bits), tuple(session.decisions))
        if key in seen:
            raise ValueError(f"the sessions {seen[key]} and {name} are one recording (mic_node"
                             f" stream {session.stream}, the same steps): each session's"
                             " evidence counts once, give it once")
        seen[key] = name


def run_analyze(args: argparse.Namespace) -> int:
    """Print the study; write ``--out`` when both peaks are found. 0, or 1 if data lack."""
    for option, value in (("--max-lag-s", args.max_lag_s),
                          ("--background-from-s", args.background_from_s)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{option} must be a number of seconds > 0, got {value}")
    _refuse_twice(args.sessions)
    check_output_files(("--out", args.out, "parameter file"), ("--plot", args.plot, "figure"))
    refuse_writing_over_inputs(
        (("--out", args.out), ("--plot", args.plot)),
        (("--params", args.params), *(("a session", name) for name in args.sessions)),
    )  # fmt: skip
    params = ModelParams.load(args.params)
    sessions = [(name, load_session(Path(name), warn=warn)) for name in args.sessions]
    check_same_windows(sessions)
    check_window(sessions[0][1], params, args.params, sessions[0][0])
    _refuse_copies(sessions)
    runs = []
    for _, session in sessions:
        records = list(replay_recorded(session, params, memory=0,  # bits and decisions
                                       follow_restarts=False))  # one stream: no gap inside
        runs.append(([bool(r.y) for r in records], [bool(r.u) for r in records]))
    # no lag can be longer than the longest session: the table stops there
    longest = max(len(bits) for bits, _ in runs)
    max_lag = max(1, min(round(args.max_lag_s / params.dt), longest))
    if max_lag < round(args.max_lag_s / params.dt):
        print(f"# lags shown up to {max_lag * params.dt:g} s, the longest session"
              f" (--max-lag-s {args.max_lag_s:g})")
    background_from = max(1, min(max_lag, round(args.background_from_s / params.dt)))
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
        with written_atomically(args.out, "--out") as stream:
            stream.write(yaml.safe_dump(values, sort_keys=False).encode("utf-8"))
        print(f"wrote {args.out}: infomax-contingency solve --params {args.out} ...")
    return 1 if shortcomings else 0

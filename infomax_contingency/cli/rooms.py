"""Command-line parts of the audio rooms: ``experiment rooms`` and ``room-wav``.

* ``experiment rooms`` — :func:`infomax_contingency.eval.rooms.experiment_rooms`: from a
  room's sound to the posture, per room and controller (tables, ``--json``, ``--out``,
  ``--plot``).
* ``room-wav ROOM`` — a room's sound as a wav, and its actions file, for listening.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

from infomax_contingency.audio.wav import write_wav_int16
from infomax_contingency.cli.formatting import json_default, number, seed
from infomax_contingency.eval import plots
from infomax_contingency.eval import rooms as evaluation
from infomax_contingency.eval.information import (
    VOCALIZATION_TARGETS,
)
from infomax_contingency.limits import (
    check_output_files,
    refuse_writing_over_inputs,
    spec_file,
    written_atomically,
)
from infomax_contingency.sim.actions import HEADER as ACTIONS_HEADER
from infomax_contingency.sim.actions import write_actions_csv
from infomax_contingency.sim.rooms import AUDIO_ROOM_NAMES

_TARGETS = " / ".join(str(n) for n in VOCALIZATION_TARGETS)
"""The vocalization targets the bounds are printed for, as the header names them."""


def _names(text: str) -> tuple[str, ...]:
    return tuple(item.strip() for item in text.split(",") if item.strip())


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(item) for item in text.split(",") if item.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected numbers separated by commas, got {text!r}"
        ) from None


def _median_ci(median: float, ci: Any, unit: str = "") -> str:
    if math.isinf(median):
        return "not settled"
    high = "-" if math.isinf(ci[1]) else number(ci[1])
    return f"{number(median)}{unit} [{number(ci[0])}, {high}]"


def _percent(value: float) -> str:
    return "-" if math.isnan(value) else f"{100 * value:.0f} %"


def _rate(rate: dict) -> str:
    if not rate["windows"]:
        return "-"
    return f"{rate['p']:.2f} ({rate['windows']})"


def print_rooms(result: dict) -> None:
    """The experiment's tables: one per controller, then the operating curves."""
    config = result["config"]
    print(
        f"experiment rooms: {config['runs']} runs of {config['seconds']:g} s per room and"
        f" controller; binarizer {config['binarizer']}; belief memory {config['memory']} steps;"
        f" check-ins every {config['check_in_every_s']:g} s above {config['check_in_above']:g};"
        f" posture attentive above {config['attentive_above']:g}, bored below"
        f" {config['bored_below']:g}; partner arrives / leaves at {result['room_change_s']:g} s;"
        f" seed {config['seed']}"
    )
    print(
        "settled: median s [95 % CI] and vocalizations until the posture is correct and stays"
        " so (from the change in +arriving / +leaving rooms); wrong at end: false attentive +"
        " missed partner; P(active) (windows) in agent-period windows with the partner there,"
        " background and self-feedback windows"
    )
    _print_summaries(result)
    _print_operating_curves(result)
    _print_information_bound(result)
    _print_belief_figures(result)


def _print_summaries(result: dict) -> None:
    """Per controller, one row per room: settling, errors and the active shares."""
    for label in result["controllers"]:
        print(f"\n{label}")
        print(
            f"  {'room':<24} {'settled':>8} {'seconds to settle':>22} {'vocalizations':>18}"
            f" {'wrong at end':>13} {'ever att.':>9} {'voc/run':>7}  {'P(agent)':>12}"
            f" {'P(background)':>13} {'P(self)':>12}"
        )
        for room, s in result["summaries"][label].items():
            rates = s["p_active"]
            vocalizations = _median_ci(
                s["settled_vocalizations_median"], s["settled_vocalizations_ci"]
            )
            print(
                f"  {room:<24} {_percent(s['settled']):>8}"
                f" {_median_ci(s['settled_s_median'], s['settled_s_ci'], ' s'):>22}"
                f" {vocalizations:>18}"
                f" {_percent(s['wrong_at_end']):>13}"
                f" {_percent(s.get('ever_attentive', math.nan)):>9}"
                f" {s['vocalizations_per_run']:>7.1f}"
                f"  {_rate(rates['agent']):>12} {_rate(rates['background']):>13}"
                f" {_rate(rates['self']):>12}"
            )


def _print_operating_curves(result: dict) -> None:
    """Per controller, room and prior: time to settle against false alarms, per threshold."""
    config = result["config"]
    print(
        "\noperating curves: per upper posture threshold, median s to settle with a partner"
        " / share of empty-room runs that ever turned attentive"
    )
    thresholds = config["curve_thresholds"]
    header = "".join(f" {t:>13g}" for t in thresholds)
    for label in result["controllers"]:
        for background, per_prior in result["operating_curves"][label].items():
            for pi, points in per_prior.items():
                cells = "".join(
                    f" {number(p['settled_s_median']):>6}/{_percent(p['false_alarm']):>6}"
                    for p in points
                )
                print(f"  {label[:22]:<22} {background:<15} pi={float(pi):<5g}{cells}")
        print(f"  {'':<22} {'':<15} {'threshold':<8}{header}")


def _print_information_bound(result: dict) -> None:
    """Per room: what the bits allow at the measured rates (known rates), and what it needs."""
    config = result["config"]
    print(
        "\ninformation bound (known rates): per vocalization with the partner there,"
        " the sum over the agent windows (lags) of KL(Bern(P lag) || Bern(P background))"
        f" nats (P: pooled / background); vocalizations to P(S=1) ="
        f" {config['attentive_above']:g} from the prior {result['params_pi']:g} at least;"
        f" P(agent) the bound needs for {_TARGETS} vocalizations (the lags' profile kept)"
    )
    for label in result["controllers"]:
        for background, bound in result.get("information_bound", {}).get(label, {}).items():
            needed = " / ".join(
                "none" if p is None else f"{p:.2f}" for p in bound["p_agent_needed"].values()
            )
            print(
                f"  {label[:22]:<22} {background:<15} P {bound['p_agent']:.2f} /"
                f" {bound['p_background']:.2f}: {bound['nats_per_vocalization']:.3f} nats,"
                f" >= {number(bound['vocalizations_bound']).replace('never', 'inf')} vocalizations;"
                f" needs {needed}"
            )


def _print_belief_figures(result: dict) -> None:
    """Per room: the model's own belief on independent bits at the measured rates."""
    config = result["config"]
    print(
        "\nthe model's belief on independent bits at those rates (exact; at each lag's rate"
        " where measured): median vocalizations"
        f" to P(S=1) = {config['attentive_above']:g}; chance by {_TARGETS} vocalizations;"
        f" P(agent) it needs for a median of {_TARGETS} (the lags' profile kept)"
    )
    for label in result["controllers"]:
        for background, bound in result.get("information_bound", {}).get(label, {}).items():
            belief = bound.get("belief")
            if not belief:
                print(f"  {label[:22]:<22} {background:<15} not followed: too many background"
                      " windows per vocalization")  # fmt: skip
                continue
            chances = " / ".join(f"{p:.2f}" for p in belief["p_crossed_by"].values())
            needed = " / ".join(
                "none" if p is None else f"{p:.2f}" for p in belief["p_agent_needed"].values()
            )
            median = belief["median_vocalizations"]
            median_text = f"> {belief['followed']}" if median is None else median
            targets = " / ".join(belief["p_crossed_by"])
            lags = bound.get("p_agent_lags")
            lag_text = "" if not lags else "; lags " + " / ".join(f"{p:.2f}" for p in lags)
            print(
                f"  {label[:22]:<22} {background:<15} {belief['background_windows']} background"
                f" windows per vocalization: median {median_text};"
                f" by {targets}: {chances}; needs {needed}{lag_text}"
            )


def run_experiment_rooms(args: argparse.Namespace) -> int:
    """``experiment rooms``."""
    config = evaluation.RoomsConfig(
        params_name=args.params,
        backgrounds=args.rooms,
        partner_states=args.partner_states,
        controllers=args.controllers,
        binarizer=args.binarizer,
        runs=args.runs,
        seconds=args.seconds,
        seed=args.seed,
        memory=args.memory,
        check_in_every_s=args.check_in_every_s,
        check_in_above=args.check_in_above,
        attentive_above=args.attentive_above,
        bored_below=args.bored_below,
        curve_thresholds=args.curve_thresholds,
        curve_priors=args.curve_priors,
        jobs=args.jobs,
    )
    check_output_files(("--out", args.out, "result file"), ("--plot", args.plot, "figure"))
    refuse_writing_over_inputs((("--out", args.out), ("--plot", args.plot)),
                               (("--params", args.params),))  # fmt: skip
    started = time.perf_counter()
    result = evaluation.experiment_rooms(config, Path(args.cache_dir) if args.cache_dir else None)
    elapsed = time.perf_counter() - started
    runs = config.runs * len(result["rooms"]) * len(result["controllers"])
    result["seconds"] = elapsed
    result["runs_per_s"] = runs / elapsed
    text = json.dumps(result, indent=1, default=json_default)
    if args.out:
        with written_atomically(args.out, "--out") as stream:
            stream.write((text + "\n").encode("utf-8"))
    if args.plot:
        plots.plot_room_curves(result, args.plot)
    if args.json:
        print(text)
        return 0
    print_rooms(result)
    print(
        f"\n{runs} runs in {elapsed:.0f} s ({runs / elapsed:.2f} runs/s, {config.jobs} processes)"
    )
    for written in (args.out, args.plot):
        if written:
            print(f"wrote {written}")
    return 0


def add_experiment_rooms_arguments(sub: argparse.ArgumentParser) -> None:
    """The options of ``experiment rooms`` (defaults: :class:`RoomsConfig`)."""
    d = evaluation.RoomsConfig  # the class: its defaults; an instance builds a bit source (scipy)
    sub.add_argument("--params", default=d.params_name, help=f"parameter set ({d.params_name})")
    sub.add_argument(
        "--rooms",
        type=_names,
        default=d.backgrounds,
        help=f"room sounds, each run with the partner in each of --partner-states"
        f" (default {','.join(d.backgrounds)})",
    )
    sub.add_argument(
        "--partner-states",
        type=_names,
        default=d.partner_states,
        help=f"of {','.join(evaluation.PARTNER_STATE_NAMES)} (default all; the operating"
        " curves need absent and partner)",
    )
    sub.add_argument(
        "--controllers",
        type=_names,
        default=d.controllers,
        help=f"of {','.join(evaluation.CONTROLLER_NAMES)} (default all)",
    )
    sub.add_argument(
        "--binarizer",
        default=d.binarizer,
        help=f"{' | '.join(evaluation.BINARIZERS)} (default {d.binarizer}, as mic_node)",
    )
    for option, kind, default, text in (
        ("--runs", int, d.runs, "runs per room and controller"),
        ("--seconds", float, d.seconds, "room time per run, s"),
        ("--seed", seed, d.seed, "master seed"),
        ("--memory", int, d.memory, "belief memory, steps (belief_node memory_steps)"),
        ("--check-in-every-s", float, d.check_in_every_s, "the optimal table's check-ins, s;"
         " 0 = the table alone (controller_node check_in_every_s)"),
        ("--check-in-above", float, d.check_in_above, "P(S=1) above which they apply"
         " (controller_node check_in_above)"),
        ("--attentive-above", float, d.attentive_above, "posture_node's upper threshold"),
        ("--bored-below", float, d.bored_below, "posture_node's lower threshold"),
        ("--jobs", int, d.jobs, "processes"),
    ):
        sub.add_argument(option, type=kind, default=default, help=f"{text} (default {default})")
    sub.add_argument(
        "--curve-thresholds",
        type=_floats,
        default=d.curve_thresholds,
        help=f"upper posture thresholds of the operating curves (default"
        f" {','.join(map(str, d.curve_thresholds))})",
    )
    sub.add_argument(
        "--curve-priors",
        type=_floats,
        default=d.curve_priors,
        help=f"belief priors pi of the operating curves (default"
        f" {','.join(map(str, d.curve_priors))})",
    )
    sub.add_argument("--out", help="also write the result as JSON to this file")
    sub.add_argument("--plot", help="write the operating curves to this PNG")


def _refuse_overwriting_other_than_actions(path: Path) -> None:
    """Refuse to replace ``path``, the actions file implied by ``--out``, unless it is one.

    An existing file there is overwritten only if it starts with the actions file's
    header (an earlier ``room-wav``'s) or is empty: a file the user never named is not
    lost.
    """
    if not path.is_file() or path.stat().st_size == 0:
        return
    with path.open("rb") as existing:
        first_line = existing.readline(len(ACTIONS_HEADER) + 8).decode("utf-8", "replace")
    if first_line.lstrip("\ufeff").strip() != ACTIONS_HEADER:
        raise ValueError(
            f"{path} exists and is not an actions file: nothing is written; give --actions"
            " to name where the robot's vocalization times go"
        )


def _run_room_wav(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix.lower() != ".wav":
        raise ValueError(f"--out {out}: the file name must end in .wav")
    actions = args.actions if args.actions is not None else out.with_suffix(".csv")
    check_output_files(("--out", out, "wav file"), ("--actions", actions, "actions file"))
    refuse_writing_over_inputs(
        (("--out", out), ("--actions", actions)),
        (("--params", args.params), ("--binarizer", spec_file(args.binarizer)),
         ("--controller", spec_file(args.controller))),
    )  # fmt: skip
    if args.actions is None:
        _refuse_overwriting_other_than_actions(actions)
    samples, times, rate = evaluation.render_room(
        args.room, args.seconds, args.seed, args.controller, args.binarizer, args.params
    )
    write_wav_int16(out, samples, rate)
    write_actions_csv(actions, times)
    print(
        f"wrote {out} ({samples.size / rate:g} s at {rate} Hz, room {args.room}, seed {args.seed})"
        f" and {actions} ({len(times)} vocalizations, controller {args.controller},"
        f" binarizer {args.binarizer})"
    )
    return 0


def register_room_wav(subparsers: argparse._SubParsersAction) -> None:
    """``room-wav ROOM``: a room preset's sound and its actions file, for listening."""
    parser = subparsers.add_parser(
        "room-wav", help="write a simulated room's sound as a wav, with its actions file"
    )
    parser.add_argument(
        "room", choices=AUDIO_ROOM_NAMES, metavar="ROOM", help=" | ".join(AUDIO_ROOM_NAMES)
    )
    parser.add_argument("--seconds", type=float, default=60.0, help="room time, s (default 60)")
    parser.add_argument("--seed", type=seed, default=0, help="the room's seed (default 0)")
    parser.add_argument("--out", required=True, help="wav file to write (16-bit PCM)")
    parser.add_argument(
        "--actions",
        help="actions file to write (CSV, column time_s: when the robot's sound was"
        " commanded); default: the wav's name with .csv, replaced there only if it is an"
        " actions file",
    )
    parser.add_argument(
        "--controller",
        default="optimal",
        help=f"who decides: {' | '.join(evaluation.CONTROLLER_NAMES)} or a controller"
        " specification such as rule:9, fixed:6, policy:FILE (default optimal)",
    )
    d = evaluation.RoomsConfig  # the class: its defaults; an instance builds a bit source (scipy)
    parser.add_argument(
        "--binarizer",
        default=evaluation.LISTENING_BINARIZER,
        help=f"{' | '.join(evaluation.BINARIZERS)} (default {evaluation.LISTENING_BINARIZER},"
        " as mic_node)",
    )
    parser.add_argument("--params", default=d.params_name, help=f"parameter set ({d.params_name})")
    parser.set_defaults(run=_run_room_wav)


__all__ = [
    "add_experiment_rooms_arguments",
    "print_rooms",
    "register_room_wav",
    "run_experiment_rooms",
]

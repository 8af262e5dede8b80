"""Command-line tools for live audio: ``devices``, ``calibrate`` and ``measure-latency``.

Registered in :mod:`infomax_contingency.cli.main`; errors follow its rules (one line on stderr,
exit status 2). ``calibrate`` reports the threshold mic_node's default bit source
(``background``) sets itself in the room heard; with ``--out`` it fits a k-means threshold
for ``threshold_mode: file`` instead, and exits with status 1, writing nothing, when the
audio cannot separate sound from quiet (cluster means closer than
``--min-separation-db``), unless ``--force``.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from infomax_contingency.audio.bitsources import BIT_SOURCES, DEFAULT_BIT_SOURCE
from infomax_contingency.audio.bitsources.background import (
    BackgroundSettings,
    SilentRobotMeter,
)
from infomax_contingency.audio.bitsources.level import LevelSource
from infomax_contingency.audio.calibration import (
    WindowMeter,
    dc_offset_note,
    energies_from_wav,
    energy_histogram,
    record_energies,
)
from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError
from infomax_contingency.audio.devices import INPUT, OUTPUT, format_devices
from infomax_contingency.audio.latency import measure_latency, self_period_windows
from infomax_contingency.audio.threshold import (
    DEFAULT_MIN_SEPARATION_DB,
    THRESHOLD_MAX_DB,
    THRESHOLD_MIN_DB,
    UnseparatedError,
    check_threshold_db,
    kmeans_split,
    require_separation,
)
from infomax_contingency.audio.threshold_file import save_threshold
from infomax_contingency.core.model import ModelParams
from infomax_contingency.limits import check_output_file, refuse_writing_over_inputs

FULL_SCALE_SLACK_DB = 0.01
"""Windows louder than 0 dB by more than this hold samples outside [-1, 1] (a full-scale
square wave is 0 dB exactly; rounding may add a hair)."""
LEVEL_SOURCES = tuple(n for n, s in BIT_SOURCES.items() if issubclass(s, LevelSource))
"""Bit sources with a threshold: what ``calibrate --bit-source`` fits."""


def _print_log(level: str, message: str) -> None:
    if level != "info":
        print(f"{level}: {message}")


# --------------------------------------------------------------------------- devices


def _run_devices(args: argparse.Namespace) -> int:
    print("input devices (microphones):")
    print(format_devices(INPUT))
    print("output devices (loudspeakers):")
    print(format_devices(OUTPUT))
    print("Choose a device by its index or by a part of its name; empty = system default.")
    return 0


def register_devices(subparsers: argparse._SubParsersAction) -> None:
    """``devices``: list the audio devices PortAudio sees."""
    parser = subparsers.add_parser("devices", help="list the audio input and output devices")
    parser.set_defaults(run=_run_devices)


# --------------------------------------------------------------------------- calibrate


def _calibration_energies(
    args: argparse.Namespace, meter: WindowMeter | None = None
) -> tuple[np.ndarray, str, str]:
    """The calibration window energies (dB), from ``--wav`` or the live microphone.

    ``meter``: what gives each window its level instead of ``--bit-source``'s.

    Returns:
        ``(energies, source, what)``: the energies, the source written to the threshold
        file, and how to name it to the user.
    """
    if args.wav is not None:
        # read block by block: a 10-hour file costs the memory of a 10-second one
        energies = energies_from_wav(
            args.wav, args.window_s, args.channel, bit_source=args.bit_source, meter=meter
        )
        return energies, f"wav:{args.wav}", str(args.wav)
    seconds = 10.0 if args.seconds is None else args.seconds
    hear = ("the room as it is, the robot silent" if args.out is None
            else "the room quiet and with sound (speech, claps)")  # fmt: skip
    print(f"recording {seconds:g} s from the microphone: let it hear {hear} ...")
    recording = record_energies(
        args.device,
        seconds,
        args.window_s,
        channel=args.channel,
        log=_print_log,
        bit_source=args.bit_source,
        meter=meter,
    )
    if recording.lost_samples or recording.gaps:
        print(
            f"warning: {recording.lost_samples} samples lost and {recording.gaps} gap(s)"
            " during the recording"
        )
    what = f"{recording.device} ({recording.device_rate} Hz)"
    return recording.energies_db, f"device:{recording.device}", what


def _full_scale_problem(energies: np.ndarray, what: str) -> str:
    """What is wrong with windows louder than full scale (0 dB); empty if there are none."""
    loud = int(np.count_nonzero(energies > THRESHOLD_MAX_DB + FULL_SCALE_SLACK_DB))
    if not loud:
        return ""
    return (f"{loud} of {energies.size} windows of {what} are louder than full scale (up to"
            f" {float(energies.max()):.1f} dB): its samples lie outside [-1, 1]; scale the"
            " audio to [-1, 1] (float samples stored unscaled?)")


def _check_full_scale(energies: np.ndarray, threshold_db: float, what: str) -> None:
    """Refuse a threshold outside the range mic_node takes; warn of windows above full scale.

    A window louder than 0 dB holds samples outside [-1, 1]: float audio stored unscaled
    (e.g. int16 values written as floats) gives thresholds near +86 dB, which would make
    every bit 0.
    """
    problem = _full_scale_problem(energies, what)
    if not problem:
        check_threshold_db(threshold_db, f"calibration on {what}")
        return
    if not THRESHOLD_MIN_DB <= threshold_db <= THRESHOLD_MAX_DB:
        raise AudioError(f"{problem}; the threshold {threshold_db:.2f} dB is outside"
                         f" {THRESHOLD_MIN_DB:g} .. {THRESHOLD_MAX_DB:g} dB, nothing written")
    print(f"warning: {problem}")


def _check_calibrate_arguments(args: argparse.Namespace) -> None:
    """ValueError for arguments that do not go together; sets the default ``--bit-source``."""
    if args.wav is not None and (args.device is not None or args.seconds is not None):
        raise ValueError("calibrate from --wav FILE or from --device/--seconds, not both")
    k_means_only = [option for option, given in (
        ("--force", args.force),
        ("--min-separation-db", args.min_separation_db is not None),
        (f"--bit-source {args.bit_source}", args.bit_source in LEVEL_SOURCES),
    ) if given]  # fmt: skip
    if k_means_only and args.out is None:
        raise ValueError(f"{k_means_only[0]} is for a k-means threshold written to a file: give"
                         " --out FILE (without it: the default bit source's report)")
    if args.bit_source is None:
        args.bit_source = DEFAULT_BIT_SOURCE if args.out is None else "energy"
    if args.min_separation_db is None:
        args.min_separation_db = DEFAULT_MIN_SEPARATION_DB
    if args.bit_source == DEFAULT_BIT_SOURCE and args.out is not None:
        raise ValueError(f"--bit-source {DEFAULT_BIT_SOURCE} needs no threshold file: mic_node's"
                         " default sets its threshold itself while it runs; --out writes one"
                         " for --bit-source energy or speech_band")  # fmt: skip


def _run_calibrate(args: argparse.Namespace) -> int:
    """Report the room as the default bit source hears it, or fit and save a threshold.

    With ``--out``: a k-means threshold, shown and saved; exit status 1 if its clusters
    do not separate.
    """
    _check_calibrate_arguments(args)
    params = ModelParams.load(args.params)
    args.window_s = params.dt  # one window is one step of the model
    if args.bit_source == DEFAULT_BIT_SOURCE:
        return _report_background(args, params)
    check_output_file(args.out, "--out", "threshold file")  # before the audio is taken
    refuse_writing_over_inputs((("--out", args.out),),
                               (("--wav", args.wav), ("--params", args.params)))  # fmt: skip
    energies, source, what = _calibration_energies(args)
    if energies.size < 2:
        raise AudioError(
            f"{what} holds {energies.size} window(s) of {args.window_s} s; calibration needs"
            " at least 2"
        )
    try:
        fit = kmeans_split(energies)
    except AudioError as error:  # no boundary: say first that the audio is out of scale
        problem = _full_scale_problem(energies, what)
        raise AudioError(f"{problem}; {error}" if problem else str(error)) from None
    _check_full_scale(energies, fit.threshold_db, what)
    print(f"calibrated on {energies.size} windows of {args.window_s:g} s from {what}")
    print(
        f"threshold: {fit.threshold_db:.2f} dB (quiet: {fit.n_low} windows, mean"
        f" {fit.low_mean_db:.1f} dB; sound: {fit.n_high} windows, mean {fit.high_mean_db:.1f} dB)"
    )
    print(energy_histogram(energies, fit.threshold_db, bin_db=args.bin_db))
    try:
        require_separation(fit, args.min_separation_db)
    except UnseparatedError as exc:
        if args.wav is not None:
            exc = f"{exc}{dc_offset_note(Path(args.wav), args.window_s, args.channel)}"
        if not args.force:
            print(
                f"infomax-contingency calibrate: error: {exc}; {args.out} not written"
                " (calibrate again on audio with both quiet and sound, or use --force)",
                file=sys.stderr,
            )
            return 1
        print(f"warning: {exc}; writing it anyway (--force)")
    save_threshold(
        args.out,
        fit,
        window_s=args.window_s,
        rate=PROCESSING_RATE_HZ,
        source=source,
        level=args.bit_source,
    )
    print(f"wrote {args.out}")
    return 0


def _report_background(args: argparse.Namespace, params: ModelParams) -> int:
    """What the default bit source makes of the room heard with the robot silent.

    Exit status 1 when it would give no bit in a recording long enough for one.
    """
    settings = BackgroundSettings()
    meter = SilentRobotMeter(params, PROCESSING_RATE_HZ, settings)
    levels, _, what = _calibration_energies(args, meter)
    source = meter.source
    print(f"heard {meter.windows} windows of {args.window_s:g} s from {what}"
          f" ({source.band_name} levels)")  # fmt: skip
    for problem in source.problems():
        print(f"warning: {problem}")
    before = f"mic_node's default bit source ({DEFAULT_BIT_SOURCE}), the robot silent"
    if meter.windows <= meter.windows_without_bit:
        print(f"{before}, would give no bit yet: its first bit comes after"
              f" {meter.windows_without_bit} windows; record longer to see its threshold")
        return 0
    if not meter.bits or source.threshold_db is None:
        print(f"{before}, would give no bit here: {source.problem or 'no threshold'}")
        return 1
    active, decided = sum(meter.bits), len(meter.bits)
    print(f"{before}: threshold {source.threshold_db:.2f} dB at the end"
          f" ({source.threshold_origin()}); {active} of {decided} windows after its warm-up"
          f" active ({active / decided:.3f}, set to {settings.false_alarm:g})")  # fmt: skip
    print(energy_histogram(levels, source.threshold_db, bin_db=args.bin_db))
    print("nothing to write: mic_node sets this threshold itself, and follows the room")
    return 0


def _non_negative(text: str) -> float:
    """An argparse type: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not (value >= 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def _positive(kind: type) -> Callable[[str], float]:
    """An argparse type: a finite number > 0 of ``kind`` (int or float)."""

    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
        if not (value > 0 and math.isfinite(value)):
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
        return value

    return parse


def register_calibrate(subparsers: argparse._SubParsersAction) -> None:
    """``calibrate``: fit the sound threshold on a recording or on the live microphone."""
    parser = subparsers.add_parser(
        "calibrate",
        help="the room's levels and threshold, from a wav file or the live microphone",
        description="Report the threshold mic_node's default bit source (background) sets"
        " itself in the room, with a histogram of the levels; or, with --out, fit a"
        " sound/quiet threshold by two-cluster k-means of window energies and write it for"
        " mic_node's threshold_mode file.",
    )
    parser.add_argument("--wav", type=Path, help="calibrate on this WAV file")
    parser.add_argument(
        "--device",
        help="microphone: index or part of its name (default: system default)",
    )
    parser.add_argument(
        "--seconds", type=_positive(float), help="seconds to record live (default: 10)"
    )
    parser.add_argument(
        "--params",
        default="robot",
        metavar="NAME|FILE",
        help="model parameters whose dt is the window length (default: robot, 0.5 s)",
    )
    parser.add_argument(
        "--channel", type=int, help="use this 0-based channel (default: mix all channels)"
    )
    parser.add_argument(
        "--bin-db", type=_positive(float), default=3.0, help="histogram bin width, dB"
    )
    parser.add_argument(
        "--min-separation-db",
        type=_non_negative,
        default=None,
        help="least distance between the quiet and sound cluster means, dB (default:"
        f" {DEFAULT_MIN_SEPARATION_DB:g}); closer clusters cannot separate sound from quiet",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="write the threshold even if the clusters lie closer than --min-separation-db"
        " (otherwise the command exits with status 1 and writes nothing)",
    )
    parser.add_argument(
        "--bit-source",
        choices=(DEFAULT_BIT_SOURCE, *LEVEL_SOURCES),
        help=f"{DEFAULT_BIT_SOURCE} (the default without --out): report the threshold"
        " mic_node's default bit source sets itself in this room; energy (the default with"
        " --out: the window energy) or speech_band (the 300-3400 Hz band energy): fit a"
        " k-means threshold for that bit_source",
    )
    parser.add_argument(
        "--out",
        type=Path,
        help="write the k-means threshold to this file (YAML) for mic_node's threshold_mode"
        " file; not needed by the default bit source",
    )
    parser.set_defaults(run=_run_calibrate)


# --------------------------------------------------------------------------- measure-latency


def _run_measure_latency(args: argparse.Namespace) -> int:
    params = ModelParams.load(args.params)
    window_s = params.dt
    if not (args.tail_s >= 0 and math.isfinite(args.tail_s)):
        raise ValueError(f"--tail-s must be >= 0 seconds, got {args.tail_s}")
    report = measure_latency(
        args.input_device,
        args.output_device,
        repeats=args.repeats,
        interval_s=args.interval_s,
        volume=args.volume,
        sound=args.sound,
        log=_print_log,
    )
    print(f"microphone: {report.input_device}; loudspeaker: {report.output_device}")
    for failure in report.failures:
        print(failure)
    if not report.trials:
        raise AudioError(
            "the sound was not heard in any repeat: check the devices, raise --volume or move"
            " the microphone closer to the loudspeaker"
        )
    for i, trial in enumerate(report.trials, 1):
        print(
            f"heard {1000 * trial.delay_s:.1f} ms after the play command (output"
            f" {1000 * trial.output_s:.1f} ms; match {trial.score:.2f}) [{i}]"
        )
    delays = report.delays_s
    print(
        f"self-feedback delay: mean {1000 * delays.mean():.1f} ms, min {1000 * delays.min():.1f}"
        f" ms, max {1000 * delays.max():.1f} ms over {delays.size} repeat(s)"
    )
    heard_s = report.sound_s + args.tail_s
    ts1, ts2 = self_period_windows(float(delays.min()), float(delays.max()), heard_s, window_s)
    print(
        f"the sound ({1000 * report.sound_s:.0f} ms + {1000 * args.tail_s:.0f} ms tail) is heard"
        f" in windows z = {ts1}..{ts2} after a vocalization (windows of {window_s:g} s)"
    )
    verdict = (
        "consistent"
        if (ts1, ts2) == (params.ts1, params.ts2) and ts2 < params.ta1
        else "different: set ts1/ts2 in the parameter file"
        if ts2 < params.ta1
        else f"NOT usable: ts2 = {ts2} reaches the agent period (ta1 = {params.ta1}); lower"
        " the latency or use longer windows"
    )
    print(
        f"implied self period: ts1 = {ts1}, ts2 = {ts2} (parameters {args.params}: ts1 ="
        f" {params.ts1}, ts2 = {params.ts2}, ta1 = {params.ta1}: {verdict})"
    )
    return 0


def register_measure_latency(subparsers: argparse._SubParsersAction) -> None:
    """``measure-latency``: play the sound, hear it, and derive the self period."""
    parser = subparsers.add_parser(
        "measure-latency",
        help="measure the self-feedback delay (speaker -> microphone) and the self period",
        description="Play the robot's sound and record it on the microphone, REPEATS times; "
        "report the delay from the play command to the sound's onset at the microphone, and "
        "the self period (ts1, ts2): the windows z = 0, 1, ... after a vocalization that the "
        "sound overlaps, window z covering [z dt, (z+1) dt) after the command.",
    )
    parser.add_argument("--input-device", help="microphone: index or part of its name")
    parser.add_argument("--output-device", help="loudspeaker: index or part of its name")
    parser.add_argument("--repeats", type=_positive(int), default=5, help="plays (default: 5)")
    parser.add_argument(
        "--interval-s",
        type=_positive(float),
        default=1.0,
        help="recording after each play, s (default: 1.0)",
    )
    parser.add_argument(
        "--volume", type=float, default=1.0, help="gain of the sound, 0..1 (default: 1)"
    )
    parser.add_argument("--sound", type=Path, help="WAV file to play instead of the chirp")
    parser.add_argument(
        "--params",
        default="robot",
        metavar="NAME|FILE",
        help="model parameters to compare with (default: robot)",
    )
    parser.add_argument(
        "--tail-s",
        type=float,
        default=0.1,
        help="room reverberation added to the sound's length, s (default: 0.1)",
    )
    parser.set_defaults(run=_run_measure_latency)

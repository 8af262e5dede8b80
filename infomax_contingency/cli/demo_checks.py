"""What ``infomax-contingency demo`` refuses or reports: bad arguments, a failed run.

Arguments it cannot run, a recording it lost, a node that failed, a run without a step.
The checks run before any node starts (one line, status 2) and, for ``--record``, after
the run (the recorder keeps the graph running when it cannot write, so the demo looks at
what it left); a failed node and a run without a step are told from the nodes' logs.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import tempfile
from pathlib import Path
from typing import Any

from infomax_contingency.audio.bitsources.base import setting_specs
from infomax_contingency.audio.bitsources.level import ThresholdSettings
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.wav import check_samples
from infomax_contingency.core.model import MAX_MEMORY_STEPS
from infomax_contingency.sim.room_config import FakeRoomConfig, partner_times


def finite_number(text: str) -> float:
    """An argparse type: a finite number (``nan`` and ``inf`` mean nothing here)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


MAX_STEPS = MAX_SEED = 2**31 - 1
"""Largest ``--steps`` and ``--seed``: the room's ``max_windows`` and ``seed`` parameters."""

MAX_LEAVE_AT_S = 1e9
"""Largest ``--leave-at``: the room's ``partner_leave_s`` parameter."""

def check_calibration_s(seconds: float) -> None:
    """Refuse a ``--calibration-s`` (s) that mic_node's ``calibration_s`` would refuse.

    The range is the setting's own declaration (:class:`ThresholdSettings`), so the
    command and the node refuse the same values, the first before any node starts.
    """
    [spec] = [s for s in setting_specs(ThresholdSettings) if s.name == "calibration_s"]
    if not (math.isfinite(seconds) and spec.low <= seconds <= spec.high):
        raise ValueError(f"--calibration-s must be in [{spec.low:g}, {spec.high:g}] seconds,"
                         f" got {seconds:g}")  # fmt: skip

DEMO_LEAVE_S = 60.0
"""Room time the responsive room's partner leaves in the demo by default, s."""


def demo_partner_times(args: argparse.Namespace) -> dict[str, float]:
    """fake_audio_node's ``partner_arrive_s`` and ``partner_leave_s`` for the demo's room.

    The room's own (``office+arriving``: 20 s; ``office``: nobody), over
    config/fake_room.yaml's partner of the first 60 s; ``--leave-at`` moves the departure;
    the responsive room's partner leaves at :data:`DEMO_LEAVE_S` unless told otherwise.
    ValueError (one line) for a departure out of range, or one the room refuses (before
    the partner arrives).
    """
    leave_at = args.leave_at
    if leave_at is not None and not (math.isfinite(leave_at) and leave_at <= MAX_LEAVE_AT_S):
        raise ValueError(
            f"--leave-at must be at most {MAX_LEAVE_AT_S:g} s (negative: the partner stays),"
            f" got {leave_at}"
        )
    if leave_at is None and args.room == "responsive":
        leave_at = DEMO_LEAVE_S
    times = partner_times(args.room, leave_at)
    if args.leave_at is not None and times.get("partner_arrive_s", 0.0) < 0:
        raise ValueError(f"--leave-at {args.leave_at:g}: room {args.room} has no partner")
    try:
        FakeRoomConfig.preset(args.room, **times)
    except ValueError as error:
        given = "" if args.leave_at is None else f"--leave-at {args.leave_at:g} in "
        raise ValueError(f"{given}room {args.room}: {error}") from None
    return times


DEMO_CALIBRATION_S = 10.0
"""s of a wav file a k-means threshold is calibrated on (``--calibration-s``)."""


def _check_options_used(args: argparse.Namespace) -> None:
    """Refuse an option the run would not use (ValueError: one line), not ignore it.

    An option counts when it is given (``args.given``,
    :class:`~infomax_contingency.cli.formatting.GivenOption`), its default value typed out
    too.
    """
    if args.wav and args.given & {"room", "seed", "leave_at"}:
        raise ValueError("--room, --seed and --leave-at set the simulated room: not with --wav")
    k_means = args.wav and args.bit_source in ("energy", "speech_band")
    if "calibration_s" in args.given and not k_means:
        raise ValueError("--calibration-s is the length of a k-means calibration: it needs --wav"
                         " and --bit-source energy or speech_band")  # fmt: skip
    if args.no_record_audio and args.record is None:
        raise ValueError("--no-record-audio leaves the audio out of a recording: give --record")


def check_arguments(args: argparse.Namespace) -> None:
    """Refuse what the graph cannot run, before a node starts (ValueError: one line)."""
    if not 1 <= args.steps <= MAX_STEPS:
        raise ValueError(f"--steps must be in [1, {MAX_STEPS}], got {args.steps}")
    if not 0 <= args.seed <= MAX_SEED:
        raise ValueError(f"--seed must be in [0, {MAX_SEED}], got {args.seed}")
    demo_partner_times(args)
    if not 0 <= args.memory <= MAX_MEMORY_STEPS:
        raise ValueError(f"--memory must be in [0, {MAX_MEMORY_STEPS}] (belief_node's"
                         f" memory_steps; 0 = all), got {args.memory}")
    if args.wav and not Path(args.wav).is_file():
        wav = Path(args.wav)
        what = ("a directory, not a wav file" if wav.is_dir() else "no such file"
                if not wav.exists() else "not a regular file (a device or a FIFO)")
        raise ValueError(f"--wav {args.wav}: {what}")
    if args.wav:
        try:  # its header and samples: a file mic_node would refuse stops here
            check_samples(args.wav)
        except AudioError as error:
            raise ValueError(f"--wav {args.wav}: {error}") from None
    check_calibration_s(args.calibration_s)
    if args.record is not None:  # "" too: it recorded nothing, without a word
        check_record_directory(args.record)
    _check_options_used(args)


def check_record_directory(directory: str | Path, option: str = "--record") -> None:
    """Refuse a bag directory (``option``) that exists or cannot be created and written.

    Tried for real (the directory and a file in it are made, then removed): a path the
    permissions allow on paper may still refuse (``/proc``, a read-only mount, a full disk).
    An empty path and a symbolic link (even a dangling one) are refused too.
    """
    if not str(directory):
        raise ValueError(f"{option}: the path is empty; name a new directory")
    directory = Path(directory)
    if directory.exists() or directory.is_symlink():
        raise ValueError(f"{option} {directory}: exists already; name a new directory")
    try:
        directory.mkdir()
    except OSError as error:
        raise ValueError(f"{option} {directory}: cannot create it: {error.strerror}") from None
    try:
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as error:
        raise ValueError(f"{option} {directory}: cannot write in it: {error.strerror}") from None
    finally:
        with contextlib.suppress(OSError):
            directory.rmdir()


def recording_failure(directory: Path, recorder_log: str) -> str:
    """Why the stopped recorder left no whole bag in ``directory``; "" when it did.

    ``recorder_log``: what recorder_node printed (its ERROR line names the reason).

    The recorder keeps the graph running when it cannot write (it logs an ERROR and
    says so in its diagnostics), and writes ``metadata.yaml`` on a clean stop only after
    writing everything: without it the bag is missing or cut short.
    """
    if (directory / "metadata.yaml").is_file():
        return ""
    errors = log_messages(recorder_log, "ERROR")
    reason = errors[0] if errors else "it wrote no metadata.yaml"
    return f"--record {directory}: the session was not recorded whole: {reason}"


def log_messages(log: str, *levels: str) -> list[str]:
    """The messages of a node's log lines at ``levels`` (``WARN``, ``ERROR``), in order."""
    return [line.split("]: ", 1)[-1].strip() for line in log.splitlines()
            if any(f"[{level}]" in line for level in levels)]  # fmt: skip


def node_failure(processes: Any) -> str | None:
    """One line for the first node that exited on its own: its status and error line."""
    for name, status in processes.dead().items():
        log = processes.log(name)
        lines = [line.strip() for line in log.splitlines() if line.strip()]
        errors = log_messages(log, "ERROR")
        if errors:
            return f"{name} exited with status {status}: {errors[-1]}"
        last = ([line for line in lines if "Error" in line or "error:" in line]
                or lines or ["(no output)"])[-1]  # fmt: skip
        message = last.split("]: ", 1)[-1] if "]: " in last else last
        return f"{name} exited with status {status}: {message}"
    return None


def no_step(source: str, windows: int, mic_log: str) -> str:
    """Why a run gave no step, in one line: mic_node's last warning, if it gave one."""
    warnings = log_messages(mic_log, "WARN", "ERROR")
    why = (f"mic_node said: {warnings[-1]}" if warnings
           else "the bit source hears about 6 s of the room's background first")
    return f"{source} gave no step: its {windows} windows all went by without a bit ({why})"

"""Cost checks before work, and a Ctrl-C that ends every command in one line.

Every command handed a size (a horizon, a number of steps or lags, a WAV file, a YAML
file) refuses what it cannot do, in one line and at once, instead of a MemoryError, an OOM
kill or an hour of work; the memory it compares with respects ``ulimit -v`` and the
cgroup's limit, not only the machine's available memory.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import resource
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.energy import iter_wav_windows
from infomax_contingency.audio.threshold import kmeans_split
from infomax_contingency.audio.threshold_file import load_threshold, save_threshold
from infomax_contingency.audio.wav import open_wav_info, write_wav_int16
from infomax_contingency.audio.windows import WavReplay
from infomax_contingency.cli import main as cli_main
from infomax_contingency.cli.main import main
from infomax_contingency.core.model import ModelParams, ParameterError
from infomax_contingency.limits import (
    cgroup_headroom,
    format_bytes,
    load_yaml,
    memory_budget,
)
from infomax_contingency.sim.rooms import ROOM_SOUNDS

SESSION = Path(__file__).parent / "data" / "session_demo"


def _one_line_error(capsys, *argv: str) -> str:
    """Run the command line; it must end with status 2 and one line on stderr."""
    assert main(list(argv)) == 2
    error = capsys.readouterr().err
    assert len(error.strip().splitlines()) == 1, error
    return error


def _wav_with_rate(path: Path, rate: int, frames: int) -> Path:
    """A 16-bit mono WAV of noise whose header says ``rate`` Hz."""
    data = (np.random.default_rng(0).standard_normal(frames) * 3000).astype("<i2").tobytes()
    header = (b"RIFF" + struct.pack("<I", 36 + len(data)) + b"WAVEfmt "
              + struct.pack("<IHHIIHH", 16, 1, 1, rate, 2 * rate, 2, 16)
              + b"data" + struct.pack("<I", len(data)))
    path.write_bytes(header + data)
    return path


# ------------------------------------------------------------------------ audio files


def test_a_wav_whose_header_says_1_hz_is_refused_before_a_sample_is_read(tmp_path, capsys):
    # 640 KB of samples at 1 Hz: 91 hours of audio, 5 * 10^9 samples once at 16 kHz
    wav = _wav_with_rate(tmp_path / "one_hz.wav", 1, 327_680)
    with pytest.raises(AudioError, match="91 hours of audio .at most 24 hours"):
        open_wav_info(wav)
    error = _one_line_error(capsys, "calibrate", "--wav", str(wav), "--out",
                            str(tmp_path / "t.yaml"))
    assert "327,680 frames at 1 Hz" in error
    assert not (tmp_path / "t.yaml").exists()
    # mic_node's source wav (demo --wav) and replay of a wav file read it the same way
    with pytest.raises(AudioError, match="91 hours of audio"):
        WavReplay(wav, 0.5)
    error = _one_line_error(capsys, "replay", str(wav), "--actions", "rule")
    assert "91 hours of audio" in error


def test_a_low_rate_wav_is_resampled_a_few_frames_at_a_time(tmp_path):
    # 4 Hz (within the limit): a block of 65536 frames would be 2.6 * 10^8 samples at 16 kHz
    wav = _wav_with_rate(tmp_path / "four_hz.wav", 4, 64)
    blocks = iter_wav_windows(wav, 0.5, rate=16_000)
    first = next(blocks)
    assert first.size <= 2 * 65_536
    assert sum(b.shape[0] for b in blocks) + first.shape[0] == 64 // 4 * 2


# ------------------------------------------------------------------------ memory


def test_solve_of_an_astronomical_horizon_is_one_line(capsys):
    error = _one_line_error(capsys, "solve", "--mode", "episodic", "--horizon", str(10**18),
                            "--out", "never.npz")
    assert "refusing to solve horizon" in error and "PiB" in error
    error = _one_line_error(capsys, "solve", "--mode", "receding", "--horizon", str(10**400),
                            "--memory", "5", "--out", "never.npz")
    assert "e+15" in error  # 10^1585 PiB, formatted from the integer


def _limit_address_space(limit_bytes: int):
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))
    return apply


def test_solve_respects_ulimit_v(tmp_path):
    # 3 GiB expected; the machine may well have that free, the process may not
    result = subprocess.run(
        [sys.executable, "-m", "infomax_contingency.cli", "solve", "--mode", "episodic",
         "--horizon", "140", "--out", str(tmp_path / "t.npz")],
        capture_output=True, text=True, timeout=120,
        preexec_fn=_limit_address_space(1536 * 2**20),
    )
    assert result.returncode == 2, result.stderr
    assert "more memory than" in result.stderr and "(ulimit -v 1572864" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "t.npz").exists()


def test_the_budget_is_the_tightest_of_meminfo_ulimit_and_cgroups(tmp_path, monkeypatch):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal: 4000000 kB\nMemAvailable: 3000000 kB\n")
    status = tmp_path / "status"
    status.write_text("VmSize:   100000 kB\n")
    # cgroup v2: the group's limit, and a tighter one above it
    root = tmp_path / "cgroup"
    (root / "a" / "b").mkdir(parents=True)
    (root / "a" / "b" / "memory.max").write_text("max\n")
    (root / "a" / "b" / "memory.current").write_text("1000\n")
    (root / "a" / "memory.max").write_text(f"{2 * 2**30}\n")
    (root / "a" / "memory.current").write_text(f"{2**30}\n")
    self_v2 = tmp_path / "self_v2"
    self_v2.write_text("0::/a/b\n")
    assert cgroup_headroom(root, self_v2) == 2**30
    budget = memory_budget(meminfo, status, root, self_v2)
    assert budget == type(budget)(2**30, "cgroup memory limit")
    # cgroup v1 (this machine's kind): memory.limit_in_bytes, 2^63 - 4096 for none
    (root / "memory").mkdir()
    (root / "memory" / "memory.limit_in_bytes").write_text("9223372036854771712\n")
    (root / "memory" / "memory.usage_in_bytes").write_text("5\n")
    self_v1 = tmp_path / "self_v1"
    self_v1.write_text("4:memory:/\n0::/\n")
    assert cgroup_headroom(root, self_v1) is None
    (root / "memory" / "memory.limit_in_bytes").write_text(f"{2**30 + 5}\n")
    assert cgroup_headroom(root, self_v1) == 2**30
    # ulimit -v: the limit less what the process maps already
    monkeypatch.setattr(resource, "getrlimit", lambda _: (500_000 * 1024, resource.RLIM_INFINITY))
    budget = memory_budget(meminfo, status, root, self_v1)
    assert budget.bytes == 400_000 * 1024 and budget.source.startswith("ulimit -v")
    assert format_bytes(10**400).endswith("PiB")


def test_learn_plot_and_analyze_refuse_sizes_that_cannot_fit(capsys):
    error = _one_line_error(capsys, "learn", "--horizon", "10000")
    assert "refusing to learn with horizon 10000" in error
    error = _one_line_error(capsys, "plot", "--steps", str(10**8), "--out", "never.png")
    assert "refusing to plot 100,000,000 steps" in error and "--steps" in error
    assert not Path("never.png").exists()


def test_analyze_lags_stop_at_the_longest_session_and_a_negative_background_is_refused(
    capsys
):
    status = main(["analyze", str(SESSION), "--max-lag-s", "1e12"])
    out = capsys.readouterr().out
    assert status in (0, 1)
    assert "lags shown up to 60 s, the longest session" in out
    assert len([line for line in out.splitlines() if line[:3].strip().isdigit()]) == 120
    for value in ("-1", "0", "nan"):
        error = _one_line_error(capsys, "analyze", str(SESSION), "--background-from-s", value)
        assert "--background-from-s must be a number of seconds > 0" in error
    error = _one_line_error(capsys, "analyze", str(SESSION), "--max-lag-s", "inf")
    assert "--max-lag-s" in error


# ------------------------------------------------------------------------ YAML


def test_a_deeply_nested_model_file_is_refused_in_one_line(tmp_path, capsys):
    huge = tmp_path / "huge.yaml"
    huge.write_text("dt: " + "[" * 100_000 + "]" * 100_000 + "\n")
    started = time.monotonic()
    with pytest.raises(ParameterError, match="is refused: it holds 200,005 bytes"):
        ModelParams.load(huge)
    deep = tmp_path / "deep.yaml"
    deep.write_text("dt: " + "[" * 30_000 + "]" * 30_000 + "\n")
    with pytest.raises(ParameterError, match="nested 30000 deep .at most 8"):
        ModelParams.load(deep)
    for command in (["solve", "--mode", "episodic", "--horizon", "5", "--out", "x.npz"],
                    ["simulate"]):
        error = _one_line_error(capsys, *command, "--params", str(deep))
        assert "is refused: it is nested" in error
    # block nesting, which the parser takes in linear time
    block = tmp_path / "block.yaml"
    block.write_text("- " * 10_000 + "1\n")
    with pytest.raises(ParameterError, match="nested 10000 deep"):
        ModelParams.load(block)
    assert time.monotonic() - started < 30  # the parser alone took minutes


def test_yaml_files_are_bounded_in_size(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * 100_000 + "\ndt: 0.5\n")
    with pytest.raises(ValueError, match="is refused: it holds 100,011 bytes"):
        load_yaml(big, "parameter file")
    fine = tmp_path / "fine.yaml"
    fine.write_text("model:\n  dt: 0.5\n  list: [1, [2, 3]]\n")
    assert load_yaml(fine, "parameter file") == {"model": {"dt": 0.5, "list": [1, [2, 3]]}}


# ------------------------------------------------------------------------ thresholds


def test_a_threshold_file_outside_the_parameters_range_is_refused(tmp_path):
    loud = tmp_path / "loud.yaml"
    save_threshold(loud, kmeans_split(np.array([60.0, 62.0, 110.0, 112.0])), window_s=0.5,
                   rate=16_000, source="wav:x.wav")
    with pytest.raises(AudioError, match="threshold_db 86 dB is not allowed: -150 .. 0 dB"):
        load_threshold(loud)


def test_calibrate_says_what_is_wrong_with_unscaled_float_audio(tmp_path, capsys):
    rate = 16_000
    t = np.arange(4 * rate) / rate
    quiet_then_loud = np.where(t < 2, 0.001, 0.5) * np.sin(2 * np.pi * 440 * t)
    scaled = tmp_path / "scaled.wav"
    write_wav_int16(scaled, quiet_then_loud, rate)
    unscaled = tmp_path / "unscaled.wav"  # int16 values written as float32 samples
    data = (quiet_then_loud * 32767).astype("<f4").tobytes()
    unscaled.write_bytes(b"RIFF" + struct.pack("<I", 36 + len(data)) + b"WAVEfmt "
                         + struct.pack("<IHHIIHH", 16, 3, 1, rate, 4 * rate, 4, 32)
                         + b"data" + struct.pack("<I", len(data)) + data)
    out = tmp_path / "t.yaml"
    error = _one_line_error(capsys, "calibrate", "--wav", str(unscaled), "--out", str(out))
    assert "louder than full scale" in error and "outside [-1, 1]" in error
    assert "nothing written" in error and not out.exists()
    assert main(["calibrate", "--wav", str(scaled), "--out", str(out)]) == 0
    assert -150 <= load_threshold(out) <= 0


# ------------------------------------------------------------------------ Ctrl-C


def _command(*argv: str, preload: str = "") -> subprocess.Popen:
    """``infomax-contingency ARGV`` in a process group of its own.

    ``preload``: a module the interpreter imports before the command runs (see
    :data:`LAZY_IMPORT_OF_CALIBRATE`).
    """
    run = ["-m", "infomax_contingency.cli"]
    if preload:
        run = ["-c", f"import {preload}, runpy; runpy.run_module('infomax_contingency.cli',"
                     " run_name='__main__', alter_sys=True)"]  # fmt: skip
    return subprocess.Popen([sys.executable, *run, *argv],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


LAZY_IMPORT_OF_CALIBRATE = "scipy.signal"
"""What calibrate imports after it opened the wav (its resampler's lazy import, 0.6 s of
CPU), and nothing else: preloaded, the open wav means the command is at work. A Ctrl-C
that lands during an import can be lost for good: CPython raised the KeyboardInterrupt in
a weakref callback of its module locks, printed "Exception ignored in: <function
_get_module_lock.<locals>.cb>" and went on with the 21 hours of audio (once in three runs
of the suite under load); the test then waited out its 60 s."""


INTERRUPTED = (130, -signal.SIGINT)
"""What a shell reports as status 130: the command's exit(130), or its end by SIGINT.

Python ends itself with SIGINT, after main() returned 130, when the Ctrl-C landed while a
C extension module ran Python code through ``PyRun_String`` (scipy's lazy import, in
calibrate): CPython's flag for an unhandled KeyboardInterrupt stays set. The line on
stderr is the same.
"""


def _interrupt(process: subprocess.Popen, ready) -> tuple[int, str]:
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) once ``ready()``."""
    deadline = time.monotonic() + 120
    try:
        while not ready():
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "the command never got to work"
            time.sleep(0.05)  # polls the child's state; the deadline bounds it
        os.killpg(process.pid, signal.SIGINT)
        _, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    return process.returncode, err


def _has_open(pid: int, path: Path) -> bool:
    try:
        return any(Path(f"/proc/{pid}/fd/{fd}").resolve() == path.resolve()
                   for fd in os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return False


def test_ctrl_c_of_simulate_exits_130_with_one_line() -> None:
    process = _command("simulate", "--steps", str(10**9))
    assert process.stdout.readline().startswith("    t")  # the header: simulating now
    status, err = _interrupt(process, lambda: True)
    assert status in INTERRUPTED, err
    assert err.strip() == "infomax-contingency simulate: interrupted"


def test_ctrl_c_of_calibrate_exits_130_with_one_line(tmp_path) -> None:
    wav = _wav_with_rate(tmp_path / "long.wav", 4, 300_000)  # 21 hours: minutes of work
    process = _command("calibrate", "--wav", str(wav), "--out", str(tmp_path / "t.yaml"),
                       preload=LAZY_IMPORT_OF_CALIBRATE)  # fmt: skip
    status, err = _interrupt(process, lambda: _has_open(process.pid, wav))
    assert status in INTERRUPTED, err
    assert err.strip() == "infomax-contingency calibrate: interrupted"


def test_ctrl_c_of_an_experiment_with_workers_ends_them_all_in_one_line() -> None:
    process = _command("experiment", "efficiency", "--workers", "2", "--steps", "100000")

    def workers_started() -> bool:
        children = Path(f"/proc/{process.pid}/task/{process.pid}/children")
        return len(children.read_text().split()) >= 2 if children.exists() else False

    status, err = _interrupt(process, workers_started)
    assert status in INTERRUPTED, err
    assert err.strip() == "infomax-contingency experiment: interrupted"


def test_ctrl_c_while_the_parser_is_built_is_one_line(capsys, monkeypatch) -> None:
    """A Ctrl-C 0.4-0.7 s after the start landed in build_parser: a traceback before."""

    def interrupted(subparsers) -> None:  # a registrar that a Ctrl-C stops mid-way
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_main, "REGISTRARS", [*cli_main.REGISTRARS[:3], interrupted])
    for argv, line in ((["info", "policies/robot_receding_H24_M60.npz"],
                        "infomax-contingency info: interrupted\n"),
                       ([], "infomax-contingency: interrupted\n")):
        try:
            status = main(argv)
        except KeyboardInterrupt:  # not the test run's own Ctrl-C: fail, do not stop pytest
            pytest.fail("the Ctrl-C went out of main(): a traceback")
        assert status == 130
        assert capsys.readouterr().err == line


def test_the_parser_is_built_without_loading_scipy() -> None:
    """Building every command's options makes no bit source: scipy took 0.5 s to load there."""
    code = ("import sys; from infomax_contingency.cli.main import build_parser; build_parser();"
            " print(sorted(name for name in sys.modules if name.split('.')[0] == 'scipy'))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=120, check=True)  # fmt: skip
    assert result.stdout.strip() == "[]", result.stdout[:300]


def test_an_experiments_workers_end_when_the_command_is_killed() -> None:
    """A command killed with SIGKILL (an OOM kill, a timeout) takes its workers along.

    Before, they ignored Ctrl-C and computed on as orphans for as long as their tasks ran.
    """
    process = _command("experiment", "efficiency", "--workers", "2", "--steps", "100000")
    children = Path(f"/proc/{process.pid}/task/{process.pid}/children")
    deadline = time.monotonic() + 120
    try:
        workers: list[int] = []
        while len(workers) < 2:
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "the workers never started"
            time.sleep(0.05)  # polls the child's state; the deadline bounds it
            workers = [int(pid) for pid in children.read_text().split()] \
                if children.exists() else []  # fmt: skip
        os.kill(process.pid, signal.SIGKILL)  # the command alone, not its group
        process.wait()
        deadline = time.monotonic() + 30
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.05)  # polls the workers' state; the deadline bounds it
        assert not [pid for pid in workers if _alive(pid)]
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)


def _alive(pid: int) -> bool:
    from infomax_contingency.lifetime import process_alive

    return process_alive(pid)


def test_a_calibration_in_the_node_refuses_a_threshold_outside_the_range() -> None:
    """mic_node's and replay's calibration (the Binarizer) took +48.7 dB from unscaled audio."""
    from infomax_contingency.audio.bitsources.rules import Binarizer

    unscaled = [30.0] * 12 + [67.0] * 8  # int16 values stored as floats: quiet and speech
    rule = Binarizer(None, calibration_windows=20)
    with pytest.raises(AudioError, match=r"threshold 48\.50 dB .* outside -150 \.\. 0 dB"):
        rule.calibrate(unscaled)
    assert rule.threshold_db is None and rule.state == "unseparated"
    for energy in unscaled:  # a stream: refused, and calibrated again on the next windows
        assert rule.push(energy) is None
    assert rule.threshold_db is None and "outside -150 .. 0 dB" in rule.calibration_problem
    assert rule.calibrate([x - 100.0 for x in unscaled]).threshold_db == pytest.approx(-51.5)


def test_calibrate_on_constant_audio_far_outside_full_scale_names_the_scale(tmp_path, capsys):
    """Audio of 3e38 has no boundary to find; the line said only that (not why)."""
    samples = np.full(16_000 * 5, 3e38)
    data = samples.astype("<f4").tobytes()
    fmt = struct.pack("<HHIIHH", 3, 1, 16_000, 64_000, 4, 32)
    body = (b"WAVE" + b"fmt " + struct.pack("<I", len(fmt)) + fmt + b"data"
            + struct.pack("<I", len(data)) + data)  # fmt: skip
    wav = tmp_path / "huge.wav"
    wav.write_bytes(b"RIFF" + struct.pack("<I", len(body)) + body)
    assert main(["calibrate", "--wav", str(wav), "--out", str(tmp_path / "t.yaml")]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1
    assert "10 of 10 windows of" in error and "outside [-1, 1]" in error
    assert "no boundary between quiet and sound" in error


def test_memory_running_out_where_no_check_foresaw_it_is_one_line(monkeypatch, capsys):
    """`experiment baby9 --horizon 1e6` and its kind died in a MemoryError traceback."""
    from infomax_contingency.cli import main as cli_main

    def run_out_of_memory(args) -> int:
        raise MemoryError

    parser = cli_main.build_parser

    def build_parser():
        built = parser()
        parse_args = built.parse_args

        def parse_with_a_greedy_command(argv):
            args = parse_args(argv)
            args.run = run_out_of_memory
            return args

        built.parse_args = parse_with_a_greedy_command
        return built

    monkeypatch.setattr(cli_main, "build_parser", build_parser)
    assert cli_main.main(["simulate", "--steps", "10"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("infomax-contingency simulate: error: out of memory: the sizes asked for"
                   " need more memory than this process may use (docs/LIMITS.md)")


@pytest.mark.parametrize("argv", [
    ("baby9", "--horizon", "1000000"),  # a MemoryError traceback before
    ("baby9", "--memory", "100000000"),
    ("rule", "--horizon", "100000"),
])
def test_an_experiment_whose_table_would_not_fit_is_refused_before_solving(argv, capsys):
    assert main(["experiment", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "refusing to solve the " in err and "give a shorter horizon or memory" in err


@pytest.mark.parametrize(("argv", "message"), [
    # a MemoryError once the solve had started
    (("horizon", "--longest", "100000"),
     "refusing to solve horizons 1 .. 100000 of paper on counts up to 12: it needs about"),
    (("horizon", "--domain", "100000"), "give a smaller --longest or --domain"),
    (("greedy", "--max-count", str(10**9)),
     "refusing to run experiment greedy on paper with --max-count 1000000000 and --steps 80"),
    # ran, holding every step
    (("greedy", "--steps", str(10**12)), "give a smaller --max-count or fewer --steps"),
    (("efficiency", "--steps", str(10**12)),
     "refusing to run experiment efficiency: 11,800 runs of 1,000,000,000,000 steps in 2"),
    (("efficiency", "--named-runs", str(10**12)), "refusing to run experiment efficiency: 72,"),
    (("efficiency", "--named-runs", "0"), "--named-runs must be >= 1, got 0"),  # was a KeyError
    (("efficiency", "--switch-runs", "0"), "--switch-runs must be >= 1, got 0"),
    (("efficiency", "--workers", "100000"), "--workers 100000: give 1 .. "),
    # grew to the memory limit
    # 10^12 runs x every room x 4 partner states x 4 controllers
    (("rooms", "--runs", str(10**12)),
     f"refusing to run experiment rooms: {10**12 * len(ROOM_SOUNDS) * 16:,} runs: it needs about"),
    (("rooms", "--jobs", "100000"), "experiment rooms: --jobs 100000: give 1 .. "),
    # the model's periods on the rooms' 0.5-s windows, unsaid
    (("rooms", "--params", "paper"), "--params paper: dt = 0.8 s, but the rooms' windows are"),
])
def test_an_experiment_too_large_is_refused_before_any_work(argv, message, capsys, monkeypatch):
    def no_work(*_args, **_kwargs):
        raise AssertionError("the work started before the cost check")

    for module, name in (("infomax_contingency.core.scoring", "backward_induction"),
                         ("infomax_contingency.eval.experiments.efficiency", "simulate_rooms"),
                         ("infomax_contingency.eval.rooms.experiment", "simulate_room_runs")):
        monkeypatch.setattr(importlib.import_module(module), name, no_work)
    assert message in _one_line_error(capsys, "experiment", *argv)


def test_the_experiments_estimates_stay_near_what_they_take():
    """Near the defaults' measured peak (robot set: horizon 289 MiB, greedy 221 MiB)."""
    from infomax_contingency.core.scoring import receding_layers_cost

    robot = ModelParams.load("robot")
    assert 200 * 2**20 < receding_layers_cost(robot, 60, 12).peak_bytes < 400 * 2**20
    assert 150 * 2**20 < receding_layers_cost(robot, 8, 60).peak_bytes < 400 * 2**20


def test_learn_and_room_wav_refuse_before_work_what_would_not_fit(capsys, monkeypatch):
    """A curve point per evaluation of 10^12; a day of sound (5.5 GB) joined into one."""
    import infomax_contingency.limits as limits

    def no_work(*_args, **_kwargs):
        raise AssertionError("the work started before the cost check")

    monkeypatch.setattr(importlib.import_module("infomax_contingency.core.learning"), "learn",
                        no_work)
    monkeypatch.setattr(importlib.import_module("infomax_contingency.eval.rooms.listening"),
                        "run_loop", no_work)
    for argv in (("baby9", "--replies", ","), ("greedy", "--params", ""),
                 ("horizon", "--params", " , ")):  # ran nothing, exit 0 before
        with pytest.raises(SystemExit) as ended:  # argparse's usage, then its error line
            main(["experiment", *argv])
        assert ended.value.code == 2
        assert "error: argument " + argv[1] + ": expected at least one name" in (
            capsys.readouterr().err)
    error = _one_line_error(capsys, "learn", "--plot", "curves.txt")  # after 8.5 s of work before
    assert "--plot curves.txt: a figure file's name must end in .png" in error
    error = _one_line_error(capsys, "learn", "--budget", str(10**12))
    assert "refusing to learn with horizon 12 and 1,000,000,001 evaluations" in error
    assert "a larger --evaluate-every" in error
    monkeypatch.setattr(limits, "memory_budget", lambda: limits.MemoryBudget(2**30, "a test"))
    error = _one_line_error(capsys, "room-wav", "quiet", "--seconds", "86400", "--out",
                            "never.wav")
    assert "refusing to render 86400 s of room sound: it needs about 51.7 GiB" in error
    assert not Path("never.wav").exists()

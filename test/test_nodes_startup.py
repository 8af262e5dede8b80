"""Node start-up as users meet it: bad parameters refused in one line, clean stops.

Every bad configuration is refused in-process (the node class built with the same ROS
arguments raises the error its executable prints); a few run as their own process
(``python -m infomax_contingency.nodes.<node>``, the code of the console scripts) with
ROS arguments on the command line, to show the one ``[ERROR]`` line and exit status 2.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import rclpy

from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.errors import USER_ERRORS
from infomax_contingency.nodes import entry
from infomax_contingency.nodes.belief_node import BeliefNode
from infomax_contingency.nodes.controller_node import DEFAULT_TABLE, ControllerNode
from infomax_contingency.nodes.fake_audio_node import FakeAudioNode
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.speaker_node import SpeakerNode
from infomax_contingency.resources import resource_path
from processes import readline_within

ROOT = Path(__file__).resolve().parent.parent

CASES = {
    "window": (
        "mic_node",
        ["source:=topic", "window_s:=0.0"],
        "parameter 'window_s' = 0 s differs from the model's dt = 0.5 s (parameter 'params'):"
        " one window is one step of the model; remove window_s",
    ),
    "window_type": (
        "mic_node",
        ["source:=topic", "window_s:=half"],
        "parameter 'window_s' = 'half' differs from the model's dt = 0.5 s",
    ),
    "missing_wav": (
        "mic_node",
        ["source:=wav", "wav_file:=/nonexistent/a.wav"],
        "/nonexistent/a.wav does not exist",
    ),
    "window_not_dt": (
        "mic_node",
        ["window_s:=0.25"],
        "parameter 'window_s' = 0.25 s differs from the model's dt = 0.5 s",
    ),
    "belief_window_not_dt": (
        "belief_node",
        ["window_s:=1.0"],
        "parameter 'window_s' = 1 s differs from the model's dt = 0.5 s",
    ),
    "no_threshold_file": (
        "mic_node",
        ["source:=topic", "bit_source:=energy", "threshold_mode:=file"],
        "parameter 'threshold_file' is empty",
    ),
    "bit_source": (
        "mic_node",
        ["source:=topic", "bit_source:=silero"],
        "parameter 'bit_source' = 'silero' is not allowed: one of energy, speech_band, vad,"
        " background",
    ),
    "vad_rate": (
        "mic_node",
        ["source:=topic", "bit_source:=vad", "audio_rate_hz:=44100"],
        "parameter 'audio_rate_hz' = 44100: bit_source vad takes audio at 8000, 16000, 32000,"
        " 48000 Hz only",
    ),
    "vad_frame": (
        "mic_node",
        ["source:=topic", "bit_source:=vad", "vad_frame_ms:=25"],
        "parameter 'vad_frame_ms' = 25: must be 10, 20 or 30 ms",
    ),
    "vad_aggressiveness": (
        "mic_node",
        ["source:=topic", "bit_source:=vad", "vad_aggressiveness:=4"],
        "parameter 'vad_aggressiveness' = 4 is not allowed: a whole number in [0, 3]",
    ),
    "vad_voiced": (
        "mic_node",
        ["source:=topic", "bit_source:=vad", "vad_min_voiced_s:=0.6"],
        "parameter 'vad_min_voiced_s' = 0.6 s is longer than a window (window_s = 0.5 s)",
    ),
    "speech_band_rate": (
        "mic_node",
        ["source:=topic", "bit_source:=speech_band", "audio_rate_hz:=6000"],
        "parameter 'audio_rate_hz' = 6000: bit_source speech_band needs audio above 6800 Hz",
    ),
    "noise_refresh": (
        "mic_node",
        ["source:=topic", "bit_source:=energy", "threshold_mode:=noise_floor", "refresh_s:=10.0"],
        "parameter 'refresh_s' = 10: refits a k-means threshold; threshold_mode noise_floor",
    ),
    "noise_percentile": (
        "mic_node",
        ["source:=topic", "bit_source:=energy", "threshold_mode:=noise_floor",
         "noise_percentile:=80.0"],
        "parameter 'noise_percentile' = 80.0 is not allowed: a number in [0, 50] %",
    ),
    "foreign_table": (
        "controller_node",
        ["params:=paper"],
        "was built for other model parameters (table vs expected: dt: 0.5 != 0.8",
    ),
    "damaged_table": (
        "controller_node",
        ["policy_file:={damaged_table}"],
        "is damaged: content digest mismatch",
    ),
    "unknown_table": (
        "controller_node",
        ["policy_file:=nope.npz"],
        "cannot find 'policies/nope.npz'",
    ),
    "no_bag": (
        "mic_node",
        ["source:=bag"],
        "parameter 'bag_dir' is empty: source 'bag' needs a session bag",
    ),
    "missing_bag": (
        "mic_node",
        ["source:=bag", "bag_dir:=/nonexistent/session"],
        "parameter 'bag_dir' = '/nonexistent/session': cannot read the session",
    ),
    "missing_bag_decisions": (
        "controller_node",
        ["controller:=recorded:/nonexistent/session"],
        "parameter 'controller' = 'recorded:/nonexistent/session': cannot read the session",
    ),
    "calibration_controller": (
        "controller_node",
        ["controller:=fixed:3"],
        "parameter 'controller' = 'fixed:3': must be empty (the policy table),"
        " interval:MIN_S-MAX_S",
    ),
    "calibration_interval": (
        "controller_node",
        ["controller:=interval:6-3"],
        "parameter 'controller' = 'interval:6-3': interval controller: need 0 < MIN_S <= MAX_S",
    ),
    "memory": (
        "belief_node",
        ["memory_steps:=-1"],
        "parameter 'memory_steps' = -1 is not allowed: a whole number in [0, 1000000]",
    ),
    "model_file": ("belief_node", ["params:=/nonexistent/model.yaml"], "does not exist"),
    "room": (
        "fake_audio_node",
        ["room:=party"],
        "parameter 'room' = 'party' is not allowed: one of responsive, silent, noisy",
    ),
    "reply_times": (
        "fake_audio_node",
        ["reply_min_s:=2.0", "reply_max_s:=1.0"],
        "reply_max_s = 1.0: must be >= reply_min_s (= 2.0)",
    ),
    "joints": (
        "posture_node",
        ["attentive_positions:=[0.0]"],
        "parameter 'attentive_positions' = [0.0]: must hold one position per joint",
    ),
    "thresholds": (
        "posture_node",
        ["attentive_above:=0.3", "bored_below:=0.5"],
        "parameter 'bored_below' = 0.5: must be below 'attentive_above' (= 0.3)",
    ),
    "volume": (
        "speaker_node",
        ["volume:=2.0"],
        "parameter 'volume' = 2.0 is not allowed: a number in [0.001, 1]",
    ),
    "sim_time": (  # nothing publishes /clock: the nodes' timers would never fire
        "belief_node",
        ["use_sim_time:=true"],
        "parameter 'use_sim_time' = True is not allowed: these nodes run on the system clock",
    ),
}


NODE_CLASSES = {
    "mic_node": MicNode,
    "controller_node": ControllerNode,
    "belief_node": BeliefNode,
    "posture_node": PostureNode,
    "fake_audio_node": FakeAudioNode,
    "speaker_node": SpeakerNode,
}

PROCESS_ONLY_CASES = {
    "sim_time_type": (  # rclpy's own check of a parameter every node has, before the node's
        "posture_node",
        ["use_sim_time:=1"],
        "cannot set parameter 'use_sim_time' to '1' of type 'INTEGER', expecting type 'BOOL'",
    ),
}
"""Refusals that rclpy raises before a node's own checks: one line only as a process."""

PROCESS_CASES = ("window_type", "damaged_table", "sim_time", *PROCESS_ONLY_CASES)
"""The refusals also run as processes: a parameter's range, a file's content, rclpy's own."""


def node_command(node: str, parameters: list[str]) -> list[str]:
    command = [sys.executable, "-m", f"infomax_contingency.nodes.{node}", "--ros-args"]
    for parameter in parameters:
        command += ["-p", parameter]
    return command


def damaged_table(folder: Path) -> Path:
    """The default table with one action bit flipped (its metadata and digest unchanged)."""
    table = PolicyTable.load(resource_path(*DEFAULT_TABLE))
    actions = table.packed_actions.copy()
    actions[len(actions) // 3] ^= 0x01
    path = folder / "damaged.npz"
    with path.open("wb") as stream:
        np.savez_compressed(
            stream, actions=actions, metadata=np.array(json.dumps(table.metadata()))
        )
    return path


@pytest.fixture(scope="module")
def refusals(tmp_path_factory) -> Iterator[dict[str, subprocess.CompletedProcess]]:
    """Start every bad configuration at once (in parallel) and collect the results."""
    files = {"damaged_table": damaged_table(tmp_path_factory.mktemp("tables"))}
    processes = {
        name: subprocess.Popen(
            node_command(node, [parameter.format(**files) for parameter in parameters]),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for name, (node, parameters, _) in {**CASES, **PROCESS_ONLY_CASES}.items()
        if name in PROCESS_CASES
    }
    results = {}
    try:
        for name, process in processes.items():
            out, _ = process.communicate(timeout=120)
            results[name] = subprocess.CompletedProcess(process.args, process.returncode, out)
        yield results
    finally:
        for process in processes.values():
            if process.poll() is None:
                process.kill()
                process.wait()


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_configuration_is_refused_in_process(case: str, tmp_path: Path) -> None:
    node, parameters, expected = CASES[case]
    files = {"damaged_table": damaged_table(tmp_path)}
    arguments = [arg for p in parameters for arg in ("-p", p.format(**files))]
    rclpy.init(args=["--ros-args", *arguments])
    try:
        with pytest.raises(USER_ERRORS) as refused:
            NODE_CLASSES[node]().destroy_node()
    finally:
        rclpy.try_shutdown()
    assert expected in str(refused.value)
    assert "\n" not in str(refused.value).strip(), "one line"


@pytest.mark.slow
# One worker runs every case: the module fixture starts every process case at once, and
# each worker that ran a case started all of them again (with `--dist loadgroup`).
@pytest.mark.xdist_group("node_refusals")
@pytest.mark.parametrize("case", PROCESS_CASES)
def test_bad_configuration_is_refused_in_one_line(
    refusals: dict[str, subprocess.CompletedProcess], case: str
) -> None:
    node, _, expected = {**CASES, **PROCESS_ONLY_CASES}[case]
    result = refusals[case]
    assert result.returncode == 2, result.stdout
    assert "Traceback" not in result.stdout
    errors = [line for line in result.stdout.splitlines() if "[ERROR]" in line]
    assert len(errors) == 1, result.stdout
    assert f"[{node}]" in errors[0] and expected in errors[0], errors[0]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_running_node_stops_cleanly(sig: signal.Signals) -> None:
    process = subprocess.Popen(
        node_command("controller_node", []),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        first_line = readline_within(process)  # the node logs its table once it is up
        assert "receding, horizon 24, memory 60" in first_line, first_line
        assert process.poll() is None
        process.send_signal(sig)
        out, _ = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, out
    assert "Traceback" not in out and "[ERROR]" not in out


HEAVY_MODULES = ("scipy", "rosbags", "mcap", "matplotlib", "sounddevice", "webrtcvad")
"""What a node loads only when its configuration needs it (each costs 0.1-1 s of CPU per
process): scipy for a belief, a coloured room, a band-pass bit source or resampling;
rosbags and mcap for a bag; sounddevice for a device; webrtcvad for the vad bit source;
matplotlib for the figures of the command line, never for a node."""

NEEDS_ROSBAGS = {"recorder_node", "bringup"}
"""The executables that always write or may write a bag (bringup holds the recorder)."""


@pytest.mark.parametrize("executable", sorted(entry.NODE_MODULES))
def test_a_node_module_loads_no_heavy_library_it_may_not_need(executable: str) -> None:
    child = Path(__file__).resolve().parent / "child_imports.py"
    out = subprocess.run([sys.executable, str(child), f"infomax_contingency.nodes.{executable}",
                          ",".join(HEAVY_MODULES)],
                         capture_output=True, text=True, check=True)  # fmt: skip
    assert json.loads(out.stdout) == (["rosbags"] if executable in NEEDS_ROSBAGS else [])


def test_a_node_out_of_memory_at_start_up_says_so_in_one_line() -> None:
    """A size no check foresaw (MemoryError): one ERROR line naming the node, status 2."""
    script = (
        "import sys\n"
        "from infomax_contingency.nodes.runtime import run_nodes\n"
        "def factory():\n"
        "    raise MemoryError\n"
        "sys.exit(run_nodes([('belief_node', factory)], 'belief_node', []))\n"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            timeout=60)  # fmt: skip
    out = result.stdout + result.stderr
    assert result.returncode == 2, out
    assert "Traceback" not in out
    errors = [line for line in out.splitlines() if "[ERROR]" in line]
    assert len(errors) == 1 and "[belief_node]" in errors[0], out
    assert "out of memory" in errors[0]

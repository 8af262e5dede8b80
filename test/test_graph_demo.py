"""The main job and the one-process graph: ``infomax-contingency demo`` and ``bringup``.

Both read the shipped parameter files (config/robot.yaml, config/fake_room.yaml).
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from graph_harness import Graph, graph_fixture
from infomax_contingency.testing.graph import wait_until

ROOT = Path(__file__).resolve().parent.parent
WAV = ROOT / "test" / "data" / "interaction.wav"
STEP_LINE = re.compile(r"^\s*(\d+)\s+([\d.]+)\s+([01])\s+(yes|-)\s+([\d.]+)\s+(attentive|bored)")

make_graph = graph_fixture()
pytestmark = pytest.mark.slow


def demo(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "infomax_contingency.cli", "demo", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_demo_finds_the_partner_and_notices_they_left() -> None:
    result = demo("--steps", "200", "--seed", "1", "--leave-at", "50")
    assert result.returncode == 0, result.stdout + result.stderr
    lines = [STEP_LINE.match(line) for line in result.stdout.splitlines()]
    steps = [m for m in lines if m]
    assert [int(m[1]) for m in steps] == list(range(1, 201))
    assert float(steps[1][2]) == 0.5, "time column in seconds of room time"
    postures = [m[6] for m in steps]
    assert postures[0] == "bored" and "attentive" in postures and postures[-1] == "bored"
    truth = [
        line.endswith("present") for line in result.stdout.splitlines() if STEP_LINE.match(line)
    ]
    assert truth == [k < 100 for k in range(200)]
    verdict = result.stdout.splitlines()[-1]
    assert verdict.startswith("# verdict: found the partner")
    assert "noticed they left" in verdict and "final answer correct" in verdict


def test_demo_replays_a_wav_file() -> None:
    result = demo("--wav", str(WAV))
    assert result.returncode == 0, result.stdout + result.stderr
    steps = [m for m in map(STEP_LINE.match, result.stdout.splitlines()) if m]
    assert len(steps) == 36
    assert result.stdout.splitlines()[-1].startswith("# verdict: the robot thinks:")


def test_demo_refuses_a_missing_wav_file() -> None:
    result = demo("--wav", "/nonexistent.wav")
    assert result.returncode == 2
    assert (
        result.stderr.strip()
        == "infomax-contingency demo: error: --wav /nonexistent.wav: no such file"
    )


def test_bringup_runs_the_graph_in_one_process(
    make_graph: Callable[[], Graph], tmp_path: Path
) -> None:
    graph = make_graph()
    # The mic and the room wait for this test's recorder too: it records from step 1.
    listeners = tmp_path / "listeners.yaml"
    listeners.write_text(
        "mic_node:\n  ros__parameters:\n    wait_for_listeners: 3\n"
        "fake_audio_node:\n  ros__parameters:\n    wait_for_truth_listeners: 1\n"
    )
    command = [sys.executable, "-m", "infomax_contingency.nodes.bringup", "--fake-room"]
    command += ["--ros-args", "--params-file", str(ROOT / "config" / "robot.yaml")]
    command += ["--params-file", str(ROOT / "config" / "fake_room.yaml")]
    command += ["--params-file", str(listeners)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        rec = graph.recorder
        # The partner of config/fake_room.yaml leaves after 60 s of room time (step 120).
        done = wait_until(lambda: len(rec.belief) >= 300 and process.poll() is None, 120.0)
        assert done, f"{rec.counts()}; bringup exited with {process.poll()}"
        process.send_signal(signal.SIGINT)
        out, _ = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, out
    assert "Traceback" not in out
    with rec.lock:
        n = min(len(rec.belief), len(rec.partner_present))
        beliefs, present = np.array(rec.belief[:n]), np.array(rec.partner_present[:n])
    assert beliefs[present].max() > 0.95 and beliefs[-20:].max() < 0.2
    assert [posture for _, posture in rec.posture][:3] == ["bored", "attentive", "bored"]

"""The main job and the one-process graph: ``infomax-contingency demo`` and ``bringup``.

Both read the shipped parameter files (config/robot.yaml, config/fake_room.yaml).
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import struct
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from graph_harness import Graph, assert_every_step_recorded, graph_fixture
from infomax_contingency.audio.bag_replay import BagReplay
from infomax_contingency.cli import demo as demo_module
from infomax_contingency.cli import demo_checks, demo_output
from infomax_contingency.testing.graph import wait_until
from processes import read_until, readline_within
from stepped_graph import stepped_graph

# The graph tests that start many node processes running at full speed run one at a
# time (on one pytest-xdist worker, with `--dist loadgroup`), so that they do not starve
# each other of CPU: NODE_GRAPHS below. The in-process and start-up tests run anywhere.
NODE_GRAPHS = pytest.mark.xdist_group("node_graphs")

ROOT = Path(__file__).resolve().parent.parent
WAV = ROOT / "test" / "data" / "interaction.wav"
STEP_LINE = re.compile(r"^\s*(\d+)\s+([\d.]+)\s+([01])\s+(yes|-)\s+([\d.]+)\s+(attentive|bored)")

make_graph = graph_fixture()


def demo(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "infomax_contingency.cli", "demo", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )


@NODE_GRAPHS
@pytest.mark.slow
@pytest.mark.dds_defaults
def test_demo_finds_the_partner_notices_they_left_and_records_every_step(tmp_path: Path) -> None:
    """The README's demo, with ``--record``: its verdict, and a bag with every step.

    The recorder is up before the graph starts: nothing of the first steps is lost. As
    ``make demo`` runs, with no profile of the suite's: the demo's own discovery profile
    (config/fastdds_demo.xml) and Fast DDS's default data path, so a sample lost on the way
    is resent only at its writer's next heartbeat (3 s), and the stop still records it.
    """
    bag = tmp_path / "demo"
    # mic_node's default source (background) first hears the room: 8 windows of
    # background and 4 more of its threshold's delay give no bit
    windows, warmup = 200, 12
    result = demo("--steps", str(windows), "--seed", "1", "--leave-at", "50", "--record",
                  str(bag))  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Fast DDS profile fastdds_demo.xml)" in result.stdout.splitlines()[0], result.stdout
    summary = "\n".join(line for line in result.stdout.splitlines() if line.startswith("#"))
    assert "# note:" not in summary, summary  # a released window: not the reproducible run
    assert "# the first 12 windows (6 s) gave no bit" in summary, summary
    lines = [STEP_LINE.match(line) for line in result.stdout.splitlines()]
    steps = [m for m in lines if m]
    assert [int(m[1]) for m in steps] == list(range(1, windows - warmup + 1))
    assert [float(m[2]) for m in steps[:2]] == [6.0, 6.5], "room time of the step's window"
    postures = [m[6] for m in steps]
    assert postures[0] == "bored" and postures[-1] == "bored", summary
    assert "attentive" in postures, summary
    truth = [
        line.endswith("present") for line in result.stdout.splitlines() if STEP_LINE.match(line)
    ]
    assert truth == [warmup + k < 100 for k in range(windows - warmup)]
    verdict = result.stdout.splitlines()[-1]
    assert verdict.startswith("# verdict: found the partner")
    assert "noticed they left" in verdict and "final answer correct" in verdict

    topics = assert_every_step_recorded(bag, windows - warmup, windows)
    assert [m.data for _, m in topics["/partner_present"]][warmup:] == truth
    replay = BagReplay(bag, 0.5, 16000)
    assert replay.has_audio and replay.n_windows == windows
    # The node processes' run is the offline loop's (the demo's room, memory and table).
    offline = _offline_demo(seed=1, leave_s=50.0, steps=windows - warmup)
    assert [m.data for _, m in topics["/sound"]] == [bool(r.y) for r in offline]
    assert [m.data for _, m in topics["/vocalize"]] == [bool(r.u) for r in offline]
    assert [m.data for _, m in topics["/belief"]] == [r.belief for r in offline]


def _offline_demo(seed: int, leave_s: float, steps: int) -> list:
    """The demo's run offline: the responsive room, mic_node's default source, the table."""
    from infomax_contingency.audio.bitsources import DEFAULT_BIT_SOURCE, make_bit_source
    from infomax_contingency.core.controllers import PolicyController, default_check_in
    from infomax_contingency.core.model import ModelParams
    from infomax_contingency.core.policy_table import PolicyTable
    from infomax_contingency.resources import resource_path
    from infomax_contingency.sim.audio_loop import simulate_audio_loop
    from infomax_contingency.sim.fake_room import FakeRoom
    from infomax_contingency.sim.room_config import FakeRoomConfig

    params = ModelParams.named("robot")
    table = PolicyTable.load(resource_path("policies", "robot_receding_H24_M60.npz"),
                             expected_params=params)  # fmt: skip
    bits = make_bit_source(DEFAULT_BIT_SOURCE, 16000, 0.5)
    bits.follow_model(params)
    room = FakeRoom(FakeRoomConfig.preset("responsive", partner_leave_s=leave_s), seed)
    controller = PolicyController(table, params, default_check_in(params))  # controller_node's
    return simulate_audio_loop(controller, room, bits, steps, memory=60)


@NODE_GRAPHS
@pytest.mark.slow
def test_demo_replays_a_wav_file() -> None:
    result = demo("--wav", str(WAV))
    assert result.returncode == 0, result.stdout + result.stderr
    steps = [m for m in map(STEP_LINE.match, result.stdout.splitlines()) if m]
    # mic_node's default source first hears the room: 8 windows of background and 4 more
    # of its threshold's delay
    assert len(steps) == 36 - 12
    assert result.stdout.splitlines()[-1].startswith("# verdict: the robot thinks:")
    assert "mic_node warned" not in result.stdout


@NODE_GRAPHS
@pytest.mark.slow
def test_demo_says_in_one_line_why_a_recording_gave_no_step(tmp_path: Path) -> None:
    """3 s of audio: all of it goes to the default source's warm-up (about 6 s)."""
    from infomax_contingency.audio.wav import write_wav_int16

    short = tmp_path / "short.wav"
    write_wav_int16(short, np.random.default_rng(0).normal(0, 0.01, 3 * 16000), 16000)
    result = demo("--wav", str(short))
    assert result.returncode == 1, result.stdout + result.stderr
    errors = [line for line in result.stderr.splitlines() if "demo: error" in line]
    assert errors == [f"infomax-contingency demo: error: {short} gave no step: its 6 windows"
                      " all went by without a bit (the bit source hears about 6 s of the"
                      " room's background first)"], result.stderr  # fmt: skip
    assert "Traceback" not in result.stderr
    # a float recording never scaled to [-1, 1]: mic_node's own warning is the reason
    from scipy.io import wavfile

    unscaled = tmp_path / "unscaled.wav"
    noise = np.random.default_rng(1).normal(0, 1000, 10 * 16000).astype(np.float32)
    wavfile.write(unscaled, 16000, noise)
    result = demo("--wav", str(unscaled))
    assert result.returncode == 1, result.stdout + result.stderr
    errors = [line for line in result.stderr.splitlines() if "demo: error" in line]
    assert len(errors) == 1 and errors[0].startswith(
        f"infomax-contingency demo: error: {unscaled} gave no step: its 20 windows all went by"
        " without a bit (mic_node said: background threshold: threshold_db 5"
    ), result.stderr
    assert "(audio not scaled to [-1, 1]?))" in errors[0]
    assert "Traceback" not in result.stderr
    # a dead input: digital silence from the start is no room; mic_node says what it is
    dead = tmp_path / "dead.wav"
    write_wav_int16(dead, np.zeros(12 * 16000), 16000)
    result = demo("--wav", str(dead))
    assert result.returncode == 1, result.stdout + result.stderr
    assert (f"{dead} gave no step: its 24 windows all went by without a bit (mic_node said: the"
            " input has been digital silence for 10 s (every sample zero or one constant"
            " value)") in result.stderr  # fmt: skip
    # one click, then dead: steps (the silence after a sound is the room's), and the warning
    click = np.zeros(16 * 16000)
    click[800:880] = 0.5
    write_wav_int16(dead, click, 16000)
    result = demo("--wav", str(dead))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "# mic_node warned: the input has been digital silence for 10 s" in result.stdout


@pytest.mark.slow
def test_demo_refuses_a_missing_wav_file(tmp_path: Path) -> None:
    result = demo("--wav", "/nonexistent.wav")
    assert result.returncode == 2
    assert (
        result.stderr.strip()
        == "infomax-contingency demo: error: --wav /nonexistent.wav: no such file"
    )
    result = demo("--wav", str(tmp_path))
    assert result.returncode == 2
    assert result.stderr.strip() == (f"infomax-contingency demo: error: --wav {tmp_path}: a"
                                     " directory, not a wav file")  # fmt: skip


def test_the_shipped_configs_find_the_partner_and_notice_they_left() -> None:
    """config/robot.yaml + config/fake_room.yaml, in-process on one stepped executor."""
    nodes = {
        "mic_node": {"source": "topic", "wait_for_listeners": 3},
        "controller_node": {"wait_for_listeners": 4},  # mic, belief, room, recorder
        "belief_node": {},
        "posture_node": {},
        "fake_audio_node": {"wait_for_truth_listeners": 1},
    }
    configs = (str(ROOT / "config" / "robot.yaml"), str(ROOT / "config" / "fake_room.yaml"))
    with stepped_graph(nodes, "fake_audio_node", configs) as graph:
        rec = graph.recorder
        # The partner of config/fake_room.yaml leaves after 60 s of room time (window 120);
        # mic_node's default source (background) gives no bit in the first 12 windows.
        graph.run_until(lambda: len(rec.belief) >= 300 and len(rec.partner_present) >= 312,
                        "300 beliefs")  # fmt: skip
        graph.run_until(lambda: len(rec.posture) >= 3, "three postures")
        windows = rec.step_windows(300)
        assert windows == list(range(12, 312))
        beliefs = np.array(rec.belief[:300])
        present = np.array([rec.partner_present[w] for w in windows])
        assert present[: 120 - 12].all() and not present[120 - 12 :].any()
        assert beliefs[present].max() > 0.95 and beliefs[-20:].max() < 0.2
        assert [posture for _, posture in rec.posture][:3] == ["bored", "attentive", "bored"]


@NODE_GRAPHS
@pytest.mark.slow
def test_bringup_runs_the_graph_in_one_process_and_stops_on_sigint(
    make_graph: Callable[[], Graph], tmp_path: Path
) -> None:
    """Smoke test of the one-process executable: the graph runs, Ctrl-C ends it cleanly."""
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
        done = wait_until(lambda: len(rec.belief) >= 20 and process.poll() is None, 120.0)
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
        assert all(0.0 <= b <= 1.0 for b in rec.belief)
        assert rec.posture and rec.posture[0][1] == "bored"


def children_of(pid: int) -> set[int]:
    """Process ids whose parent is ``pid``, from /proc."""
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # exited meanwhile
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            found.add(int(entry.name))
    return found


def alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def described(pid: int) -> str:
    """What a test's failure says of a process still running: its node, state and waits.

    The node (from its command line), its state, the signals pending, blocked and
    handled, and where its threads wait in the kernel.
    """
    proc = Path(f"/proc/{pid}")
    try:
        words = (proc / "cmdline").read_bytes().split(b"\0")
        node = next((w.decode() for w in words if w.endswith(b"_node")), "?")
        status = [line for line in (proc / "status").read_text().splitlines()
                  if line.startswith(("State", "SigPnd", "ShdPnd", "SigBlk", "SigCgt"))]
        waits = sorted({(task / "wchan").read_text() for task in (proc / "task").iterdir()})
    except OSError as error:
        return f"{pid}: {error}"
    return f"{pid} {node}: {'; '.join(status)}; threads waiting in {waits}"


@NODE_GRAPHS
@pytest.mark.slow
@pytest.mark.parametrize(
    ("how", "status", "name"),
    [
        ("SIGINT", 130, "SIGINT"),
        ("SIGTERM", 143, "SIGTERM"),
        ("SIGHUP", 129, "SIGHUP"),  # the terminal closed
        ("Ctrl-C", 130, "SIGINT"),  # SIGINT to the whole process group, as a terminal does
    ],
)
def test_a_signal_stops_the_demo_and_every_node(how: str, status: int, name: str) -> None:
    process = subprocess.Popen(
        [sys.executable, "-m", "infomax_contingency.cli", "demo", "--steps", "10000000"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, for the Ctrl-C case
    )
    try:
        lines = []
        while not lines or not lines[-1].startswith("# demo: the graph is up"):
            line = readline_within(process)
            assert line, f"the demo ended before its graph was up: {lines} {process.stderr.read()}"
            lines.append(line)
        nodes = children_of(process.pid)
        assert len(nodes) == 6, nodes
        if how == "Ctrl-C":
            os.killpg(process.pid, signal.SIGINT)
        else:
            process.send_signal(getattr(signal, how))
        out, err = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    assert process.returncode == status, err
    assert err.strip() == f"infomax-contingency demo: interrupted ({name}); nodes stopped"
    assert "Traceback" not in out + err
    assert not [pid for pid in nodes if alive(pid)], "node processes left behind"


@NODE_GRAPHS
@pytest.mark.slow
def test_the_nodes_of_a_demo_killed_with_sigkill_end_too(tmp_path: Path) -> None:
    """A demo killed with SIGKILL leaves no node running the graph on.

    An OOM kill or a CI timeout gives the demo no chance to stop its nodes: they end on
    their own (the kernel's parent-death signal). Nor to remove its directory of node
    logs: that one is made under the test's own directory.
    """
    process = subprocess.Popen(
        [sys.executable, "-m", "infomax_contingency.cli", "demo", "--steps", "10000000"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        env={**os.environ, "TMPDIR": str(tmp_path)},
    )  # fmt: skip
    nodes: set[int] = set()
    try:
        read_until(process, "# demo: the graph is up")
        nodes = children_of(process.pid)
        assert len(nodes) == 6, nodes
        process.kill()
        process.communicate(timeout=30)
        assert wait_until(lambda: not [pid for pid in nodes if alive(pid)], 30.0), (
            "node processes left running 30 s after the demo was killed: "
            + " | ".join(described(pid) for pid in nodes if alive(pid))
        )
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
        for pid in nodes:  # on the old code: end the orphans, not to load the suite
            if alive(pid):
                os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
def test_a_node_that_refuses_its_parameters_is_named_at_once() -> None:
    """The demo refuses its own bad arguments first; a node's refusal is still named."""
    script = (
        "from infomax_contingency.cli import demo, main\n"
        "args = main.build_parser().parse_args(['demo', '--steps', '10'])\n"
        "demo.isolate_dds()\n"
        "nodes, clock = demo._nodes(args)\n"
        "nodes['belief_node']['memory_steps'] = 2_000_000\n"
        "print(demo._run_graph(args, nodes, clock))\n"
    )
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                            text=True, timeout=300)  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip().splitlines()[-1] == (
        "belief_node exited with status 2: parameter 'memory_steps' = 2000000 is not allowed:"
        " a whole number in [0, 1000000]"
    )


class CountingRecorder:
    """A stand-in for StepRecorder whose message count grows while ``growing``."""

    def __init__(self, growing: bool) -> None:
        self.growing, self.total = growing, 0

    def counts(self) -> dict[str, int]:
        self.total += self.growing
        return {"belief": self.total}


def test_the_watchdog_waits_as_long_as_messages_come() -> None:
    """No cap on the run's length: only a stall (no message for stall_s) ends the wait."""
    recorder = CountingRecorder(growing=True)
    # Holds only after far longer than stall_s, but messages keep coming meanwhile.
    assert demo_module._wait_with_watchdog(
        lambda: recorder.total >= 40, recorder, stall_s=0.05, poll_s=0.01
    )
    stalled = CountingRecorder(growing=False)
    assert not demo_module._wait_with_watchdog(lambda: False, stalled, stall_s=0.05, poll_s=0.01)


class StalledRun:
    """Stand-ins for the recorder and the node processes of a run that stopped early."""

    def __init__(self, lost: dict[str, int]) -> None:
        self.belief, self.partner_present, self.lost = [0.5] * 3, [True] * 4, lost
        self.sound, self.vocalize, self.no_step = [False] * 4, [False] * 4, []

    def counts(self) -> dict[str, int]:
        return {"belief": len(self.belief), "partner_present": len(self.partner_present)}

    def dead(self) -> dict[str, int]:
        return {}

    def report(self) -> str:
        return "all nodes are running"


def test_a_lost_message_is_the_monitors_fault(monkeypatch) -> None:
    monkeypatch.setattr(demo_module, "STALL_TIMEOUT_S", 0.05)
    args = demo_module.argparse.Namespace(wav=None, steps=10)
    run = StalledRun(lost={"belief": 1, "sound": 0})
    _, failure = demo_module._wait_for_run(args, run, run)
    assert failure.startswith("the demo's monitor lost messages {'belief': 1} (its own fault")
    run = StalledRun(lost={"belief": 0})
    _, failure = demo_module._wait_for_run(args, run, run)
    assert failure.startswith("the graph made no progress for 0.05 s after")


class LatePostures:
    """A recorder whose posture changes arrive only on the ``arrive_at``-th look.

    As a posture message lost on the way and resent at its writer's next heartbeat:
    the beliefs are all in, the changes they call for come later.
    """

    def __init__(self, arrive_at: int) -> None:
        high, low = demo_module.ATTENTIVE_ABOVE + 0.05, demo_module.BORED_BELOW - 0.05
        self.belief = [low, high, high, low]
        self._looks, self._arrive_at = 0, arrive_at

    @property
    def posture(self) -> list[tuple[int, str]]:
        self._looks += 1
        changes = [(2, "attentive"), (4, "bored")] if self._looks >= self._arrive_at else []
        return [(0, "bored"), *changes]


def test_the_table_waits_for_the_posture_changes_the_beliefs_call_for() -> None:
    recorder = LatePostures(arrive_at=5)
    received = [posture for _, posture in recorder.posture]
    assert demo_output.step_postures(recorder.belief, received) == []  # not yet: arrival order
    demo_module._wait_for_postures(recorder, steps=4, poll_s=0.0)
    received = [posture for _, posture in recorder.posture]
    assert demo_output.step_postures(recorder.belief, received) == [
        "bored", "attentive", "attentive", "bored"]


class Recorded:
    """What the demo's monitor holds after 3 complete steps and a 4th still in flight."""

    sound = [0, 1, 1, 0]
    vocalize = [True, False, False]
    belief = [0.01, 0.5, 0.95]
    posture = [(0, "bored"), (3, "attentive")]
    partner_present = [True] * 20
    no_step: list[int] = []

    def step_windows(self, steps: int) -> list[int]:
        return [12 + k for k in range(steps)]


def test_an_interrupted_demo_prints_the_steps_it_completed(capsys) -> None:
    """Ctrl-C in a long demo keeps its table: the steps whose bit, decision and belief came."""
    demo_output.print_run_so_far(Recorded(), 0.5, truth=True)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("# the first 12 windows (6 s) gave no bit")
    assert lines[1].split() == ["step", "time_s", "bit", "vocalize", "belief", "posture", "partner"]
    assert [line.split() for line in lines[2:5]] == [
        ["1", "6.0", "0", "yes", "0.0100", "bored", "present"],
        ["2", "6.5", "1", "-", "0.5000", "bored", "present"],
        ["3", "7.0", "1", "-", "0.9500", "attentive", "present"],
    ]
    assert lines[5:] == ["# interrupted after 3 steps"]
    demo_output.print_run_so_far(None, 0.5, truth=True)  # interrupted before the monitor
    assert capsys.readouterr().out == ""
    lagging = Recorded()
    lagging.partner_present = [True] * 13  # the truth of window 13 (step 2) not yet in
    demo_output.print_run_so_far(lagging, 0.5, truth=True)
    assert capsys.readouterr().out.splitlines()[-1] == "# interrupted after 1 steps"


def test_the_demo_graph_announces_itself_quickly_unless_the_user_chose_a_profile(
    tmp_path: Path,
) -> None:
    """config/fastdds_demo.xml for the demo's graph; any profile the user chose stands."""
    environ: dict[str, str] = {}
    chosen = demo_module.demo_dds_profile(environ, cwd=tmp_path)
    assert environ == {"FASTRTPS_DEFAULT_PROFILES_FILE": chosen}
    assert Path(chosen) == ROOT / "config" / "fastdds_demo.xml"
    assert demo_module.describe_dds_profile(chosen) == "fastdds_demo.xml"
    text = Path(chosen).read_text()
    assert "<leaseAnnouncement><sec>0</sec><nanosec>500000000</nanosec>" in text
    assert "heartbeat" not in text.split("-->")[-1].lower(), "the data path keeps the defaults"

    for users in ({"FASTRTPS_DEFAULT_PROFILES_FILE": "/robot/dds.xml"},
                  {"FASTDDS_DEFAULT_PROFILES_FILE": "/robot/dds.xml"}):  # fmt: skip
        environ = dict(users)
        assert demo_module.demo_dds_profile(environ, cwd=tmp_path) == "/robot/dds.xml"
        assert environ == users
    environ = {"SKIP_DEFAULT_XML_FILE": "1"}
    assert demo_module.demo_dds_profile(environ, cwd=tmp_path) == ""
    assert environ == {"SKIP_DEFAULT_XML_FILE": "1"}
    assert demo_module.describe_dds_profile("") == "none"
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles/>")
    environ = {}
    assert demo_module.demo_dds_profile(environ, cwd=tmp_path) == "DEFAULT_FASTRTPS_PROFILES.xml"
    assert environ == {}


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--leave-at", "nan"], "argument --leave-at: expected a finite number, got 'nan'"),
        (["--leave-at", "inf"], "argument --leave-at: expected a finite number, got 'inf'"),
        (["--leave-at", "1e10"], "--leave-at must be at most 1e+09 s"),
        (["--calibration-s", "inf"], "argument --calibration-s: expected a finite number"),
        (["--calibration-s", "4000"], "--calibration-s must be in [0.02, 3600] seconds"),
        (["--wav", str(WAV), "--bit-source", "energy", "--calibration-s", "0.01"],
         "--calibration-s must be in [0.02, 3600] seconds, got 0.01"),  # mic_node's range
        (["--steps", str(2**31)], "--steps must be in [1, 2147483647]"),
        (["--seed", "-1"], "argument --seed: expected a whole number >= 0, got '-1'"),
        (["--seed", str(2**31)], "--seed must be in [0, 2147483647]"),
        (["--memory", "1000000000000"], "--memory must be in [0, 1000000] (belief_node's"
                                        " memory_steps; 0 = all), got 1000000000000"),
        (["--record", "/proc/x"], "--record /proc/x: cannot create it: "),
        (["--wav", "/dev/zero"], "--wav /dev/zero: not a regular file (a device or a FIFO)"),
        # options the run would not use: refused, not ignored
        (["--wav", str(WAV), "--room", "office"], "set the simulated room: not"),
        (["--wav", str(WAV), "--seed", "5"], "set the simulated room: not with"),
        (["--wav", str(WAV), "--leave-at", "10"], "set the simulated room: not"),
        (["--room", "office", "--leave-at", "10"], "--leave-at 10: room office has no partner"),
        (["--calibration-s", "5"], "--calibration-s is the length of a k-means calibration"),
        (["--wav", str(WAV), "--calibration-s", "5"], "it needs --wav and"),
        (["--calibration-s", "10"], "--calibration-s is the length of a k-means calibration"),
        (["--wav", str(WAV), "--bit-source", "vad", "--calibration-s=10"], "it needs --wav and"),
        (["--no-record-audio"], "--no-record-audio leaves the audio out of a recording"),
    ],
)
def test_the_demo_refuses_what_it_cannot_run_before_starting_a_node(
    arguments: list[str], message: str, capsys: pytest.CaptureFixture[str], no_node_graph: None
) -> None:
    """One line and status 2, before any node starts.

    ``--leave-at nan`` meant "the partner never leaves"; ``--record /proc/x`` ran the
    whole demo and exited 0 with no bag and no word.
    """
    from infomax_contingency.cli.main import main

    try:
        status = main(["demo", *arguments])
    except SystemExit as exit_:  # argparse
        status = exit_.code
    assert status == 2
    assert message in capsys.readouterr().err


def test_the_demo_refuses_a_wav_file_mic_node_would_refuse_before_starting_a_node(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A header with a 0 Hz rate: one line and status 2 (the graph once started, then failed)."""
    from infomax_contingency.cli.main import main

    fmt = struct.pack("<HHIIHH", 1, 1, 0, 0, 2, 16)  # PCM, mono, 0 Hz, 16 bits
    body = b"WAVE" + b"fmt " + struct.pack("<I", len(fmt)) + fmt + b"data" + struct.pack("<I", 4)
    wav = tmp_path / "rate0.wav"
    wav.write_bytes(b"RIFF" + struct.pack("<I", len(body) + 4) + body + bytes(4))
    assert main(["demo", "--wav", str(wav)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith(f"infomax-contingency demo: error: --wav {wav}: ")
    assert "0 Hz" in error and "\n" not in error


@pytest.fixture
def no_node_graph(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if the demo goes past its checks (to its DDS domain and its nodes)."""

    def no_graph() -> None:
        raise AssertionError("the demo went on to start its node graph")

    monkeypatch.setattr(demo_module, "isolate_dds", no_graph)


@pytest.mark.parametrize("bad", ["all NaN", "one NaN in the second block", "one inf"])
def test_the_demo_refuses_a_wav_file_of_bad_samples_before_starting_a_node(
    bad: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], no_node_graph: None
) -> None:
    """A float wav of NaN or infinite samples: mic_node's message, one line, status 2.

    mic_node refused it only once the whole graph was up (about 5 s); the demo now reads
    the samples first, block by block, with the readers' own check.
    """
    from scipy.io import wavfile

    from infomax_contingency.audio.common import AudioError
    from infomax_contingency.audio.energy import iter_wav_energies
    from infomax_contingency.audio.wav import DEFAULT_BLOCK_FRAMES
    from infomax_contingency.cli.main import main

    samples = np.zeros(2 * DEFAULT_BLOCK_FRAMES, dtype=np.float32)
    if bad == "all NaN":
        samples[:] = np.nan
    else:
        samples[DEFAULT_BLOCK_FRAMES + 5] = np.nan if "NaN" in bad else np.inf
    wav = tmp_path / "bad.wav"
    wavfile.write(wav, 16000, samples)
    with pytest.raises(AudioError) as mic:  # what mic_node's reader says of it
        for _ in iter_wav_energies(wav, demo_module.WINDOW_S):
            pass
    assert main(["demo", "--wav", str(wav)]) == 2
    error = capsys.readouterr().err
    assert error == f"infomax-contingency demo: error: --wav {wav}: {mic.value}\n"
    assert "contain NaN or infinite values" in error


@pytest.mark.parametrize(
    "given",
    [["--room", "responsive"], ["--seed", "1"], ["--room=responsive", "--seed=1"],
     ["--se", "1"], ["--leave-at", "60"]],
)
def test_the_rooms_options_are_refused_with_a_wav_file_even_at_their_default_values(
    given: list[str], capsys: pytest.CaptureFixture[str], no_node_graph: None
) -> None:
    """``demo --wav F --room responsive --seed 1`` was accepted and ignored.

    The options were told by their values (different from the defaults), not by being given.
    """
    from infomax_contingency.cli.main import main

    assert main(["demo", "--wav", str(WAV), *given]) == 2
    assert capsys.readouterr().err == ("infomax-contingency demo: error: --room, --seed and"
                                       " --leave-at set the simulated room: not with --wav\n")


def test_the_rooms_options_not_given_keep_their_defaults() -> None:
    """Given to the simulated room they are taken; not given, their values are the defaults."""
    from infomax_contingency.cli.main import build_parser

    parser = build_parser()
    typed = parser.parse_args(["demo", "--room", "responsive", "--seed", "1", "--leave-at", "60"])
    demo_checks.check_arguments(typed)
    assert (typed.room, typed.seed, typed.leave_at) == ("responsive", 1, 60.0)
    assert typed.given == {"room", "seed", "leave_at"}
    for argv in (["demo"], ["demo", "--wav", str(WAV)]):  # the same parser: nothing carried over
        plain = parser.parse_args(argv)
        demo_checks.check_arguments(plain)
        assert (plain.room, plain.seed, plain.leave_at, plain.given) == (
            "responsive", 1, None, frozenset()
        )


def test_the_record_check_leaves_nothing_behind(tmp_path: Path) -> None:
    demo_checks.check_record_directory(tmp_path / "bag")
    assert not (tmp_path / "bag").exists()  # the recorder must create it itself
    (tmp_path / "bag").mkdir()
    with pytest.raises(ValueError, match="exists already"):
        demo_checks.check_record_directory(tmp_path / "bag")


def test_a_recording_that_stopped_is_the_demos_failure(tmp_path: Path) -> None:
    """The recorder keeps the graph running when it cannot write; the demo must say so."""
    log = ("[INFO] [1.0] [recorder_node]: up\n[ERROR] [2.0] [recorder_node]: recording stopped:"
           " cannot write: No space left on device\n")  # fmt: skip
    failure = demo_checks.recording_failure(tmp_path, log)
    assert failure == (
        f"--record {tmp_path}: the session was not recorded whole: recording stopped:"
        " cannot write: No space left on device"
    )
    (tmp_path / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    assert demo_checks.recording_failure(tmp_path, log) == ""


def test_bringup_refuses_an_empty_record_directory(capsys: pytest.CaptureFixture[str]) -> None:
    """``--record ""`` ran the graph and recorded nothing, without a word; now refused."""
    from infomax_contingency.nodes import bringup

    with pytest.raises(SystemExit) as ended:  # before any node: the arguments are read first
        bringup._parse(["bringup", "--fake-room", "--record", ""])
    assert ended.value.code == 2
    assert "the path is empty; name a new directory" in capsys.readouterr().err


def test_a_named_room_keeps_its_own_partner_in_the_demo() -> None:
    """``demo --room office+partner`` has a partner, ``office`` none.

    config/fake_room.yaml's partner of the first 60 s is the responsive room's alone;
    ``--leave-at`` moves the departure.
    """
    from infomax_contingency.cli.demo import _nodes, register_demo
    from infomax_contingency.cli.demo_checks import check_arguments

    def parse(room: str, *leave_at: str) -> argparse.Namespace:
        parser = argparse.ArgumentParser()
        register_demo(parser.add_subparsers())
        leave = ("--leave-at", *leave_at) if leave_at else ()
        return parser.parse_args(["demo", "--room", room, *leave])

    def schedule(room: str, *leave_at: str) -> tuple[float, float]:
        times = _nodes(parse(room, *leave_at))[0]["fake_audio_node"]
        return times["partner_arrive_s"], times["partner_leave_s"]

    assert schedule("responsive") == (0.0, 60.0)
    assert schedule("responsive", "-1") == (0.0, -1.0)
    assert schedule("office") == (-1.0, -1.0)
    assert schedule("silent") == (-1.0, -1.0)
    assert schedule("office+partner") == (0.0, -1.0)
    assert schedule("playroom+arriving") == (20.0, -1.0)
    assert schedule("dog-home+leaving") == (0.0, 20.0)
    assert schedule("office+partner", "30") == (0.0, 30.0)
    with pytest.raises(ValueError, match="--leave-at 10 in room office\\+arriving: room parameter"
                       " partner_leave_s = 10.0: must be > partner_arrive_s"):
        check_arguments(parse("office+arriving", "10"))

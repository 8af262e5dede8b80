"""The layout a real ROS 2 install uses: colcon build, ``ros2 run``, ``ros2 launch``.

``ros2 run PKG EXE`` is: find the package prefix in the ament index, then exec
``<prefix>/lib/PKG/EXE``. The test takes the run's colcon build of the package
(``colcon_workspace``), resolves three executables exactly that way, starts them with the install's
Python path (as ``. install/setup.sh`` would), and reads ``belief`` from this process,
as ``ros2 topic echo /belief`` would. Where ``ros2`` is not on PATH, it then starts two
graphs in namespaces /robot1 and /robot2 from the installed config/robot.yaml side by
side and checks that robot2's beliefs equal those of the graph alone (no cross-talk);
where it is, test_launch.py checks that with the real launch files. The launch file is
checked statically here; test_launch.py runs it with the real ``ros2``.
"""

from __future__ import annotations

import ast
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
import yaml

from infomax_contingency.testing.graph import (
    GraphProcesses,
    SpinThread,
    StepRecorder,
    start_graph,
    wait_until,
)

ROOT = Path(__file__).resolve().parent.parent
PKG = "infomax_contingency"
WAV = ROOT / "test" / "data" / "interaction.wav"


@pytest.mark.slow
def test_ros2_run_layout_runs_the_graph(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, colcon_workspace: Path
) -> None:
    install = colcon_workspace / "install" / PKG
    monkeypatch.setenv("AMENT_PREFIX_PATH", os.pathsep.join((str(install), sys.prefix)))
    from ament_index_python.packages import get_package_prefix

    prefix = Path(get_package_prefix(PKG))
    assert prefix == install
    site_packages = next(prefix.glob("lib/python3*/site-packages"))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(site_packages), env.get("PYTHONPATH")) if p)

    def ros2_run(node: str) -> list[str]:
        executable = prefix / "lib" / PKG / node
        assert executable.is_file() and os.access(executable, os.X_OK), executable
        return [str(executable)]

    processes = GraphProcesses(tmp_path / "run", env=env, executable=ros2_run)
    rclpy.init()
    recorder = StepRecorder("belief_echo", instrument=True)
    try:
        with SpinThread(recorder):
            mic = {"source": "wav", "wav_file": str(WAV), "exit_at_end": True}
            mic["wait_for_listeners"] = 3
            nodes = {"controller_node": {}, "belief_node": {"memory_steps": 0}, "mic_node": mic}
            start_graph(processes, recorder, nodes, "mic_node", timeout_s=120.0)
            assert processes.processes["mic_node"].wait(timeout=120) == 0, processes.report()
            steps = len(recorder.sound)
            # 18 s of audio in 0.5 s windows; the default bit source first hears the room
            # (8 windows of warm-up, 4 more of its threshold's delay)
            assert steps == 36 - 12
            processes.stop_all()
    finally:
        processes.stop_all()
        recorder.destroy_node()
        rclpy.try_shutdown()
    assert len(recorder.belief) == steps and all(0.0 < b < 1.0 for b in recorder.belief)
    # The nodes ran the installed code and found the installed data files.
    share = prefix / "share" / PKG
    assert f"policy {share}/policies/robot_receding_H24_M60.npz" in processes.log("controller_node")
    if shutil.which("ros2") is None:
        # Where ros2 is on PATH, test_launch.py checks the same with the real launch files
        # (test_two_robots_in_namespaces_have_their_own_topics_and_do_not_cross_talk).
        beside = two_namespaced_graphs(tmp_path / "two", env, prefix, steps)
        assert beside == recorder.belief  # robot2 beside robot1 equals the graph alone


OPTIONAL_MODULES = ("rosbags", "mcap", "mcap_ros2", "webrtcvad")
"""Modules of pip packages a robot may lack after a plain ``colcon build``: sessions
(rosbags), the tests' bag readers (mcap) and the vad bit source (webrtcvad)."""


def without_optional_modules(directory: Path) -> Path:
    """A directory that, first on PYTHONPATH, makes :data:`OPTIONAL_MODULES` missing."""
    for module in OPTIONAL_MODULES:
        (directory / module).mkdir(parents=True)
        (directory / module / "__init__.py").write_text(
            f"raise ModuleNotFoundError(\"No module named '{module}'\", name='{module}')\n"
        )
    return directory


@pytest.mark.slow
def test_the_command_line_through_ros2_run_without_optional_packages(
    tmp_path: Path, colcon_workspace: Path
) -> None:
    """``ros2 run infomax_contingency infomax-contingency``: help, and one line for a bag.

    With ``ros2`` on PATH the real ``ros2 run`` after ``. install/setup.sh``; without, what
    it does (the package prefix from the ament index, then exec ``lib/PKG/EXE``).
    """
    blocked = without_optional_modules(tmp_path / "blocked")
    install = colcon_workspace / "install"
    ros2 = shutil.which("ros2")

    def run(arguments: str) -> subprocess.CompletedProcess:
        if ros2 is not None:
            env_script = Path(ros2).resolve().parent.parent / "ros2-env.sh"
            setup = f". {env_script} && " if env_script.is_file() else ""
            command = (f"{setup}. {install}/setup.sh && PYTHONPATH={blocked}:$PYTHONPATH"
                       f" exec ros2 run {PKG} infomax-contingency {arguments}")
        else:
            prefix = install / PKG
            site_packages = next(prefix.glob("lib/python3*/site-packages"))
            command = (f"AMENT_PREFIX_PATH={prefix}:$AMENT_PREFIX_PATH"
                       f" PYTHONPATH={blocked}:{site_packages}:$PYTHONPATH"
                       f" exec {prefix}/lib/{PKG}/infomax-contingency {arguments}")
        return subprocess.run(["bash", "-c", command], capture_output=True, text=True,
                              timeout=120)  # fmt: skip

    helped = run("--help")
    assert helped.returncode == 0 and "usage: infomax-contingency" in helped.stdout, helped
    replayed = run(f"replay {tmp_path}")
    assert replayed.returncode == 2, replayed
    assert replayed.stderr.strip().splitlines() == [
        "infomax-contingency replay: error: recording or reading a session (rosbag2 bag) needs"
        " the Python package 'rosbags', which is not installed: pip install rosbags; rosdep"
        " key python3-rosbags-pip"
    ]


def two_namespaced_graphs(workdir: Path, env: dict, prefix: Path, steps: int) -> list[float]:
    """Graphs /robot1 and /robot2 from the installed config/robot.yaml; robot2's beliefs."""
    workdir.mkdir()
    config = prefix / "share" / PKG / "config" / "robot.yaml"
    overrides = {
        "mic_node": {"source": "wav", "wav_file": str(WAV), "exit_at_end": True},
        "belief_node": {"memory_steps": 0},
    }
    processes: list[subprocess.Popen] = []
    rclpy.init()
    recorder = StepRecorder("robot2_echo", namespace="robot2", instrument=True)
    try:
        with SpinThread(recorder):
            for robot, listeners in (("robot1", 2), ("robot2", 3)):
                for node in ("controller_node", "belief_node", "mic_node"):
                    command = [str(prefix / "lib" / PKG / node), "--ros-args", "-r"]
                    command += [f"__ns:=/{robot}", "--params-file", str(config)]
                    values = dict(overrides.get(node, {}))
                    if node == "mic_node":
                        values["wait_for_listeners"] = listeners
                    # A later file's /**/node: section overrides the installed config's.
                    path = workdir / f"{robot}.{node}.yaml"
                    path.write_text(yaml.safe_dump({f"/**/{node}": {"ros__parameters": values}}))
                    command += ["--params-file", str(path)]
                    log = (workdir / f"{robot}.{node}.log").open("wb")
                    processes.append(
                        subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT)
                    )
            mics = [p for p in processes if p.args[0].endswith("mic_node")]
            for mic in mics:
                assert mic.wait(timeout=120) == 0, sorted(p.name for p in workdir.iterdir())
            assert wait_until(lambda: len(recorder.belief) >= steps, 120.0), "robot2: beliefs"
    finally:
        for process in processes:
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process in processes:
            process.wait(timeout=30)
        recorder.destroy_node()
        rclpy.try_shutdown()
    assert len(recorder.sound_step) == steps
    return list(recorder.belief)


def test_launch_file_starts_the_installed_executables_with_installed_config() -> None:
    path = ROOT / "launch" / "contingency.launch.py"
    tree = ast.parse(path.read_text(), filename=str(path))
    compile(tree, str(path), "exec")
    functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert "generate_launch_description" in functions
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)}
    started = {s for s in strings if isinstance(s, str) and s.endswith("_node") and " " not in s}
    graph = {"mic_node", "fake_audio_node", "controller_node", "belief_node", "posture_node"}
    assert started - {"recorder_node"} == graph | {"speaker_node"}
    setup = (ROOT / "setup.py").read_text()
    for executable in started - {"recorder_node"}:  # recorder_node: only with record:=true
        assert f'"{executable} = {PKG}.nodes.entry:{executable}"' in setup
    for config in ("robot.yaml", "fake_room.yaml"):
        assert config in strings and (ROOT / "config" / config).is_file()
    # The nodes end with the launch: the variable they read (not imported by the file).
    from infomax_contingency.nodes.runtime import PARENT_PID_VARIABLE, STOP_DEADLINE_S

    assert PARENT_PID_VARIABLE in strings
    # ... and are killed only after their own stop deadline (also not imported)
    assert STOP_DEADLINE_S in strings

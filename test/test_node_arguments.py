"""Command lines of the nodes: bad arguments, and a stop while a node loads.

Malformed --ros-args end a node with one line and status 2, not a traceback; a stop signal
while a node is still loading ends it quietly.
"""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from infomax_contingency import lifetime
from infomax_contingency.nodes import entry, runtime


@pytest.mark.parametrize("module", ["belief_node", "bringup"])
def test_malformed_ros_arguments(module: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", f"infomax_contingency.nodes.{module}", "--ros-args", "-p", "x:="],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert f"{module}: invalid ROS arguments" in result.stderr
    assert "x:=" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_while_a_node_loads_ends_it_with_status_0_and_no_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, signum: int
) -> None:
    """The console scripts' entry: the signal comes while the node's module is imported."""
    (tmp_path / "loading_node.py").write_text(
        "import os, signal\n"
        f"os.kill(os.getpid(), {int(signum)})  # stopped while loading\n"
        "def main():\n    raise AssertionError('main() must not run')\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    before = {s: signal.getsignal(s) for s in entry.STOP_SIGNALS}
    try:
        with pytest.raises(SystemExit) as stop:
            entry.run_module("loading_node")
        assert stop.value.code == 0
        # The process is ending: a second stop signal (the terminal's Ctrl-C and ros2
        # launch's both reach a node) is ignored, not a KeyboardInterrupt on the way out.
        assert all(signal.getsignal(s) == signal.SIG_IGN for s in entry.STOP_SIGNALS)
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)


def test_a_stop_whose_exit_is_lost_while_a_node_loads_still_ends_it_quietly(
    tmp_path: Path,
) -> None:
    """Python cannot raise from a ``__del__`` or a weakref callback, and importlib runs such.

    A Ctrl-C handled there lost its ``SystemExit``: the node printed "Exception ignored
    in ... Traceback" and went on starting (seen once in a launch stopped at start-up).
    """
    (tmp_path / "loading_node.py").write_text(
        "import os, signal\n"
        "class Stopper:\n"
        "    def __del__(self):\n"
        "        os.kill(os.getpid(), signal.SIGINT)\n"
        "        sum(range(1000))  # the handler runs here, inside __del__\n"
        "Stopper()\n"
        "def main():\n    print('main ran', flush=True)\n    return 3\n"
    )
    program = (
        f"import sys; sys.path.insert(0, {str(tmp_path)!r})\n"
        "from infomax_contingency.nodes import entry\n"
        "sys.exit(entry.run_module('loading_node'))\n"
    )
    result = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True,
                            timeout=60)  # fmt: skip
    assert (result.returncode, result.stdout, result.stderr) == (0, "", "")


def test_a_stop_lost_before_main_took_the_signals_is_a_stop_requested(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A lost stop inside ``main()``, before its StopSignals: the node stops at once.

    The entry module may run as ``__main__`` (``python -m``) beside a second copy that the
    node's modules import: the stop is noted where both copies see it.
    """
    monkeypatch.setattr(lifetime, "_stop_while_starting", [False])  # the original kept as it is
    spec = importlib.util.spec_from_file_location("entry_as_main", entry.__file__)
    entry_as_main = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(entry_as_main)
    before = {s: signal.getsignal(s) for s in entry.STOP_SIGNALS}
    try:
        with pytest.raises(SystemExit):
            entry_as_main._stopped_while_starting(signal.SIGINT, None)
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)
    assert lifetime.stop_came_while_starting()
    ended: list[tuple[str, float]] = []
    stop = runtime.StopSignals("probe", deadline_s=0.05,
                               on_deadline=lambda *named: ended.append(named))  # fmt: skip
    try:
        stop.install()
        assert stop.requested and stop.stopping_since is not None
    finally:
        stop.restore()
        stop._watchdog.join(30)
    assert ended == [("probe", 0.05)]


def test_a_node_that_ends_ignoring_stop_signals_keeps_ignoring_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A node's ``main()`` ends ignoring SIGINT and SIGTERM; the entry must not undo that.

    ``ros2 launch`` and a terminal's Ctrl-C both send SIGINT: the second one can land
    while the interpreter shuts down, and the default handler would raise a
    KeyboardInterrupt traceback there.
    """
    (tmp_path / "ending_node.py").write_text(
        "import signal\n"
        "def main():\n"
        "    for signum in (signal.SIGINT, signal.SIGTERM):\n"
        "        signal.signal(signum, signal.SIG_IGN)  # as StopSignals.ignore_from_now_on\n"
        "    return 0\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    before = {s: signal.getsignal(s) for s in entry.STOP_SIGNALS}
    try:
        assert entry.run_module("ending_node") == 0
        assert all(signal.getsignal(s) == signal.SIG_IGN for s in entry.STOP_SIGNALS)
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)


def test_the_stop_deadline_starts_once_with_the_first_stop(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Nothing happens before a stop; the first stop (not a later one) starts the deadline."""
    monkeypatch.setattr(runtime, "DEADLINE_POLL_S", 0.01)
    ended: list[tuple[str, float]] = []
    armed: list[float] = []
    stop = runtime.StopSignals("probe", deadline_s=0.3,
                               on_deadline=lambda *named: ended.append(named),
                               arm_hard_deadline=armed.append)  # fmt: skip
    stop._watchdog.start()  # as install() does, without taking over this process's signals
    stop._watchdog.join(0.5)
    assert stop._watchdog.is_alive() and not ended  # no stop yet: no deadline
    stop._handle(signal.SIGTERM, None)
    began = stop.stopping_since
    stop._handle(signal.SIGINT, None)
    assert not armed  # a signal handler only sets flags
    stop.arm_stop_deadline()
    stop.arm_stop_deadline()
    assert stop.requested and stop.stopping_since == began
    assert len(armed) == 1 and 0 < armed[0] <= 0.3 + runtime.HARD_DEADLINE_MARGIN_S
    stop._watchdog.join(30)
    assert not stop._watchdog.is_alive() and ended == [("probe", 0.3)]


def _stuck_process(program: str, stop_signal: int | None = None, stderr_closed: bool = False
                   ) -> tuple[int, str]:  # fmt: skip
    """Run ``program`` (``-c``), send ``stop_signal`` once it printed "ready": status, stderr.

    ``stderr_closed``: the program starts without a standard error (``2>&-``; "" returned).
    """
    process = subprocess.Popen(
        [sys.executable, "-c", program], stdout=subprocess.PIPE, text=True,
        stderr=None if stderr_closed else subprocess.PIPE,
        preexec_fn=(lambda: os.close(2)) if stderr_closed else None,
    )  # fmt: skip
    try:
        if stop_signal is not None:
            assert process.stdout.readline() == "ready\n"
            process.send_signal(stop_signal)
        _, err = process.communicate(timeout=60)
        err = err or ""
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    return process.returncode, err


def test_a_node_process_stuck_after_its_stop_signal_ends_by_the_deadline() -> None:
    """A process whose stop hangs (a DDS teardown on a loaded machine) still ends, in one line.

    Before, a node stuck there outlived a demo killed with SIGKILL, and a launch waited on it.
    """
    program = (
        "import time\n"
        "from infomax_contingency.nodes import runtime\n"
        "stop = runtime.StopSignals('stuck_node', deadline_s=1.0).install()\n"
        "print('ready', flush=True)\n"
        "while True:\n"
        "    time.sleep(0.05)  # the stop hangs: requested is never looked at\n"
    )
    status, err = _stuck_process(program, stop_signal=signal.SIGTERM)
    assert status == 1
    assert err == "stuck_node: not stopped 1 s after the stop signal; ending now\n"


def test_a_node_process_whose_teardown_holds_the_interpreter_still_ends() -> None:
    """A stop stuck in a C call that keeps the interpreter still ends, with its stacks.

    The deadline's own thread never runs then; the hard deadline ends it, status 1. A
    launch once waited for ever on a belief_node after its stop signal: one way is this.
    """
    program = (
        "import ctypes\n"
        "from infomax_contingency.nodes import runtime\n"
        "runtime.HARD_DEADLINE_MARGIN_S = 1.0\n"
        "stop = runtime.StopSignals('stuck_node', deadline_s=1.0).install()\n"
        "stop.arm_stop_deadline()  # the spin ended; the teardown begins and hangs\n"
        "ctypes.PyDLL(None).sleep(120)  # libc's sleep, the interpreter held throughout\n"
    )
    status, err = _stuck_process(program)
    assert status == 1
    assert err.startswith("Timeout (0:00:0") and "line 6 in <module>" in err, err  # ~2 s


def test_a_start_that_never_spins_ends_by_the_start_deadline(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Nodes not spinning by the start deadline end the process; spinning, nothing happens."""
    monkeypatch.setattr(runtime, "DEADLINE_POLL_S", 0.01)
    ended: list[tuple[str, float]] = []
    armed: list[float] = []
    stop = runtime.StopSignals("probe", start_deadline_s=0.2, arm_hard_deadline=armed.append,
                               on_start_deadline=lambda *named: ended.append(named))  # fmt: skip
    before = {s: signal.getsignal(s) for s in entry.STOP_SIGNALS}
    try:
        stop.install()
    finally:
        for signum, handler in before.items():  # not restore(): that ends the start deadline
            signal.signal(signum, handler)
    assert armed == [0.2 + runtime.HARD_DEADLINE_MARGIN_S]
    stop._watchdog.join(30)
    assert not stop._watchdog.is_alive() and ended == [("probe", 0.2)]

    spun = runtime.StopSignals("probe", start_deadline_s=0.2, arm_hard_deadline=armed.append,
                               on_start_deadline=lambda *named: ended.append(named))  # fmt: skip
    spun.starting_since = runtime.time.monotonic()  # as install() does
    spun.spinning()
    spun._watchdog.start()
    spun._watchdog.join(0.5)
    assert spun._watchdog.is_alive() and len(ended) == 1  # no start deadline once spinning
    assert armed[-1] < 0  # the hard one cancelled


def test_a_stop_while_starting_is_left_to_the_stop_deadline(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A stop signal during a start hands the process to the stop deadline, not the start's.

    The one that needs no interpreter too: armed for the start, it is armed again for the
    stop (before, a start slower than the start deadline ended with faulthandler's stacks
    even though a stop signal had come).
    """
    monkeypatch.setattr(runtime, "DEADLINE_POLL_S", 0.01)
    ended: list[str] = []
    armed: list[float] = []
    stop = runtime.StopSignals("probe", deadline_s=0.3, arm_hard_deadline=armed.append,
                               on_deadline=lambda *named: ended.append("stop"),
                               start_deadline_s=0.2,
                               on_start_deadline=lambda *named: ended.append("start"))  # fmt: skip
    stop.starting_since = runtime.time.monotonic()  # as install() does, but for the signals
    armed.append(0.2 + runtime.HARD_DEADLINE_MARGIN_S)  # (install() arms this one)
    stop._handle(signal.SIGTERM, None)
    stop._watchdog.start()
    stop._watchdog.join(30)
    assert ended == ["stop"]
    assert len(armed) == 2 and 0 < armed[1] <= 0.3 + runtime.HARD_DEADLINE_MARGIN_S
    stop.spinning()  # the creation returns after all: the stop's hard deadline stays
    assert len(armed) == 2


START_HANGS = (
    "import sys, time, ctypes\n"
    "from infomax_contingency.nodes import runtime\n"
    "runtime.START_DEADLINE_S = 1.0\n"
    "runtime.HARD_DEADLINE_MARGIN_S = {margin}\n"
    "{patch}\n"
    "def factory():\n"
    "    {hang}\n"
    "sys.exit(runtime.run_nodes([('stuck_node', factory)], 'stuck_node', []))\n"
)
"""A node process whose node creation never returns (``{hang}``: how), after ``rclpy.init``;
``{margin}``: faulthandler's, s, after the start deadline of 1 s; ``{patch}``: a line run
first."""


def test_a_node_whose_creation_never_returns_ends_by_the_start_deadline() -> None:
    """A node stuck in its creation (once seen in Fast DDS) ends in one line, status 1.

    Before, it never spun and never ended: a launch waited on it until stopped.
    """
    # faulthandler's deadline far behind the watchdog's, however slowly a loaded machine runs it
    program = START_HANGS.format(hang="time.sleep(120)", margin=30.0, patch="")
    status, err = _stuck_process(program)
    assert status == 1
    assert err.startswith("stuck_node: not started within 1 s (creating its node did not"), err
    assert err.count("\n") == 1, err


SPINS_PAST_THE_START_DEADLINE = (
    "import sys\n"
    "from rclpy.node import Node\n"
    "from infomax_contingency.nodes import runtime\n"
    "runtime.START_DEADLINE_S = 5.0  # a start on a loaded machine takes a few seconds\n"
    "runtime.HARD_DEADLINE_MARGIN_S = 1.0\n"
    "def factory():\n"
    "    node = Node('spinning_node')\n"
    "    node.create_timer(6.5, lambda: print('ready', flush=True))  # past both\n"
    "    return node\n"
    "sys.exit(runtime.run_nodes([('spinning_node', factory)], 'spinning_node', []))\n"
)
"""A node process that prints "ready" once it has spun past both start deadlines."""


def test_a_node_that_spins_past_the_start_deadline_runs_on_and_stops_cleanly() -> None:
    """Once spinning, neither start deadline (the watchdog's, faulthandler's) applies."""
    status, err = _stuck_process(SPINS_PAST_THE_START_DEADLINE, stop_signal=signal.SIGINT)
    assert status == 0, err
    assert "not started" not in err and "Timeout" not in err, err


def test_a_node_started_without_a_standard_error_runs_and_stops_cleanly() -> None:
    """``2>&-``: the deadlines that need no interpreter have nowhere to write; no matter."""
    status, _ = _stuck_process(SPINS_PAST_THE_START_DEADLINE, stop_signal=signal.SIGINT,
                               stderr_closed=True)  # fmt: skip
    assert status == 0


def test_a_node_whose_creation_holds_the_interpreter_still_ends() -> None:
    """Node creation stuck in a C call that keeps the interpreter: the stacks, status 1."""
    # the watchdog's line held back, so that a slow rclpy.init cannot end it first; the
    # stacks 6 s after the start, the factory surely holding the interpreter by then
    program = START_HANGS.format(hang="ctypes.PyDLL(None).sleep(120)", margin=5.0,
                                 patch="runtime._not_started = lambda *args: None")  # fmt: skip
    status, err = _stuck_process(program)
    assert status == 1
    assert err.startswith("Timeout (0:00:0") and "in factory" in err, err  # ~2 s


def test_the_entry_module_names_its_nodes_when_asked_for_another() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "infomax_contingency.nodes.entry", "no_such_node"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 2 and "mic_node" in result.stderr
    assert "Traceback" not in result.stderr


def test_a_node_that_needs_a_missing_optional_package_ends_in_one_line(tmp_path: Path) -> None:
    """recorder_node without ``rosbags``: one ERROR line naming the package, status 2.

    As after a plain ``colcon build`` without rosdep; a launch with ``record:=true`` then
    stops, naming the recorder.
    """
    (tmp_path / "rosbags").mkdir()
    (tmp_path / "rosbags" / "__init__.py").write_text(
        "raise ModuleNotFoundError(\"No module named 'rosbags'\", name='rosbags')\n"
    )
    path = os.pathsep.join(p for p in (str(tmp_path), os.environ.get("PYTHONPATH")) if p)
    result = subprocess.run(
        [sys.executable, "-m", "infomax_contingency.nodes.entry", "recorder_node"],
        capture_output=True, text=True, timeout=60, env={**os.environ, "PYTHONPATH": path},
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "[ERROR]" in lines[0] and "[recorder_node]: " in lines[0], lines
    assert lines[0].endswith("needs the Python package 'rosbags', which is not installed: pip"
                             " install rosbags; rosdep key python3-rosbags-pip")  # fmt: skip


@pytest.mark.parametrize(("chosen", "threads"), [({}, 1), ({"OPENBLAS_NUM_THREADS": "2"}, 2)])
def test_a_node_has_one_blas_thread_unless_its_user_chose_a_count(
    tmp_path: Path, chosen: dict[str, str], threads: int
) -> None:
    """Threads of a node process once numpy is loaded: the main one, and BLAS threads.

    numpy's OpenBLAS starts its threads when numpy is imported; with one, it starts none.
    It never starts more than the machine has cores, so two need two.
    """
    if threads > (os.cpu_count() or 1):
        pytest.skip(f"OpenBLAS starts at most a thread per core; here: {os.cpu_count()}")
    (tmp_path / "counting_node.py").write_text(
        "import os\n"
        "def main():\n"
        "    import numpy  # noqa: F401\n"
        "    print(len(os.listdir('/proc/self/task')))\n"
        "    return 0\n"
    )
    environment = {key: value for key, value in os.environ.items()
                   if key not in entry.BLAS_THREAD_VARIABLES}  # fmt: skip
    result = subprocess.run(
        [sys.executable, "-c", "import sys; from infomax_contingency.nodes import entry; "
         f"sys.path.insert(0, {str(tmp_path)!r}); sys.exit(entry.run_module('counting_node'))"],
        capture_output=True, text=True, timeout=60, env={**environment, **chosen},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert int(result.stdout) == threads


def test_the_blas_thread_count_a_user_chose_is_kept() -> None:
    for name in entry.BLAS_THREAD_VARIABLES:
        environment = {name: "4"}
        entry.use_one_blas_thread(environment)
        assert environment == {name: "4"}
    environment = {"OMP_NUM_THREADS": " "}  # set but empty: not a choice
    entry.use_one_blas_thread(environment)
    assert environment["OPENBLAS_NUM_THREADS"] == "1"


def test_a_node_whose_parent_died_while_it_loaded_does_not_start() -> None:
    """The parent named by the harness (or the demo) died before the node could follow it.

    The node sets its parent-death signal only once loaded; a parent gone by then cannot
    send it, so the node checks and ends at once, instead of running as an orphan.
    """
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    env = {**os.environ, runtime.PARENT_PID_VARIABLE: str(gone.pid)}
    result = subprocess.run(
        [sys.executable, "-m", "infomax_contingency.nodes.entry", "posture_node"],
        capture_output=True, text=True, timeout=60, env=env,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stderr.strip() == (
        "posture_node: the process that started it is gone; not starting"
    )

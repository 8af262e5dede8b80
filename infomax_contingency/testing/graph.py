"""Run the node graph as separate processes and watch it: for the demo, tests and benchmarks.

* :class:`GraphProcesses` starts nodes as child processes (by default ``python -m
  infomax_contingency.nodes.<node>``, the same code as the console scripts), with their
  parameters in one ROS parameter file, their output in log files, and stops them with
  SIGINT (then SIGTERM, then SIGKILL). They end when this process dies, however it dies
  (SIGKILL included: :func:`~infomax_contingency.nodes.runtime.end_with_parent`).
* :class:`StepRecorder` is a node that records the step-clock topics (``sound``,
  ``sound_step``, ``sound_energy``, ``vocalize``, ``vocalize_step``, ``belief``,
  ``posture``, ``partner_present``) with the
  time each message arrived and the time it was published.

This module imports rclpy; the callers set ``ROS_AUTOMATIC_DISCOVERY_RANGE`` and
``ROS_DOMAIN_ID`` first.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import yaml
from rclpy.event_handler import SubscriptionEventCallbacks, UnsupportedEventTypeError
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from std_msgs.msg import Bool, Float32, Float32MultiArray, Float64, Int64MultiArray, String

from infomax_contingency.nodes.entry import NODES
from infomax_contingency.nodes.qos import LATCHED_READER_QOS, STREAM_QOS
from infomax_contingency.nodes.runtime import parent_pid_environment

PUBLISHES: dict[str, tuple[str, ...]] = {
    "mic_node": ("sound", "sound_step", "sound_energy"),
    "controller_node": ("vocalize", "vocalize_step"),
    "belief_node": ("belief",),
    "posture_node": ("posture", "joint_targets"),
    "fake_audio_node": ("audio", "partner_present"),
    "speaker_node": (),
    "recorder_node": ("session_info",),
}
"""Topics each node publishes (besides /diagnostics)."""


def instrument_options(**kwargs: Any) -> dict[str, Any]:
    """``Node`` keyword arguments for a node that only watches the graph under test.

    A test's recorder or probe: no parameter services and no type-description service
    (``kwargs`` may add parameter overrides). An executor rebuilds its wait set from every
    service, subscription and QoS event handler of its nodes on each wait, and a test's
    hand-stepped graph waits a few times per step: the recorder's seven services and the
    default QoS event handlers of its subscriptions were about 12 % of such a graph's CPU.
    Nobody asks a test's instrument for its parameters; the nodes under test keep theirs.
    """
    overrides = [*kwargs.pop("parameter_overrides", ()),
                 Parameter("start_type_description_service", value=False)]  # fmt: skip
    return {**kwargs, "start_parameter_services": False, "parameter_overrides": overrides}


class GraphError(RuntimeError):
    """The graph did not come up, or a node died; the message holds the nodes' logs."""


class GraphProcesses:
    """Node processes started from this process; :meth:`stop_all` ends them.

    Args:
        workdir: where the parameter files and the nodes' log files go.
        env: environment of the children (default: this process's).
        executable: the command that runs a node, given its name (default:
            ``python -m infomax_contingency.nodes.entry <node>`` with this interpreter, as
            the console scripts run it: quiet when stopped while it starts).
        parameter_files: ROS parameter files every node reads first (e.g.
            ``config/robot.yaml``); the parameters given to :meth:`start` override them.
        own_process_group: start every node in a process group of its own, so a Ctrl-C
            in the terminal reaches only this process, which then stops the nodes itself
            (the demo); default: the nodes share this process's group.

    Every node ends when this process dies, however it dies (a SIGKILL, an OOM kill, a
    CI timeout): it gets SIGTERM from the kernel (``env`` names this process as its
    parent, :func:`~infomax_contingency.nodes.runtime.end_with_parent`). Start the nodes
    from a thread that lives as long as they should: the kernel takes the end of the
    thread that started a process for its parent's death.
    """

    def __init__(
        self,
        workdir: str | Path,
        env: Mapping[str, str] | None = None,
        executable: Callable[[str], list[str]] | None = None,
        parameter_files: list[str | Path] | None = None,
        own_process_group: bool = False,
    ) -> None:
        self.own_process_group = own_process_group
        self.parameter_files = [str(path) for path in parameter_files or []]
        self.executable = executable or (
            lambda node: [sys.executable, "-m", "infomax_contingency.nodes.entry", node]
        )
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.env = parent_pid_environment(dict(os.environ if env is None else env))
        self.processes: dict[str, subprocess.Popen] = {}
        self.stopped: set[str] = set()
        """Nodes stopped on purpose (not reported by :meth:`dead`)."""
        self._starts = 0

    def command(
        self, node: str, parameters: Mapping[str, Any], name: str | None = None
    ) -> list[str]:
        """The command line of ``node`` with ``parameters`` in a fresh parameter file.

        ``name`` renames the node (``-r __node:=name``): a second instance of a node.
        """
        if node not in NODES:
            raise ValueError(f"unknown node {node!r}; nodes: {', '.join(NODES)}")
        self._starts += 1
        name = name or node
        path = self.workdir / f"{name}.{self._starts}.params.yaml"
        path.write_text(yaml.safe_dump({name: {"ros__parameters": dict(parameters)}}))
        files = [arg for file in (*self.parameter_files, path) for arg in ("--params-file", file)]
        rename = ["-r", f"__node:={name}"] if name != node else []
        return [*self.executable(node), "--ros-args", *map(str, files), *rename]

    def start(
        self, node: str, parameters: Mapping[str, Any] | None = None, name: str | None = None
    ) -> subprocess.Popen:
        """Start ``node`` (as ``name``, default its own; replacing a stopped process)."""
        name = name or node
        if name in self.processes and self.processes[name].poll() is None:
            raise RuntimeError(f"{name} is already running")
        command = self.command(node, parameters or {}, name)
        log = (self.workdir / f"{name}.log").open("ab")
        process = subprocess.Popen(
            command,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            env=self.env,
            start_new_session=self.own_process_group,
        )
        log.close()
        self.processes[name] = process
        self.stopped.discard(name)
        return process

    def kill(self, name: str) -> None:
        """Kill ``name`` with SIGKILL (no clean-up: a crash) and wait for it."""
        process = self.processes[name]
        self.stopped.add(name)
        process.kill()
        process.wait()

    def log(self, node: str) -> str:
        """What the node printed so far."""
        path = self.workdir / f"{node}.log"
        return path.read_text(errors="replace") if path.exists() else ""

    def dead(self) -> dict[str, int]:
        """Nodes that exited without being stopped, with their exit status."""
        return {
            name: process.returncode
            for name, process in self.processes.items()
            if process.poll() is not None and name not in self.stopped
        }

    def report(self) -> str:
        """Exit statuses and last log lines of the nodes that exited."""
        lines = []
        for name, status in self.dead().items():
            tail = "\n    ".join(self.log(name).strip().splitlines()[-8:])
            lines.append(f"{name} exited with status {status}:\n    {tail}")
        return "\n".join(lines) or "all nodes are running"

    def stop(self, node: str, timeout_s: float = 10.0) -> int | None:
        """Stop one node: SIGINT, then SIGTERM, then SIGKILL; returns its exit status."""
        process = self.processes.get(node)
        if process is None:
            return None
        self.stopped.add(node)
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if process.poll() is not None:
                break
            process.send_signal(sig)
            try:
                process.wait(timeout=timeout_s / 2 if sig != signal.SIGKILL else None)
            except subprocess.TimeoutExpired:
                continue
        return process.returncode

    def stop_all(self, timeout_s: float = 12.0) -> dict[str, int | None]:
        """Stop every node within about ``timeout_s``; returns their exit statuses.

        All running nodes get SIGINT at once; those still running after half of
        ``timeout_s`` get SIGTERM, and after three quarters SIGKILL. Every process is
        waited for (reaped), so none is left behind.
        """
        self.stopped.update(self.processes)
        start = time.monotonic()
        for sig, until in ((signal.SIGINT, 0.5), (signal.SIGTERM, 0.75), (signal.SIGKILL, None)):
            running = [p for p in self.processes.values() if p.poll() is None]
            for process in running:
                try:
                    process.send_signal(sig)
                except ProcessLookupError:
                    pass
            deadline = None if until is None else start + until * timeout_s
            for process in running:
                try:
                    wait = None if deadline is None else max(0.0, deadline - time.monotonic())
                    process.wait(timeout=wait)
                except subprocess.TimeoutExpired:
                    pass
        return {name: process.returncode for name, process in self.processes.items()}


class StepRecorder(Node):
    """Records the step-clock topics as they arrive.

    Attributes (lists, in arrival order): ``sound``, ``energy``, ``vocalize``, ``belief``,
    ``partner_present``, ``sound_step``, ``vocalize_step`` and ``no_step`` (tuples of their
    fields),
    ``posture`` (every posture message, with the number of beliefs received before it);
    ``times[topic]``: ``(received, published)`` per message, both system-clock
    nanoseconds (DDS reception and source timestamps).

    ``lost[topic]`` counts the messages DDS reports this recorder lost (its own fault,
    not the graph's: it did not read fast enough for its queue).

    Args:
        name: node name.
        audio: also record the arrival times of the ``audio`` chunks (not their samples).
        stream_qos: QoS of the step-clock subscriptions (default
            :data:`~infomax_contingency.nodes.qos.STREAM_QOS`); e.g. keep-all so that a
            slow reader cannot drop messages.
        step_topics: also record ``sound_step`` and ``vocalize_step`` (a benchmark that
            measures the graph leaves them out: they would load the machine it measures);
            False leaves them to a later :meth:`record_step_topics`.
        instrument: a test's recorder (:func:`instrument_options`): no services, and its
            subscriptions have no default QoS event handlers (rclpy's, which log an
            incompatible QoS or type); it still counts the messages DDS reports lost.
            The demo's monitor keeps both.
    """

    def __init__(
        self,
        name: str = "step_recorder",
        audio: bool = False,
        stream_qos: QoSProfile | None = None,
        step_topics: bool = True,
        instrument: bool = False,
        **kwargs: Any,
    ) -> None:
        super().__init__(name, **(instrument_options(**kwargs) if instrument else kwargs))
        self._instrument = instrument
        stream_qos = stream_qos or STREAM_QOS
        self.lost: dict[str, int] = {}
        self.lock = threading.Lock()
        self.sound: list[bool] = []
        self.energy: list[float] = []
        self.vocalize: list[bool] = []
        self.belief: list[float] = []
        self.partner_present: list[bool] = []
        self.posture: list[tuple[int, str]] = []
        self.sound_step: list[tuple[int, ...]] = []
        self.vocalize_step: list[tuple[int, ...]] = []
        self.no_step: list[tuple[int, ...]] = []
        self.times: dict[str, list[tuple[float, int]]] = {}
        self.on_message: Callable[[str], None] | None = None
        self._stream_qos = stream_qos
        for topic, kind, store, qos in (
            ("sound", Bool, self.sound, stream_qos),
            ("sound_energy", Float32, self.energy, stream_qos),
            ("vocalize", Bool, self.vocalize, stream_qos),
            ("belief", Float64, self.belief, stream_qos),
            ("partner_present", Bool, self.partner_present, stream_qos),
            ("posture", String, None, LATCHED_READER_QOS),
            # recorder_node announces itself here once all its subscriptions exist.
            ("session_info", String, None, LATCHED_READER_QOS),
        ):
            self.times[topic] = []
            self._subscribe(kind, topic, self._recorder(topic, store), qos)
        if step_topics:
            self.record_step_topics()
        if audio:
            self.times["audio"] = []
            self.create_subscription(
                Float32MultiArray, "audio", self._recorder("audio", None), STREAM_QOS,
                event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=not instrument),
            )

    def record_step_topics(self) -> None:
        """Subscribe ``sound_step``, ``vocalize_step`` and ``no_step`` (now, or later).

        mic_node counts the listeners of ``sound_step`` before its first bit: a recorder
        that subscribes it only once its other topics reach it (:meth:`sees`) is counted
        only when it will miss none of the graph's messages.
        """
        steps = (("sound_step", self.sound_step), ("vocalize_step", self.vocalize_step),
                 ("no_step", self.no_step))
        for topic, store in steps:
            self.times[topic] = []
            self._subscribe(Int64MultiArray, topic, self._recorder(topic, store), self._stream_qos)

    def _subscribe(self, kind: Any, topic: str, callback: Callable, qos: QoSProfile) -> None:
        """Subscribe, counting the messages DDS reports lost in ``lost[topic]``."""
        self.lost[topic] = 0

        def on_lost(status: Any) -> None:
            with self.lock:
                self.lost[topic] += int(status.total_count_change)

        defaults = not self._instrument  # rclpy's handlers of an incompatible QoS or type
        try:
            events = SubscriptionEventCallbacks(
                message_lost=on_lost, use_default_callbacks=defaults
            )
            self.create_subscription(kind, topic, callback, qos, event_callbacks=events)
        except UnsupportedEventTypeError:  # a middleware that cannot tell
            events = SubscriptionEventCallbacks(use_default_callbacks=defaults)
            self.create_subscription(kind, topic, callback, qos, event_callbacks=events)

    def _recorder(self, topic: str, store: list | None) -> Callable[[Any, dict], None]:
        def record(msg: Any, info: dict) -> None:
            # When DDS received it (not when this executor got round to it), if known.
            received = int(info.get("received_timestamp", 0)) or time.time_ns()
            with self.lock:
                self.times[topic].append((received, int(info.get("source_timestamp", 0))))
                if topic == "posture":
                    self.posture.append((len(self.belief), msg.data))
                elif isinstance(msg, Int64MultiArray):
                    store.append(tuple(int(v) for v in msg.data))
                elif store is not None:
                    store.append(msg.data)
            if self.on_message is not None:
                self.on_message(topic)

        return record

    def sees(self, nodes: list[str] | tuple[str, ...]) -> bool:
        """True once ``nodes`` are in the graph and their topics reach this recorder."""
        if not set(nodes) <= set(self.get_node_names()):
            return False
        recorded = {sub.topic_name: sub for sub in self.subscriptions}
        for node in nodes:
            for topic in PUBLISHES[node]:
                subscription = recorded.get(self.resolve_topic_name(topic))
                if subscription is not None and subscription.get_publisher_count() == 0:
                    return False
        return True

    @property
    def current_posture(self) -> str | None:
        """The last posture received (None before any)."""
        with self.lock:
            return self.posture[-1][1] if self.posture else None

    def step_windows(self, steps: int) -> list[int]:
        """The window (0, 1, ... of all mic_node made) of each of the first ``steps`` steps.

        Windows said on ``no_step`` (the bit source's warm-up) gave none. In lockstep with
        the fake room, window ``w`` is the room's: its truth is ``partner_present[w]`` and
        its room time ``w * window_s``.
        """
        with self.lock:
            skipped = {window - 1 for _, window in self.no_step}
        windows: list[int] = []
        window = 0
        while len(windows) < steps:
            if window not in skipped:
                windows.append(window)
            window += 1
        return windows

    def counts(self) -> dict[str, int]:
        """Messages received per topic."""
        with self.lock:
            return {topic: len(times) for topic, times in self.times.items()}


class SpinThread:
    """Spins nodes on an executor in a background thread (``with SpinThread(node): ...``)."""

    def __init__(self, *nodes: Node) -> None:
        self.executor = SingleThreadedExecutor()
        for node in nodes:
            self.executor.add_node(node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._stop = threading.Event()

    def _spin(self) -> None:
        while not self._stop.is_set():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except ExternalShutdownException:  # Ctrl-C or SIGTERM: rclpy shut down
                return

    def __enter__(self) -> SpinThread:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.executor.shutdown(timeout_sec=1.0)


def wait_until(
    condition: Callable[[], bool],
    timeout_s: float,
    processes: GraphProcesses | None = None,
    poll_s: float = 0.02,
) -> bool:
    """Poll ``condition`` until it holds (True) or ``timeout_s`` passes (False).

    With ``processes``, stop early (False) as soon as one of them has exited.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        if processes is not None and processes.dead():
            return condition()
        time.sleep(poll_s)
    return condition()


def start_graph(
    processes: GraphProcesses,
    recorder: StepRecorder,
    nodes: Mapping[str, Mapping[str, Any]],
    clock: str,
    timeout_s: float = 60.0,
) -> None:
    """Start ``nodes`` (name -> parameters); the ``clock`` node last.

    The clock node (the fake room, or the mic replaying a file) sets the pace of the
    whole graph, so it starts only once every other node is up and its topics reach the
    recorder: then no node misses the first steps. ``recorder`` must be spinning.

    Raises:
        GraphError: a node exited, or the graph did not connect within ``timeout_s``.
    """
    others = [name for name in nodes if name != clock]
    for name in others:
        processes.start(name, nodes[name])
    if not wait_until(lambda: recorder.sees(others), timeout_s, processes):
        raise GraphError(
            f"the nodes {others} did not connect within {timeout_s} s\n{processes.report()}"
        )
    processes.start(clock, nodes[clock])

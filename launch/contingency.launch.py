"""Start the contingency-detection graph as separate processes (a real ROS 2 install).

    ros2 launch infomax_contingency contingency.launch.py                      # audio on 'audio'
    ros2 launch infomax_contingency contingency.launch.py use_fake_room:=true  # simulated room
    ros2 launch infomax_contingency contingency.launch.py namespace:=robot1 use_fake_room:=true
    ros2 launch infomax_contingency contingency.launch.py params_file:=/path/to/my.yaml

Arguments (``ros2 launch ... --show-args`` lists them):

- ``namespace`` (default empty): every node, topic and private service lives under it
  (``/robot1/belief``, ``/robot1/belief_node/reset``); the shipped configs use
  ``/**/node:`` keys, so they apply in any namespace.
- ``use_fake_room`` (default false): add fake_audio_node, a simulated room, and listen to
  it.
- ``realtime`` (default true): the fake room plays at the speed of the room (one 0.5 s
  window per 0.5 s); false runs lockstep, as fast as the graph answers.
- ``room_seed`` (default empty = fake_room_file's): the simulated room's seed.
- ``log_level`` (default info): debug, info, warn, error or fatal: the level of the
  package's node loggers (``--log-level <namespace>.<node>:=<level>``); rcl, rmw and DDS
  keep their own (INFO), so ``debug`` shows the nodes' debug lines, not ROS internals.
- ``params_file`` (default: the installed config/robot.yaml) is read by every node;
  ``fake_room_file`` (default config/fake_room.yaml) by mic_node and fake_audio_node
  with the fake room.
- ``record`` (default false) / ``record_dir``: true adds this package's recorder_node
  with parameter ``directory`` = ``record_dir`` (default: a new
  ``session_YYYY_MM_DD-HH_MM_SS`` in the current directory, as ``ros2 bag record`` names
  its bags; a ``record_dir`` that exists already is refused and ends the launch);
  mic_node then waits for it as a third listener of ``sound_step`` (and the fake room
  for its ``partner_present``), so the bag holds the session from its first step.
- ``controller`` (default empty: the policy table): ``interval:MIN_S-MAX_S`` makes
  controller_node follow the calibration protocol, sounds at random intervals uniform over
  MIN_S .. MAX_S seconds; with ``record:=true`` that is a calibration session for
  ``infomax-contingency analyze`` (``calibration-session`` does it in one command).

``use_fake_room``, ``realtime`` and ``record`` take ``true`` or ``false``;
any other value ends the launch before a node starts, naming the valid values. An argument
of a mode not chosen (``room_seed`` or ``realtime:=false`` without ``use_fake_room:=true``,
``record_dir`` without ``record:=true``) is ignored, with a WARNING line naming it; so is
an argument this file does not declare (``fake_room:=true``), with the closest one it does.

A node that exits with an error ends the whole launch with a final line naming it; a
Ctrl-C ends it with ``launch interrupted (ctrl-c (SIGINT)): ...``. The nodes start with
SIGINT and SIGTERM blocked (``env --block-signal``, GNU coreutils 9.1 or later; without
it they start as they are) until their entry point takes the signals over, so a Ctrl-C
while their interpreters start waits for that point and ends them quietly, never with a
KeyboardInterrupt traceback from the interpreter's own start-up.
Every node process ends with the launch, however the launch ends (``kill -9``, an OOM
kill, a supervisor's SIGTERM, after which ``ros2 launch`` itself would leave its processes
running): the launch names its own process in ``INFOMAX_CONTINGENCY_PARENT_PID`` and each
node asks the kernel for SIGTERM when its parent dies (``nodes/runtime.end_with_parent``;
a node started under a ``--launch-prefix`` such as gdb ends with the prefix's process).
mic_node ending with status 0 (``max_windows`` bits published, the end of a wav file
with ``exit_at_end``, or a stop signal sent to it alone) stops the other nodes of its
robot with SIGINT, so the launch ends (status 0) once they are done; the last line says
so. Another node that ends with status 0 or by a stop signal while the graph runs (killed
by hand, say) leaves the rest running, as a node restarted by hand joins it again: an
ERROR line names it, what stops working without it, and the command that restarts it.
``multi_robot.launch.py`` starts several robots against several simulated rooms;
``bringup`` runs the same graph in one process.
"""

import difflib
import functools
import os
import re
import signal
import subprocess
import tempfile
import time

import launch.logging
import yaml
from launch.actions import (
    DeclareLaunchArgument,
    EmitEvent,
    LogInfo,
    OpaqueFunction,
    RegisterEventHandler,
)
from launch.event_handlers import OnProcessExit, OnShutdown
from launch.events import Shutdown, matches_action
from launch.events.process import SignalProcess
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchContext, LaunchDescription

PACKAGE = "infomax_contingency"

GRAPH_NODES = ("controller_node", "belief_node", "posture_node", "speaker_node")
"""Nodes started from ``params_file`` (controller_node also reads ``fake_room_file`` with the
fake room); mic_node (and the fake room) are added apart."""

PARENT_PID_VARIABLE = "INFOMAX_CONTINGENCY_PARENT_PID"
"""What names the process a node ends with (``nodes/runtime.PARENT_PID_VARIABLE``; not
imported, so that loading this file loads nothing of the package)."""

STOPS_WORKING = {
    "fake_audio_node": "no audio from the simulated room: mic_node makes no bits",
    "controller_node": "no decisions: the robot stops vocalizing, belief_node stops updating"
                       " and the posture holds",
    "belief_node": "no belief: the posture holds",
    "posture_node": "the posture holds",
    "speaker_node": "the robot makes no sound (its decisions go on unheard)",
    "recorder_node": "the recording stops (the bag holds what came before)",
}
"""What stops working when a node other than mic_node ends while the graph runs."""

NODE_STOP_DEADLINE_S = 20.0
"""Seconds a node takes at most to end after its stop signal (``nodes/runtime.STOP_DEADLINE_S``;
not imported, as above). ``ros2 launch`` escalates a Ctrl-C to SIGTERM after
``sigterm_timeout`` (5 s) and to SIGKILL after ``sigkill_timeout`` more; that wait is this
long, so a node slow to stop on a loaded machine (its stop waits up to 5 s for
acknowledgments and queued samples) finishes its stop, or ends itself with one line,
rather than being killed halfway (seen once: mic_node killed, status -9, under load)."""

BOOLEAN_CHOICES = ["true", "false"]
"""The values of the true/false launch arguments; ``ros2 launch`` refuses any other."""

BLOCK_STOP_SIGNALS = ("env", "--block-signal=INT,TERM")
"""Prefix that starts a node with SIGINT and SIGTERM blocked (GNU env, coreutils >= 9.1);
the node's entry point unblocks them once it handles them (nodes/entry.py)."""


def _is_true(context: LaunchContext, name: str) -> bool:
    return LaunchConfiguration(name).perform(context) == "true"


@functools.cache
def _can_block_signals() -> bool:
    """True where ``env --block-signal`` exists (GNU coreutils 9.1 or later)."""
    try:
        return subprocess.run([*BLOCK_STOP_SIGNALS, "true"], capture_output=True,
                              timeout=10).returncode == 0  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return False


def _prefix(context: LaunchContext, executable: str) -> str:
    """The command put before ``executable``.

    The user's ``--launch-prefix`` where it applies (``--launch-prefix-filter``), else the
    signal-blocking ``env`` where there is one.
    """
    user_prefix = LaunchConfiguration("launch-prefix", default="").perform(context).strip()
    only = LaunchConfiguration("launch-prefix-filter", default="").perform(context)
    if user_prefix and (not only or re.match(only, executable)):
        return user_prefix
    return " ".join(BLOCK_STOP_SIGNALS) if _can_block_signals() else ""


def _room_seed(context: LaunchContext) -> dict:
    """``{"seed": N}`` from ``room_seed:=N``; ``{}`` when empty (fake_room_file's seed)."""
    seed = LaunchConfiguration("room_seed").perform(context).strip()
    if seed and not seed.isdigit():
        raise ValueError(f"room_seed:={seed} is not allowed: a whole number >= 0, or empty for"
                         " the seed of fake_room_file")  # fmt: skip
    return {"seed": int(seed)} if seed else {}


def node_logger(namespace: str, name: str) -> str:
    """The logger name of node ``name`` in ``namespace`` (``robot1.mic_node``), as rcl makes it."""
    return ".".join(part for part in (*namespace.strip("/").split("/"), name) if part)


class _ExitWatch:
    """Watches this robot's node processes: the first failure, mic_node's own end."""

    def __init__(self) -> None:
        self.started = 0
        self.exited = 0
        self.failure = ""
        self.finished = ""
        self.nodes: list = []
        """This robot's node actions (another robot's launch has a watch of its own)."""
        self.mic = None
        self.interrupted = ""
        """The reason of a shutdown the user asked for (Ctrl-C), once it came."""
        self.restart: dict[int, tuple] = {}
        """id of a node action -> how it was started: executable, namespace, parameter files
        and the launch's own values (the command that starts it again: _restart_command)."""

    def on_shutdown(self, event, context: LaunchContext) -> None:
        """Remember a Ctrl-C: the last line then says the launch was interrupted."""
        if getattr(event, "due_to_sigint", False) and not self.failure and not self.finished:
            self.interrupted = event.reason or "ctrl-c (SIGINT)"

    def owns(self, action) -> bool:
        """True for a node process of this robot."""
        return any(action is node for node in self.nodes)

    def on_exit(self, event, context: LaunchContext) -> list:
        """A node that exits with an error ends the launch; the last exit says why.

        mic_node ending by itself (status 0) stops the robot's other nodes with SIGINT.
        """
        self.exited += 1
        actions: list = []
        if event.action is self.mic and event.returncode == 0 and not self.failure:
            if not context.is_shutdown and not self.finished:
                self.finished = (
                    f"{event.action.name} ended with status 0 (max_windows reached, the end of"
                    " its file with exit_at_end, or a stop signal)"
                )
                actions.append(LogInfo(msg=f"{self.finished}: stopping the other nodes"))
                actions += [
                    EmitEvent(
                        event=SignalProcess(
                            signal_number=signal.SIGINT, process_matcher=matches_action(node)
                        )
                    )
                    for node in self.nodes
                    if node is not self.mic
                ]
        if self.finished and not self.failure and self.exited >= self.started:
            actions.append(LogInfo(msg=f"launch ended: {self.finished}"))
        # -2 / -15 / 130 / 143: interrupted, because the launch is stopping (Ctrl-C).
        failed = event.returncode not in (0, None, -2, -15, 130, 143)
        self._say_gone(event, context, failed)
        if failed and not self.failure:
            self.failure = f"{event.action.name} exited with status {event.returncode}"
            if not self.interrupted:
                actions.append(LogInfo(
                    msg=f"{self.failure}: stopping the whole launch (its error is above)"
                ))  # fmt: skip
            if not context.is_shutdown:
                actions.append(EmitEvent(event=Shutdown(reason=self.failure)))
        if self.exited < self.started:
            return actions
        if self.interrupted:
            failed_too = f"; {self.failure} (its error is above)" if self.failure else ""
            actions.append(LogInfo(msg=f"launch interrupted ({self.interrupted}):"
                                       f" {self.started} nodes stopped{failed_too}"))  # fmt: skip
        elif self.failure:  # an exception: launch logs it and exits with status 1
            raise RuntimeError(f"launch stopped: {self.failure} (its error is above)")
        return actions


    def _say_gone(self, event, context: LaunchContext, failed: bool) -> None:
        """ERROR: a node ended while the graph runs (not stopped by the launch); how to restart.

        Not for mic_node (its end stops the robot) nor a failure (it ends the launch).
        """
        if failed or event.action is self.mic or context.is_shutdown or self.finished:
            return
        if self.failure or self.interrupted:
            return  # the launch is stopping: every node ends
        executable = event.action.name.rsplit("-", 1)[0]
        started = self.restart.get(id(event.action))
        command = _restart_command(*started) if started else f"`{executable}`"
        launch.logging.get_logger("launch").error(
            f"{event.action.name} ended (status {event.returncode}) while the graph runs:"
            f" {STOPS_WORKING.get(executable, 'its part of the graph stops')}. The other nodes"
            f" run on; restart it with {command}, or relaunch"
        )


_WATCH = _ExitWatch()


def _restart_command(executable: str, namespace: str, files: list[str], values: dict) -> str:
    """The ``ros2 run`` command (in backquotes) that starts ``executable`` again as launched.

    The launch's own ``values`` for the node go into a parameter file of their own, written
    now (in the temporary directory), keyed by the node's full name and given after the
    launch's ``files``, so they win in any namespace: ``-p NODE:NAME:=VALUE`` matches no
    node in a namespace (rcl reads one name token before the ``:``, which rclpy compares
    as ``/NODE``) and a plain ``-p`` loses to the files' ``/**/NODE`` sections.
    """
    words = ["ros2", "run", PACKAGE, executable, "--ros-args"]
    namespace = namespace.strip("/")
    full_name = f"/{namespace}/{executable}" if namespace else f"/{executable}"
    if namespace:
        words += ["-r", f"__ns:=/{namespace}"]
    for path in files:
        words += ["--params-file", path]
    if values:
        text = yaml.safe_dump({full_name: {"ros__parameters": values}}, default_flow_style=False)
        try:
            handle, path = tempfile.mkstemp(prefix=f"{executable}_restart_", suffix=".yaml")
            with os.fdopen(handle, "w") as out:
                out.write(text)
        except OSError as error:
            shown = ", ".join(f"{key}: {value}" for key, value in values.items())
            return (f"`{' '.join(words)} --params-file FILE`, FILE setting {shown} for"
                    f" {full_name} (the launch could not write it: {error})")  # fmt: skip
        words += ["--params-file", path]
    return f"`{' '.join(words)}`"


def _check_namespace(namespace: str) -> None:
    """RuntimeError (one line, the launch ends with status 1) unless ``namespace`` is valid."""
    if not namespace:
        return
    from launch_ros.utilities import make_namespace_absolute, prefix_namespace
    from rclpy.validate_namespace import InvalidNamespaceException, validate_namespace

    try:  # as launch_ros's Node makes it ("robot1/" is "/robot1")
        validate_namespace(make_namespace_absolute(prefix_namespace(None, namespace)))
    except InvalidNamespaceException as error:
        reason = str(error).splitlines()[0].removeprefix("Invalid namespace: ").rstrip(":")
        raise RuntimeError(f"launch stopped: namespace:={namespace} is not a ROS namespace:"
                           f" {reason}") from None  # fmt: skip


def _arguments_of_other_modes(context: LaunchContext, fake_room: bool, record: bool) -> list[str]:
    """One line per argument given that the chosen mode does not use (it is ignored)."""
    given = {name: LaunchConfiguration(name).perform(context).strip()
             for name in ("room_seed", "realtime", "record_dir")}  # fmt: skip
    out = []
    if not fake_room:
        if given["room_seed"]:
            out.append(f"room_seed:={given['room_seed']}")
        if given["realtime"] == "false":
            out.append("realtime:=false")
    if not record and given["record_dir"]:
        out.append(f"record_dir:={given['record_dir']}")
    needs = {"room_seed": "use_fake_room:=true", "realtime": "use_fake_room:=true",
             "record_dir": "record:=true"}  # fmt: skip
    return [f"{argument} is ignored: it is for {needs[argument.split(':=')[0]]}"
            for argument in out]


NOT_OURS = ("launch-prefix", "launch-prefix-filter", "use_sim_time")
"""Launch arguments this file declares not but knows: ``ros2 launch``'s ``--launch-prefix``
and ``--launch-prefix-filter`` come as these; ``use_sim_time:=true`` is refused apart."""

ARGUMENTS_CHECKED = "arguments_checked"
"""A launch configuration that a launch file including this one sets to ``true`` when it
checked the command line's arguments against its own (multi_robot.launch.py)."""


def undeclared_arguments(context: LaunchContext, declared: list[str], launch_file: str
                         ) -> list[str]:  # fmt: skip
    """One line per ``NAME:=VALUE`` of the command line that ``launch_file`` does not declare.

    ``ros2 launch`` passes any argument on, and an argument no one declares is ignored
    without a word (``fake_room:=true`` for ``use_fake_room:=true``); the line names it and
    the closest of the ``declared`` names.
    """
    lines = []
    for text in context.argv:
        name, _, value = text.partition(":=")
        if name in declared or name in NOT_OURS:
            continue
        close = difflib.get_close_matches(name, declared, n=1, cutoff=0.5)
        hint = f"did you mean {close[0]}:={value}? " if close else ""
        lines.append(f"{name}:={value} is ignored: {launch_file} has no argument {name!r}"
                     f" ({hint}--show-args lists them)")  # fmt: skip
    return lines


def _ignored_arguments(context: LaunchContext, fake_room: bool, record: bool) -> list[str]:
    """One line per argument given that is ignored: of another mode, or not declared here."""
    lines = _arguments_of_other_modes(context, fake_room, record)
    if LaunchConfiguration(ARGUMENTS_CHECKED, default="").perform(context) != "true":
        declared = [argument.name for argument in launch_arguments(FindPackageShare(PACKAGE))]
        lines += undeclared_arguments(context, declared, "contingency.launch.py")
    return lines


def _graph(context: LaunchContext) -> list:
    """The nodes, chosen by the launch arguments (evaluated once the arguments are known)."""
    params_file = LaunchConfiguration("params_file")
    fake_room_file = LaunchConfiguration("fake_room_file")
    namespace = LaunchConfiguration("namespace")
    log_level = LaunchConfiguration("log_level")
    actions: list = []
    fake_room = _is_true(context, "use_fake_room")
    realtime = _is_true(context, "realtime")
    files = ["params_file"] + (["fake_room_file"] if fake_room else [])
    for argument in files:
        path = LaunchConfiguration(argument).perform(context)
        if not os.path.isfile(path):
            reason = f"{argument}:={path} is not a file: give a ROS parameter file (YAML)"
            raise RuntimeError(f"launch stopped: {reason}")  # launch exits with status 1

    if context.launch_configurations.get("use_sim_time", "").strip().lower() == "true":
        raise RuntimeError("launch stopped: use_sim_time:=true: these nodes run on the system"
                           " clock (nothing publishes /clock for them; they refuse it)")
    namespace_text = namespace.perform(context)
    _check_namespace(namespace_text)
    level = log_level.perform(context)

    def node(executable: str, parameters: list) -> Node:
        # The level of this node's logger only: rcl's, rmw's and DDS's stay at INFO.
        logger = node_logger(namespace_text, executable)
        action = Node(
            package=PACKAGE,
            executable=executable,
            name=executable,
            namespace=namespace,
            parameters=parameters,
            arguments=["--ros-args", "--log-level", f"{logger}:={level}"],
            prefix=_prefix(context, executable),
            exec_name=executable,  # the process label, not the prefix's "env"
            # Ends with this process (ros2 launch, which starts every node, a respawned
            # one too, from its main thread): no orphan node outlives a killed launch.
            additional_env={PARENT_PID_VARIABLE: str(os.getpid())},
            output="screen",
            emulate_tty=True,
            sigkill_timeout=str(NODE_STOP_DEADLINE_S),
        )
        _WATCH.restart[id(action)] = (
            executable, namespace_text,
            [item.perform(context) for item in parameters if not isinstance(item, dict)],
            {key: value for item in parameters if isinstance(item, dict)
             for key, value in item.items()},
        )  # fmt: skip
        return action

    record = _is_true(context, "record")
    for line in _ignored_arguments(context, fake_room, record):
        launch.logging.get_logger("launch").warning(line)
    # Recording: the recorder is a third listener of the bits (controller, belief,
    # recorder) and the room's truth listener, so the first step is not sent before it.
    mic = {"wait_for_listeners": 3} if record else {}
    if fake_room:
        # Lockstep on request; paced at the room's speed (speed 1.0) by default.
        pacing = {"lockstep": not realtime}
        room = dict(pacing)
        room.update(_room_seed(context))
        if record:
            room["wait_for_truth_listeners"] = 1
        _WATCH.mic = node("mic_node", [params_file, fake_room_file, {**pacing, **mic}])
        actions.append(_WATCH.mic)
        actions.append(node("fake_audio_node", [params_file, fake_room_file, room]))
    else:
        _WATCH.mic = node("mic_node", [params_file, mic])
        actions.append(_WATCH.mic)
    controller: dict = {}
    spec = LaunchConfiguration("controller").perform(context).strip()
    if spec:
        controller["controller"] = spec
    # The decisions' listeners: mic, belief and the speaker (which follows 'vocalize_step'),
    # the room in lockstep, and the recorder: the first decision waits for all of them.
    controller["wait_for_listeners"] = 3 + int(fake_room) + int(record)
    actions += [node(name, [params_file] + ([fake_room_file] if fake_room and
                                            name == "controller_node" else [])
                     + ([controller] if controller and name == "controller_node" else []))
                for name in GRAPH_NODES]
    if record:
        directory = LaunchConfiguration("record_dir").perform(context).strip()
        directory = directory or time.strftime("session_%Y_%m_%d-%H_%M_%S")
        actions.append(node("recorder_node", [params_file, {"directory": directory}]))
    _WATCH.nodes = [a for a in actions if isinstance(a, Node)]
    _WATCH.started = len(_WATCH.nodes)
    return actions


def launch_arguments(share: FindPackageShare) -> list[DeclareLaunchArgument]:
    """The arguments of this launch file (also used by multi_robot.launch.py)."""
    return [
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the robot"),
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution([share, "config", "robot.yaml"]),
            description="ROS parameter file read by every node",
        ),
        DeclareLaunchArgument(
            "use_fake_room",
            default_value="false",
            choices=BOOLEAN_CHOICES,
            description="true: add fake_audio_node, a simulated room, and listen to it",
        ),
        DeclareLaunchArgument(
            "fake_room_file",
            default_value=PathJoinSubstitution([share, "config", "fake_room.yaml"]),
            description="parameters of the simulated room (with use_fake_room:=true)",
        ),
        DeclareLaunchArgument(
            "realtime",
            default_value="true",
            choices=BOOLEAN_CHOICES,
            description="fake room: true = at the room's speed, false = lockstep, as fast as"
            " the graph answers",
        ),
        DeclareLaunchArgument(
            "room_seed",
            default_value="",
            description="fake room: seed of the room; empty = the one of fake_room_file",
        ),
        DeclareLaunchArgument(
            "log_level",
            default_value="info",
            choices=["debug", "info", "warn", "error", "fatal"],
            description="log level of the package's node loggers (rcl and DDS keep theirs)",
        ),
        DeclareLaunchArgument(
            "record",
            default_value="false",
            choices=BOOLEAN_CHOICES,
            description="true: add recorder_node",
        ),
        DeclareLaunchArgument(
            "controller",
            default_value="",
            description="controller_node's decisions: empty = the policy table;"
            " interval:MIN_S-MAX_S = the calibration protocol (sounds at random intervals)",
        ),
        DeclareLaunchArgument(
            "record_dir",
            default_value="",
            description="bag directory of recorder_node (with record:=true), new; empty ="
            " session_YYYY_MM_DD-HH_MM_SS in the current directory",
        ),
    ]


def generate_launch_description() -> LaunchDescription:
    """The graph of one robot, in ``namespace``."""
    share = FindPackageShare(PACKAGE)
    return LaunchDescription(
        [
            *launch_arguments(share),
            RegisterEventHandler(OnProcessExit(target_action=_WATCH.owns, on_exit=_WATCH.on_exit)),
            RegisterEventHandler(OnShutdown(on_shutdown=_WATCH.on_shutdown)),
            OpaqueFunction(function=_graph),
        ]
    )

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
- ``log_level`` (default info): debug, info, warn, error or fatal, for every node.
- ``params_file`` (default: the installed config/robot.yaml) is read by every node;
  ``fake_room_file`` (default config/fake_room.yaml) by mic_node and fake_audio_node
  with the fake room.
- ``record`` (default false) / ``record_dir``: true adds this package's recorder_node
  with parameter ``directory`` = ``record_dir``; mic_node then waits for it as a third
  listener of ``sound_step`` (and the fake room for its ``partner_present``), so the bag
  holds the session from its first step.
- ``controller`` (default empty: the policy table): ``interval:MIN_S-MAX_S`` makes
  controller_node follow the calibration protocol, sounds at random intervals uniform over
  MIN_S .. MAX_S seconds; with ``record:=true`` that is a calibration session for
  ``infomax-contingency analyze`` (``calibration-session`` does it in one command).

A node that exits with an error ends the whole launch with a final line naming it.
mic_node ending by itself (status 0: ``max_windows`` bits published, or the end of a wav
file with ``exit_at_end``) stops the other nodes of its robot with SIGINT, so the launch
ends (status 0) once they are done; the last line says so.
``multi_robot.launch.py`` starts several robots against several simulated rooms;
``bringup`` runs the same graph in one process.
"""

import os
import signal

from launch.actions import (
    DeclareLaunchArgument,
    EmitEvent,
    LogInfo,
    OpaqueFunction,
    RegisterEventHandler,
)
from launch.event_handlers import OnProcessExit
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

TRUE_WORDS = ("true", "1", "yes", "on")


def _is_true(context: LaunchContext, name: str) -> bool:
    return LaunchConfiguration(name).perform(context).strip().lower() in TRUE_WORDS


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
                    f"{event.action.name} finished by itself (max_windows or exit_at_end)"
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
        if failed and not self.failure:
            self.failure = f"{event.action.name} exited with status {event.returncode}"
            actions.append(
                LogInfo(msg=f"{self.failure}: stopping the whole launch (its error is above)")
            )
            if not context.is_shutdown:
                actions.append(EmitEvent(event=Shutdown(reason=self.failure)))
        if self.failure and self.exited >= self.started:
            actions.append(LogInfo(msg=f"launch stopped: {self.failure} (its error is above)"))
        return actions


_WATCH = _ExitWatch()


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
            return [
                LogInfo(msg=f"launch stopped: {reason}"),
                EmitEvent(event=Shutdown(reason=reason)),
            ]

    def node(executable: str, parameters: list) -> Node:
        return Node(
            package=PACKAGE,
            executable=executable,
            name=executable,
            namespace=namespace,
            parameters=parameters,
            arguments=["--ros-args", "--log-level", log_level],
            output="screen",
            emulate_tty=True,
        )

    record = _is_true(context, "record")
    # Recording: the recorder is a third listener of the bits (controller, belief,
    # recorder) and the room's truth listener, so the first step is not sent before it.
    mic = {"wait_for_listeners": 3} if record else {}
    if fake_room:
        # Lockstep on request; paced at the room's speed (speed 1.0) by default.
        pacing = {"lockstep": not realtime}
        room = dict(pacing)
        seed = LaunchConfiguration("room_seed").perform(context).strip()
        if seed:
            room["seed"] = int(seed)
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
    if record:
        # The decisions' listeners: mic, belief (and the room), and the recorder.
        controller["wait_for_listeners"] = 4 if fake_room else 3
    actions += [node(name, [params_file] + ([fake_room_file] if fake_room and
                                            name == "controller_node" else [])
                     + ([controller] if controller and name == "controller_node" else []))
                for name in GRAPH_NODES]
    if record:
        directory = LaunchConfiguration("record_dir")
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
            description="log level of every node",
        ),
        DeclareLaunchArgument(
            "record", default_value="false", description="true: add recorder_node"
        ),
        DeclareLaunchArgument(
            "controller",
            default_value="",
            description="controller_node's decisions: empty = the policy table;"
            " interval:MIN_S-MAX_S = the calibration protocol (sounds at random intervals)",
        ),
        DeclareLaunchArgument(
            "record_dir",
            default_value="sessions",
            description="directory of recorder_node (with record:=true)",
        ),
    ]


def generate_launch_description() -> LaunchDescription:
    """The graph of one robot, in ``namespace``."""
    share = FindPackageShare(PACKAGE)
    return LaunchDescription(
        [
            *launch_arguments(share),
            RegisterEventHandler(OnProcessExit(target_action=_WATCH.owns, on_exit=_WATCH.on_exit)),
            OpaqueFunction(function=_graph),
        ]
    )

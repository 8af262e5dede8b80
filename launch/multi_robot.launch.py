"""Several robots, each in its own namespace against its own simulated room.

    ros2 launch infomax_contingency multi_robot.launch.py robots:=3

starts ``contingency.launch.py`` once per robot with ``namespace:=robotK``,
``use_fake_room:=true`` and ``room_seed:=K`` (K = 1 .. robots): the graphs share no topic
(``/robot1/belief``, ``/robot2/belief``, ...) and no service (``/robot2/belief_node/reset``);
only ``/diagnostics`` is common, each status named by the node's full name. ``realtime``,
``log_level``, ``params_file`` and ``fake_room_file`` are passed to every robot. An
argument this file does not declare is named in a WARNING line (with the closest it does).
"""

import launch.logging
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription, OpaqueFunction
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.launch_description_sources.python_launch_file_utilities import (
    load_python_launch_file_as_module,
)
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.substitutions import FindPackageShare

from launch import LaunchContext, LaunchDescription

PACKAGE = "infomax_contingency"

PASSED_ON = ("realtime", "log_level", "params_file", "fake_room_file")
"""Arguments given to every robot's contingency.launch.py as they are."""


def _robots(context: LaunchContext) -> list:
    text = LaunchConfiguration("robots").perform(context).strip()
    if not text.isdigit() or not 1 <= int(text) <= 32:
        raise ValueError(f"robots:={text!r} is not allowed: a whole number in [1, 32]")
    one_robot = PathJoinSubstitution(
        [FindPackageShare(PACKAGE), "launch", "contingency.launch.py"]
    )
    # An argument this file does not declare is named once here, not by every robot's file.
    robot_file = load_python_launch_file_as_module(one_robot.perform(context))
    for line in robot_file.undeclared_arguments(context, [*PASSED_ON, "robots"],
                                                "multi_robot.launch.py"):  # fmt: skip
        launch.logging.get_logger("launch").warning(line)
    includes = []
    for index in range(1, int(text) + 1):
        arguments = {
            "namespace": f"robot{index}",
            "use_fake_room": "true",
            "room_seed": str(index),
            robot_file.ARGUMENTS_CHECKED: "true",
        }
        for name in PASSED_ON:
            arguments[name] = LaunchConfiguration(name).perform(context)
        includes.append(
            IncludeLaunchDescription(
                PythonLaunchDescriptionSource(one_robot), launch_arguments=arguments.items()
            )
        )
    return includes


def generate_launch_description() -> LaunchDescription:
    """``robots`` graphs in namespaces robot1 .. robotN against N simulated rooms."""
    share = FindPackageShare(PACKAGE)
    return LaunchDescription(
        [
            DeclareLaunchArgument("robots", default_value="2", description="number of robots"),
            DeclareLaunchArgument(
                "realtime",
                default_value="true",
                choices=["true", "false"],
                description="rooms at the room's speed",
            ),
            DeclareLaunchArgument(
                "log_level",
                default_value="info",
                choices=["debug", "info", "warn", "error", "fatal"],
                description="log level of the package's node loggers",
            ),
            DeclareLaunchArgument(
                "params_file",
                default_value=PathJoinSubstitution([share, "config", "robot.yaml"]),
                description="ROS parameter file read by every node of every robot",
            ),
            DeclareLaunchArgument(
                "fake_room_file",
                default_value=PathJoinSubstitution([share, "config", "fake_room.yaml"]),
                description="parameters of every simulated room",
            ),
            OpaqueFunction(function=_robots),
        ]
    )

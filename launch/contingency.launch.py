"""Start the contingency-detection graph as separate processes (a real ROS 2 install).

    ros2 launch infomax_contingency contingency.launch.py                  # audio on 'audio'
    ros2 launch infomax_contingency contingency.launch.py fake_room:=true  # simulated room
    ros2 launch infomax_contingency contingency.launch.py params_file:=/path/to/my.yaml

Every node reads ``params_file`` (default: the installed config/robot.yaml); with
``fake_room:=true`` fake_audio_node joins the graph and mic_node and fake_audio_node
also read ``fake_room_file`` (default: config/fake_room.yaml, a partner who answers for
60 s and then leaves, in lockstep). ``bringup`` runs the same graph in one process.
"""

from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription

PACKAGE = "infomax_contingency"


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare(PACKAGE)
    params_file = LaunchConfiguration("params_file")
    fake_room_file = LaunchConfiguration("fake_room_file")
    fake_room = LaunchConfiguration("fake_room")

    def node(executable: str, parameters: list, condition=None) -> Node:
        return Node(
            package=PACKAGE,
            executable=executable,
            name=executable,
            parameters=parameters,
            output="screen",
            emulate_tty=True,
            condition=condition,
        )

    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "params_file",
                default_value=PathJoinSubstitution([share, "config", "robot.yaml"]),
                description="ROS parameter file read by every node",
            ),
            DeclareLaunchArgument(
                "fake_room",
                default_value="false",
                description="true: add fake_audio_node, a simulated room, and listen to it",
            ),
            DeclareLaunchArgument(
                "fake_room_file",
                default_value=PathJoinSubstitution([share, "config", "fake_room.yaml"]),
                description="parameters of the simulated room (with fake_room:=true)",
            ),
            node("mic_node", [params_file], UnlessCondition(fake_room)),
            node("mic_node", [params_file, fake_room_file], IfCondition(fake_room)),
            node("fake_audio_node", [params_file, fake_room_file], IfCondition(fake_room)),
            node("controller_node", [params_file]),
            node("belief_node", [params_file]),
            node("posture_node", [params_file]),
            node("speaker_node", [params_file]),
        ]
    )

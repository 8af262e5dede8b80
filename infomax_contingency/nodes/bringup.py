"""bringup: the whole graph in one process, on one executor.

Starts mic_node, controller_node, belief_node, posture_node and speaker_node (and, with
``--fake-room``, fake_audio_node, with the mic reading its ``audio`` topic). Parameters
come from the usual ROS arguments, e.g.::

    bringup --fake-room --ros-args --params-file config/fake_room.yaml

(``/**:`` sections apply to every node, ``mic_node:`` sections to one). The process
ends on Ctrl-C or when a node finishes (e.g. the mic at the end of a wav file with
``exit_at_end``). ``launch/contingency.launch.py`` starts the same graph as separate
processes.
"""

from __future__ import annotations

import argparse
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.task import Future
from rclpy.utilities import remove_ros_args

from infomax_contingency.errors import USER_ERRORS
from infomax_contingency.nodes.belief_node import BeliefNode
from infomax_contingency.nodes.controller_node import ControllerNode
from infomax_contingency.nodes.fake_audio_node import FakeAudioNode
from infomax_contingency.nodes.graph_node import GraphNode
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.runtime import init_ros
from infomax_contingency.nodes.speaker_node import SpeakerNode


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="bringup", description="All nodes of the contingency graph in one process."
    )
    parser.add_argument(
        "--fake-room",
        action="store_true",
        help="also run fake_audio_node and let mic_node listen to it (source topic)",
    )
    return parser.parse_args(remove_ros_args(argv)[1:])


def main(args: list[str] | None = None) -> int:
    """Run the graph in this process; returns the exit status."""
    argv = list(sys.argv if args is None else args)
    if not init_ros(argv, "bringup"):
        return 2
    options = _parse(argv)
    nodes: list[GraphNode] = []
    logger = rclpy.logging.get_logger("bringup")
    try:
        try:
            if options.fake_room:
                nodes.append(FakeAudioNode())
                nodes.append(MicNode(parameter_overrides=[Parameter("source", value="topic")]))
            else:
                nodes.append(MicNode())
            nodes += [ControllerNode(), BeliefNode(), PostureNode(), SpeakerNode()]
        except USER_ERRORS as error:
            logger.error(str(error))
            return 2
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        any_finished = Future()

        def one_finished(future: Future) -> None:
            if not any_finished.done():
                any_finished.set_result(future.result())

        for node in nodes:
            node.finished.add_done_callback(one_finished)
        executor.spin_until_future_complete(any_finished)
        return int(any_finished.result()) if any_finished.done() else 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    except USER_ERRORS as error:
        logger.error(str(error))
        return 2
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())

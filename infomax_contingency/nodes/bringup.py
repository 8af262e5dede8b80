"""bringup: the whole graph in one process, on one executor.

Starts mic_node, controller_node, belief_node, posture_node and speaker_node (and, with
``--fake-room``, fake_audio_node, with the mic reading its ``audio`` topic; with
``--record DIR``, recorder_node writing the session to the bag directory DIR). Parameters
come from the usual ROS arguments, e.g.::

    bringup --fake-room --ros-args --params-file config/fake_room.yaml

(``/**:`` sections apply to every node, ``mic_node:`` sections to one). A node that cannot start is
named in the error line. The process ends on Ctrl-C or SIGTERM (cleanly, whenever it
arrives) or when a node finishes (e.g. the mic at the end of a wav file with
``exit_at_end``). ``launch/contingency.launch.py`` starts the same graph as separate
processes.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from rclpy.parameter import Parameter

from infomax_contingency.nodes.belief_node import BeliefNode
from infomax_contingency.nodes.controller_node import ControllerNode
from infomax_contingency.nodes.fake_audio_node import FakeAudioNode
from infomax_contingency.nodes.graph_node import GraphNode
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.recorder_node import RecorderNode
from infomax_contingency.nodes.runtime import run_nodes
from infomax_contingency.nodes.speaker_node import SpeakerNode


def _bag_directory(text: str) -> str:
    """``--record``'s directory: refused when empty (it recorded nothing, without a word)."""
    if not text:
        raise argparse.ArgumentTypeError("the path is empty; name a new directory")
    return text


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="bringup", description="All nodes of the contingency graph in one process."
    )
    parser.add_argument(
        "--fake-room",
        action="store_true",
        help="also run fake_audio_node and let mic_node listen to it (source topic)",
    )
    parser.add_argument(
        "--record",
        metavar="DIR",
        type=_bag_directory,
        help="also run recorder_node, recording the session as a rosbag2 (MCAP) bag in DIR",
    )
    ros_start = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    return parser.parse_args(argv[1:ros_start])


def main(args: list[str] | None = None) -> int:
    """Run the graph in this process; returns the exit status."""
    argv = list(sys.argv if args is None else args)
    options = _parse(argv)
    factories: list[tuple[str, Callable[[], GraphNode]]] = []
    if options.fake_room:
        factories += [
            (FakeAudioNode.NODE_NAME, FakeAudioNode),
            (
                MicNode.NODE_NAME,
                lambda: MicNode(parameter_overrides=[Parameter("source", value="topic")]),
            ),
        ]
    else:
        factories.append((MicNode.NODE_NAME, MicNode))
    factories += [
        (node.NODE_NAME, node) for node in (ControllerNode, BeliefNode, PostureNode, SpeakerNode)
    ]
    if options.record:
        directory = str(options.record)
        factories.append((
            RecorderNode.NODE_NAME,
            lambda: RecorderNode(parameter_overrides=[Parameter("directory", value=directory)]),
        ))
    return run_nodes(factories, "bringup", argv)


if __name__ == "__main__":
    sys.exit(main())

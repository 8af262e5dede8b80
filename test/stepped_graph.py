"""The lockstep node graph in the test process, on one executor stepped by hand.

:func:`stepped_graph` (a context manager) builds MicNode, ControllerNode, BeliefNode,
PostureNode and, optionally, FakeAudioNode as plain objects on one
:class:`~infomax_contingency.testing.stepped.SteppedExecutor`, with a
:class:`~infomax_contingency.testing.graph.StepRecorder` as ``ros2 topic echo``. The
clock node (the fake room, or the mic replaying a file) is added last, once every
other node's topics reach the recorder, as ``start_graph`` does for processes, so no
node misses the first steps. Nothing runs between the test's ``run_until`` calls;
assertions are on step numbers, never on wall time.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile

from infomax_contingency.nodes.belief_node import BeliefNode
from infomax_contingency.nodes.controller_node import ControllerNode
from infomax_contingency.nodes.fake_audio_node import FakeAudioNode
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.posture_node import PostureNode
from infomax_contingency.nodes.recorder_node import RecorderNode
from infomax_contingency.nodes.speaker_node import SpeakerNode
from infomax_contingency.testing.graph import StepRecorder
from infomax_contingency.testing.stepped import DEFAULT_DEADLINE_S, SteppedExecutor

NODE_CLASSES: dict[str, type[Node]] = {
    "mic_node": MicNode,
    "controller_node": ControllerNode,
    "belief_node": BeliefNode,
    "posture_node": PostureNode,
    "fake_audio_node": FakeAudioNode,
    "recorder_node": RecorderNode,
    "speaker_node": SpeakerNode,
}
"""Node name -> class, for the nodes a stepped graph can hold."""

NO_START_DELAY = {"start_delay_s": 0.0}
"""The start gates wait for their listeners only: in one process nothing else must connect."""


@dataclass
class SteppedGraph:
    """Nodes, their recorder and the executor that runs them."""

    nodes: dict[str, Node]
    recorder: StepRecorder
    executor: SteppedExecutor

    def run_until(
        self, condition: Callable[[], bool], what: str, deadline_s: float = DEFAULT_DEADLINE_S
    ) -> None:
        """Step the graph until ``condition`` holds (fails with the counts received)."""
        try:
            self.executor.run_until(condition, what, deadline_s)
        except AssertionError as error:
            raise AssertionError(f"{error}; received {self.recorder.counts()}") from None

    def add(self, node: str, parameters: dict[str, Any], name: str | None = None) -> Node:
        """Start one more ``node`` (a node name of :data:`NODE_CLASSES`), as ``name``.

        E.g. a second mic_node into the running graph; ``name`` remaps the node name
        (``-r __node:=name``) and is its key in :attr:`nodes`.
        """
        name = name or node
        remap = ["--ros-args", "-r", f"__node:={name}"] if name != node else None
        self.nodes[name] = self.executor.add(
            NODE_CLASSES[node](cli_args=remap, parameter_overrides=_parameters(parameters)))
        return self.nodes[name]

    def remove(self, name: str) -> None:
        """Stop the node ``name``: off the executor and destroyed."""
        self.executor.remove(self.nodes.pop(name))

    def run_steps(self, steps: int) -> None:
        """Step until ``steps`` bits, decisions and beliefs have been recorded.

        Bits and decisions on both their topics (plain and stamped): DDS orders no topic
        against another, so a step's belief may be recorded before its stamped bit.
        """
        rec = self.recorder
        topics = (rec.sound, rec.sound_step, rec.vocalize, rec.vocalize_step, rec.belief)
        self.run_until(lambda: min(map(len, topics)) >= steps, f"{steps} steps")


def _parameters(values: dict[str, Any]) -> list[Parameter]:
    return [Parameter(name, value=value) for name, value in values.items()]


@contextmanager
def stepped_graph(
    nodes: dict[str, dict[str, Any]],
    clock: str | None,
    parameter_files: tuple[str, ...] = (),
    recorder_qos: QoSProfile | None = None,
) -> Iterator[SteppedGraph]:
    """The graph of ``nodes`` (name -> parameters) in this process, ``clock`` added last.

    ``clock`` None: no node of the graph paces it (the test publishes its ``audio``).

    ``parameter_files``: ROS parameter files every node reads first (``--params-file``);
    the parameters in ``nodes`` override them. ``recorder_qos``: the recorder's
    step-topic QoS (default: the graph's). Initialises rclpy and shuts it down
    afterwards, whatever happens.
    """
    files = [arg for path in parameter_files for arg in ("--params-file", str(path))]
    rclpy.init(args=["--ros-args", *files] if files else None)
    executor = None
    try:
        recorder = StepRecorder(stream_qos=recorder_qos, instrument=True)
        executor = SteppedExecutor([recorder])
        built: dict[str, Node] = {}
        others = [name for name in nodes if name != clock]
        for name in others:
            built[name] = executor.add(NODE_CLASSES[name](parameter_overrides=_parameters(
                {**NO_START_DELAY, **nodes[name]} if name == "mic_node" else nodes[name])))
        executor.run_until(lambda: recorder.sees(others), f"the nodes {others} to connect")
        if clock is not None:
            built[clock] = executor.add(NODE_CLASSES[clock](
                parameter_overrides=_parameters({**NO_START_DELAY, **nodes[clock]})))
        yield SteppedGraph(built, recorder, executor)
    finally:
        if executor is not None:
            executor.close()
        rclpy.try_shutdown()

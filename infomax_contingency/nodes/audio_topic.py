"""mic_node's side of the ``audio`` topic: one writer's chunks, checked, into windows.

``audio`` (std_msgs/Float32MultiArray) names no sender. :class:`AudioTopicInput`
subscribes it for a microphone node whose source is the topic and hands each chunk to
:class:`~infomax_contingency.audio.windows.TopicWindows` with its DDS number, its writer's
name where rclpy gives one (``publisher_gid``, rclpy 9.1 on) and whether the topic has
one publisher, so that only the first writer's chunks are windowed, its lost chunks are a
gap, and a new writer after the followed one fell silent (a restarted room) is a gap of
unknown length. Another writer's chunks (a second driver, ``ros2 topic pub``) are counted
and ignored, with a throttled WARN naming the publishers; ``audio`` is one of the node's
watched topics, so the second publisher is also named in the intruder WARN and the ERROR
diagnostic while it lasts. The chunks taken are checked against the topic's contract
(:class:`~infomax_contingency.audio.contracts.AudioContract`).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any

import numpy as np
from std_msgs.msg import Float32MultiArray

from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.contracts import AudioContract
from infomax_contingency.audio.windows import TopicWindows
from infomax_contingency.core.flowcontrol import Writing
from infomax_contingency.nodes.graph_node import GraphNode, publisher_name
from infomax_contingency.nodes.qos import AUDIO_QOS

AUDIO = "audio"
"""The topic of mono audio chunks."""


class AudioTopicInput:
    """The ``audio`` subscription of ``node`` (see the module docstring).

    Args:
        node: the microphone node (its log, clock and ``losses``: when audio was lost).
        source: the window source the chunks go to.
        contract: the topic's contract, checked on each chunk taken.
        on_windows: called after each chunk taken (the node takes the windows made).
    """

    def __init__(self, node: GraphNode, source: TopicWindows, contract: AudioContract,
                 on_windows: Callable[[], None]) -> None:  # fmt: skip
        self.node = node
        self.source = source
        self.contract = contract
        self.on_windows = on_windows
        node.WATCHED_TOPICS = (*node.WATCHED_TOPICS, AUDIO)
        node.create_subscription(Float32MultiArray, AUDIO, self._on_message, AUDIO_QOS)
        node.wait_visibly(
            AUDIO,
            f"std_msgs/Float32MultiArray, mono samples at {source.rate_hz} Hz: start an"
            " audio driver or fake_audio_node (launch use_fake_room:=true), or set source"
            " to wav or sounddevice",
        )

    def _on_message(self, msg: Float32MultiArray, info: dict[str, Any]) -> None:
        node = self.node
        node.count_arrival(AUDIO)
        stamp = int(info.get("source_timestamp", 0))
        if 0 < stamp < node.started_ns:
            node.stale_messages += 1  # published before this node started
            return
        sequence = info.get("publication_sequence_number")
        try:
            writing = self.source.feed(
                np.frombuffer(msg.data, dtype=np.float32),
                sequence if isinstance(sequence, int) else None,
                stamp or node.get_clock().now().nanoseconds,
                writer_of(info),
                lambda: node.count_publishers(AUDIO) <= 1,
            )
        except AudioError as error:
            node.losses.note(node.now_s())
            node.log_throttled("bad chunk", "warning", f"audio chunk ignored: {error}")
            return
        if writing is Writing.FOREIGN:
            node.log_throttled("foreign audio", "warning", f"audio chunk ignored: another writer"
                               f" than the one followed sent it ({self._publishers()}); only the"
                               " first writer's audio is windowed")  # fmt: skip
            return
        for warning in self.contract.check(msg.data, msg.layout.dim,
                                           node.sent_s(stamp, self.contract.clock())):  # fmt: skip
            node.get_logger().warning(warning)
        if writing is Writing.SWITCHED:
            node.get_logger().warning(
                f"'{node.resolve_topic_name(AUDIO)}' now comes from another writer: the one"
                f" followed sent nothing for {self.source.writers.silent_s:.1f} s (restarted?);"
                " the audio in between is of unknown length, a gap"
            )
        if writing is Writing.SWITCHED or self.source.writers.missed:
            node.losses.note(node.now_s())
            self.contract.chunks_lost()
        self.on_windows()

    def _publishers(self) -> str:
        infos = self.node.get_publishers_info_by_topic(self.node.resolve_topic_name(AUDIO))
        return "publishers: " + ", ".join(sorted(publisher_name(info) for info in infos))


def writer_of(info: dict[str, Any]) -> Hashable | None:
    """The name of a message's writer (``publisher_gid``: rclpy 9.1 on), else None."""
    gid = info.get("publisher_gid")
    if isinstance(gid, dict):
        gid = gid.get("data")
    return bytes(gid) if gid else None

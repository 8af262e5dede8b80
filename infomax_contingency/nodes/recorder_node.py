"""recorder_node: every topic of the graph written to a rosbag2 directory (MCAP storage).

The bag is what ``ros2 bag record`` writes on Jazzy: ``DIR/metadata.yaml`` and
``DIR/DIR_NAME_0.mcap``, written with the ``rosbags`` library. Each message is stored as
the serialized CDR bytes received over DDS (a ``raw`` subscription: nothing is
deserialized), with two times, both ns since the epoch: its receive time (MCAP
``log_time``, the one ``ros2 bag`` and ``rosbags`` order and play by: when DDS received it
on this machine) and its publish time (MCAP ``publish_time``: the DDS source timestamp,
when the publisher sent it), and each topic with the QoS its publishers offer
(``offered_qos_profiles`` in the metadata).

Topics (:data:`RECORDED_TOPICS`): ``audio`` (when a publisher exists), ``sound``,
``sound_step``, ``no_step`` (the windows that gave no step), ``sound_energy``,
``vocalize``, ``vocalize_step``, ``belief``, ``posture``, ``joint_targets``,
``speaker_started``, ``partner_present``, ``self_sound`` (the robot's declared own
sound), ``/diagnostics``. The session itself
(the parameter files and threshold file named in ``session_files``, their text) goes
on the topic ``session_info`` (std_msgs/String, YAML) as the first message, and into
the metadata's ``custom_data``. ``session_info`` is also published (transient-local),
and only once every subscription of the recorder exists, so a launcher that waits for
it (the demo does) cannot start the graph before the recorder listens.

Logs: the bag's path when recording starts, that it waits for the first ``sound_step``
(and when it came), and when it stops the messages recorded per topic.

Robustness: the MCAP file is flushed every ``flush_period_s`` seconds (a chunk ends
there), so a recorder killed with ``kill -9`` leaves a file readable up to the last
complete chunk (``metadata.yaml`` is only written on a clean stop; the MCAP file reads
without it). A bag directory that cannot be created (a parent that is not writable,
``/proc/x``) is refused at start-up like one that exists: one line, exit status 2. A
write that fails later (a full disk) gives one ERROR line and an ERROR diagnostic; the
recorder stops writing and keeps what it has written, and the rest of the graph keeps
running.

Parameters: ``directory`` (the bag directory to create; one that exists already or
cannot be created is refused at start-up, exit status 2, which ends a launch: as
``ros2 bag record -o``),
``session_files`` (comma-separated paths to store with the session), ``flush_period_s``,
``record_audio`` (false: leave out the ``audio`` topic, the bulk of a bag).
Publishes ``session_info``, ``/diagnostics``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import yaml
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile
from std_msgs.msg import Bool, Float32, Float64, Int64MultiArray, String
from trajectory_msgs.msg import JointTrajectory

from infomax_contingency.audio.bag import BagWriteError, BagWriter
from infomax_contingency.limits import read_text_capped
from infomax_contingency.nodes.graph_node import ERROR, OK, GraphNode
from infomax_contingency.nodes.parameters import ConfigError
from infomax_contingency.nodes.qos import (
    LATCHED_QOS,
    LATCHED_READER_QOS,
    LOSSLESS_READER_QOS,
    STREAM_QOS,
)
from infomax_contingency.nodes.runtime import run_node

SESSION_TOPIC = "session_info"
"""Topic of the session description (std_msgs/String holding YAML)."""

_DISCOVERY_PERIOD_S = 0.5
"""Seconds between looks for topics that have no subscription yet (``audio``, and
:data:`SUBSCRIBED_ONCE_PUBLISHED`)."""


RECORDER_QOS = LOSSLESS_READER_QOS
"""QoS of the recorder's stream subscriptions (``audio`` too): keep-all. The recorder is
not in the lockstep loop, so in a run at full speed (200 steps in under a second) it
falls behind the graph by hundreds of messages while it writes; a keep-last queue of
100 ``audio`` chunks dropped 4 of 200 for good in such a demo. At real time it keeps up
(about 0.2 % of a core), so the queue stays short."""

RECORDED_TOPICS: dict[str, tuple[type, QoSProfile]] = {
    "sound": (Bool, RECORDER_QOS),
    "sound_step": (Int64MultiArray, RECORDER_QOS),
    "no_step": (Int64MultiArray, RECORDER_QOS),
    "sound_energy": (Float32, RECORDER_QOS),
    "vocalize": (Bool, RECORDER_QOS),
    "vocalize_step": (Int64MultiArray, RECORDER_QOS),
    "belief": (Float64, RECORDER_QOS),
    "posture": (String, LATCHED_READER_QOS),
    "joint_targets": (JointTrajectory, LATCHED_READER_QOS),
    "speaker_started": (TimeMsg, RECORDER_QOS),
    "partner_present": (Bool, RECORDER_QOS),
    "self_sound": (Int64MultiArray, RECORDER_QOS),
    "/diagnostics": (DiagnosticArray, QoSProfile(depth=100)),
}
"""Topic -> (message type, QoS of the recorder's subscription); ``audio`` is added when
it has a publisher (its type is the publisher's)."""

SUBSCRIBED_ONCE_PUBLISHED = frozenset({"partner_present"})
"""Topics of the node that starts last (the fake room, the clock of a lockstep graph),
subscribed only once they have a publisher. A subscription that exists before the
publisher appears can be matched by the publisher before it has matched the publisher
itself: the room, which waits for its listeners, then starts, and the first messages
(all 40 of a short run, once) are dropped by the recorder's side. A subscription made
once the publisher is known is matched on the recorder's side first. In the bag the
topic is there from the start."""


def qos_values(profile: QoSProfile) -> dict[str, int]:
    """A QoS profile as the dict of rmw values that :mod:`audio.bag` stores."""
    return {
        "history": int(profile.history), "depth": int(profile.depth),
        "reliability": int(profile.reliability), "durability": int(profile.durability),
        "liveliness": int(profile.liveliness),
        "deadline_ns": profile.deadline.nanoseconds,
        "lifespan_ns": profile.lifespan.nanoseconds,
        "liveliness_lease_duration_ns": profile.liveliness_lease_duration.nanoseconds,
    }


def ros_type_name(kind: type) -> str:
    """``std_msgs/msg/Bool`` for the rclpy class ``std_msgs.msg.Bool``."""
    package = kind.__module__.split(".")[0]
    return f"{package}/msg/{kind.__name__}"


def session_description(files: list[str]) -> str:
    """YAML text naming the session's files with their contents (missing: the reason).

    Each file is read by :func:`~infomax_contingency.limits.read_text_capped` (a regular
    UTF-8 file of at most ``MAX_YAML_BYTES``, 64 KiB: parameter and threshold files).

    Raises:
        ConfigError: a file that is a directory, a device or a FIFO, larger than the cap,
            unreadable or not UTF-8 text — one line naming ``session_files`` and the file.
    """
    contents: dict[str, str] = {}
    for name in files:
        try:
            contents[name] = read_text_capped(name, "session file")
        except FileNotFoundError as error:
            contents[name] = f"<unreadable: {error.strerror or error}>"
        except ValueError as error:
            raise ConfigError(f"parameter 'session_files': {error} (it names the parameter"
                              " and threshold files to store)") from None
    return yaml.safe_dump({"recorded_at_ns": time.time_ns(), "files": contents})


class RecorderNode(GraphNode):
    """Recorder: the graph's topics into a rosbag2 (MCAP) bag."""

    NODE_NAME = "recorder_node"

    def configure(self) -> None:
        """Declare and check the parameters; the state they set."""
        read = self.parameters
        directory = read.text("directory", "", "Bag directory to create (one that exists or"
                              " cannot be created ends the node at start-up)")
        files = read.text(
            "session_files", "", "Parameter and threshold files to store (comma-separated)"
        )
        self.flush_period_s = read.number(
            "flush_period_s", 1.0, "Seconds between flushes of the bag (one chunk)", 0.05,
            3600.0, "s",
        )
        self.record_audio = read.flag("record_audio", True, "Also record the 'audio' topic")
        if not directory:
            raise ConfigError("parameter 'directory' is empty: name the bag directory to create")
        self.directory = Path(directory)
        if self.directory.exists():
            raise ConfigError(
                f"parameter 'directory' = {directory!r} exists already: a bag is written to a"
                " new directory; name one that does not exist (a session is never overwritten)"
            )
        self.failure = ""
        self.counts: dict[str, int] = {}
        self.subscribed: set[str] = set()
        self._waiting: dict[str, tuple[type, QoSProfile]] = {}
        """Topics to subscribe to once they have a publisher (see SUBSCRIBED_ONCE_PUBLISHED)."""
        self.description = session_description([f.strip() for f in files.split(",") if f.strip()])

    def activate(self) -> None:
        """Publishers, subscriptions, services and timers."""
        self.writer: BagWriter | None = None
        try:
            self.writer = BagWriter(self.directory, custom_data={"session": self.description})
        except BagWriteError as error:  # nothing to record into: the node (and launch) ends
            raise ConfigError(f"parameter 'directory' = {str(self.directory)!r}: {error}"
                              ) from None
        self.get_logger().info(f"recording to {self.directory.resolve()}")
        self._add_topic(SESSION_TOPIC, String, STREAM_QOS)
        for topic, (kind, qos) in RECORDED_TOPICS.items():
            self._add_topic(topic, kind, qos)
        # Announced only now that every subscription exists: a graph that waits for
        # 'session_info' (the demo's monitor) starts once nothing can be missed.
        self._session_pub = self.create_publisher(String, SESSION_TOPIC, LATCHED_QOS)
        self._write_own(SESSION_TOPIC, String(data=self.description))
        self._session_pub.publish(String(data=self.description))
        self.create_timer(_DISCOVERY_PERIOD_S, self._discover)
        self.create_timer(self.flush_period_s, self._flush)
        self.wait_visibly("sound_step", "the bits of mic_node: the session starts with them",
                          companions=("no_step",))  # recorded: paused while no step comes

    def _fail(self, message: str) -> None:
        """Stop writing after an error (logged once, shown in the diagnostics)."""
        if not self.failure:
            self.failure = message
            self.get_logger().error(f"recording stopped: {message}")
        if self.writer is not None:
            self.writer.abandon()
            self.writer = None

    def _add_topic(self, topic: str, kind: type, qos: QoSProfile) -> None:
        """Add ``topic`` to the bag and subscribe to it raw (some once published)."""
        name = self.resolve_topic_name(topic)
        self.counts[name] = 0
        if topic in SUBSCRIBED_ONCE_PUBLISHED:
            self._waiting[topic] = (kind, qos)
        else:
            self._subscribe(topic, kind, qos)

    def _subscribe(self, topic: str, kind: type, qos: QoSProfile) -> None:
        name = self.resolve_topic_name(topic)
        if self.writer is not None:
            offered = [qos_values(info.qos_profile)
                       for info in self.get_publishers_info_by_topic(name)]
            try:
                self.writer.add_topic(name, ros_type_name(kind), offered or [qos_values(qos)])
            except BagWriteError as error:
                self._fail(str(error))

        def receive(data: bytes, info: dict[str, Any]) -> None:
            self.count_arrival(topic)
            received = int(info.get("received_timestamp", 0)) or time.time_ns()
            self._write(name, data, received, int(info.get("source_timestamp", 0)) or None)

        if topic != SESSION_TOPIC:
            self.create_subscription(kind, topic, receive, qos, raw=True)
        self.subscribed.add(topic)

    def _write_own(self, topic: str, msg: Any) -> None:
        """Write a message this node makes itself (the session description)."""
        from rclpy.serialization import serialize_message

        now = time.time_ns()
        self._write(self.resolve_topic_name(topic), serialize_message(msg), now, now)

    def _write(self, name: str, data: bytes, received_ns: int, published_ns: int | None
               ) -> None:
        self.counts[name] = self.counts.get(name, 0) + 1
        if self.writer is None:
            return
        try:
            self.writer.write(name, data, received_ns, published_ns)
        except BagWriteError as error:
            self._fail(str(error))

    def _discover(self) -> None:
        """Subscribe to the waiting topics and ``audio`` once they have a publisher."""
        for topic, (kind, qos) in list(self._waiting.items()):
            if self.count_publishers(self.resolve_topic_name(topic)) > 0:
                del self._waiting[topic]
                self._subscribe(topic, kind, qos)
        if "audio" in self.subscribed or not self.record_audio:
            return
        for name, types in self.get_topic_names_and_types():
            if name == self.resolve_topic_name("audio") and types:
                kind = _message_class(types[0])
                if kind is not None:
                    self._add_topic("audio", kind, RECORDER_QOS)

    def _flush(self) -> None:
        if self.writer is not None:
            try:
                self.writer.flush()
            except BagWriteError as error:
                self._fail(str(error))

    def diagnostic_status(self) -> tuple[bytes, str, dict[str, Any]]:
        """Recording or failed; messages per topic."""
        values: dict[str, Any] = {"directory": str(self.directory)}
        values.update({f"messages {name}": count for name, count in self.counts.items()})
        if self.failure:
            return ERROR, f"not recording: {self.failure}", values
        return OK, f"recording to {self.directory}", values

    def messages_taken(self) -> int:
        """Messages received on the recorded topics so far (the runtime drains by it)."""
        return sum(self.counts.values())

    def destroy_node(self) -> None:
        """Close the bag (writes ``metadata.yaml``), log what it holds, destroy the node."""
        if self.writer is not None:
            try:
                self.writer.close()
                self.get_logger().info(self.summary())
            except BagWriteError as error:
                self.get_logger().error(f"closing the bag: {error}")
            self.writer = None
        super().destroy_node()

    def summary(self) -> str:
        """One line: the bag, its messages per topic, and the topics that stayed empty."""
        total = sum(self.counts.values())
        held = ", ".join(f"{name} {count}" for name, count in self.counts.items() if count)
        empty = ", ".join(name for name, count in self.counts.items() if not count)
        return (f"recorded {total} messages to {self.directory.resolve()}: {held}"
                + (f"; nothing on {empty}" if empty else ""))  # fmt: skip


def _message_class(type_name: str) -> type | None:
    """The rclpy class of ``pkg/msg/Name`` (None if it cannot be imported)."""
    import importlib

    try:
        package, _, name = type_name.split("/")
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ValueError, ImportError, AttributeError):
        return None


def main(args: list[str] | None = None) -> int:
    """Run the recorder node."""
    return run_node(RecorderNode, args)


if __name__ == "__main__":
    sys.exit(main())

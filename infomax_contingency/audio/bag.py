"""Sessions on disk: a rosbag2 directory with MCAP storage, written with ``rosbags``.

:class:`BagWriter` takes serialized CDR bytes as they came over DDS (nothing is decoded
here, no rclpy), with the receive time in ns since the epoch as the message time (MCAP
``log_time``, what ``ros2 bag`` and ``rosbags`` readers order by) and the publisher's send
time (the DDS source timestamp) as MCAP ``publish_time``. It
ends a chunk and flushes the file on :meth:`BagWriter.flush`, so a writer that dies
leaves a file readable up to the last flushed chunk. Every failure of the file system
(no such directory, not writable, disk full) is one :class:`BagWriteError` with a
one-line reason.

QoS profiles are given as plain dicts of rmw values (``history``, ``depth``,
``reliability``, ``durability``, ``liveliness``: the rmw enum integers; ``deadline_ns``,
``lifespan_ns``, ``liveliness_lease_duration_ns``: ns), stored in the metadata as
``offered_qos_profiles``.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from io import BytesIO
from pathlib import Path
from typing import Any

from infomax_contingency.errors import MissingPackageError

try:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )
    from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
    from rosbags.rosbag2.storage_mcap import (
        McapWriter,
        write_record,
        write_uint16,
        write_uint32,
        write_uint64,
    )
    from rosbags.typesys import Stores, get_typestore
except ModuleNotFoundError:  # sessions are optional: say which package is missing
    raise MissingPackageError(
        "rosbags", "recording or reading a session (rosbag2 bag)", "python3-rosbags-pip"
    ) from None

BAG_VERSION = 9
"""rosbag2 metadata version (the one Jazzy writes)."""


class _McapPublishTimeStorage(McapWriter):
    """rosbags' MCAP storage, writing each message's publish time beside its log time.

    ``rosbags`` 0.11 writes its one timestamp as both MCAP times; this storage writes
    :attr:`publish_time_ns` (set just before each write) as ``publish_time``. The record
    is the one ``McapWriter.write`` makes, with that field changed.
    """

    publish_time_ns: int | None = None

    def write(self, connection: Any, timestamp: int, data: bytes | memoryview) -> None:
        """Write one message with log time ``timestamp`` and the set publish time."""
        publish = timestamp if self.publish_time_ns is None else self.publish_time_ns
        self.message_start_time = min(timestamp, self.message_start_time)
        self.message_end_time = max(timestamp, self.message_end_time)
        self.channel_stats[connection.id] += 1
        self.chunk.message_start_time = min(timestamp, self.chunk.message_start_time)
        self.chunk.message_end_time = max(timestamp, self.chunk.message_end_time)
        self.chunk.msgs[connection.id].append((timestamp, self.chunk.bio.tell()))
        record = BytesIO()
        write_uint16(record, connection.id)
        write_uint32(record, 0)
        write_uint64(record, timestamp)
        write_uint64(record, publish)
        record.write(data)
        write_record(self.chunk.bio, _MCAP_MESSAGE_OPCODE, record)
        if self.chunk.bio.tell() > _MCAP_CHUNK_BYTES:
            self.close_chunk()


_MCAP_MESSAGE_OPCODE = 0x05
_MCAP_CHUNK_BYTES = 2**20
"""A chunk is closed once it holds this many bytes (as ``rosbags`` does)."""


class _Writer(Writer):
    """rosbags' rosbag2 writer with the MCAP storage that keeps publish times."""

    STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: _McapPublishTimeStorage}


class BagWriteError(OSError):
    """The bag cannot be created or written; the message says why in one line."""


def _time(ns: int) -> QosTime:
    seconds, nanoseconds = divmod(int(ns), 10**9)
    return QosTime(seconds, nanoseconds)


def bag_qos(profile: Mapping[str, Any]) -> Qos:
    """The rosbags ``Qos`` of a profile given as a dict of rmw values (module docstring)."""
    return Qos(
        QosHistory(int(profile.get("history", 1))),
        int(profile.get("depth", 10)),
        QosReliability(int(profile.get("reliability", 1))),
        QosDurability(int(profile.get("durability", 2))),
        _time(profile.get("deadline_ns", 0)),
        _time(profile.get("lifespan_ns", 0)),
        QosLiveliness(int(profile.get("liveliness", 1))),
        _time(profile.get("liveliness_lease_duration_ns", 0)),
        False,
    )


def _reason(error: BaseException) -> str:
    if isinstance(error, OSError) and error.strerror:
        where = f" ({error.filename})" if error.filename else ""
        return f"{error.strerror}{where}"
    return str(error)


class BagWriter:
    """A rosbag2 (MCAP) bag being written.

    Args:
        directory: the bag directory to create (it must not exist; its parent must).
        custom_data: key -> text stored in ``metadata.yaml`` (``custom_data``).

    Raises:
        BagWriteError: the directory exists already or cannot be created.
    """

    def __init__(self, directory: Path, custom_data: Mapping[str, str] | None = None) -> None:
        self.directory = Path(directory)
        self.typestore = _jazzy_types()
        self.topics: dict[str, Any] = {}
        try:
            self._writer = _Writer(self.directory, version=BAG_VERSION,
                                  storage_plugin=StoragePlugin.MCAP)
            for key, value in (custom_data or {}).items():
                self._writer.set_custom_data(key, value)
            self._writer.open()
        except (WriterError, OSError) as error:
            raise BagWriteError(f"cannot create the bag {self.directory}: {_reason(error)}") \
                from error

    def add_topic(self, topic: str, type_name: str, offered_qos: Sequence[Mapping[str, Any]]
                  ) -> None:
        """Declare ``topic`` of ``type_name`` (``pkg/msg/Name``) with the QoS offered."""
        try:
            self.topics[topic] = self._writer.add_connection(
                topic, type_name, typestore=self.typestore,
                offered_qos_profiles=[bag_qos(profile) for profile in offered_qos],
            )
        except (WriterError, OSError, KeyError) as error:
            raise BagWriteError(f"cannot add topic {topic} to the bag: {_reason(error)}") \
                from error

    def write(self, topic: str, data: bytes, time_ns: int, publish_ns: int | None = None
              ) -> None:
        """Append one serialized message received at ``time_ns`` (ns since the epoch).

        ``publish_ns``: when its publisher sent it (the DDS source timestamp, ns since the
        epoch), stored as the MCAP ``publish_time``; None: the receive time.
        """
        storage = self._writer.storage
        if isinstance(storage, _McapPublishTimeStorage):
            storage.publish_time_ns = None if publish_ns is None else int(publish_ns)
        try:
            self._writer.write(self.topics[topic], int(time_ns), data)
        except (WriterError, OSError) as error:
            raise BagWriteError(f"cannot write to the bag {self.directory}: {_reason(error)}") \
                from error

    def flush(self) -> None:
        """End the current chunk and flush the file (what is written survives a kill)."""
        storage = self._writer.storage
        try:
            if storage is not None and storage.chunk.bio.tell():
                storage.close_chunk()
                storage.bio.flush()
        except OSError as error:
            raise BagWriteError(f"cannot write to the bag {self.directory}: {_reason(error)}") \
                from error

    def close(self) -> None:
        """Write the summary and ``metadata.yaml``; the bag is complete."""
        try:
            self._writer.close()
        except (WriterError, OSError) as error:
            raise BagWriteError(f"cannot finish the bag {self.directory}: {_reason(error)}") \
                from error

    def abandon(self) -> None:
        """Stop writing after a failure, keeping the chunks already on disk."""
        storage = self._writer.storage
        if storage is not None:
            try:
                storage.bio.close()
            except OSError:
                pass
        self._writer.storage = None


class BagReadError(OSError):
    """The session cannot be read; the message says why in one line."""


def read_topics(directory: Path, topics: Sequence[str]) -> dict[str, list[tuple[int, Any]]]:
    """``topic -> [(receive time ns, decoded message), ...]`` of a bag, in time order.

    A topic the bag does not hold maps to an empty list. Messages are decoded with the
    Jazzy message definitions that ``rosbags`` ships (no rclpy).

    Raises:
        BagReadError: not a rosbag2 directory, or unreadable.
    """
    from rosbags.rosbag2 import Reader, ReaderError

    found: dict[str, list[tuple[int, Any]]] = {topic: [] for topic in topics}
    typestore = _jazzy_types()
    try:
        with Reader(Path(directory)) as reader:
            connections = [c for c in reader.connections if c.topic in found]
            for connection, time_ns, data in reader.messages(connections=connections):
                message = typestore.deserialize_cdr(data, connection.msgtype)
                found[connection.topic].append((time_ns, message))
    except (ReaderError, OSError) as error:
        raise BagReadError(f"cannot read the session {directory}: {_reason(error)}") from error
    return found


@functools.cache
def _jazzy_types() -> Any:
    """The Jazzy message definitions ``rosbags`` ships (built once)."""
    return get_typestore(Stores.ROS2_JAZZY)


def encode(message_type: str, **fields: Any) -> bytes:
    """The CDR bytes of a ``message_type`` (``pkg/msg/Name``) message with ``fields``.

    For sessions made offline (no rclpy): the bytes rclpy would put on the wire. An
    ``std_msgs/msg/*MultiArray`` takes ``data`` as a sequence and an empty layout.
    """
    typestore = _jazzy_types()
    kinds = typestore.types
    if message_type.endswith("MultiArray"):
        import numpy as np

        dtype = {"Int64MultiArray": np.int64, "Float32MultiArray": np.float32}[
            message_type.rsplit("/", 1)[1]]
        fields = {"layout": kinds["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
                  "data": np.asarray(fields["data"], dtype=dtype)}
    return bytes(typestore.serialize_cdr(kinds[message_type](**fields), message_type))

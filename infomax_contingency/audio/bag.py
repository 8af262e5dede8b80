"""Sessions on disk: a rosbag2 directory with MCAP storage, written with ``rosbags``.

:class:`BagWriter` takes serialized CDR bytes as they came over DDS (nothing is decoded
here, no rclpy), with the receive time in ns since the epoch as the message time (MCAP
``log_time``, what ``ros2 bag`` and ``rosbags`` readers order by) and the publisher's send
time (the DDS source timestamp) as MCAP ``publish_time``. It ends a chunk and flushes the
file on :meth:`BagWriter.flush`, so a writer that dies leaves it readable up to there.
Every failure of the file system (no such directory, not writable, disk full) is one
:class:`BagWriteError` with a one-line reason.

QoS profiles are given as plain dicts of rmw values (``history``, ``depth``,
``reliability``, ``durability``, ``liveliness``: the rmw enum integers; ``deadline_ns``,
``lifespan_ns``, ``liveliness_lease_duration_ns``: ns), stored in the metadata as
``offered_qos_profiles``.
"""

from __future__ import annotations

import functools
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from io import BytesIO
from pathlib import Path
from typing import Any

from infomax_contingency.audio.mcap_scan import BagReadError, Scan, scan_mcap
from infomax_contingency.errors import MissingPackageError
from infomax_contingency.limits import load_yaml, refuse_over_budget, short_repr

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


SESSION_TYPES = {
    "/audio": "std_msgs/msg/Float32MultiArray",
    "/sound": "std_msgs/msg/Bool",
    "/sound_step": "std_msgs/msg/Int64MultiArray",
    "/no_step": "std_msgs/msg/Int64MultiArray",
    "/sound_energy": "std_msgs/msg/Float32",
    "/vocalize": "std_msgs/msg/Bool",
    "/vocalize_step": "std_msgs/msg/Int64MultiArray",
    "/belief": "std_msgs/msg/Float64",
    "/posture": "std_msgs/msg/String",
    "/partner_present": "std_msgs/msg/Bool",
    "/self_sound": "std_msgs/msg/Int64MultiArray",
    "/joint_targets": "trajectory_msgs/msg/JointTrajectory",
    "/speaker_started": "builtin_interfaces/msg/Time",
    "/session_info": "std_msgs/msg/String",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}
"""The types of a session's topics (recorder_node), as a bag names them."""

MAX_METADATA_BYTES, MAX_METADATA_DEPTH = 1 << 20, 16
"""Largest ``metadata.yaml`` read, bytes, and its deepest nesting (a session's: 11 KB, 8)."""


def _bag_metadata(directory: Path) -> dict[str, Any] | None:
    """``rosbag2_bagfile_information`` of ``metadata.yaml`` (``limits.load_yaml``), or None."""
    path = directory / "metadata.yaml"
    if not path.exists() and not path.is_symlink():
        return None
    try:
        info = load_yaml(path, "metadata.yaml", MAX_METADATA_DEPTH, MAX_METADATA_BYTES)
    except (OSError, ValueError) as error:
        raise BagReadError(f"cannot read the session {directory}: its metadata.yaml is damaged"
                           f" ({' '.join(str(error).split())[:200]})") from None
    info = info.get("rosbag2_bagfile_information") if isinstance(info, dict) else None
    if not isinstance(info, dict):
        raise BagReadError(f"cannot read the session {directory}: its metadata.yaml holds no"
                           " rosbag2_bagfile_information")
    return info


def _bag_files(directory: Path, info: dict[str, Any] | None) -> list[Path]:
    """The MCAP files of a bag: ``relative_file_paths``, else its ``*.mcap`` files.

    BagReadError for a path that is absolute, leaves the bag directory (symlinks
    resolved) or names no regular file (a device, a FIFO).
    """
    listed = (info or {}).get("relative_file_paths") or []
    if not isinstance(listed, list) or not all(isinstance(name, str) for name in listed):
        raise BagReadError(f"cannot read the session {directory}: its metadata.yaml's"
                           f" relative_file_paths is not a list of names: {short_repr(listed)}")
    twice = sorted(name for name, count in Counter(listed).items() if count > 1)[:3]
    if twice:  # each file read once: its messages would count twice
        raise BagReadError(f"cannot read the session {directory}: its metadata.yaml's"
                           f" relative_file_paths lists {short_repr(twice)} more than once")
    files = [directory / name for name in listed] or sorted(directory.glob("*.mcap"))
    inside = directory.resolve()
    for path, name in zip(files, listed or [p.name for p in files], strict=True):
        resolved, shown = path.resolve(), f"cannot read the session {directory}: {name[:200]!r}"
        if Path(name).is_absolute() or not resolved.is_relative_to(inside):
            raise BagReadError(f"{shown} lies outside the bag directory (metadata.yaml must"
                               " name its files relative to it)")
        if resolved.exists() and not resolved.is_file():
            raise BagReadError(f"{shown} is not a regular file (a directory, device or FIFO)")
    return files


def unlisted_recordings(directory: Path) -> list[str]:
    """The ``*.mcap`` files of a bag that its ``metadata.yaml`` lists not, so reads not.

    A bag without ``metadata.yaml`` (cut), or whose metadata lists no file, is read from
    all its MCAP files: none then. BagReadError as :func:`read_topics` for damaged metadata.
    """
    info = _bag_metadata(directory)
    if not info or not info.get("relative_file_paths"):
        return []
    read = {path.resolve() for path in _bag_files(directory, info)}
    return sorted(path.name for path in directory.glob("*.mcap") if path.resolve() not in read)


def _listed_counts(info: dict[str, Any]) -> dict[str, int]:
    """Topic -> message count that metadata.yaml lists."""
    counts = {}
    for entry in info.get("topics_with_message_count") or []:
        try:
            counts[str(entry["topic_metadata"]["name"])] = int(entry["message_count"])
        except (KeyError, TypeError, ValueError):
            continue
    return counts


def _type_list(types: Mapping[str, str]) -> str:
    return ", ".join(f"{topic} ({kind})" for topic, kind in sorted(types.items())) or "nothing"


class SessionTopics(dict[str, list[tuple[int, Any]]]):
    """``topic -> [(receive time ns, decoded message), ...]``, and the session's namespace."""

    namespace: str = ""
    """The namespace its topics were recorded under (``/robot1``), "" for none."""


def read_topics(directory: Path, topics: Mapping[str, str] | Sequence[str],
                required: Sequence[str | tuple[str, ...]] = (),
                warn: Callable[[str], None] | None = None) -> SessionTopics:
    """``topic -> [(receive time ns, decoded message), ...]`` of a bag, in time order.

    ``topics`` maps each topic wanted to the type it must have (``std_msgs/msg/Bool``; a
    sequence of names: their types in :data:`SESSION_TYPES`); a topic the bag does not
    hold maps to an empty list, unless it is ``required`` (a name, or a tuple of names
    one of which is needed).
    Messages are decoded with the Jazzy message definitions that ``rosbags`` ships (no
    rclpy). The MCAP file is read record by record from its start, so:

    * a bag cut by a killed recorder (no ``metadata.yaml``, the file ending inside a
      record) is read up to its last complete chunk, and ``warn`` is told it was cut;
    * a bag whose file holds fewer messages of a wanted topic than its ``metadata.yaml``
      lists, or a message that does not decode, is damaged: refused, naming what is missing;
    * a session recorded under a namespace (``/robot1/sound_step``) is read by the plain
      names (:func:`_session_namespace`), the namespace kept in the result's ``namespace``.

    Raises:
        BagReadError: not a rosbag2 directory, unreadable, damaged, a wanted topic of
            another type, or a required topic missing (naming what the bag holds).
    """
    directory = Path(directory)
    if not isinstance(topics, Mapping):
        topics = {topic: SESSION_TYPES[topic] for topic in topics}
    if not directory.is_dir():
        what = "does not exist" if not directory.exists() else "is not a directory"
        raise BagReadError(f"cannot read the session {directory}: it {what}")
    info = _bag_metadata(directory)
    if info is not None and info.get("storage_identifier") not in (None, "mcap"):
        return _read_with_rosbags(directory, topics, required)
    files = _bag_files(directory, info)
    if not files:
        raise BagReadError(f"cannot read the session {directory}: it holds neither"
                           " metadata.yaml nor an .mcap file (not a rosbag2 bag)")
    found = SessionTopics({topic: [] for topic in topics})
    scans = [_scan_file(directory, path, metadata=info is not None, warn=warn)
             for path in files]
    held: dict[str, str] = {}
    for scan in scans:
        held.update(scan.channels.values())
    namespace = found.namespace = _session_namespace(directory, held, topics)
    strip = functools.partial(_without_namespace, namespace)
    held = {strip(topic): kind for topic, kind in held.items()}
    for scan in scans:
        scan.channels = {channel: (strip(topic), kind)
                         for channel, (topic, kind) in scan.channels.items()}
        _decode_into(found, scan, topics, directory)
    _check_types(directory, held, topics, required)
    if info is not None:
        listed = {strip(topic): count for topic, count in _listed_counts(info).items()}
        _check_counts(directory, found, listed)
    for messages in found.values():
        messages.sort(key=lambda item: item[0])
    return found


GLOBAL_TOPICS = ("/diagnostics",)
"""Session topics that keep their absolute name under a namespace."""


def _session_namespace(directory: Path, held: Mapping[str, str],
                       topics: Mapping[str, str]) -> str:
    """The namespace a session was recorded under (``/robot1``), or "" for none.

    A graph launched with ``namespace:=robot1`` records ``/robot1/sound_step`` and so on
    (``/diagnostics`` stays absolute): a bag that holds none of the wanted topics by its
    plain name but holds them under one namespace is that robot's session. Two
    namespaces are two robots: refused, naming both.
    """
    relative = [topic for topic in topics if topic not in GLOBAL_TOPICS]
    if any(topic in held for topic in relative):
        return ""
    namespaces = {topic[:-len(wanted)] for topic in held for wanted in relative
                  if topic.endswith(wanted) and len(topic) > len(wanted)}
    if len(namespaces) > 1:
        raise BagReadError(f"the session {directory} holds the topics of several robots"
                           f" ({', '.join(sorted(namespaces))}): record one robot per bag")
    return namespaces.pop() if namespaces else ""


def _without_namespace(namespace: str, topic: str) -> str:
    """``topic`` with the session's ``namespace`` taken off its front."""
    if namespace and topic.startswith(namespace + "/"):
        return topic[len(namespace):]
    return topic


def _scan_file(directory: Path, path: Path, metadata: bool,
               warn: Callable[[str], None] | None) -> Scan:
    """One MCAP file of a bag: damage refused (with ``metadata``), a cut told to ``warn``."""
    try:
        scan, stopped = scan_mcap(path)
    except OSError as error:
        raise BagReadError(f"cannot read the session {directory}: {_reason(error)}") from error
    if stopped is None:
        return scan
    if metadata:
        raise BagReadError(f"the session {directory} is damaged: {path.name} is readable only"
                           f" up to byte {scan.read_bytes:,} of {path.stat().st_size:,}"
                           f" ({stopped})")
    if warn is not None:
        warn(f"the session {directory} was cut (no metadata.yaml: was its recorder killed?):"
             f" {path.name} read up to its last complete chunk, byte {scan.read_bytes:,} of"
             f" {path.stat().st_size:,}, {len(scan.messages):,} messages")
    return scan


DECODED_BYTES_PER_MESSAGE = 1024
"""Memory of a decoded message besides its data, bytes (a dataclass, a numpy array)."""
DECODED_BYTES_PER_CDR_BYTE = {"diagnostic_msgs/msg/DiagnosticArray": 12}
"""Memory of a decoded message per byte of its CDR data, by type (others: 2). Measured: a
/diagnostics of 10^8 CDR bytes took 8 x as much decoded (Python objects per status)."""


def decoded_bytes(scan: Scan, topics: Mapping[str, str]) -> int:
    """Estimated memory of the wanted messages of ``scan`` once decoded, bytes."""
    total = 0
    for channel, _, data in scan.messages:
        topic, kind = scan.channels.get(channel, ("", ""))
        if topics.get(topic) == kind:
            factor = DECODED_BYTES_PER_CDR_BYTE.get(kind, 2)
            total += DECODED_BYTES_PER_MESSAGE + factor * len(data)
    return total


def _decode_into(found: dict[str, list[tuple[int, Any]]], scan: Scan,
                 topics: Mapping[str, str], directory: Path) -> None:
    try:
        refuse_over_budget(decoded_bytes(scan, topics), f"decode the session {directory}",
                           "read it on a machine with more memory")
    except ValueError as error:
        raise BagReadError(str(error)) from None
    typestore = _jazzy_types()
    for channel, time_ns, data in scan.messages:
        topic, kind = scan.channels.get(channel, ("", ""))
        if topic not in found or kind != topics[topic]:
            continue
        try:
            found[topic].append((time_ns, typestore.deserialize_cdr(data, kind)))
        except Exception as error:  # noqa: BLE001 - any decoding failure is damage
            raise BagReadError(
                f"the session {directory} is damaged: message {len(found[topic]) + 1} of"
                f" {topic} cannot be decoded as {kind} ({type(error).__name__}:"
                f" {' '.join(str(error).split())[:120]})") from None


def _check_types(directory: Path, held: Mapping[str, str], topics: Mapping[str, str],
                 required: Sequence[str | tuple[str, ...]]) -> None:
    """Refuse a wanted topic of another type, or a required one missing; name what it holds."""
    wrong = {topic: kind for topic, kind in held.items()
             if topic in topics and kind != topics[topic]}
    groups = [(group,) if isinstance(group, str) else tuple(group) for group in required]
    missing = [group for group in groups if not any(topic in held for topic in group)]
    if not wrong and not missing:
        return
    names = list(wrong) or [topic for group in missing for topic in group]
    needed = _type_list({topic: topics[topic] for topic in names})
    problem = ("holds " + _type_list(wrong) + " of other types" if wrong
               else "lacks " + " and ".join(" or ".join(group) for group in missing))
    raise BagReadError(f"the session {directory} is not one of this package's sessions: it"
                       f" {problem}; needed: {needed}. It holds: {_type_list(held)}")


def _check_counts(directory: Path, found: Mapping[str, list], listed: Mapping[str, int]) -> None:
    """Refuse a bag whose file holds fewer messages than its metadata.yaml lists."""
    short = [f"{topic} {len(messages)} of {listed[topic]}" for topic, messages in found.items()
             if topic in listed and len(messages) < listed[topic]]
    if short:
        raise BagReadError(f"the session {directory} is damaged: its file holds fewer messages"
                           f" than its metadata.yaml lists ({', '.join(short)})")


def _read_with_rosbags(directory: Path, topics: Mapping[str, str],
                       required: Sequence[str | tuple[str, ...]]
                       ) -> SessionTopics:
    """A bag of another storage (sqlite3) through ``rosbags``; any failure is one line."""
    from rosbags.rosbag2 import Reader

    found = SessionTopics({topic: [] for topic in topics})
    typestore = _jazzy_types()
    try:
        with Reader(directory) as reader:
            held = {c.topic: c.msgtype for c in reader.connections}
            _check_types(directory, held, topics, required)
            connections = [c for c in reader.connections
                           if c.topic in found and c.msgtype == topics[c.topic]]
            for connection, time_ns, data in reader.messages(connections=connections):
                found[connection.topic].append(
                    (time_ns, typestore.deserialize_cdr(data, connection.msgtype)))
    except BagReadError:
        raise
    except Exception as error:  # noqa: BLE001 - a damaged bag fails in many ways
        raise BagReadError(f"cannot read the session {directory}: {_reason(error)}") from None
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

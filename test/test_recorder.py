"""recorder_node: the graph's topics into a rosbag2 (MCAP) bag, read back independently."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

# mcap reads the bags back independently of the recorder's library (test_depend
# mcap-ros2-support); without it these tests skip, with this reason.
pytest.importorskip("mcap", reason="mcap is not installed (pip install mcap-ros2-support)")

import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rclpy.parameter import Parameter
from std_msgs.msg import Bool, Float64, Int64MultiArray

from infomax_contingency.audio.bag import BagWriteError, BagWriter
from infomax_contingency.nodes.parameters import ConfigError
from infomax_contingency.nodes.recorder_node import (
    RECORDED_TOPICS,
    SUBSCRIBED_ONCE_PUBLISHED,
    RecorderNode,
)
from infomax_contingency.testing.stepped import Probe, SteppedExecutor


@pytest.fixture
def ros() -> Iterator[None]:
    rclpy.init()
    try:
        yield
    finally:
        rclpy.try_shutdown()


def _read_mcap(path: Path) -> list[tuple[str, int, object]]:
    """(topic, log time ns, decoded message) with the mcap reader and ROS 2 decoder."""
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [(channel.topic, message.log_time, decoded)
                for _, channel, message, decoded in reader.iter_decoded_messages()]


def _read_cut_mcap(path: Path) -> list[tuple[str, object]]:
    """(topic, decoded message) of a file without its end, read record by record."""
    factory, schemas, channels, messages = DecoderFactory(), {}, {}, []
    with path.open("rb") as stream:
        try:
            for record in StreamReader(stream).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    channel = channels[record.channel_id]
                    decode = factory.decoder_for(channel.message_encoding,
                                                 schemas[channel.schema_id])
                    messages.append((channel.topic, decode(record.data)))
        except EndOfFile:  # the cut: everything before it was read
            pass
    return messages


def _record(directory: Path, steps: int) -> tuple[RecorderNode, SteppedExecutor]:
    recorder = RecorderNode(parameter_overrides=[Parameter("directory", value=str(directory))])
    probe = Probe()
    executor = SteppedExecutor([recorder, probe])
    steps_pub = probe.talk("sound_step", Int64MultiArray)
    belief_pub = probe.talk("belief", Float64)
    executor.connected(steps_pub)
    executor.connected(belief_pub)
    for step in range(1, steps + 1):
        steps_pub.publish(Int64MultiArray(data=[7, step, step % 2, 250_000]))
        belief_pub.publish(Float64(data=step / (steps + 1)))
    executor.run_until(lambda: recorder.counts["/belief"] == steps
                       and recorder.counts["/sound_step"] == steps, "all messages recorded")
    return recorder, executor


def test_a_recorded_run_reads_back_with_the_mcap_reader(
    ros: None, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    recorder, executor = _record(tmp_path / "session", 30)
    executor.close()  # closes the bag: metadata.yaml is written
    # The log says where, what it waited for and when it came, and what the bag holds.
    log = [line.split("[recorder_node]: ")[1] for line in capfd.readouterr().err.splitlines()
           if "[recorder_node]: " in line]  # fmt: skip
    assert log[:2] == [f"recording to {tmp_path / 'session'}", "waiting for '/sound_step'"]
    assert log[2].startswith("'/sound_step' received after ")
    assert log[-1].startswith(
        f"recorded 61 messages to {tmp_path / 'session'}: /session_info 1, /sound_step 30,"
        " /belief 30; nothing on /sound, /no_step, /sound_energy, "
    ), log
    assert (tmp_path / "session" / "metadata.yaml").exists()
    messages = _read_mcap(tmp_path / "session" / "session.mcap")
    steps = [m for topic, _, m in messages if topic == "/sound_step"]
    beliefs = [m.data for topic, _, m in messages if topic == "/belief"]
    assert [list(m.data) for m in steps] == [[7, s, s % 2, 250_000] for s in range(1, 31)]
    assert beliefs == [s / 31 for s in range(1, 31)]
    assert [topic for topic, _, _ in messages].count("/session_info") == 1
    times = [t for topic, t, _ in messages if topic == "/belief"]
    assert times == sorted(times) and times[0] > 0


def test_receive_and_publish_times_are_stored_apart(ros: None, tmp_path: Path) -> None:
    before = time.time_ns()
    recorder, executor = _record(tmp_path / "session", 20)
    executor.close()
    with (tmp_path / "session" / "session.mcap").open("rb") as stream:
        times = [(message.publish_time, message.log_time)
                 for _, channel, message in make_reader(stream).iter_messages()
                 if channel.topic == "/belief"]
    assert len(times) == 20
    # Published (the DDS source timestamp) after the test began, received after that.
    assert all(before <= published <= received for published, received in times)
    assert any(published < received for published, received in times)
    publish_order = [published for published, _ in times]
    assert publish_order == sorted(publish_order)


def test_the_recorder_subscribes_every_topic_with_its_publishers_type(ros: None,
                                                                      tmp_path: Path) -> None:
    """A type other than the publisher's never matches: the topic would stay empty."""
    recorder = RecorderNode(parameter_overrides=[Parameter("directory", value=str(tmp_path / "s"))])
    room = rclpy.create_node("room")
    try:
        types = {s.topic_name: s.msg_type for s in recorder.subscriptions}
        at_once = set(RECORDED_TOPICS) - SUBSCRIBED_ONCE_PUBLISHED
        assert {f"/{t}" if not t.startswith("/") else t for t in at_once} <= set(types)
        assert "/partner_present" not in types  # until it has a publisher
        assert types["/speaker_started"] is TimeMsg  # builtin_interfaces/Time
        assert types["/belief"] is Float64
        assert any(p.topic_name == "/session_info" for p in recorder.publishers)
        room.create_publisher(Bool, "partner_present", 10)
        deadline = time.monotonic() + 30.0
        while recorder.count_publishers("/partner_present") == 0:
            assert time.monotonic() < deadline, "the recorder never saw the publisher"
            time.sleep(0.05)  # polls the graph; the deadline bounds it
        recorder._discover()
        types = {s.topic_name: s.msg_type for s in recorder.subscriptions}
        assert types["/partner_present"] is Bool
    finally:
        room.destroy_node()
        recorder.destroy_node()


def test_a_killed_recorder_leaves_the_flushed_chunks_readable(ros: None, tmp_path: Path) -> None:
    recorder, executor = _record(tmp_path / "session", 20)
    recorder._flush()
    # What a kill -9 leaves: the file as flushed, no summary, no metadata.yaml.
    data = (tmp_path / "session" / "session.mcap").read_bytes()
    (tmp_path / "copy.mcap").write_bytes(data)
    recorder.writer = None  # do not close the bag on teardown
    executor.close()
    beliefs = [m.data for topic, m in _read_cut_mcap(tmp_path / "copy.mcap")
               if topic == "/belief"]
    assert beliefs == [s / 21 for s in range(1, 21)]


def test_an_unwritable_directory_is_one_clear_error(tmp_path: Path) -> None:
    (tmp_path / "a_file").write_text("")
    with pytest.raises(BagWriteError, match="cannot create the bag .*a_file"):
        BagWriter(tmp_path / "a_file" / "session")
    (tmp_path / "exists").mkdir()
    with pytest.raises(BagWriteError, match="exists already"):
        BagWriter(tmp_path / "exists")


def test_an_existing_directory_is_refused_at_start_up(ros: None, tmp_path: Path) -> None:
    """As ``ros2 bag record -o DIR``: a session is never written into an existing one."""
    (tmp_path / "session").mkdir()
    with pytest.raises(ConfigError, match="'directory' = '.*session' exists already"):
        RecorderNode(parameter_overrides=[
            Parameter("directory", value=str(tmp_path / "session"))])  # fmt: skip
    assert list((tmp_path / "session").iterdir()) == []


def test_a_bag_that_cannot_be_made_is_refused_at_start_up(ros: None, tmp_path: Path) -> None:
    """As one that exists: a recorder that would record nothing ends (and so the launch)."""
    (tmp_path / "a_file").write_text("")
    for directory in (tmp_path / "a_file" / "session", Path("/proc/infomax_no_bag")):
        with pytest.raises(ConfigError, match=f"'directory' = '{directory}': cannot create"
                                              " the bag"):
            RecorderNode(parameter_overrides=[Parameter("directory", value=str(directory))])
    assert not Path("/proc/infomax_no_bag").exists()


def test_a_recorder_killed_with_kill_9_leaves_a_readable_bag(ros: None, tmp_path: Path) -> None:
    directory = tmp_path / "session"
    child = subprocess.Popen(
        [sys.executable, "-m", "infomax_contingency.nodes.recorder_node", "--ros-args",
         "-p", f"directory:={directory}", "-p", "flush_period_s:=0.1"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    probe = Probe()
    executor = SteppedExecutor([probe])
    try:
        belief_pub = probe.talk("belief", Float64)
        executor.connected(belief_pub, what="the recorder subscribed to belief")
        for step in range(1, 11):
            belief_pub.publish(Float64(data=step / 11))
        mcap_file = directory / "session.mcap"

        def flushed() -> bool:
            cut = _read_cut_mcap(mcap_file) if mcap_file.exists() else []
            return sum(topic == "/belief" for topic, _ in cut) == 10

        executor.run_until(flushed, "the ten beliefs flushed to disk")
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        executor.close()
    assert not (directory / "metadata.yaml").exists()  # killed: no clean close
    beliefs = [m.data for topic, m in _read_cut_mcap(directory / "session.mcap")
               if topic == "/belief"]
    assert beliefs == [step / 11 for step in range(1, 11)]

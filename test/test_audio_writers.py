"""One writer's audio: a second publisher on ``audio`` is ignored, a restarted one is a gap.

The tester's live finding: ``ros2 topic pub /audio ...`` beside the fake room made
mic_node read the room's next chunk as thousands of chunks lost (the sequence numbers of
two writers compared), withhold bits and drop real windows; a refused chunk moved the
numbers too; and a room restarted after an outage (a new writer, numbering from 1) was no
gap at all. Numbers are now followed per writer (``core.flowcontrol.WriterFollower``).
"""

from __future__ import annotations

import array
import math
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from std_msgs.msg import Float32, Float32MultiArray, Int64MultiArray

from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.audio.windows import TopicWindows
from infomax_contingency.core.flowcontrol import WriterFollower, Writing
from infomax_contingency.nodes.audio_topic import writer_of
from infomax_contingency.nodes.graph_node import ERROR
from infomax_contingency.nodes.mic_node import MicNode
from infomax_contingency.nodes.step_topics import parse_bit
from infomax_contingency.sim.fake_room import FakeRoom, as_transmitted
from infomax_contingency.sim.room_config import FakeRoomConfig
from infomax_contingency.testing.stepped import Probe, nodes_on_their_own_executors

NS = 1_000_000_000
RATE = 1000  # Hz: windows of 500 samples in the unit tests


def test_a_writer_follower_tells_writers_by_name_or_by_numbers() -> None:
    named = WriterFollower(switch_s=3.0)
    assert named.judge(1, 0.0, writer=b"room") is Writing.FOLLOWED
    assert named.judge(5, 0.1, writer=b"room") is Writing.FOLLOWED and named.missed == 3
    assert named.judge(6, 0.2, writer=b"pub") is Writing.FOREIGN  # a name decides, not a number
    assert named.judge(1, 3.1, writer=b"room2") is Writing.SWITCHED and named.missed == 0
    numbers = WriterFollower(switch_s=3.0)
    assert all(numbers.judge(n, n * 0.1) is Writing.FOLLOWED for n in range(1, 101))
    assert numbers.judge(1, 10.0) is Writing.FOREIGN  # `ros2 topic pub`: numbered from 1
    assert numbers.judge(101, 10.1) is Writing.FOLLOWED and numbers.missed == 0
    # numbers that skip some: the followed writer's lost messages only while it is alone
    assert numbers.judge(500, 10.2, alone=lambda: False) is Writing.FOREIGN
    assert numbers.judge(104, 10.3, alone=lambda: True) is Writing.FOLLOWED
    assert numbers.missed == 2 and numbers.refused == 2
    assert numbers.judge(1, 13.3) is Writing.SWITCHED and numbers.switches == 1  # a restart
    assert numbers.silent_s == pytest.approx(3.0)
    assert numbers.judge(2, 13.4) is Writing.FOLLOWED


def test_a_writer_follower_tells_a_refused_message_without_following_it() -> None:
    """would_refuse: judge's verdict on another writer, with nothing changed."""
    named = WriterFollower(switch_s=3.0)
    assert not named.would_refuse(7, 0.0, writer=b"pub")  # nobody followed yet
    named.judge(1, 0.0, writer=b"room")
    assert named.would_refuse(1, 0.1, writer=b"pub") and not named.would_refuse(2, 0.1, b"room")
    assert not named.would_refuse(1, 3.5, writer=b"pub")  # the room silent: pub would be taken
    assert (named.refused, named.last, named.writer) == (0, 1, b"room")
    numbers = WriterFollower(switch_s=3.0)
    numbers.judge(5, 0.0)
    assert numbers.would_refuse(1, 0.1) and not numbers.would_refuse(6, 0.1)
    assert numbers.would_refuse(9, 0.1, alone=lambda: False)
    assert not numbers.would_refuse(9, 0.1, alone=lambda: True)  # its own, 3 lost
    assert not numbers.would_refuse(None, 0.1)  # unnumbered, unnamed: taken
    assert (numbers.refused, numbers.last) == (0, 5)


def _chunk(value: float, n: int = 250) -> np.ndarray:
    return np.full(n, value, np.float32)


def test_topic_windows_take_one_writers_chunks_and_a_refused_chunk_moves_nothing() -> None:
    topic = TopicWindows(RATE, 0.5)
    for k in range(1, 5):  # the room: 2 windows
        assert topic.feed(_chunk(0.1), k, k * NS // 4) is Writing.FOLLOWED
    # `ros2 topic pub {data: [.nan, 0.1, 5.0]}`: another writer's, ignored as such (no loss)
    assert topic.feed(np.float32([np.nan, 0.1, 5.0]), 1, 5 * NS // 4) is Writing.FOREIGN
    assert topic.feed(_chunk(0.5, 8), 1, 5 * NS // 4, alone=lambda: False) is Writing.FOREIGN
    for k in range(5, 9):  # the room goes on: no gap, nothing from the other writer
        assert topic.feed(_chunk(0.1), k, (k + 1) * NS // 4) is Writing.FOLLOWED
    windows = topic.take()
    assert len(windows) == 4 and {w.gap_s for w in windows} == {0.0}
    assert (topic.dropped_chunks, topic.bad_chunks, topic.foreign_chunks) == (0, 0, 2)
    with pytest.raises(AudioError, match="NaN|inf"):  # the room's own chunk 9: refused, a loss
        topic.feed(np.float32([np.inf]), 9, 10 * NS // 4)
    topic.feed(_chunk(0.1, 500), 10, 11 * NS // 4)
    (after,) = topic.take()
    assert after.gap_s == 0.5 and topic.dropped_chunks == 1  # chunk 9 is audio lost: a gap


def test_topic_windows_take_a_restarted_writer_after_its_silence_as_a_gap_of_unknown_length(
) -> None:  # fmt: skip
    topic = TopicWindows(RATE, 0.5)
    for k in range(1, 4):
        topic.feed(_chunk(0.1, 500), k, k * NS)
    assert len(topic.take()) == 3
    assert topic.feed(_chunk(0.1, 250), 1, 5 * NS) is Writing.FOREIGN  # 2 s: not silent yet
    assert topic.feed(_chunk(0.1, 250), 1, 19 * NS) is Writing.SWITCHED  # 16 s later: restarted
    topic.feed(_chunk(0.1, 250), 2, 19 * NS + NS // 4)
    (after,) = topic.take()
    assert math.isinf(after.gap_s) and topic.status()["audio_writer_changes"] == 1
    assert topic.dropped_chunks == 0  # unknown: not counted as chunks


def test_a_message_names_its_writer_where_rclpy_gives_one() -> None:
    assert writer_of({"publication_sequence_number": 3}) is None  # Jazzy's rclpy 7.1
    gid = {"implementation_identifier": "rmw_fastrtps_cpp", "data": bytes(range(16))}
    assert writer_of({"publisher_gid": gid}) == bytes(range(16))


# ---------------------------------------------------------------------- mic_node, in process


@pytest.fixture
def run() -> Iterator[Callable[..., tuple[Any, Probe, Any]]]:
    with nodes_on_their_own_executors() as start:
        yield start


def _room_audio(windows: int) -> np.ndarray:
    room = FakeRoom(FakeRoomConfig.preset("noisy", event_rate_hz=2.0), seed=3)
    return np.concatenate([as_transmitted(room.next_window().samples) for _ in range(windows)])


def _message(chunk: np.ndarray) -> Float32MultiArray:
    message = Float32MultiArray()
    message.data = array.array("f", chunk.astype(np.float32).tobytes())
    return message


def _fixed_threshold_mic(run: Callable) -> tuple:
    """mic_node on the 'audio' topic, a fixed -40 dB threshold, started at once."""
    return run(MicNode, source="topic", bit_source="energy", threshold_mode="fixed",
               threshold_db=-40.0, wait_for_listeners=1, start_delay_s=0.0)


def test_mic_windows_the_first_writer_only_and_names_the_second(
    run: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    """The room and a `ros2 topic pub` on `audio`: the room's windows, whole, no gap."""
    node, probe, graph = _fixed_threshold_mic(run)
    steps = probe.listen("sound_step", Int64MultiArray)
    energies = probe.listen("sound_energy", Float32)
    room = probe.talk("audio", Float32MultiArray)
    intruder = graph.add(Probe("intruder")).talk("audio", Float32MultiArray)
    graph.connected(room)
    graph.connected(intruder)
    graph.run_until(lambda: node.started and node.count_publishers("audio") == 2,
                    "start, two publishers on audio")  # fmt: skip
    samples = _room_audio(12)
    chunks = np.array_split(samples, 24)
    for chunk in chunks[:4]:
        room.publish(_message(chunk))
    graph.run_until(lambda: len(energies) == 2, "the room's first windows")
    for k, chunk in enumerate(chunks[4:]):
        room.publish(_message(chunk))
        if k % 5 == 0:  # 0.5 -0.5 ... and now and then a chunk refused for its samples
            intruder.publish(_message(np.float32([0.5, -0.5] * 4)))
            intruder.publish(_message(np.float32([np.nan, 0.1, 5.0])))
    graph.run_until(lambda: len(energies) == 12 and node.source.foreign_chunks == 8,
                    "the room's 12 windows, the intruder's 8 chunks")  # fmt: skip
    expected = window_energies_db(samples.astype(np.float64), 16000, 0.5)
    assert np.array_equal(np.float32([m.data for m in energies]), expected.astype(np.float32))
    assert [parse_bit(m).step for m in steps] == list(range(1, 13))
    values = node.diagnostic_status()[2]
    assert (values["dropped_chunks"], values["bad_chunks"], values["foreign_chunks"]) == (0, 0, 8)
    assert not node.losses.recent(node.now_s())  # another writer's bad chunks lose no audio
    assert values["bits_withheld_after_gap"] == 0 and not any(parse_bit(m).withheld for m in steps)
    node.publish_diagnostics()  # names the second publisher, as on 'sound' and 'sound_step'
    level, message, _ = node.diagnostic_status()
    assert level == ERROR and "another publisher on 'audio'" in message
    err = capfd.readouterr().err
    assert "2 publishers on 'audio': /intruder, /probe" in err
    assert "audio chunk ignored: another writer than the one followed sent it" in err
    assert "were lost" not in err


def test_mic_takes_a_restarted_room_as_a_gap_and_withholds_the_bits_after_it(
    run: Callable, capfd: pytest.CaptureFixture[str]
) -> None:
    """A new writer numbering from 1 after the first fell silent: a gap of unknown length."""
    node, probe, graph = _fixed_threshold_mic(run)
    steps = probe.listen("sound_step", Int64MultiArray)
    room = probe.talk("audio", Float32MultiArray)
    graph.connected(room)
    graph.run_until(lambda: node.started, "the mic's start gate")
    windows = _room_audio(16).reshape(16, 8000)
    for window in windows[:8]:
        room.publish(_message(window))
    graph.run_until(lambda: len(steps) == 8, "the first room's 8 steps")
    probe.destroy_publisher(room)  # the room dies; its successor is a new writer
    # the silence that makes a writer followed is measured on publication times: no wait
    node.source.writers.switch_s = 1e-6
    restarted = graph.add(Probe("restarted")).talk("audio", Float32MultiArray)
    graph.connected(restarted)
    for window in windows[8:]:
        restarted.publish(_message(window))
    graph.run_until(lambda: len(steps) == 16, "the restarted room's 8 steps")
    withheld = [parse_bit(m).withheld for m in steps]
    assert withheld == [0] * 8 + [1] * 5 + [0] * 3  # no decision known: ta2 + 1 withheld
    values = node.diagnostic_status()[2]
    assert values["audio_writer_changes"] == 1 and values["bits_withheld_after_gap"] == 5
    err = capfd.readouterr().err
    assert "now comes from another writer" in err
    assert "were lost (audio of unknown length: a new writer on 'audio')" in err

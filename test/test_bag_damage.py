"""Bags that are damaged, cut by a killed recorder, or not this package's sessions.

Each is read exactly, replayed with a warning naming what is missing (a cut bag), or
refused in one line naming what the bag holds and what is needed — never a traceback,
never silently shorter. ``replay`` and ``analyze`` (the command line), mic_node's
``source: bag`` (:class:`BagReplay`) and controller_node's ``recorded:BAG``
(:func:`recorded_decisions`) read bags through the one reader.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from infomax_contingency.audio.bag import BagReadError, BagWriter, encode, read_topics
from infomax_contingency.audio.bag_replay import BagReplay, recorded_decisions
from infomax_contingency.cli.main import main
from infomax_contingency.eval.sessions import load_session

SESSION = Path(__file__).parent / "data" / "session_demo"
MCAP = SESSION / "session_demo.mcap"


def _copy(tmp_path: Path, name: str, data: bytes, metadata: bool = True) -> Path:
    bag = tmp_path / name
    bag.mkdir()
    (bag / MCAP.name).write_bytes(data)
    if metadata:
        shutil.copy(SESSION / "metadata.yaml", bag / "metadata.yaml")
    return bag


def _one_line_error(capsys, *argv: str) -> str:
    assert main(list(argv)) == 2
    captured = capsys.readouterr()
    assert len(captured.err.strip().splitlines()) == 1, captured.err
    return captured.err


@pytest.mark.parametrize("offset, fill", [
    (39_152, b"\x00"),  # a chunk's header (opcode and length) zeroed
    (42_500, b"\x00"),  # a SerdeError traceback before
    (35_562, b"\xff"),  # a message index's header: a length of 2^64 - 1
    (112_500, b"\x00"),  # a MemoryError before (a record declaring 2^64 bytes)
])
def test_a_damaged_bag_is_refused_in_one_line_by_every_reader(tmp_path, capsys, offset, fill):
    data = MCAP.read_bytes()
    bag = _copy(tmp_path, "damaged", data[:offset] + fill * 40 + data[offset + 40:])
    if offset < 100_000:  # in the data section (the last one damages the summary)
        for command in ("replay", "analyze"):
            assert "is damaged" in _one_line_error(capsys, command, str(bag))
        with pytest.raises(BagReadError, match="is damaged"):
            BagReplay(bag, 0.5, 16_000)
        with pytest.raises(BagReadError, match="is damaged"):
            recorded_decisions(bag)
    else:  # the summary is not needed: the data reads whole
        assert len(load_session(bag).bits) == 120


def test_a_truncated_bag_with_its_metadata_is_refused_naming_what_is_readable(tmp_path,
                                                                              capsys):
    bag = _copy(tmp_path, "truncated", MCAP.read_bytes()[:60_000])
    error = _one_line_error(capsys, "replay", str(bag))
    assert "is damaged: session_demo.mcap is readable only up to byte 39,152 of 60,000" in error


def test_a_bag_cut_by_kill_9_is_replayed_up_to_its_last_chunk_and_says_so(tmp_path, capsys):
    # what a recorder killed with kill -9 leaves: the file as flushed, no summary, no
    # metadata.yaml (test_recorder makes one with a real kill -9 and reads it with mcap)
    bag = _copy(tmp_path, "cut", MCAP.read_bytes()[:70_000], metadata=False)
    assert main(["replay", str(bag)]) == 0
    captured = capsys.readouterr()
    assert "was cut (no metadata.yaml: was its recorder killed?)" in captured.err
    assert "up to its last complete chunk, byte 39,152 of 70,000" in captured.err
    assert "equals the recorded belief at all 29 steps" in captured.out
    assert main(["analyze", str(bag)]) in (0, 1)
    captured = capsys.readouterr()
    assert "was cut" in captured.err and "vocalizations" in captured.out
    replay = BagReplay(bag, 0.5, 16_000)
    assert replay.n_windows == 29 and "was cut" in replay.warnings[0]  # 29 bits, 29 answered
    assert len(recorded_decisions(bag)) == 29
    # the messages read are exactly the complete file's first ones
    whole = read_topics(SESSION, ("/sound_step", "/belief"))
    cut = read_topics(bag, ("/sound_step", "/belief"))
    for topic, messages in cut.items():
        assert [t for t, _ in messages] == [t for t, _ in whole[topic][:len(messages)]]


def _bag(directory: Path, topics: dict[str, tuple[str, dict]]) -> Path:
    writer = BagWriter(directory)
    for topic, (kind, fields) in topics.items():
        writer.add_topic(topic, kind, [{}])
        writer.write(topic, encode(kind, **fields), 1_000)
    writer.close()
    return directory


def test_a_bag_of_another_robots_topics_is_refused_naming_what_it_holds(tmp_path, capsys):
    bag = _bag(tmp_path / "other", {"/camera/info": ("std_msgs/msg/String", {"data": "x"}),
                                    "/odom_rate": ("std_msgs/msg/Float64", {"data": 1.0})})
    for command in ("replay", "analyze"):
        error = _one_line_error(capsys, command, str(bag))
        assert "is not one of this package's sessions: it lacks /sound_step" in error
        assert "needed: /sound_step (std_msgs/msg/Int64MultiArray)" in error
        assert "It holds: /camera/info (std_msgs/msg/String), /odom_rate" in error
    with pytest.raises(BagReadError, match="lacks /audio or /sound_step"):
        BagReplay(bag, 0.5, 16_000)
    with pytest.raises(BagReadError, match="lacks /sound_step and /vocalize_step"):
        recorded_decisions(bag)


def test_a_bag_of_this_robots_topic_names_with_other_types_is_refused(tmp_path, capsys):
    bag = _bag(tmp_path / "types", {
        "/sound_step": ("std_msgs/msg/String", {"data": "1"}),
        "/vocalize_step": ("std_msgs/msg/Int64MultiArray", {"data": [1, 1, 0, 9]}),
        "/audio": ("std_msgs/msg/Float64", {"data": 0.5}),
    })
    for command in ("replay", "analyze"):
        error = _one_line_error(capsys, command, str(bag))
        assert "holds /sound_step (std_msgs/msg/String) of other types" in error
        assert "needed: /sound_step (std_msgs/msg/Int64MultiArray)" in error
    with pytest.raises(BagReadError, match=r"holds /audio \(std_msgs/msg/Float64\), /sound_step"):
        BagReplay(bag, 0.5, 16_000)
    with pytest.raises(BagReadError, match="of other types"):
        recorded_decisions(bag)


def test_what_is_not_a_bag_is_one_line(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert "not a rosbag2 bag" in _one_line_error(capsys, "replay", str(tmp_path / "empty"))
    bad = _copy(tmp_path, "junk", b"not an mcap file at all", metadata=False)
    assert "is not an MCAP file" in _one_line_error(capsys, "analyze", str(bad))
    meta = _copy(tmp_path, "meta", MCAP.read_bytes())
    (meta / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    assert "its metadata.yaml is damaged" in _one_line_error(capsys, "replay", str(meta))


def test_the_session_types_are_the_recorders() -> None:
    from infomax_contingency.audio.bag import SESSION_TYPES
    from infomax_contingency.nodes.recorder_node import RECORDED_TOPICS

    recorded = {("" if name.startswith("/") else "/") + name:
                f"{kind.__module__.split('.')[0]}/msg/{kind.__name__}"
                for name, (kind, _) in RECORDED_TOPICS.items()}
    assert recorded.items() <= SESSION_TYPES.items()
    assert SESSION_TYPES["/audio"] == "std_msgs/msg/Float32MultiArray"


def test_controller_node_on_a_cut_bag_says_it_was_cut(tmp_path, capfd):
    from infomax_contingency.nodes.controller_node import ControllerNode
    from infomax_contingency.testing.stepped import nodes_on_their_own_executors

    bag = _copy(tmp_path, "cut", MCAP.read_bytes()[:70_000], metadata=False)
    with nodes_on_their_own_executors() as start:
        node, _, _ = start(ControllerNode, controller=f"recorded:{bag}")
        assert node.controller.decisions == recorded_decisions(bag)  # up to the cut
    assert "was cut (no metadata.yaml: was its recorder killed?)" in capfd.readouterr().err


def _copy_under_namespaces(tmp_path: Path, namespaces: tuple[str, ...],
                           diagnostics: tuple[tuple[str, str | None], ...] | None = None
                           ) -> Path:
    """The demo session again, every topic but /diagnostics under each of ``namespaces``.

    ``/diagnostics`` holds, for each ``(namespace, memory)`` of ``diagnostics`` (default:
    each of ``namespaces`` with its memory as recorded), the statuses of that namespace's
    nodes, named as a namespaced graph names them (``robot1/belief_node``), belief_node's
    ``memory_steps`` set to ``memory`` unless None: the robots of one domain.
    """
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    types = get_typestore(Stores.ROS2_JAZZY)
    kind = "diagnostic_msgs/msg/DiagnosticArray"
    bag = tmp_path / "namespaced"
    writer = BagWriter(bag)
    with Reader(SESSION) as reader:
        for connection in reader.connections:
            for namespace in namespaces:
                name = (connection.topic if connection.topic == "/diagnostics"
                        else namespace + connection.topic)
                if name not in writer.topics:
                    writer.add_topic(name, connection.msgtype, [])
        for connection, time_ns, data in reader.messages():
            if connection.topic != "/diagnostics":
                for namespace in namespaces:
                    writer.write(namespace + connection.topic, data, time_ns)
                continue
            for namespace, memory in diagnostics or [(n, None) for n in namespaces]:
                array = types.deserialize_cdr(data, kind)
                for status in array.status:
                    status.name = namespace.strip("/") + "/" + status.name
                    for pair in status.values:
                        if pair.key == "memory_steps" and memory is not None:
                            pair.value = memory
                writer.write("/diagnostics", bytes(types.serialize_cdr(array, kind)), time_ns)
    writer.close()
    return bag


def test_a_session_recorded_under_a_namespace_is_read_by_its_plain_topic_names(tmp_path,
                                                                               capsys):
    # `ros2 launch ... namespace:=robot1 record:=true` records /robot1/sound_step, ...:
    # replay said it "holds no sound_step messages" before
    bag = _copy_under_namespaces(tmp_path, ("/robot1",))
    assert len(load_session(bag).bits) == len(load_session(SESSION).bits) > 0
    assert main(["replay", str(bag)]) == 0
    assert "equals the recorded belief" in capsys.readouterr().out
    assert len(recorded_decisions(bag)) == len(recorded_decisions(SESSION))


def test_a_namespaced_session_replays_with_its_own_belief_nodes_memory(tmp_path, capsys):
    """Two robots on one domain: robot1's bag holds robot2's diagnostics too.

    robot2's belief_node kept another memory: the replay of robot1's session takes
    robot1's (60), not that of the last belief_node that reported.
    """
    bag = _copy_under_namespaces(tmp_path, ("/robot1",),
                                 diagnostics=(("/robot1", None), ("/robot2", "20")))
    assert load_session(bag).memory_steps == 60
    assert main(["replay", str(bag)]) == 0
    assert "equals the recorded belief at all 120 steps" in capsys.readouterr().out


@pytest.mark.parametrize("diagnostics, problem", [
    ((("/robot2", "20"),), "no memory_steps of this session's robot1/belief_node, only of"
                           " robot2/belief_node"),
    ((("/robot1", None), ("/robot1", "20")), "robot1/belief_node report memory_steps 20 and 60"),
])
def test_a_belief_node_memory_that_cannot_be_told_is_one_line(tmp_path, capsys, diagnostics,
                                                              problem):
    """Only another robot's memory, or two of one name that differ: said, not guessed."""
    bag = _copy_under_namespaces(tmp_path, ("/robot1",), diagnostics)
    for command in (["replay", str(bag)], ["replay", str(bag), "--actions", "rule"],
                    ["plot", "--session", str(bag), "--out", str(tmp_path / "p.png")]):
        error = _one_line_error(capsys, *command)
        assert problem in error and "give --memory N" in error
    assert main(["replay", str(bag), "--memory", "60"]) == 0
    assert "equals the recorded belief" in capsys.readouterr().out


def test_a_bag_of_two_namespaced_robots_is_refused_naming_both(tmp_path, capsys):
    bag = _copy_under_namespaces(tmp_path, ("/robot1", "/robot2"))
    error = _one_line_error(capsys, "replay", str(bag))
    assert "several robots (/robot1, /robot2)" in error


def _copy_saying_its_belief_model(tmp_path: Path, k2_per_lag: str) -> Path:
    """The demo session (recorded with one K2) with its belief_node saying ``k2_per_lag``."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    types = get_typestore(Stores.ROS2_JAZZY)
    kind = "diagnostic_msgs/msg/DiagnosticArray"
    key_value = types.types["diagnostic_msgs/msg/KeyValue"]
    bag = tmp_path / f"says_{k2_per_lag}"
    writer = BagWriter(bag)
    with Reader(SESSION) as reader:
        for connection in reader.connections:
            writer.add_topic(connection.topic, connection.msgtype, [])
        for connection, time_ns, data in reader.messages():
            if connection.topic == "/diagnostics":
                array = types.deserialize_cdr(data, kind)
                for status in array.status:
                    if status.name.split(":", 1)[0] == "belief_node":
                        status.values.append(key_value(key="k2_per_lag", value=k2_per_lag))
                data = bytes(types.serialize_cdr(array, kind))
            writer.write(connection.topic, data, time_ns)
    writer.close()
    return bag


def test_the_belief_model_a_session_says_is_the_one_it_is_replayed_with(tmp_path, capsys):
    one_k2 = str(Path(__file__).parent / "data" / "robot_one_k2.yaml")
    says_one_k2 = _copy_saying_its_belief_model(tmp_path, "False")
    for command in (["replay", str(says_one_k2)],
                    ["plot", "--session", str(says_one_k2), "--out", str(tmp_path / "p.png")]):
        error = _one_line_error(capsys, *command)
        assert ("belief_node had one K2 (k2_per_lag false); the parameter set robot (--params)"
                " has one K2 per agent timer value: give --params with k2_per_lag: false") in error
    assert main(["replay", str(says_one_k2), "--params", one_k2]) == 0
    out = capsys.readouterr().out
    assert "equals the recorded belief at all 120 steps" in out and "does not say" not in out
    # a session that says one K2 per lag is replayed so, even where one K2 would equal
    assert main(["replay", str(_copy_saying_its_belief_model(tmp_path, "True"))]) == 1
    assert "DIFFERS" in capsys.readouterr().out


def test_a_session_that_does_not_say_its_belief_model_is_told_by_its_beliefs(capsys):
    # recorded with one K2 before belief_node said so: replayed with the model that equals
    assert main(["replay", str(SESSION)]) == 0
    out = capsys.readouterr().out
    assert "equals the recorded belief at all 120 steps" in out
    assert ("with one K2 (k2_per_lag false: the session does not say its belief model, and"
            " its beliefs are that one's)") in out
    assert main(["replay", str(SESSION), "--memory", "3"]) == 1  # neither model equals
    out = capsys.readouterr().out
    assert "DIFFERS" in out and "k2_per_lag" not in out

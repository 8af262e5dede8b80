r"""Recorded sessions: the committed bag replays to its recorded belief, read two ways.

``test/data/session_demo`` was made with (120 steps of the responsive fake room, no
audio topic, about 130 KB)::

    infomax-contingency demo --steps 120 --seed 3 --leave-at -1 --no-record-audio \
        --record test/data/session_demo
"""

from __future__ import annotations

import json
import shutil
import stat
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from infomax_contingency.audio.bag import read_topics
from infomax_contingency.cli.main import main
from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.sessions import load_session
from test_rooms_experiment import fifo_with_a_reader

SESSION = Path(__file__).parent / "data" / "session_demo"
JSON_KEYS = {"t", "time_s", "z", "y", "u", "belief", "entropy", "ratio"}


def test_the_committed_session_replays_to_the_recorded_belief_exactly(capsys) -> None:
    assert main(["replay", str(SESSION), "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    session = load_session(SESSION)
    assert len(rows) == len(session.beliefs) == 120
    assert [row["belief"] for row in rows] == session.beliefs
    assert JSON_KEYS <= set(rows[0])
    assert [row["u"] for row in rows] == [int(u) for _, u in session.decisions]


def test_a_replay_with_other_memory_differs_and_says_so(capsys) -> None:
    assert main(["replay", str(SESSION), "--memory", "3"]) == 1
    assert "DIFFERS" in capsys.readouterr().out


def test_the_bag_reads_the_same_with_rosbags_and_with_mcap() -> None:
    topics = ("/sound_step", "/vocalize_step", "/belief", "/posture")
    by_rosbags = read_topics(SESSION, topics)
    by_mcap: dict[str, list] = {topic: [] for topic in topics}
    (mcap_file,) = SESSION.glob("*.mcap")
    with mcap_file.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(topics=list(topics)):
            by_mcap[channel.topic].append((message.log_time, decoded))
    for topic in topics:
        assert [t for t, _ in by_rosbags[topic]] == [t for t, _ in by_mcap[topic]], topic
        values = [m.data for _, m in by_rosbags[topic]]
        assert [list(v) if topic.endswith("_step") else v for v in values] == [
            list(m.data) if topic.endswith("_step") else m.data for _, m in by_mcap[topic]
        ], topic
    assert len(by_rosbags["/belief"]) == 120


@pytest.mark.parametrize("arguments, message", [
    (["replay", "/nonexistent/session"], "cannot read the session"),
    (["replay", str(SESSION), "--actions", "channel:1"], "goes with a wav file"),
    (["replay", str(SESSION), "--memory", "-1"], "--memory must be >= 0"),
    (["replay", str(SESSION), "--threshold-db", "-30"], "--threshold-db applies to a wav file"),
    (["replay", str(SESSION), "--mic-channel", "1"], "--mic-channel applies to a wav file"),
    (["replay", str(SESSION), "--calibrate"], "--calibrate applies to a wav file"),
])
def test_bad_replay_input_is_one_line_and_status_2(arguments, message, capsys) -> None:
    assert main(arguments) == 2
    error = capsys.readouterr().err
    assert message in error and len(error.strip().splitlines()) == 1


def test_demo_refuses_to_record_over_an_existing_directory(tmp_path: Path, capsys) -> None:
    assert main(["demo", "--record", str(tmp_path)]) == 2
    assert "exists already" in capsys.readouterr().err


def test_an_empty_or_linked_bag_directory_is_refused_before_a_node_starts(tmp_path) -> None:
    """``demo --record ""`` recorded nothing without a word; a dangling link was followed.

    The checks are called as the commands call them, before any node starts.
    """
    from infomax_contingency.cli.calibration_session import _check
    from infomax_contingency.cli.demo_checks import check_arguments
    from infomax_contingency.cli.main import build_parser

    parser = build_parser()
    with pytest.raises(ValueError, match="^--record: the path is empty; name a new directory$"):
        check_arguments(parser.parse_args(["demo", "--record", ""]))
    (tmp_path / "link").symlink_to(tmp_path / "nowhere")
    for argv in (["demo", "--record"], ["calibration-session", "--fake-room", "--out"]):
        with pytest.raises(ValueError, match="link: exists already; name a new directory"):
            (check_arguments if argv[0] == "demo" else _check)(
                parser.parse_args([*argv, str(tmp_path / "link")]))
    with pytest.raises(ValueError, match="^--out: the path is empty"):
        _check(parser.parse_args(["calibration-session", "--fake-room", "--out", ""]))
    assert not (tmp_path / "nowhere").exists()


def test_analyze_finds_the_fake_rooms_periods_and_writes_a_parameter_file(
    tmp_path: Path, capsys
) -> None:
    out = tmp_path / "params.yaml"
    status = main(["analyze", str(SESSION), "--out", str(out)])
    text = capsys.readouterr().out
    assert "only 13 vocalizations" in text and status == 1  # a short session: says so
    written = ModelParams.load(str(out))
    # The room's own chirp starts 0.15 s into the window after the decision (lag 0);
    # replies start 1.0-1.4 s after it and last into the next window (lags 2 and 3).
    assert (written.ts1, written.ts2, written.ta1, written.ta2) == (0, 0, 2, 3)
    table = tmp_path / "table.npz"
    assert main(["solve", "--params", str(out), "--mode", "episodic", "--horizon", "4",
                 "--out", str(table)]) == 0


def test_analyze_writes_over_nothing_but_a_regular_file(tmp_path: Path, capsys) -> None:
    """A FIFO at --out is refused before the study (it hung); so are --out and --plot as one."""
    with fifo_with_a_reader(tmp_path / "fifo") as fifo:
        assert main(["analyze", str(SESSION), "--out", str(fifo)]) == 2
        output = capsys.readouterr()
        assert output.err == (f"infomax-contingency analyze: error: --out {fifo} is not a"
                              " regular file (it is a FIFO): nothing is written over it; give a"
                              " new name or a regular file\n")
        assert output.out == ""  # refused before the study
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
    same = tmp_path / "same.png"
    assert main(["analyze", str(SESSION), "--out", str(same), "--plot", str(same)]) == 2
    assert "name one file" in capsys.readouterr().err and not same.exists()


def test_analyze_says_a_recording_its_metadata_does_not_list_was_not_read(
        tmp_path: Path, capsys) -> None:
    """Only the files metadata.yaml lists are read: an added recording is named, once."""
    bag = tmp_path / "bag"
    shutil.copytree(SESSION, bag)
    shutil.copy(bag / "session_demo.mcap", bag / "later.mcap")
    assert main(["analyze", str(bag)]) == 1  # the short session's shortcomings, as before
    assert capsys.readouterr().err == (
        f"warning: the session {bag} also holds later.mcap, which its metadata.yaml does not"
        " list: not read (another recording? give each its own directory)\n")
    assert main(["analyze", str(SESSION)]) == 1
    assert capsys.readouterr().err == ""


def test_analyze_draws_the_figure(tmp_path: Path) -> None:
    figure = tmp_path / "fig4.png"
    main(["analyze", str(SESSION), "--plot", str(figure)])
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_analyze_refuses_a_session_given_twice(tmp_path: Path, capsys) -> None:
    """The same bag twice (however named) would count its evidence twice."""
    (tmp_path / "link").symlink_to(SESSION.resolve())
    for again in (str(SESSION), str(tmp_path / "link")):
        assert main(["analyze", str(SESSION), again]) == 2
        error = capsys.readouterr().err
        assert "is given twice" in error and len(error.strip().splitlines()) == 1
    copy = tmp_path / "copy"
    shutil.copytree(SESSION, copy)  # a copy: the same recording under another name
    assert main(["analyze", str(SESSION), str(copy)]) == 2
    error = capsys.readouterr().err
    assert f"and {copy} are one recording (mic_node stream " in error, error
    assert len(error.strip().splitlines()) == 1

"""Session bags with malformed step messages, a late recorder, or nothing to compare.

A malformed ``sound_step`` or ``vocalize_step`` (fewer fields than the contract, as
``ros2 topic pub --once /sound_step std_msgs/Int64MultiArray "{data: [5]}"`` leaves in a
recording) is skipped by every reader, as the live nodes ignore it, with one warning
line per topic; a recorder that joined after mic_node's first steps is named in the
replay's verdict; a replay that compared nothing is no success.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from infomax_contingency.audio.bag import BagWriter, encode
from infomax_contingency.audio.bag_replay import BagReplay, recorded_decisions
from infomax_contingency.cli.main import main
from infomax_contingency.core.model import NAMED_PARAMS
from infomax_contingency.core.stepfields import bit_of, decision_of
from infomax_contingency.eval.sessions import (
    OFFLINE_STREAM,
    load_session,
    replay_recorded,
    write_offline_session,
)

STEPS = 30
BITS = [k % 4 == 1 for k in range(STEPS)]
DECISIONS = [k % 6 == 4 for k in range(STEPS)]
QOS = [{"history": 1, "depth": 1000, "reliability": 1, "durability": 2}]
ARRAY = "std_msgs/msg/Int64MultiArray"


def _beliefs(tmp_path: Path, bits: list[bool] = BITS, withheld: tuple[bool, ...] = ()
             ) -> list[float]:
    """belief_node's beliefs of the whole session (the replay of a complete bag)."""
    clean = write_offline_session(tmp_path / "clean", bits, DECISIONS, [0.5] * STEPS, 0.5,
                                  withheld=withheld)
    return [r.belief for r in replay_recorded(load_session(clean), NAMED_PARAMS["robot"])]


def _bag(directory: Path, steps: range, beliefs: list[float], forged: dict | None = None,
         bits: list[bool] = BITS, withheld: tuple[bool, ...] = ()) -> Path:
    """A session of the given steps (from 1), ``beliefs`` before them; ``forged`` first."""
    writer = BagWriter(directory)
    for topic, kind in (("/sound_step", ARRAY), ("/vocalize_step", ARRAY),
                        ("/belief", "std_msgs/msg/Float64")):  # fmt: skip
        writer.add_topic(topic, kind, QOS)
    for topic, data in (forged or {}).items():
        writer.write(topic, encode(ARRAY, data=data), 1)
    start = 10**9
    for k, belief in enumerate(beliefs[: len(beliefs) - len(steps)]):  # of steps not recorded
        writer.write("/belief", encode("std_msgs/msg/Float64", data=belief), start + k)
    for step in steps:
        now, w = start + round(step * 0.5e9), int(bool(withheld) and withheld[step - 1])
        writer.write("/sound_step", encode(ARRAY, data=[OFFLINE_STREAM, step,
                     int(bits[step - 1]), 500000, w]), now)  # fmt: skip
        writer.write("/vocalize_step", encode(ARRAY, data=[OFFLINE_STREAM, step,
                     int(DECISIONS[step - 1]), 2]), now + 1)  # fmt: skip
    for k, belief in enumerate(beliefs[-len(steps):]):
        writer.write("/belief", encode("std_msgs/msg/Float64", data=belief),
                     start + round((steps[0] + k) * 0.5e9) + 2)
    writer.close()
    return directory


@pytest.mark.parametrize("topic", ["/sound_step", "/vocalize_step"])
def test_a_malformed_step_message_is_skipped_by_every_reader(tmp_path: Path, topic: str,
                                                             capsys) -> None:
    beliefs = _beliefs(tmp_path)
    clean = _bag(tmp_path / "bag", range(1, STEPS + 1), beliefs)
    forged = _bag(tmp_path / "forged", range(1, STEPS + 1), beliefs, {topic: [123456]})
    assert main(["replay", str(forged)]) == 0
    captured = capsys.readouterr()
    assert "replayed belief equals the recorded belief at all 30 steps" in captured.out
    assert captured.err.count("\n") == 1
    assert f"warning: {topic}: skipped 1 malformed message(s)" in captured.err
    assert load_session(forged) == load_session(clean)
    assert recorded_decisions(forged) == recorded_decisions(clean)  # controller recorded:BAG
    replay, original = BagReplay(forged, 0.5, 16000), BagReplay(clean, 0.5, 16000)  # source: bag
    assert replay.windows == original.windows and replay.withheld == original.withheld
    assert replay.warnings == ([captured.err.strip()[len("warning: "):]]
                               if topic == "/sound_step" else [])  # it reads no decisions
    assert main(["replay", str(forged), "--actions", "rule"]) == 0
    assert "30 steps" in capsys.readouterr().out
    main(["analyze", str(clean)])
    expected = capsys.readouterr().out
    main(["analyze", str(forged)])
    assert capsys.readouterr().out == expected


def test_a_bag_of_malformed_bits_only_is_one_line(tmp_path: Path, capsys) -> None:
    bag = _bag(tmp_path / "forged", range(1, 1), [], {"/sound_step": [], "/vocalize_step": []})
    assert main(["replay", str(bag)]) == 2
    err = capsys.readouterr().err
    assert "holds no valid sound_step messages" in err and "Traceback" not in err


def test_the_core_rules_are_the_live_nodes(tmp_path: Path) -> None:
    assert bit_of([5]) is None and decision_of([5]) is None and bit_of([]) is None
    assert bit_of([1, 2, 1, 500000]).withheld is False
    assert bit_of([1, 2, 1, 500000, 1]).observation.bit is True
    assert decision_of([1, 2, 1, 0]) is None and decision_of([1, 2, 1, 7]).vocalize


@pytest.mark.parametrize("beliefs_of_missing", [True, False])
def test_a_late_recorder_is_named_and_compared_from_its_first_step(
        tmp_path: Path, beliefs_of_missing: bool, capsys) -> None:
    """Steps 1-3 not recorded: the replay lacks their history, and says so."""
    beliefs = _beliefs(tmp_path)
    recorded = beliefs if beliefs_of_missing else beliefs[3:]
    bag = _bag(tmp_path / "late", range(4, STEPS + 1), recorded)
    assert main(["replay", str(bag)]) == 1
    out = capsys.readouterr().out
    assert "the recorder joined late: the bag's first bit is step 4 of its stream" in out
    assert "compared from step 4" in out and "second publisher" not in out
    assert ("after the 3 beliefs of the steps not recorded" in out) == beliefs_of_missing
    assert f"{len(recorded)} beliefs recorded, 27 compared" in out


def test_a_late_recorder_after_steps_that_changed_nothing_replays_equal(tmp_path: Path,
                                                                       capsys) -> None:
    """Steps 1-3 withheld and not answered leave the belief as it starts: exact equality."""
    bits, withheld = [True] * STEPS, (True, True, True) + (False,) * (STEPS - 3)
    beliefs = _beliefs(tmp_path, bits, withheld)
    bag = _bag(tmp_path / "late", range(4, STEPS + 1), beliefs, bits=bits, withheld=withheld)
    assert main(["replay", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "equals the recorded belief at all 27 steps compared" in out
    assert "joined late" in out


def test_a_bag_whose_only_later_step_jumps_ahead_compares_nothing_and_fails(tmp_path: Path,
                                                                           capsys) -> None:
    writer = BagWriter(tmp_path / "gap")
    for topic in ("/sound_step", "/vocalize_step"):
        writer.add_topic(topic, ARRAY, QOS)
    for k, step in enumerate((1, 10**9)):
        writer.write("/sound_step", encode(ARRAY, data=[7, step, 1, 500000, 0]), 10**18 + k)
        writer.write("/vocalize_step", encode(ARRAY, data=[7, step, k, 9]), 10**18 + k)
    writer.close()
    assert main(["replay", str(tmp_path / "gap")]) == 1
    out = capsys.readouterr().out
    assert "nothing was compared: no belief was recorded" in out and "equals" not in out


def test_plotting_a_session_without_an_answered_step_is_one_line(tmp_path: Path, capsys
                                                                 ) -> None:
    bag = _bag(tmp_path / "forged", range(1, 1), [], {"/sound_step": [7, 1, 1, 500000, 0],
                                                      "/vocalize_step": [7]})
    assert main(["plot", "--session", str(bag), "--out", str(tmp_path / "p.png")]) == 2
    err = capsys.readouterr().err
    assert "has no step to plot" in err and "Traceback" not in err

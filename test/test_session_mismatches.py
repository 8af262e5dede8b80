"""Sessions that the replay or the analysis cannot take as given: named in one line.

Windows of another length than ``--params``' dt, sessions of different windows pooled,
belief_node's memory of another robot on the domain, a restarted mic_node or belief_node,
a step recorded twice: each is named, never a bare difference or a wrong number.
"""

from __future__ import annotations

from pathlib import Path

from exact_beliefs import MEMORY, offline_beliefs
from infomax_contingency.audio.bag import BagWriter, encode
from infomax_contingency.cli.main import main
from infomax_contingency.eval.sessions import write_offline_session

STEPS = 30
BITS = [k % 4 == 1 for k in range(STEPS)]
DECISIONS = [k % 6 == 4 for k in range(STEPS)]
ARRAY = "std_msgs/msg/Int64MultiArray"
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"


def _one_line_error(capsys, *arguments: str) -> str:
    assert main(list(arguments)) == 2
    error = capsys.readouterr().err
    assert len(error.strip().splitlines()) == 1 and "Traceback" not in error, error
    return error


def test_windows_other_than_the_params_dt_are_refused_naming_both(tmp_path: Path,
                                                                  capsys) -> None:
    """A session of the paper's 0.8 s windows, replayed or analyzed with robot's 0.5 s."""
    paper = write_offline_session(tmp_path / "paper", BITS, DECISIONS, [0.5] * STEPS, 0.8)
    robot = write_offline_session(tmp_path / "robot", BITS, DECISIONS, [0.5] * STEPS, 0.5)
    expected = (f"the session {paper} has windows of 0.8 s; the parameter set robot (--params)"
                " has windows of 0.5 s: give --params with dt 0.8 (paper)")
    for command in (["replay", str(paper)], ["replay", str(paper), "--actions", "rule"],
                    ["analyze", str(paper)],
                    ["plot", "--session", str(paper), "--out", str(tmp_path / "p.png")]):
        assert expected in _one_line_error(capsys, *command)
    assert main(["analyze", str(paper), "--params", "paper"]) == 1  # too few sounds: said
    assert "windows of 0.8 s" in capsys.readouterr().out
    error = _one_line_error(capsys, "analyze", str(paper), str(robot), "--params", "paper")
    assert (f"windows of different lengths ({robot}: 0.5 s, {paper}: 0.8 s)" in error)



def test_every_restarted_belief_node_is_replayed_from_its_join(tmp_path: Path, capsys) -> None:
    """Two restarts: steps 1-8 by the first node, 11-19 by the second, 22-30 by the third.

    The second published a step past the last it reported (19 against 18); a belief
    changed in the third one's part is found, not left uncompared.
    """
    bits, decisions = _fields(7, range(1, STEPS + 1))
    pairs = [(b[2] == 1, bool(d[2])) for b, d in zip(bits, decisions, strict=True)]
    parts = [offline_beliefs([(pairs[:8], "start")]),
             offline_beliefs([(pairs[10:19], "joined")]),
             offline_beliefs([(pairs[21:], "joined")])]  # fmt: skip
    instances = ((11, 8, 8), (22, 18, 8), (33, 25, 4))  # joined at 18 - 8 + 1, 25 - 4 + 1
    bag = _session(tmp_path / "twice", bits, decisions, sum(parts, []), instances=instances)
    assert main(["replay", str(bag)]) == 0
    out = capsys.readouterr().out
    assert ("compared the first one's 8 beliefs; and the new one's 9 beliefs, replayed from"
            " step 11 with zero counts (the one before published 8); the new one's 9 beliefs,"
            " replayed from step 22 with zero counts (the one before published 9); 26 recorded"
            " beliefs compared in all)") in out, out
    beliefs = sum(parts, [])
    beliefs[8 + 9 + 4] += 0.125  # the third one's fifth
    other = _session(tmp_path / "changed", bits, decisions, beliefs, instances=instances)
    assert main(["replay", str(other)]) == 1
    out = capsys.readouterr().out
    assert ("DIFFERS from the recorded one after the belief_node restart: no split of the 26"
            " recorded beliefs gives the first one's and those of a new one from steps 11, 22"
            " with zero counts") in out, out

def _session(directory: Path, bits: list[list[int]], decisions: list[list[int]],
             beliefs: list[float], resets: int = 0,
             instances: tuple[tuple[int, int, int], ...] = (), memory: str = str(MEMORY),
             node: str = "belief_node") -> Path:
    """A session bag: ``sound_step`` and ``vocalize_step`` fields in the order given.

    Message ``k`` of each topic is received at ``k`` x 0.5 s (a bit, then its decision,
    then a belief); /diagnostics of ``node``: ``memory`` (60, the yardstick's) and ``resets``,
    and one more report per ``(listener_id, last_step, steps)`` of ``instances``.
    """
    from rosbags.typesys import Stores, get_typestore

    types = get_typestore(Stores.ROS2_JAZZY)
    writer = BagWriter(directory)
    for topic, kind in (("/sound_step", ARRAY), ("/vocalize_step", ARRAY),
                        ("/belief", "std_msgs/msg/Float64"), ("/diagnostics", DIAGNOSTICS)):
        writer.add_topic(topic, kind, [])
    start = 10**18
    for topic, messages in (("/sound_step", bits), ("/vocalize_step", decisions)):
        for k, data in enumerate(messages):
            writer.write(topic, encode(ARRAY, data=data), start + k * 500_000_000 + 1)
    for k, belief in enumerate(beliefs):
        writer.write("/belief", encode("std_msgs/msg/Float64", data=belief),
                     start + k * 500_000_000 + 2)
    header = types.types["std_msgs/msg/Header"](
        stamp=types.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="")
    reports = [()] + [(("listener_id", str(listener)), ("last_step", str(last)),
                       ("steps", str(steps))) for listener, last, steps in instances]
    for k, more in enumerate(reports):
        pairs = [types.types["diagnostic_msgs/msg/KeyValue"](key=key, value=value)
                 for key, value in (("memory_steps", memory), ("resets", str(resets)),
                                    *more)]  # fmt: skip
        status = types.types["diagnostic_msgs/msg/DiagnosticStatus"](
            level=0, name=f"{node}: P(S=1)", message="", hardware_id=f"/{node}",
            values=pairs)
        array = types.types[DIAGNOSTICS](header=header, status=[status])
        writer.write("/diagnostics", bytes(types.serialize_cdr(array, DIAGNOSTICS)),
                     start + len(bits) * 500_000_000 + k)
    writer.close()
    return directory


def _fields(stream: int, steps: range, bits: list[bool] = BITS) -> tuple[list, list]:
    """``sound_step`` and ``vocalize_step`` fields of ``steps`` of ``stream`` (controller 2)."""
    return ([[stream, s, int(bits[(s - 1) % STEPS]), 500000, 0] for s in steps],
            [[stream, s, int(DECISIONS[(s - 1) % STEPS]), 2] for s in steps])


def test_a_step_recorded_twice_is_named_as_a_second_writer(tmp_path: Path, capsys) -> None:
    """A forged bit for step 11 (the true stream's id) before the true one.

    The live nodes told it by its writer's DDS numbers and ignored it; the bag holds no
    writer: the replay names the step and what it cannot tell, not a bare difference.
    """
    bits, decisions = _fields(7, range(1, STEPS + 1))
    pairs = [(b[2] == 1, bool(d[2])) for b, d in zip(bits, decisions, strict=True)]
    beliefs = offline_beliefs([(pairs, "start")])
    forged = [7, 11, 1 - bits[10][2], 500000, 0]
    bag = _session(tmp_path / "forged", [*bits[:10], forged, *bits[10:]], decisions, beliefs)
    assert main(["replay", str(bag)]) == 1
    out = capsys.readouterr().out
    assert "DIFFERS from the recorded one at step 11" in out
    assert ("the bit of step 11 recorded twice: a second writer (forged?); the live nodes"
            " ignored its messages") in out and "cannot tell which" in out


def test_a_restarted_mic_node_is_named_and_replayed_across(tmp_path: Path, capsys) -> None:
    """mic_node restarted after step 20: a new stream, which belief_node follows on.

    The replay follows it as belief_node does (counts kept, the timer forgotten) and
    says so; the beliefs of the new stream are no second publisher's.
    """
    first_bits, first_decisions = _fields(7, range(1, 21))
    later_bits, later_decisions = _fields(8, range(1, 11))
    segments = [([(b[2] == 1, bool(d[2])) for b, d in zip(bits, decisions, strict=True)], how)
                for bits, decisions, how in ((first_bits, first_decisions, "start"),
                                             (later_bits, later_decisions, "new stream"))]
    bag = _session(tmp_path / "restart", first_bits + later_bits,
                   first_decisions + later_decisions, offline_beliefs(segments))
    assert main(["replay", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "equals the recorded belief at all 30 steps compared" in out, out
    assert ("mic_node restarted (stream 8 after step 20): replayed across it as belief_node"
            " follows it (counts kept, the timer forgotten)") in out, out
    assert "second publisher" not in out
    figure = tmp_path / "restart.png"  # its figure: the same replay, the timer forgotten there
    assert main(["plot", "--session", str(bag), "--out", str(figure)]) == 0, capsys.readouterr()
    assert figure.stat().st_size > 0 and "30 steps" in capsys.readouterr().out


def test_a_reset_belief_node_is_replayed_with_its_reset(tmp_path: Path, capsys) -> None:
    """belief_node's ~/reset between steps 15 and 16 (its diagnostics count one reset)."""
    bits, decisions = _fields(7, range(1, STEPS + 1))
    pairs = [(b[2] == 1, bool(d[2])) for b, d in zip(bits, decisions, strict=True)]
    beliefs = offline_beliefs([(pairs[:15], "start"), (pairs[15:], "reset")])
    bag = _session(tmp_path / "reset", bits, decisions, beliefs, resets=1)
    assert main(["replay", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "equals the recorded belief at all 30 steps compared" in out
    assert ("belief_node was reset during the session (diagnostics: resets 1): replayed with"
            " the history forgotten before step(s) 16") in out
    twice = _session(tmp_path / "twice", bits, decisions, beliefs, resets=2)
    assert main(["replay", str(twice)]) == 0  # the second left no trace: equal, and said
    assert "(diagnostics: resets 2): replayed" in capsys.readouterr().out
    beliefs[20] += 0.125  # a difference no reset explains
    other = _session(tmp_path / "other", bits, decisions, beliefs, resets=2)
    assert main(["replay", str(other)]) == 1
    out = capsys.readouterr().out
    assert "DIFFERS from the recorded one at step 21" in out
    assert "1 reset(s) not located: compared up to step 21" in out


def test_a_restarted_belief_node_is_named_and_both_replayed(tmp_path: Path, capsys) -> None:
    """belief_node killed after step 12, a new one joined at step 16 with zero counts.

    Its diagnostics report another listener_id; the replay compares the first one's
    beliefs and the new one's, replayed from its join, where it blamed a recorder that
    missed beliefs.
    """
    bits, decisions = _fields(7, range(1, STEPS + 1))
    pairs = [(b[2] == 1, bool(d[2])) for b, d in zip(bits, decisions, strict=True)]
    first = offline_beliefs([(pairs[:12], "start")])
    later = offline_beliefs([(pairs[15:], "joined")])  # zero counts, the timer unknown
    instances = ((11, 12, 12), (22, 0, 0), (22, 17, 2))  # the second joined at 17 - 2 + 1 = 16,
    # reporting first before it had joined (no step: last_step 0, steps 0)
    bag = _session(tmp_path / "restarted", bits, decisions, first + later, instances=instances)
    assert main(["replay", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "equals the recorded belief at all 12 steps compared" in out, out
    assert ("belief_node restarted (a new one joined at step 16 with zero counts, the one"
            " before reported step 12 last, its diagnostics say): compared the first one's 12"
            " beliefs; and the new one's 15 beliefs, replayed from step 16 with zero counts"
            " (the one before published 12); 27 recorded beliefs compared in all)") in out, out
    for wrong, where in ((first[5] + 0.125, 5), (later[3] + 0.125, 12 + 3)):
        beliefs = first + later
        beliefs[where] = wrong
        other = _session(tmp_path / f"other{where}", bits, decisions, beliefs,
                         instances=instances)  # fmt: skip
        assert main(["replay", str(other)]) == 1
        out = capsys.readouterr().out
        assert "DIFFERS" in out and ("at step 6" in out if where == 5 else
                                     "after the belief_node restart" in out), out


def test_a_split_among_the_most_restarts_compared_is_found_or_refused() -> None:
    """A new belief_node claimed at every step (forged diagnostics, or a node crashing in a loop).

    As many restarts as a replay compares, each node allowed to have published nothing:
    a split that accounts for every recorded belief is found, and none when the last
    belief matches no node's replay.
    """
    from infomax_contingency.eval.session_verdict import MOST_RESTARTS_COMPARED, _split_beliefs

    nodes = MOST_RESTARTS_COMPARED + 1
    recorded = [0.5] * nodes
    replays = [[0.5] * 3 for _ in range(nodes)]  # each agrees for as far as it could go
    firsts = list(range(1, nodes + 1))
    counts = _split_beliefs(recorded, replays, firsts, [0] * (nodes - 1))
    assert counts is not None and sum(counts) == nodes and all(c in (0, 1, 2, 3) for c in counts)
    recorded[-1] = 0.25  # the last belief changed: no node's replay has it
    assert _split_beliefs(recorded, replays, firsts, [0] * (nodes - 1)) is None


def test_more_restarts_than_compared_are_named(tmp_path: Path, capsys) -> None:
    """Diagnostics claiming more belief_node restarts than a replay splits: said, not tried.

    Exit status 1: the later nodes' beliefs are not shown equal (they may be anything).
    """
    from infomax_contingency.eval.session_verdict import MOST_RESTARTS_COMPARED

    bits, decisions = _fields(7, range(1, STEPS + 1))
    pairs = [(b[2] == 1, bool(d[2])) for b, d in zip(bits, decisions, strict=True)]
    restarts = MOST_RESTARTS_COMPARED + 1
    instances = ((11, STEPS, STEPS),) + tuple((100 + k, STEPS, 1) for k in range(restarts))
    bag = _session(tmp_path / "looping", bits, decisions, offline_beliefs([(pairs, "start")]),
                   instances=instances)  # fmt: skip
    assert main(["replay", str(bag)]) == 1  # not shown equal
    out = capsys.readouterr().out
    assert f"compared the first one's {STEPS} beliefs" in out, out
    assert (f"belief_node restarted {restarts} times, more than the {MOST_RESTARTS_COMPARED}"
            " whose beliefs the replay splits: the later ones' not compared") in out, out


def test_a_memory_that_is_no_whole_number_is_named_and_another_robots_ignored(
        tmp_path: Path, capsys) -> None:
    """belief_node's memory_steps as text, a fraction, negative or of 19 digits.

    Named in one line (give --memory); another robot's belief_node saying so disturbs nothing.
    """
    bits, decisions = _fields(7, range(1, STEPS + 1))
    pairs = [(b[2] == 1, bool(d[2])) for b, d in zip(bits, decisions, strict=True)]
    beliefs = offline_beliefs([(pairs, "start")])
    for memory in ("sixty", "60.0", "-5", "1" * 19):
        bag = _session(tmp_path / f"m{len(memory)}{memory[0]}", bits, decisions, beliefs,
                       memory=memory)  # fmt: skip
        error = _one_line_error(capsys, "replay", str(bag))
        assert (f"the diagnostics of belief_node report memory_steps '{memory}', not one whole"
                " number of steps (0 or more, at most 18 digits): its memory cannot be told:"
                " give --memory N") in error, error
        assert main(["replay", str(bag), "--memory", str(MEMORY)]) == 0
        capsys.readouterr()
    other = _session(tmp_path / "other", bits, decisions, beliefs, memory="sixty",
                     node="robot2/belief_node")  # fmt: skip
    assert main(["replay", str(other), "--memory", str(MEMORY)]) == 0

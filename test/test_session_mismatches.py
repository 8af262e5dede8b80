"""Sessions that the replay or the analysis cannot take as given: named in one line.

Windows of another length than ``--params``' dt, sessions of different windows pooled,
belief_node's memory of another robot on the domain, a restarted mic_node or belief_node,
a step recorded twice: each is named, never a bare difference or a wrong number.
"""

from __future__ import annotations

from pathlib import Path

from infomax_contingency.cli.main import main
from infomax_contingency.eval.sessions import write_offline_session

STEPS = 30
BITS = [k % 4 == 1 for k in range(STEPS)]
DECISIONS = [k % 6 == 4 for k in range(STEPS)]


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
    expected = (f"the session {paper} has windows of 0.8 s; --params robot has windows of"
                " 0.5 s: give --params with dt 0.8 (paper)")
    for command in (["replay", str(paper)], ["replay", str(paper), "--actions", "rule"],
                    ["analyze", str(paper)],
                    ["plot", "--session", str(paper), "--out", str(tmp_path / "p.png")]):
        assert expected in _one_line_error(capsys, *command)
    assert main(["analyze", str(paper), "--params", "paper"]) == 1  # too few sounds: said
    assert "windows of 0.8 s" in capsys.readouterr().out
    error = _one_line_error(capsys, "analyze", str(paper), str(robot), "--params", "paper")
    assert (f"windows of different lengths ({robot}: 0.5 s, {paper}: 0.8 s)" in error)

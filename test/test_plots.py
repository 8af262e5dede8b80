"""Figures: the session plot (simulated and recorded), learning curves, efficiency, horizons."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from infomax_contingency.cli import main as cli
from infomax_contingency.core.controllers import make_controller
from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval import plots
from infomax_contingency.sim.simulation import simulate
from infomax_contingency.sim.world import make_room
from test_rooms_experiment import fifo_with_a_reader

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
ROBOT = ModelParams.named("robot")


def _session(steps: int = 60) -> list[dict]:
    rng = np.random.default_rng(2)
    room = make_room("responsive", ROBOT, rng)
    records = simulate(ROBOT, make_controller("rule", ROBOT, rng), room, steps, rng)
    return [record.__dict__ for record in records]


def test_session_figure_has_four_panels_sharing_time() -> None:
    figure = plots.session_figure(ROBOT, _session())
    time_axes = [axis for axis in figure.axes if axis.get_xlabel() != "density"]
    assert len(time_axes) == 4
    shared = time_axes[0].get_shared_x_axes()
    assert all(shared.joined(time_axes[0], axis) for axis in time_axes[1:])
    assert time_axes[-1].get_xlabel() == "time (s)"
    assert time_axes[-1].get_xlim()[1] == pytest.approx(60 * ROBOT.dt)


def test_plot_command_writes_png(tmp_path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "session.png"
    args = ["plot", "--out", str(out), "--world", "responsive", "--steps", "40", "--seed", "1"]
    assert cli.main(args) == 0
    data = out.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 20_000
    assert "wrote" in capsys.readouterr().out


def test_plot_recorded_session(tmp_path, capsys: pytest.CaptureFixture) -> None:
    session = tmp_path / "run.jsonl"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        cli.main(
            ["simulate", "--params", "paper", "--controller", "rule", "--steps", "30", "--json"]
        )
    session.write_text(stdout.getvalue())
    out = tmp_path / "recorded.png"
    assert (
        cli.main(["plot", "--params", "paper", "--session", str(session), "--out", str(out)]) == 0
    )
    assert out.read_bytes().startswith(PNG_MAGIC)
    # Other parameters than the session's: the timers cannot be replayed.
    assert (
        cli.main(["plot", "--params", "robot", "--session", str(session), "--out", str(out)]) == 2
    )
    assert "differs from the replayed" in capsys.readouterr().err


def test_plot_writes_over_nothing_but_a_regular_file(tmp_path, capsys) -> None:
    (tmp_path / "kept.png").write_bytes(b"kept")
    (tmp_path / "link.png").symlink_to("kept.png")
    with fifo_with_a_reader(tmp_path / "fifo.png") as fifo:
        for path, kind in ((fifo, "a FIFO"), (tmp_path / "link.png", "a symbolic link")):
            assert cli.main(["plot", "--steps", "5", "--out", str(path)]) == 2
            error = capsys.readouterr().err
            assert error.count("\n") == 1, error
            assert f"--out {path} is not a regular file (it is {kind})" in error
    assert stat.S_ISFIFO(fifo.lstat().st_mode) and (tmp_path / "link.png").is_symlink()
    assert (tmp_path / "kept.png").read_bytes() == b"kept"
    with fifo_with_a_reader(tmp_path / "f.png") as fifo, pytest.raises(ValueError, match="FIFO"):
        plots.plot_session(ROBOT, _session(5), fifo)  # the writer itself refuses it too


def test_bad_session_files(tmp_path, capsys: pytest.CaptureFixture) -> None:
    out = str(tmp_path / "x.png")
    broken = tmp_path / "broken.jsonl"
    broken.write_text('{"t": 1}\nnot json\n')
    assert cli.main(["plot", "--session", str(broken), "--out", out]) == 2
    error = capsys.readouterr().err
    assert "line 1 lacks the field(s)" in error and error.count("\n") == 1
    broken.write_text("not json\n")
    assert cli.main(["plot", "--session", str(broken), "--out", out]) == 2
    assert "line 1 is not JSON" in capsys.readouterr().err
    assert cli.main(["plot", "--session", str(tmp_path / "none"), "--out", out]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert cli.main(["plot", "--steps", "5", "--out", str(tmp_path / "x.jpg")]) == 2
    assert "must end in .png" in capsys.readouterr().err


def test_a_deeply_nested_line_is_no_session(tmp_path, capsys) -> None:
    """100,000 ``[`` on a line: a RecursionError traceback of the JSON parser before."""
    deep = tmp_path / "deep.jsonl"
    deep.write_text("[" * 100_000 + "\n")
    assert cli.main(["plot", "--session", str(deep), "--out", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err == (
        f"infomax-contingency plot: error: {deep} line 1 is nested 100,000 deep: not a step"
        " record (one flat JSON object per line, as `infomax-contingency simulate --json`"
        " writes)\n")


@pytest.mark.parametrize(("line", "field", "value", "message"), [
    (2, "belief", 7.5, "belief must be a finite number in [0, 1], got 7.5"),
    (2, "belief", float("nan"), "belief must be a finite number in [0, 1], got nan"),
    (2, "belief", -0.1, "belief must be a finite number in [0, 1], got -0.1"),
    (3, "t", 2, "t 2 does not come after the previous step's 2 (t must increase, each step"
                " once)"),
    (2, "t", 1.5, "t must be a whole number, got 1.5"),
    (2, "y", 7, "y must be 0 or 1, got 7"),
    (2, "u", 2, "u must be 0 or 1, got 2"),
    (1, "z", -1, "z must be a whole number >= 0, got -1"),
    (1, "z", 0.5, "z must be a whole number >= 0, got 0.5"),
    (4, "time_s", float("inf"), "time_s must be a number of seconds in [0, 1e+09], got inf"),
    # drawn before, as if fine: a figure over itself, or spanning 1e308 s
    (4, "time_s", 0.5, "time_s 0.5 does not come after the previous step's 1 s (time must"
                       " increase)"),
    (1, "time_s", -1e308, "time_s must be a number of seconds in [0, 1e+09], got -1e+308"),
    (2, "time_s", 10**400, "time_s must be a number of seconds in [0, 1e+09], got an integer"
                           " of about 401 digits"),
])
def test_tampered_session_values_are_refused_naming_line_and_field(
        tmp_path, capsys, line, field, value, message) -> None:
    records = _session(6)
    records[line - 1][field] = value
    path = tmp_path / "s.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    assert cli.main(["plot", "--session", str(path), "--out", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err == (
        f"infomax-contingency plot: error: {path} line {line}: {message}\n")
    assert not (tmp_path / "x.png").exists()


def test_learning_horizon_and_efficiency_figures(tmp_path) -> None:
    curve = {"method": "plain", "horizon": 12, "vocalizations": [0, 10, 100], "scores": [0, 0.5, 1]}
    path = plots.plot_learning_curves([curve, {**curve, "method": "improved"}], tmp_path / "l.png")
    assert path.read_bytes().startswith(PNG_MAGIC)
    horizon = {
        "domain_max_count": 2,
        "sets": [
            {
                "params": "paper",
                "stable_from": 3,
                "horizons": [
                    {
                        "horizon": h,
                        "map_long_ago": [[0.0, 1.0, None], [0.5, None, None], [None] * 3],
                    }
                    for h in (2, 4)
                ],
            }
        ],
    }
    assert plots.plot_horizon_maps(horizon, tmp_path / "h.png").stat().st_size > 5_000
    summary = {
        "prior_weighted_entropy": 0.05,
        "prior_weighted_entropy_ci": (0.04, 0.06),
        **{
            f"{room}+partner": {"detection_s_median": 20.0, "detection_s_ci": (15.0, float("inf"))}
            for room in ("quiet", "office")
        },
    }
    efficiency = {
        "controllers": ["a", "b"],
        "summaries": {"a": summary, "b": summary},
        "rooms": {"backgrounds_k3": {"quiet": 0.05, "office": 0.2}},
        "config": {"steps": 80, "params_name": "robot"},
        "dt": 0.5,
    }
    assert plots.plot_efficiency(efficiency, tmp_path / "e.png").stat().st_size > 5_000


def test_package_imports_without_matplotlib() -> None:
    child = Path(__file__).resolve().parent / "child_imports.py"
    modules = "infomax_contingency.cli.main,infomax_contingency.eval.experiments"
    out = subprocess.run([sys.executable, str(child), modules, "matplotlib"],
                         check=True, capture_output=True, text=True).stdout  # fmt: skip
    assert json.loads(out) == []


def test_read_session_round_trip(tmp_path) -> None:
    records = _session(10)
    path = tmp_path / "s.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    assert plots.read_session(path) == records
    counts = plots.session_counts(ROBOT, records)
    assert counts.shape == (10, 4) and counts[-1].sum() <= 10


def test_titles_with_bytes_that_are_not_utf8_are_drawn(tmp_path, capsys) -> None:
    """--title or a session's file name with such bytes: a TypeError of the renderer before."""
    out = tmp_path / "q.png"
    assert cli.main(["plot", "--steps", "10", "--title", "x\udcff", "--out", str(out)]) == 0
    assert out.read_bytes().startswith(PNG_MAGIC)
    bag = tmp_path / "bag\udcff\udcfe"  # as Python names a directory named b"bag\xff\xfe"
    shutil.copytree(Path(__file__).parent / "data" / "session_demo", bag)
    assert cli.main(["plot", "--session", str(bag), "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    assert plots.drawable_text("bag\udcff\udcfe \ud800") == "bag\ufffd\ufffd \ufffd"


@pytest.mark.parametrize("title", ["$" + "{" * 45 + "x" + "}" * 45 + "$", "$\\foo$", "$"])
def test_a_title_is_drawn_as_written_never_parsed_as_math(tmp_path, title: str) -> None:
    """Dollar signs are text, never mathtext.

    A deeply nested $...$ was a RecursionError (3,000 lines of traceback), an unknown
    command an error starting "error: ".
    """
    out = tmp_path / "t.png"
    assert cli.main(["plot", "--steps", "5", "--title", title, "--out", str(out)]) == 0
    assert out.read_bytes().startswith(PNG_MAGIC)


def test_a_session_file_refuses_the_simulations_options(tmp_path, capsys) -> None:
    """--steps, --world, --controller, --seed with --session: ignored before, unsaid."""
    path = tmp_path / "s.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in _session(6)))
    out = tmp_path / "x.png"
    argv = ["plot", "--session", str(path), "--out", str(out)]
    assert cli.main([*argv, "--steps", "120", "--controller", "rule"]) == 2  # a default too
    assert capsys.readouterr().err == (
        "infomax-contingency plot: error: --controller, --steps: for a simulated session"
        f" only; --session {path} is drawn as it was recorded\n")
    assert not out.exists()
    assert cli.main(argv) == 0


def test_plot_a_session_bag(tmp_path, capsys: pytest.CaptureFixture) -> None:
    bag = Path(__file__).parent / "data" / "session_demo"
    out = tmp_path / "bag.png"
    assert cli.main(["plot", "--session", str(bag), "--out", str(out)]) == 0
    assert out.read_bytes().startswith(PNG_MAGIC)
    assert "120 steps" in capsys.readouterr().out
    # The figure draws the recorded belief (replayed exactly with the recorded actions).
    from infomax_contingency.eval.sessions import load_session, replay_recorded

    session = load_session(bag)  # recorded with one K2, which it does not say: plot tells
    one_k2 = ROBOT.for_table()
    records = [r.__dict__ for r in replay_recorded(session, one_k2)]
    figure = plots.session_figure(one_k2, records, memory=session.memory_steps)
    belief_line = figure.axes[1].get_lines()[0]
    assert list(belief_line.get_ydata()) == session.beliefs
    not_a_bag = tmp_path / "empty_dir"
    not_a_bag.mkdir()
    assert cli.main(["plot", "--session", str(not_a_bag), "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert "cannot read the session" in error and error.count("\n") == 1

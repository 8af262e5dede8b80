"""The DP solver against plain expectimax over every action/observation history."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import brute_force
from infomax_contingency.cli import main as cli_main
from infomax_contingency.cli.main import main, parse_size
from infomax_contingency.core.model import TIE_TOLERANCE, ModelParams, Statistic
from infomax_contingency.core.policy_table import PolicyTable, content_digest
from infomax_contingency.core.solver import solve, solve_cost, solve_episodic, solve_receding
from infomax_contingency.core.statespace import (
    count_index,
    count_index_array,
    count_tuples,
    n_count_tuples,
)
from test_model import PARAM_SETS


def statistic_of(params: ModelParams, z: int, events: tuple) -> Statistic:
    """The statistic of a brute-force history (counted directly)."""
    return Statistic(
        z,
        events.count(("agent", 1)),
        events.count(("agent", 0)),
        events.count(("background", 1)),
        events.count(("background", 0)),
    )


def test_count_index_is_a_bijection_ordered_by_total() -> None:
    tuples = count_tuples(9)
    assert len(tuples) == n_count_tuples(9) == 715
    assert np.array_equal(count_index_array(*tuples.T), np.arange(len(tuples)))
    assert len({tuple(t) for t in tuples}) == len(tuples)
    totals = tuples.sum(axis=1)
    assert np.all(np.diff(totals) >= 0) and totals.max() == 9
    assert all(count_index(*map(int, tuples[i])) == i for i in range(0, len(tuples), 37))


@pytest.mark.parametrize("name", sorted(PARAM_SETS))
@pytest.mark.parametrize("horizon", [2, 4, 6])
def test_episodic_dp_equals_expectimax(name: str, horizon: int) -> None:
    params = PARAM_SETS[name]
    table = solve_episodic(params, horizon, keep_values=True)
    checked = 0
    for z_first in range(params.n_timer_values):
        first_period = brute_force.period(params, z_first)
        for y_first in (0, 1):
            events = [] if first_period == "self" else [(first_period, y_first)]
            _, _, record = brute_force.expectimax(
                params, events, z_first, horizon - 1, TIE_TOLERANCE
            )
            for (steps_to_go, z, history), (value, action) in record.items():
                if steps_to_go == 0:
                    continue
                step = horizon - steps_to_go
                statistic = statistic_of(params, z, history)
                dp_value = table.values[step - 1][z, count_index(*statistic.counts)]
                assert dp_value == pytest.approx(value, abs=1e-11), (step, statistic)
                assert table.action(statistic, step=step) == action, (step, statistic)
                checked += 1
    assert checked > 0


@pytest.mark.parametrize("name", sorted(PARAM_SETS))
def test_receding_dp_equals_expectimax_from_every_statistic(name: str) -> None:
    params = PARAM_SETS[name]
    horizon, memory = 3, 3
    table = solve_receding(params, horizon, memory, keep_values=True)
    vocalizations = 0
    for counts in count_tuples(memory):
        p2, q2, p3, q3 = (int(c) for c in counts)
        events = [("agent", 1)] * p2 + [("agent", 0)] * q2
        events += [("background", 1)] * p3 + [("background", 0)] * q3
        for z in range(params.n_timer_values):
            value, action, _ = brute_force.expectimax(params, events, z, horizon, TIE_TOLERANCE)
            statistic = Statistic(z, p2, q2, p3, q3)
            assert table.values[0][z, count_index(p2, q2, p3, q3)] == pytest.approx(
                value, abs=1e-11
            )
            assert table.action(statistic) == action, statistic
            vocalizations += action
    assert vocalizations > 0  # the comparison covers both actions


def test_paper_table_listens_first_then_asks() -> None:
    """Qualitative anchors of the paper's controller.

    With no data it first listens to the background; once the background is known and
    the agent period is not, it asks; inside the agent period it waits for the answer.
    """
    params = ModelParams.named("paper")
    table = solve_episodic(params, 12)
    assert table.action(Statistic(params.timer_long_ago), step=1) == 0
    assert table.action(Statistic(params.timer_long_ago, 0, 0, 0, 5), step=6) == 1
    assert table.action(Statistic(1, 0, 0, 0, 5), step=7) == 0
    assert table.action(Statistic(2, 1, 0, 0, 5), step=8) == 0


def test_ties_go_to_silence() -> None:
    # Last decision of an episode whose both choices land in the self period: the
    # robot set's timer 0 moves to 1 (self) when silent and to 0 (self) when vocalizing.
    params = ModelParams.named("robot")
    table = solve_episodic(params, 2, keep_values=True)
    for counts in count_tuples(1):
        assert table.action(Statistic(0, *map(int, counts)), step=1) == 0


def test_bad_arguments() -> None:
    params = ModelParams.named("paper")
    with pytest.raises(ValueError, match="horizon"):
        solve_episodic(params, 1)
    with pytest.raises(ValueError, match="memory"):
        solve_receding(params, 3, 0)
    table = solve_episodic(params, 5)
    with pytest.raises(IndexError, match="steps 1 .. 4"):
        table.action(Statistic(4), step=5)
    with pytest.raises(IndexError, match="outside the table"):
        table.action(Statistic(4, 2, 0, 0, 0), step=1)


# ----------------------------------------------------------------------------------------
# The cost of a solve, known before it starts; the solve and info --verify commands


COST_CASES = [("paper", "episodic", 9, 0), ("robot", "episodic", 6, 0), ("robot", "receding", 4, 6)]


@pytest.mark.parametrize(("name", "mode", "horizon", "memory"), COST_CASES)
def test_solve_cost_counts_what_the_solve_does(name, mode, horizon, memory) -> None:
    params = ModelParams.named(name)
    cost = solve_cost(params, mode, horizon, memory)
    calls: list[tuple[int, int, float]] = []
    table = solve(params, mode, horizon, memory, progress=lambda *call: calls.append(call))
    assert cost.statistics == table.n_statistics
    assert cost.layers == len(calls) - 1
    assert [done for done, _, _ in calls] == list(range(cost.layers + 1))
    fractions = [fraction for _, _, fraction in calls]
    assert fractions[0] == 0.0 and fractions[-1] == pytest.approx(1.0)
    assert all(a < b for a, b in zip(fractions, fractions[1:], strict=False))
    assert cost.peak_bytes > 50 * 2**20 and cost.seconds > 0


def test_solve_cost_of_the_benchmark_horizons() -> None:
    """The figures bench/bench_solver.py measured: statistics exact, memory close."""
    paper = ModelParams.named("paper")
    assert solve_cost(paper, "episodic", 40).statistics == 5_430_035
    assert solve_cost(paper, "episodic", 100).statistics == 459_812_595
    for horizon, measured_mib in ((40, 71), (100, 669)):
        estimate = solve_cost(paper, "episodic", horizon).peak_bytes / 2**20
        assert measured_mib / 2 < estimate < 2 * measured_mib, (horizon, estimate)
    huge = solve_cost(paper, "episodic", 10_000)  # closed form: nothing is allocated
    assert huge.peak_bytes > 2**50 and huge.statistics > 10**18


def test_solve_cost_refuses_what_solve_refuses() -> None:
    paper = ModelParams.named("paper")
    for arguments, message in [
        (("episodic", 1, 0), "horizon"),
        (("episodic", 5, 3), "no memory"),
        (("receding", 3, 0), "memory"),
        (("sideways", 3, 0), "unknown table mode"),
    ]:
        with pytest.raises(ValueError, match=message):
            solve_cost(paper, *arguments)
        with pytest.raises(ValueError, match=message):
            solve(paper, *arguments)


@pytest.mark.parametrize(
    ("text", "size"),
    [("4G", 4 * 2**30), ("500M", 500 * 2**20), ("64k", 65536), ("1.5GiB", 3 * 2**29), ("10", 10)],
)
def test_parse_size(text: str, size: int) -> None:
    assert parse_size(text) == size


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.fixture
def no_solving(monkeypatch) -> None:
    """Make any solve of the command line fail the test: refusals come first."""

    def forbidden(*args, **kwargs):
        raise AssertionError("the command solved although it should have refused")

    monkeypatch.setattr(cli_main, "solve", forbidden)


SOLVE_40 = ["solve", "--params", "paper", "--mode", "episodic", "--horizon", "40"]


def test_solve_horizon_10000_refuses_at_once(capsys, tmp_path, no_solving) -> None:
    out = tmp_path / "table.npz"
    status, stdout, stderr = run_cli(
        capsys, "solve", "--params", "paper", "--mode", "episodic", "--horizon", "10000",
        "--out", str(out),
    )  # fmt: skip
    assert status == 2 and stdout == ""
    assert stderr.count("\n") == 1
    assert stderr.startswith(
        "infomax-contingency solve: error: refusing to solve horizon 10000: it needs"
        " 4.17e+18 statistics, about "
    )
    assert "PiB of memory" in stderr and "years" in stderr
    assert not out.exists()


def test_solve_refuses_above_max_memory(capsys, tmp_path, no_solving) -> None:
    status, _, stderr = run_cli(
        capsys, *SOLVE_40, "--max-memory", "20M", "--out", str(tmp_path / "t.npz")
    )
    assert status == 2
    assert "5.43M statistics, about 73.9 MiB of memory" in stderr
    assert "more memory than 20 MiB (--max-memory)" in stderr


def refused_arguments(capsys, *argv: str) -> str:
    """The error line of arguments argparse refuses (status 2), before the command runs."""
    with pytest.raises(SystemExit) as ended:
        main(list(argv))
    assert ended.value.code == 2
    return capsys.readouterr().err.splitlines()[-1]


@pytest.mark.parametrize(
    "argv",
    [
        ["info", "{table}"],  # the option was read only by --verify, else ignored
        ["info", "/nonexistent/table.npz"],  # refused before the table is read
        ["info", "--verify", "{table}"],
        [*SOLVE_40, "--out", "{tmp}/t.npz"],
        ["solve", "--params", "/nonexistent.yaml", "--mode", "episodic", "--horizon", "40",
         "--out", "{tmp}/t.npz"],  # refused before the parameters are read
    ],
)
def test_a_malformed_max_memory_is_refused_by_every_command_that_takes_it(
    capsys, tmp_path, no_solving, argv: list[str]
) -> None:
    """``info --max-memory abc`` (without ``--verify``) was accepted and ignored."""
    table = tmp_path / "table.npz"
    solve_receding(ModelParams.named("robot"), 4, 6).save(table)
    argv = [word.format(table=table, tmp=tmp_path) for word in argv]
    for size in ("abc", "lots", "1.5.G", "-4G", ""):
        error = refused_arguments(capsys, *argv, f"--max-memory={size}")
        assert error == (
            f"infomax-contingency {argv[0]}: error: argument --max-memory: give bytes or a"
            f" size such as 500M or 4G, got {size!r}"
        )
    assert not (tmp_path / "t.npz").exists()


@pytest.mark.parametrize(
    ("out", "message"),
    [
        ("{tmp}", "is a directory"),
        ("/proc/self/table.npz", "/proc is no place for a table file"),
        ("/dev/null", "/dev is no place for a table file"),
        ("{tmp}/file.txt/table.npz", "cannot write in"),
        ("{tmp}/fifo", "is not a regular file (it is a FIFO)"),
        ("{tmp}/link", "is not a regular file (it is a symbolic link)"),
    ],
)
def test_solve_checks_out_before_solving(capsys, tmp_path, no_solving, out, message) -> None:
    (tmp_path / "file.txt").write_text("a file where a directory would be")
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "link").symlink_to("file.txt")  # replacing it would turn it into a file
    status, _, stderr = run_cli(capsys, *SOLVE_40, "--out", out.format(tmp=tmp_path))
    assert status == 2 and message in stderr and stderr.count("\n") == 1, stderr


def test_solve_prints_the_estimate_and_progress(capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(cli_main, "PROGRESS_EVERY_S", 0.0)
    out = tmp_path / "t.npz"
    status, stdout, stderr = run_cli(
        capsys, "solve", "--params", "paper", "--mode", "episodic", "--horizon", "9",
        "--max-memory", "4G", "--out", str(out),
    )  # fmt: skip
    assert status == 0, stderr
    assert stdout.startswith("solve: 6.43k statistics, about ")
    assert "solved episodic table (horizon 9) for paper: 6430 statistics" in stdout
    lines = stderr.splitlines()
    assert lines[0].startswith("solve: layer 0 of 8, ") and lines[-1].startswith("solve: layer 7")
    assert PolicyTable.load(out).same_policy_as(solve_episodic(ModelParams.named("paper"), 9))


def test_info_verify(capsys, tmp_path) -> None:
    table = solve_receding(ModelParams.named("robot"), 4, 6)
    path = tmp_path / "table.npz"
    table.save(path)
    status, stdout, _ = run_cli(capsys, "info", "--verify", str(path))
    assert status == 0
    assert stdout.splitlines()[-1].startswith(
        f"verified: all {table.n_statistics:,} action bits equal a fresh solve"
    )
    # One bit flipped and the file sealed again: only a fresh solve can tell.
    actions = table.packed_actions.copy()
    actions[5] ^= 0x20
    metadata = table.metadata()
    metadata["content_sha256"] = content_digest(metadata, actions.tobytes())
    with path.open("wb") as stream:
        np.savez(stream, actions=actions, metadata=np.array(json.dumps(metadata)))
    status, stdout, _ = run_cli(capsys, "info", "--verify", str(path))
    assert status == 1
    assert stdout.splitlines()[-1] == (
        f"MISMATCH: 1 of {table.n_statistics:,} action bits differ from a fresh solve;"
        " metadata fields that differ: content_sha256"
    )
    status, _, stderr = run_cli(capsys, "info", "--verify", "--max-memory", "1M", str(path))
    assert status == 2 and f"refusing to verify {path}: it needs" in stderr

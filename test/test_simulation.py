"""Controllers, simulated rooms, the offline simulator and the command line."""

from __future__ import annotations

import contextlib
import itertools
import json
import re
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from infomax_contingency.cli import main as cli
from infomax_contingency.core.controllers import (
    CHECK_IN_ABOVE,
    CHECK_IN_EVERY_S,
    MAX_INTERVAL_STEPS,
    CheckIn,
    FixedIntervalController,
    GreedyController,
    PolicyController,
    RandomController,
    RuleController,
    make_controller,
)
from infomax_contingency.core.model import ModelParams, Statistic
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.core.solver import solve_episodic, solve_receding
from infomax_contingency.core.statespace import count_tuples
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.rooms import ROOM_NAMES, ROOMS
from infomax_contingency.sim.simulation import RunSummary, iter_simulate, simulate
from infomax_contingency.sim.world import make_room, named_room

PAPER = ModelParams.named("paper")
ROBOT = ModelParams.named("robot")


def test_greedy_equals_the_one_step_table() -> None:
    table = solve_receding(ROBOT, 1, 8)
    greedy = GreedyController(ROBOT.for_table())  # the table's model: one K2
    vocalizes = 0
    for counts in count_tuples(8):
        for z in range(ROBOT.n_timer_values):
            statistic = Statistic(z, *map(int, counts))
            assert greedy.decide(statistic) == table.action(statistic)
            vocalizes += greedy.decide(statistic)
    # one step ahead, asking is never worth it: the next window is a self-feedback window
    assert vocalizes == 0


def test_rule_controller() -> None:
    rule = RuleController(PAPER, c=9)
    assert rule.decide(Statistic(3, 0, 0, 0, 5)) == 0  # still inside the agent period
    assert rule.decide(Statistic(4, 0, 0, 0, 5)) == 1  # no agent data yet
    assert rule.decide(Statistic(4, 0, 0, 0, 0)) == 0  # no background data yet
    # Var(K2)/n2 vs 9 Var(K3)/n3: few agent observations against many background ones
    assert rule.decide(Statistic(4, 1, 1, 1, 40)) == 1
    assert rule.decide(Statistic(4, 10, 10, 1, 5)) == 0
    with pytest.raises(ValueError, match="c must be > 0"):
        RuleController(PAPER, c=0)


def test_fixed_and_random_controllers() -> None:
    fixed = FixedIntervalController(PAPER, 3)
    assert [fixed.step(0) for _ in range(9)] == [0, 0, 1] * 3
    fixed.reset()
    assert fixed.step(0) == 0
    rng = np.random.default_rng(0)
    share = np.mean([RandomController(PAPER, 0.3, rng).step(0) for _ in range(4000)])
    assert 0.27 < share < 0.33
    with pytest.raises(ValueError, match="interval"):
        FixedIntervalController(PAPER, 0)


def test_interval_controller_refuses_an_interval_no_run_reaches(capsys) -> None:
    """Past 2^31 - 1 steps: one line naming the largest (an OverflowError or numpy's before)."""
    rng = np.random.default_rng(0)
    largest = ("MAX_S must be at most 1.07374e+09 s (2,147,483,647 steps of 0.5 s: no run is"
               " longer)")
    for spec in ("interval:1e308-1e308", "interval:1e20-1e20", "interval:3-1.1e9"):
        with pytest.raises(ValueError, match=re.escape(f"interval controller: {largest}")):
            make_controller(spec, ROBOT, rng)
    longest = make_controller("interval:1e9-1.07374e9", ROBOT, rng)
    assert longest.max_steps <= MAX_INTERVAL_STEPS and longest.step(0) == 0
    shortest = make_controller("interval:1e-05-1", ROBOT, rng)  # an exponent's minus
    assert (shortest.min_steps, shortest.max_steps) == (1, 2)
    session = str(Path(__file__).parent / "data" / "session_demo")
    for command in (["simulate", "--controller", "interval:1e308-1e308", "--steps", "3"],
                    ["replay", session, "--actions", "interval:1e308-1e308"]):
        assert cli.main(command) == 2
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and f"{largest}, got 1e+308" in error, error


def test_policy_controller_follows_the_table_and_restarts_episodes() -> None:
    table = solve_episodic(PAPER, 6)
    controller = PolicyController(table)
    rng = np.random.default_rng(5)
    z, statistic, step = PAPER.timer_long_ago, Statistic(PAPER.timer_long_ago), 0
    for _ in range(20):
        y = int(rng.integers(0, 2))
        step += 1
        if step >= table.horizon:  # a new episode: zero counts, current timer
            statistic, step = Statistic(z), 1
        statistic = statistic.observe(PAPER, y)
        expected = table.action(statistic, step=step)
        assert controller.step(y) == expected
        statistic = statistic.act(PAPER, expected)
        z = statistic.z


def test_receding_policy_controller_keeps_its_memory() -> None:
    table = solve_receding(PAPER, 3, 4)
    controller = PolicyController(table)
    for y in [1, 0, 1, 1, 0, 0, 1, 0, 1, 1, 1, 0]:
        controller.step(y)  # would leave the table without the sliding memory
        counts = controller.tracker.statistic.counts
        assert sum(counts) <= 4


def test_a_check_in_is_whole_steps_and_refuses_what_is_not_a_duration() -> None:
    assert CheckIn.from_seconds(ROBOT, CHECK_IN_EVERY_S, CHECK_IN_ABOVE) == CheckIn(8, 0.9)
    assert CheckIn.from_seconds(PAPER, 4.0, 0.9).every_steps == 5  # 0.8-s windows
    assert CheckIn.from_seconds(ROBOT, 0.0, 0.9).every_steps == 0  # off
    assert CheckIn.from_seconds(ROBOT, 0.1, 0.9).every_steps == 5  # at least the reply period
    for every_s, above in ((-1.0, 0.9), (float("nan"), 0.9), (float("inf"), 0.9), (4.0, 1.0),
                           (4.0, 0.0), (4.0, 0.3), (5000.0, 0.9)):  # fmt: skip
        with pytest.raises(ValueError, match="check-in"):
            CheckIn.from_seconds(ROBOT, every_s, above)


def _answered(controller: PolicyController, steps: int, partner: bool = True,
              ) -> tuple[list[int], list[float], list[int]]:  # fmt: skip
    """Decisions, beliefs and check-in steps; a partner answers every agent window (or nobody)."""
    decisions, beliefs, check_ins = [], [], []
    for k in range(steps):
        z = controller.tracker.statistic.z
        before = getattr(controller, "check_ins", 0)
        decisions.append(controller.step(int(partner and ROBOT.ta1 <= z <= ROBOT.ta2)))
        beliefs.append(controller.tracker.statistic.belief(ROBOT))
        if controller.check_ins > before:
            assert z > ROBOT.ta2, "a check-in never cuts into a reply's period"
            check_ins.append(k)
    return decisions, beliefs, check_ins


def test_check_ins_keep_asking_a_partner_the_belief_is_sure_of_and_change_nothing_before() -> None:
    """Below the threshold the table alone decides; above it no silence outlasts the check-in."""
    table = PolicyTable.load(resource_path("policies", "robot_receding_H24_M60.npz"))
    plain, plain_beliefs, _ = _answered(PolicyController(table, ROBOT), 200)
    checked, beliefs, check_ins = _answered(PolicyController(table, ROBOT, CheckIn(8, 0.9)), 200)
    sure = next(k for k, belief in enumerate(plain_beliefs) if belief > 0.9)
    assert checked[: sure + 1] == plain[: sure + 1], "the same search for a partner"
    assert check_ins and min(check_ins) > sure
    assert all(beliefs[k] > 0.9 for k in check_ins)  # the belief after the bit it decides on
    silences = "".join(map(str, checked[sure + 1:])).split("1")
    assert max(map(len, silences)) <= 8, silences
    assert max(map(len, "".join(map(str, plain[sure + 1:])).split("1"))) > 8, (
        "the table alone asks a partner it is sure of less often: nothing to check otherwise")
    nobody, _, none = _answered(PolicyController(table, ROBOT, CheckIn(8, 0.9)), 200, False)
    assert nobody == _answered(PolicyController(table, ROBOT), 200, False)[0] and not none
    off, _, none = _answered(PolicyController(table, ROBOT, CheckIn(0, 0.9)), 200)
    assert off == plain and not none


def test_make_controller_specs(tmp_path) -> None:
    rng = np.random.default_rng(0)
    assert make_controller("rule:4", PAPER, rng).c == 4
    assert make_controller("greedy", PAPER, rng).name == "greedy"
    assert make_controller("fixed:5", PAPER, rng).interval == 5
    assert make_controller("random:0.25", PAPER, rng).probability == 0.25
    paper_table = str(resource_path("policies", "paper_episodic_T40.npz"))
    assert make_controller(f"policy:{paper_table}", PAPER, rng).table.horizon == 40
    for spec, message in [
        ("wizard", "unknown controller"),
        ("fixed:two", "bad number"),
        ("random:2", "probability"),
        ("policy:", "table file"),
        (f"policy:{tmp_path / 'missing.npz'}", "does not exist"),
        (f"policy:{paper_table}", "other model parameters"),  # with robot parameters
    ]:
        with pytest.raises(ValueError, match=message):
            make_controller(spec, ROBOT, rng)


def test_rooms() -> None:
    rng = np.random.default_rng(1)
    responsive = make_room("responsive:k2=0.7,k3=0.05", ROBOT, rng)
    assert responsive.partner_present
    # robot set: z = 0, 1 self; 2..4 agent; 5 background
    assert responsive.rates == (0.9, 0.9, 0.7, 0.7, 0.7, 0.05)
    silent = make_room("silent", ROBOT, rng)
    assert not silent.partner_present and len(set(silent.rates[2:])) == 1
    assert make_room("baby9", PAPER, rng).rates == (0.0, 1.0, 1.0, 1.0, 0.0)
    assert make_room("baby9:reply=2", PAPER, rng).rates == (0.0, 0.0, 1.0, 0.0, 0.0)
    drawn = [make_room("prior:pi=0.5", ROBOT, rng) for _ in range(400)]
    assert 0.4 < np.mean([room.partner_present for room in drawn]) < 0.6
    assert all(room.rates[2] == room.rates[5] for room in drawn if not room.partner_present)
    for spec, message in [
        ("garage", "unknown room"),
        ("responsive:k2=1.5", "k2 must be a probability"),
        ("responsive:k9=0.1", "unknown option"),
        ("baby9:reply=7", "agent period"),
        ("silent:k3", "key=value"),
        ("prior:pi=2", "pi must be a probability in \\[0, 1\\], got 2"),
        ("prior:pi=nan", "pi must be a probability"),
        ("prior:pi=0.5,pi=0.9", "pi is given twice"),
        ("noisy:k3=inf", "k3 must be a probability"),  # the key typed, though it sets k2 too
    ]:
        with pytest.raises(ValueError, match=message):
            make_room(spec, ROBOT, rng)


def test_every_registered_room_is_made_with_its_stated_rates() -> None:
    rng = np.random.default_rng(0)
    z_self, z_agent, z_background = 0, ROBOT.ta1, ROBOT.timer_long_ago
    assert ROOM_NAMES[:5] == ("prior", "responsive", "silent", "noisy", "baby9")
    for name, kind in ROOMS.items():
        if kind.family == "audio":
            with pytest.raises(ValueError, match="exists only as sound"):
                make_room(name, ROBOT, rng)
            continue
        room = make_room(name, ROBOT, rng)
        assert room.name == name
        if kind.partner_present is not None:
            assert room.partner_present == kind.partner_present, name
        if kind.rates is not None:
            k2 = kind.rates.k3 if kind.rates.k2 is None else kind.rates.k2
            expected = (kind.rates.k1, k2, kind.rates.k3)
            assert (room.rates[z_self], room.rates[z_agent], room.rates[z_background]) == expected
    # the rooms of the efficiency experiment, by either name
    for name in ("quiet", "office+partner", "poster-session"):
        assert make_room(name, ROBOT, rng) == named_room(ROBOT, name)
    assert make_room("office+partner", ROBOT, rng).rates[z_agent] == pytest.approx(0.68)
    assert make_room("noisy:k3=0.3", ROBOT, rng).rates[z_agent] == 0.3  # no partner: k2 = k3
    for spec, message in [
        ("quiet:k2=0.5", "unknown option"),
        ("responsive:k2=lots", "k2 must be a number"),
        ("prior:k1=0.5", "unknown option"),
    ]:
        with pytest.raises(ValueError, match=message):
            make_room(spec, ROBOT, rng)


def test_simulation_is_reproducible_and_detects() -> None:
    table = PolicyTable.load(resource_path("policies", "robot_receding_H24_M60.npz"), ROBOT)

    def run(room: str, seed: int) -> list:
        rng = np.random.default_rng(seed)
        return simulate(ROBOT, PolicyController(table, ROBOT), make_room(room, ROBOT, rng), 120,
                        rng)  # fmt: skip

    assert run("responsive", 3) == run("responsive", 3)
    assert run("responsive", 3)[-1].belief > 0.95
    assert run("silent", 3)[-1].belief < 0.05
    assert run("noisy", 3)[-1].belief < 0.05
    records = run("responsive", 4)
    assert [r.t for r in records] == list(range(1, 121))
    # the timer column is the statistic's timer: 0 right after every vocalization
    for before, after in zip(records, records[1:], strict=False):
        assert after.z == (0 if before.u else min(before.z + 1, ROBOT.timer_long_ago))


def test_cli_simulate_json_and_table(capsys) -> None:
    assert (
        cli.main(
            [
                "simulate",
                "--params",
                "paper",
                "--controller",
                "rule",
                "--world",
                "baby9",
                "--steps",
                "20",
                "--json",
            ]
        )
        == 0
    )
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 20
    first = json.loads(lines[0])
    assert {"t", "z", "y", "u", "belief", "entropy", "ratio"} <= set(first)
    assert first["ratio"] is None
    assert any(json.loads(line)["ratio"] is not None for line in lines)
    assert cli.main(["simulate", "--params", "paper", "--world", "baby9", "--steps", "5"]) == 0
    out = capsys.readouterr().out
    assert "belief" in out and "vocalizations in 5 steps" in out


def test_cli_solve_and_info(tmp_path, capsys) -> None:
    out = tmp_path / "t.npz"
    assert (
        cli.main(
            [
                "solve",
                "--params",
                "paper",
                "--mode",
                "episodic",
                "--horizon",
                "8",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert PolicyTable.load(out, PAPER).same_policy_as(solve_episodic(PAPER, 8))
    assert cli.main(["info", str(out)]) == 0
    assert '"horizon": 8' in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            [
                "solve",
                "--params",
                "paper",
                "--mode",
                "receding",
                "--horizon",
                "3",
                "--out",
                "x.npz",
            ],
            "needs --memory",
        ),
        (["simulate", "--params", "nope"], "unknown parameter set"),
        (["simulate", "--world", "garage"], "unknown room"),
        (["info", "missing.npz"], "does not exist"),
        (["simulate", "--steps", "0"], "steps must be >= 1"),
    ],
)
def test_cli_user_errors_are_one_line(tmp_path, monkeypatch, capsys, argv, message) -> None:
    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_console_script_runs() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "infomax_contingency.cli", "simulate", "--steps", "3", "--json"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert len(result.stdout.splitlines()) == 3


HUGE_RUN = ["-m", "infomax_contingency.cli", "simulate", "--steps", "1000000000"]
"""A run far too long to finish during the test: its first lines must come while it runs."""

WATCHDOG_S = 120.0
"""A run that does not stream is killed after this long, so its test fails, not hangs."""


@contextlib.contextmanager
def huge_run(*options: str) -> Iterator[subprocess.Popen]:
    """``simulate`` of :data:`HUGE_RUN` steps with piped output; killed on leaving."""
    argv = [sys.executable, *HUGE_RUN, *options]
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as run:
        watchdog = threading.Timer(WATCHDOG_S, run.kill)
        watchdog.start()
        try:
            yield run
        finally:
            watchdog.cancel()
            run.kill()
            run.communicate()


def test_iter_simulate_is_lazy_and_the_summary_counts() -> None:
    rng = np.random.default_rng(2)
    room = make_room("responsive", ROBOT, rng)
    records = iter_simulate(ROBOT, make_controller("rule", ROBOT, rng), room, 10**12, rng)
    summary = RunSummary()
    for record in itertools.islice(records, 50):
        summary.add(record)
    assert summary.steps == 50 and summary.final_belief == record.belief
    rng = np.random.default_rng(2)
    room = make_room("responsive", ROBOT, rng)
    listed = simulate(ROBOT, make_controller("rule", ROBOT, rng), room, 50, rng)
    assert summary.vocalizations == sum(r.u for r in listed) > 0
    assert summary.verdict == ("partner present" if listed[-1].belief > 0.5 else "no partner")


@pytest.mark.parametrize("json_lines", [True, False], ids=["json", "table"])
def test_cli_simulate_streams_its_steps(json_lines: bool) -> None:
    """The first steps of a huge run arrive while it runs; the run is then stopped."""
    with huge_run(*(["--json"] if json_lines else [])) as run:
        first, second = run.stdout.readline(), run.stdout.readline()
        assert run.poll() is None, "the run ended (or was killed): it did not stream"
    if json_lines:
        assert json.loads(first)["t"] == 1 and json.loads(second)["t"] == 2
    else:
        assert first.split()[:2] == ["t", "time_s"] and second.split()[0] == "1"


def test_cli_simulate_into_a_closed_pipe_ends_cleanly() -> None:
    """``simulate ... | head -3``: three lines, then exit status 0 and no traceback."""
    with huge_run("--json") as run:
        lines = [run.stdout.readline() for _ in range(3)]
        run.stdout.close()  # the reader goes away, as `head` does
        error = run.stderr.read()
        status = run.wait()
    assert [json.loads(line)["t"] for line in lines] == [1, 2, 3]
    assert status == 0 and error == "", error


@pytest.mark.parametrize("command", [["simulate"], ["experiment", "rooms"], ["demo"],
                                     ["experiment", "efficiency"], ["plot"]])  # fmt: skip
def test_a_negative_seed_is_refused_naming_the_option(command: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        cli.main([*command, "--seed", "-1"])
    assert stop.value.code == 2
    assert "argument --seed: expected a whole number >= 0, got '-1'" in capsys.readouterr().err

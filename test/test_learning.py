"""Infomax TD learning: the learned policy against the DP policy, and the learner's invariants."""

from __future__ import annotations

import json

import numpy as np
import pytest

from infomax_contingency.cli import main as cli
from infomax_contingency.core import learning, scoring
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.solver import solve_episodic

PAPER = ModelParams.named("paper")


def test_learned_t6_policy_equals_the_dp_policy() -> None:
    horizon = 6
    curve, learner = learning.learn(
        PAPER, horizon, "improved", budget=4000, seed=1, evaluate_every=500
    )
    optimal = scoring.table_actions(solve_episodic(PAPER, horizon))
    learned = learner.greedy_actions()
    visits = scoring.visit_distributions(PAPER, horizon, optimal)
    compared = 0
    for t in range(1, horizon):
        reached = visits[t - 1] > 0
        assert np.array_equal(learned(t)[reached], optimal(t)[reached]), t
        compared += int(reached.sum())
    assert compared > 50
    assert curve.scores[-1] == pytest.approx(1.0, abs=1e-9)
    assert curve.first_reaching is not None and curve.first_reaching <= 4000


def test_listening_values_stay_between_never_and_optimal() -> None:
    """With best backups from the never-vocalize values, every value is a lower bound."""
    horizon = 8
    settings = learning.LearningSettings(epsilon=0.2, backup="best", initial="listening")
    learner = learning.TDLearner(PAPER, horizon, settings, np.random.default_rng(4))
    for _ in range(400):
        learner.trial()
    never = scoring.episode_values(PAPER, horizon, scoring.never_actions(PAPER))
    optimal = scoring.episode_values(PAPER, horizon)
    raised = 0
    for t in range(1, horizon):
        values = np.array(learner.values[t])
        assert np.all(values >= never[t - 1] - 1e-12), t
        assert np.all(values <= optimal[t - 1] + 1e-12), t
        raised += int(np.sum(values > never[t - 1] + 1e-12))
    assert raised > 0


def test_plain_backup_is_the_taken_action_and_counts_vocalizations() -> None:
    """With epsilon = 1 the greedy choice is always flipped; vocalizations are counted."""
    horizon = 4
    settings = learning.LearningSettings(epsilon=1.0, backup="taken", initial="zero")
    learner = learning.TDLearner(PAPER, horizon, settings, np.random.default_rng(0))
    made = sum(learner.trial() for _ in range(50))
    assert made == learner.vocalizations > 0
    assert learner.trials == 50
    # Zero-initialised values: with ties going to silence, the first greedy action is
    # silence and epsilon = 1 flips it: the first trial vocalizes at every step.
    fresh = learning.TDLearner(PAPER, horizon, settings, np.random.default_rng(0))
    assert fresh.trial() == horizon - 1
    last = np.array(fresh.values[horizon])
    visited = np.flatnonzero(last != 0.0)
    assert len(visited) == 1  # only the final statistic of the trial was backed up


def test_learning_is_reproducible_and_bad_settings_are_refused() -> None:
    first, _ = learning.learn(PAPER, 5, "plain", budget=300, seed=9, evaluate_every=100)
    second, _ = learning.learn(PAPER, 5, "plain", budget=300, seed=9, evaluate_every=100)
    assert first.scores == second.scores and first.vocalizations == second.vocalizations
    with pytest.raises(ValueError, match="epsilon"):
        learning.LearningSettings(epsilon=1.5)
    with pytest.raises(ValueError, match="backup"):
        learning.LearningSettings(backup="median")
    with pytest.raises(ValueError, match="unknown learning method"):
        learning.learn(PAPER, 5, "fastest", budget=10, seed=0)


def test_learn_command(capsys: pytest.CaptureFixture, tmp_path) -> None:
    figure = tmp_path / "curves.png"
    status = cli.main(
        [
            "learn",
            "--horizon",
            "6",
            "--method",
            "improved@3000",
            "--method",
            "epsilon=0.1,backup=taken,initial=zero@500",
            "--json",
            "--plot",
            str(figure),
        ]
    )
    assert status == 0
    result = json.loads(capsys.readouterr().out)
    improved, custom = result["curves"]
    assert improved["scores"][-1] == pytest.approx(1.0, abs=1e-9)
    assert custom["settings"] == {"epsilon": 0.1, "backup": "taken", "initial": "zero"}
    assert figure.stat().st_size > 10_000
    assert cli.main(["learn", "--method", "plain@many"]) == 2
    assert "budget" in capsys.readouterr().err
    for target in ("2", "nan", "0", "-1"):  # a score above 1 is never reached
        assert cli.main(["learn", "--horizon", "4", "--budget", "10", "--target", target]) == 2
        assert capsys.readouterr().err.startswith(
            f"infomax-contingency learn: error: --target must be a score in (0, 1], got"
            f" {float(target)}: ")
    for growth in ("inf", "nan", "-0.5"):  # inf was an OverflowError traceback
        assert cli.main(["learn", "--horizon", "4", "--budget", "10",
                         "--evaluate-growth", growth]) == 2  # fmt: skip
        assert capsys.readouterr().err == ("infomax-contingency learn: error: evaluation growth"
                                           f" must be a finite number >= 0, got {float(growth)}\n")

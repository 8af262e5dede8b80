"""``analyze`` on fake-room sessions whose delays are set: it finds the periods they imply.

The sessions are made offline with the audio-level loop (the fake room's sound, window
energies, the -40 dB threshold of config/fake_room.yaml, the random-interval controller
of the calibration protocol) and written as session bags, so ``analyze`` reads them as
it reads a recorded graph run.

Timing (windows of 0.5 s; lag 0 is the window right after the decision, whose start is
when the robot's sound is played): the robot's 200 ms chirp 360 ms into lag 0 ends 60 ms
into lag 1, so ts = (0, 1); replies starting 1.1-1.5 s after the sound and lasting
0.6-1.0 s fall in lags 2 .. 4 (1.0-2.5 s), so ta = (2, 4).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.audio.bitsources.rules import Binarizer
from infomax_contingency.cli.main import main
from infomax_contingency.core.controllers import make_controller
from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.fig4 import fig4_study
from infomax_contingency.eval.sessions import write_offline_session
from infomax_contingency.sim.audio_loop import iter_audio_loop
from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.room_config import FakeRoomConfig

# One worker runs the module: each worker that ran one of its tests made the three
# sessions of the module fixture again (with `--dist loadgroup`).
pytestmark = pytest.mark.xdist_group("fake_room_sessions")

ROBOT = ModelParams.named("robot")
THRESHOLD_DB = -40.0
REPLY_PROBABILITY = 0.8
STEPS = 1200


def _room(partner: bool) -> FakeRoomConfig:
    return FakeRoomConfig.preset(
        "responsive", self_delay_s=0.36, reply_delay_min_s=1.1, reply_delay_max_s=1.5,
        reply_probability=REPLY_PROBABILITY, partner_arrive_s=0.0 if partner else -1.0,
    )


def _session(directory: Path, partner: bool, seed: int) -> tuple[Path, list, list]:
    controller = make_controller("interval:3-6", ROBOT, np.random.default_rng(seed))
    bits_of = make_bit_source("energy", 16000, 0.5, threshold_mode="fixed",
                              threshold_db=THRESHOLD_DB)  # fmt: skip
    records = list(iter_audio_loop(controller, FakeRoom(_room(partner), seed=seed), bits_of,
                                   STEPS))  # fmt: skip
    bits, decisions = [bool(r.y) for r in records], [bool(r.u) for r in records]
    write_offline_session(directory, bits, decisions, [r.belief for r in records], ROBOT.dt)
    return directory, bits, decisions


def _true_background_rate(windows: int = 4000) -> float:
    """The room's background rate: windows above the threshold with the robot silent."""
    room = FakeRoom(_room(partner=False), seed=99)
    binarizer = Binarizer(THRESHOLD_DB)
    hits = 0
    for _ in range(windows):
        samples = room.next_window().samples.astype(np.float32).astype(np.float64)
        energy = 10 * np.log10(np.mean(samples * samples) + 1e-12)
        hits += bool(binarizer.push(float(energy)))
    return hits / windows


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, tuple[Path, list, list]]:
    root = tmp_path_factory.mktemp("fake_room_sessions")
    return {
        "partner": _session(root / "partner", partner=True, seed=4),
        "partner2": _session(root / "partner2", partner=True, seed=5),
        "nobody": _session(root / "nobody", partner=False, seed=4),
    }


def test_analyze_finds_the_set_self_and_reply_periods(sessions, tmp_path: Path,
                                                      capsys) -> None:
    out = tmp_path / "params.yaml"
    bags = [str(sessions[name][0]) for name in ("partner", "partner2")]
    assert main(["analyze", *bags, "--out", str(out)]) == 0  # enough data: no shortcoming
    text = capsys.readouterr().out
    assert "self-feedback period (ts1, ts2): (0, 1)" in text
    assert "reply period (ta1, ta2): (2, 4)" in text
    written = ModelParams.load(str(out))
    assert (written.ts1, written.ts2, written.ta1, written.ta2) == (0, 1, 2, 4)


def test_the_rates_lie_within_their_intervals(sessions) -> None:
    _, bits, decisions = sessions["partner"]
    study = fig4_study(bits, decisions, max_lag=20, background_from=6)
    assert study.vocalizations >= 100
    # The robot hears itself every time.
    low, high = study.self_rate.interval
    assert low <= 1.0 <= high + 1e-12 and study.self_rate.value == 1.0
    # Lag 3 (1.5-2.0 s) holds the body of every reply: its rate is the reply probability.
    low, high = study.by_lag[3].interval
    assert low <= REPLY_PROBABILITY <= high
    low, high = study.background.interval
    assert low <= _true_background_rate() <= high


def test_without_a_partner_there_is_no_reply_peak(sessions, tmp_path: Path, capsys) -> None:
    out = tmp_path / "params.yaml"
    assert main(["analyze", str(sessions["nobody"][0]), "--out", str(out)]) == 1
    text = capsys.readouterr().out
    assert "self-feedback period (ts1, ts2): (0, 1)" in text
    assert "reply period (ta1, ta2): not found" in text
    assert "too little data: no reply peak" in text
    assert "not written" in text and not out.exists()


def test_an_offline_session_replays_to_its_belief(sessions, capsys) -> None:
    assert main(["replay", str(sessions["partner"][0])]) == 0
    assert f"equals the recorded belief at all {STEPS} steps" in capsys.readouterr().out

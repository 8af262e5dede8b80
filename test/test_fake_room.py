"""The audio-level simulated room: timing of the robot's sound and replies, determinism."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.core.controllers import PolicyController
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.audio_loop import AudioWorld, simulate_audio_loop
from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.room_config import PRESETS, FakeRoomConfig, timing_warnings
from infomax_contingency.sim.rooms import ROOMS

ROBOT = ModelParams.named("robot")
QUIET = {"event_rate_hz": 0.0}


def fixed_at_40_db():
    return make_bit_source("energy", 16000, 0.5, threshold_mode="fixed", threshold_db=-40.0)


def energy(window) -> float:
    return float(window_energies_db(window.samples, 16000, 0.5)[0])


def run(room: FakeRoom, vocalize_at: set[int], windows: int) -> list[float]:
    out = []
    for k in range(windows):
        out.append(energy(room.next_window()))
        if k in vocalize_at:
            room.vocalize()
    return out


def test_robot_hears_itself_in_the_window_after_it_vocalizes() -> None:
    room = FakeRoom(FakeRoomConfig.preset("silent", **QUIET), seed=1)
    e = run(room, {3}, 8)
    loud = [k for k, x in enumerate(e) if x > -40]
    assert loud == [4]
    assert -24 < e[4] < -18 and all(-61 < x < -59 for k, x in enumerate(e) if k != 4)


def test_partner_replies_inside_the_agent_period() -> None:
    config = FakeRoomConfig.preset("responsive", reply_probability=1.0, **QUIET)
    for seed in range(20):
        room = FakeRoom(config, seed)
        e = run(room, {0}, 9)
        # vocalization after window 0: timer z = 0 in window 1, agent period z = 2..4
        loud = {k for k, x in enumerate(e) if x > -40}
        assert 1 in loud and 2 not in loud
        assert loud - {1} and loud - {1} <= {3, 4, 5}, (seed, e)
        assert room.replies == 1


def test_no_reply_without_partner_or_after_it_left() -> None:
    config = FakeRoomConfig.preset(
        "responsive", reply_probability=1.0, partner_arrive_s=2.0, partner_leave_s=4.0, **QUIET
    )
    room = FakeRoom(config, 0)
    windows = []
    for k in range(12):
        windows.append(room.next_window())
        if k in (0, 4, 8):  # vocalizations at 0.5 s, 2.5 s, 4.5 s
            room.vocalize()
    assert room.replies == 1
    assert [w.partner_present for w in windows] == [k in (4, 5, 6, 7) for k in range(12)]


def test_same_seed_same_sound_and_background_independent_of_the_robot() -> None:
    config = FakeRoomConfig.preset("noisy")
    a, b = FakeRoom(config, 5), FakeRoom(config, 5)
    assert run(a, {2, 9}, 20) == run(b, {2, 9}, 20)
    quiet_robot = FakeRoom(config, 5)
    silent_run = run(quiet_robot, set(), 20)
    assert run(FakeRoom(config, 6), set(), 20) != silent_run
    assert a.events == quiet_robot.events > 0, "the robot does not change the background"


def test_background_event_rate() -> None:
    room = FakeRoom(FakeRoomConfig.preset("noisy", event_rate_hz=2.0), seed=3)
    run(room, set(), 400)  # 200 s
    assert 300 < room.events < 500


def test_default_timing_fits_the_robot_and_paper_models() -> None:
    assert timing_warnings(FakeRoomConfig(), ROBOT) == []
    paper = ModelParams.named("paper")
    assert timing_warnings(FakeRoomConfig(window_s=0.8), paper) == []
    warnings = timing_warnings(FakeRoomConfig(reply_delay_min_s=0.2), ROBOT)
    assert len(warnings) == 1 and "before the agent period" in warnings[0]
    assert "dt" in timing_warnings(FakeRoomConfig(window_s=0.25), ROBOT)[0]


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("window_s", 0.0, "window_s"),
        ("reply_probability", 1.5, "probability"),
        ("noise_floor_db", 3.0, "noise_floor_db"),
        ("reply_max_s", 0.1, "reply_max_s"),
        ("partner_leave_s", 1.0, "partner_leave_s"),
        ("event_rate_hz", float("nan"), "finite"),
    ],
)
def test_bad_room_parameters_are_refused(field: str, value: float, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        FakeRoomConfig(**{"partner_arrive_s": 2.0, field: value})


def test_presets_are_the_registered_rooms_with_audio() -> None:
    assert list(PRESETS)[:3] == ["responsive", "silent", "noisy"]
    for background in ("quiet", "office", "poster-session", "tv-on"):
        for state in ("", "+partner", "+arriving", "+leaving"):
            assert background + state in PRESETS
    for name, fields in PRESETS.items():
        kind = ROOMS[name]
        assert fields == dict(kind.audio)
        config = FakeRoomConfig.preset(name)
        if kind.partner_present is not None:
            assert config.partner_present_at(1.0) == kind.partner_present, name
            assert config.partner_present_at(50.0) == kind.partner_present, name
        else:  # arriving or leaving: present at the start xor at the end
            assert config.partner_present_at(1.0) != config.partner_present_at(50.0), name


def test_unknown_preset() -> None:
    with pytest.raises(ValueError, match="rooms: responsive, silent, noisy, quiet"):
        FakeRoomConfig.preset("party")


def test_closed_loop_finds_the_partner_and_not_the_noise() -> None:
    """The robot's defaults: its table and mic_node's default bit source (background).

    (The robot's prior on K3, mean 0.05, is that source's; a fixed -40 dB threshold holds
    the noisy room's K3 at 0.5, far from it, and the belief passes 0.3 early there.)
    """
    from infomax_contingency.audio.bitsources import DEFAULT_BIT_SOURCE, make_bit_source

    table = PolicyTable.load(
        resource_path("policies", "robot_receding_H24_M60.npz"), expected_params=ROBOT
    )
    results = {}
    for room in ("responsive", "noisy"):
        bits = make_bit_source(DEFAULT_BIT_SOURCE, 16000, 0.5)
        bits.follow_model(ROBOT)
        records = simulate_audio_loop(
            PolicyController(table, ROBOT), FakeRoom(FakeRoomConfig.preset(room), 1), bits, 200
        )
        results[room] = np.array([r.belief for r in records])
        assert [r.t for r in records] == list(range(1, 201))
    assert results["responsive"][-1] > 0.99 and results["noisy"].max() < 0.05


def test_reconfigure_applies_from_the_next_window_and_is_deterministic() -> None:
    def run() -> tuple[list[float], list[bool]]:
        room = FakeRoom(FakeRoomConfig.preset("noisy"), seed=8)
        energies, present = [], []
        for index in range(20):
            if index == 10:
                room.reconfigure(
                    FakeRoomConfig.preset(
                        "noisy", noise_floor_db=-30.0, event_rate_hz=0.0, partner_arrive_s=6.0
                    )
                )
            window = room.next_window()
            energies.append(float(window_energies_db(window.samples, 16000, 0.5)[0]))
            present.append(window.partner_present)
        return energies, present

    energies, present = run()
    assert max(energies[:10]) > -40 and all(abs(e + 30.0) < 0.5 for e in energies[12:])
    assert present == [False] * 12 + [True] * 8
    assert run() == (energies, present)
    room = FakeRoom(FakeRoomConfig(), seed=1)
    with pytest.raises(ValueError, match="window_s cannot change"):
        room.reconfigure(FakeRoomConfig(window_s=0.25))


@pytest.mark.parametrize(("room", "loads_the_filters"), [
    ("responsive", False),  # config/fake_room.yaml's room: a white floor, no filter
    ("responsive+pink", True),
])  # fmt: skip
def test_a_room_loads_scipy_signal_only_when_it_filters(room: str, loads_the_filters: bool) -> None:
    """scipy.signal costs about 1 s of CPU to load, in every fake_audio_node process."""
    child = Path(__file__).resolve().parent / "child_imports.py"
    out = subprocess.run([sys.executable, str(child), f"child_room:step_room:{room}",
                          "scipy.signal"], capture_output=True, text=True, check=True)  # fmt: skip
    assert json.loads(out.stdout) == (["scipy.signal"] if loads_the_filters else [])


def test_the_offline_loop_tells_a_learning_source_which_windows_were_withheld() -> None:
    """As mic_node does: the robot's declared speech never sets a background threshold."""
    from types import SimpleNamespace

    class Room:
        def __init__(self) -> None:
            self.robot_sound = iter([False, True, False])

        def next_window(self):
            return SimpleNamespace(samples=np.zeros(8000, dtype=np.float32),
                                   partner_present=False, robot_sound=next(self.robot_sound))

        def vocalize(self) -> None:
            pass

    class LearningSource:
        needs_decisions = True
        last_energy_db = -60.0

        def __init__(self) -> None:
            self.decisions: list[tuple[int | None, bool]] = []

        def push_window(self, samples) -> bool:
            return False

        def note_decision(self, u, withheld: bool = False) -> None:
            self.decisions.append((u, withheld))

    source = LearningSource()
    world = AudioWorld(Room(), source, gap_steps=5)  # type: ignore[arg-type]
    for u in (1, 0, 0):
        world.observe()
        world.act(u)
    assert source.decisions == [(1, False), (0, True), (0, False)]
    undeclared = LearningSource()
    world = AudioWorld(Room(), undeclared, declare_self_sound=False,  # type: ignore[arg-type]
                       gap_steps=5)
    for u in (1, 0, 0):
        world.observe()
        world.act(u)
    assert undeclared.decisions == [(1, False), (0, False), (0, False)]

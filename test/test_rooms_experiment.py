"""Experiment ``rooms`` (audio rooms to posture), ``room-wav`` and the actions file."""

from __future__ import annotations

import contextlib
import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from infomax_contingency.audio.wav import read_wav
from infomax_contingency.cli.main import main
from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval import rooms as rooms_evaluation
from infomax_contingency.eval.rooms import (
    BINARIZERS,
    RoomsConfig,
    binarizer_options,
    controller_specs,
    experiment_rooms,
    make_binarizer,
    room_seed,
    run_room,
    settled_step,
)
from infomax_contingency.sim.actions import read_actions_csv, write_actions_csv

ROBOT = ModelParams.named("robot")
SMALL = {"backgrounds": ("quiet",), "binarizer": "fixed:-40", "seconds": 30.0, "jobs": 1}


def test_settled_step_needs_a_correct_posture_to_the_end() -> None:
    partner = np.array([True] * 6)
    beliefs = np.array([0.01, 0.5, 0.95, 0.6, 0.95, 0.97])
    attentive = np.array([False, False, True, False, True, True])
    assert settled_step(attentive, partner, beliefs, 0.2, 0) == 4
    assert settled_step(attentive[:4], partner[:4], beliefs[:4], 0.2, 0) is None
    # nobody there: bored is correct, but only once the belief fell below bored_below
    empty = np.zeros(5, dtype=bool)
    assert settled_step(empty, empty, np.array([0.3, 0.25, 0.1, 0.3, 0.1]), 0.2, 0) == 2
    assert settled_step(empty, empty, np.full(5, 0.3), 0.2, 0) is None
    # counted from the change (a partner leaving at step 2)
    left = np.array([True, True, False, False, False])
    was_attentive = np.array([True, True, True, False, False])
    beliefs = np.array([0.95, 0.95, 0.5, 0.1, 0.05])
    assert settled_step(was_attentive, left, beliefs, 0.2, 2) == 3


def test_experiment_detects_the_partner_and_measures_the_bits() -> None:
    config = RoomsConfig(runs=2, controllers=("optimal", "fixed"), **SMALL)
    result = experiment_rooms(config)
    assert result["rooms"] == ["quiet", "quiet+partner", "quiet+arriving", "quiet+leaving"]
    optimal = result["summaries"]["optimal receding H=24 M=60"]
    with_partner = optimal["quiet+partner"]
    assert with_partner["settled"] > 0 and with_partner["wrong_at_end"] < 1
    bits = with_partner["p_active"]
    assert bits["agent"]["p"] > 0.4 > 0.1 > bits["background"]["p"], bits
    assert optimal["quiet"]["false_attentive"] == 0 and optimal["quiet"]["missed_partner"] == 0
    assert optimal["quiet"]["p_active"]["agent"]["windows"] == 0, "no partner: no agent windows"
    # the agent windows per lag (timer ta1 .. ta2) add up to the pooled ones, and the bound's
    # belief is the robot's (one K2 per lag) at those rates
    lags = with_partner["p_active_agent_lags"]
    assert len(lags) == ROBOT.ta2 - ROBOT.ta1 + 1
    assert [sum(lag[k] for lag in lags) for k in ("active", "windows")] == [
        bits["agent"]["active"], bits["agent"]["windows"]]
    bound = result["information_bound"]["optimal receding H=24 M=60"]["quiet"]
    assert bound["p_agent_lags"] == [lag["p"] for lag in lags] and bound["belief"] is not None
    curve = result["operating_curves"]["fixed K=8"]["quiet"][repr(ROBOT.pi)]
    assert [point["attentive_above"] for point in curve] == list(config.curve_thresholds)
    # a lower threshold never settles later (the posture turns attentive no later)
    medians = [point["settled_s_median"] for point in curve]
    assert medians == sorted(medians)
    json.dumps(result)  # plain data


def test_every_controller_hears_the_same_room_and_runs_are_reproducible() -> None:
    specs = dict(controller_specs(ROBOT, ["optimal", "random"]))
    runs = {
        label: run_room(ROBOT, "office+partner", spec, "fixed:-40", 10.0, 4, 2, 60)
        for label, spec in specs.items()
    }
    first = [run.energy_db[0] for run in runs.values()]
    assert first[0] == first[1], "the same room before the robot has done anything"
    again = run_room(ROBOT, "office+partner", specs["random P=1/8"], "fixed:-40", 10.0, 4, 2, 60)
    assert np.array_equal(again.belief, runs["random P=1/8"].belief)
    assert room_seed(4, "office+partner", 2) != room_seed(4, "office+partner", 3)
    assert room_seed(4, "office", 2) != room_seed(4, "office+partner", 2)


def test_calibrating_binarizer_takes_room_time_without_steps() -> None:
    spec = controller_specs(ROBOT, ["fixed"])[0][1]
    run = run_room(ROBOT, "office+partner", spec, "calibrate:5", 20.0, 0, 0, 60)
    assert run.window.size == 0 or run.window[0] >= 10  # 5 s of calibration: 10 windows
    assert run.window.size <= 40 - 10


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"binarizer": "loud"}, "binarizer 'loud': unknown binarizer; binarizers: calibrate"),
        ({"binarizer": "fixed"}, "fixed:DB"),
        ({"binarizer": "fixed:loud"}, "bad number"),
        ({"backgrounds": ("garage",)}, "unknown room 'garage'"),
        ({"controllers": ("greedy",)}, "controllers"),
        ({"partner_states": ("gone",)}, "partner_states"),
        ({"partner_states": ()}, "partner_states"),
        ({"runs": 0}, "runs"),
        ({"seed": -1}, "seed"),
        ({"seconds": 10.0}, "seconds"),
        ({"attentive_above": 0.1}, "attentive_above"),
        ({"curve_priors": (0.0,)}, "curve_priors"),
    ],
)
def test_bad_settings_are_refused(changes: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        RoomsConfig(**{**SMALL, **changes})


def test_partner_states_choose_the_rooms() -> None:
    config = RoomsConfig(**{**SMALL, "partner_states": ("partner", "absent")})
    assert config.room_names() == ["quiet", "quiet+partner"]


def test_binarizer_factory() -> None:
    assert make_binarizer("fixed:-35", 0.5).threshold_db == -35.0
    calibrating = make_binarizer("calibrate", 0.5)
    assert calibrating.calibrating and calibrating.rule.calibration_windows == 20
    assert make_binarizer("speech_band:noise_floor:6:3", 0.5).rule.warmup_windows == 6


@pytest.mark.parametrize(
    ("name", "source", "options"),
    [
        ("calibrate", "energy", {"threshold_mode": "calibrate"}),
        ("calibrate:5", "energy", {"threshold_mode": "calibrate", "calibration_s": 5.0}),
        ("fixed:-40", "energy", {"threshold_mode": "fixed", "threshold_db": -40.0}),
        ("energy:fixed:-35", "energy", {"threshold_mode": "fixed", "threshold_db": -35.0}),
        ("speech_band:calibrate", "speech_band", {"threshold_mode": "calibrate"}),
        ("speech_band:noise_floor", "speech_band", {"threshold_mode": "noise_floor"}),
        (
            "energy:noise_floor:12",
            "energy",
            {"threshold_mode": "noise_floor", "noise_margin_db": 12.0},
        ),
        (
            "speech_band:noise_floor:6:3",
            "speech_band",
            {"threshold_mode": "noise_floor", "noise_margin_db": 6.0, "calibration_s": 3.0},
        ),
        (
            "energy:file:/a/b.json",
            "energy",
            {"threshold_mode": "file", "threshold_file": "/a/b.json"},
        ),
        ("vad", "vad", {}),
        ("vad:3", "vad", {"vad_aggressiveness": 3}),
        ("vad:0:0.25", "vad", {"vad_aggressiveness": 0, "vad_min_voiced_s": 0.25}),
    ],
)
def test_binarizer_grammar(name: str, source: str, options: dict) -> None:
    assert binarizer_options(name) == (source, options)


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("speech_band", "speech_band needs a threshold_mode"),
        ("energy:loudest", "unknown threshold_mode 'loudest'"),
        ("speech_band:fixed:x", "bad number 'x' for DB"),
        ("energy:noise_floor:6:soon", "bad number 'soon' for WARMUP_S"),
        ("fixed:nan", "DB must be finite"),
        ("vad:4", r"AGGRESSIVENESS: vad_aggressiveness = 4 is not allowed: .* in \[0, 3\]"),
        ("vad:2:0.1:9", "at most AGGRESSIVENESS and MIN_VOICED_S"),
        ("vad:2:0.8", "longer than a window"),  # make_bit_source's own check
        ("energy:noise_floor:-3", r"MARGIN_DB: noise_margin_db = -3.0 is not allowed: .*100\] dB"),
        ("energy:file:/nonexistent/threshold.json", "threshold"),
    ],
)
def test_bad_binarizer_names_list_the_grammar(name: str, message: str) -> None:
    with pytest.raises(ValueError, match=message) as error:
        make_binarizer(name, 0.5)
    text = str(error.value)
    assert "\n" not in text and text.endswith(
        ", ".join(BINARIZERS) + " (SOURCE: energy or speech_band)"
    ), text


@pytest.mark.parametrize(
    "name", ["speech_band:fixed:-40", "energy:noise_floor:6:2", "speech_band:noise_floor:6:2",
             "vad:3", "vad:1:0.2"],
)  # fmt: skip
def test_every_bit_source_runs_in_the_loop(name: str) -> None:
    spec = controller_specs(ROBOT, ["fixed"])[0][1]
    run = run_room(ROBOT, "quiet+partner", spec, name, 12.0, 0, 0, 60)
    warmup = 4 if "noise_floor" in name else 0  # 2 s of floor: 4 windows without a bit
    assert run.window.size == 24 - warmup and run.window[0] == warmup
    assert run.u.sum() >= 2 and set(np.unique(run.y)) <= {0, 1}
    assert run.y.any(), "the partner's replies and the robot's own sound are heard"


def test_command_prints_json_and_refuses_bad_input(capsys, tmp_path: Path) -> None:
    out = tmp_path / "rooms.json"
    argv = ["experiment", "rooms", "--runs", "1", "--seconds", "25", "--rooms", "quiet"]
    argv += ["--controllers", "fixed", "--binarizer", "fixed:-40", "--jobs", "1"]
    assert main([*argv, "--json", "--out", str(out)]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["experiment"] == "rooms"
    assert json.loads(out.read_text())["rooms"] == printed["rooms"]
    assert main([*argv, "--binarizer", "whisper"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "unknown binarizer" in error


def test_room_wav_writes_the_sound_and_its_actions(capsys, tmp_path: Path) -> None:
    wav = tmp_path / "quiet.wav"
    argv = ["room-wav", "quiet+partner", "--seconds", "6", "--seed", "3", "--out", str(wav)]
    assert main([*argv, "--controller", "fixed:4", "--binarizer", "fixed:-40"]) == 0
    samples, rate = read_wav(wav)
    assert rate == 16000 and samples.size == 6 * 16000
    # decisions after steps 4, 8 (and 12, played after the end): commanded at 2 s and 4 s
    assert read_actions_csv(tmp_path / "quiet.csv") == [2.0, 4.0]
    loud = np.abs(samples[round(2.15 * rate) : round(2.35 * rate)]).max()
    assert loud > 10 * np.abs(samples[round(1.6 * rate) : round(1.9 * rate)]).max()
    assert main([*argv[:-1], str(tmp_path / "quiet.mp3")]) == 2
    assert "must end in .wav" in capsys.readouterr().err


def test_room_wav_replaces_only_an_actions_file_it_was_not_told_of(
        capsys, tmp_path: Path, monkeypatch) -> None:
    """The csv beside ``--out`` is replaced if it is an actions file or empty, else kept."""
    monkeypatch.setattr(rooms_evaluation, "render_room", lambda *a: pytest.fail("rendered"))
    wav, beside = tmp_path / "r.wav", tmp_path / "r.csv"
    beside.write_text("name,score\nann,3\n")
    assert main(["room-wav", "quiet", "--seconds", "5", "--out", str(wav)]) == 2
    assert capsys.readouterr().err == (
        f"infomax-contingency room-wav: error: {beside} exists and is not an actions file:"
        " nothing is written; give --actions to name where the robot's vocalization times"
        " go\n")
    assert beside.read_text() == "name,score\nann,3\n" and not wav.exists()
    rendered = (np.zeros(16000 * 5, dtype=np.float32), [1.0], 16000)
    monkeypatch.setattr(rooms_evaluation, "render_room", lambda *a: rendered)
    for earlier in ("time_s\n0.500000\n", ""):
        beside.write_text(earlier)
        assert main(["room-wav", "quiet", "--seconds", "5", "--out", str(wav)]) == 0
        assert read_actions_csv(beside) == [1.0]
    capsys.readouterr()
    beside.write_text("name,score\n")  # named with --actions: replaced, as every --out is
    assert main(["room-wav", "quiet", "--seconds", "5", "--out", str(wav), "--actions",
                 str(beside)]) == 0
    assert read_actions_csv(beside) == [1.0]


@contextlib.contextmanager
def fifo_with_a_reader(path: Path):
    """A FIFO at ``path`` whose read end is open: a write into it would not block."""
    os.mkfifo(path)
    reader = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        yield path
    finally:
        os.close(reader)


def test_room_wav_refuses_one_file_for_both_and_a_fifo_before_rendering(
        capsys, tmp_path: Path, monkeypatch) -> None:
    """The wav and its actions file are two files, regular ones, checked before the work."""
    monkeypatch.setattr(rooms_evaluation, "render_room", lambda *a: pytest.fail("rendered"))
    (tmp_path / "sub").mkdir()
    (tmp_path / "here").symlink_to(".")
    wav = tmp_path / "r.wav"
    argv = ["room-wav", "quiet+partner", "--seconds", "5", "--out", str(wav), "--actions"]
    for actions in (wav, tmp_path / "sub" / ".." / "r.wav", tmp_path / "here" / "r.wav"):
        assert main([*argv, str(actions)]) == 2
        assert capsys.readouterr().err == (
            f"infomax-contingency room-wav: error: --out {wav} and --actions {actions} name"
            " one file: give each its own\n")
    with fifo_with_a_reader(tmp_path / "fifo") as fifo:
        assert main([*argv, str(fifo)]) == 2
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and "--actions" in error and "(it is a FIFO)" in error
    assert stat.S_ISFIFO(fifo.lstat().st_mode) and not wav.exists()


def test_actions_file_is_written_over_nothing_but_a_regular_file(tmp_path: Path) -> None:
    with fifo_with_a_reader(tmp_path / "fifo") as fifo:
        with pytest.raises(ValueError, match="actions file .* is not a regular file"):
            write_actions_csv(fifo, [1.0])
    (tmp_path / "link").symlink_to("fifo")
    with pytest.raises(ValueError, match=r"\(it is a symbolic link\)"):
        write_actions_csv(tmp_path / "link", [1.0])
    assert stat.S_ISFIFO(fifo.lstat().st_mode)


def test_actions_file_round_trip_and_bad_files(tmp_path: Path) -> None:
    path = tmp_path / "a.csv"
    write_actions_csv(path, [0.5, 3.0, 4.5])
    assert read_actions_csv(path) == [0.5, 3.0, 4.5]
    with pytest.raises(ValueError, match="increasing"):
        write_actions_csv(path, [1.0, 1.0])
    for text, message in [
        ("t\n1.0\n", "header"),
        ("time_s\n1.0\nsoon\n", "line 3"),
        ("time_s\n2.0\n1.0\n", "later than"),
        ("time_s\nnan\n", "finite"),
    ]:
        path.write_text(text)
        with pytest.raises(ValueError, match=message):
            read_actions_csv(path)


@pytest.mark.parametrize(("option", "value", "message"), [
    ("--check-in-every-s", "nan", "check-in interval must be in [0, 3600] s"),
    ("--check-in-above", "1", "check-in threshold must be in [0.5, 0.9999], got 1"),
])
def test_rooms_refuse_check_ins_the_node_would_refuse(capsys, option: str, value: str,
                                                      message: str) -> None:
    assert main(["experiment", "rooms", "--rooms", "quiet", "--runs", "1", option, value]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error, error

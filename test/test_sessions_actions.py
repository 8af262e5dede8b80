"""replay --actions: a controller on recorded bits, a wav file with an actions CSV or channel.

A policy on a session's recorded bits, a wav file with an actions CSV file or with a
channel carrying the robot's own output; and their bad input.
"""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path

import numpy as np
import pytest

import brute_force
from infomax_contingency.audio.resample import load_mono
from infomax_contingency.audio.synth import synthesize_chirp
from infomax_contingency.audio.wav import write_wav_int16
from infomax_contingency.cli.main import main
from infomax_contingency.core.model import NAMED_PARAMS
from infomax_contingency.eval.sessions import (
    decisions_from_times,
    load_session,
    write_offline_session,
)
from infomax_contingency.resources import resource_path

DATA = Path(__file__).parent / "data"
SESSION = DATA / "session_demo"
WAV = DATA / "interaction.wav"
CHIRPS_S = (1.0, 5.0, 9.5, 14.0)
"""When interaction.wav's robot chirps start (test/data/make_interaction.py)."""
ROBOT_TABLE = resource_path("policies", "robot_receding_H24_M60.npz")
JSON_KEYS = {"t", "time_s", "z", "y", "u", "belief", "entropy", "ratio"}


def _rows(capsys) -> list[dict]:
    return [json.loads(line) for line in capsys.readouterr().out.splitlines()]


def _csv(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.fixture
def stereo_wav(tmp_path: Path) -> Path:
    """interaction.wav on channel 0 and the robot's chirps alone on channel 1 (16 kHz)."""
    rate = 16000
    mic = load_mono(WAV, rate)
    reference = np.zeros_like(mic)
    chirp = synthesize_chirp(rate, 0.2, amplitude=0.5)
    for start_s in CHIRPS_S:
        start = round(start_s * rate)
        reference[start:start + chirp.size] += chirp
    path = tmp_path / "stereo.wav"
    write_wav_int16(path, np.stack([mic, reference], axis=1), rate)
    return path


def test_the_robots_own_table_on_the_recorded_bits_makes_the_recorded_decisions(capsys
                                                                                 ) -> None:
    # The session was recorded with this table in the loop: on the same bits it decides
    # as the robot did, and its belief is the recorded one (of one K2, as it was recorded).
    one_k2 = str(DATA / "robot_one_k2.yaml")
    assert main(["replay", str(SESSION), "--actions", f"policy:{ROBOT_TABLE}", "--json",
                 "--params", one_k2]) == 0
    rows = _rows(capsys)
    session = load_session(SESSION)
    assert [row["u"] for row in rows] == [int(u) for _, u in session.decisions]
    assert [row["belief"] for row in rows] == session.beliefs
    assert JSON_KEYS == set(rows[0])


def test_another_controller_on_the_recorded_bits_is_a_what_if(capsys) -> None:
    assert main(["replay", str(SESSION), "--actions", "fixed:4", "--json"]) == 0
    rows = _rows(capsys)
    assert len(rows) == 120
    assert [row["u"] for row in rows] == [int(t % 4 == 0) for t in range(1, 121)]
    assert [row["y"] for row in rows] == [int(b) for _, b in load_session(SESSION).bits]


def test_a_what_if_on_a_session_with_withheld_steps_leaves_them_uncounted(
    tmp_path: Path, capsys
) -> None:
    bits = [k % 3 == 0 for k in range(24)]
    withheld = [k in (4, 5, 6, 13) for k in range(24)]  # the robot's sound, a gap
    bag = write_offline_session(tmp_path / "bag", bits, [False] * 24, [0.01] * 24, 0.5,
                                withheld=withheld)  # fmt: skip
    assert main(["replay", str(bag), "--actions", "fixed:4", "--json"]) == 0
    rows = _rows(capsys)
    params = NAMED_PARAMS["robot"]
    events = []
    for k, row in enumerate(rows):
        assert (row["y"], row["u"]) == (int(bits[k]), int((k + 1) % 4 == 0))
        if not withheld[k]:
            events.append((brute_force.evidence(params, row["z"]), row["y"]))
        assert row["belief"] == pytest.approx(brute_force.belief(params, events), abs=1e-12)


def test_a_forged_step_in_a_bag_is_left_out_as_the_live_nodes_leave_it(
    tmp_path: Path, capsys
) -> None:
    """``ros2 topic pub`` of a far-ahead step during a recording: named, not replayed."""
    from infomax_contingency.audio.bag import BagWriter, encode
    from infomax_contingency.eval.sessions import OFFLINE_STREAM, replay_recorded

    params = NAMED_PARAMS["robot"]
    bits = [k % 4 == 1 for k in range(30)]
    decisions = [k % 6 == 0 for k in range(30)]
    clean = write_offline_session(tmp_path / "clean", bits, decisions, [0.5] * 30, 0.5)
    beliefs = [r.belief for r in replay_recorded(load_session(clean), params)]
    writer = BagWriter(tmp_path / "forged")
    qos = [{"history": 1, "depth": 1000, "reliability": 1, "durability": 2}]
    for topic, kind in (("/sound_step", "std_msgs/msg/Int64MultiArray"),
                        ("/vocalize_step", "std_msgs/msg/Int64MultiArray"),
                        ("/belief", "std_msgs/msg/Float64")):  # fmt: skip
        writer.add_topic(topic, kind, qos)
    for t in range(30):
        now = round(t * 0.5e9)
        writer.write("/sound_step", encode("std_msgs/msg/Int64MultiArray",
                     data=[OFFLINE_STREAM, t + 1, int(bits[t]), 500000, 0]), now)  # fmt: skip
        if t == 10:  # the forgery, with the true stream id
            writer.write("/sound_step", encode("std_msgs/msg/Int64MultiArray",
                         data=[OFFLINE_STREAM, 50000, 1, 500000, 0]), now + 5)  # fmt: skip
        writer.write("/vocalize_step", encode("std_msgs/msg/Int64MultiArray",
                     data=[OFFLINE_STREAM, t + 1, int(decisions[t]), 2]), now + 1)  # fmt: skip
        writer.write("/belief", encode("std_msgs/msg/Float64", data=beliefs[t]), now + 2)
    writer.close()
    assert main(["replay", str(tmp_path / "forged")]) == 0
    captured = capsys.readouterr()
    assert "replayed belief equals the recorded belief at all 30 steps" in captured.out
    assert "the recorded bit for step 50000 ignored: it jumps ahead of step 11" in captured.err


def test_a_wav_with_an_actions_csv_puts_each_sound_on_the_step_before_its_window(
    tmp_path: Path, capsys
) -> None:
    actions = _csv(tmp_path / "actions.csv", "time_s\n" + "\n".join(map(str, CHIRPS_S)) + "\n")
    # (--calibrate: a bit for every window, from the first; the default first hears the room)
    assert main(["replay", str(WAV), "--actions", str(actions), "--json", "--calibrate"]) == 0
    rows = _rows(capsys)
    assert len(rows) == 36 and JSON_KEYS == set(rows[0])
    # A sound commanded at t lies in window floor(t / 0.5) (from 0): the decision on the
    # window before it, step floor(t / 0.5) counting from 1.
    assert [row["t"] for row in rows if row["u"]] == [2, 10, 19, 28]
    assert [row["z"] for row in rows if row["t"] in (3, 11, 20, 29)] == [0, 0, 0, 0]
    assert all(row["y"] for row in rows if row["t"] in (3, 11, 20, 29))  # the chirp heard


def test_a_sound_during_the_warm_up_labels_the_steps_after_it(tmp_path: Path, capsys) -> None:
    """A recorded robot that spoke before the default threshold's first bit.

    Its sound and the windows after it are counted in their own periods, not as
    background: each step's timer follows every recorded decision (warm-up windows' too),
    and the belief equals direct counting of the steps' bits at those timers.
    """
    actions = _csv(tmp_path / "actions.csv", "time_s\n" + "\n".join(map(str, CHIRPS_S)) + "\n")
    assert main(["replay", str(WAV), "--actions", str(actions), "--json"]) == 0
    rows = _rows(capsys)
    params = NAMED_PARAMS["robot"]
    decisions = decisions_from_times(CHIRPS_S, 36, params.dt, "x")
    timers = [params.ta2 + 1]
    for u in decisions:
        timers.append(brute_force.next_timer(params, timers[-1], int(u)))
    first = 36 - len(rows)  # the windows before it heard the room (no step)
    # (the sounds took windows from the warm-up: the first step comes after the third)
    assert rows[0]["z"] == timers[first] < params.ta2 + 1, first
    events = []
    for k, row in enumerate(rows):
        assert (row["z"], row["u"]) == (timers[first + k], int(decisions[first + k]))
        events.append((brute_force.evidence(params, row["z"]), row["y"]))
        assert row["belief"] == pytest.approx(brute_force.belief(params, events), abs=1e-12)


def test_a_wav_that_gives_no_step_is_undetermined_and_says_why(tmp_path: Path, capsys) -> None:
    """Shorter than the warm-up: no threshold, no verdict made up."""
    short = tmp_path / "short.wav"
    write_wav_int16(short, np.random.default_rng(3).normal(0, 0.01, 16000 * 4), 16000)
    actions = _csv(tmp_path / "actions.csv", "time_s\n1.0\n3.0\n")
    assert main(["replay", str(short), "--actions", str(actions)]) == 1
    out = capsys.readouterr().out
    assert "the recording's 8 windows are fewer than the warm-up's 8 background windows" in out
    assert "-> undetermined (no step)" in out and "no partner" not in out


def test_a_noise_gated_recording_replays_with_the_defaults(tmp_path: Path, capsys) -> None:
    """All zeros between sounds (a noise gate): the silence is the room's background."""
    rate = 16000
    mic = load_mono(WAV, rate)
    mic[np.abs(mic) < 0.02] = 0.0  # the gate: quiet samples become digital silence
    gated = tmp_path / "gated.wav"
    write_wav_int16(gated, mic, rate)
    actions = _csv(tmp_path / "actions.csv", "time_s\n" + "\n".join(map(str, CHIRPS_S)) + "\n")
    assert main(["replay", str(gated), "--actions", str(actions)]) == 0
    out = capsys.readouterr().out
    assert "were digital silence" in out and "steps" in out, out
    assert " 0 steps" not in out


def test_a_replayed_wav_takes_the_level_band_of_mic_node(tmp_path: Path, capsys) -> None:
    """--level-band as mic_node's level_band; refused where no self-calibrating threshold is."""
    rate = 16000
    room = np.random.default_rng(2).normal(0, 0.01, rate * 20)
    t = np.arange(room.size) / rate
    room += 0.3 * np.sin(2 * np.pi * 60.0 * t) * (np.sin(2 * np.pi * 0.1 * t) > 0)  # a hum
    wav = tmp_path / "hum.wav"
    write_wav_int16(wav, room, rate)
    actions = _csv(tmp_path / "actions.csv", "time_s\n8.0\n12.0\n")
    thresholds = {}
    for band, words in (("speech", "speech-band"), ("full", "whole-window")):
        options = [] if band == "speech" else ["--level-band", band]
        assert main(["replay", str(wav), "--actions", str(actions), *options]) == 0
        out = capsys.readouterr().out
        assert f"background windows' {words} levels (" in out, out
        thresholds[band] = float(out.split(f"{words} levels (")[1].split(" dB")[0])
        assert main(["replay", str(wav), "--actions", "random:0.1", *options]) == 0
        assert f"self-calibrating sound threshold ({words} levels)" in capsys.readouterr().out
    assert thresholds["full"] > thresholds["speech"] + 10.0  # the hum counts in full only
    with pytest.raises(SystemExit):
        main(["replay", str(wav), "--actions", str(actions), "--level-band", "low"])
    capsys.readouterr()
    assert main(["replay", str(wav), "--actions", str(actions), "--level-band", "full",
                 "--threshold-db", "-30"]) == 2  # fmt: skip
    assert ("--level-band sets a wav file's self-calibrating threshold: not with a recorded"
            " session, --threshold-db or --calibrate") in capsys.readouterr().err


def test_a_replayed_wav_reports_clipping_and_a_dc_offset(tmp_path: Path, capsys) -> None:
    rate = 16000
    noise = np.random.default_rng(1).normal(0, 0.01, rate * 20)
    noise[::50] = 1.0  # 2 % of the samples at full scale
    faulty = tmp_path / "faulty.wav"
    write_wav_int16(faulty, noise + 0.3, rate)  # and a DC offset
    actions = _csv(tmp_path / "actions.csv", "time_s\n8.0\n12.0\n")
    for how in (str(actions), "random:0.1"):  # recorded actions, and a what-if
        assert main(["replay", str(faulty), "--actions", how]) == 0
        out = capsys.readouterr().out
        assert "windows were clipped (samples at full scale): lower the input gain" in out, out
        assert "windows had a DC offset (removed from the level; check the microphone)" in out


def test_a_float_wav_not_scaled_to_full_scale_is_named_with_a_fixed_threshold(
    tmp_path: Path, capsys
) -> None:
    """IEEE-float samples 1000 times too large (+60 dB): said, not a silent answer."""
    rate = 16000
    samples = (load_mono(WAV, rate) * 1000.0).astype("<f4")
    fmt = struct.pack("<HHIIHH", 3, 1, rate, rate * 4, 4, 32)  # IEEE float, mono, 32 bits
    body = (b"WAVE" + b"fmt " + struct.pack("<I", len(fmt)) + fmt + b"data"
            + struct.pack("<I", samples.nbytes) + samples.tobytes())  # fmt: skip
    loud = tmp_path / "unscaled.wav"
    loud.write_bytes(b"RIFF" + struct.pack("<I", len(body)) + body)
    actions = _csv(tmp_path / "actions.csv", "time_s\n" + "\n".join(map(str, CHIRPS_S)) + "\n")
    for how in (str(actions), "random:0.1"):  # recorded actions, and a what-if
        assert main(["replay", str(loud), "--actions", how, "--threshold-db", "-30"]) == 0
        out = capsys.readouterr().out
        assert " windows were louder than full scale (0 dB: samples beyond [-1, 1], a float" in out
    assert main(["replay", str(WAV), "--actions", str(actions), "--threshold-db", "-30"]) == 0
    assert "louder than full scale" not in capsys.readouterr().out


def test_a_kmeans_refusal_names_a_dc_offset(tmp_path: Path, capsys) -> None:
    """The energy rule counts a DC offset as sound; the refusal says so, in one line."""
    rate = 16000
    speechy = load_mono(WAV, rate)
    offset = tmp_path / "offset.wav"
    write_wav_int16(offset, speechy * 0.3 + 0.5, rate)
    actions = _csv(tmp_path / "actions.csv", "time_s\n" + "\n".join(map(str, CHIRPS_S)) + "\n")
    assert main(["replay", str(offset), "--actions", str(actions), "--calibrate"]) == 2
    error = capsys.readouterr().err
    assert "windows have a DC offset, which the energy counts as sound" in error, error
    assert len(error.strip().splitlines()) == 1


def test_a_reference_channel_sounding_in_the_first_window_is_refused(tmp_path: Path,
                                                                     capsys) -> None:
    rate = 16000
    mic = load_mono(WAV, rate)
    reference = np.zeros_like(mic)
    chirp = synthesize_chirp(rate, 0.2, amplitude=0.5)
    for start_s in (0.0, *CHIRPS_S[1:]):  # the first at once: it follows no decision
        reference[round(start_s * rate):round(start_s * rate) + chirp.size] += chirp
    stereo = tmp_path / "early.wav"
    write_wav_int16(stereo, np.stack([mic, reference], axis=1), rate)
    assert main(["replay", str(stereo), "--actions", "channel:1"]) == 2
    error = capsys.readouterr().err
    assert "the robot's sound already plays in the first window" in error
    assert len(error.strip().splitlines()) == 1


def test_a_closed_pipe_ends_the_replay_quietly(tmp_path: Path) -> None:
    """``replay X.wav --json | head``: 1,200 steps, more than a pipe's buffer (64 KiB)."""
    import subprocess
    import sys

    long_wav = tmp_path / "ten_minutes.wav"
    write_wav_int16(long_wav, np.random.default_rng(2).normal(0, 0.01, 600 * 8000), 8000)
    actions = _csv(tmp_path / "actions.csv", "time_s\n8.0\n")
    command = (f"{sys.executable} -m infomax_contingency.cli replay {long_wav} --actions"
               f" {actions} --json | head -n 1")  # fmt: skip
    result = subprocess.run(command, shell=True, capture_output=True, text=True, timeout=120)
    assert len(result.stdout.splitlines()) == 1 and result.stderr == "", result.stderr


def test_a_reference_channel_gives_the_decisions_of_the_csv(stereo_wav: Path, tmp_path: Path,
                                                            capsys) -> None:
    actions = _csv(tmp_path / "actions.csv", "time_s\n" + "\n".join(map(str, CHIRPS_S)) + "\n")
    assert main(["replay", str(stereo_wav), "--actions", str(actions), "--mic-channel", "0",
                 "--json", "--calibrate"]) == 0
    from_csv = _rows(capsys)
    assert main(["replay", str(stereo_wav), "--actions", "channel:1", "--json",
                 "--calibrate"]) == 0
    from_channel = _rows(capsys)
    assert [row["t"] for row in from_channel if row["u"]] == [2, 10, 19, 28]
    assert from_channel == from_csv


def test_time_mapping_convention() -> None:
    assert decisions_from_times([0.5, 1.0, 1.99], 5, 0.5, "x") == [True, True, True, False, False]
    with pytest.raises(ValueError, match="two sounds commanded"):
        decisions_from_times([0.6, 0.9], 4, 0.5, "x")
    for huge in (1e20, 1e308):  # 1e308 / 0.5 overflows: still the one line, not a traceback
        with pytest.raises(ValueError, match=re.escape(f"time_s {huge:g} lies beyond the")):
            decisions_from_times([huge], 4, 0.5, "x")


@pytest.mark.parametrize("csv_text, message", [
    ("time\n1.0\n", "the first line must be the header 'time_s'"),
    ("time_s,u\n1.0,1\n", "the first line must be the header 'time_s'"),
    ("", "found 'an empty file'"),
    ("time_s\n5.0\n2.0\n", "line 3: time_s 2 does not come after the previous 5"),
    ("time_s\n5.0\n5.0\n", "does not come after"),
    ("time_s\n1.0\nabc\n", "line 3: 'abc' is not a time in seconds"),
    ("time_s\n-1.0\n", "must be a finite number >= 0"),
    ("time_s\nnan\n", "must be a finite number >= 0"),
    ("time_s\n18.0\n", "time_s 18 lies beyond the recording (18 s, 36 windows"),
    ("time_s\n100\n", "lies beyond the recording"),
    ("time_s\n0.2\n", "lies in the first window"),
])
def test_a_bad_actions_csv_is_one_line_and_status_2(csv_text: str, message: str,
                                                    tmp_path: Path, capsys) -> None:
    actions = _csv(tmp_path / "actions.csv", csv_text)
    assert main(["replay", str(WAV), "--actions", str(actions)]) == 2
    error = capsys.readouterr().err
    assert message in error, error
    assert len(error.strip().splitlines()) == 1


def test_bad_channels_and_combinations_are_one_line_and_status_2(stereo_wav: Path,
                                                                 tmp_path: Path, capsys
                                                                 ) -> None:
    silent = tmp_path / "silent.wav"
    mic = load_mono(WAV, 16000)
    write_wav_int16(silent, np.stack([mic, np.zeros_like(mic)], axis=1), 16000)
    cases = [
        ([str(stereo_wav), "--actions", "channel:2"], "has 2 channel(s), numbered 0 .. 1"),
        ([str(stereo_wav), "--actions", "channel:x"], "must be a whole number"),
        ([str(WAV), "--actions", "channel:0"], "has one channel"),
        ([str(silent), "--actions", "channel:1"], "the channel holds no sound of the robot"),
        ([str(stereo_wav), "--actions", "channel:1", "--mic-channel", "1"],
         "is the reference channel"),
        ([str(stereo_wav), "--actions", "policy:x.npz", "--mic-channel", "5"],
         "channel 5 does not exist"),
        ([str(WAV)], "has no recorded actions"),
        ([str(WAV), "--actions", "recorded"], "has no recorded actions"),
        ([str(SESSION), "--actions", "channel:1"], "goes with a wav file"),
        ([str(SESSION), "--actions", str(tmp_path / "a.csv")], "goes with a wav file"),
        ([str(WAV), "--actions", str(tmp_path / "none.csv")], "does not exist"),
        ([str(WAV), "--actions", "policy:/nonexistent.npz"], "nonexistent.npz"),
        ([str(WAV), "--actions", "bogus"], "unknown controller"),
        ([str(WAV), "--actions", "fixed:3", "--calibrate", "--calibration-s", "0"],
         "--calibration-s must be > 0"),
        ([str(WAV), "--actions", "fixed:3", "--calibration-s", "3"], "give --calibrate too"),
        ([str(WAV), "--actions", "fixed:3", "--calibrate", "--calibration-s", "inf"],
         "--calibration-s must be > 0 seconds, got inf"),
        ([str(WAV), "--actions", "fixed:3", "--calibrate", "--threshold-db", "-30"],
         "--calibrate or --threshold-db"),
        ([str(WAV), "--actions", "fixed:3", "--threshold-db", "5"], "--threshold-db"),
    ]
    for arguments, message in cases:
        assert main(["replay", *arguments]) == 2, arguments
        error = capsys.readouterr().err
        assert message in error, (arguments, error)
        assert len(error.strip().splitlines()) == 1, error


def test_a_noisy_recording_replays_with_the_defaults_where_kmeans_refuses(
    tmp_path: Path, capsys
) -> None:
    """A noisy hall: the default self-calibrating threshold finds the partner.

    A poster session (12 distant talkers at -30 dB), a partner who answers 90 % of the
    robot's sounds: k-means cannot separate sound from quiet (7 dB); the default threshold
    finds the partner with the recording's own actions.
    """
    from infomax_contingency.eval.rooms import render_room
    from infomax_contingency.sim.actions import write_actions_csv

    # the robot chirps every 8 steps of fixed -40 dB bits (from window 1: no warm-up)
    samples, times, rate = render_room("poster-session+partner", 45.0, seed=7,
                                       controller="fixed:8", binarizer="fixed:-40")  # fmt: skip
    wav, actions = tmp_path / "hall.wav", tmp_path / "hall.csv"
    write_wav_int16(wav, samples, rate)
    write_actions_csv(actions, times)
    assert main(["replay", str(wav), "--actions", str(actions)]) == 0
    out = capsys.readouterr().out
    belief = float(out.split("final P(S=1) = ")[1].split()[0])
    assert belief > 0.99, out
    assert "the first 12 windows heard the room" in out  # 8 of warm-up, 4 of delay
    assert main(["replay", str(wav), "--actions", str(actions), "--calibrate"]) == 2
    assert "clusters lie only 6.9 dB apart" in capsys.readouterr().err


def test_a_what_if_on_a_wav_times_its_steps_by_the_files_windows(capsys, tmp_path: Path
                                                                 ) -> None:  # fmt: skip
    """As with recorded actions: a step's time_s is its window's start in the file."""
    assert main(["replay", str(WAV), "--actions", f"policy:{ROBOT_TABLE}", "--json"]) == 0
    rows = _rows(capsys)
    assert rows[0]["time_s"] == 6.0  # the warm-up: 8 background windows, then 4 more
    assert [row["time_s"] for row in rows] == [6.0 + 0.5 * k for k in range(len(rows))]
    late = tmp_path / "late.wav"  # 4 s of zeros first: no room, no step
    write_wav_int16(late, np.concatenate([np.zeros(4 * 16000), load_mono(WAV, 16000)]), 16000)
    assert main(["replay", str(late), "--actions", f"policy:{ROBOT_TABLE}", "--json"]) == 0
    assert [row["time_s"] for row in _rows(capsys)] == [row["time_s"] + 4.0 for row in rows]


def test_a_wav_whose_header_claims_an_absurd_rate_is_named_before_its_actions(
    tmp_path: Path, capsys
) -> None:
    """4 GHz in the header: 3 s of samples last microseconds; said of the file, in one line."""
    wav = tmp_path / "rate.wav"
    write_wav_int16(wav, np.zeros(3 * 16000), 16000)
    header = bytearray(wav.read_bytes())
    header[24:28] = struct.pack("<I", 4_000_000_000)  # the fmt chunk's sample rate
    wav.write_bytes(bytes(header))
    actions = tmp_path / "a.csv"
    actions.write_text("time_s\n1.5\n")
    assert main(["replay", str(wav), "--actions", str(actions)]) == 2
    error = capsys.readouterr().err
    assert f"{wav} lasts 0.000 s, shorter than one window" in error, error
    assert len(error.strip().splitlines()) == 1

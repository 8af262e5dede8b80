"""Tests of the live-audio commands: ``devices``, ``calibrate`` and ``measure-latency``.

``calibrate`` and ``devices`` run through the real PortAudio/ALSA stack on virtual devices
(a subprocess per configuration, see alsa_devices.py). ``measure-latency`` needs an
acoustic loop, which file-plugin devices cannot give (they have no clock): its
measurement runs on the fake PortAudio's simulated room; through ALSA only the devices'
opening and the "not heard" error are checked.
"""

from __future__ import annotations

import functools
import os
import stat

import numpy as np
import pytest
import yaml

from alsa_devices import VirtualAlsa
from fake_portaudio import FakeBackend, FakeClock, Room, device
from infomax_contingency.audio import devices as audio_devices
from infomax_contingency.audio.bitsources import make_bit_source, window_levels_db
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.audio.latency import measure_latency
from infomax_contingency.audio.resample import load_mono
from infomax_contingency.audio.threshold import kmeans_split
from infomax_contingency.audio.threshold_file import load_threshold
from infomax_contingency.audio.wav import write_wav_int16
from infomax_contingency.cli import live as live_commands
from infomax_contingency.cli import main as cli
from test_live_audio import write_recording


def run_cli(alsa: VirtualAlsa, *args: str) -> tuple[int, str, str]:
    result = alsa.run("cli", args=list(args))
    stdout = result["_stdout"].rsplit("\n", 2)[0]
    return result["rc"], stdout, result["_stderr"]


@pytest.fixture
def room_wav(tmp_path):
    return write_recording(tmp_path / "room.wav", 16000, seconds=7.0)


def test_calibrate_on_a_wav_prints_threshold_and_histogram(room_wav, tmp_path, capsys) -> None:
    out = tmp_path / "cal" / "threshold.yaml"
    assert cli.main(["calibrate", "--wav", str(room_wav), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    energies = window_energies_db(load_mono(room_wav), 16000, 0.5)
    fit = kmeans_split(energies)
    assert load_threshold(out) == fit.threshold_db
    record = yaml.safe_load(out.read_text())
    assert record["window_s"] == 0.5 and record["source"] == f"wav:{room_wav}"
    assert f"calibrated on {energies.size} windows of 0.5 s from {room_wav}" in text
    assert f"threshold: {fit.threshold_db:.2f} dB (quiet: {fit.n_low} windows" in text
    assert f"threshold {fit.threshold_db:.1f} dB" in text  # the histogram's marker
    bars = [line for line in text.splitlines() if " dB | " in line]
    assert sum(int(line.rsplit(" ", 1)[1]) for line in bars) == energies.size
    assert "warning" not in text
    assert f"wrote {out}" in text


def _not_regular_files(directory) -> list[tuple[str, object]]:
    """A FIFO, a symbolic link to a file and a dangling one in ``directory``: (kind, path)."""
    fifo, link, dangling = (directory / name for name in ("fifo", "link", "dangling"))
    os.mkfifo(fifo)
    (directory / "target.txt").write_text("keep me")
    link.symlink_to("target.txt")
    dangling.symlink_to("nowhere.txt")
    return [("a FIFO", fifo), ("a symbolic link", link), ("a symbolic link", dangling)]


def test_calibrate_writes_over_nothing_but_a_regular_file(room_wav, tmp_path, capsys) -> None:
    """A FIFO or symbolic link at --out is refused before calibrating, and left as it was."""
    for kind, path in _not_regular_files(tmp_path):
        assert cli.main(["calibrate", "--wav", str(room_wav), "--out", str(path)]) == 2
        out, err = capsys.readouterr()
        assert err == (f"infomax-contingency calibrate: error: --out {path} is not a regular"
                       f" file (it is {kind}): nothing is written over it; give a new"
                       " name or a regular file\n")
        assert "calibrated on" not in out  # refused before the audio was read
    assert stat.S_ISFIFO((tmp_path / "fifo").lstat().st_mode)
    assert (tmp_path / "link").is_symlink() and (tmp_path / "dangling").is_symlink()
    assert (tmp_path / "target.txt").read_text() == "keep me"
    assert not (tmp_path / "nowhere.txt").exists()


def test_calibrate_reports_the_default_bit_source_as_a_replay_hears_it(tmp_path, capsys) -> None:
    """Without --out: the threshold mic_node's default sets itself, the robot silent."""
    wav = write_recording(tmp_path / "room.wav", 16000, seconds=20.0)
    assert cli.main(["calibrate", "--wav", str(wav)]) == 0
    text = capsys.readouterr().out
    source = make_bit_source("background", 16000, 0.5)  # the replay's path, on samples
    windows = load_mono(wav)[: 40 * 8000].reshape(40, 8000)
    bits = [source.push_recorded(window, 0) for window in windows]
    decided = [bit for bit in bits if bit is not None]
    assert len(decided) == 40 - 12  # no bit in the first 12 windows (as mic_node says)
    assert "heard 40 windows of 0.5 s from" in text and "(speech-band levels)" in text
    assert f"threshold {source.threshold_db:.2f} dB at the end (room: the" in text
    assert f"{sum(decided)} of {len(decided)} windows after its warm-up active" in text
    assert f"threshold {source.threshold_db:.1f} dB" in text  # the histogram's marker
    assert "nothing to write" in text and not list(tmp_path.glob("*.yaml"))
    short = write_recording(tmp_path / "short.wav", 16000, seconds=6.0)  # 12 windows
    assert cli.main(["calibrate", "--wav", str(short)]) == 0
    assert "would give no bit yet: its first bit comes after 12 windows" in (
        capsys.readouterr().out)


def test_calibrate_reports_what_mic_node_would_warn_of(tmp_path, capsys) -> None:
    """Clipping, a DC offset and digital silence: the source's own warnings, no made-up bits."""
    rng = np.random.default_rng(0)
    clipped = tmp_path / "clipped.wav"
    write_wav_int16(clipped, np.clip(3.0 * rng.standard_normal(16000 * 10), -1, 1), 16000)
    assert cli.main(["calibrate", "--wav", str(clipped)]) == 0
    assert "warning: 20 windows were clipped (samples at full scale)" in capsys.readouterr().out
    offset = tmp_path / "offset.wav"
    write_wav_int16(offset, 0.3 + 0.01 * rng.standard_normal(16000 * 10), 16000)
    assert cli.main(["calibrate", "--wav", str(offset)]) == 0
    assert "warning: 20 windows had a DC offset" in capsys.readouterr().out
    silent = tmp_path / "silent.wav"
    write_wav_int16(silent, np.zeros(16000 * 10), 16000)
    assert cli.main(["calibrate", "--wav", str(silent)]) == 1
    text = capsys.readouterr().out
    assert "warning: 20 of 20 windows were digital silence" in text
    assert "would give no bit here" in text and " dB | " not in text  # no made-up threshold


def test_calibrate_refuses_a_threshold_file_for_the_default_bit_source(
    room_wav, tmp_path, capsys
) -> None:
    out = tmp_path / "t.yaml"
    assert cli.main(["calibrate", "--wav", str(room_wav), "--bit-source", "background",
                     "--out", str(out)]) == 2  # fmt: skip
    assert "needs no threshold file" in capsys.readouterr().err
    assert cli.main(["calibrate", "--wav", str(room_wav), "--force"]) == 2
    assert "--force is for a k-means threshold written to a file: give --out FILE" in (
        capsys.readouterr().err)
    for options, named in ((["--bit-source", "speech_band"], "--bit-source speech_band"),
                           (["--bit-source", "energy"], "--bit-source energy"),
                           (["--min-separation-db", "3"], "--min-separation-db")):
        assert cli.main(["calibrate", "--wav", str(room_wav), *options]) == 2, options
        assert f"{named} is for a k-means threshold" in capsys.readouterr().err
    assert not out.exists()


def test_calibrate_user_errors(room_wav, tmp_path, capsys) -> None:
    out = tmp_path / "t.yaml"
    assert cli.main(["calibrate", "--wav", str(room_wav), "--device", "1", "--out", str(out)]) == 2
    assert "not both" in capsys.readouterr().err
    silent = tmp_path / "silent.wav"
    write_wav_int16(silent, np.zeros(16000), 16000)
    assert cli.main(["calibrate", "--wav", str(silent), "--out", str(out)]) == 2
    assert "no boundary between quiet and sound" in capsys.readouterr().err
    assert cli.main(["calibrate", "--wav", str(tmp_path / "none.wav"), "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not out.exists()
    # the window is the model's dt: no --window-s, a model that cannot load is refused
    assert cli.main(["calibrate", "--wav", str(room_wav), "--params", str(tmp_path / "no.yaml"),
                     "--out", str(out)]) == 2  # fmt: skip
    assert "no.yaml" in capsys.readouterr().err and not out.exists()
    with pytest.raises(SystemExit):
        cli.main(["calibrate", "--wav", str(room_wav), "--window-s", "0.5", "--out", str(out)])


def test_calibrate_on_the_live_microphone_matches_the_wav(room_wav, tmp_path, capsys) -> None:
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.wav_microphone("fakemic", room_wav)
    alsa.write(default_capture="fakemic")
    live = tmp_path / "live.yaml"
    rc, stdout, _ = run_cli(
        alsa, "calibrate", "--device", "fake", "--seconds", "7", "--out", str(live)
    )
    assert rc == 0, stdout
    offline = tmp_path / "offline.yaml"
    assert cli.main(["calibrate", "--wav", str(room_wav), "--out", str(offline)]) == 0
    assert load_threshold(live) == load_threshold(offline)
    assert yaml.safe_load(live.read_text())["source"] == "device:fakemic"
    assert "calibrated on 14 windows of 0.5 s from fakemic (16000 Hz)" in stdout
    assert "threshold" in stdout and " dB | " in stdout
    rc, stdout, _ = run_cli(alsa, "calibrate", "--device", "fake", "--seconds", "7")
    assert rc == 0, stdout
    assert "let it hear the room as it is, the robot silent" in stdout
    assert "heard 14 windows of 0.5 s from fakemic (16000 Hz) (speech-band levels)" in stdout
    capsys.readouterr()
    assert cli.main(["calibrate", "--wav", str(room_wav)]) == 0
    offline_report = capsys.readouterr().out.splitlines()[1:]
    assert offline_report and offline_report == stdout.splitlines()[-len(offline_report):]


def test_calibrate_for_the_speech_band_on_a_wav_and_live_writes_its_level(
    room_wav, tmp_path
) -> None:
    offline = tmp_path / "band.yaml"
    assert cli.main(["calibrate", "--wav", str(room_wav), "--bit-source", "speech_band",
                     "--out", str(offline)]) == 0  # fmt: skip
    windows = load_mono(room_wav)[: 14 * 8000].reshape(14, 8000)
    fit = kmeans_split(window_levels_db("speech_band", windows, 16000))
    assert load_threshold(offline, "speech_band") == fit.threshold_db
    assert yaml.safe_load(offline.read_text())["level"] == "speech_band"
    assert "its speech_band level > threshold_db" in offline.read_text()
    with pytest.raises(AudioError, match="holds a threshold of the speech_band level, not of"):
        load_threshold(offline)  # mic_node's bit_source energy refuses it
    energy = tmp_path / "energy.yaml"
    assert cli.main(["calibrate", "--wav", str(room_wav), "--out", str(energy)]) == 0
    assert "level" not in yaml.safe_load(energy.read_text())  # as before levels existed
    with pytest.raises(AudioError, match="calibrate again with --bit-source speech_band"):
        make_bit_source("speech_band", 16000, 0.5, threshold_mode="file",
                        threshold_file=str(energy))  # fmt: skip
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.wav_microphone("fakemic", room_wav)
    alsa.write(default_capture="fakemic")
    live = tmp_path / "live.yaml"
    rc, stdout, _ = run_cli(alsa, "calibrate", "--device", "fake", "--seconds", "7",
                            "--bit-source", "speech_band", "--out", str(live))  # fmt: skip
    assert rc == 0, stdout
    assert load_threshold(live, "speech_band") == fit.threshold_db


def test_calibrate_on_a_missing_device_lists_the_devices(tmp_path) -> None:
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.microphone("fakemic", np.zeros(1600))
    alsa.write(default_capture="fakemic")
    rc, _, stderr = run_cli(alsa, "calibrate", "--device", "USB", "--out", str(tmp_path / "t"))
    assert rc == 2
    assert "infomax-contingency calibrate: error: no input device name contains 'USB'" in stderr
    assert "[0] fakemic (ALSA" in stderr


def test_devices_lists_inputs_and_outputs(tmp_path) -> None:
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.microphone("fakemic", np.zeros(1600))
    alsa.speaker("fakespeaker")
    alsa.write(default_capture="fakemic", default_playback="fakespeaker")
    rc, stdout, _ = run_cli(alsa, "devices")
    assert rc == 0
    inputs, outputs = stdout.split("output devices (loudspeakers):")
    assert "[0] fakemic (ALSA" in inputs and "fakespeaker" not in inputs
    assert "[1] fakespeaker (ALSA" in outputs and "fakemic" not in outputs
    assert "default" in inputs and "<- system default" in inputs


def test_measure_latency_on_virtual_devices_reports_not_heard(tmp_path) -> None:
    # file-plugin devices: the loudspeaker writes a file, the microphone hears silence
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.microphone("fakemic", np.zeros(1600))
    out = alsa.speaker("fakespeaker")
    alsa.write(default_capture="fakemic", default_playback="fakespeaker")
    rc, stdout, stderr = run_cli(
        alsa, "measure-latency", "--repeats", "2", "--interval-s", "0.3", "--volume", "0.2"
    )
    assert rc == 2
    assert "microphone: default; loudspeaker: default" in stdout
    assert stdout.count("the sound was not heard") == 2
    assert "measure-latency: error: the sound was not heard in any repeat" in stderr
    assert np.fromfile(out, dtype="<f4").any()  # the chirps were played


def test_measure_latency_reports_delay_and_self_period(monkeypatch, capsys) -> None:
    clock = FakeClock()
    room = Room(16000, delay_s=0.25, clock=clock)
    backend = FakeBackend(
        [device(0, "robot mic", 1, 0, 16000), device(1, "robot speaker", 0, 1, 16000)],
        default_input=0,
        default_output=1,
        clock=clock,
        source=room.source,
        sink=room.sink,
        output_latency_s=0.03,
    )
    monkeypatch.setattr(audio_devices, "SoundDeviceBackend", lambda: backend)
    on_the_clock = functools.partial(measure_latency, clock=clock, sleep=clock.sleep)
    monkeypatch.setattr(live_commands, "measure_latency", on_the_clock)
    rc = cli.main(["measure-latency", "--repeats", "2", "--interval-s", "0.7"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "microphone: robot mic; loudspeaker: robot speaker" in text
    lines = [line for line in text.splitlines() if line.startswith("heard ")]
    assert len(lines) == 2
    delays = [float(line.split()[1]) for line in lines]
    assert all(280 <= d <= 330 for d in delays)  # 250 ms room + 30 ms output + a block
    assert "self-feedback delay: mean" in text and "over 2 repeat(s)" in text
    # heard over [~0.29, ~0.59] s (200 ms sound + 100 ms tail): windows 0 and 1 of 0.5 s
    assert "heard in windows z = 0..1 after a vocalization (windows of 0.5 s)" in text
    assert "implied self period: ts1 = 0, ts2 = 1 (parameters robot" in text
    assert "consistent" in text
    rc = cli.main(["measure-latency", "--repeats", "1", "--interval-s", "0.7", "--params", "paper"])
    text = capsys.readouterr().out
    assert rc == 0
    assert "ts1 = 0, ts2 = 0 (parameters paper" in text and "consistent" in text


def test_cli_registers_the_live_commands() -> None:
    parser = cli.build_parser()
    choices = parser._subparsers._group_actions[0].choices
    assert {"devices", "calibrate", "measure-latency"} <= set(choices)


def test_calibrate_refuses_clusters_too_close_to_separate_unless_forced(tmp_path, capsys) -> None:
    # a steady hum whose loudness wobbles by 2 dB: two clusters, but no quiet and no sound
    rng = np.random.default_rng(2)
    gains = np.repeat(np.where(np.arange(12) % 2 == 1, 0.1 * 10 ** (2 / 20), 0.1), 8000)
    hum = tmp_path / "hum.wav"
    write_wav_int16(hum, gains * rng.standard_normal(gains.size), 16000)
    out = tmp_path / "t.yaml"
    assert cli.main(["calibrate", "--wav", str(hum), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert not out.exists()
    [line] = captured.err.splitlines()
    assert line.startswith("infomax-contingency calibrate: error: calibration cannot separate")
    assert "lie only 2.0 dB apart" in line and "--force" in line
    assert "threshold:" in captured.out  # the fit and the histogram are still shown
    assert cli.main(["calibrate", "--wav", str(hum), "--out", str(out), "--force"]) == 0
    captured = capsys.readouterr()
    assert "warning: calibration cannot separate" in captured.out and out.exists()
    assert "lie only 2.0 dB apart" in captured.out
    out.unlink()
    args = ["calibrate", "--wav", str(hum), "--out", str(out), "--min-separation-db", "1.5"]
    assert cli.main(args) == 0 and out.exists()
    with pytest.raises(SystemExit):
        cli.main(["calibrate", "--wav", str(hum), "--out", str(out), "--min-separation-db", "-1"])

"""Wav replay and the binarizer: the mic node's core, without ROS."""

from pathlib import Path

import numpy as np
import pytest
from scipy.io import wavfile

from infomax_contingency.audio.bitsources.rules import Binarizer
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.audio.resample import load_mono
from infomax_contingency.audio.threshold import (
    UnseparatedError,
    bits_from_energies,
    calibration_window_count,
    kmeans_split,
)
from infomax_contingency.audio.wav import write_wav_int16
from infomax_contingency.audio.windows import WavReplay

WAV = Path(__file__).parent / "data" / "interaction.wav"


def test_committed_interaction_is_small_and_resampled_on_replay() -> None:
    assert WAV.stat().st_size < 300_000
    replay = WavReplay(WAV, 0.5)
    expected = window_energies_db(load_mono(WAV), 16000, 0.5)
    served = [replay.next_energy() for _ in range(replay.n_windows)]
    assert served == expected.tolist()
    assert replay.next_energy() is None and replay.finished


def test_loop_starts_again(tmp_path: Path) -> None:
    path = tmp_path / "two.wav"
    rng = np.random.default_rng(0)
    write_wav_int16(
        path, np.concatenate([rng.normal(0, 0.001, 800), rng.normal(0, 0.3, 800)]), 1600
    )
    replay = WavReplay(path, 0.5, loop=True)
    energies = [replay.next_energy() for _ in range(5)]
    assert energies[0] == energies[2] == energies[4] and energies[1] == energies[3]
    assert energies[1] > energies[0] + 30 and not replay.finished


def test_channel_choice(tmp_path: Path) -> None:
    path = tmp_path / "stereo.wav"
    quiet, loud = np.full(16000, 0.001), np.full(16000, 0.5)
    write_wav_int16(path, np.stack([quiet, loud], axis=1), 16000)
    left, right = (WavReplay(path, 0.5, channel=c).next_energy() for c in (0, 1))
    assert right > left + 40
    with pytest.raises(AudioError, match="channel 2 does not exist"):
        WavReplay(path, 0.5, channel=2)


def test_file_shorter_than_a_window_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "short.wav"
    write_wav_int16(path, np.zeros(100), 16000)
    with pytest.raises(AudioError, match="shorter than one window"):
        WavReplay(path, 0.5)


def test_calibration_window_count() -> None:
    assert calibration_window_count(10.0, 0.5) == 20
    assert calibration_window_count(0.1, 0.5) == 2
    with pytest.raises(AudioError):
        calibration_window_count(0.0, 0.5)


def test_fixed_threshold_is_strict() -> None:
    binarizer = Binarizer(-40.0)
    assert [binarizer.push(e) for e in (-60.0, -40.0, -39.99)] == [False, False, True]


def test_streaming_calibration_consumes_its_windows_then_splits() -> None:
    energies = [-60.0, -20.0, -61.0, -22.0, -59.0, -21.0]
    binarizer = Binarizer(None, calibration_windows=4)
    out = [binarizer.push(e) for e in energies]
    assert out[:4] == [None] * 4 and out[4:] == [False, True]
    assert binarizer.threshold_db == kmeans_split(energies[:4]).threshold_db


def test_calibration_without_boundary_starts_again() -> None:
    binarizer = Binarizer(None, calibration_windows=2)
    assert binarizer.push(-120.0) is None and binarizer.push(-120.0) is None
    assert binarizer.calibrating and binarizer.calibration_failures == 1
    binarizer.push(-60.0)
    binarizer.push(-20.0)
    assert binarizer.threshold_db == pytest.approx(-40.0)


def test_read_ahead_calibration() -> None:
    binarizer = Binarizer()
    fit = binarizer.calibrate([-60.0, -20.0])
    assert binarizer.threshold_db == fit.threshold_db == -40.0 and not binarizer.calibrating
    with pytest.raises(AudioError):
        Binarizer().calibrate([-50.0, -50.0])


def test_refresh_follows_a_louder_room_but_ignores_pure_silence() -> None:
    binarizer = Binarizer(-40.0, refresh_windows=4, min_separation_db=10.0)
    for e in (-30.0, -10.0, -31.0, -11.0):  # the floor rose to -30 dB
        binarizer.push(e)
    assert binarizer.threshold_db == pytest.approx(-20.5) and binarizer.refits_accepted == 1
    for e in (-30.0, -30.5, -29.5, -30.2):  # only floor: two clusters 1 dB apart
        binarizer.push(e)
    assert binarizer.threshold_db == pytest.approx(-20.5)
    assert binarizer.refits_rejected >= 1


@pytest.mark.parametrize(
    "kwargs",
    [
        {"threshold_db": float("nan")},
        {"calibration_windows": 1},
        {"threshold_db": -40.0, "refresh_windows": 1},
        {"threshold_db": -40.0, "min_separation_db": -1.0},
    ],
)
def test_bad_binarizer_settings_are_refused(kwargs: dict) -> None:
    with pytest.raises(AudioError):
        Binarizer(**kwargs)


def long_two_level_wav(path: Path, rate: int, seconds: float, channels: int = 1) -> Path:
    """Alternating quiet (noise floor) and loud stretches of 0.7 s."""
    rng = np.random.default_rng(5)
    n = round(rate * seconds)
    loud = (np.arange(n) // round(0.7 * rate)) % 2 == 1
    x = rng.normal(0, 0.001, (n, channels)) + np.where(loud, 0.3, 0.0)[:, None] * rng.normal(
        0, 1, (n, channels)
    )
    write_wav_int16(path, np.clip(x, -1, 1), rate)
    return path


def test_replay_of_a_block_read_file_equals_the_offline_energies_through_loops(
    tmp_path: Path,
) -> None:
    path = long_two_level_wav(tmp_path / "long.wav", 44100, 9.3, channels=2)  # > 2 blocks
    expected = window_energies_db(load_mono(path), 16000, 0.1)
    replay = WavReplay(path, 0.1, loop=True)
    assert replay.n_windows == expected.size == 93
    served = [replay.next_energy() for _ in range(2 * replay.n_windows + 5)]
    assert served == expected.tolist() * 2 + expected[:5].tolist()
    ahead = replay.calibration_energies(2.0, 0.1)
    np.testing.assert_array_equal(ahead, expected[:20])
    np.testing.assert_array_equal(replay.calibration_energies(60.0, 0.1), expected)
    assert replay.position == 2 * 93 + 5  # reading ahead does not move the replay


def test_calibration_too_close_to_separate_is_refused_and_retried() -> None:
    warnings: list[str] = []
    binarizer = Binarizer(
        None, calibration_windows=4, min_separation_db=10.0, on_calibration_refused=warnings.append
    )
    # two clusters only 4 dB apart: a steady hum with a little variation
    out = [binarizer.push(e) for e in (-50.0, -46.0, -50.0, -46.0)]
    assert out == [None] * 4
    assert binarizer.state == "unseparated" and binarizer.calibrating
    assert binarizer.calibration_failures == 1
    assert "lie only 4.0 dB apart" in binarizer.calibration_problem
    assert "at least 10 dB" in binarizer.calibration_problem
    assert "calibrating again on the next 4 windows" in binarizer.calibration_problem
    assert warnings == [binarizer.calibration_problem]
    assert binarizer.rejected_fit.separation_db == pytest.approx(4.0)
    assert binarizer.threshold_db is None and binarizer.fit is None
    # the next windows are a new calibration: sound and quiet this time
    out = [binarizer.push(e) for e in (-60.0, -20.0, -61.0, -21.0, -59.0, -22.0)]
    assert out == [None] * 4 + [False, True]
    assert binarizer.state == "ready" and binarizer.calibration_problem == ""
    assert binarizer.threshold_db == pytest.approx(-40.5)
    assert binarizer.calibration_failures == 1 and len(warnings) == 1


def test_read_ahead_calibration_too_close_raises_with_the_gap() -> None:
    binarizer = Binarizer(min_separation_db=10.0)
    with pytest.raises(UnseparatedError, match=r"lie only 3\.0 dB apart") as caught:
        binarizer.calibrate([-50.0, -47.0, -50.0, -47.0])
    assert caught.value.separation_db == pytest.approx(3.0)
    assert binarizer.state == "unseparated" and binarizer.calibration_failures == 1
    assert "calibrating again" not in binarizer.calibration_problem  # read ahead: no retry
    assert Binarizer(min_separation_db=0.0).calibrate([-50.0, -47.0]).threshold_db == -48.5


def test_the_binarizer_bit_is_the_one_bit_rule() -> None:
    energies = np.array([-60.0, -40.0, -40.0 + 1e-12, -39.0, -80.0])
    binarizer = Binarizer(-40.0)
    bits = [binarizer.push(e) for e in energies]
    assert bits == bits_from_energies(energies, -40.0).tolist() == [False, False, True, True, False]


def test_read_ahead_reads_only_the_start_of_the_file(tmp_path: Path) -> None:
    # a float file whose 9th second holds a NaN: only a whole-file read reaches it
    rate = 8000
    x = np.random.default_rng(1).normal(0, 0.1, 10 * rate).astype(np.float32)
    x[: 2 * rate] *= 0.01
    x[9 * rate] = np.nan
    path = tmp_path / "late_nan.wav"
    wavfile.write(path, rate, x)
    replay = WavReplay(path, 0.5)
    ahead = replay.calibration_energies(4.0, 0.5)
    assert ahead.size == 8 and np.isfinite(ahead).all()
    served = [replay.next_energy() for _ in range(8)]
    np.testing.assert_array_equal(served, ahead)  # blocks up to 4 s are fine
    with pytest.raises(AudioError, match="NaN"):
        for _ in range(replay.n_windows):
            replay.next_energy()
    with pytest.raises(AudioError, match="NaN"):
        load_mono(path)


def test_replay_of_a_file_that_shrank_says_so(tmp_path: Path) -> None:
    path = tmp_path / "shrinks.wav"
    write_wav_int16(path, np.random.default_rng(0).normal(0, 0.1, 16000), 16000)
    replay = WavReplay(path, 0.25, loop=True)
    assert [replay.next_energy() is not None for _ in range(4)] == [True] * 4  # one pass
    write_wav_int16(path, np.zeros(8000), 16000)  # rewritten shorter while replaying
    assert replay.next_energy() == replay.next_energy() == -120.0  # the loop reopens it
    with pytest.raises(AudioError, match="ended after 2 of its 4 windows: the file changed"):
        replay.next_energy()

"""Bit sources (energy, speech_band, vad) and the noise-floor threshold, without ROS."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from infomax_contingency.audio.bitsources import BIT_SOURCES, all_setting_specs, make_bit_source
from infomax_contingency.audio.bitsources.base import OUT_OF_RANGE
from infomax_contingency.audio.bitsources.level import SpeechBandLevel
from infomax_contingency.audio.bitsources.rules import Binarizer, NoiseFloorBinarizer
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.energy import (
    ENERGY_FLOOR_DB,
    WindowAssembler,
    window_energies_db,
)
from infomax_contingency.audio.resample import load_mono, resample
from infomax_contingency.audio.threshold import (
    NoiseFloorTracker,
    bits_from_energies,
    calibration_window_count,
    kmeans_split,
)
from infomax_contingency.audio.windows import WavReplay
from infomax_contingency.core.controllers import PolicyController
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.resources import resource_path
from infomax_contingency.sim.audio_loop import simulate_audio_loop
from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.room_config import FakeRoomConfig

sys.path.insert(0, str(Path(__file__).parent / "data"))
import make_interaction  # noqa: E402  (the espeak-ng helper of the committed fixture)

ROOT = Path(__file__).resolve().parent.parent
WAV = Path(__file__).parent / "data" / "interaction.wav"
RATE, WINDOW_S, N = 16000, 0.5, 8000

# Options that make each source's bits defined from the first window on.
# (background gives no bit before it has heard the room: test/test_background.py)
READY_OPTIONS: dict[str, dict[str, object]] = {
    "energy": {"threshold_mode": "fixed", "threshold_db": -40.0},
    "speech_band": {"threshold_mode": "fixed", "threshold_db": -40.0},
    "vad": {},
}


def windows_of(samples: np.ndarray) -> np.ndarray:
    """The complete 0.5 s windows of 16 kHz samples, one per row."""
    n = samples.size // N
    return samples[: n * N].reshape(n, N)


def tone(hz: float, seconds: float, amplitude: float = 0.1) -> np.ndarray:
    t = np.arange(round(seconds * RATE)) / RATE
    return amplitude * np.sin(2 * np.pi * hz * t)


@pytest.fixture(scope="module")
def speech(tmp_path_factory: pytest.TempPathFactory) -> np.ndarray:
    """Several seconds of espeak-ng speech at 16 kHz (peak 0.5), whole windows only."""
    workdir = tmp_path_factory.mktemp("speech")
    text = "the robot asks a question and the child answers it with a few words"
    x = resample(make_interaction.speech(text, workdir), make_interaction.RATE_HZ, RATE)
    return windows_of(x).ravel()


# --------------------------------------------------------------------------- registry


def test_the_registry_names_every_source_and_its_options() -> None:
    assert tuple(BIT_SOURCES) == ("energy", "speech_band", "vad", "background")
    for name, options in READY_OPTIONS.items():
        source = make_bit_source(name, RATE, WINDOW_S, **options)
        assert source.samples_per_window == N and source.push_window(np.zeros(N)) is False
    with pytest.raises(AudioError, match="unknown bit source 'silero'; bit sources: energy"):
        make_bit_source("silero", RATE, WINDOW_S)
    with pytest.raises(AudioError, match="'vad' takes no option threshold_db; its options: vad_"):
        make_bit_source("vad", RATE, WINDOW_S, threshold_db=-40.0)
    with pytest.raises(AudioError, match="threshold_mode = 'median' is not allowed: one of"):
        make_bit_source("energy", RATE, WINDOW_S, threshold_mode="median")


def test_option_defaults_are_mic_node_defaults_in_robot_yaml() -> None:
    config = yaml.safe_load((ROOT / "config" / "robot.yaml").read_text())
    mic = config["/**/mic_node"]["ros__parameters"]
    for spec in all_setting_specs():
        assert mic[spec.name] == spec.default, spec.name
    assert mic["bit_source"] == "background"


def test_energy_source_gives_the_binarizers_bits_on_a_recording() -> None:
    energies = window_energies_db(load_mono(WAV), RATE, WINDOW_S)
    windows = windows_of(load_mono(WAV))
    calibration = calibration_window_count(10.0, WINDOW_S)
    reference = Binarizer(None, calibration)
    expected = [reference.push(e) for e in energies]
    by_samples = make_bit_source("energy", RATE, WINDOW_S)
    by_energy = make_bit_source("energy", RATE, WINDOW_S)
    assert not by_samples.needs_samples
    assert [by_samples.push_window(w) for w in windows] == expected
    assert [by_energy.push(e) for e in energies] == expected
    assert by_samples.threshold_db == reference.threshold_db
    assert by_samples.last_energy_db == energies[-1]


def test_wav_replay_serves_the_windows_of_the_file() -> None:
    replay = WavReplay(WAV, WINDOW_S, samples=True)
    served = np.array([replay.next_window() for _ in range(replay.n_windows)])
    assert np.array_equal(served, windows_of(load_mono(WAV)))
    assert replay.next_window() is None and replay.finished
    assert np.array_equal(replay.calibration_windows(2.0, WINDOW_S), served[:4])
    with pytest.raises(AudioError, match="use next_window"):
        replay.next_energy()
    with pytest.raises(AudioError, match="use next_energy"):
        WavReplay(WAV, WINDOW_S).next_window()


def test_the_assembler_cuts_windows_whatever_the_chunking() -> None:
    x = np.random.default_rng(3).normal(0, 0.1, 5 * N + 123)
    assembler = WindowAssembler(RATE, WINDOW_S)
    rows = [assembler.push_windows(chunk) for chunk in np.array_split(x, 17)]
    assert np.array_equal(np.concatenate(rows), windows_of(x))


# --------------------------------------------------------------------------- speech band


def test_speech_band_passes_voice_frequencies_and_rejects_hum_and_hiss() -> None:
    def level(hz: float) -> float:
        band = SpeechBandLevel(RATE)
        return [band.level_db(w) for w in windows_of(tone(hz, 2.0))][-1]

    full = window_energies_db(tone(1000, 0.5), RATE, WINDOW_S)[0]
    assert abs(level(1000) - full) < 0.5
    assert level(50) < full - 30 and level(7000) < full - 20


def test_speech_band_carries_its_filter_state_across_windows() -> None:
    from scipy.signal import sosfilt, sosfilt_zi  # here: scipy.signal takes ~0.5 s to load

    x = np.random.default_rng(4).normal(0, 0.1, 6 * N) + 0.3  # with a DC offset
    band = SpeechBandLevel(RATE)
    levels = [band.level_db(w) for w in windows_of(x)]
    # one pass over the whole signal, started as if the first window's mean had always been
    whole, _ = sosfilt(band._sos, x, zi=sosfilt_zi(band._sos) * x[:N].mean())
    assert np.allclose(levels, window_energies_db(whole, RATE, WINDOW_S), atol=1e-9)
    assert abs(levels[0] - levels[1]) < 1.0  # no step from the offset into the first window


def test_a_nan_window_does_not_spoil_the_speech_band_filter() -> None:
    x = np.random.default_rng(8).normal(0, 0.1, 3 * N)
    band = SpeechBandLevel(RATE)
    first, bad, last = windows_of(x)
    bad = bad.copy()
    bad[10] = np.nan
    band.level_db(first)
    assert not np.isfinite(band.level_db(bad))
    after = band.level_db(last)  # started again: as a fresh filter on this window
    assert np.isfinite(after)
    assert after == pytest.approx(SpeechBandLevel(RATE).level_db(last), abs=1e-9)


def test_speech_band_calibrates_ahead_like_a_stream() -> None:
    room = np.random.default_rng(5).normal(0, 0.003, 12 * N)
    room[3 * N : 4 * N] += tone(800, 0.5, 0.3)
    room[7 * N : 8 * N] += tone(1500, 0.5, 0.3)
    ahead = make_bit_source("speech_band", RATE, WINDOW_S, calibration_s=6.0)
    ahead.calibrate_ahead(np.full(12, np.nan), windows_of(room)[:12])  # levels from samples
    stream = make_bit_source("speech_band", RATE, WINDOW_S, calibration_s=6.0)
    assert [stream.push_window(w) for w in windows_of(room)[:12]] == [None] * 12
    assert stream.threshold_db == ahead.threshold_db is not None
    assert [ahead.push_window(w) for w in windows_of(room)] == [
        i in (3, 7) for i in range(12)
    ]


def test_speech_band_needs_a_rate_above_twice_the_band() -> None:
    with pytest.raises(AudioError, match="'rate_hz' = 6000: bit_source speech_band needs audio"):
        make_bit_source("speech_band", 6000, WINDOW_S)
    assert make_bit_source("speech_band", 8000, WINDOW_S).samples_per_window == 4000


# --------------------------------------------------------------------------- noise floor


def test_noise_floor_tracker_is_the_low_percentile_of_the_last_windows() -> None:
    rng = np.random.default_rng(6)
    levels = rng.normal(-60, 5, 300).round(1)  # rounded: with ties
    for capacity, percentile in ((1, 10.0), (7, 0.0), (40, 10.0), (40, 50.0)):
        tracker = NoiseFloorTracker(capacity, percentile)
        for i, level in enumerate(levels):
            tracker.add(float(level))
            recent = np.sort(levels[max(0, i + 1 - capacity) : i + 1])
            rank = math.floor(percentile / 100 * (recent.size - 1))
            assert tracker.floor_db == recent[rank]
    for bad in (-1.0, 51.0, True):
        with pytest.raises(AudioError, match="noise_percentile"):
            NoiseFloorTracker(10, bad)


def test_noise_floor_threshold_warms_up_then_follows_a_slowly_louder_room() -> None:
    rule = NoiseFloorBinarizer(margin_db=10.0, floor_windows=20, percentile=10.0,
                               warmup_windows=4)  # fmt: skip
    assert [rule.push(-60.0) for _ in range(3)] == [None] * 3
    assert rule.calibrating and rule.threshold_db is None and rule.state == "calibrating"
    assert rule.push(-60.0) is None
    assert not rule.calibrating and rule.threshold_db == -50.0 and rule.state == "ready"
    assert rule.push(-50.0) is False and rule.push(-49.9) is True  # strict, as every rule
    drift = [-60.0 + 0.25 * k for k in range(160)]  # the room gets 40 dB louder over 80 s
    assert not any(rule.push(level) for level in drift)  # a fixed -50 dB would say "sound"
    assert rule.push(drift[-1] + 20.0) is True  # a sound over the new floor still counts
    assert rule.floor_db > -30.0


def test_a_noise_floor_threshold_outside_the_parameters_range_gives_no_bits() -> None:
    """As a threshold file outside -150 .. 0 dB is refused: no made-up bits, said once."""
    said: list[str] = []
    rule = NoiseFloorBinarizer(margin_db=10.0, floor_windows=4, percentile=0.0,
                               warmup_windows=2, on_problem=said.append)  # fmt: skip
    assert [rule.push(-5.0) for _ in range(2)] == [None, None]  # warm-up
    assert rule.threshold_db == 5.0  # unscaled audio: its floor is above full scale - margin
    assert [rule.push(level) for level in (-5.0, 20.0, -5.0)] == [None, None, None]
    assert rule.state == OUT_OF_RANGE
    assert rule.windows_out_of_range == 3
    assert said == [rule.calibration_problem]  # once, while it lasts
    assert "threshold_db 5 dB is not allowed: -150 .. 0 dB" in said[0]
    for _ in range(4):  # the room is scaled again: the floor falls back into range
        rule.push(-60.0)
    assert rule.state == "ready" and rule.calibration_problem == ""
    assert rule.push(-40.0) is True and rule.windows_out_of_range == 4


def test_noise_floor_mode_is_offered_for_energy_and_speech_band() -> None:
    for name in ("energy", "speech_band"):
        source = make_bit_source(name, RATE, WINDOW_S, threshold_mode="noise_floor",
                                 calibration_s=1.0)  # fmt: skip
        hiss = np.random.default_rng(7).normal(0, 0.001, 4 * N)
        assert [source.push_window(w) for w in windows_of(hiss)] == [None, None, False, False]
        assert source.push_window(tone(1000, 0.5, 0.2)) is True
        assert "noise_floor_db" in source.diagnostic_values()
    with pytest.raises(AudioError, match="follows the noise floor by itself: set it to 0"):
        make_bit_source("energy", RATE, WINDOW_S, threshold_mode="noise_floor", refresh_s=5.0)
    with pytest.raises(AudioError, match="noise_margin_db"):
        make_bit_source("energy", RATE, WINDOW_S, threshold_mode="noise_floor",
                        noise_margin_db=-1.0)  # fmt: skip


# --------------------------------------------------------------------------- vad


def test_vad_hears_speech_over_a_steady_noise_floor_and_not_the_floor(speech: np.ndarray) -> None:
    rng = np.random.default_rng(8)
    rms = float(np.sqrt(np.mean(speech**2)))
    floor = rng.normal(0, rms * 10 ** (-15 / 20), 20 * N)  # 15 dB under the speech
    vad = make_bit_source("vad", RATE, WINDOW_S)
    noise_bits = [vad.push_window(w) for w in windows_of(floor)]
    noisy_speech = speech + rng.normal(0, rms * 10 ** (-15 / 20), speech.size)
    speech_bits = [vad.push_window(w) for w in windows_of(noisy_speech)]
    assert sum(noise_bits) <= 1  # the detector learns the floor in its first frames
    assert sum(speech_bits) >= 0.8 * len(speech_bits)
    assert vad.diagnostic_values()["voiced_windows"] == sum(speech_bits)


def test_vad_frames_run_on_across_window_edges(speech: np.ndarray) -> None:
    """30 ms frames do not fit a 0.5 s window: the rest waits for the next window."""
    import webrtcvad

    source = make_bit_source("vad", RATE, WINDOW_S)
    voiced_frames = 0
    for w in windows_of(speech):
        source.push_window(w)
        voiced_frames += round(source.last_voiced_s / 0.03)
    pcm = np.round(speech * 32767.0).astype(np.int16)
    whole = webrtcvad.Vad(2)  # the same detector over the whole signal, frame after frame
    frames = pcm[: pcm.size // 480 * 480].reshape(-1, 480)
    assert voiced_frames == sum(whole.is_speech(f.tobytes(), RATE) for f in frames)
    assert voiced_frames > 0.5 * len(frames)
    shorter = make_bit_source("vad", RATE, 0.25, vad_min_voiced_s=0.05)
    assert sum(shorter.push_window(w) for w in speech.reshape(-1, 4000)) > 0


def test_vad_refuses_what_webrtcvad_cannot_take() -> None:
    takes = "'rate_hz' = 44100: bit_source vad takes audio at 8000, 16000, 32000, 48000 Hz"
    with pytest.raises(AudioError, match=takes):
        make_bit_source("vad", 44100, WINDOW_S)
    for option, value, message in (
        ("vad_aggressiveness", 4, r"a whole number in \[0, 3\]"),
        ("vad_frame_ms", 25, "10, 20 or 30"),
        ("vad_min_voiced_s", 0.6, "longer than a window"),
        ("vad_min_voiced_s", 0.0, r"a number in \[0.001, 10\] s"),
    ):
        with pytest.raises(AudioError, match=message):
            make_bit_source("vad", RATE, WINDOW_S, **{option: value})
    for rate in (8000, 32000, 48000):
        assert make_bit_source("vad", rate, WINDOW_S).push_window(np.zeros(rate // 2)) is False


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("name", tuple(READY_OPTIONS))
def test_bad_windows_are_refused_in_one_line(name: str) -> None:
    source = make_bit_source(name, RATE, WINDOW_S, **READY_OPTIONS[name])
    for value in (np.nan, np.inf, -np.inf):
        window = np.zeros(N)
        window[100] = value
        with pytest.raises(AudioError, match="contain NaN or infinite values"):
            source.push_window(window)
    window = np.zeros(N)
    window[7] = 1e200
    with pytest.raises(AudioError, match="a sample of 1e[+]200 is not audio"):
        source.push_window(window)
    with pytest.raises(AudioError, match="a window must hold 8000 samples, got 7999"):
        source.push_window(np.zeros(N - 1))
    with pytest.raises(AudioError, match="must be mono"):
        source.push_window(np.zeros((N, 2)))
    with pytest.raises(AudioError, match="integers"):
        source.push_window(np.zeros(N, dtype=np.int16))
    assert source.push_window(np.zeros(N)) is False  # still usable afterwards


@pytest.mark.parametrize("name", tuple(READY_OPTIONS))
def test_silence_and_clipping_have_defined_bits(name: str, speech: np.ndarray) -> None:
    source = make_bit_source(name, RATE, WINDOW_S, **READY_OPTIONS[name])
    assert source.push_window(np.zeros(N)) is False
    assert source.last_energy_db == ENERGY_FLOOR_DB
    clipped = np.clip(8.0 * speech[:N], -1.0, 1.0)  # a shout, flattened at full scale
    assert source.push_window(clipped) is True
    beyond = 4.0 * speech[N : 2 * N]  # past full scale: measured as is (VAD: clipped)
    assert np.max(np.abs(beyond)) > 1.5
    assert source.push_window(beyond) is True
    assert source.last_energy_db == window_energies_db(beyond, RATE, WINDOW_S)[0]


@pytest.mark.parametrize("name", ("energy", "speech_band"))
def test_a_silent_calibration_is_refused_and_retried(name: str) -> None:
    refused: list[str] = []
    source = make_bit_source(name, RATE, WINDOW_S, calibration_s=1.0,
                             on_problem=refused.append)  # fmt: skip
    assert [source.push_window(np.zeros(N)) for _ in range(2)] == [None, None]
    assert source.state == "unseparated" and source.calibrating and source.problem
    assert refused and "no boundary between quiet and sound" in refused[0]


# --------------------------------------------------------------------------- offline loop


@pytest.mark.parametrize("name", tuple(READY_OPTIONS))
def test_the_offline_loop_takes_any_bit_source(name: str) -> None:
    table = PolicyTable.load(resource_path("policies", "robot_receding_H24_M60.npz"))

    def run(make: Callable[[], object]) -> list:
        room = FakeRoom(FakeRoomConfig.preset("responsive"), 3)
        return simulate_audio_loop(PolicyController(table), room, make(), 40)

    records = run(lambda: make_bit_source(name, RATE, WINDOW_S, **READY_OPTIONS[name]))
    assert records == run(lambda: make_bit_source(name, RATE, WINDOW_S, **READY_OPTIONS[name]))
    assert 0 < sum(r.y for r in records) < len(records)
    if name == "energy":  # the energy source is the bit rule, bit for bit
        energies = [r.energy_db for r in records]
        assert [r.y for r in records] == list(bits_from_energies(energies, -40.0))
    assert all(math.isfinite(r.energy_db) for r in records)
    assert kmeans_split([r.energy_db for r in records]).separation_db > 10


# --------------------------------------------------------------------------- command line


def test_demo_hands_its_bit_source_to_mic_node() -> None:
    from infomax_contingency.cli import demo
    from infomax_contingency.cli.main import build_parser

    for extra, expected in (([], None), (["--bit-source", "vad"], "vad")):
        for source in ([], ["--wav", str(WAV)]):
            args = build_parser().parse_args(["demo", *source, *extra])
            nodes, _clock = demo._nodes(args)
            assert nodes["mic_node"].get("bit_source") == expected
    with pytest.raises(SystemExit):
        build_parser().parse_args(["demo", "--bit-source", "silero"])


# --------------------------------------------------------------------------- a new source


def test_a_new_bit_source_is_one_class_and_one_registry_line() -> None:
    """The toy source (test/toy_bit_source.py), registered, serves the offline loop and names."""
    from infomax_contingency.eval.rooms import binarizer_options, make_binarizer
    from toy_bit_source import registered_toy

    with pytest.raises(ValueError, match="unknown binarizer"):
        binarizer_options("toy:-20")
    with registered_toy():
        assert binarizer_options("toy:-20") == ("toy", {"toy_level_db": -20.0})
        assert binarizer_options("toy") == ("toy", {})
        with pytest.raises(ValueError, match=r"toy_level_db = 5.0 is not allowed"):
            make_binarizer("toy:5", WINDOW_S)
        toy = make_bit_source("toy", RATE, WINDOW_S, toy_level_db=-40.0)
        room = FakeRoom(FakeRoomConfig.preset("responsive"), 3)
        table = PolicyTable.load(resource_path("policies", "robot_receding_H24_M60.npz"))
        records = simulate_audio_loop(PolicyController(table), room, toy, 40)
        energies = [r.energy_db for r in records]
        assert [r.y for r in records] == list(bits_from_energies(energies, -40.0))
        toy.set_live("toy_level_db", -10.0)
        assert toy.push_window(tone(1000, 0.5, 0.1)) is False  # -23 dB: quiet now
    assert "toy" not in BIT_SOURCES

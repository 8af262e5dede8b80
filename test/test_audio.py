"""Tests of the audio-to-bits core: reading wavs, energies, the k-means threshold, streaming."""

import math
import os
import stat
import struct
import warnings

import numpy as np
import pytest
import yaml
from scipy.io import wavfile

from infomax_contingency.audio.common import PROCESSING_RATE_HZ, AudioError
from infomax_contingency.audio.energy import (
    ENERGY_FLOOR,
    ENERGY_FLOOR_DB,
    WindowAssembler,
    iter_wav_energies,
    wav_energies,
    wav_window_count,
    window_energies_db,
    window_samples,
)
from infomax_contingency.audio.resample import StreamResampler, load_mono, resample
from infomax_contingency.audio.synth import synthesize_chirp
from infomax_contingency.audio.threshold import (
    OnlineThreshold,
    ThresholdFit,
    bits_from_energies,
    kmeans_split,
    kmeans_threshold,
)
from infomax_contingency.audio.threshold_file import (
    THRESHOLD_FORMAT_VERSION,
    load_threshold,
    save_threshold,
)
from infomax_contingency.audio.wav import (
    WavReader,
    open_wav_info,
    read_wav,
    to_mono,
    write_wav_int16,
)

# --------------------------------------------------------------------------- helpers


def riff(
    data: bytes,
    *,
    fmt_tag: int = 1,
    channels: int = 1,
    rate: int = 16000,
    bits: int = 16,
    byte_rate: int | None = None,
    extra: bytes = b"",
) -> bytes:
    """A WAV file built byte by byte (``extra`` chunks go between fmt and data)."""
    block_align = channels * ((bits + 7) // 8)
    if byte_rate is None:
        byte_rate = rate * block_align
    fmt = struct.pack("<HHIIHH", fmt_tag, channels, rate, byte_rate, block_align, bits)
    body = b"WAVE" + b"fmt " + struct.pack("<I", len(fmt)) + fmt + extra
    body += b"data" + struct.pack("<I", len(data)) + data + b"\x00" * (len(data) % 2)
    return b"RIFF" + struct.pack("<I", len(body)) + body


def tone(freq: float, rate: int, duration_s: float, amplitude: float = 1.0) -> np.ndarray:
    return amplitude * np.sin(2 * np.pi * freq * np.arange(round(duration_s * rate)) / rate)


def brute_force_split(values: np.ndarray) -> tuple[int, float]:
    """(n_low, threshold) by scoring every split of the sorted values with direct sums."""
    x = np.sort(values)
    total = float(np.sum((x - x.mean()) ** 2))
    errors = []
    for k in range(1, x.size):
        low, high = x[:k], x[k:]
        errors.append(np.sum((low - low.mean()) ** 2) + np.sum((high - high.mean()) ** 2))
    errors = np.array(errors)
    # Same tie rule as documented: the lowest split within 1e-9 * total of the minimum.
    k = int(np.flatnonzero(errors <= errors.min() + 1e-9 * total)[0]) + 1
    return k, 0.5 * (x[:k].mean() + x[k:].mean())


# --------------------------------------------------------------------------- energies


def test_full_scale_sine_is_minus_3_db() -> None:
    rate = 16000
    x = tone(1000.0, rate, 1.0)  # 0.1 s windows hold exactly 100 periods
    energies = window_energies_db(x, rate, 0.1)
    assert energies.shape == (10,)
    np.testing.assert_allclose(energies, 10 * math.log10(0.5), atol=1e-9)
    assert energies[0] == pytest.approx(-3.0103, abs=1e-4)


def test_silence_gives_the_floor_and_dc_gives_its_square() -> None:
    assert ENERGY_FLOOR_DB == pytest.approx(10 * math.log10(ENERGY_FLOOR))
    np.testing.assert_allclose(window_energies_db(np.zeros(800), 8000, 0.05), ENERGY_FLOOR_DB)
    np.testing.assert_allclose(window_energies_db(np.full(800, -0.1), 8000, 0.05), -20.0)


def test_window_count_and_partial_window_dropped() -> None:
    rate, window_s = 16000, 0.01  # 160 samples per window
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.5, 0.5, 1000)  # 6 windows and 40 samples left over
    energies = window_energies_db(x, rate, window_s)
    assert energies.shape == (6,)
    expected = [10 * np.log10(np.mean(x[i * 160 : (i + 1) * 160] ** 2) + 1e-12) for i in range(6)]
    np.testing.assert_allclose(energies, expected, rtol=1e-12)
    louder_tail = x.copy()
    louder_tail[960:] = 1.0
    np.testing.assert_array_equal(window_energies_db(louder_tail, rate, window_s), energies)
    assert window_energies_db(x[:159], rate, window_s).shape == (0,)


def test_window_samples_rounds() -> None:
    assert window_samples(16000, 0.1) == 1600
    assert window_samples(1000, 0.03125) == 31
    assert window_samples(1000, 0.0316) == 32
    assert window_samples(8000, 1 / 8000) == 1


@pytest.mark.parametrize(
    ("window_s", "fragment"),
    [
        (0.0, "positive number of seconds"),
        (-0.1, "positive number of seconds"),
        (float("nan"), "positive number of seconds"),
        (1e-6, "holds no sample"),
    ],
)
def test_bad_window_is_refused(window_s: float, fragment: str) -> None:
    with pytest.raises(AudioError, match=fragment):
        window_energies_db(np.zeros(100), 16000, window_s)


def test_bad_rate_and_bad_samples_are_refused() -> None:
    with pytest.raises(AudioError, match="positive integer in Hz"):
        window_energies_db(np.zeros(100), 0, 0.01)
    with pytest.raises(AudioError, match="positive integer in Hz"):
        window_energies_db(np.zeros(100), 16000.5, 0.01)
    with pytest.raises(AudioError, match="to_mono"):
        window_energies_db(np.zeros((100, 2)), 16000, 0.001)
    with pytest.raises(AudioError, match="NaN"):
        window_energies_db(np.array([0.0, np.nan]), 1000, 0.001)
    with pytest.raises(AudioError, match="int16 integers; scale them to floats"):
        window_energies_db(np.zeros(100, dtype=np.int16), 16000, 0.001)


# --------------------------------------------------------------------------- k-means


@pytest.mark.parametrize("seed", range(60))
def test_kmeans_equals_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 80))
    kind = seed % 3
    if kind == 0:
        values = rng.normal(-50.0, 15.0, n)
    elif kind == 1:  # two levels plus noise, like quiet and sound
        values = np.where(rng.random(n) < 0.3, -20.0, -60.0) + rng.normal(0.0, 3.0, n)
    else:  # many duplicates
        values = rng.integers(-4, 4, n).astype(float) * 7.5
    if np.all(values == values[0]):
        values[0] += 1.0
    fit = kmeans_split(values)
    n_low, threshold = brute_force_split(values)
    assert (fit.n_low, fit.n_high) == (n_low, n - n_low)
    assert fit.threshold_db == pytest.approx(threshold, rel=1e-12, abs=1e-12)
    assert kmeans_threshold(values) == fit.threshold_db
    assert kmeans_threshold(rng.permutation(values)) == fit.threshold_db
    x = np.sort(values)
    assert fit.low_mean_db == pytest.approx(x[:n_low].mean())
    assert fit.high_mean_db == pytest.approx(x[n_low:].mean())
    assert x[n_low - 1] <= fit.threshold_db <= x[n_low]


def test_kmeans_equals_brute_force_on_long_realistic_input() -> None:
    # An hour-long calibration is ~36000 windows; here 3000, many at the silence floor.
    rng = np.random.default_rng(7)
    values = np.concatenate(
        [np.full(1500, ENERGY_FLOOR_DB), rng.normal(-55.0, 4.0, 1000), rng.normal(-18.0, 6.0, 500)]
    )
    fit = kmeans_split(rng.permutation(values))
    n_low, threshold = brute_force_split(values)
    assert fit.n_low == n_low
    assert fit.threshold_db == pytest.approx(threshold, rel=1e-12)


def test_kmeans_tie_goes_to_the_lowest_split() -> None:
    # {0} | {1, 2} and {0, 1} | {2} have the same error (0.5).
    fit = kmeans_split([2.0, 0.0, 1.0])
    assert fit == ThresholdFit(0.75, 0.0, 1.5, 1, 2)
    # Mirror-symmetric data: the two mirrored best splits tie, but floating-point rounding
    # makes the upper one look better by ~3e-12; it still counts as a tie.
    offsets = np.array([0.4, 9.0, 19.9, 34.6])
    values = -90.0 + np.concatenate([-offsets, [0.0], offsets])
    assert kmeans_threshold(values) < -90.0
    assert kmeans_threshold(values) == pytest.approx(brute_force_split(values)[1])


def test_two_level_signal_threshold_between_levels() -> None:
    rate, window_s = 16000, 0.05
    rng = np.random.default_rng(3)
    pattern = rng.random(200) < 0.4
    n = window_samples(rate, window_s)
    levels = np.where(pattern, 0.3, 0.003)  # about -13.5 dB and -53.5 dB
    x = np.repeat(levels, n) * rng.normal(0.0, 1.0, pattern.size * n)
    energies = window_energies_db(x, rate, window_s)
    fit = kmeans_split(energies)
    assert -50.0 < fit.threshold_db < -17.0
    assert fit.low_mean_db == pytest.approx(20 * np.log10(0.003), abs=0.5)
    assert fit.high_mean_db == pytest.approx(20 * np.log10(0.3), abs=0.5)
    assert (fit.n_low, fit.n_high) == (int((~pattern).sum()), int(pattern.sum()))
    np.testing.assert_array_equal(bits_from_energies(energies, fit.threshold_db), pattern)


@pytest.mark.parametrize(
    ("values", "fragment"),
    [
        ([], "at least 2"),
        ([-40.0], "at least 2"),
        ([-40.0] * 50, "both quiet and sound"),
        ([-40.0, np.nan, -10.0], "NaN"),
    ],
)
def test_kmeans_refuses_unusable_input(values: list[float], fragment: str) -> None:
    with pytest.raises(AudioError, match=fragment):
        kmeans_threshold(values)


def test_bits_are_strictly_above_threshold() -> None:
    bits = bits_from_energies([-50.0, -30.0, -29.999, -10.0], -30.0)
    assert bits.dtype == np.bool_
    np.testing.assert_array_equal(bits, [False, False, True, True])
    with pytest.raises(AudioError, match="finite"):
        bits_from_energies([-50.0], float("nan"))


# --------------------------------------------------------------------------- streaming


@pytest.mark.parametrize("seed", range(20))
def test_window_assembler_equals_batch_under_random_chunking(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    rate = int(rng.choice([8000, 16000, 44100]))
    window_s = float(rng.uniform(0.001, 0.05))
    # float32 samples, as they arrive in audio messages
    x = (rng.normal(0.0, 0.2, int(rng.integers(0, 20000))) * rng.random()).astype(np.float32)
    cuts = np.sort(rng.integers(0, x.size + 1, int(rng.integers(0, 40))))
    assembler = WindowAssembler(rate, window_s)
    streamed = []
    for chunk in np.split(x, cuts):  # includes empty chunks
        streamed.extend(assembler.push(chunk))
    np.testing.assert_array_equal(streamed, window_energies_db(x, rate, window_s))
    assert assembler.samples_per_window == window_samples(rate, window_s)


def test_window_assembler_chunks_of_one_sample_and_reset() -> None:
    assembler = WindowAssembler(1000, 0.004)
    assert assembler.samples_per_window == 4
    out = [assembler.push([v]) for v in [0.5, 0.5, 0.5, 0.5, 1.0, 1.0]]
    assert out[:3] == [[], [], []]
    assert out[3] == pytest.approx([10 * math.log10(0.25)])
    assert out[4:] == [[], []]
    assembler.reset()  # drops the two pending samples
    assert assembler.push(np.zeros(4)) == pytest.approx([ENERGY_FLOOR_DB])
    with pytest.raises(AudioError, match="mono"):
        assembler.push(np.zeros((4, 2)))


def test_online_threshold_keeps_the_last_windows() -> None:
    online = OnlineThreshold(capacity=6)
    values = [-60.0, -59.0, -20.0, -61.0, -21.0, -19.0, -62.0, -22.0]
    for v in values:
        online.add(v)
    assert len(online) == 6
    assert online.refit() == kmeans_split(values[-6:])
    for _ in range(6):
        online.add(-40.0)
    with pytest.raises(AudioError, match="both quiet and sound"):
        online.refit()
    with pytest.raises(AudioError, match="capacity"):
        OnlineThreshold(capacity=1)
    with pytest.raises(AudioError, match="finite"):
        online.add(float("inf"))


# --------------------------------------------------------------------------- reading wavs


def test_read_16bit_mono(tmp_path) -> None:
    x = tone(440.0, 16000, 0.25, amplitude=0.8)
    path = tmp_path / "mono.wav"
    write_wav_int16(path, x, 16000)
    samples, rate = read_wav(path)
    assert rate == 16000
    assert samples.shape == (x.size, 1)
    assert samples.dtype == np.float64
    # Written as round(x * 32767), read as n / 32768.
    np.testing.assert_allclose(samples[:, 0], x * 32767 / 32768, atol=0.5 / 32768)


def test_read_stereo_mix_down_and_channel_pick(tmp_path) -> None:
    left = tone(440.0, 16000, 0.1, amplitude=0.5)
    path = tmp_path / "stereo.wav"
    write_wav_int16(path, np.column_stack([left, np.zeros_like(left)]), 16000)
    samples, _ = read_wav(path)
    assert samples.shape == (left.size, 2)
    np.testing.assert_allclose(to_mono(samples), left / 2, atol=1.0 / 32767)
    np.testing.assert_allclose(to_mono(samples, channel=0), left, atol=1.0 / 32767)
    np.testing.assert_array_equal(to_mono(samples, channel=1), 0.0)
    with pytest.raises(AudioError, match=r"channel 2 does not exist: the audio has 2 channel"):
        to_mono(samples, channel=2)
    with pytest.raises(AudioError, match="has 2 channel"):
        load_mono(path, channel=-1)
    np.testing.assert_allclose(load_mono(path, channel=0), left, atol=1.0 / 32767)


def test_to_mono_shapes() -> None:
    np.testing.assert_array_equal(to_mono([0.1, 0.2]), [0.1, 0.2])
    with pytest.raises(AudioError, match="frames, channels"):
        to_mono(np.zeros((2, 2, 2)))
    with pytest.raises(AudioError, match="no channels"):
        to_mono(np.zeros((2, 0)))


def test_read_8bit_unsigned(tmp_path) -> None:
    path = tmp_path / "u8.wav"
    wavfile.write(path, 8000, np.array([128, 128, 255, 0, 192], dtype=np.uint8))
    samples, rate = read_wav(path)
    assert rate == 8000
    np.testing.assert_allclose(samples[:, 0], [0.0, 0.0, 127 / 128, -1.0, 0.5])


def test_read_24bit(tmp_path) -> None:
    values = np.array([0, 2**22, -(2**23), 2**23 - 1, -1, 12345])
    data = b"".join(int(v).to_bytes(3, "little", signed=True) for v in values)
    path = tmp_path / "s24.wav"
    path.write_bytes(riff(data, bits=24, rate=48000))
    samples, rate = read_wav(path)
    assert rate == 48000
    np.testing.assert_allclose(samples[:, 0], values / 2**23, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    ("dtype", "scale"), [(np.int16, 2**15), (np.int32, 2**31), (np.float32, 1), (np.float64, 1)]
)
def test_read_other_encodings(tmp_path, dtype: type, scale: int) -> None:
    stored = np.array([[0, 0], [1, -1], [-2, 3]], dtype=np.float64) * 0.25
    data = (stored * (scale - 1 if scale > 1 else 1)).astype(dtype)
    path = tmp_path / "x.wav"
    wavfile.write(path, 22050, data)
    samples, rate = read_wav(path)
    assert rate == 22050
    assert samples.shape == (3, 2)
    np.testing.assert_allclose(samples, data.astype(np.float64) / scale)
    assert np.max(np.abs(samples)) <= 1.0


@pytest.mark.parametrize("file_rate", [44100, 48000])
def test_resampled_tone_keeps_its_energy(tmp_path, file_rate: int) -> None:
    path = tmp_path / f"tone{file_rate}.wav"
    write_wav_int16(path, tone(1000.0, file_rate, 1.0, amplitude=0.5), file_rate)
    x = load_mono(path)  # to PROCESSING_RATE_HZ
    assert PROCESSING_RATE_HZ == 16000
    assert x.size == 16000
    energies = window_energies_db(x, 16000, 0.05)
    # Windows away from the edges: mean square 0.125, i.e. -9.03 dB.
    np.testing.assert_allclose(energies[2:-2], 10 * math.log10(0.125), atol=0.01)


def test_resample_rates() -> None:
    x = np.arange(10.0)
    same = resample(x, 16000, 16000)
    np.testing.assert_array_equal(same, x)
    assert same is not x
    assert resample(np.zeros(441), 44100, 16000).shape == (160,)
    assert resample(np.zeros((480, 2)), 48000, 16000).shape == (160, 2)
    assert resample(np.zeros(100), 16000, 48000).shape == (300,)
    with pytest.raises(AudioError, match="to_rate must be a positive integer"):
        resample(x, 16000, 0)


def test_harmless_chunks_are_read_silently(tmp_path) -> None:
    data = np.array([1000, -1000], dtype="<i2").tobytes()
    path = tmp_path / "bext.wav"
    path.write_bytes(riff(data, extra=b"bext" + struct.pack("<I", 4) + b"abcd"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        samples, _ = read_wav(path)
    np.testing.assert_allclose(samples[:, 0], [1000 / 32768, -1000 / 32768])


def test_missing_file(tmp_path) -> None:
    with pytest.raises(AudioError, match="does not exist"):
        read_wav(tmp_path / "nope.wav")


def test_directory(tmp_path) -> None:
    with pytest.raises(AudioError, match="is a directory"):
        read_wav(tmp_path)


@pytest.mark.parametrize("content", [b"hello, this is text and not audio\n", b"RIFF\x04\0\0\0AVI "])
def test_not_a_wav_file(tmp_path, content: bytes) -> None:
    path = tmp_path / "notes.wav"
    path.write_bytes(content)
    with pytest.raises(AudioError, match="is not a WAV file"):
        read_wav(path)


def test_zero_byte_file(tmp_path) -> None:
    path = tmp_path / "zero.wav"
    path.write_bytes(b"")
    with pytest.raises(AudioError, match="0-byte file"):
        read_wav(path)


def test_empty_wav(tmp_path) -> None:
    path = tmp_path / "empty.wav"
    path.write_bytes(riff(b""))
    with pytest.raises(AudioError, match="is empty: it holds no audio frames"):
        read_wav(path)


def test_truncated_data(tmp_path) -> None:
    path = tmp_path / "cut.wav"
    write_wav_int16(path, tone(440.0, 16000, 0.5, 0.5), 16000)
    path.write_bytes(path.read_bytes()[:-1000])
    with pytest.raises(AudioError, match="truncated WAV file"):
        read_wav(path)


@pytest.mark.parametrize("keep", [6, 14, 30, 40])
def test_truncated_header(tmp_path, keep: int) -> None:
    path = tmp_path / "cut.wav"
    path.write_bytes(riff(np.zeros(100, dtype="<i2").tobytes())[:keep])
    with pytest.raises(AudioError, match="corrupt or truncated WAV file"):
        read_wav(path)


def test_truncated_mid_frame(tmp_path) -> None:
    path = tmp_path / "cut.wav"
    full = riff(np.zeros((100, 2), dtype="<i2").tobytes(), channels=2)
    path.write_bytes(full[:-3])
    with pytest.raises(AudioError, match="truncated"):
        read_wav(path)


def test_compressed_encoding(tmp_path) -> None:
    path = tmp_path / "alaw.wav"
    path.write_bytes(riff(b"\xd5" * 100, fmt_tag=6, bits=8, rate=8000))
    with pytest.raises(AudioError, match="unsupported WAV encoding.*pcm_s16le"):
        read_wav(path)


def test_zero_channels_and_zero_rate(tmp_path) -> None:
    path = tmp_path / "bad.wav"
    path.write_bytes(riff(b"\0" * 8, channels=0))
    with pytest.raises(AudioError, match="corrupt"):
        read_wav(path)
    path.write_bytes(riff(b"\0" * 8, rate=0, byte_rate=0))
    with pytest.raises(AudioError, match="sample rate of 0 Hz"):
        read_wav(path)


def test_float_wav_with_nan(tmp_path) -> None:
    path = tmp_path / "nan.wav"
    wavfile.write(path, 16000, np.array([0.0, np.nan], dtype=np.float32))
    with pytest.raises(AudioError, match="NaN"):
        read_wav(path)
    huge = tmp_path / "huge.wav"
    wavfile.write(huge, 16000, np.array([0.0, 1e300, -2.0], dtype=np.float64))
    with pytest.raises(AudioError, match="huge.wav's samples: a sample of 1e[+]300 is not audio"):
        read_wav(huge)
    wavfile.write(huge, 16000, np.array([0.0, 32767.0, -2.0], dtype=np.float32))
    assert read_wav(huge)[0].max() == 32767.0  # unscaled, but audio: the bit sources say so


# --------------------------------------------------------------------------- threshold file


def test_threshold_file_round_trip(tmp_path) -> None:
    fit = ThresholdFit(-37.25, -55.5, -19.0, 120, 40)
    path = tmp_path / "calib" / "threshold.yaml"
    save_threshold(path, fit, window_s=0.1, rate=16000, source="room.wav")
    assert load_threshold(path) == -37.25
    record = yaml.safe_load(path.read_text())
    assert record["format_version"] == THRESHOLD_FORMAT_VERSION
    assert record["window_s"] == 0.1
    assert record["sample_rate_hz"] == 16000
    assert (record["low_mean_db"], record["high_mean_db"]) == (-55.5, -19.0)
    assert (record["n_low"], record["n_high"]) == (120, 40)
    assert record["source"] == "room.wav"
    assert record["created"].endswith("+00:00")
    assert [p.name for p in path.parent.iterdir()] == ["threshold.yaml"]


def test_threshold_file_hand_written(tmp_path) -> None:
    path = tmp_path / "t.yaml"
    path.write_text("format_version: 1\nthreshold_db: -40\n")
    assert load_threshold(path) == -40.0


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        ("format_version: 1\nthreshold_db: [unclosed\n", "not valid YAML"),
        ("- 1\n- 2\n", "must hold a YAML mapping"),
        ("", "must hold a YAML mapping"),
        ("format_version: 1\nwindow_s: 0.1\n", "missing the field 'threshold_db'"),
        ("threshold_db: -40\n", "missing the field 'format_version'"),
        ("format_version: 2\nthreshold_db: -40\n", "format_version 2"),
        ("format_version: 1\nthreshold_db: loud\n", "must be a number"),
        ("format_version: 1\nthreshold_db: true\n", "must be a number"),
        ("format_version: 1\nthreshold_db: .nan\n", "must be finite"),
        ("format_version: 1\nthreshold_db: -.inf\n", "must be finite"),
    ],
)
def test_bad_threshold_files(tmp_path, content: str, fragment: str) -> None:
    path = tmp_path / "t.yaml"
    path.write_text(content)
    with pytest.raises(AudioError, match=fragment):
        load_threshold(path)


def test_missing_threshold_file(tmp_path) -> None:
    with pytest.raises(AudioError, match="does not exist.*calibrating"):
        load_threshold(tmp_path / "none.yaml")
    with pytest.raises(AudioError, match="is a directory"):
        load_threshold(tmp_path)


def test_binary_threshold_file(tmp_path) -> None:
    path = tmp_path / "t.yaml"
    path.write_bytes(b"\xff\xfe\x00\x01\x80")
    with pytest.raises(AudioError, match="threshold file"):
        load_threshold(path)


def test_save_refuses_non_finite_fit(tmp_path) -> None:
    with pytest.raises(AudioError, match="non-finite"):
        save_threshold(
            tmp_path / "t.yaml",
            ThresholdFit(float("nan"), -50.0, -10.0, 1, 1),
            window_s=0.1,
            rate=16000,
            source="x",
        )


def test_save_refuses_a_directory_and_leaves_nothing_behind(tmp_path) -> None:
    fit = ThresholdFit(-30.0, -50.0, -10.0, 1, 1)
    with pytest.raises(AudioError, match="it is a directory"):
        save_threshold(tmp_path, fit, window_s=0.1, rate=16000, source="x")
    (tmp_path / "t.yaml").mkdir()
    (tmp_path / "t.yaml" / "inside").write_text("")  # a directory that cannot be replaced
    with pytest.raises(AudioError, match="it is a directory"):
        save_threshold(tmp_path / "t.yaml", fit, window_s=0.1, rate=16000, source="x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.yaml"]


def test_save_writes_over_nothing_but_a_regular_file(tmp_path) -> None:
    """A FIFO, a symbolic link, or a link where the old temporary name was: left alone."""
    fit = ThresholdFit(-30.0, -50.0, -10.0, 1, 1)
    (tmp_path / "target.txt").write_text("keep me")
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "link").symlink_to("target.txt")
    for name, kind in (("fifo", "a FIFO"), ("link", "a symbolic link")):
        with pytest.raises(AudioError, match=f"threshold file .*{name} is not a regular file"
                           f" \\(it is {kind}\\)"):
            save_threshold(tmp_path / name, fit, window_s=0.1, rate=16000, source="x")
    assert stat.S_ISFIFO((tmp_path / "fifo").lstat().st_mode)
    assert (tmp_path / "link").is_symlink()
    (tmp_path / "t.yaml.tmp").symlink_to("target.txt")  # the name it once wrote through
    save_threshold(tmp_path / "t.yaml", fit, window_s=0.1, rate=16000, source="x")
    assert load_threshold(tmp_path / "t.yaml") == -30.0
    assert (tmp_path / "target.txt").read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "fifo", "link", "t.yaml", "t.yaml.tmp", "target.txt"]


# --------------------------------------------------------------------------- synthesis


def test_chirp_shape_fades_and_band() -> None:
    rate = 16000
    x = synthesize_chirp(rate)
    assert x.shape == (3200,)
    assert np.max(np.abs(x)) <= 0.5
    assert np.max(np.abs(x[1000:2000])) == pytest.approx(0.5, abs=1e-3)
    fade = round(0.01 * rate)
    assert abs(x[0]) < 0.01 and abs(x[-1]) < 0.01
    assert np.max(np.abs(x[: fade // 4])) < 0.1
    spectrum = np.abs(np.fft.rfft(x)) ** 2
    freqs = np.fft.rfftfreq(x.size, 1 / rate)
    in_band = spectrum[(freqs >= 700) & (freqs <= 2500)].sum()
    assert in_band / spectrum.sum() > 0.99
    # The sweep rises: the first quarter is lower in pitch than the last.
    crossings = [np.count_nonzero(np.diff(np.sign(q)) != 0) for q in np.split(x, 4)]
    assert crossings[0] < crossings[-1]


def test_chirp_refuses_bad_arguments() -> None:
    with pytest.raises(AudioError, match="f1=9000"):
        synthesize_chirp(16000, f1=9000)
    with pytest.raises(AudioError, match="amplitude"):
        synthesize_chirp(16000, amplitude=1.5)
    with pytest.raises(AudioError, match="duration_s"):
        synthesize_chirp(16000, duration_s=0)


def test_write_wav_int16_clips(tmp_path) -> None:
    path = tmp_path / "clip.wav"
    write_wav_int16(path, [2.0, -3.0, 0.5], 8000)
    rate, data = wavfile.read(path)
    assert rate == 8000
    assert data.dtype == np.int16
    np.testing.assert_array_equal(data, [32767, -32767, 16384])
    with pytest.raises(AudioError, match="NaN"):
        write_wav_int16(path, [np.nan], 8000)
    with pytest.raises(AudioError, match="cannot write"):
        write_wav_int16(tmp_path / "no" / "dir.wav", [0.0], 8000)


# --------------------------------------------------------------------------- block reading


def pcm_bytes(values: np.ndarray, sample_bytes: int, big_endian: bool = False) -> bytes:
    """Signed integers as little- (or big-) endian PCM of ``sample_bytes`` bytes each."""
    order = "big" if big_endian else "little"
    return b"".join(int(v).to_bytes(sample_bytes, order, signed=True) for v in values.ravel())


def wav_of_format(tmp_path, kind: str, rate: int, channels: int, seconds: float):
    """A noisy tone with quiet stretches in the ``kind`` encoding; returns the path."""
    rng = np.random.default_rng(7)
    n = round(rate * seconds)
    x = 0.4 * np.sin(2 * np.pi * 440 * np.arange(n) / rate)
    x[n // 3 : n // 2] *= 0.01
    x = np.column_stack([x * (c + 1) / channels for c in range(channels)])
    x += 0.01 * rng.standard_normal(x.shape)
    path = tmp_path / f"{kind}_{rate}_{channels}.wav"
    if kind == "u8":
        wavfile.write(path, rate, np.round(x * 127 + 128).astype(np.uint8))
    elif kind == "s24":
        ints = np.round(x * (2**23 - 1)).astype(np.int64)
        path.write_bytes(riff(pcm_bytes(ints, 3), channels=channels, rate=rate, bits=24))
    elif kind in ("s16", "s32"):
        dtype, scale = (np.int16, 2**15 - 1) if kind == "s16" else (np.int32, 2**31 - 1)
        wavfile.write(path, rate, np.round(x * scale).astype(dtype))
    else:
        wavfile.write(path, rate, x.astype(np.float32 if kind == "f32" else np.float64))
    return path


@pytest.mark.parametrize(
    ("kind", "rate", "channels"),
    [
        ("s16", 16000, 1),
        ("s16", 44100, 2),
        ("u8", 8000, 1),
        ("s24", 48000, 3),
        ("s32", 22050, 2),
        ("f32", 44100, 1),
        ("f64", 16000, 2),
    ],
)
@pytest.mark.parametrize("block_frames", [1, 7, 1000, 4097, 1 << 16])
def test_block_read_energies_equal_the_whole_file_computation(
    tmp_path, kind: str, rate: int, channels: int, block_frames: int
) -> None:
    seconds = {1: 0.13, 7: 0.4}.get(block_frames, 1.37)  # tiny blocks: a short file
    path = wav_of_format(tmp_path, kind, rate, channels, seconds)
    for channel in (None, channels - 1):
        whole = window_energies_db(load_mono(path, channel=channel), 16000, 0.02)
        parts = list(iter_wav_energies(path, 0.02, channel, block_frames=block_frames))
        assert all(p.size for p in parts)
        streamed = np.concatenate(parts)
        assert streamed.shape == whole.shape and whole.size >= 6
        np.testing.assert_array_equal(streamed, whole)  # exactly, not approximately
        assert wav_window_count(open_wav_info(path), 0.02) == whole.size


def test_block_reader_blocks_concatenate_to_the_file(tmp_path) -> None:
    path = wav_of_format(tmp_path, "s24", 44100, 2, 0.5)
    with WavReader(path) as reader:
        info = reader.info
        blocks = list(reader.blocks(999))
        again = list(reader.blocks(5000))  # every call starts from the first frame
    assert (info.rate, info.channels, info.sample_bytes, info.encoding) == (44100, 2, 3, "int")
    assert [b.shape[0] for b in blocks[:-1]] == [999] * (len(blocks) - 1)
    np.testing.assert_array_equal(np.concatenate(blocks), np.concatenate(again))
    np.testing.assert_array_equal(np.concatenate(blocks), read_wav(path)[0])
    assert np.concatenate(blocks).shape == (info.frames, 2) and info.frames == 22050
    with WavReader(path) as reader, pytest.raises(AudioError, match="block_frames"):
        next(reader.blocks(0))


def test_read_wav_matches_scipy_on_the_formats_it_reads(tmp_path) -> None:
    for kind in ("u8", "s16", "s32", "f32", "f64"):
        path = wav_of_format(tmp_path, kind, 16000, 2, 0.2)
        rate, data = wavfile.read(path)
        if data.dtype == np.uint8:
            expected = (data.astype(np.float64) - 128) / 128
        elif data.dtype.kind == "i":
            expected = data / float(-np.iinfo(data.dtype).min)
        else:
            expected = data.astype(np.float64)
        samples, got_rate = read_wav(path)
        assert got_rate == rate
        np.testing.assert_array_equal(samples, expected)


def test_read_big_endian_rifx_and_extensible(tmp_path) -> None:
    values = np.array([0, 1000, -32768, 32767, -1])
    fmt = struct.pack(">HHIIHH", 1, 1, 8000, 16000, 2, 16)
    data = pcm_bytes(values, 2, big_endian=True)
    body = b"WAVE" + b"fmt " + struct.pack(">I", 16) + fmt + b"data"
    body += struct.pack(">I", len(data)) + data
    path = tmp_path / "rifx.wav"
    path.write_bytes(b"RIFX" + struct.pack(">I", len(body)) + body)
    samples, rate = read_wav(path)
    assert rate == 8000
    np.testing.assert_array_equal(samples[:, 0], values / 32768)
    # WAVE_FORMAT_EXTENSIBLE with the PCM sub-format GUID
    ext = struct.pack("<HHIIHHHHI", 0xFFFE, 1, 8000, 24000, 3, 24, 22, 24, 4)
    ext += struct.pack("<H", 1) + b"\x00\x00\x00\x00\x10\x00\x80\x00\x00\xaa\x00\x38\x9b\x71"
    data = pcm_bytes(values * 256, 3)
    body = b"WAVE" + b"fmt " + struct.pack("<I", len(ext)) + ext
    body += b"data" + struct.pack("<I", len(data)) + data + b"\x00" * (len(data) % 2)
    path.write_bytes(b"RIFF" + struct.pack("<I", len(body)) + body)
    samples, _ = read_wav(path)
    np.testing.assert_array_equal(samples[:, 0], values / 32768)


def test_stream_resampler_finish_completes_the_whole_signal_resampling() -> None:
    rng = np.random.default_rng(3)
    for from_rate, to_rate in [(44100, 16000), (48000, 16000), (8000, 16000), (16000, 44100)]:
        for n in (1, 3, 441, 4410, 10007):
            x = rng.standard_normal(n)
            resampler = StreamResampler(from_rate, to_rate)
            parts, i = [], 0
            while i < n:
                k = int(rng.integers(1, 700))
                parts.append(resampler.push(x[i : i + k]))
                i += k
            parts.append(resampler.finish())
            np.testing.assert_array_equal(np.concatenate(parts), resample(x, from_rate, to_rate))
    passthrough = StreamResampler(16000, 16000)
    np.testing.assert_array_equal(passthrough.push([0.5, 0.25]), [0.5, 0.25])
    assert passthrough.finish().size == 0


def test_wav_energies_stops_after_max_windows(tmp_path) -> None:
    path = wav_of_format(tmp_path, "s16", 44100, 1, 1.37)
    whole = window_energies_db(load_mono(path), 16000, 0.05)
    np.testing.assert_array_equal(wav_energies(path, 0.05, max_windows=4), whole[:4])
    np.testing.assert_array_equal(wav_energies(path, 0.05, max_windows=10_000), whole)
    with pytest.raises(AudioError, match="channel 1 does not exist"):
        wav_energies(path, 0.05, channel=1)

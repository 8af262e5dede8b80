"""Tests of live audio.

Device choice, exact streaming resampling, microphone windows, losses, reconnection, the
speaker, calibration helpers and the latency measurement.

Two kinds of tests:
* through the real sounddevice -> PortAudio -> ALSA stack, on virtual ALSA devices in a
  subprocess per test (see alsa_devices.py): capture bits, the 48 kHz-only device, a
  missing device, a device that stalls and vanishes, playback;
* with a fake PortAudio (fake_portaudio.py) where timing, unplugging or an acoustic loop
  must be controlled exactly.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from alsa_devices import VirtualAlsa, read_raw
from fake_portaudio import FakeBackend, FakeClock, Room, Rule, device
from infomax_contingency.audio.calibration import energy_histogram, record_energies
from infomax_contingency.audio.capture import MicrophoneStream
from infomax_contingency.audio.common import AudioError
from infomax_contingency.audio.devices import (
    AudioDeviceError,
    LogFunction,
    clock_offset,
    import_sounddevice,
    negotiate_format,
    resolve_device,
)
from infomax_contingency.audio.energy import window_energies_db
from infomax_contingency.audio.latency import find_onset, measure_latency, self_period_windows
from infomax_contingency.audio.playback import SpeakerOutput
from infomax_contingency.audio.resample import StreamResampler, load_mono, resample
from infomax_contingency.audio.synth import synthesize_chirp
from infomax_contingency.audio.threshold import bits_from_energies, kmeans_threshold
from infomax_contingency.audio.timeline import WindowTimeline
from infomax_contingency.audio.wav import to_mono, write_wav_int16

# --------------------------------------------------------------------------- fixtures


def recording(rate: int, seconds: float, seed: int = 0) -> np.ndarray:
    """Quiet room noise with bursts of loud modulated noise (speech-like), in [-1, 1]."""
    rng = np.random.default_rng(seed)
    n = round(seconds * rate)
    t = np.arange(n) / rate
    x = 0.002 * rng.standard_normal(n)
    for start, length in ((0.6, 0.9), (2.3, 0.5), (3.4, 1.3), (5.5, 0.7)):
        on = (t >= start) & (t < start + length)
        envelope = 0.5 + 0.5 * np.sin(2 * np.pi * 4 * t[on])
        x[on] += 0.2 * envelope * rng.standard_normal(on.sum())
    return np.clip(x, -1, 1)


def f32(x: np.ndarray) -> np.ndarray:
    """``x`` rounded to float32, the sample format PortAudio delivers."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)


def write_recording(path: Path, rate: int, seconds: float = 7.0, channels: int = 1) -> Path:
    x = recording(rate, seconds)
    if channels > 1:
        x = np.stack([x * (0.5 + 0.5 * c) for c in range(channels)], axis=1)
    write_wav_int16(path, x, rate)
    return path


def mic_backend(rate: int = 16000, rules: Rule | None = None, inputs: int = 1) -> FakeBackend:
    return FakeBackend(
        [device(0, "Built-in Mic", inputs=inputs, rate=rate), device(1, "USB Audio Device", 2)],
        default_input=0,
        rules={0: rules or Rule()},
    )


def logs() -> tuple[list[str], LogFunction]:
    lines: list[str] = []
    return lines, lambda level, message: lines.append(f"{level}: {message}")


# --------------------------------------------------------------------------- PortAudio import


def test_missing_portaudio_library_says_install_libportaudio2(monkeypatch, tmp_path) -> None:
    (tmp_path / "sounddevice.py").write_text("raise OSError('PortAudio library not found')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "sounddevice", raising=False)
    with pytest.raises(AudioDeviceError, match="libportaudio2"):
        import_sounddevice()
    with pytest.raises(AudioDeviceError, match="apt-get install libportaudio2"):
        MicrophoneStream().start()


def test_missing_sounddevice_package_says_pip_install(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "sounddevice", None)
    with pytest.raises(AudioDeviceError, match="pip install sounddevice"):
        import_sounddevice()


# --------------------------------------------------------------------------- devices


def test_resolve_default_index_and_name_substring() -> None:
    backend = FakeBackend(
        [
            device(0, "HDA Intel PCH: ALC3246 Analog (hw:0,0)", 2, 2, 44100),
            device(1, "USB PnP Sound Device: Audio (hw:1,0)", 1, 0, 48000),
            device(2, "usb speaker (hw:2,0)", 0, 2, 48000),
            device(3, "default", 32, 32, 44100),
        ],
        default_input=3,
        default_output=3,
    )
    assert resolve_device(None, "input", backend).index == 3
    assert resolve_device("", "output", backend).index == 3
    assert resolve_device(1, "input", backend).name.startswith("USB PnP")
    assert resolve_device(" 1 ", "input", backend).index == 1
    assert resolve_device(np.int64(0), "input", backend).index == 0
    # case-insensitive substring, first match among devices of the right kind
    assert resolve_device("usb", "input", backend).index == 1
    assert resolve_device("usb", "output", backend).index == 2
    assert resolve_device("hw:0", "output", backend).index == 0


def test_missing_device_lists_devices_and_how_to_choose() -> None:
    backend = FakeBackend(
        [device(0, "Built-in Mic", 1, 0, 48000), device(1, "HDMI out", 0, 8, 48000)],
        default_input=0,
    )
    with pytest.raises(AudioDeviceError) as info:
        resolve_device("ReSpeaker", "input", backend)
    message = str(info.value)
    assert "no input device name contains 'ReSpeaker'" in message
    assert "[0] Built-in Mic (Fake, 1 ch, 48000 Hz)  <- system default" in message
    assert "HDMI" not in message  # output-only devices are not offered as microphones
    assert "by its index (e.g. 0) or by a part of its name (e.g. 'Built-in')" in message
    with pytest.raises(AudioDeviceError, match="no audio device with index 7"):
        resolve_device(7, "input", backend)
    with pytest.raises(AudioDeviceError, match=r"device 1 \(HDMI out\) has no input channels"):
        resolve_device("1", "input", backend)
    with pytest.raises(AudioDeviceError, match="no default output device"):
        resolve_device(None, "output", backend)
    with pytest.raises(AudioDeviceError, match="no output device at all. Connect one"):
        resolve_device(None, "output", FakeBackend([device(0, "Built-in Mic")], 0))
    with pytest.raises(AudioDeviceError, match="index or a name"):
        resolve_device(True, "input", backend)


def test_negotiate_prefers_requested_rate_then_native_rates() -> None:
    backend = mic_backend(44100, Rule(rates={44100}, channels={1, 2}))
    dev = backend.devices()[0]
    rate, channels, refusals = negotiate_format(dev, "input", 16000, 1, backend)
    assert (rate, channels) == (44100, 1)
    assert refusals and "16000 Hz x 1 ch: Invalid sample rate" in refusals[0]
    backend = mic_backend(44100, Rule(rates={48000}))  # default rate refused too
    rate, _, _ = negotiate_format(backend.devices()[0], "input", 16000, 1, backend)
    assert rate == 48000
    backend = mic_backend(16000, Rule(channels={6}), inputs=6)  # array: all channels only
    assert negotiate_format(backend.devices()[0], "input", 16000, 1, backend)[:2] == (16000, 6)
    backend = mic_backend(16000, Rule(rates={8000}))
    with pytest.raises(AudioDeviceError, match="none of the tried formats") as info:
        negotiate_format(backend.devices()[0], "input", 16000, 1, backend)
    assert "48000 Hz x 1 ch" in str(info.value) and "44100 Hz x 1 ch" in str(info.value)


# --------------------------------------------------------------------------- resampling


@pytest.mark.parametrize(
    ("from_rate", "to_rate"), [(48000, 16000), (44100, 16000), (22050, 16000), (8000, 16000)]
)
def test_stream_resampler_is_bit_identical_to_whole_signal_resampling(from_rate, to_rate) -> None:
    rng = np.random.default_rng(from_rate)
    x = 0.3 * rng.standard_normal(2 * from_rate)
    reference = resample(x, from_rate, to_rate)
    resampler = StreamResampler(from_rate, to_rate)
    pieces, i = [], 0
    while i < x.size:
        n = int(rng.integers(1, 2500))
        pieces.append(resampler.push(x[i : i + n]))
        i += n
    y = np.concatenate(pieces)
    assert reference.size - 40 < y.size < reference.size  # only the last few outputs wait
    assert np.array_equal(y, reference[: y.size])
    resampler.reset()  # a new signal: same result again
    assert np.array_equal(resampler.push(x), y)


def test_stream_resampler_equal_rates_pass_through() -> None:
    x = np.linspace(-1, 1, 101)
    r = StreamResampler(16000, 16000)
    assert np.array_equal(r.push(x[:50]), x[:50]) and np.array_equal(r.push(x[50:]), x[50:])


# --------------------------------------------------------------------------- microphone (fake)


def pump_all(stream, x: np.ndarray, block: int, t0: float = 1000.0, rate: int = 16000) -> None:
    for i in range(0, x.shape[0], block):
        stream.pump(x[i : i + block], t=t0 + i / rate)


def test_microphone_windows_equal_offline_energies_and_use_adc_time() -> None:
    backend = mic_backend(16000)
    x = f32(recording(16000, 3.0))
    with MicrophoneStream(None, window_s=0.5, backend=backend) as mic:
        stream = backend.last()
        assert (stream.rate, stream.channels, stream.blocksize) == (16000, 1, 320)
        pump_all(stream, x, 320, t0=1000.0)
        windows = mic.read_windows(0.0)
    expected = window_energies_db(x, 16000, 0.5)
    assert [w.energy_db for w in windows] == expected.tolist()
    assert [w.index for w in windows] == list(range(6))
    # the fake stream clock is time.monotonic(): window times are the ADC times
    assert windows[0].start_time == pytest.approx(1000.0, abs=1e-4)
    assert windows[3].start_time == pytest.approx(1001.5, abs=1e-4)
    assert windows[3].end_time == pytest.approx(1002.0, abs=1e-4)
    assert all(w.intact and w.segment == 0 and w.gap_s == 0 for w in windows)


def test_microphone_at_native_rate_resamples_exactly() -> None:
    backend = mic_backend(48000, Rule(rates={48000}))
    x48 = f32(recording(48000, 3.0))
    lines, log = logs()
    with MicrophoneStream(None, window_s=0.5, backend=backend, log=log) as mic:
        assert mic.device_rate == 48000
        pump_all(backend.last(), x48, 960, rate=48000)
        energies = [w.energy_db for w in mic.read_windows(0.0)]
    expected = window_energies_db(resample(x48, 48000, 16000), 16000, 0.5)
    assert energies == expected[: len(energies)].tolist() and len(energies) == 5
    assert any("does not open at 16000 Hz" in line and "48000 Hz" in line for line in lines)


def test_microphone_channel_choice_and_mixdown() -> None:
    x = f32(recording(16000, 1.0))
    stereo = np.stack([x, 0.1 * x], axis=1)
    for channel, expected in ((None, 0.55 * x), (1, 0.1 * x)):
        backend = mic_backend(16000, inputs=2)
        with MicrophoneStream(
            None, window_s=0.25, channel=channel, channels=2, backend=backend
        ) as mic:
            pump_all(backend.last(), stereo, 400)
            energies = [w.energy_db for w in mic.read_windows(0.0)]
        reference = window_energies_db(to_mono(f32(stereo), channel), 16000, 0.25)
        assert energies == reference.tolist()
        assert np.allclose(energies, window_energies_db(expected, 16000, 0.25), atol=1e-4)
    backend = mic_backend(16000, Rule(channels={1}))
    with pytest.raises(AudioDeviceError, match="channel 1 does not exist"):
        MicrophoneStream(None, channel=1, backend=backend).start()


def test_dropped_blocks_stay_visible_in_the_window_that_lost_them() -> None:
    backend = mic_backend(16000)
    x = f32(recording(16000, 2.0))
    # queue of 5 blocks: the reader sleeps while 8 blocks arrive, 3 are dropped
    with MicrophoneStream(None, window_s=0.5, queue_s=0.1, backend=backend) as mic:
        stream = backend.last()
        blocks = [x[i : i + 320] for i in range(0, x.size, 320)]
        for k in range(8):
            stream.pump(blocks[k], t=1000.0 + k * 0.02)
        windows = mic.read_windows(0.0)
        for k in range(8, len(blocks)):
            stream.pump(blocks[k], t=1000.0 + k * 0.02)
            windows += mic.read_windows(0.0)
        status = mic.status()
    assert status.dropped_blocks == 3 and status.lost_samples == 960
    first = windows[0]
    assert first.lost_samples == 960 and not first.intact  # still emitted, loss visible
    kept = np.concatenate([*blocks[:5], *blocks[8:]])
    assert first.energy_db == window_energies_db(kept[:8000], 16000, 0.5)[0]
    assert first.end_time - first.start_time == pytest.approx(0.5 + 0.06)
    # the step clock keeps to ADC time: the next window starts where the first ended
    assert windows[1].start_time == pytest.approx(first.end_time)
    assert all(w.intact and w.segment == 0 for w in windows[1:])


def test_overflow_is_counted_and_its_length_estimated_from_adc_times() -> None:
    backend = mic_backend(16000)
    x = f32(recording(16000, 1.0))
    with MicrophoneStream(None, window_s=0.5, backend=backend) as mic:
        stream = backend.last()
        t = 1000.0
        for i in range(0, x.size, 320):
            jump = 0.01 if i == 3200 else 0.0  # 160 samples lost in an xrun
            t += jump
            stream.pump(x[i : i + 320], t=t, overflow=jump > 0)
            t += 0.02
        windows = mic.read_windows(0.0)
        status = mic.status()
    assert status.overflows == 1 and status.lost_samples == 160
    assert (windows[0].overflows, windows[0].lost_samples) == (1, 160)
    assert windows[1].intact and windows[1].start_time == pytest.approx(1000.51)


def test_a_loss_of_a_whole_window_is_a_gap_without_made_up_windows() -> None:
    backend = mic_backend(16000)
    x = f32(recording(16000, 4.0))
    blocks = [x[i : i + 320] for i in range(0, x.size, 320)]  # 0.02 s each
    windows = []
    with MicrophoneStream(None, window_s=0.5, queue_s=0.2, backend=backend) as mic:
        stream = backend.last()
        for k in range(len(blocks)):
            if k == 70:
                windows += mic.read_windows(0.0)
            stream.pump(blocks[k], t=1000.0 + k * 0.02)
            if not 20 <= k < 70:  # the reader stalls for 1 s: 10 blocks queue, 40 drop
                windows += mic.read_windows(0.0)
        status = mic.status()
    assert status.dropped_blocks == 40 and status.lost_samples == 40 * 320
    assert status.gaps == 1
    # segment 0: blocks 0..29 make one window; its partial second window is dropped
    assert [w.segment for w in windows] == [0] + [1] * (len(windows) - 1)
    assert windows[0].intact and windows[0].end_time == pytest.approx(1000.5, abs=1e-4)
    # the new segment starts with the first block after the loss, at its ADC time
    first = windows[1]
    assert first.start_time == pytest.approx(1000.0 + 70 * 0.02, abs=1e-4)
    assert first.gap_s == pytest.approx(0.9, abs=1e-4)  # 0.1 s partial window + 0.8 s lost
    assert first.intact and status.gap_total_s == pytest.approx(0.9, abs=1e-4)
    expected = window_energies_db(np.concatenate(blocks[70:]), 16000, 0.5)
    assert [w.energy_db for w in windows[1:]] == expected.tolist()
    assert windows[0].energy_db == window_energies_db(x[:8000], 16000, 0.5)[0]


@pytest.mark.slow
def test_stall_and_unplug_reconnect_with_backoff_and_report_the_gap() -> None:
    # On a fake clock: the device delivers a 20 ms block whenever the clock passes its
    # ADC time, and the stream's waits move the clock, so every time below is exact.
    clock = FakeClock(1000.0)
    t0 = clock()
    x = f32(recording(16000, 30.0))
    backend = FakeBackend(
        [device(0, "USB mic", 1, 0, 16000), device(1, "Built-in", 1, 0, 16000)],
        default_input=1,
        clock=clock,
        source=lambda stream, t, n: x[(i := round((t - t0) * 16000)) : i + n],
    )
    lines, log = logs()
    mic = MicrophoneStream(
        "usb",
        window_s=0.1,
        stall_timeout_s=0.3,
        backoff_s=(0.1, 0.4),
        log=log,
        backend=backend,
        clock=clock,
        sleep=clock.sleep,
    ).start()
    windows, rescans_at = [], []
    rescan = backend.rescan
    backend.rescan = lambda: (rescans_at.append(clock()), rescan())  # before every reopening

    def run(seconds: float) -> None:
        end = clock() + seconds
        while clock() < end:
            windows.extend(mic.read_windows(0.02))

    try:
        run(0.5)
        assert mic.state == "connected" and len(windows) == 5  # blocks come at their ADC time
        before = len(windows)
        unplugged = clock()
        backend.unplug(0)  # the stream dies; the device is gone from the next rescan
        run(1.3)
        status = mic.status()
        assert status.state == "disconnected" and status.disconnects == 1
        # back-off 0.1, 0.2, 0.4, 0.4 s after the disconnect (noticed 20 ms after unplugging)
        # noticed at the first read after the unplug (20 ms later); then it retries after
        # back-offs of 0.1, 0.2, 0.4 and 0.4 s (doubling up to backoff_s[1])
        assert [round(t - unplugged, 9) for t in rescans_at] == [0.12, 0.32, 0.72, 1.12]
        assert status.reconnect_attempts == 4
        assert "no input device name contains 'usb'" in status.last_error
        assert "[1] Built-in" in status.last_error
        assert len(windows) == before  # nothing is made up while the device is gone
        backend.plug(device(0, "USB mic", 1, 0, 16000))
        replugged = clock()
        run(1.0)
        status = mic.status()
        assert status.state == "connected" and status.reconnects == 1
        reopened = unplugged + 1.52  # the attempt 0.4 s after the last failed one
        resumed = windows[before:]
        assert resumed and all(w.segment == 1 for w in resumed)
        assert resumed[0].start_time == pytest.approx(reopened, abs=1e-9)
        assert resumed[0].gap_s == pytest.approx(reopened - windows[before - 1].end_time)
        assert status.gaps == 1 and status.gap_total_s == resumed[0].gap_s
        assert replugged < reopened and all(w.gap_s == 0 for w in resumed[1:])
        # every window after the gap holds exactly the audio at its ADC time
        for w in resumed:
            i = round((w.start_time - t0) * 16000)
            assert w.energy_db == window_energies_db(x[i : i + 1600], 16000, 0.1)[0]
        # a stalled device (delivers nothing, does not fail) is noticed too
        count = len(windows)
        backend.stalled[0] = True  # a reopened stream stalls too: it flaps until data flows
        run(0.6)
        assert mic.status().disconnects >= 2 and len(windows) <= count + 1
        assert any("no audio from USB mic for 0.3 s" in line for line in lines)
        backend.stalled[0] = False
        run(0.8)
        assert mic.state == "connected" and mic.status().reconnects >= 2
        assert len(windows) > count + 3
        assert backend.rescans >= 2
        assert any("microphone disconnected" in line for line in lines)
        assert any("reconnected" in line for line in lines)
    finally:
        mic.close()
    assert mic.state == "closed"
    assert clock.slept == pytest.approx(clock() - t0)  # all the time passed in the stream's waits
    with pytest.raises(AudioError, match="not started"):
        mic.read_windows()


def timeline_blocks(timeline, x, block, t0=100.0, rate=16000, **losses):
    """Convert ``x`` block by block at contiguous ADC times; return the windows."""
    windows = []
    for k in range(0, x.size, block):
        chunk = timeline.convert(x[k : k + block, None], t0 + k / rate, 0, False, None, now=0.0)
        windows.extend(timeline.assemble(chunk))
    return windows


def test_timeline_contiguous_blocks_give_offline_energies_at_exact_times() -> None:
    x = recording(16000, 1.0)
    timeline = WindowTimeline(16000, 0.25)
    timeline.start_stream(16000)
    windows = timeline_blocks(timeline, x, 333)
    assert [w.index for w in windows] == [0, 1, 2, 3]
    assert [w.start_time for w in windows] == [100.0, 100.25, 100.5, 100.75]
    assert [w.end_time for w in windows] == [100.25, 100.5, 100.75, 101.0]
    assert [w.energy_db for w in windows] == window_energies_db(x, 16000, 0.25).tolist()
    assert all(w.intact and w.segment == 0 and w.gap_s == 0 for w in windows)
    assert (timeline.windows, timeline.gaps, timeline.lost_samples) == (4, 0, 0)


def test_timeline_short_loss_stays_in_its_window_and_long_loss_is_a_gap() -> None:
    timeline = WindowTimeline(16000, 0.1)  # 1600 samples a window
    timeline.start_stream(16000)
    block = np.full((800, 1), 0.1)
    first = timeline.assemble(timeline.convert(block, 10.0, 0, False, None, 0.0))
    # 400 samples dropped before the next block: inside the window being filled
    second = timeline.assemble(timeline.convert(block, 10.075, 400, False, None, 0.0))
    assert first == [] and len(second) == 1
    w = second[0]
    assert (w.lost_samples, w.segment, w.gap_s) == (400, 0, 0.0) and not w.intact
    assert w.start_time == 10.0 and w.end_time == pytest.approx(10.125)
    # an overflow whose ADC time jumps 0.2 s (a window or more): a new segment and a gap
    late = 10.125 + 0.2
    chunk = timeline.convert(np.full((1600, 1), 0.1), late, 0, True, None, 0.0)
    assert chunk.segment == 1 and chunk.start_time == pytest.approx(late)
    [after] = timeline.assemble(chunk)
    assert after.segment == 1 and after.overflows == 1 and after.lost_samples == 0
    assert after.start_time == pytest.approx(late)
    assert after.gap_s == pytest.approx(0.2) and timeline.gap_total_s == after.gap_s
    assert (timeline.gaps, timeline.lost_samples) == (1, 400 + 3200)


def test_timeline_reopened_stream_resamples_and_reports_the_gap() -> None:
    timeline = WindowTimeline(16000, 0.5)
    timeline.start_stream(16000)
    timeline_blocks(timeline, recording(16000, 1.0), 320, t0=0.0)
    timeline.start_stream(48000)  # reopened at another rate, 2 s later
    x48 = recording(48000, 1.0, seed=2)
    windows = timeline_blocks(timeline, x48, 960, t0=3.0, rate=48000)
    assert [w.segment for w in windows] == [1]  # the resampler delays the second window
    assert windows[0].start_time == 3.0 and windows[0].gap_s == pytest.approx(2.0)
    expected = window_energies_db(resample(x48, 48000, 16000), 16000, 0.5)[0]
    assert windows[0].energy_db == expected
    # blocks without an ADC time are anchored at the caller's clock
    timeline.start_stream(16000)
    chunk = timeline.convert(np.zeros((8000, 1)), None, 0, False, None, now=7.5)
    assert chunk.start_time == 7.5 and timeline.assemble(chunk)[0].start_time == 7.5


def test_microphone_argument_errors() -> None:
    with pytest.raises(AudioError, match="window_s"):
        MicrophoneStream(window_s=0)
    with pytest.raises(AudioError, match="channel"):
        MicrophoneStream(channel=-1)
    with pytest.raises(AudioError, match="channel 2 does not exist among 2"):
        MicrophoneStream(channel=2, channels=2)
    with pytest.raises(AudioError, match="backoff_s"):
        MicrophoneStream(backoff_s=(2.0, 1.0))


# --------------------------------------------------------------------------- speaker (fake)


def speaker_backend(rate: int = 16000, clock: FakeClock | None = None) -> FakeBackend:
    return FakeBackend([device(0, "Speakers", 0, 2, rate)], default_output=0, clock=clock)


def test_speaker_plays_on_command_only_and_reports_dac_start() -> None:
    clock = FakeClock(10.0)  # the blocks are pumped by hand: the clock stays at 10 s
    backend = speaker_backend(clock=clock)
    with SpeakerOutput(volume=0.5, block_s=0.01, backend=backend, clock=clock,
                       sleep=clock.sleep) as speaker:  # fmt: skip
        stream = backend.last("output")
        assert (stream.rate, stream.channels) == (16000, 1)
        silent = np.concatenate([stream.pump(t=10.0 + 0.01 * k) for k in range(5)])
        assert not silent.any()
        sequence = speaker.play()
        out = np.concatenate([stream.pump(t=20.0 + 0.01 * k) for k in range(30)])
        events = speaker.events()
        # A DAC time from a stale device time stamp, before the block was even filled
        # (13 ms early, as once on a loaded machine): the sound starts no earlier than now.
        speaker.play()
        stream.pump(t=clock() - 0.013)
        stale = speaker.events()
    chirp = (0.5 * synthesize_chirp(16000, 0.2, amplitude=1.0)).astype(np.float32)
    assert np.array_equal(out[: chirp.size, 0], chirp)
    assert not out[chirp.size :].any()
    assert len(events) == 1 and events[0].sequence == sequence
    assert events[0].start_time == pytest.approx(20.0, abs=1e-4) and events[
        0
    ].duration_s == pytest.approx(0.2)
    assert not events[0].interrupted
    assert len(stale) == 1 and stale[0].start_time == clock() == stale[0].requested_time
    assert speaker.status().played == 2 and speaker.status().requests == 2


def test_the_stream_clock_offset_comes_from_the_tightest_reading() -> None:
    """A thread preempted between two clock readings does not shift the stream's times."""
    true_offset = 100.0
    now = [5.0]
    pauses = iter([0.02, 0.0, 0.03, 0.0, 0.0])  # preempted twice in five readings

    def clock() -> float:
        now[0] += 1e-6
        return now[0]

    def stream_time() -> float:
        now[0] += next(pauses)  # preempted before the stream clock is read
        return now[0] - true_offset

    assert clock_offset(clock, stream_time) == pytest.approx(true_offset, abs=1e-6)
    # one reading (the offset as it was read before) would have been 20 ms off
    now[0], pauses = 5.0, iter([0.02])
    assert clock() - stream_time() == pytest.approx(true_offset - 0.02)


def test_speaker_restart_policy_and_skip_policy() -> None:
    for overlap, interrupted, skipped in (("restart", 1, 0), ("skip", 0, 1)):
        backend = speaker_backend()
        with SpeakerOutput(overlap=overlap, backend=backend) as speaker:
            stream = backend.last("output")
            speaker.play()
            first = np.concatenate([stream.pump(t=float(k)) for k in range(10)])  # 0.1 s
            speaker.play()
            speaker.play()  # two commands before the next block count as one
            rest = np.concatenate([stream.pump(t=float(k)) for k in range(40)])
            status = speaker.status()
            events = speaker.events()
        chirp = synthesize_chirp(16000, 0.2, amplitude=1.0).astype(np.float32)
        assert np.array_equal(first[:, 0], chirp[:1600])
        assert (status.requests, status.interrupted, status.skipped) == (3, interrupted, skipped)
        if overlap == "restart":  # the sound starts again from the beginning: no queue
            assert np.array_equal(rest[:3200, 0], chirp) and not rest[3200:].any()
            assert [e.interrupted for e in events] == [False, True]
        else:  # the rest of the first sound plays out, the new command is dropped
            assert np.array_equal(rest[:1600, 0], chirp[1600:]) and not rest[1600:].any()
            assert len(events) == 1


def test_speaker_sound_from_wav_and_array_resampled_to_the_device(tmp_path) -> None:
    tone = 0.3 * np.sin(2 * np.pi * 440 * np.arange(8000) / 16000)
    wav = tmp_path / "beep.wav"
    write_wav_int16(wav, tone, 16000)
    backend = speaker_backend(48000)
    with SpeakerOutput(sound=wav, backend=backend) as speaker:
        assert speaker.device_rate == 48000 and speaker.sound.size == 24000
        assert np.allclose(speaker.sound, resample(load_mono(wav), 16000, 48000))
    with SpeakerOutput(sound=tone, sound_rate=16000, backend=speaker_backend(16000)) as speaker:
        assert np.array_equal(speaker.sound, tone)
    with pytest.raises(AudioError, match="sound_rate"):
        SpeakerOutput(sound=tone)
    with pytest.raises(AudioError, match="volume"):
        SpeakerOutput(volume=1.5)
    with pytest.raises(AudioError, match="overlap"):
        SpeakerOutput(overlap="queue")


def test_speaker_survives_a_vanished_device() -> None:
    clock = FakeClock(50.0)
    backend = FakeBackend([device(0, "Speakers", 0, 2, 16000)], default_output=0, clock=clock)
    lines, log = logs()
    speaker = SpeakerOutput(retry_s=0.2, log=log, backend=backend, clock=clock, sleep=clock.sleep)
    speaker.start()
    try:
        backend.unplug(0)
        assert speaker.play() is None
        status = speaker.status()
        assert status.state == "disconnected" and status.errors == 2
        assert "no output device" in status.last_error or "Speakers" in status.last_error
        opened = backend.open_attempts
        backend.plug(device(0, "Speakers", 0, 2, 16000))
        clock.advance(0.19)
        assert speaker.play() is None  # within retry_s: not even tried
        assert backend.open_attempts == opened and speaker.status().errors == 3
        clock.advance(0.02)  # retry_s has passed
        assert speaker.play() == 1
        assert speaker.status().state == "connected"
        stream = backend.last("output")
        dac = clock() + 0.05
        assert stream.pump(t=dac).any() and speaker.events()[0].start_time == dac
        assert speaker.events(0.5) == [] and clock() == pytest.approx(50.71)  # waited on the clock
    finally:
        speaker.close()
    with pytest.raises(AudioError, match="not started"):
        speaker.play()
    assert any("speaker" in line for line in lines)


# --------------------------------------------------------------------------- helpers


def test_histogram_marks_the_threshold_between_bins() -> None:
    energies = [-60.2, -59.0, -58.5, -61.0, -30.0, -29.5, -31.0, -45.0]
    text = energy_histogram(energies, threshold_db=-45.0, bin_db=3.0, width=10)
    lines = text.splitlines()
    marker = next(i for i, line in enumerate(lines) if "threshold -45.0 dB" in line)
    below, above = lines[:marker], lines[marker + 1 :]
    count = lambda rows: sum(int(r.rsplit(" ", 1)[1]) for r in rows)  # noqa: E731
    assert count(below) == 5 and count(above) == 3  # -45.0 itself is quiet (y = e > theta)
    assert above[0].startswith("   -45.0 ..  -42.0 dB")
    assert "##########" in text and "###########" not in text
    wide = energy_histogram([-120.0, -119.0, -20.0, -21.0], -70.0, bin_db=1.0, max_bins=10)
    assert len(wide.splitlines()) <= 12


def test_self_period_windows_definition() -> None:
    # heard over [0.05, 0.25] s: window z = 0 only
    assert self_period_windows(0.05, 0.05, 0.2, 0.5) == (0, 0)
    # heard over [0.35, 0.75]: windows 0 and 1
    assert self_period_windows(0.30, 0.35, 0.4, 0.5) == (0, 1)
    # a sound ending exactly at a window boundary does not reach the next window
    assert self_period_windows(0.3, 0.3, 0.2, 0.5) == (0, 0)
    assert self_period_windows(0.6, 0.7, 0.2, 0.5) == (1, 1)
    with pytest.raises(AudioError):
        self_period_windows(0.5, 0.1, 0.2, 0.5)


def test_find_onset_locates_the_chirp() -> None:
    rng = np.random.default_rng(3)
    chirp = synthesize_chirp(16000)
    x = 0.01 * rng.standard_normal(16000)
    x[5000 : 5000 + chirp.size] += 0.3 * chirp
    index, score = find_onset(x, chirp)
    assert index == 5000 and score > 0.9
    assert find_onset(0.01 * rng.standard_normal(16000), chirp) is None
    assert find_onset(x[:100], chirp) is None


def test_measure_latency_through_a_simulated_room() -> None:
    clock = FakeClock(500.0)
    room = Room(16000, delay_s=0.137, clock=clock)
    backend = FakeBackend(
        [device(0, "mic", 1, 0, 16000), device(1, "speaker", 0, 1, 16000)],
        default_input=0,
        default_output=1,
        clock=clock,
        source=room.source,
        sink=room.sink,
        output_latency_s=0.03,
    )
    report = measure_latency(
        repeats=3, interval_s=0.6, volume=0.5, backend=backend, clock=clock, sleep=clock.sleep
    )
    assert not report.failures and len(report.trials) == 3
    for trial in report.trials:
        assert trial.delay_s - trial.output_s == pytest.approx(0.137, abs=1 / 16000)
        assert 0.03 <= trial.output_s <= 0.03 + 0.01  # output latency + up to one 10 ms block
        assert trial.score > 0.9
    assert report.sound_s == pytest.approx(0.2)
    assert (report.input_device, report.output_device) == ("mic", "speaker")


# --------------------------------------------------------------------------- real ALSA path

def capture(alsa: VirtualAlsa, spec, n: int, window_s=0.5, channel=None, channels=None) -> dict:
    return alsa.run("capture", spec=spec, n=n, window_s=window_s, channel=channel,
                    channels=channels)  # fmt: skip


def test_alsa_capture_gives_the_bits_of_the_wav_source(tmp_path) -> None:
    wav = write_recording(tmp_path / "room.wav", 16000)
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.wav_microphone("fakemic", wav)
    alsa.write(default_capture="fakemic")
    reference = window_energies_db(load_mono(wav), 16000, 0.5)
    threshold = kmeans_threshold(reference)
    for spec in (None, "FAKEmic"):
        result = capture(alsa, spec, reference.size)
        assert result["intact"] and result["status"]["device_rate"] == 16000
        energies = np.array(result["energies"])
        assert np.array_equal(energies, reference)  # bit for bit
        assert np.array_equal(
            bits_from_energies(energies, threshold),
            bits_from_energies(reference, threshold),
        )
    assert result["status"]["device"] == "fakemic"
    assert any("microphone: [0] fakemic" in line for line in result["logs"])


def test_alsa_stereo_capture_mixes_down_or_picks_a_channel(tmp_path) -> None:
    wav = write_recording(tmp_path / "stereo.wav", 16000, seconds=3.0, channels=2)
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.wav_microphone("array", wav)
    alsa.write(default_capture="array")
    for channel in (None, 1):
        reference = window_energies_db(load_mono(wav, channel=channel), 16000, 0.5)
        result = capture(alsa, "array", reference.size, channel=channel, channels=2)
        assert result["intact"] and np.array_equal(result["energies"], reference)


def test_alsa_48khz_only_device_is_resampled_to_the_same_bits(tmp_path) -> None:
    wav = write_recording(tmp_path / "room48.wav", 48000)
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.wav_microphone("usb48", wav, only_rate=48000)
    alsa.write(default_capture="usb48")
    # the device really refuses 16 kHz through PortAudio
    probe = alsa.run("input_rates", device="usb48")
    assert probe == {**probe, "r16": False, "r48": True, "default": 48000.0}
    reference = window_energies_db(load_mono(wav, 16000), 16000, 0.5)
    result = capture(alsa, "usb48", reference.size)
    assert result["status"]["device_rate"] == 48000 and result["intact"]
    assert np.array_equal(result["energies"], reference)  # bit for bit, after resampling
    assert any("does not open at 16000 Hz" in line for line in result["logs"])


def test_alsa_missing_device_lists_the_devices(tmp_path) -> None:
    alsa = VirtualAlsa(tmp_path / "alsa")
    alsa.microphone("fakemic", np.zeros(1600))
    alsa.speaker("fakespeaker")
    alsa.write(default_playback="fakespeaker")  # no default input
    by_name, by_index, speaker = alsa.run(
        "missing", devices=[["mic", "ReSpeaker"], ["mic", 5], ["speaker", "HDMI"]]
    )["messages"]
    assert "no input device name contains 'ReSpeaker'" in by_name
    assert "Available input devices:\n  [0] fakemic (ALSA," in by_name
    assert "by its index" in by_name
    assert "there is no audio device with index 5" in by_index
    assert "no output device name contains 'HDMI'" in speaker and "fakespeaker" in speaker
    # no microphone at all: the system default is missing, and the list says so
    alsa.remove("fakemic")
    alsa.write(default_playback="fakespeaker")
    (default,) = alsa.run("missing", devices=[["mic", None]])["messages"]
    assert "there is no default input device" in default
    assert "PortAudio sees no input device at all" in default and "arecord -l" in default


def test_alsa_playback_holds_the_chirp_only_when_commanded(tmp_path) -> None:
    alsa = VirtualAlsa(tmp_path / "alsa")
    out = alsa.speaker("fakespeaker")
    alsa.write(default_playback="fakespeaker")
    result = alsa.run("speaker", play=True)
    status = result["status"]
    rate, channels = status["device_rate"], status["channels"]
    assert status["played"] == 1 and status["errors"] == 0
    played = read_raw(out, channels)[:, 0]
    loud = np.flatnonzero(played)
    chirp = (0.5 * synthesize_chirp(rate, amplitude=1.0)).astype(np.float32)
    start = loud[0] - 1  # the chirp's first sample is sin(0) = 0
    assert np.array_equal(played[start : start + chirp.size], chirp)  # exactly once
    assert loud[-1] < start + chirp.size and not played[:start].any()
    duration = (loud[-1] - loud[0] + 2) / rate
    assert duration == pytest.approx(0.2, abs=1e-3)
    spectrum = np.abs(np.fft.rfft(played[start : start + chirp.size]))
    peak_hz = np.argmax(spectrum) * rate / chirp.size
    assert 800 <= peak_hz <= 2400
    event = result["events"][0]
    assert event["start_time"] >= event["requested_time"] - 0.5  # DAC time, monotonic clock
    # without a command: silence only
    result = alsa.run("speaker", play=False)
    silent = read_raw(out, result["status"]["channels"])
    assert silent.size > 0 and not silent.any()


@pytest.mark.slow
def test_alsa_device_that_stalls_and_vanishes_is_reopened_when_back(tmp_path) -> None:
    a = recording(16000, 2.0, seed=1).astype("<f4")  # 8 windows of 0.25 s
    b = np.concatenate([recording(16000, 1.5, seed=2), np.zeros(16000)]).astype("<f4")
    np.save(tmp_path / "a.npy", a)
    np.save(tmp_path / "b.npy", b)
    alsa = VirtualAlsa(tmp_path / "alsa")
    fifo = alsa.fifo_microphone("fifomic")
    alsa.speaker("fakespeaker")
    full = alsa.write(default_playback="fakespeaker", path=tmp_path / "full.conf")
    alsa.remove("fifomic")
    missing = alsa.write(default_playback="fakespeaker", path=tmp_path / "missing.conf")
    alsa.config.write_bytes(full.read_bytes())
    result = alsa.run(
        "vanish",
        timeout=90,
        fifos=[str(fifo)],
        fifo=str(fifo),
        a=str(tmp_path / "a.npy"),
        b=str(tmp_path / "b.npy"),
        missing_conf=str(missing),
        full_conf=str(full),
        conf=str(alsa.config),
        nb=6,
    )
    status = result["status"]
    segments = [w[0] for w in result["windows"]]
    energies = np.array([w[1] for w in result["windows"]])
    story = f"{status}\n" + "\n".join(result["logs"])  # what the stream went through
    assert status["disconnects"] == 1 and status["reconnects"] == 1, story
    assert status["reconnect_attempts"] >= 2 and status["state"] == "connected", story
    assert segments == [0] * 8 + [1] * (len(segments) - 8)
    assert np.array_equal(energies[:8], window_energies_db(a.astype(float), 16000, 0.25))
    expected_b = window_energies_db(b.astype(float), 16000, 0.25)
    assert np.array_equal(energies[8:14], expected_b[:6])
    # the gap is counted and no window is made up for it; its length (gap_s) means nothing
    # here, since the clock-less null device runs ahead of real time (see the fake test)
    assert status["gaps"] == 1
    joined = "\n".join(result["logs"])
    assert "no audio from fifomic" in joined
    assert "no input device name contains 'fifomic'" in joined  # while it was gone
    assert "reconnected" in joined


def test_live_audio_imports_neither_rclpy_nor_sounddevice() -> None:
    import subprocess

    modules = ",".join(["infomax_contingency.cli.live"] + [
        f"infomax_contingency.audio.{name}"
        for name in ("calibration", "capture", "latency", "playback")
    ])
    child = Path(__file__).resolve().parent / "child_imports.py"
    out = subprocess.run([sys.executable, str(child), modules, "rclpy,sounddevice"],
                         capture_output=True, text=True, check=True)  # fmt: skip
    assert json.loads(out.stdout) == []


def test_record_energies_on_the_fake_clock_and_its_deadline() -> None:
    clock = FakeClock(10.0)
    x = f32(recording(16000, 10.0, seed=4))
    backend = FakeBackend(
        [device(0, "mic", 1, 0, 16000)],
        default_input=0,
        clock=clock,
        source=lambda stream, t, n: x[(i := round((t - 10.0) * 16000)) : i + n],
    )
    result = record_energies(None, 2.0, 0.25, backend=backend, clock=clock, sleep=clock.sleep)
    assert (result.device, result.device_rate, result.gaps) == ("mic", 16000, 0)
    np.testing.assert_array_equal(result.energies_db, window_energies_db(x[:32000], 16000, 0.25))
    backend.stalled[0] = True  # delivers nothing: given up after seconds + 5 s on the clock
    start = clock()
    with pytest.raises(AudioDeviceError, match=r"recorded only 0 of 8 windows from mic in 7 s"):
        record_energies(None, 2.0, 0.25, backend=backend, clock=clock, sleep=clock.sleep)
    assert 7.0 < clock() - start < 7.2

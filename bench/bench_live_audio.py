"""Cost of live capture, from the PortAudio callback to the windows (prints figures).

Measures the callback, the reader (mix, resample, windows), and the whole path through
PortAudio/ALSA on a virtual device.

Usage (from the repository root, after ``make setup``)::

    .venv/bin/python bench/bench_live_audio.py            # 60 s of audio per device rate
    .venv/bin/python bench/bench_live_audio.py --seconds 20

* callback: time per call of MicrophoneStream's PortAudio callback (copy into the queue),
  driven by the fake PortAudio of the tests (test/fake_portaudio.py);
* reader: time of ``read_windows`` per second of audio (mix-down, exact resampling to
  16 kHz, windows), for devices at 16, 44.1 and 48 kHz, in 20 ms blocks;
* ALSA: a virtual 48 kHz-only microphone (test/alsa_devices.py) runs free (the ALSA
  ``null`` slave has no clock), so the time to read its windows is the throughput of the
  whole sounddevice -> PortAudio -> ALSA -> reader path.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))

from alsa_devices import VirtualAlsa  # noqa: E402
from fake_portaudio import FakeBackend, device  # noqa: E402
from infomax_contingency.audio.capture import MicrophoneStream  # noqa: E402
from infomax_contingency.audio.resample import StreamResampler, resample  # noqa: E402

ALSA_CHILD = """
import json, time
from infomax_contingency.audio.capture import MicrophoneStream
mic = MicrophoneStream('usb48', window_s=0.5, queue_s={seconds} + 5).start()
start, windows = time.perf_counter(), []
while len(windows) < {n}:
    windows += mic.read_windows(0.1)
elapsed = time.perf_counter() - start
status = mic.status()
mic.close()
print(json.dumps(dict(elapsed=elapsed, rate=status.device_rate, lost=status.lost_samples)))
"""


def bench_reader(rate: int, seconds: float) -> tuple[float, float]:
    """(callback µs per 20 ms block, reader ms per second of audio) at a device rate."""
    backend = FakeBackend([device(0, "bench", 1, 0, rate)], default_input=0)
    x = (0.1 * np.random.default_rng(0).standard_normal(round(seconds * rate))).astype(np.float32)
    block = round(0.02 * rate)
    blocks = [x[i : i + block, np.newaxis] for i in range(0, x.size - block + 1, block)]
    callback_s = reader_s = 0.0
    with MicrophoneStream(None, queue_s=seconds + 1, backend=backend) as mic:
        stream = backend.last()
        for k, b in enumerate(blocks):
            t = time.perf_counter()
            stream.pump(b, t=1000.0 + k * 0.02)
            callback_s += time.perf_counter() - t
            if k % 5 == 4:  # the node reads about every 100 ms
                t = time.perf_counter()
                mic.read_windows(0.0)
                reader_s += time.perf_counter() - t
    return 1e6 * callback_s / len(blocks), 1e3 * reader_s / seconds


def bench_resampler(rate: int, seconds: float) -> tuple[float, float]:
    """(streaming, whole-signal) resampling time to 16 kHz, ms per second of audio."""
    x = np.random.default_rng(1).standard_normal(round(seconds * rate))
    block = round(0.02 * rate)
    r = StreamResampler(rate, 16000)
    t = time.perf_counter()
    for i in range(0, x.size, block):
        r.push(x[i : i + block])
    streaming = time.perf_counter() - t
    t = time.perf_counter()
    resample(x, rate, 16000)
    whole = time.perf_counter() - t
    return 1e3 * streaming / seconds, 1e3 * whole / seconds


def bench_alsa(seconds: float) -> dict:
    """Read ``seconds`` of audio from a free-running virtual 48 kHz microphone."""
    with tempfile.TemporaryDirectory() as tmp:
        alsa = VirtualAlsa(Path(tmp))
        rng = np.random.default_rng(2)
        alsa.microphone(
            "usb48", 0.1 * rng.standard_normal(round(seconds * 48000)), rate=48000, only_rate=48000
        )
        alsa.write(default_capture="usb48")
        return alsa.run(ALSA_CHILD.format(seconds=seconds, n=int(seconds / 0.5)), timeout=600)


def main() -> None:
    """Print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="audio per measurement")
    args = parser.parse_args()
    print(f"live capture, {args.seconds:g} s of audio per figure, 20 ms blocks, 0.5 s windows")
    for rate in (16000, 44100, 48000):
        callback_us, reader_ms = bench_reader(rate, args.seconds)
        print(
            f"  device at {rate:5d} Hz: callback {callback_us:6.1f} µs/block;"
            f" reader {reader_ms:6.2f} ms per s of audio ({reader_ms / 10:.2f} % of a core)"
        )
    for rate in (44100, 48000):
        streaming, whole = bench_resampler(rate, args.seconds)
        print(
            f"  resampling {rate} -> 16000 Hz: streaming {streaming:.2f} ms/s,"
            f" whole signal {whole:.2f} ms/s"
        )
    result = bench_alsa(args.seconds)
    print(
        f"  through PortAudio/ALSA (virtual 48 kHz-only mic, free-running):"
        f" {args.seconds:g} s of audio read in {result['elapsed']:.2f} s"
        f" ({args.seconds / result['elapsed']:.0f}x real time; {result['lost']} samples lost)"
    )


if __name__ == "__main__":
    main()

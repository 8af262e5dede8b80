"""Memory and time of reading WAV files into window energies (prints figures).

Usage (from the repository root, after ``make setup``)::

    .venv/bin/python bench/bench_wav.py                 # 1 min and 1 h files
    .venv/bin/python bench/bench_wav.py --long-s 600    # a shorter long file

The files are made at run time in a temporary directory (16 kHz 16-bit mono: 115 MB for
an hour; also a 44.1 kHz stereo file, resampled on the way). Each figure comes from a
fresh Python process, which reports its peak resident memory (``ru_maxrss``) before and
after the work, so the difference is what reading the file cost:

* streamed: :func:`~infomax_contingency.audio.energy.iter_wav_energies`, the path of
  ``WavReplay``, ``energies_from_wav`` and the ``calibrate`` command (block by block);
* read-ahead: the first 10 s of calibration (``WavReplay.calibration_energies``);
* whole file: ``window_energies_db(load_mono(path))``, for comparison (only for the
  short file and a 10 min one: a whole hour would take over 1 GB).
"""

from __future__ import annotations

import argparse
import json
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CHILD = """
import json, resource, sys, time
import numpy as np
import scipy.signal  # loaded lazily by the resampler: count it as an import, not as the work
from infomax_contingency.audio.windows import WavReplay
from infomax_contingency.audio.energy import iter_wav_energies, window_energies_db
from infomax_contingency.audio.resample import load_mono
path, mode = sys.argv[1], sys.argv[2]
window_s = 0.5
baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
start = time.perf_counter()
if mode == "streamed":
    windows = sum(e.size for e in iter_wav_energies(path, window_s))
elif mode == "read-ahead":
    windows = WavReplay(path, window_s).calibration_energies(10.0, window_s).size
else:
    windows = window_energies_db(load_mono(path), 16000, window_s).size
elapsed = time.perf_counter() - start
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps(dict(windows=windows, elapsed=elapsed, baseline_kb=baseline, peak_kb=peak)))
"""


def write_noise_wav(path: Path, seconds: float, rate: int, channels: int) -> int:
    """Write a 16-bit PCM WAV of alternating quiet and loud noise, block by block.

    Returns:
        The file size, bytes.
    """
    frames = round(seconds * rate)
    data_bytes = frames * channels * 2
    header = b"RIFF" + struct.pack("<I", 36 + data_bytes) + b"WAVE"
    header += b"fmt " + struct.pack(
        "<IHHIIHH", 16, 1, channels, rate, rate * channels * 2, channels * 2, 16
    )
    header += b"data" + struct.pack("<I", data_bytes)
    rng = np.random.default_rng(0)
    block = 10 * rate
    with path.open("wb") as f:
        f.write(header)
        for start in range(0, frames, block):
            n = min(block, frames - start)
            t = (start + np.arange(n)) / rate
            loud = (t // 0.7) % 2 == 1
            x = rng.normal(0, 0.002, (n, channels)) + np.where(loud, 0.2, 0)[:, None] * rng.normal(
                0, 1, (n, channels)
            )
            f.write(np.round(np.clip(x, -1, 1) * 32767).astype("<i2").tobytes())
    return path.stat().st_size


def measure(path: Path, mode: str) -> dict:
    """Run one measurement in a fresh process."""
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(path), mode],
        check=True,
        capture_output=True,
        text=True,
        timeout=3600,
    )
    return json.loads(out.stdout)


def main() -> None:
    """Print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--long-s", type=float, default=3600.0, help="length of the long file")
    args = parser.parse_args()
    cases = [
        ("1 min, 16 kHz mono", 60.0, 16000, 1, ("streamed", "read-ahead", "whole")),
        ("10 min, 16 kHz mono", 600.0, 16000, 1, ("streamed", "whole")),
        (
            f"{args.long_s / 60:g} min, 16 kHz mono",
            args.long_s,
            16000,
            1,
            ("streamed", "read-ahead"),
        ),
        ("1 min, 44.1 kHz stereo", 60.0, 44100, 2, ("streamed", "whole")),
        ("10 min, 44.1 kHz stereo", 600.0, 44100, 2, ("streamed",)),
    ]
    print("WAV file -> window energies (0.5 s windows); peak RSS of a fresh process")
    with tempfile.TemporaryDirectory() as tmp:
        for name, seconds, rate, channels, modes in cases:
            path = Path(tmp) / "audio.wav"
            size = write_noise_wav(path, seconds, rate, channels)
            for mode in modes:
                r = measure(path, mode)
                extra = (r["peak_kb"] - r["baseline_kb"]) / 1024
                print(
                    f"  {name:26s} ({size / 1e6:7.1f} MB) {mode:10s}: peak RSS"
                    f" {r['peak_kb'] / 1024:7.1f} MB (+{extra:6.1f} MB over the imports),"
                    f" {r['windows']:6d} windows in {r['elapsed']:6.2f} s"
                )
            path.unlink()


if __name__ == "__main__":
    main()

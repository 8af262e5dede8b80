"""Make ``interaction.wav``: a short recorded-style interaction for the wav replay tests.

18 s of mono 16-bit audio at 8 kHz (so the replay also exercises resampling to the
16 kHz processing rate; under 300 KB): a room's hiss, the robot's chirp four times,
a person answering three of them with speech (espeak-ng) about 1.2 s later, and two
background knocks. Deterministic: a fixed seed and fixed utterances.

Run from the repository root (needs espeak-ng, e.g. ``apt-get install espeak-ng``)::

    .venv/bin/python test/data/make_interaction.py
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from infomax_contingency.audio.resample import load_mono
from infomax_contingency.audio.synth import synthesize_chirp
from infomax_contingency.audio.wav import write_wav_int16

RATE_HZ = 8000
DURATION_S = 18.0
SEED = 20100
CHIRPS_S = (1.0, 5.0, 9.5, 14.0)
REPLIES = ((2.2, "hello robot"), (6.3, "yes, I can hear you"), (15.2, "hi there"))
KNOCKS_S = (7.9, 12.1)
OUT = Path(__file__).with_name("interaction.wav")


def speech(text: str, workdir: Path) -> np.ndarray:
    """``text`` spoken by espeak-ng, at RATE_HZ, peak-normalised to 0.5."""
    path = workdir / "speech.wav"
    try:
        subprocess.run(["espeak-ng", "-s", "150", "-w", str(path), text], check=True)
    except FileNotFoundError:
        sys.exit("espeak-ng is not installed: apt-get install espeak-ng")
    x = load_mono(path, rate=RATE_HZ)
    return 0.5 * x / np.max(np.abs(x))


def place(track: np.ndarray, sound: np.ndarray, at_s: float) -> None:
    """Add ``sound`` into ``track`` starting at ``at_s`` seconds."""
    start = round(at_s * RATE_HZ)
    track[start : start + sound.size] += sound[: track.size - start]


def main() -> None:
    """Write test/data/interaction.wav."""
    rng = np.random.default_rng(SEED)
    track = rng.standard_normal(round(DURATION_S * RATE_HZ)) * 10 ** (-55 / 20)
    chirp = synthesize_chirp(RATE_HZ, 0.2, f0=800.0, f1=2400.0, amplitude=0.3)
    for at in CHIRPS_S:
        place(track, chirp, at)
    with tempfile.TemporaryDirectory() as workdir:
        for at, text in REPLIES:
            place(track, speech(text, Path(workdir)), at)
    for at in KNOCKS_S:
        n = round(0.15 * RATE_HZ)
        place(track, 0.3 * rng.standard_normal(n) * np.exp(-np.arange(n) / (n / 4)), at)
    write_wav_int16(OUT, track, RATE_HZ)
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes, {DURATION_S} s at {RATE_HZ} Hz)")


if __name__ == "__main__":
    main()

"""Recordings built outside the room renderer, replayed as a user would: detection figures.

Each recording is 60 s of a hall at 16 kHz written as a wav file with its actions CSV,
from sources ``sim/fake_room.py`` does not use: babble of 16 copies of two espeak-ng
talkers at random offsets and gains (low-passed 1.8 kHz) at ``--babble-db`` RMS with brown
noise 6 dB under it; a robot chirping (a 0.4-s sweep, 900-1860 Hz, -20 dB) at irregular
times 2.5-6 s apart, its
own schedule (not the optimal table); a partner who answers 90 % of the chirps 0.9-1.3 s
later with one of six espeak-ng words at -26 dB, or nobody. ``announcements`` adds a
public-address voice 4 dB above the babble for two 11.7-s stretches (12 s and 41 s in):
a room loud for 40 % of the time. ``--scene roadside`` replaces the hall by a terrace beside
a road, built here too: cars passing (brown noise low-passed 700 Hz under a 3-8 s
raised-cosine swell, peaking at ``--babble-db`` + 4 dB, one every 4-10 s), two espeak-ng
passers-by 10 dB under it, a car horn (a 0.5-s 420 + 510 Hz chord at the peak level) now and
then, over a floor 16 dB under it; ``announcements`` is then a bus idling beside the terrace
(low-passed brown noise, 8 dB over the floor) for the same two stretches.

Each recording goes through ``infomax-contingency replay FILE.wav --actions FILE.csv``
with the defaults, the default source over the whole window (``--level-band full``), with
``--calibrate`` (k-means) and with fixed thresholds; printed per
hall and partner state: the final P(S=1) over the seeds (median) and the share of
recordings it puts above 0.9 (partner) or leaves below 0.5 (nobody). Needs espeak-ng
(``make`` installs it).

Run:
    .venv/bin/python bench/probe_hall_recording.py [--seeds 10] [--babble-db -32]
        [--scene hall|roadside]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import shutil
import subprocess
import sys
import tempfile
import wave
from pathlib import Path

import numpy as np
from scipy.signal import butter, resample_poly, sosfilt

from infomax_contingency.cli.main import main as command_line

RATE_HZ = 16000
SECONDS = 60.0
REPLY_WORDS = ("yes", "hello", "what", "uh huh", "oh hi", "hey there")
TALK = (
    "The quarterly numbers came in lower than expected, and the board wants a new plan by"
    " Friday. We should meet with the team tomorrow to go over the budget and the schedule.",
    "Did you see the match last night? They scored twice in the last ten minutes and the"
    " whole stadium went wild. I could not believe it.",
)
ANNOUNCEMENTS_S = (12.0, 41.0)
THRESHOLDS_DB = (-30.0, -29.0, -28.0)


def speak(text: str, voice: str, folder: Path) -> np.ndarray:
    """espeak-ng's rendering of ``text`` at :data:`RATE_HZ` (float, full scale 1)."""
    path = folder / f"speech{len(list(folder.glob('speech*.wav')))}.wav"
    subprocess.run(["espeak-ng", "-v", voice, "-w", str(path), text], check=True)
    with wave.open(str(path)) as w:
        if w.getframerate() != 22050:
            raise SystemExit(f"probe_hall_recording: espeak-ng wrote {w.getframerate()} Hz,"
                             " expected 22050")  # fmt: skip
        x = np.frombuffer(w.readframes(w.getnframes()), np.int16) / 32768.0
    return resample_poly(x, 320, 441)


def at_db(x: np.ndarray, level_db: float) -> np.ndarray:
    """``x`` scaled to ``level_db`` RMS over its sounding samples."""
    sounding = x[np.abs(x) > 1e-4]
    return x * 10 ** (level_db / 20) / np.sqrt(np.mean(sounding**2))


def brown_noise(rng: np.random.Generator, n: int, cutoff_hz: float | None = None
                ) -> np.ndarray:  # fmt: skip
    """Brown noise (integrated white, its drift below 20 Hz removed), low-passed if asked."""
    brown = np.cumsum(rng.standard_normal(n))
    brown -= sosfilt(butter(2, 20, fs=RATE_HZ, output="sos"), brown)
    if cutoff_hz is None:
        return brown
    return sosfilt(butter(2, cutoff_hz, fs=RATE_HZ, output="sos"), brown)


def roadside(rng: np.random.Generator, idling_bus: bool, peak_db: float,
             sounds: dict[str, list[np.ndarray]]) -> np.ndarray:  # fmt: skip
    """The roadside terrace's sound without the robot (see the module docstring)."""
    n = int(SECONDS * RATE_HZ)
    floor_db = peak_db - 16.0
    room = at_db(brown_noise(rng, n, 4000.0), floor_db)
    start = -rng.uniform(0, 4)
    while start < SECONDS:
        length = rng.uniform(3.0, 8.0)
        a, b = max(int(start * RATE_HZ), 0), min(int((start + length) * RATE_HZ), n)
        if b > a:
            swell = np.sin(np.pi * (np.arange(a, b) / RATE_HZ - start) / length) ** 2
            car = at_db(brown_noise(rng, b - a, 700.0), peak_db) * swell
            room[a:b] += car * rng.uniform(0.5, 1.0)
        start += rng.uniform(4.0, 10.0)
    for talker in range(2):
        talk = at_db(sounds["talk"][talker], peak_db - 10)
        a = int(rng.uniform(0, SECONDS - 10) * RATE_HZ)
        room[a : a + talk.size] += talk[: n - a]
    t = np.arange(int(0.5 * RATE_HZ)) / RATE_HZ
    horn = at_db(np.sin(2 * np.pi * 420 * t) + np.sin(2 * np.pi * 510 * t), peak_db)
    for _ in range(rng.integers(0, 3)):
        a = int(rng.uniform(0, SECONDS - 1) * RATE_HZ)
        room[a : a + horn.size] += horn
    if idling_bus:
        bus = at_db(brown_noise(rng, int(11.7 * RATE_HZ), 300.0), floor_db + 8)
        for start_s in ANNOUNCEMENTS_S:
            a = int(start_s * RATE_HZ)
            room[a : a + bus.size] += bus[: n - a]
    return room


def hall(seed: int, partner: bool, announcements: bool, babble_db: float,
         sounds: dict[str, list[np.ndarray]], scene: str = "hall",
         ) -> tuple[np.ndarray, list[float]]:  # fmt: skip
    """One recording's samples and the robot's chirp times, s."""
    rng = np.random.default_rng(seed)
    n = int(SECONDS * RATE_HZ)
    if scene == "roadside":
        return with_robot(rng, roadside(rng, announcements, babble_db + 4, sounds), partner,
                          sounds)  # fmt: skip
    babble = np.zeros(n)
    for talker in range(16):
        talk = sounds["talk"][talker % 2] * rng.uniform(0.5, 1.0)
        start = -int(rng.uniform(0, len(talk)))  # talking from the start, on and on
        while start < n:
            a, b = max(start, 0), min(start + len(talk), n)
            babble[a:b] += talk[a - start : b - start]
            start += len(talk) + int(rng.uniform(0, 2) * RATE_HZ)
    babble = sosfilt(butter(4, 1800, fs=RATE_HZ, output="sos"), babble)
    room = at_db(babble, babble_db) + at_db(brown_noise(rng, n), babble_db - 6)
    if announcements:
        voice = at_db(sounds["talk"][0], babble_db + 4)
        for start_s in ANNOUNCEMENTS_S:
            a = int(start_s * RATE_HZ)
            room[a : a + len(voice)] += voice[: n - a]
    return with_robot(rng, room, partner, sounds)


def with_robot(rng: np.random.Generator, room: np.ndarray, partner: bool,
               sounds: dict[str, list[np.ndarray]]) -> tuple[np.ndarray, list[float]]:  # fmt: skip
    """``room`` with the robot's chirps and the partner's replies; the chirp times, s."""
    n = room.size
    t = np.arange(int(0.4 * RATE_HZ)) / RATE_HZ
    chirp = at_db(np.sin(2 * np.pi * (900 + 1200 * t) * t) * np.hanning(t.size), -20.0)
    times: list[float] = []
    when = 6.0 + rng.uniform(0, 2)
    while when < SECONDS - 3:
        times.append(when)
        a = int(when * RATE_HZ)
        room[a : a + chirp.size] += chirp
        if partner and rng.random() < 0.9:
            reply = at_db(sounds["replies"][rng.integers(len(sounds["replies"]))], -26.0)
            b = int((when + rng.uniform(0.9, 1.3)) * RATE_HZ)
            room[b : b + reply.size] += reply[: max(0, n - b)]
        when += rng.uniform(2.5, 6.0)
    return np.clip(room, -1.0, 1.0), times


def final_belief(wav: Path, actions: Path, options: list[str]) -> float:
    """The final P(S=1) of ``replay wav --actions actions`` with ``options`` (NaN: refused)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        status = command_line(["replay", str(wav), "--actions", str(actions), "--json", *options])
    if status:
        return float("nan")
    steps = [json.loads(line) for line in out.getvalue().splitlines() if line.startswith("{")]
    return float(steps[-1]["belief"])


def write_recording(folder: Path, samples: np.ndarray, times: list[float]) -> tuple[Path, Path]:
    """The recording as a 16-bit wav file and its actions CSV (``time_s``) in ``folder``."""
    wav, actions = folder / "hall.wav", folder / "hall.csv"
    with wave.open(str(wav), "wb") as out:
        out.setnchannels(1)
        out.setsampwidth(2)
        out.setframerate(RATE_HZ)
        out.writeframes((samples * 32767).astype(np.int16).tobytes())
    actions.write_text("time_s\n" + "".join(f"{t:.6f}\n" for t in times))
    return wav, actions


def cell(beliefs: list[float], partner: bool) -> str:
    """Median final P(S=1) and the share right (> 0.9 with the partner, < 0.5 without)."""
    b = np.array(beliefs)
    if np.isnan(b).all():
        return "refused"
    right = np.mean(b > 0.9) if partner else np.mean(b < 0.5)
    refused = np.isnan(b).sum()
    return f"{np.nanmedian(b):.3f}, {right:4.0%}" + (f" ({refused} no)" if refused else "")


def main() -> None:
    """Print the figures (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10, help="recordings per hall and state")
    parser.add_argument("--babble-db", type=float, default=-32.0, help="the babble's RMS, dB")
    parser.add_argument("--scene", choices=("hall", "roadside"), default="hall",
                        help="the hall (babble) or the roadside terrace (passing cars)")
    args = parser.parse_args()
    if args.seeds < 1:
        parser.error(f"--seeds must be at least 1, got {args.seeds}")
    if shutil.which("espeak-ng") is None:
        raise SystemExit("probe_hall_recording: espeak-ng is not installed (make installs it)")
    methods = {"default": [], "whole window": ["--level-band", "full"],
               "calibrate": ["--calibrate"]}
    methods.update({f"fixed {db:g}": ["--threshold-db", f"{db:g}"] for db in THRESHOLDS_DB})
    with tempfile.TemporaryDirectory() as folder_name:
        folder = Path(folder_name)
        sounds = {
            "talk": [speak(TALK[0], "en-us", folder), speak(TALK[1], "en-gb", folder)],
            "replies": [speak(word, "en", folder) for word in REPLY_WORDS],
        }
        print(f"{args.seeds} recordings of 60 s per hall and state; babble {args.babble_db:g} dB;"
              " final P(S=1): median, and the share right (> 0.9 with the partner, < 0.5"
              " without); (N no): replay refused N recordings")  # fmt: skip
        print(f"{'hall':<14} {'partner':<8} " + "".join(f"{m:>22}" for m in methods))
        for announcements in (False, True):
            for partner in (True, False):
                beliefs: dict[str, list[float]] = {m: [] for m in methods}
                for seed in range(args.seeds):
                    samples, times = hall(seed, partner, announcements, args.babble_db, sounds,
                                          args.scene)
                    wav, actions = write_recording(folder, samples, times)
                    for method, options in methods.items():
                        beliefs[method].append(final_belief(wav, actions, options))
                name = ("announcements" if announcements else "steady") if args.scene == "hall" \
                    else ("idling bus" if announcements else "traffic")
                print(f"{name:<14} {'yes' if partner else 'no':<8} "
                      + "".join(f"{cell(b, partner):>22}" for b in beliefs.values()))  # fmt: skip
                sys.stdout.flush()


if __name__ == "__main__":
    main()

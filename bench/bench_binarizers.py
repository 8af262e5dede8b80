"""Bit sources: cost per window, and the bit contrast each achieves in the fake rooms.

Two tables:

* **cost**: microseconds of ``push_window`` per 0.5 s window at 16 kHz (the window's
  energy, level, VAD frames and threshold rule; best of ``--repeats`` passes over the
  same windows of the ``responsive`` room). It must stay far below the 500 000 us of
  the window itself.
* **contrast**: the fixed-interval controller (a vocalization every ``--interval``
  windows) against the audio-level fake rooms (:data:`infomax_contingency.sim.room_config.PRESETS`,
  plus ``noisy+partner``: the noisy room with a partner who answers), ``--seeds`` runs
  of ``--steps`` steps each through the offline loop (the mic node's own path). For
  every bit source: P(active) in the agent period after a vocalization (timer z in
  [ta1, ta2], where a present partner answers), in the self-feedback period (the robot
  hears its own chirp) and in the background (z > ta2). The model needs agent >
  background; the bigger the gap, the fewer vocalizations to a verdict.

Run from the repository root::

    .venv/bin/python bench/bench_binarizers.py [--seeds 10] [--steps 240] [--interval 8]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.core.controllers import FixedIntervalController
from infomax_contingency.core.model import ModelParams
from infomax_contingency.sim.audio_loop import AudioWorld
from infomax_contingency.sim.fake_room import FakeRoom, as_transmitted
from infomax_contingency.sim.loop import run_loop
from infomax_contingency.sim.room_config import FakeRoomConfig

RATE_HZ, WINDOW_S = 16000, 0.5

SOURCES: dict[str, tuple[str, dict[str, Any]]] = {
    "energy fixed -40 dB": ("energy", {"threshold_mode": "fixed", "threshold_db": -40.0}),
    "energy calibrate 10 s": ("energy", {"threshold_mode": "calibrate"}),
    "energy noise_floor": ("energy", {"threshold_mode": "noise_floor"}),
    "speech_band fixed -40 dB": (
        "speech_band",
        {"threshold_mode": "fixed", "threshold_db": -40.0},
    ),
    "speech_band noise_floor": ("speech_band", {"threshold_mode": "noise_floor"}),
    "vad aggressiveness 2": ("vad", {"vad_aggressiveness": 2}),
    "vad aggressiveness 3": ("vad", {"vad_aggressiveness": 3}),
}
"""The bit sources compared: label -> (name, options); the other options are mic_node's
defaults (noise floor: 10 dB above the 10th percentile of 30 s, 10 s warm-up; VAD: 30 ms
frames, 0.1 s voiced)."""

ROOMS: dict[str, dict[str, Any]] = {
    "responsive": {},
    "silent": {},
    "noisy": {},
    "noisy+partner": {"partner_arrive_s": 0.0},
}
"""The rooms: a preset name (before any ``+``) and the fields overridden."""


def make_source(label: str) -> Any:
    """A fresh bit source of :data:`SOURCES`."""
    name, options = SOURCES[label]
    return make_bit_source(name, RATE_HZ, WINDOW_S, **options)


def room_config(room: str) -> FakeRoomConfig:
    """The fake room named in :data:`ROOMS`."""
    return FakeRoomConfig.preset(room.split("+")[0], **ROOMS[room])


def cost_us(label: str, windows: np.ndarray, repeats: int) -> float:
    """Best microseconds per window of ``push_window`` over ``windows`` (one per row)."""
    best = float("inf")
    for _ in range(repeats):
        source = make_source(label)
        started = time.perf_counter()
        for window in windows:
            source.push_window(window)
        best = min(best, (time.perf_counter() - started) / len(windows))
    return best * 1e6


def contrast(
    label: str, room: str, seeds: int, steps: int, interval: int, params: ModelParams
) -> dict[str, float]:
    """P(active) per period of the timer, over ``seeds`` runs of ``steps`` steps."""
    active = {"self": 0, "agent": 0, "background": 0}
    count = dict.fromkeys(active, 0)
    for seed in range(seeds):
        world = AudioWorld(FakeRoom(room_config(room), seed), make_source(label),
                           gap_steps=params.ta2 + 1)
        controller = FixedIntervalController(params, interval)
        for step in run_loop(world, controller, steps):
            if params.ts1 <= step.z <= params.ts2:
                period = "self"
            elif params.ta1 <= step.z <= params.ta2:
                period = "agent"
            elif step.z > params.ta2:
                period = "background"
            else:
                continue
            count[period] += 1
            active[period] += step.observation.y
    return {period: active[period] / max(1, count[period]) for period in active}


def main() -> None:
    """Print the cost table and the contrast table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10, help="runs per room (default 10)")
    parser.add_argument("--steps", type=int, default=240, help="steps per run (default 240)")
    parser.add_argument(
        "--interval", type=int, default=8, help="windows between vocalizations (default 8)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="timing passes (default 3)")
    args = parser.parse_args()
    params = ModelParams.named("robot")

    room = FakeRoom(room_config("responsive"), 0)
    windows = np.array(
        [as_transmitted(room.next_window().samples).astype(np.float64) for _ in range(200)]
    )
    print(f"# cost per {WINDOW_S} s window at {RATE_HZ} Hz ({len(windows)} windows,"
          f" best of {args.repeats})")  # fmt: skip
    print(f"{'bit source':26s} {'us/window':>10s} {'share of the window':>20s}")
    for label in SOURCES:
        us = cost_us(label, windows, args.repeats)
        print(f"{label:26s} {us:10.0f} {us / (WINDOW_S * 1e6):20.4%}")

    print(
        f"\n# P(active) by period: fixed interval {args.interval}, {args.seeds} seeds x"
        f" {args.steps} steps per room (robot: self z={params.ts1}..{params.ts2},"
        f" agent z={params.ta1}..{params.ta2}, background z>{params.ta2})"
    )
    header = f"{'room':14s} {'bit source':26s} {'self':>6s} {'agent':>6s} {'backgr':>6s}"
    print(header + f" {'agent-backgr':>12s}")
    rows: list[tuple[str, str, Callable[[], dict[str, float]]]] = [
        (room_name, label, lambda r=room_name, s=label: contrast(
            s, r, args.seeds, args.steps, args.interval, params))
        for room_name in ROOMS
        for label in SOURCES
    ]  # fmt: skip
    for room_name, label, measure in rows:
        p = measure()
        print(
            f"{room_name:14s} {label:26s} {p['self']:6.2f} {p['agent']:6.2f}"
            f" {p['background']:6.2f} {p['agent'] - p['background']:12.2f}"
        )


if __name__ == "__main__":
    main()

"""Speed of the audio rooms: synthesis per window, and runs per second of ``experiment rooms``.

For each room sound (partner present, the robot vocalizing every 6 windows), the mean
wall-clock cost of one 500-ms window of the fake room (µs per window; the speech bank is
made before timing); then one run of the experiment's loop per controller in that room
(runs/s, one process: room, energies, binarizer, controller, belief and posture).

Run from the repository root::

    .venv/bin/python bench/bench_rooms.py [--windows 240] [--runs 4]
"""

from __future__ import annotations

import argparse
import time

from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.posture import ATTENTIVE_ABOVE, BORED_BELOW
from infomax_contingency.eval.rooms import (
    CONTROLLER_NAMES,
    controller_specs,
    run_metrics,
    run_room,
)
from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.room_config import FakeRoomConfig
from infomax_contingency.sim.rooms import ROOM_SOUNDS


def window_cost_us(room: str, windows: int) -> float:
    """Mean µs per window of ``room`` (after one warm-up window)."""
    fake_room = FakeRoom(FakeRoomConfig.preset(room), seed=1)
    fake_room.next_window()
    started = time.perf_counter()
    for k in range(windows):
        fake_room.next_window()
        if k % 6 == 0:
            fake_room.vocalize()
    return (time.perf_counter() - started) / windows * 1e6


def main() -> int:
    """One line per room: µs per window, runs/s of the experiment's loop."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--windows", type=int, default=240, help="windows timed per room")
    parser.add_argument("--runs", type=int, default=4, help="60-s runs timed per room")
    parser.add_argument("--binarizer", default="fixed:-40", help="binarizer of the runs")
    args = parser.parse_args()
    params = ModelParams.named("robot")
    specs = controller_specs(params, CONTROLLER_NAMES)
    print(f"{'room':<24} {'us/window':>10} {'runs/s':>8}  (binarizer {args.binarizer})")
    for background in ROOM_SOUNDS:
        room = f"{background}+partner"
        cost = window_cost_us(room, args.windows)
        started = time.perf_counter()
        for run in range(args.runs):
            for _, spec in specs:
                result = run_room(params, room, spec, args.binarizer, 60.0, 0, run, 60)
                run_metrics(params, result, room, 60.0, ATTENTIVE_ABOVE, BORED_BELOW)
        rate = args.runs * len(specs) / (time.perf_counter() - started)
        print(f"{room:<24} {cost:>10.0f} {rate:>8.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

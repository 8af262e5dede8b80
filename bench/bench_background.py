"""The default sound-to-bit path (bit source ``background``): cost per window, printed.

Per 0.5 s window at 16 kHz: the window checked, its faults (clipping, DC offset), its
level (the energy of its 300-3400 Hz band), the threshold (the k-th loudest of the last
background windows), the bit and, after it, the decision that labels the windows
(``note_decision``): what mic_node and the offline loop spend per window. Best of
``--repeats`` passes over ``--windows`` windows of the ``office+partner`` room, a
vocalization every 6 windows.
It must stay far below the 500 000 us of the window itself. For comparison, the
``energy`` source at a fixed threshold on the same windows.

Run from the repository root::

    .venv/bin/python bench/bench_background.py [--windows 400] [--repeats 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from infomax_contingency.audio.bitsources import make_bit_source
from infomax_contingency.core.model import ModelParams
from infomax_contingency.sim.fake_room import FakeRoom, as_transmitted
from infomax_contingency.sim.room_config import FakeRoomConfig

RATE_HZ, WINDOW_S = 16000, 0.5


def room_windows(count: int) -> list[np.ndarray]:
    """``count`` windows of the office with a partner, the robot speaking every 6th."""
    room = FakeRoom(FakeRoomConfig.preset("office+partner"), seed=1)
    windows = []
    for k in range(count):
        windows.append(as_transmitted(room.next_window().samples).astype(np.float64))
        if k % 6 == 5:
            room.vocalize()
    return windows


def cost_us(name: str, options: dict, windows: list[np.ndarray], repeats: int) -> float:
    """Best microseconds per window of ``push_window`` (and ``note_decision``)."""
    params = ModelParams.named("robot")
    best = float("inf")
    for _ in range(repeats):
        source = make_bit_source(name, RATE_HZ, WINDOW_S, **options)
        if source.needs_decisions:
            source.follow_model(params)
        started = time.perf_counter()
        for k, window in enumerate(windows):
            if source.push_window(window) is not None and source.needs_decisions:
                source.note_decision(int(k % 6 == 5))
        best = min(best, (time.perf_counter() - started) / len(windows))
    return best * 1e6


def main() -> None:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--windows", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    windows = room_windows(args.windows)
    print(f"cost per {WINDOW_S} s window at {RATE_HZ} Hz ({args.windows} windows of"
          f" office+partner, best of {args.repeats})")  # fmt: skip
    for label, name, options in (
        ("background (the default)", "background", {}),
        ("energy, fixed -40 dB", "energy", {"threshold_mode": "fixed", "threshold_db": -40.0}),
    ):
        print(f"  {label:<26} {cost_us(name, options, windows, args.repeats):8.1f} us")


if __name__ == "__main__":
    main()

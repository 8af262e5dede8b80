"""A room's sound with a controller deciding, to listen to (``room-wav``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from infomax_contingency.core.controllers import default_check_in
from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.experiments.runs import experiment_controller
from infomax_contingency.eval.rooms.binarizers import make_binarizer
from infomax_contingency.eval.rooms.config import (
    CONTROLLER_NAMES,
    RoomsConfig,
    check_room_windows,
    controller_specs,
)
from infomax_contingency.eval.rooms.running import RoomTimeUpError, TimedWorld
from infomax_contingency.limits import refuse_over_budget
from infomax_contingency.sim.audio_loop import AudioWorld
from infomax_contingency.sim.fake_room import FakeRoom, RoomWindow, as_transmitted
from infomax_contingency.sim.loop import run_loop
from infomax_contingency.sim.room_config import FakeRoomConfig

LISTENING_BINARIZER = RoomsConfig.binarizer
"""``room-wav``'s default: mic_node's, the ``background`` source that calibrates itself on
the room's background windows (its first windows give no bit and no decision)."""


RENDER_BASE_BYTES = 200 * 2**20
"""Memory of :func:`render_room` apart from the sound it keeps, bytes."""

RENDER_SAMPLE_BYTES = 40
"""Memory of :func:`render_room` per sample of sound, bytes: measured 32 (peak RSS 254 MiB
for 300 s of the quiet room at 16 kHz, 693 MiB for 1,200 s: the samples kept, joined,
then converted for the wav), with a margin; 8 (float32 twice) let 24 h through the check,
which needs about 44 GB at the measured 32 bytes a sample."""


class _RecordingRoom(FakeRoom):
    """A fake room that keeps every window's samples as the ``audio`` topic carries them."""

    def __init__(self, config: FakeRoomConfig, seed: int) -> None:
        super().__init__(config, seed)
        self.recorded: list[np.ndarray] = []

    def next_window(self) -> RoomWindow:
        window = super().next_window()
        self.recorded.append(as_transmitted(window.samples))
        return window


def render_room(
    room: str,
    seconds: float,
    seed: int,
    controller: str = "optimal",
    binarizer: str = LISTENING_BINARIZER,
    params_name: str = RoomsConfig.params_name,
    cache_dir: Path | None = None,
) -> tuple[np.ndarray, list[float], int]:
    """The sound of ``room`` for ``seconds`` with a controller deciding, for listening.

    The same closed loop as a run of the experiment (``seed`` is the fake room's own
    seed, as fake_audio_node's ``seed`` parameter). ``controller`` is a name of
    :data:`CONTROLLER_NAMES` (``optimal``: controller_node's table and check-ins) or any
    controller specification of :func:`~infomax_contingency.core.controllers.make_controller`.

    Returns:
        float32 samples, the room times at which the robot's sound was commanded
        (seconds, the start of the window after each vocalizing decision), the rate (Hz).
    """
    params = ModelParams.load(params_name)
    check_room_windows(params, params_name)
    config = FakeRoomConfig.preset(room)
    if not (math.isfinite(seconds) and config.window_s <= seconds <= 24 * 3600):
        raise ValueError(f"seconds = {seconds!r}: must be at least one window, at most a day")
    if not 0 <= seed < 2**31:
        raise ValueError(f"seed = {seed!r}: must be a whole number in 0 .. 2**31 - 1")
    spec = (
        controller_specs(params, [controller], cache_dir)[0][1]
        if controller in CONTROLLER_NAMES
        else controller
    )
    windows = round(seconds / config.window_s)
    samples = windows * round(config.window_s * config.rate_hz)
    refuse_over_budget(RENDER_BASE_BYTES + RENDER_SAMPLE_BYTES * samples,
                       f"render {seconds:g} s of room sound",
                       "give fewer --seconds")
    # "optimal" is controller_node's table with its check-ins; policy:FILE the table alone
    check_in = default_check_in(params) if controller == "optimal" else None
    chosen = experiment_controller(spec, params, np.random.default_rng([seed, 1]), check_in)
    recording = _RecordingRoom(config, seed)
    bits = make_binarizer(binarizer, config.window_s, config.rate_hz, params)
    world = TimedWorld(AudioWorld(recording, bits, gap_steps=params.ta2 + 1), windows)
    actions = []
    try:
        for step in run_loop(world, chosen, None):
            if step.u and recording.windows_made < windows:  # else played after the end
                actions.append(recording.windows_made * config.window_s)
    except RoomTimeUpError:
        pass
    return np.concatenate(recording.recorded), actions, recording.rate

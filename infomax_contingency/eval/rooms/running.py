"""One run of the rooms experiment: the lockstep loop offline, bounded by room time."""

from __future__ import annotations

import dataclasses

import numpy as np

from infomax_contingency.core.controllers import CheckIn
from infomax_contingency.core.model import ModelParams, belief_from_log_odds
from infomax_contingency.eval.experiments.runs import experiment_controller
from infomax_contingency.eval.rooms.binarizers import make_binarizer
from infomax_contingency.eval.rooms.config import room_seed
from infomax_contingency.sim.audio_loop import AudioObservation, AudioWorld
from infomax_contingency.sim.fake_room import FakeRoom
from infomax_contingency.sim.loop import LoopStep, run_loop
from infomax_contingency.sim.room_config import FakeRoomConfig


class RoomTimeUpError(Exception):
    """The run's room time is over (raised by :class:`TimedWorld`)."""


class TimedWorld:
    """An :class:`AudioWorld` that ends after ``windows`` windows of room time.

    Calibration windows yield no step but do take room time, so the run is bounded by
    the room's clock, not by a number of steps.
    """

    def __init__(self, world: AudioWorld, windows: int) -> None:
        self.world = world
        self.windows = windows

    def observe(self) -> AudioObservation | None:
        """The next window's observation; :class:`RoomTimeUpError` once the time is over."""
        if self.world.room.windows_made >= self.windows:
            raise RoomTimeUpError
        return self.world.observe()

    def act(self, u: int) -> None:
        """As :meth:`AudioWorld.act`."""
        self.world.act(u)


@dataclasses.dataclass(frozen=True)
class RoomRun:
    """The steps of one run, as arrays (one entry per step).

    Attributes:
        window: room window of each step (calibration windows have no step).
        z: reporting timer during the window.
        y: the bits.
        u: the decisions.
        log_odds: log posterior odds of S=1 after the bit (natural log), with the
            belief node's memory.
        belief: P(S=1) after the bit, ``expit(log_odds)`` (as the belief node has it).
        partner: ground truth at the start of the window.
        energy_db: window energies.
    """

    window: np.ndarray
    z: np.ndarray
    y: np.ndarray
    u: np.ndarray
    log_odds: np.ndarray
    belief: np.ndarray
    partner: np.ndarray
    energy_db: np.ndarray


def run_room(
    params: ModelParams,
    room: str,
    controller_spec: str,
    binarizer: str,
    seconds: float,
    seed: int,
    run: int,
    memory: int,
    check_in: CheckIn | None = None,
) -> RoomRun:
    """One run of ``controller_spec`` in ``room`` for ``seconds`` of room time.

    ``check_in``: a policy table's check-ins (controller_node's; None: the table alone).
    """
    config = FakeRoomConfig.preset(room)
    fake_room = FakeRoom(config, room_seed(seed, room, run))
    rng = np.random.default_rng([seed, 1, run])
    controller = experiment_controller(controller_spec, params, rng, check_in)
    world = TimedWorld(
        AudioWorld(fake_room, make_binarizer(binarizer, config.window_s, config.rate_hz, params),
                   gap_steps=params.ta2 + 1),
        round(seconds / config.window_s),
    )
    steps: list[tuple[int, LoopStep[AudioObservation]]] = []
    try:
        for step in run_loop(world, controller, None, memory=memory):
            steps.append((fake_room.windows_made - 1, step))
    except RoomTimeUpError:
        pass
    log_odds = np.array([s.statistic.log_odds(params) for _, s in steps])
    return RoomRun(
        window=np.array([w for w, _ in steps], dtype=int),
        z=np.array([s.z for _, s in steps], dtype=int),
        y=np.array([s.observation.y for _, s in steps], dtype=int),
        u=np.array([s.u for _, s in steps], dtype=int),
        log_odds=log_odds,
        belief=np.array([float(belief_from_log_odds(lam)) for lam in log_odds]),
        partner=np.array([s.observation.partner_present for _, s in steps], dtype=bool),
        energy_db=np.array([s.observation.energy_db for _, s in steps]),
    )

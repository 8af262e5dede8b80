"""What the rooms experiment runs: its settings, the controllers by name, each run's room seed."""

from __future__ import annotations

import dataclasses
import math
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from infomax_contingency.core.controllers import (
    CHECK_IN_ABOVE,
    CHECK_IN_EVERY_S,
    CheckIn,
    check_check_in,
)
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import RECEDING
from infomax_contingency.core.posture import ATTENTIVE_ABOVE, BORED_BELOW
from infomax_contingency.eval.experiments.tables import obtain_table
from infomax_contingency.eval.rooms.binarizers import make_binarizer
from infomax_contingency.eval.workers import check_workers
from infomax_contingency.sim.room_config import FakeRoomConfig
from infomax_contingency.sim.rooms import (
    PARTNER_STATES,
    ROOM_CHANGE_S,
    ROOM_SOUNDS,
    audio_room_names,
)

PARTNER_STATE_NAMES: dict[str, str] = {
    "absent": PARTNER_STATES[0],
    "partner": PARTNER_STATES[1],
    "arriving": PARTNER_STATES[2],
    "leaving": PARTNER_STATES[3],
}
"""Partner states of ``RoomsConfig.partner_states`` -> suffix of the room's name."""

CONTROLLER_NAMES = ("optimal", "rule", "fixed", "random")
"""The controllers of the experiment (see :func:`controller_specs`)."""

FIXED_INTERVAL = 8
"""K of the fixed-interval controller (and 1/K of the random one): the K that detected
fastest in the efficiency experiment (docs/RESULTS.md section 6)."""


def controller_specs(
    params: ModelParams, names: Sequence[str], cache_dir: Path | None = None
) -> list[tuple[str, str]]:
    """(label, specification) of each named controller.

    ``optimal``: the receding table H = 24, M = 60 (controller_node's default);
    ``rule``: MODEL.md's rule, c = 9; ``fixed``: every :data:`FIXED_INTERVAL` steps;
    ``random``: with probability 1 / :data:`FIXED_INTERVAL` per step.
    """
    specs = []
    for name in names:
        if name == "optimal":
            _, path = obtain_table(params, RECEDING, 24, 60, cache_dir)
            specs.append(("optimal receding H=24 M=60", f"policy:{path}"))
        elif name == "rule":
            specs.append(("rule c=9", "rule:9"))
        elif name == "fixed":
            specs.append((f"fixed K={FIXED_INTERVAL}", f"fixed:{FIXED_INTERVAL}"))
        elif name == "random":
            specs.append((f"random P=1/{FIXED_INTERVAL}", f"random:{1.0 / FIXED_INTERVAL!r}"))
        else:
            raise ValueError(
                f"unknown controller {name!r}; controllers: {', '.join(CONTROLLER_NAMES)}"
            )
    return specs


@dataclasses.dataclass(frozen=True)
class RoomsConfig:
    """Size and settings of the rooms experiment.

    Attributes:
        params_name: model parameter set (the table's and the belief's).
        backgrounds: room sounds (keys of :data:`~infomax_contingency.sim.rooms.ROOM_SOUNDS`);
            each is run with the partner in each of ``partner_states``.
        partner_states: names of :data:`PARTNER_STATE_NAMES` (default all four; the
            operating curves need ``absent`` and ``partner``).
        controllers: names of :data:`CONTROLLER_NAMES`.
        binarizer: a name of :data:`BINARIZERS`.
        runs: runs per room and controller.
        seconds: room time per run, s.
        seed: master seed (a run's room seed depends on it, the room and the run number,
            not on the controller: every controller hears the same rooms).
        memory: the belief's sliding memory, steps (belief_node's ``memory_steps``).
        check_in_every_s: the optimal table's check-ins, s (controller_node's
            ``check_in_every_s``; 0 = the table alone).
        check_in_above: P(S=1) above which they apply (controller_node's
            ``check_in_above``).
        attentive_above: posture_node's upper threshold.
        bored_below: posture_node's lower threshold.
        curve_thresholds: upper thresholds of the operating curves.
        curve_priors: belief priors pi of the operating curves.
        jobs: worker processes (the results do not depend on it).
    """

    params_name: str = "robot"
    backgrounds: tuple[str, ...] = tuple(ROOM_SOUNDS)
    partner_states: tuple[str, ...] = tuple(PARTNER_STATE_NAMES)
    controllers: tuple[str, ...] = CONTROLLER_NAMES
    binarizer: str = "background"
    runs: int = 100
    seconds: float = 60.0
    seed: int = 0
    memory: int = 60
    check_in_every_s: float = CHECK_IN_EVERY_S
    check_in_above: float = CHECK_IN_ABOVE
    attentive_above: float = ATTENTIVE_ABOVE
    bored_below: float = BORED_BELOW
    curve_thresholds: tuple[float, ...] = (0.5, 0.7, 0.8, 0.9, 0.95, 0.99)
    curve_priors: tuple[float, ...] = (0.01, 0.05, 0.2, 0.5)
    jobs: int = 2

    def __post_init__(self) -> None:  # noqa: C901
        def fail(name: str, allowed: str) -> None:
            raise ValueError(
                f"experiment rooms: {name} = {getattr(self, name)!r}: must be {allowed}"
            )

        for background in self.backgrounds:
            if background not in ROOM_SOUNDS:
                known = ", ".join(ROOM_SOUNDS)
                raise ValueError(f"experiment rooms: unknown room {background!r}; rooms: {known}")
        if not self.backgrounds:
            fail("backgrounds", "at least one room")
        for name in self.partner_states:
            if name not in PARTNER_STATE_NAMES:
                fail("partner_states", f"names among {', '.join(PARTNER_STATE_NAMES)}")
        if not self.partner_states:
            fail("partner_states", "at least one partner state")
        for name in self.controllers:
            if name not in CONTROLLER_NAMES:
                fail("controllers", f"names among {', '.join(CONTROLLER_NAMES)}")
        if not self.controllers:
            fail("controllers", "at least one controller")
        make_binarizer(self.binarizer, 0.5)  # refuses a bad name now, not in a worker
        if self.runs < 1:
            fail("runs", ">= 1")
        if not (math.isfinite(self.seconds) and ROOM_CHANGE_S < self.seconds <= 3600):
            fail("seconds", f"more than the partner's change at {ROOM_CHANGE_S:g} s, at most 3600")
        if self.seed < 0:
            fail("seed", "a whole number >= 0")
        if self.memory < 0:
            fail("memory", ">= 0 steps (0: the whole history)")
        try:
            check_check_in(self.check_in_every_s, self.check_in_above)
        except ValueError as error:
            raise ValueError(f"experiment rooms: {error}") from None
        if not 0.0 <= self.bored_below < self.attentive_above <= 1.0:
            fail("attentive_above", f"in ({self.bored_below}, 1] above bored_below >= 0")
        for value in self.curve_thresholds:
            if not self.bored_below < value <= 1.0:
                fail("curve_thresholds", f"values in ({self.bored_below}, 1]")
        for value in self.curve_priors:
            if not 0.0 < value < 1.0:
                fail("curve_priors", "probabilities in (0, 1)")
        check_workers(self.jobs, "experiment rooms: --jobs")

    def check_in(self, params: ModelParams) -> CheckIn:
        """The optimal table's check-ins (controller_node's, by default)."""
        return CheckIn.from_seconds(params, self.check_in_every_s, self.check_in_above)

    def room_names(self) -> list[str]:
        """Every room of the experiment, each background in each of its partner states."""
        chosen = {PARTNER_STATE_NAMES[name] for name in self.partner_states}
        return [
            name
            for background in self.backgrounds
            for name, state in zip(audio_room_names(background), PARTNER_STATES, strict=True)
            if state in chosen
        ]


def check_room_windows(params: ModelParams, params_name: str | Path) -> None:
    """ValueError (one line) unless ``params`` step in the rooms' windows (dt 0.5 s).

    The rooms' sound comes in windows of :attr:`FakeRoomConfig.window_s`; a set of
    another dt would run its periods on them unsaid (``--params paper``: 0.8 s).
    """
    window_s = FakeRoomConfig.window_s
    if not math.isclose(params.dt, window_s):
        raise ValueError(f"--params {params_name}: dt = {params.dt:g} s, but the rooms'"
                         f" windows are {window_s:g} s: give a parameter set with dt ="
                         f" {window_s:g} (robot)")


def room_seed(seed: int, room: str, run: int) -> int:
    """The fake room's seed of run ``run`` in ``room`` (fits fake_audio_node's ``seed``)."""
    key = [seed, zlib.crc32(room.encode()), run]
    return int(np.random.SeedSequence(key).generate_state(1)[0]) & 0x7FFFFFFF

"""Simulated runs of the efficiency experiment: its rooms, controllers and per-run figures.

Rooms: drawn from the prior, named, or switching (a partner who leaves or arrives);
controllers: ``make_controller``'s specs or ``policy:FILE``; every controller runs in
every room on the same bits (:func:`simulate_rooms`, in worker processes if asked), and
:func:`run_metrics` gives each run's figures.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import Any

import numpy as np

from infomax_contingency.core import model
from infomax_contingency.core.controllers import (
    CheckIn,
    Controller,
    PolicyController,
    make_controller,
)
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import PolicyTable
from infomax_contingency.eval.workers import worker_pool
from infomax_contingency.sim.simulation import simulate
from infomax_contingency.sim.world import Room, make_room, named_room

PRIOR_ROOM_SPEC = "prior:pi=0.5"
"""Rooms drawn from the model's priors, with a partner in half of them (in expectation)."""

SWITCHES = {"leaves": ("office+partner", "office"), "arrives": ("office", "office+partner")}
"""Scenarios of a changing room: (room before, room after) the switch."""


@dataclasses.dataclass
class SwitchingRoom:
    """A room that becomes another one after ``switch_step`` steps.

    A partner arrives or leaves. It draws bits like a
    :class:`~infomax_contingency.sim.world.Room`, so
    :func:`~infomax_contingency.sim.simulation.simulate` runs it; use a fresh one per run.
    """

    name: str
    before: Room
    after: Room
    switch_step: int
    steps_drawn: int = 0

    @property
    def partner_present(self) -> bool:
        """The truth after the switch."""
        return self.after.partner_present

    def draw_bit(self, z: int, rng: np.random.Generator) -> int:
        """One window's bit at timer value z (from the room of the current step)."""
        self.steps_drawn += 1
        room = self.before if self.steps_drawn <= self.switch_step else self.after
        return room.draw_bit(z, rng)


def efficiency_room(
    params: ModelParams, spec: str, rng: np.random.Generator
) -> Room | SwitchingRoom:
    """A room of the efficiency experiment.

    ``prior[:pi=P]`` (drawn), a named room, or ``leaves@S`` / ``arrives@S`` (office with a
    partner who leaves, or arrives, after S steps).
    """
    if spec.startswith("prior"):
        return make_room(spec, params, rng)
    scenario, at, step = spec.partition("@")
    if at:
        if scenario not in SWITCHES or not step.isdigit():
            raise ValueError(f"switching room {spec!r}: use leaves@STEP or arrives@STEP")
        before, after = SWITCHES[scenario]
        return SwitchingRoom(spec, named_room(params, before), named_room(params, after), int(step))
    return named_room(params, spec)


@functools.lru_cache(maxsize=32)
def _load_table(path: str, params: ModelParams) -> PolicyTable:
    return PolicyTable.load(path, expected_params=params)


def experiment_controller(spec: str, params: ModelParams, rng: np.random.Generator,
                          check_in: CheckIn | None = None) -> Controller:
    """A controller from its spec (``make_controller``'s, or ``policy:FILE``).

    Policy tables are read once per process; ``check_in`` is given to a table's
    controller (controller_node's check-ins), ignored by the others.
    """
    kind, _, argument = spec.partition(":")
    if kind == "policy":
        return PolicyController(_load_table(argument, params), params, check_in)
    return make_controller(spec, params, rng)


def beliefs_with_memory(params: ModelParams, records: Sequence, memory: int) -> np.ndarray:
    """P(S=1) after each step of a run, from a statistic with a sliding memory of M."""
    tracker = model.StatisticTracker(params, memory=memory)
    beliefs = []
    for record in records:
        beliefs.append(tracker.observe(record.y).belief(params))
        tracker.act(record.u)
    return np.array(beliefs)


def _first(condition: np.ndarray, start: int = 0) -> int | None:
    """1-based step of the first True at or after index ``start``, or None."""
    hits = np.flatnonzero(condition[start:])
    return int(hits[0]) + start + 1 if hits.size else None


def run_metrics(
    params: ModelParams,
    records: Sequence,
    room: Room | SwitchingRoom,
    memory: int,
    checkpoints: Sequence[int],
    confident: float,
) -> dict:
    """Figures of one simulated run.

    With the whole-history belief (the same observer for every controller): whether the
    decision (belief > 0.5 iff partner) is correct at each checkpoint step, the mean
    entropy per step, the vocalizations; in a partner room the step at which P(S=1)
    first reached ``confident`` and the vocalizations before it (None: never), in an
    empty room whether it ever did (a false alarm). With ``memory`` M > 0, the same
    detection step for the robot's own belief (sliding memory M, as the belief node
    keeps it). In a switching room (own belief), if the robot was confidently right just
    before the switch: steps from the switch until the belief falls below 0.5 (partner
    left) or reaches ``confident`` (partner arrived).
    """
    beliefs = np.array([r.belief for r in records])
    actions = np.array([r.u for r in records])
    partner = room.partner_present
    own = beliefs_with_memory(params, records, memory) if memory else beliefs
    result: dict[str, Any] = {
        "correct": [bool((beliefs[n - 1] > 0.5) == partner) for n in checkpoints],
        "mean_entropy": float(np.mean([r.entropy for r in records])),
        "vocalizations": int(actions.sum()),
        "detection_step": None,
        "detection_vocalizations": None,
        "own_detection_step": None,
        "false_alarm": None,
    }
    if isinstance(room, SwitchingRoom):
        # Only runs whose robot was confidently right just before the switch measure a
        # response to it: P(S=1) >= confident before a partner leaves, <= 1 - confident
        # before one arrives.
        before = own[room.switch_step - 1]
        sure = before <= 1.0 - confident if partner else before >= confident
        after = own[room.switch_step :]
        response = _first(after >= confident) if partner else _first(after < 0.5)
        result["sure_before_switch"] = bool(sure)
        result["switch_response_steps"] = response if sure else None
    elif partner:
        step = _first(beliefs >= confident)
        result["detection_step"] = step
        result["detection_vocalizations"] = int(actions[: step - 1].sum()) if step else None
        result["own_detection_step"] = _first(own >= confident)
    else:
        result["false_alarm"] = bool(np.any(beliefs >= confident))
    return result


@dataclasses.dataclass(frozen=True)
class Entry:
    """A controller of the experiment: label, controller spec, and the robot's memory M."""

    label: str
    spec: str
    memory: int = 0


def _simulate_rooms(
    params: ModelParams,
    entries: Sequence[Entry],
    rooms: Sequence[tuple[int, str]],
    steps: int,
    seed: int,
    checkpoints: Sequence[int],
    confident: float,
) -> list[dict]:
    """Every controller in every room; a room's bits use the same seed for every controller."""
    results = []
    for index, spec in rooms:
        for entry in entries:
            room = efficiency_room(params, spec, np.random.default_rng([seed, 0, index]))
            rng = np.random.default_rng([seed, 1, index])
            controller = experiment_controller(entry.spec, params, rng)
            records = simulate(params, controller, room, steps, rng)
            metrics = run_metrics(params, records, room, entry.memory, checkpoints, confident)
            results.append(
                {
                    "room": index,
                    "spec": spec,
                    "partner": room.partner_present,
                    "controller": entry.label,
                    **metrics,
                }
            )
    return results


def simulate_rooms(
    params: ModelParams,
    entries: Sequence[Entry],
    room_specs: Sequence[str],
    steps: int,
    seed: int,
    checkpoints: Sequence[int] = (10, 20, 40),
    confident: float = 0.95,
    workers: int = 1,
) -> list[dict]:
    """Run every controller in every room, in ``workers`` processes (same results for any)."""
    rooms = list(enumerate(room_specs))
    arguments = (params, entries)
    rest = (steps, seed, checkpoints, confident)
    if workers <= 1 or len(rooms) < 2:
        return _simulate_rooms(*arguments, rooms, *rest)
    with worker_pool(workers) as pool:
        futures = [
            pool.submit(_simulate_rooms, *arguments, rooms[i::workers], *rest)
            for i in range(workers)
        ]
        rows = [row for future in futures for row in future.result()]
    order = {entry.label: position for position, entry in enumerate(entries)}
    return sorted(rows, key=lambda row: (row["room"], order[row["controller"]]))

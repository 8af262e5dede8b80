"""Offline closed loop: a controller against a simulated room, one window per step."""

from __future__ import annotations

import dataclasses

import numpy as np

from infomax_contingency.core.controllers import Controller
from infomax_contingency.core.model import ModelParams, StatisticTracker
from infomax_contingency.sim.world import Room


@dataclasses.dataclass(frozen=True)
class StepRecord:
    """One step of a run.

    Attributes:
        t: step number, from 1.
        time_s: start of the step's window, seconds from the start of the run.
        z: the timer during the window (steps since the last vocalization).
        y: the window's bit.
        u: the decision taken after it (1 = vocalize).
        belief: P(S=1) after counting y.
        entropy: entropy of S after counting y, bits.
        ratio: ``[Var(K2)/n2] / [Var(K3)/n3]`` after counting y (None where undefined).
    """

    t: int
    time_s: float
    z: int
    y: int
    u: int
    belief: float
    entropy: float
    ratio: float | None


def simulate(
    params: ModelParams,
    controller: Controller,
    room: Room,
    steps: int,
    rng: np.random.Generator,
    memory: int = 0,
) -> list[StepRecord]:
    """Run ``steps`` steps from zero counts and the timer at "long ago".

    The reported belief is that of a statistic over the whole run (``memory = 0``) or over
    the last ``memory`` counted observations; the controller keeps its own statistic.
    """
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    tracker = StatisticTracker(params, memory=memory)
    controller.reset()
    records = []
    for t in range(1, steps + 1):
        z = tracker.statistic.z
        y = room.draw_bit(z, rng)
        statistic = tracker.observe(y)
        u = controller.step(y)
        tracker.act(u)
        records.append(
            StepRecord(
                t=t,
                time_s=round((t - 1) * params.dt, 9),
                z=z,
                y=y,
                u=u,
                belief=statistic.belief(params),
                entropy=statistic.entropy(params),
                ratio=statistic.variance_ratio(params),
            )
        )
    return records

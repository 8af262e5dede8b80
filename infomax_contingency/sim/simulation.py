"""Offline closed loop: a controller against a bit-level room, one window per step.

:func:`iter_simulate` is the streaming form (a generator of :class:`StepRecord`, constant
memory in the number of steps); :func:`simulate` collects it into a list.
:class:`RunSummary` keeps the running counters a verdict needs, so a streamed run never
has to hold its records.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import NamedTuple, Protocol

import numpy as np

from infomax_contingency.core.controllers import Controller
from infomax_contingency.core.model import ModelParams, Statistic, advance_timer
from infomax_contingency.sim.loop import LoopStep, run_loop


class BitRoom(Protocol):
    """A room at the level of bits (:class:`~infomax_contingency.sim.world.Room` and kin)."""

    @property
    def partner_present(self) -> bool:
        """The true S."""
        ...

    def draw_bit(self, z: int, rng: np.random.Generator) -> int:
        """One window's bit at timer value z."""
        ...


class BitObservation(NamedTuple):
    """A bit-level room's window: just its bit."""

    y: int


class BitWorld:
    """A bit-level room as a :class:`~infomax_contingency.sim.loop.World`.

    The room answers the robot's vocalizations at delays counted by a timer (steps since
    the last vocalization, ``ta2 + 1`` meaning long ago), which this world advances with
    each decision exactly as the model does.

    Args:
        params: model parameters (the timer's periods).
        room: the room's rates per timer value.
        rng: the random stream the bits are drawn from.
    """

    def __init__(self, params: ModelParams, room: BitRoom, rng: np.random.Generator) -> None:
        self.params = params
        self.room = room
        self.rng = rng
        self.z = params.timer_long_ago

    def observe(self) -> BitObservation:
        """Draw the next window's bit at the current timer value."""
        return BitObservation(self.room.draw_bit(self.z, self.rng))

    def act(self, u: int) -> None:
        """Advance the timer: 0 after a vocalization, else one more step (up to long ago)."""
        self.z = advance_timer(self.params, self.z, u)


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


def iter_simulate(
    params: ModelParams,
    controller: Controller,
    room: BitRoom,
    steps: int,
    rng: np.random.Generator,
    memory: int = 0,
) -> Iterator[StepRecord]:
    """Yield ``steps`` steps, from zero counts and the timer at "long ago".

    The reported belief is that of a statistic over the whole run (``memory = 0``) or over
    the last ``memory`` counted observations; the controller keeps its own statistic (it
    is reset first). The bits and any randomised decisions draw from ``rng``.

    Raises:
        ValueError: ``steps < 1`` (raised at once, not at the first step).
    """
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    controller.reset()
    loop = run_loop(BitWorld(params, room, rng), controller, steps, memory=memory)
    return (step_record(params, step) for step in loop)


def step_record(params: ModelParams, step: LoopStep) -> StepRecord:
    """The :class:`StepRecord` of one step of :func:`~infomax_contingency.sim.loop.run_loop`."""
    return statistic_record(params, step.t, (step.t - 1) * params.dt, step.z,
                            int(step.observation.y), step.u, step.statistic)  # fmt: skip


def statistic_record(params: ModelParams, t: int, time_s: float, z: int, y: int, u: int,
                     statistic: Statistic) -> StepRecord:  # fmt: skip
    """The :class:`StepRecord` of step ``t`` (timer ``z`` before it) and the statistic after."""
    return StepRecord(
        t=t,
        time_s=round(time_s, 9),
        z=z,
        y=int(y),
        u=int(u),
        belief=statistic.belief(params),
        entropy=statistic.entropy(params),
        ratio=statistic.variance_ratio(params),
    )


RECORD_BYTES = 1024
"""Memory a simulated run keeps per step (its :class:`StepRecord` and what the controller
keeps), bytes: measured with tracemalloc 280 (rule) to 790 (greedy). The experiments'
cost checks count it per step of a run they hold."""


def simulate(
    params: ModelParams,
    controller: Controller,
    room: BitRoom,
    steps: int,
    rng: np.random.Generator,
    memory: int = 0,
) -> list[StepRecord]:
    """The records of :func:`iter_simulate`, as a list (:data:`RECORD_BYTES` per step)."""
    return list(iter_simulate(params, controller, room, steps, rng, memory=memory))


@dataclasses.dataclass
class RunSummary:
    """Running counters of a run, fed one :class:`StepRecord` at a time.

    Attributes:
        steps: records seen.
        vocalizations: records with u = 1.
        final_belief: P(S=1) of the last record (None before the first).
    """

    steps: int = 0
    vocalizations: int = 0
    final_belief: float | None = None

    def add(self, record: StepRecord) -> None:
        """Count one step."""
        self.steps += 1
        self.vocalizations += record.u
        self.final_belief = record.belief

    @property
    def verdict(self) -> str:
        """``partner present`` if the last belief is above 1/2, else ``no partner``.

        ``undetermined (no step)`` before the first record.
        """
        if self.final_belief is None:
            return "undetermined (no step)"
        return "partner present" if self.final_belief > 0.5 else "no partner"

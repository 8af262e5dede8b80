"""The one closed observe -> decide -> act loop of every offline simulation.

A *world* is anything with ``observe()`` (the next window's observation, or ``None`` for
a window that yields no step, e.g. while a binarizer calibrates) and ``act(u)`` (the
decision taken after the window: 1 = vocalize, played at the start of the next window).
:func:`run_loop` drives a controller against a world, one window per step, and keeps a
reporting statistic beside the controller's own: it is a generator, so a run of any
length is consumed step by step in constant memory.

The bit-level rooms (:func:`infomax_contingency.sim.simulation.simulate`) and the
audio-level fake room (:func:`infomax_contingency.sim.audio_loop.simulate_audio_loop`)
both run through it; each turns its :class:`LoopStep` into its own record type.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Generic, Protocol, TypeVar

from infomax_contingency.core.controllers import Controller
from infomax_contingency.core.model import Statistic, StatisticTracker, Withheld


class Observation(Protocol):
    """What a world reports for one window: at least its bit ``y`` (0 or 1).

    A world whose observations have a true ``withheld`` attribute reports a window the
    robot declared as its own sound, or one right after windows without a step: it is
    observed, but not counted (by the reporting statistic nor the controller's:
    :class:`~infomax_contingency.core.model.Withheld`).
    """

    @property
    def y(self) -> int:
        """The window's bit."""
        ...


ObservationT = TypeVar("ObservationT", bound=Observation, covariant=True)
StepObservationT = TypeVar("StepObservationT", bound=Observation)


class World(Protocol[ObservationT]):
    """A simulated room the loop runs against."""

    def observe(self) -> ObservationT | None:
        """The next window's observation; ``None``: the window yields no step."""
        ...

    def act(self, u: int) -> None:
        """The decision taken after the last observed window (1 = vocalize)."""
        ...


@dataclasses.dataclass(frozen=True)
class LoopStep(Generic[StepObservationT]):
    """One step of :func:`run_loop`.

    Attributes:
        t: step number, from 1.
        z: the reporting statistic's timer during the window (steps since the last
            vocalization, before counting the window's bit).
        observation: what the world reported for the window.
        statistic: the reporting statistic after counting the bit.
        u: the decision taken after the window (1 = vocalize).
    """

    t: int
    z: int
    observation: StepObservationT
    statistic: Statistic
    u: int


def run_loop(
    world: World[StepObservationT],
    controller: Controller,
    steps: int | None,
    memory: int = 0,
) -> Iterator[LoopStep[StepObservationT]]:
    """Yield ``steps`` steps (``None``: without end) of ``controller`` against ``world``.

    Per window: observe, count the bit in the reporting statistic (the whole history with
    ``memory = 0``, else a sliding memory of ``memory`` counted observations), let the
    controller count it and decide, advance the reporting timer and tell the world. The
    reporting statistic starts from zero counts and the timer "long ago"; the controller
    is used as it is (reset it first for a fresh run).
    """
    tracker = StatisticTracker(controller.params, memory=memory)
    t = 0
    while steps is None or t < steps:
        observation = world.observe()
        if observation is None:
            continue
        t += 1
        z = tracker.statistic.z
        y: int | Withheld = int(observation.y)
        if getattr(observation, "withheld", False):
            y = Withheld(bool(y))
        statistic = tracker.observe_window(y)
        u = int(controller.step(y))
        tracker.act(u)
        world.act(u)
        yield LoopStep(t, z, observation, statistic, u)

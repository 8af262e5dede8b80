"""The fake room heard through a bit source: the node graph's lockstep loop, offline.

:class:`AudioWorld` is the loop world of :func:`~infomax_contingency.sim.loop.run_loop` for
a :class:`~infomax_contingency.sim.fake_room.FakeRoom`: each window's audio goes through the
bit source as mic_node's does, and each decision back to the room; :func:`simulate_audio_loop`
runs it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from infomax_contingency.audio.bitsources import BitSource
from infomax_contingency.core.controllers import Controller
from infomax_contingency.core.selfsound import GapWithholding
from infomax_contingency.sim.fake_room import FakeRoom, as_transmitted
from infomax_contingency.sim.loop import run_loop


class AudioObservation(NamedTuple):
    """One window of the fake room as the mic node sees it.

    Attributes:
        y: the window's bit.
        energy_db: the window's energy (of the float32 samples), dB.
        partner_present: the room's ground truth at the start of the window.
        withheld: the window overlaps the robot's declared speech, or comes right after
            windows without a step: observed, not counted
            (:func:`~infomax_contingency.sim.loop.run_loop`).
    """

    y: int
    energy_db: float
    partner_present: bool
    withheld: bool = False


class AudioWorld:
    """The fake room heard through a bit source, as a loop world.

    Each window's audio is rounded to float32 as on the ``audio`` topic before the bit
    source sees it; a window the bit source spends calibrating (no bit yet) yields no
    step, as in the mic node. A vocalization is played at the start of the next window.

    Args:
        room: the simulated room.
        binarizer: a bit source of
            :func:`~infomax_contingency.audio.bitsources.make_bit_source` (its
            ``last_energy_db`` is the window's energy).
        declare_self_sound: a window that overlaps the robot's speech is withheld (as
            the graph does when fake_audio_node publishes ``self_sound``); False: it is
            evidence like any other (the robot says nothing about its own sound).
        gap_steps: the model's ``ta2 + 1``: bits right after windows without a step are
            withheld as mic_node withholds them
            (:class:`~infomax_contingency.core.selfsound.GapWithholding`).
    """

    def __init__(self, room: FakeRoom, binarizer: BitSource,
                 declare_self_sound: bool = True, *, gap_steps: int) -> None:  # fmt: skip
        self.room = room
        self.binarizer = binarizer
        self.declare_self_sound = declare_self_sound
        self.gap = GapWithholding(gap_steps)
        """Bits withheld right after windows without a step, as mic_node withholds them."""
        self._withheld = False  # the last observed window's, for the decision on it

    def observe(self) -> AudioObservation | None:
        """The next window's bit, energy and ground truth (None while calibrating)."""
        window = self.room.next_window()
        y = self.binarizer.push_window(as_transmitted(window.samples).astype(np.float64))
        energy = self.binarizer.last_energy_db
        if y is None:
            self.gap.no_step()
            return None
        after_gap = self.gap.bit()
        withheld = (self.declare_self_sound and window.robot_sound) or after_gap
        self._withheld = withheld
        return AudioObservation(int(y), energy, window.partner_present, withheld)

    def act(self, u: int) -> None:
        """Vocalize at the start of the next window if ``u`` is 1 (the bit source hears of it).

        A source that learns from the decisions also hears whether the window was withheld
        (the robot's own sound is not the room's background), as mic_node tells it.
        """
        self.gap.decided(self.gap.bits, u)
        if getattr(self.binarizer, "needs_decisions", False):
            self.binarizer.note_decision(u, self._withheld)
        if u:
            self.room.vocalize()


@dataclasses.dataclass(frozen=True)
class AudioStepRecord:
    """One step of :func:`simulate_audio_loop`.

    Attributes:
        t: step number, from 1.
        energy_db: the window's energy, dB.
        y: the window's bit.
        u: the decision taken after it (1 = vocalize).
        belief: P(S=1) after counting y.
        partner_present: the room's ground truth at the start of the window.
        withheld: y was not counted (the robot's declared speech, or right after a gap).
    """

    t: int
    energy_db: float
    y: int
    u: int
    belief: float
    partner_present: bool
    withheld: bool = False


def iter_audio_loop(
    controller: Controller,
    room: FakeRoom,
    binarizer: BitSource,
    steps: int | None,
    memory: int = 0,
    declare_self_sound: bool = True,
) -> Iterator[AudioStepRecord]:
    """The streaming form of :func:`simulate_audio_loop` (``steps = None``: without end)."""
    params = controller.params
    world = AudioWorld(room, binarizer, declare_self_sound, gap_steps=params.ta2 + 1)
    for step in run_loop(world, controller, steps, memory=memory):
        seen = step.observation
        yield AudioStepRecord(
            step.t,
            seen.energy_db,
            seen.y,
            step.u,
            step.statistic.belief(params),
            seen.partner_present,
            seen.withheld,
        )


def simulate_audio_loop(
    controller: Controller,
    room: FakeRoom,
    binarizer: BitSource,
    steps: int,
    memory: int = 0,
    declare_self_sound: bool = True,
) -> list[AudioStepRecord]:
    """The node graph's lockstep loop, offline: room -> energy -> bit -> decision -> room.

    The audio is rounded to float32 as on the ``audio`` topic, so the energies, bits,
    decisions and beliefs equal those of the graph (mic, controller and belief nodes
    against the fake audio node in lockstep) for the same seed, threshold and memory.
    Calibration windows (a binarizer without a threshold) yield no step, as in the mic node.
    Windows that overlap the robot's speech are withheld (``declare_self_sound``, as
    fake_audio_node's parameter of that name). The controller is used as it is (not reset).
    """
    return list(iter_audio_loop(controller, room, binarizer, steps, memory=memory,
                                declare_self_sound=declare_self_sound))

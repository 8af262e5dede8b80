"""Recorded sessions replayed offline: the belief computed again from the recorded steps.

A session is a bag written by recorder_node. With the recorded actions, replay joins
the recorded ``sound_step`` bits and ``vocalize_step`` decisions by step with the same
:class:`~infomax_contingency.core.stepclock.StepJoiner` and
:class:`~infomax_contingency.core.model.StatisticTracker` that belief_node runs, so the
replayed belief equals the recorded ``belief`` step for step (exactly: same code, same
inputs). Steps are windows of ``params.dt`` seconds, numbered from 1 within a stream.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from infomax_contingency.audio.bag import read_topics
from infomax_contingency.core.model import ModelParams, StatisticTracker
from infomax_contingency.core.stepclock import StepJoiner
from infomax_contingency.sim.simulation import StepRecord

SESSION_TOPICS = ("/sound_step", "/vocalize_step", "/belief", "/diagnostics")
"""Topics a replay with recorded actions reads."""


@dataclass
class RecordedSession:
    """The steps of one recorded mic stream.

    Attributes:
        bits: ``(step, bit)`` of the first stream heard, in arrival order.
        decisions: ``(step, vocalize)`` for that stream, in arrival order.
        beliefs: the recorded ``belief`` values, in arrival order.
        memory_steps: belief_node's memory (from its diagnostics; 0 = whole history).
    """

    bits: list[tuple[int, bool]]
    decisions: list[tuple[int, bool]]
    beliefs: list[float]
    memory_steps: int


def load_session(directory: Path) -> RecordedSession:
    """Read the steps of the first mic stream of a session bag.

    Raises:
        BagReadError: the bag cannot be read.
        ValueError: it holds no ``sound_step`` (nothing to replay).
    """
    topics = read_topics(directory, SESSION_TOPICS)
    steps = [list(m.data) for _, m in topics["/sound_step"]]
    if not steps:
        raise ValueError(f"the session {directory} holds no sound_step messages: nothing to"
                         " replay (was mic_node running while it was recorded?)")
    stream = steps[0][0]
    bits = [(int(s[1]), bool(s[2])) for s in steps if s[0] == stream]
    decisions = [(int(d[1]), bool(d[2])) for d in (list(m.data) for _, m in
                 topics["/vocalize_step"]) if d[0] == stream]
    beliefs = [float(m.data) for _, m in topics["/belief"]]
    return RecordedSession(bits, decisions, beliefs, _belief_memory(topics["/diagnostics"]))


def _belief_memory(diagnostics: list) -> int:
    """belief_node's ``memory_steps`` from its last diagnostics (0 if never reported)."""
    memory = 0
    for _, array in diagnostics:
        for status in array.status:
            for pair in status.values:
                if pair.key == "memory_steps" and status.name.startswith("belief_node"):
                    memory = int(pair.value)
    return memory


def replay_recorded(session: RecordedSession, params: ModelParams,
                    memory: int | None = None) -> Iterator[StepRecord]:
    """The steps of ``session`` with its recorded actions, as ``simulate --json`` rows.

    The bits and decisions are fed in the order they were recorded (a decision arrives
    after its step's bit); ``memory`` defaults to the session's.
    """
    tracker = StatisticTracker(params, memory=session.memory_steps if memory is None else
                               memory)
    out: list[StepRecord] = []

    def apply(step: int, y: bool | None, u: bool | None) -> None:
        z = tracker.statistic.z
        if y is None:
            tracker.skip_observation()
        else:
            tracker.observe(y)
        statistic = tracker.statistic
        out.append(StepRecord(
            t=step, time_s=round((step - 1) * params.dt, 9), z=z, y=int(bool(y)),
            u=int(bool(u)), belief=statistic.belief(params),
            entropy=statistic.entropy(params), ratio=statistic.variance_ratio(params),
        ))
        if u is None:
            tracker.act_unknown()
        else:
            tracker.act(u)

    joiner = StepJoiner(apply, max_pending=max(1, len(session.bits)))
    decisions = dict(session.decisions)
    for step, bit in session.bits:
        joiner.bit(step, bit)
        if step in decisions:
            joiner.decision(step, decisions[step])
        yield from out
        out.clear()

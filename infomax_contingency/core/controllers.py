"""Controllers: from the bit of each window to the decision to vocalize.

Every controller keeps its own :class:`~infomax_contingency.core.model.StatisticTracker` and
is driven by the step clock: :meth:`Controller.step` takes the bit ``y_t`` and returns
``u_t`` (1 = vocalize). Specifications for the command line:

* ``policy:FILE`` — an optimal table (episodic tables restart an episode at the horizon,
  with zero counts and the current timer; receding tables keep a sliding memory of M
  counted observations).
* ``rule[:C]`` — MODEL.md's interpretable rule, vocalize iff ``z > ta2`` and
  ``Var(K2)/n2 > C Var(K3)/n3`` (C = 9 by default; no agent data counts as infinitely
  uncertain, no background data as never worth asking).
* ``greedy`` — one-step infomax (``H = 1``).
* ``fixed:K`` — vocalize every K steps.
* ``random:P`` — vocalize with probability P.
* ``interval:MIN_S-MAX_S`` — the paper's calibration protocol: vocalize at random
  intervals drawn uniformly from MIN_S .. MAX_S seconds (rounded to whole steps of
  ``dt``, at least one step, at most :data:`MAX_INTERVAL_STEPS`), the first after one
  such interval.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from infomax_contingency.core import model
from infomax_contingency.core.model import ModelParams, Statistic, StatisticTracker, Withheld
from infomax_contingency.core.policy_table import EPISODIC, PolicyTable

CONTROLLER_KINDS = (
    "policy:FILE", "rule[:C]", "greedy", "fixed:K", "random:P", "interval:MIN_S-MAX_S"
)
MAX_INTERVAL_STEPS = 2**31 - 1
"""Longest interval of ``interval:MIN_S-MAX_S``, steps: the longest run there is (the nodes'
``max_windows``), so a longer one would never sound (and past 2^63 no draw can take it)."""


def interval_steps(params: ModelParams, min_s: float, max_s: float,
                   names: tuple[str, str] = ("MIN_S", "MAX_S")) -> tuple[int, int]:
    """The steps of ``dt`` of an interval range of ``min_s .. max_s`` seconds, checked.

    Each is rounded to whole steps, at least one. ``names``: what the message calls the
    two (the specification's ``MIN_S`` / ``MAX_S``, or a command's options).

    Raises:
        ValueError: not ``0 < min_s <= max_s`` finite, or ``max_s`` beyond
            :data:`MAX_INTERVAL_STEPS` steps (one line naming the largest allowed).
    """
    low_name, high_name = names
    if not (math.isfinite(min_s) and math.isfinite(max_s) and 0 < min_s <= max_s):
        raise ValueError(f"need 0 < {low_name} <= {high_name} seconds, got {min_s:g} .."
                         f" {max_s:g}")
    longest_s = MAX_INTERVAL_STEPS * params.dt
    if max_s > longest_s:
        raise ValueError(f"{high_name} must be at most {longest_s:g} s ({MAX_INTERVAL_STEPS:,}"
                         f" steps of {params.dt:g} s: no run is longer), got {max_s:g}")
    low = max(1, round(min_s / params.dt))
    return low, min(MAX_INTERVAL_STEPS, max(low, round(max_s / params.dt)))


def rule_decisions(
    params: ModelParams, c: float, z: Any, p2: Any, q2: Any, p3: Any, q3: Any
) -> Any:
    """Decisions of the interpretable rule, vectorised over statistics (1 = vocalize).

    Vocalize iff ``z > ta2`` and ``Var(K2)/n2 > c Var(K3)/n3``; no agent data (``n2 = 0``)
    counts as infinitely uncertain and no background data (``n3 = 0``) as never worth
    asking, like the controller.
    """
    p2, q2, p3, q3 = (np.asarray(v) for v in (p2, q2, p3, q3))
    n2, n3 = p2 + q2, p3 + q3
    var2, var3 = model.rate_variances(params, p2, q2, p3, q3)
    with np.errstate(divide="ignore", invalid="ignore"):
        asks = var2 / n2 > c * var3 / n3
    asks = np.where(n3 == 0, False, np.where(n2 == 0, True, asks))
    return (np.asarray(z) > params.ta2) & asks


class Controller:
    """Base class: owns the statistic; subclasses implement :meth:`decide`."""

    name = "controller"

    def __init__(self, params: ModelParams, memory: int = 0):
        self.params = params
        self.tracker = StatisticTracker(params, memory=memory)

    def decide(self, statistic: Statistic) -> int:
        """The decision for the current statistic (after the bit has been counted)."""
        raise NotImplementedError

    def step(self, y: int | Withheld) -> int:
        """Count bit ``y``, decide, advance the timer with the decision; returns u.

        A :class:`~infomax_contingency.core.model.Withheld` bit is not counted (the robot
        made the sound); the controller still decides on the window.
        """
        statistic = self.tracker.observe_window(y)
        u = int(self.decide(statistic))
        self.tracker.act(u)
        return u

    def missed(self, steps: int) -> None:
        """``steps`` windows passed unseen, without a decision (so without a vocalization).

        Their bits are missing and not counted (exact); the timer advances over them.
        """
        for _ in range(min(max(steps, 0), self.params.timer_long_ago)):
            self.tracker.act(0)

    def reset(self) -> None:
        """Forget the history."""
        self.tracker.reset()


CHECK_IN_EVERY_S = 4.0
"""controller_node's default longest silence, s, before it checks in with a partner it is
sure of (:class:`CheckIn`): 8 windows of 0.5 s, about the table's own spacing of questions
while it is still searching (one in 7.4 windows in the TV room)."""

CHECK_IN_ABOVE = 0.9
"""controller_node's default P(S=1) above which it checks in: posture_node's attentive
threshold, so that the check-ins begin where the robot shows it has found someone."""

CHECK_IN_MAX_S = 3600.0
"""Longest check-in interval, s (controller_node's ``check_in_every_s``, ``experiment rooms``)."""

CHECK_IN_ABOVE_RANGE = (0.5, 0.9999)
"""Allowed ``check_in_above``: a belief that favours a partner, short of certainty."""


def check_check_in(every_s: float, above: float) -> None:
    """Refuse check-in settings outside their ranges (ValueError, one line naming the value)."""
    if not (math.isfinite(every_s) and 0 <= every_s <= CHECK_IN_MAX_S):
        raise ValueError(f"check-in interval must be in [0, {CHECK_IN_MAX_S:g}] s (0: the table"
                         f" alone), got {every_s:g}")  # fmt: skip
    low, high = CHECK_IN_ABOVE_RANGE
    if not low <= above <= high:
        raise ValueError(f"check-in threshold must be in [{low:g}, {high:g}], got {above:g}")


@dataclasses.dataclass(frozen=True)
class CheckIn:
    """Keep asking a partner the belief is sure of, whatever the table says.

    The table is solved for counts that only grow, but the robot's belief forgets all
    but its last M counted windows. Sure of a partner, the table asks less (the answer
    tells it little), so the memory holds fewer questions; where a room masks the
    replies, the few heard then leave it and the belief falls back to the prior with
    the partner still there. A check-in adds a vocalization after ``every_steps`` steps
    without one, on a background window (never inside an answer's period), while
    P(S=1) > ``above``; below it the table alone decides, so a partner is found
    exactly as before. The belief stays exact: it is computed on the decisions made.

    Attributes:
        every_steps: longest silence, steps (windows of ``dt``), at least ``ta2 + 1`` (a
            check-in waits for a background window); 0 = never check in.
        above: P(S=1) above which the check-ins apply, in :data:`CHECK_IN_ABOVE_RANGE`.
    """

    every_steps: int
    above: float

    @classmethod
    def from_seconds(cls, params: ModelParams, every_s: float, above: float) -> CheckIn:
        """The check-in of ``every_s`` seconds (0 = off), rounded to whole steps.

        At least ``ta2 + 1`` steps: a check-in comes on a background window, so a shorter
        silence could never be kept (2.5 s for the robot set).
        """
        check_check_in(every_s, above)
        steps = 0 if every_s == 0 else max(params.ta2 + 1, round(every_s / params.dt))
        return cls(min(steps, MAX_INTERVAL_STEPS), float(above))

    def due(self, params: ModelParams, statistic: Statistic, silent_steps: int) -> bool:
        """Whether to vocalize now, after ``silent_steps`` steps without a vocalization."""
        return (self.every_steps > 0 and silent_steps >= self.every_steps
                and statistic.z > params.ta2 and statistic.belief(params) > self.above)


def default_check_in(params: ModelParams) -> CheckIn:
    """controller_node's check-ins by default (:data:`CHECK_IN_EVERY_S`, :data:`CHECK_IN_ABOVE`)."""
    return CheckIn.from_seconds(params, CHECK_IN_EVERY_S, CHECK_IN_ABOVE)


class PolicyController(Controller):
    """Decisions looked up in a solved :class:`PolicyTable` (and a :class:`CheckIn`, if given)."""

    def __init__(self, table: PolicyTable, params: ModelParams | None = None,
                 check_in: CheckIn | None = None):
        """Look up ``table``; keep the statistic for ``params`` (its belief).

        ``params`` default to the table's; a table is solved for one K2, so they may
        differ from its own in ``k2_per_lag`` only (ValueError otherwise). ``check_in``
        adds vocalizations to the table's while the belief is sure of a partner (None:
        the table alone).
        """
        if params is not None and params.for_table() != table.params:
            raise ValueError("the table was solved for other model parameters: "
                             + "; ".join(table.params.differences(params.for_table())))
        memory = 0 if table.mode == EPISODIC else table.memory
        super().__init__(table.params if params is None else params, memory=memory)
        self.table = table
        self.name = f"policy:{table.mode}"
        self.episode_step = 0
        self.check_in = check_in
        self.silent_steps = 0
        """Steps since the last vocalization (or since the start)."""
        self.check_ins = 0
        """Vocalizations the check-in added to the table's."""

    def step(self, y: int | Withheld) -> int:
        """As :meth:`Controller.step`; an episodic table starts a new episode at its horizon."""
        if self.table.mode == EPISODIC:
            self.episode_step += 1
            if self.episode_step >= self.table.horizon:
                z = self.tracker.statistic.z
                self.tracker.statistic = Statistic(z)
                self.episode_step = 1
        u = super().step(y)
        self.silent_steps = 0 if u else self.silent_steps + 1
        return u

    def missed(self, steps: int) -> None:
        """As :meth:`Controller.missed`; the episode clock goes on over the missed steps."""
        super().missed(steps)
        self.silent_steps += max(steps, 0)
        if self.table.mode == EPISODIC and steps > 0:
            self.episode_step = (self.episode_step + steps) % self.table.horizon

    def decide(self, statistic: Statistic) -> int:
        """Table lookup; a check-in where the table is silent and one is due."""
        step = self.episode_step if self.table.mode == EPISODIC else None
        u = self.table.action(statistic, step=step)
        if not u and self.check_in is not None and self.check_in.due(self.params, statistic,
                                                                     self.silent_steps):
            self.check_ins += 1
            return 1
        return u

    def reset(self) -> None:
        """Forget the history and start a new episode."""
        super().reset()
        self.episode_step = 0
        self.silent_steps = 0


def check_rule_constant(c: float) -> float:
    """The rule's constant ``c``, which must be a finite number > 0 (ValueError, one line)."""
    if not (c > 0 and math.isfinite(c)):
        raise ValueError(f"rule constant c must be > 0 and finite, got {c}")
    return c


class RuleController(Controller):
    """The interpretable rule with constant ``c``."""

    def __init__(self, params: ModelParams, c: float = 9.0, memory: int = 0):
        super().__init__(params, memory)
        check_rule_constant(c)
        self.c = c
        self.name = f"rule:{c:g}"

    def decide(self, statistic: Statistic) -> int:
        """Vocalize iff the timer is past the agent period and agent data is the scarcer."""
        return int(rule_decisions(self.params, self.c, statistic.z, *statistic.counts))


class GreedyController(Controller):
    """One-step infomax: the action that minimises the expected entropy of the next step."""

    name = "greedy"

    def decide(self, statistic: Statistic) -> int:
        """Compare the expected next entropy of both actions (ties: silence)."""
        silent = model.expected_next_entropy(self.params, statistic, 0)
        vocal = model.expected_next_entropy(self.params, statistic, 1)
        return int(silent - vocal > model.TIE_TOLERANCE)


class FixedIntervalController(Controller):
    """Vocalize once every ``interval`` steps (at steps interval, 2 interval, ...)."""

    def __init__(self, params: ModelParams, interval: int):
        super().__init__(params)
        if interval < 1:
            raise ValueError(f"fixed interval must be >= 1 step, got {interval}")
        self.interval = interval
        self.name = f"fixed:{interval}"
        self.count = 0

    def decide(self, statistic: Statistic) -> int:
        """Every ``interval``-th call vocalizes."""
        self.count += 1
        return int(self.count % self.interval == 0)

    def reset(self) -> None:
        """Restart the count."""
        super().reset()
        self.count = 0


class RandomController(Controller):
    """Vocalize with probability ``probability`` at every step."""

    def __init__(self, params: ModelParams, probability: float, rng: np.random.Generator):
        super().__init__(params)
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"random controller probability must be in [0, 1], got {probability}")
        self.probability = probability
        self.rng = rng
        self.name = f"random:{probability:g}"

    def decide(self, statistic: Statistic) -> int:
        """A coin flip."""
        return int(self.rng.random() < self.probability)


class RandomIntervalController(Controller):
    """Vocalize after random intervals, uniform over ``min_steps .. max_steps`` steps.

    The paper's calibration protocol (Section 6): the robot sounds at random moments
    whatever it hears, so that what follows its sounds can be measured. The interval
    from one vocalization to the next (and from the start to the first) is drawn
    uniformly from the whole numbers ``min_steps .. max_steps``.
    """

    def __init__(self, params: ModelParams, min_steps: int, max_steps: int,
                 rng: np.random.Generator) -> None:
        super().__init__(params)
        if not 1 <= min_steps <= max_steps <= MAX_INTERVAL_STEPS:
            raise ValueError(f"interval controller: need 1 <= min steps <= max steps <="
                             f" {MAX_INTERVAL_STEPS}, got {min_steps} .. {max_steps}")
        self.min_steps, self.max_steps = min_steps, max_steps
        self.rng = rng
        self.name = f"interval:{min_steps * params.dt:g}-{max_steps * params.dt:g}"
        self.wait = self._draw()

    @classmethod
    def from_seconds(cls, params: ModelParams, min_s: float, max_s: float,
                     rng: np.random.Generator) -> RandomIntervalController:
        """Intervals of ``min_s .. max_s`` seconds, rounded to steps (:func:`interval_steps`)."""
        try:
            low, high = interval_steps(params, min_s, max_s)
        except ValueError as error:
            raise ValueError(f"interval controller: {error}") from None
        return cls(params, low, high, rng)

    def _draw(self) -> int:
        return int(self.rng.integers(self.min_steps, self.max_steps + 1))

    def decide(self, statistic: Statistic) -> int:
        """Vocalize when the drawn interval has passed; then draw the next one."""
        self.wait -= 1
        if self.wait > 0:
            return 0
        self.wait = self._draw()
        return 1

    def reset(self) -> None:
        """Forget the history and draw a first interval again."""
        super().reset()
        self.wait = self._draw()


class ReplayedDecisions(Controller):
    """A controller that answers each step with a given decision (a recorded table).

    The decisions come from a recording: a session bag, an actions CSV file or a
    reference channel (``eval.sessions``); step ``t`` (from 1) is answered with
    ``decisions[t - 1]``, and 0 past their end. Missed steps move on as many decisions.
    """

    name = "recorded"

    def __init__(self, params: ModelParams, decisions: Sequence[bool], name: str = "") -> None:
        super().__init__(params)
        self.decisions = [bool(u) for u in decisions]
        self.position = 0
        self.name = name or self.name

    def decide(self, statistic: Statistic) -> int:
        """The next given decision."""
        self.position += 1
        return int(self.position <= len(self.decisions) and self.decisions[self.position - 1])

    def missed(self, steps: int) -> None:
        """As :meth:`Controller.missed`; the decisions of the missed steps are skipped."""
        super().missed(steps)
        self.position += max(steps, 0)

    def reset(self) -> None:
        """Forget the history and start again from the first decision."""
        super().reset()
        self.position = 0


def _interval_seconds(argument: str) -> tuple[float, float]:
    """``(min_s, max_s)`` of ``MIN_S-MAX_S`` (the minus of an exponent is the number's: 1e-05-6)."""
    for index, char in enumerate(argument):
        if char == "-" and index > 0 and argument[index - 1] not in "eE":
            return float(argument[:index]), float(argument[index + 1:])
    raise ValueError("interval needs MIN_S-MAX_S seconds, e.g. interval:3-6")


def make_controller(
    spec: str, params: ModelParams, rng: np.random.Generator, memory: int = 0
) -> Controller:
    """Build a controller from its specification (see the module docstring).

    ``memory`` bounds the statistic of the rule and greedy controllers (0 = unbounded).
    A policy table must have been solved for ``params``.
    """
    kind, _, argument = spec.partition(":")
    try:
        if kind == "policy":
            if not argument:
                raise ValueError("policy needs a table file: policy:FILE")
            return PolicyController(PolicyTable.load(Path(argument), expected_params=params),
                                    params)
        if kind == "rule":
            return RuleController(params, float(argument) if argument else 9.0, memory)
        if kind == "greedy" and not argument:
            return GreedyController(params, memory)
        if kind == "fixed":
            return FixedIntervalController(params, int(argument))
        if kind == "random":
            return RandomController(params, float(argument), rng)
        if kind == "interval":
            return RandomIntervalController.from_seconds(params, *_interval_seconds(argument),
                                                         rng)
    except ValueError as error:
        if "could not convert" in str(error) or "invalid literal" in str(error):
            raise ValueError(f"controller {spec!r}: bad number {argument!r}") from None
        raise
    raise ValueError(f"unknown controller {spec!r}; controllers: {', '.join(CONTROLLER_KINDS)}")

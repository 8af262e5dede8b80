"""The paper's Fig. 4 study on recorded steps: P(sensor active) against time since the sound.

Steps are windows of ``dt`` seconds. ``lag`` counts windows since the robot decided to
vocalize, with the model's timer convention (docs/MODEL.md): the window right after a
decision ``u_t = 1`` has lag 0. A trial runs from one vocalization to the next, at most
``max_lag`` windows. Rates come with 95 % Wilson intervals. A lag is *raised* when its
interval lies wholly above the background's (the windows with no vocalization in the
last ``background_from`` windows); the first run of raised lags starting at lag 0 or 1 is the
self-feedback period (ts1, ts2), the next run the agent's reply period (ta1, ta2). When the
replies begin right after the robot's own sound the two make one run: the self period is
then its longest prefix whose rates agree with the first lag's (overlapping 95 %
intervals: the robot hears itself about every time), and the reply period the rest of
that run. Replies exactly as frequent as the self-feedback cannot be told from it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

Z_95 = 1.959963984540054
"""Two-sided 95 % normal quantile."""

MIN_VOCALIZATIONS = 20
"""Fewer trials than this are too few to locate the peaks."""


def wilson(active: int, total: int) -> tuple[float, float]:
    """95 % Wilson interval of a rate ``active / total`` ((0, 1) when ``total`` is 0)."""
    if total == 0:
        return 0.0, 1.0
    p = active / total
    denominator = 1 + Z_95**2 / total
    centre = (p + Z_95**2 / (2 * total)) / denominator
    half = Z_95 * math.sqrt(p * (1 - p) / total + Z_95**2 / (4 * total**2)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


@dataclass(frozen=True)
class Rate:
    """``active`` of ``total`` windows, with its 95 % interval."""

    active: int
    total: int

    @property
    def value(self) -> float:
        """The rate (nan without windows)."""
        return self.active / self.total if self.total else float("nan")

    @property
    def interval(self) -> tuple[float, float]:
        """95 % Wilson interval."""
        return wilson(self.active, self.total)


@dataclass(frozen=True)
class Fig4Study:
    """Result of :func:`fig4_study` (periods in windows, None when not found)."""

    vocalizations: int
    by_lag: list[Rate]
    background: Rate
    self_period: tuple[int, int] | None
    agent_period: tuple[int, int] | None
    self_rate: Rate | None
    reply_rate: Rate | None

    def shortcomings(self) -> list[str]:
        """What is missing for a trustworthy calibration (empty: nothing)."""
        missing = []
        if self.vocalizations < MIN_VOCALIZATIONS:
            missing.append(
                f"only {self.vocalizations} vocalizations (at least {MIN_VOCALIZATIONS} needed):"
                " record a longer session, e.g. infomax-contingency demo --record DIR"
            )
        if self.agent_period is None:
            missing.append(
                "no reply peak: record a session in which a person answers the robot's"
                " sounds, within a few seconds of each"
            )
        return missing


def _runs(flags: Sequence[bool]) -> list[tuple[int, int]]:
    """(first, last) index of each run of True."""
    runs, start = [], None
    for index, flag in enumerate([*flags, False]):
        if flag and start is None:
            start = index
        elif not flag and start is not None:
            runs.append((start, index - 1))
            start = None
    return runs


def _pooled(rates: Sequence[Rate], period: tuple[int, int]) -> Rate:
    chosen = rates[period[0]:period[1] + 1]
    return Rate(sum(r.active for r in chosen), sum(r.total for r in chosen))


def _intervals_overlap(a: Rate, b: Rate) -> bool:
    (low_a, high_a), (low_b, high_b) = a.interval, b.interval
    return low_a <= high_b and low_b <= high_a


def _split_self_run(by_lag: Sequence[Rate], run: tuple[int, int]
                    ) -> tuple[tuple[int, int], tuple[int, int] | None]:
    """The self period and the rest of a raised run that starts at lag 0 or 1.

    A reply that begins right after the robot's own sound makes one raised run of both;
    the self period is the run's longest prefix whose rates agree with its first lag's
    (95 % intervals overlap), the rest (if any) is where the replies begin.
    """
    first, last = run
    end = first
    while end < last and _intervals_overlap(by_lag[end + 1], by_lag[first]):
        end += 1
    return (first, end), ((end + 1, last) if end < last else None)


def fig4_study(bits: Sequence[bool], decisions: Sequence[bool], max_lag: int = 20,
               background_from: int = 6) -> Fig4Study:
    """The Fig. 4 study of one run: ``bits[t]`` heard in window t, ``decisions[t]`` after it.

    Windows at lag ``background_from`` or later (or before the first vocalization) make
    the background; peaks are sought at the lags before it.
    """
    return fig4_study_of_runs([(bits, decisions)], max_lag, background_from)


def fig4_study_of_runs(runs: Sequence[tuple[Sequence[bool], Sequence[bool]]], max_lag: int = 20,
                       background_from: int = 6) -> Fig4Study:
    """:func:`fig4_study` of several runs (sessions) pooled; the lag restarts in each."""
    if not 0 < background_from <= max_lag:
        raise ValueError(f"background_from must be in 1 .. max_lag = {max_lag}, got"
                         f" {background_from}")
    active, total = [0] * max_lag, [0] * max_lag
    background = [0, 0]
    for bits, decisions in runs:
        if len(bits) != len(decisions):
            raise ValueError(
                f"{len(bits)} bits but {len(decisions)} decisions: one each per step"
            )
        lag: int | None = None
        for y, u in zip(bits, decisions, strict=True):
            if lag is not None and lag < max_lag:
                active[lag] += int(y)
                total[lag] += 1
            if lag is None or lag >= background_from:
                background[0] += int(y)
                background[1] += 1
            lag = 0 if u else (None if lag is None else lag + 1)
    by_lag = [Rate(a, n) for a, n in zip(active, total, strict=True)]
    base = Rate(*background)
    ceiling = base.interval[1]
    raised = _runs([rate.total > 0 and rate.interval[0] > ceiling
                  for rate in by_lag[:background_from]])
    self_period = raised[0] if raised and raised[0][0] <= 1 else None
    later = raised[1:] if self_period else raised
    if self_period is not None:
        self_period, reply_start = _split_self_run(by_lag, self_period)
        if reply_start is not None:
            later = [reply_start, *later]
    agent_period = later[0] if later else None
    return Fig4Study(
        vocalizations=sum(bool(u) for _, decisions in runs for u in decisions),
        by_lag=by_lag,
        background=base,
        self_period=self_period,
        agent_period=agent_period,
        self_rate=_pooled(by_lag, self_period) if self_period else None,
        reply_rate=_pooled(by_lag, agent_period) if agent_period else None,
    )


def trial_raster(runs: Sequence[tuple[Sequence[bool], Sequence[bool]]], max_lag: int = 20
                 ) -> list[list[bool]]:
    """One row per vocalization: the bits at lags 0, 1, ... until the next one (or ``max_lag``)."""
    rows: list[list[bool]] = []
    for bits, decisions in runs:
        current: list[bool] | None = None
        for y, u in zip(bits, decisions, strict=True):
            if current is not None and len(current) < max_lag:
                current.append(bool(y))
            if u:
                current = []
                rows.append(current)
    return rows

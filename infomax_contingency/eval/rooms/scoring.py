"""The figures of one run: posture, settling, final posture, bit counts, operating-curve points."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from infomax_contingency.core.model import (
    AGENT,
    BACKGROUND,
    SELF,
    ModelParams,
    belief_from_log_odds,
    period_of,
)
from infomax_contingency.core.posture import ATTENTIVE, PostureHysteresis
from infomax_contingency.eval.rooms.running import RoomRun
from infomax_contingency.sim.room_config import FakeRoomConfig
from infomax_contingency.sim.rooms import BACKGROUND_CHANGES_S, ROOM_CHANGE_S


def postures(beliefs: np.ndarray, attentive_above: float, bored_below: float) -> np.ndarray:
    """True where posture_node's rule is attentive after each belief (it starts bored)."""
    rule = PostureHysteresis(attentive_above, bored_below)
    out = np.zeros(beliefs.size, dtype=bool)
    for k, belief in enumerate(beliefs):
        rule.update(float(belief))
        out[k] = rule.posture == ATTENTIVE
    return out


def settled_step(
    attentive: np.ndarray,
    partner: np.ndarray,
    beliefs: np.ndarray,
    bored_below: float,
    first: int,
) -> int | None:
    """Index of the first step at or after ``first`` from which the posture stays correct.

    With nobody there at the end, the belief must also be below ``bored_below`` at that
    step. None if the posture is wrong at the end (or the run has no step).
    """
    if attentive.size == 0:
        return None
    wrong = np.flatnonzero(attentive != partner)
    start = max(first, int(wrong[-1]) + 1 if wrong.size else 0)
    if start >= attentive.size:
        return None
    if partner[-1]:
        return start
    sure = np.flatnonzero(beliefs[start:] < bored_below)
    return start + int(sure[0]) if sure.size else None


RECOVERY_S = 20.0
"""In a room whose background changes (:data:`~infomax_contingency.sim.rooms.BACKGROUND_CHANGES_S`),
the posture must be correct from this many seconds after the change to the end of the run."""


def change_time_s(room: str) -> float:
    """When the run's clock starts: the partner's arrival or departure, else 0."""
    state = room[room.index("+") :] if "+" in room else ""
    return ROOM_CHANGE_S if state in ("+arriving", "+leaving") else 0.0


def run_metrics(
    params: ModelParams,
    run: RoomRun,
    room: str,
    seconds: float,
    attentive_above: float,
    bored_below: float,
) -> dict[str, Any]:
    """The figures of one run (the package's docstring): settling, final posture, bit counts."""
    dt = params.dt
    attentive = postures(run.belief, attentive_above, bored_below)
    change = change_time_s(room)
    first = int(np.searchsorted(run.window * dt, change - 1e-9))
    settled = settled_step(attentive, run.partner, run.belief, bored_below, first)
    truth_at_end = FakeRoomConfig.preset(room).partner_present_at(seconds - dt)
    final_attentive = bool(attentive[-1]) if attentive.size else False
    background_change = BACKGROUND_CHANGES_S.get(room.partition("+")[0])
    correct_after_change = None
    if background_change is not None:
        late = run.window * dt >= background_change + RECOVERY_S - 1e-9
        correct_after_change = bool(np.all(attentive[late] == run.partner[late]))
    periods = period_of(params, run.z) if run.z.size else np.zeros(0, dtype=int)
    agent = (periods == AGENT) & run.partner
    background = periods == BACKGROUND
    self_period = periods == SELF
    return {
        "steps": int(run.y.size),
        "vocalizations": int(run.u.sum()),
        "settled_s": None if settled is None else (int(run.window[settled]) + 1) * dt - change,
        "settled_vocalizations": None if settled is None else int(run.u[first:settled].sum()),
        "partner_at_end": bool(truth_at_end),
        "false_attentive": bool(final_attentive and not truth_at_end),
        "missed_partner": bool(truth_at_end and not final_attentive),
        "ever_attentive": bool(attentive.any()),
        "correct_after_change": correct_after_change,
        "bits": {
            "agent": [int(run.y[agent].sum()), int(agent.sum())],
            "agent_lags": [
                [int(run.y[lag].sum()), int(lag.sum())]
                for lag in (agent & (run.z == z) for z in range(params.ta1, params.ta2 + 1))
            ],
            "background": [int(run.y[background].sum()), int(background.sum())],
            "self": [int(run.y[self_period].sum()), int(self_period.sum())],
        },
    }


def curve_points(
    params: ModelParams,
    run: RoomRun,
    room: str,
    thresholds: Sequence[float],
    priors: Sequence[float],
    bored_below: float,
) -> dict[str, list[Any]]:
    """Points of the operating curves from one run's log odds.

    Per belief prior: per threshold, the settling seconds (partner room) or whether the
    posture turned attentive at any time (empty room); the other rooms give nothing. The
    belief under another prior pi' is exact from the log odds:
    ``lam' = lam - logit(pi) + logit(pi')`` (the likelihood ratio does not depend on pi).
    """
    if room.endswith(("+arriving", "+leaving")):
        return {}
    partner = room.endswith("+partner")
    out: dict[str, list[Any]] = {}
    for pi in priors:
        beliefs = belief_from_log_odds(run.log_odds - _logit(params.pi) + _logit(pi))
        row: list[Any] = []
        for threshold in thresholds:
            attentive = postures(beliefs, threshold, bored_below)
            if partner:
                settled = settled_step(attentive, run.partner, beliefs, bored_below, 0)
                row.append(None if settled is None else (int(run.window[settled]) + 1) * params.dt)
            else:
                row.append(bool(attentive.any()))
        out[repr(pi)] = row
    return out


def _logit(p: float) -> float:
    return math.log(p) - math.log1p(-p)

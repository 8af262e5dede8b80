"""Figures of many runs with 95 % intervals: per room, operating curves, information bounds."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.experiments.summaries import bootstrap_median, wilson_interval
from infomax_contingency.eval.information import (
    MAX_CROSSING_BACKGROUND_WINDOWS,
    information_bound,
)
from infomax_contingency.eval.rooms.config import RoomsConfig


def _rate(counts: Sequence[Sequence[int]]) -> dict[str, Any]:
    active = sum(c[0] for c in counts)
    total = sum(c[1] for c in counts)
    return {
        "active": active,
        "windows": total,
        "p": active / total if total else math.nan,
        "ci": wilson_interval(active, total),
    }


def summarise_room(rows: Sequence[dict], seed: int) -> dict[str, Any]:
    """Figures with 95 % intervals of one controller in one room.

    Medians count runs that never settled as infinite (percentile-bootstrap interval,
    2,000 resamples); proportions have Wilson intervals.
    """
    rng = np.random.default_rng(seed)
    n = len(rows)
    seconds = np.array([math.inf if r["settled_s"] is None else r["settled_s"] for r in rows])
    vocalizations = np.array(
        [
            math.inf if r["settled_vocalizations"] is None else r["settled_vocalizations"]
            for r in rows
        ]
    )
    settled = int(np.isfinite(seconds).sum())
    ever = sum(r.get("ever_attentive", False) for r in rows)
    after_change = [
        r["correct_after_change"] for r in rows if r.get("correct_after_change") is not None
    ]
    false_attentive = sum(r["false_attentive"] for r in rows)
    missed = sum(r["missed_partner"] for r in rows)
    median_s, ci_s = bootstrap_median(seconds, rng)
    median_v, ci_v = bootstrap_median(vocalizations, rng)
    return {
        "runs": n,
        "settled": settled / n,
        "settled_ci": wilson_interval(settled, n),
        "settled_s_median": median_s,
        "settled_s_ci": ci_s,
        "settled_vocalizations_median": median_v,
        "settled_vocalizations_ci": ci_v,
        "wrong_at_end": (false_attentive + missed) / n,
        "wrong_at_end_ci": wilson_interval(false_attentive + missed, n),
        "false_attentive": false_attentive / n,
        "missed_partner": missed / n,
        "ever_attentive": ever / n,
        "ever_attentive_ci": wilson_interval(ever, n),
        "correct_after_change": sum(after_change) / len(after_change) if after_change else None,
        "correct_after_change_ci": wilson_interval(sum(after_change), len(after_change))
        if after_change
        else None,
        "vocalizations_per_run": float(np.mean([r["vocalizations"] for r in rows])),
        "steps_per_run": float(np.mean([r["steps"] for r in rows])),
        "p_active": {
            period: _rate([r["bits"][period] for r in rows])
            for period in ("agent", "background", "self")
        },
        "p_active_agent_lags": [
            _rate([r["bits"]["agent_lags"][lag] for r in rows])
            for lag in range(len(rows[0]["bits"]["agent_lags"]))
        ],
    }


def operating_curves(config: RoomsConfig, rows: Sequence[dict], label: str) -> dict[str, Any]:
    """Per background and belief prior: (threshold, median settling s, false-alarm share)."""
    rng = np.random.default_rng(config.seed)
    curves: dict[str, Any] = {}
    for background in config.backgrounds:
        partner = [
            r for r in rows if r["controller"] == label and r["room"] == f"{background}+partner"
        ]
        empty = [r for r in rows if r["controller"] == label and r["room"] == background]
        per_prior = {}
        for pi in config.curve_priors:
            points = []
            for k, threshold in enumerate(config.curve_thresholds):
                seconds = np.array(
                    [
                        math.inf if r["curve"][repr(pi)][k] is None else r["curve"][repr(pi)][k]
                        for r in partner
                    ]
                )
                alarms = sum(bool(r["curve"][repr(pi)][k]) for r in empty)
                median, ci = bootstrap_median(seconds, rng)
                points.append(
                    {
                        "attentive_above": threshold,
                        "settled_s_median": median,
                        "settled_s_ci": ci,
                        "detected": float(np.isfinite(seconds).mean())
                        if seconds.size
                        else math.nan,
                        "false_alarm": alarms / len(empty) if empty else math.nan,
                        "false_alarm_ci": wilson_interval(alarms, len(empty)),
                    }
                )
            per_prior[repr(pi)] = points
        curves[background] = per_prior
    return curves


def contrast_bounds(
    params: ModelParams, summaries: dict[str, dict[str, Any]], config: RoomsConfig
) -> dict[str, Any]:
    """Per background with a ``+partner`` room: the information bound of its bit contrast.

    P(active) in agent-period (pooled, and per lag) and background windows of the
    ``+partner`` runs (:func:`~infomax_contingency.eval.information.information_bound`, to
    the posture's ``attentive_above`` from the model's prior), and the model's own belief
    (one K2 per lag where ``params`` say so) on independent bits at those rates, with the
    runs' background windows per vocalization (rounded).
    """
    out: dict[str, Any] = {}
    for background in config.backgrounds:
        summary = summaries.get(f"{background}+partner")
        if summary is None:
            continue
        rates = summary["p_active"]
        if not (rates["agent"]["windows"] and rates["background"]["windows"]):
            continue
        vocalizations = summary["vocalizations_per_run"] * summary["runs"]
        per_vocalization = rates["background"]["windows"] / max(vocalizations, 1.0)
        lags = [lag["p"] for lag in summary["p_active_agent_lags"]]
        out[background] = information_bound(
            rates["agent"]["p"],
            rates["background"]["p"],
            params,
            config.attentive_above,
            background_windows=min(round(per_vocalization), MAX_CROSSING_BACKGROUND_WINDOWS),
            p_agent_lags=lags if all(lag["windows"] for lag in summary["p_active_agent_lags"])
            else None,
        )
    return out

"""Figures of a group of runs with 95 % intervals (Wilson, normal, bootstrap, prior-weighted)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np


def wilson_interval(successes: int, total: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion."""
    if total == 0:
        return (math.nan, math.nan)
    p = successes / total
    centre = (p + z * z / (2 * total)) / (1 + z * z / total)
    half = z * math.sqrt(p * (1 - p) / total + z * z / (4 * total * total)) / (1 + z * z / total)
    return (max(0.0, centre - half), min(1.0, centre + half))


def mean_interval(values: np.ndarray) -> tuple[float, tuple[float, float]]:
    """Mean and its 95 % normal-approximation interval."""
    if values.size == 0:
        return (math.nan, (math.nan, math.nan))
    mean = float(values.mean())
    half = 1.96 * float(values.std(ddof=1)) / math.sqrt(values.size) if values.size > 1 else 0.0
    return (mean, (mean - half, mean + half))


def bootstrap_median(
    values: np.ndarray, rng: np.random.Generator, resamples: int = 2000
) -> tuple[float, tuple[float, float]]:
    """Median and its 95 % percentile-bootstrap interval (``inf`` entries: censored runs)."""
    if values.size == 0:
        return (math.nan, (math.nan, math.nan))
    draws = rng.integers(0, values.size, size=(resamples, values.size))
    medians = np.median(values[draws], axis=1)
    low = float(np.percentile(medians, 2.5, method="lower"))
    high = float(np.percentile(medians, 97.5, method="higher"))
    return (float(np.median(values)), (low, high))


def prior_weighted_entropy(rows: Sequence[dict], pi: float) -> tuple[float, tuple[float, float]]:
    """Mean entropy per step in rooms drawn from the prior with P(partner) = pi, and its 95 % CI.

    The rooms were drawn with a partner in about half of them; given the partner (or its
    absence) they follow the prior, so the expectation under the model's own prior is
    ``pi * mean(partner rooms) + (1 - pi) * mean(empty rooms)``: the quantity an infomax
    controller minimises.
    """
    groups = [
        np.array([row["mean_entropy"] for row in rows if row["partner"] == present])
        for present in (True, False)
    ]
    if any(group.size < 2 for group in groups):
        raise ValueError(
            "need at least two prior rooms with and two without a partner (use more prior rooms)"
        )
    weights = (pi, 1.0 - pi)
    mean = sum(w * g.mean() for w, g in zip(weights, groups, strict=True))
    half = 1.96 * math.sqrt(
        sum(w * w * g.var(ddof=1) / g.size for w, g in zip(weights, groups, strict=True))
    )
    return float(mean), (float(mean - half), float(mean + half))


def paired_entropy_difference(
    rows: Sequence[dict], reference: Sequence[dict], pi: float
) -> tuple[float, tuple[float, float]]:
    """Prior-weighted mean entropy per step minus a reference controller's, in the same rooms.

    Pairing each room with itself removes the spread between rooms (their rates), so the
    95 % interval is much narrower than the difference of two separate intervals.
    """
    by_room = {row["room"]: row for row in reference}
    paired = [
        {
            "partner": row["partner"],
            "mean_entropy": row["mean_entropy"] - by_room[row["room"]]["mean_entropy"],
        }
        for row in rows
    ]
    return prior_weighted_entropy(paired, pi)


def steps_to_seconds(steps: Sequence[int | None], dt: float) -> np.ndarray:
    """Steps as seconds (``step * dt``); None (never reached) as ``inf``."""
    return np.array([math.inf if s is None else s * dt for s in steps], dtype=float)


def detection_figures(
    partner: Sequence[dict], dt: float, steps: int, rng: np.random.Generator
) -> dict[str, Any]:
    """How fast the runs of partner rooms reached a confident belief, with 95 % intervals.

    For the whole-history belief (``detection_*``) and the robot's own (``own_detection_*``):
    the share detected, the median seconds and the restricted mean (censored at the run's
    length); the median vocalizations before detection.
    """
    summary: dict[str, Any] = {}
    for prefix, key in (("", "detection_step"), ("own_", "own_detection_step")):
        seconds = steps_to_seconds([row[key] for row in partner], dt)
        detected = int(np.isfinite(seconds).sum())
        summary[f"{prefix}detected"] = detected / len(partner)
        summary[f"{prefix}detected_ci"] = wilson_interval(detected, len(partner))
        summary[f"{prefix}detection_s_median"], summary[f"{prefix}detection_s_ci"] = (
            bootstrap_median(seconds, rng)
        )
        (
            summary[f"{prefix}detection_s_restricted_mean"],
            summary[f"{prefix}detection_s_restricted_mean_ci"],
        ) = mean_interval(np.minimum(seconds, steps * dt))
    vocalizations = np.array(
        [
            math.inf if row["detection_step"] is None else row["detection_vocalizations"]
            for row in partner
        ],
        dtype=float,
    )
    summary["detection_vocalizations_median"], summary["detection_vocalizations_ci"] = (
        bootstrap_median(vocalizations, rng)
    )
    return summary


def summarise(
    rows: Sequence[dict], dt: float, steps: int, checkpoints: Sequence[int], seed: int
) -> dict:
    """Figures with 95 % intervals for one controller in one group of rooms.

    Detection times are seconds from the start of the run to the end of the window at
    which the belief first reached the confidence level; runs that never reached it are
    censored: they count as infinite in the median and as the run's length in the
    restricted mean.
    """
    n = len(rows)
    summary: dict[str, Any] = {"runs": n}
    rng = np.random.default_rng(seed)
    for position, step in enumerate(checkpoints):
        correct = sum(row["correct"][position] for row in rows)
        summary[f"accuracy_{step}"] = correct / n if n else math.nan
        summary[f"accuracy_{step}_ci"] = wilson_interval(correct, n)
    summary["mean_entropy"], summary["mean_entropy_ci"] = mean_interval(
        np.array([row["mean_entropy"] for row in rows])
    )
    summary["vocalizations_per_run"] = float(np.mean([row["vocalizations"] for row in rows]))
    partner = [row for row in rows if row["partner"]]
    switching = [row for row in rows if "@" in row["spec"] and row["sure_before_switch"]]
    if any("@" in row["spec"] for row in rows):
        summary["sure_before_switch"] = len(switching) / n
        seconds = steps_to_seconds([row["switch_response_steps"] for row in switching], dt)
        summary["switch_response_s_median"], summary["switch_response_s_ci"] = bootstrap_median(
            seconds, rng
        )
        responded = int(np.isfinite(seconds).sum())
        summary["switch_responded"] = responded / len(switching) if switching else math.nan
        summary["switch_responded_ci"] = wilson_interval(responded, len(switching))
        return summary
    if partner:
        summary.update(detection_figures(partner, dt, steps, rng))
    empty = [row for row in rows if not row["partner"]]
    if empty:
        alarms = sum(bool(row["false_alarm"]) for row in empty)
        summary["false_alarm_rate"] = alarms / len(empty)
        summary["false_alarm_ci"] = wilson_interval(alarms, len(empty))
    return summary

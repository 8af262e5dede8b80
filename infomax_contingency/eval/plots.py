"""Figures (PNG) of sessions, learning curves, horizons and the efficiency comparison.

matplotlib is imported only when a figure is drawn, and only its object-oriented API
(``matplotlib.figure.Figure`` rendered by the Agg canvas) is used: no display, no pyplot
state, and the rest of the package never needs matplotlib.

A *session* is a list of per-step records with the fields of
:class:`~infomax_contingency.sim.simulation.StepRecord` (``t, time_s, z, y, u, belief,
entropy, ratio``), from :func:`~infomax_contingency.sim.simulation.simulate` or read from the
JSON-lines output of ``infomax-contingency simulate --json``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from infomax_contingency.core.model import AGENT, SELF, ModelParams, StatisticTracker, period_of
from infomax_contingency.limits import (
    bracket_depth,
    finite,
    read_text_capped,
    short_repr,
    written_atomically,
)

SESSION_FIELDS = ("t", "time_s", "z", "y", "u", "belief", "entropy", "ratio")
DPI = 100
MAX_SESSION_FILE_BYTES = 64 << 20
"""Largest JSON-lines session read, bytes: 500,000 steps of ``simulate --json`` (133 bytes
each), more than a plot of them fits in memory (16 KiB per step)."""


MAX_SESSION_LINE_DEPTH = 8
"""Deepest nesting of ``[`` / ``{`` on a session line (a step record is one flat object:
1): a deeper line is refused before the JSON parser, which recursed past Python's limit
on 100,000 ``[``."""


class PlotError(ValueError):
    """A figure that cannot be drawn: bad input file, or matplotlib missing."""


def _figure(width: float, height: float) -> Any:
    """A new figure (matplotlib imported here, on first use)."""
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise PlotError(
            "figures need matplotlib: install it (`pip install matplotlib`, or the"
            " python3-matplotlib system package)"
        ) from None
    return Figure(figsize=(width, height), dpi=DPI, layout="constrained")


def drawable_text(text: str) -> str:
    """``text`` with every lone surrogate replaced by U+FFFD, which a font can draw.

    Python escapes each byte of a file name or an argument that is not UTF-8 as a lone
    surrogate (``surrogateescape``); the renderer cannot draw one.
    """
    return "".join("\ufffd" if "\ud800" <= char <= "\udfff" else char for char in text)


def _save(figure: Any, path: str | Path) -> Path:
    """Write ``figure`` as a PNG file, whole, where nothing or a regular file is.

    Every text of the figure is made drawable first (:func:`drawable_text`): a title from
    a non-UTF-8 file name or ``--title`` made the renderer raise a TypeError.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise PlotError(f"figure file {path} must end in .png")
    from matplotlib.text import Text  # loaded with the figure already

    for artist in figure.findobj(Text):
        artist.set_text(drawable_text(artist.get_text()))
    with written_atomically(path, "figure file", make_parents=True) as stream:
        figure.savefig(stream, format="png", dpi=DPI)
    return path


# --------------------------------------------------------------------------------------
# Sessions


def read_session(path: str | Path) -> list[dict]:
    """Read a JSON-lines session (``simulate --json``); errors name the line and the field.

    A regular file of at most :data:`MAX_SESSION_FILE_BYTES` (``limits.read_text_capped``:
    a device or FIFO is refused before it is read).
    """
    path = Path(path)
    try:
        lines = read_text_capped(path, "session file", MAX_SESSION_FILE_BYTES).splitlines()
    except FileNotFoundError:
        raise PlotError(f"session file {path} does not exist") from None
    except ValueError as error:
        raise PlotError(str(error)) from None
    records: list[dict] = []
    for number, line in enumerate(lines, start=1):
        if not line.strip() or line.startswith("#"):
            continue
        depth = bracket_depth(line)
        if depth > MAX_SESSION_LINE_DEPTH:
            raise PlotError(f"{path} line {number} is nested {depth:,} deep: not a step record"
                            " (one flat JSON object per line, as `infomax-contingency simulate"
                            " --json` writes)")
        try:
            record = json.loads(line)
        except json.JSONDecodeError as error:
            raise PlotError(
                f"{path} line {number} is not JSON ({error.msg}); expected one object per"
                " line as written by `infomax-contingency simulate --json`"
            ) from None
        if not isinstance(record, dict):
            raise PlotError(f"{path} line {number}: expected a JSON object, got"
                            f" {short_repr(record, 40)}")
        missing = [field for field in SESSION_FIELDS if field not in record]
        if missing:
            raise PlotError(f"{path} line {number} lacks the field(s) {missing}")
        _check_record(record, records[-1] if records else None, f"{path} line {number}")
        records.append(record)
    if not records:
        raise PlotError(f"session file {path} holds no step records")
    return records


def _whole(value: Any) -> bool:
    """A JSON whole number: an integer, or a number with no fraction (not true / false)."""
    if isinstance(value, bool):
        return False
    return isinstance(value, int) or (isinstance(value, float) and value.is_integer())


def _finite(value: Any) -> bool:
    """A finite JSON number (not true / false, NaN, infinity or an int beyond a float)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    return finite(value)


LATEST_TIME_S = 1e9
"""Latest ``time_s`` of a step record drawn, s (some 30 years: beyond, a figure's axis is
no time line)."""


SESSION_FIELD_RULES: dict[str, tuple[Any, str]] = {
    "t": (_whole, "a whole number"),
    "time_s": (lambda v: _finite(v) and 0 <= v <= LATEST_TIME_S,
               f"a number of seconds in [0, {LATEST_TIME_S:g}]"),
    "z": (lambda v: _whole(v) and v >= 0, "a whole number >= 0"),
    "y": (lambda v: _whole(v) and v in (0, 1), "0 or 1"),
    "u": (lambda v: _whole(v) and v in (0, 1), "0 or 1"),
    "belief": (lambda v: _finite(v) and 0 <= v <= 1, "a finite number in [0, 1]"),
    "ratio": (lambda v: v is None or (isinstance(v, int | float) and not isinstance(v, bool)),
              "null or a number"),
}
"""What each field of a step record drawn must hold: (test, what it says when it fails)."""


def _check_record(record: dict, previous: dict | None, where: str) -> None:
    """Refuse a step record whose fields the figure cannot be drawn from (one line).

    ``previous``: the step record before (None for the first); ``t`` and ``time_s`` must
    grow (a time that goes back drew the figure over itself).
    """
    for field, (test, allowed) in SESSION_FIELD_RULES.items():
        if not test(record[field]):
            raise PlotError(f"{where}: {field} must be {allowed}, got"
                            f" {short_repr(record[field], 40)}")
    if previous is None:
        return
    if not record["t"] > previous["t"]:
        raise PlotError(f"{where}: t {record['t']} does not come after the previous step's"
                        f" {previous['t']} (t must increase, each step once)")
    if not record["time_s"] > previous["time_s"]:
        raise PlotError(f"{where}: time_s {record['time_s']:g} does not come after the previous"
                        f" step's {previous['time_s']:g} s (time must increase)")


def session_counts(params: ModelParams, records: Sequence[dict], memory: int = 0) -> np.ndarray:
    """Counts ``(p2, q2, p3, q3)`` after each step, replayed from the records' z, y and u.

    A step numbered no higher than the one before begins a new stream (a restarted
    mic_node, as a session's replay has it): the timer is forgotten there, as the replay
    and belief_node forget it (counts kept).

    Raises :class:`PlotError` when a record's timer disagrees with the replay (the session
    was recorded with other parameters, or steps are missing).
    """
    first = records[0]
    if not 0 <= first["z"] <= params.timer_long_ago:
        raise PlotError(f"step t={first['t']}: the record's timer z={first['z']} is not one of"
                        f" the parameters' 0 .. {params.timer_long_ago} (use --params)")
    tracker = StatisticTracker(params, memory=memory, z_initial=int(first["z"]))
    counts, previous_t = [], first["t"] - 1
    for record in records:
        if record["t"] <= previous_t:  # a new stream (a restarted mic_node), numbered anew:
            tracker.forget_timer()  # as belief_node and the replay follow it
        previous_t = record["t"]
        if tracker.statistic.z != record["z"]:
            raise PlotError(
                f"step t={record['t']}: the record's timer z={record['z']} differs from the"
                f" replayed {tracker.statistic.z}; were the session's parameters"
                f" {params.to_dict()} (use --params) and are all steps present?"
            )
        tracker.observe(int(record["y"]))
        counts.append(tracker.statistic.counts)
        tracker.act(int(record["u"]))
    return np.array(counts)


def plot_session(
    params: ModelParams,
    records: Sequence[dict],
    path: str | Path,
    title: str = "",
    memory: int = 0,
    rule_c: float = 9.0,
) -> Path:
    """Write :func:`session_figure` to a PNG file; returns its path."""
    return _save(session_figure(params, records, title, memory, rule_c), path)


def _session_arrays(params: ModelParams, records: Sequence[dict]) -> dict[str, np.ndarray]:
    """The columns a session figure draws: window start/end (s), bits, vocalizations, ...

    ``end`` is where a step's belief and a vocalization are drawn (the end of the window,
    where the sound is played); ``ratio`` is nan where undefined.
    """
    start = np.array([r["time_s"] for r in records], dtype=float)
    return {
        "start": start,
        "end": start + params.dt,
        "bits": np.array([r["y"] for r in records], dtype=bool),
        "vocal": np.array([r["u"] for r in records], dtype=bool),
        "periods": np.array([period_of(params, int(r["z"])) for r in records]),
        "belief": np.array([r["belief"] for r in records], dtype=float),
        "ratio": np.array(
            [np.nan if r["ratio"] is None else r["ratio"] for r in records], dtype=float
        ),
    }


def _draw_raster(axis: Any, columns: dict[str, np.ndarray], dt: float, title: str) -> None:
    """Panel 1: the windows' bits and the vocalizations, agent and self windows shaded."""
    start, periods = columns["start"], columns["periods"]
    for mask, colour, label in (
        (periods == AGENT, "#cfe8cf", "agent period"),
        (periods == SELF, "#e4e4e4", "self-feedback"),
    ):
        axis.bar(start[mask], 2.6, width=dt, bottom=-0.3, align="edge", color=colour, label=label)
    axis.bar(
        start[columns["bits"]],
        0.8,
        width=dt * 0.9,
        bottom=0.1,
        align="edge",
        color="black",
        label="sound bit = 1",
    )
    axis.vlines(
        columns["end"][columns["vocal"]],
        1.2,
        2.2,
        color="tab:red",
        linewidth=2,
        label="vocalization",
    )
    axis.set_yticks([0.5, 1.7], ["sound", "robot"])
    axis.set_ylim(-0.3, 2.3)
    axis.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    # the user's title as written: matplotlib's mathtext would parse $...$ (and recurse
    # without bound on a deeply nested one)
    axis.set_title(title or f"session: {len(start)} windows of {dt:g} s", fontsize=10,
                   parse_math=False)  # fmt: skip


def _draw_belief(axis: Any, columns: dict[str, np.ndarray]) -> None:
    """Panel 2: P(S=1) after each window, with the 0.5 and 0.95 levels."""
    axis.step(columns["end"], columns["belief"], where="post", color="tab:blue")
    axis.axhline(0.5, color="grey", linestyle=":", linewidth=1)
    axis.axhline(0.95, color="grey", linestyle="--", linewidth=1)
    axis.set_ylim(-0.02, 1.02)
    axis.set_ylabel("P(S=1)")


def _draw_rate_posteriors(
    rates: Any, densities: Any, params: ModelParams, counts: np.ndarray, end: np.ndarray
) -> None:
    """Panel 3: mean and 90 % band of K2 and K3 under S=1; their final densities sideways."""
    from scipy import stats

    p2, q2, p3, q3 = counts.T
    grid_k = np.linspace(0.0, 1.0, 401)
    for ones, zeros, a, b, colour, name in (
        (p2, q2, params.b21, params.b22, "tab:green", "K2 (agent)"),
        (p3, q3, params.b31, params.b32, "tab:purple", "K3 (background)"),
    ):
        alpha, beta = a + ones, b + zeros
        rates.step(end, alpha / (alpha + beta), where="post", color=colour, label=name)
        low, high = stats.beta.ppf([[0.05], [0.95]], alpha, beta)
        rates.fill_between(end, low, high, step="post", color=colour, alpha=0.2, linewidth=0)
        density = stats.beta.pdf(grid_k, alpha[-1], beta[-1])
        densities.plot(density, grid_k, color=colour)
        densities.fill_betweenx(grid_k, 0, density, color=colour, alpha=0.2)
    rates.set_ylim(0.0, 1.0)
    rates.set_ylabel("rate | S=1")
    rates.legend(loc="upper left", fontsize=8)
    densities.set_title("at the end", fontsize=9)
    densities.set_xlabel("density")
    densities.tick_params(labelleft=False)


def _draw_variance_ratio(axis: Any, columns: dict[str, np.ndarray], rule_c: float) -> None:
    """Panel 4: the variance ratio (log scale where defined), vocalizations and c."""
    end, ratio, vocal = columns["end"], columns["ratio"], columns["vocal"]
    axis.step(end, ratio, where="post", color="tab:orange")
    axis.plot(end[vocal], ratio[vocal], "v", color="tab:red", markersize=5)
    axis.axhline(rule_c, color="grey", linestyle="--", linewidth=1, label=f"c = {rule_c:g}")
    if np.isfinite(ratio).any():
        axis.set_yscale("log")
    axis.set_ylabel("var. ratio")
    axis.legend(loc="upper left", fontsize=8)
    axis.set_xlabel("time (s)")
    axis.set_xlim(0.0, end[-1])


def session_figure(
    params: ModelParams,
    records: Sequence[dict],
    title: str = "",
    memory: int = 0,
    rule_c: float = 9.0,
) -> Any:
    """Four panels over time, plus the end-of-session densities (a matplotlib Figure).

    Panels sharing the time axis (seconds): (1) raster of the windows' bits and of the
    vocalizations (drawn where the sound is played, at the start of the next window),
    with the agent-period windows shaded; (2) the belief P(S=1); (3) posterior mean and
    90 % band of K2 and K3 under S=1, with their densities at the end drawn sideways on
    the right; (4) the variance ratio ``[Var(K2)/n2] / [Var(K3)/n3]`` (log scale) with the
    rule's constant c.
    """
    counts = session_counts(params, records, memory)
    columns = _session_arrays(params, records)
    figure = _figure(9.0, 8.0)
    grid = figure.add_gridspec(4, 2, width_ratios=(6, 1), height_ratios=(1.0, 1.3, 1.6, 1.3))
    raster = figure.add_subplot(grid[0, 0])
    belief_axis = figure.add_subplot(grid[1, 0], sharex=raster)
    rates = figure.add_subplot(grid[2, 0], sharex=raster)
    ratio_axis = figure.add_subplot(grid[3, 0], sharex=raster)
    densities = figure.add_subplot(grid[2, 1], sharey=rates)
    _draw_raster(raster, columns, params.dt, title)
    _draw_belief(belief_axis, columns)
    _draw_rate_posteriors(rates, densities, params, counts, columns["end"])
    _draw_variance_ratio(ratio_axis, columns, rule_c)
    for axis in (raster, belief_axis, rates):
        axis.tick_params(labelbottom=False)
    return figure


# --------------------------------------------------------------------------------------
# Learning curves, horizons, efficiency


def plot_learning_curves(curves: Sequence[dict], path: str | Path, target: float = 0.995) -> Path:
    """Score of the learned policy against vocalizations, one line per curve.

    Each curve is a :meth:`~infomax_contingency.core.learning.LearningCurve.to_dict` record.
    """
    figure = _figure(7.5, 4.2)
    axis = figure.add_subplot()
    colours = {}
    for curve in curves:
        label = curve["method"]
        first = label not in colours
        colour = colours.setdefault(label, f"C{len(colours)}")
        x = np.maximum(np.array(curve["vocalizations"], dtype=float), 1.0)
        axis.plot(
            x,
            curve["scores"],
            color=colour,
            linewidth=1.2 if first else 0.6,
            alpha=1.0 if first else 0.5,
            label=f"{label}" if first else None,
        )
    axis.axhline(target, color="grey", linestyle="--", linewidth=1, label=f"target {target:g}")
    axis.axvline(60_000, color="grey", linestyle=":", linewidth=1, label="60,000 vocalizations")
    axis.set_xscale("log")
    axis.set_ylim(min(0.0, *(min(c["scores"]) for c in curves)) - 0.02, 1.02)
    axis.set_xlabel("vocalizations made while learning (log scale; the start is drawn at 1)")
    axis.set_ylabel("score (0 = never vocalize, 1 = optimal)")
    horizons = sorted({c["horizon"] for c in curves})
    axis.set_title(f"infomax TD learning, T = {', '.join(map(str, horizons))}", fontsize=10)
    axis.legend(fontsize=8, loc="lower right")
    return _save(figure, path)


def plot_horizon_maps(result: dict, path: str | Path, params_name: str | None = None) -> Path:
    """Action maps at the timer "long ago" for each listed horizon (experiment_horizon)."""
    sets = {entry["params"]: entry for entry in result["sets"]}
    name = params_name or next(iter(sets))
    entry = sets[name]
    horizons = entry["horizons"]
    columns = min(3, len(horizons))
    rows = math.ceil(len(horizons) / columns)
    figure = _figure(3.0 * columns + 0.8, 2.8 * rows)
    image = None
    for index, item in enumerate(horizons):
        axis = figure.add_subplot(rows, columns, index + 1)
        grid = np.array([[np.nan if v is None else v for v in row] for row in item["map_long_ago"]])
        image = axis.imshow(grid, origin="lower", cmap="viridis", vmin=0.0, vmax=1.0)
        axis.set_title(f"H = {item['horizon']}", fontsize=9)
        axis.set_xlabel("n3 (background)", fontsize=8)
        axis.set_ylabel("n2 (agent)", fontsize=8)
    if image is not None:
        figure.colorbar(image, ax=figure.axes, shrink=0.8, label="fraction vocalizing")
    figure.suptitle(
        f"{name}: policy_H at z = long ago, counts n2 + n3 <= {result['domain_max_count']}"
        f" (stable from H = {entry['stable_from']})",
        fontsize=10,
    )
    return _save(figure, path)


def _detection_panel(left: Any, summaries: dict, labels: list[str], rooms: list[str],
                     ceiling: float) -> None:
    """plot_efficiency's first panel: median s to a 95 %-confident detection, per room."""
    y = np.arange(len(labels))
    height = 0.8 / len(rooms)
    for index, room in enumerate(rooms):
        medians, lows, highs = [], [], []
        for label in labels:
            summary = summaries[label].get(room, {})
            median = min(summary.get("detection_s_median", math.inf), ceiling)
            low, high = summary.get("detection_s_ci", (math.inf, math.inf))
            medians.append(median)
            lows.append(median - min(low, ceiling))
            highs.append(min(high, ceiling) - median)
        left.barh(
            y - 0.4 + height * (index + 0.5),
            medians,
            height=height,
            xerr=[lows, highs],
            label=room,
            color=f"C{index}",
            error_kw={"linewidth": 0.8},
        )
    left.axvline(ceiling, color="grey", linestyle=":", linewidth=1)
    left.set_yticks(y, labels, fontsize=8)
    left.invert_yaxis()
    left.set_xlabel(
        f"median s to P(S=1) >= 0.95\n(95 % CI; {ceiling:g} s: not reached)", fontsize=9
    )
    left.legend(fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncols=len(rooms))


def plot_efficiency(result: dict, path: str | Path) -> Path:
    """Three panels per controller (experiment_efficiency).

    Median seconds to a 95 %-confident detection in the named partner rooms; the mean
    entropy per step in rooms from the prior; the exact episode score (when the
    controller is a deterministic policy of the step and statistic).
    """
    summaries = result["summaries"]
    labels = list(result["controllers"])
    rooms = [f"{name}+partner" for name in result["rooms"]["backgrounds_k3"]]
    steps = result["config"]["steps"]
    ceiling = steps * result["dt"]
    scores = result.get("exact_episode_scores")
    columns = 3 if scores else 2
    figure = _figure(12.0 if scores else 10.0, 0.38 * len(labels) + 2.0)
    axes = figure.subplots(1, columns, sharey=True, width_ratios=(2.2, 1, 1)[:columns])
    y = np.arange(len(labels))
    _detection_panel(axes[0], summaries, labels, rooms, ceiling)
    means = np.array([summaries[label]["prior_weighted_entropy"] for label in labels])
    cis = np.array([summaries[label]["prior_weighted_entropy_ci"] for label in labels])
    axes[1].barh(
        y,
        means,
        xerr=[means - cis[:, 0], cis[:, 1] - means],
        color="tab:gray",
        error_kw={"linewidth": 0.8},
    )
    axes[1].set_xlabel("entropy per step, rooms from\nthe prior (bits, 95 % CI)", fontsize=9)
    if scores:
        values = [scores.get(label) for label in labels]
        axes[2].barh(y, [np.nan if v is None else v for v in values], color="tab:olive")
        for position, value in zip(y, values, strict=True):
            text = "n/a" if value is None else f"{value:.3f}"
            axes[2].text(0.02, position, text, va="center", fontsize=7)
        axes[2].set_xlim(0.0, 1.05)
        axes[2].set_xlabel(
            f"exact episode score, T = {result['config']['episodic_horizon']}\n"
            "(0 never vocalize, 1 optimal)",
            fontsize=9,
        )
    figure.suptitle(
        f"detection efficiency, {result['config']['params_name']} parameters, runs of {steps}"
        f" windows ({ceiling:g} s)",
        fontsize=10,
    )
    return _save(figure, path)


def plot_room_curves(result: dict, path: str | Path) -> Path:
    """Operating curves of experiment_rooms: one panel per room sound.

    x: share of runs in the empty room that ever turned attentive; y: median seconds
    until the posture settled in the room with a partner (the run's length where the
    median run never settled). One line per controller (the belief node's prior pi) and,
    dashed, the optimal controller under the other belief priors; points are the upper
    posture thresholds.
    """
    curves = result["operating_curves"]
    labels = list(result["controllers"])
    backgrounds = list(result["config"]["backgrounds"])
    ceiling = result["config"]["seconds"]
    base_pi = repr(result["params_pi"])
    figure = _figure(3.2 * len(backgrounds) + 0.8, 3.6)
    axes = np.atleast_1d(figure.subplots(1, len(backgrounds), sharey=True))
    for axis, background in zip(axes, backgrounds, strict=True):
        for index, label in enumerate(labels):
            for pi, points in curves[label][background].items():
                if pi != base_pi and index != 0:
                    continue
                x = [p["false_alarm"] for p in points]
                y = [min(p["settled_s_median"], ceiling) for p in points]
                style = "-" if pi == base_pi else "--"
                text = label if pi == base_pi else f"{label.split()[0]}, belief pi={float(pi):g}"
                axis.plot(x, y, style, marker="o", markersize=3, label=text, linewidth=1)
        axis.axhline(ceiling, color="grey", linestyle=":", linewidth=1)
        axis.set_title(background, fontsize=9)
        axis.set_xlim(-0.03, 1.03)
        axis.set_xlabel("false attentive (share of empty-room runs)", fontsize=8)
    axes[0].set_ylabel(f"median s to a settled posture\n({ceiling:g}: not settled)", fontsize=8)
    axes[-1].legend(fontsize=6, loc="center right")
    figure.suptitle(
        f"operating curves as the posture threshold varies (0.5 .. 0.99), binarizer"
        f" {result['config']['binarizer']}, {result['config']['runs']} runs per room",
        fontsize=9,
    )
    return _save(figure, path)

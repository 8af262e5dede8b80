"""The rooms experiment: every controller in every room, in worker processes, summarised."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from infomax_contingency.core.model import ModelParams
from infomax_contingency.eval.rooms.config import RoomsConfig, check_room_windows, controller_specs
from infomax_contingency.eval.rooms.running import run_room
from infomax_contingency.eval.rooms.scoring import curve_points, run_metrics
from infomax_contingency.eval.rooms.summaries import (
    contrast_bounds,
    operating_curves,
    summarise_room,
)
from infomax_contingency.eval.workers import WORKER_BYTES, worker_pool
from infomax_contingency.limits import refuse_over_budget
from infomax_contingency.sim.rooms import PARTNER_STATES, ROOM_CHANGE_S, room_kind

ROOMS_BASE_BYTES = 128 * 2**20
"""Memory of the experiment apart from its runs' figures, bytes (measured 110 MB peak
resident in one process; a run's audio is made a window at a time, whatever its length)."""
ROOMS_ROW_BYTES, ROOMS_CURVE_POINT_BYTES = 2 * 2**10, 128
"""Memory of one run's figures, bytes: the first, plus the second per point of its operating
curves (threshold x prior; measured 4 KiB with the 24 default points)."""


def refuse_oversized_rooms(config: RoomsConfig) -> None:
    """Refuse, before any run, an experiment whose figures would not fit in memory (one line).

    The estimate: :data:`ROOMS_BASE_BYTES`, the worker processes, and every run's figures
    twice (a worker's are copied to this process at once).
    """
    runs = len(config.room_names()) * config.runs * len(config.controllers)
    points = len(config.curve_thresholds) * len(config.curve_priors)
    needed = (ROOMS_BASE_BYTES + config.jobs * WORKER_BYTES
              + 2 * runs * (ROOMS_ROW_BYTES + ROOMS_CURVE_POINT_BYTES * points))  # fmt: skip
    refuse_over_budget(needed, f"run experiment rooms: {runs:,} runs", "give fewer --runs, rooms"
                       " or controllers")  # fmt: skip


def _run_batch(
    config: RoomsConfig, controllers: list[tuple[str, str]], tasks: list[tuple[str, int]]
) -> list[dict]:
    """Every controller on each (room, run) of ``tasks``."""
    params = ModelParams.load(config.params_name)
    rows = []
    for room, run in tasks:
        for label, spec in controllers:
            result = run_room(
                params,
                room,
                spec,
                config.binarizer,
                config.seconds,
                config.seed,
                run,
                config.memory,
                config.check_in(params),
            )
            rows.append(
                {
                    "room": room,
                    "run": run,
                    "controller": label,
                    **run_metrics(
                        params,
                        result,
                        room,
                        config.seconds,
                        config.attentive_above,
                        config.bored_below,
                    ),
                    "curve": curve_points(
                        params,
                        result,
                        room,
                        config.curve_thresholds,
                        config.curve_priors,
                        config.bored_below,
                    ),
                }
            )
    return rows


def simulate_room_runs(config: RoomsConfig, controllers: list[tuple[str, str]]) -> list[dict]:
    """Rows of every run, in ``config.jobs`` processes (the same rows for any number)."""
    tasks = [(room, run) for room in config.room_names() for run in range(config.runs)]
    if config.jobs <= 1 or len(tasks) < 2:
        rows = _run_batch(config, controllers, tasks)
    else:
        with worker_pool(config.jobs) as pool:
            futures = [
                pool.submit(_run_batch, config, controllers, tasks[i :: config.jobs])
                for i in range(config.jobs)
            ]
            rows = [row for future in futures for row in future.result()]
    rooms = {room: k for k, room in enumerate(config.room_names())}
    order = {label: k for k, (label, _) in enumerate(controllers)}
    return sorted(rows, key=lambda row: (rooms[row["room"]], row["run"], order[row["controller"]]))


def experiment_rooms(config: RoomsConfig, cache_dir: Path | None = None) -> dict[str, Any]:
    """The rooms experiment (the package's docstring): summaries per room and controller, curves."""
    params = ModelParams.load(config.params_name)
    check_room_windows(params, config.params_name)
    for name in config.room_names():
        room_kind(name)  # every name is in the one registry
    refuse_oversized_rooms(config)
    controllers = controller_specs(params, config.controllers, cache_dir)
    rows = simulate_room_runs(config, controllers)
    summaries: dict[str, dict[str, Any]] = {}
    for label, _ in controllers:
        summaries[label] = {
            room: summarise_room(
                [r for r in rows if r["controller"] == label and r["room"] == room], config.seed
            )
            for room in config.room_names()
        }
    return {
        "experiment": "rooms",
        "config": dataclasses.asdict(config),
        "dt": params.dt,
        "params_pi": params.pi,
        "room_change_s": ROOM_CHANGE_S,
        "partner_states": list(PARTNER_STATES),
        "controllers": [label for label, _ in controllers],
        "rooms": config.room_names(),
        "summaries": summaries,
        "operating_curves": {
            label: operating_curves(config, rows, label) for label, _ in controllers
        },
        "information_bound": {
            label: contrast_bounds(params, summaries[label], config) for label, _ in controllers
        },
    }

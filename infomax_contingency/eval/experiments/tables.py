"""Policy tables of the experiments: the committed one, one cached earlier, or solved now."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from infomax_contingency.core import model
from infomax_contingency.core.model import ModelParams
from infomax_contingency.core.policy_table import EPISODIC, PolicyTable, PolicyTableError
from infomax_contingency.core.solver import SOLVER_VERSION, solve, solve_cost
from infomax_contingency.limits import refuse_over_budget
from infomax_contingency.resources import resource_path


def table_name(params: ModelParams, mode: str, horizon: int, memory: int = 0) -> str:
    """File name of a table: ``<set>_episodic_T<T>.npz`` or ``<set>_receding_H<H>_M<M>.npz``.

    ``<set>`` is the name of a reference parameter set, or ``params-<first 12 hex digits of
    the parameter hash>`` for other parameters.
    """
    solved_for = params.for_table()  # a table does not depend on k2_per_lag
    label = next(
        (name for name, named in model.NAMED_PARAMS.items() if named.for_table() == solved_for),
        f"params-{solved_for.digest()[:12]}",
    )
    if mode == EPISODIC:
        return f"{label}_episodic_T{horizon}.npz"
    return f"{label}_receding_H{horizon}_M{memory}.npz"


def default_cache_dir() -> Path:
    """Where solved tables are cached: ``$INFOMAX_CACHE_DIR`` or a directory under the temp dir."""
    configured = os.environ.get("INFOMAX_CACHE_DIR")
    if configured:
        return Path(configured)
    return Path(tempfile.gettempdir()) / "infomax_contingency_tables"


def obtain_table(
    params: ModelParams,
    mode: str,
    horizon: int,
    memory: int = 0,
    cache_dir: Path | None = None,
) -> tuple[PolicyTable, Path]:
    """A solved table and its file.

    The committed one in ``policies/`` if it exists, else one cached earlier, else solved
    now (a few seconds at most) and cached. A cached table from another solver version is
    solved again. A table that would not fit in memory is refused before any work
    (ValueError, one line).
    """
    name = table_name(params, mode, horizon, memory)
    try:
        committed = resource_path("policies", name)
    except FileNotFoundError:
        committed = None
    if committed is not None:
        return PolicyTable.load(committed, expected_params=params), committed
    directory = cache_dir or default_cache_dir()
    path = directory / name
    if path.is_file():
        try:
            cached = PolicyTable.load(path, expected_params=params)
        except PolicyTableError:
            cached = None  # a damaged cache entry: solve again and overwrite it
        if cached is not None and cached.solver_version == SOLVER_VERSION:
            return cached, path
    size = f"horizon {horizon}" + (f" and memory {memory}" if memory else "")
    refuse_over_budget(solve_cost(params, mode, horizon, memory).peak_bytes,
                       f"solve the {mode} table of {size}", "give a shorter horizon or memory")
    table = solve(params, mode, horizon, memory)
    directory.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(f".{os.getpid()}.tmp")
    table.save(partial)
    partial.replace(path)
    return table, path

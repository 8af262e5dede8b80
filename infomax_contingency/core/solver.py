"""Exact dynamic programming for infomax control (MODEL.md section 3).

With ``k`` steps to go::

    V_0(a) = -H(a)
    V_k(a) = -H(a) + max_u sum_y P(y | a, u) V_{k-1}(f(a, u, y))

The statistic ``a = (z, p2, q2, p3, q3)`` is finite once the counts are bounded, and
from a layer whose counts sum to at most N the next layer's counts sum to at most N + 1.
The solver therefore sweeps backwards over layers ``k = 1 .. K`` whose counts sum to at
most ``N_k = N_0 - k``, every layer fully vectorised over all count tuples (numbered by
:mod:`infomax_contingency.core.statespace`) and all timer values:

* **episodic**, horizon T: ``N_0 = T``; step ``t`` uses layer ``k = T - t`` (counts sum
  to at most t); all layers ``t = 1 .. T-1`` are stored.
* **receding**, horizon H, memory M: ``N_0 = M + H``; only layer ``k = H`` (counts sum
  to at most M) is stored. The look-ahead lets counts grow; the sliding memory is
  applied by the caller between decisions.

Ties go to silence: vocalize only when its value exceeds silence's by more than
:data:`~infomax_contingency.core.model.TIE_TOLERANCE` bits, so floating-point noise never
decides an exact tie.

The same backward step, given actions instead of maximising over them, evaluates any
policy exactly (``fixed_actions`` of :func:`backward_induction`); the evaluation suite
scores controllers with it and TD learning reads its greedy policy off it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from math import comb

import numpy as np

from infomax_contingency.core.model import (
    AGENT,
    BACKGROUND,
    SELF,
    TIE_TOLERANCE,
    ModelParams,
    belief_from_log_odds,
    entropy_from_log_odds,
    log_odds,
    period_of,
    predictive_active,
)
from infomax_contingency.core.policy_table import EPISODIC, RECEDING, PolicyTable
from infomax_contingency.core.statespace import n_count_tuples, partial_sums
from infomax_contingency.limits import as_float

SOLVER_VERSION = 1


CHUNK = 1 << 15
"""Count tuples processed together: keeps every temporary of a chunk in the CPU cache."""

Progress = Callable[[int, int, float], None]
"""Called with (layers done, layers in all, fraction of the sweep's work done): once with
0 layers done when the set-up is over, then after each layer."""

# The cost model of a solve, fitted to bench/bench_solver.py on a 2-core x86-64 machine
# (its "cost model vs measured" section prints both; times vary with the machine's load).
# Memory: the working arrays of tuple_quantities and two value layers per count tuple of
# the k = 0 layer, the packed actions kept, and the interpreter with numpy. Time: one
# Bellman update per statistic of every layer swept, plus the per-tuple set-up.
BASE_BYTES = 54 * 2**20
"""Resident memory of the interpreter with numpy and the package, before a solve (bytes)."""
TUPLE_BYTES, TUPLE_BYTES_PER_TIMER_VALUE, MIN_TUPLE_BYTES = 64, 17, 124
"""Peak working memory per count tuple: max(MIN, 64 + 17 * n_timer_values) bytes
(neighbour indices, predictive probabilities, two float64 value rows and one action row
per timer value; the set-up's temporaries need about 120 bytes)."""
SECONDS_PER_UPDATE = 1.1e-8
"""Time of one Bellman update (one statistic of one layer), seconds."""
SECONDS_PER_TUPLE = 1.2e-7
"""Set-up time per count tuple of the k = 0 layer (tuple_quantities), seconds."""


@dataclasses.dataclass(frozen=True)
class SolveCost:
    """What a solve will take, known before it starts (:func:`solve_cost`).

    Attributes:
        statistics: statistics the table will hold (one action bit each).
        updates: Bellman updates of the sweep (statistics of every layer swept).
        layers: layers swept backwards.
        peak_bytes: expected peak resident memory of the solving process, bytes.
        seconds: expected solve time, seconds (the machine the model was fitted on).
    """

    statistics: int
    updates: int
    layers: int
    peak_bytes: int
    seconds: float


def _sweep(mode: str, horizon: int, memory: int) -> tuple[int, int, Sequence[int]]:
    """``(N_0, layers swept, max counts of the kept layers)`` of a solve (validated).

    The kept layers are a ``range`` for an episodic table: a horizon of 10^18 is
    estimated (and refused) without a list of 10^18 layers.
    """
    if mode == EPISODIC:
        if horizon < 2:
            raise ValueError(f"episodic horizon must be >= 2 steps, got {horizon}")
        if memory:
            raise ValueError("episodic tables take no memory (the episode is the memory)")
        return horizon, horizon - 1, range(1, horizon)
    if mode == RECEDING:
        if horizon < 1:
            raise ValueError(f"receding horizon must be >= 1 step, got {horizon}")
        if memory < 1:
            raise ValueError(f"memory must be >= 1 observation, got {memory}")
        return memory + horizon, horizon, [memory]
    raise ValueError(f"unknown table mode {mode!r}; use {EPISODIC!r} or {RECEDING!r}")


def solve_cost(params: ModelParams, mode: str, horizon: int, memory: int = 0) -> SolveCost:
    """Statistics, peak memory and time of :func:`solve`, in closed form (any size, at once).

    Raises ``ValueError`` for arguments :func:`solve` refuses.
    """
    base, steps, _ = _sweep(mode, horizon, memory)
    n_timer = params.n_timer_values
    if mode == EPISODIC:
        statistics = n_timer * (comb(horizon + 4, 5) - 1)
        kept_bytes = statistics // 8 + steps  # a rounding byte per kept layer
    else:
        statistics = n_timer * n_count_tuples(memory)
        kept_bytes = (statistics + 7) // 8
    return induction_cost(params, base, steps, statistics, kept_bytes)


def induction_cost(params: ModelParams, base_max_count: int, steps: int, kept_statistics: int,
                   kept_bytes: int) -> SolveCost:  # fmt: skip
    """What :func:`backward_induction` takes, in closed form (any size, at once).

    Args:
        params: model parameters.
        base_max_count: ``N_0``, the largest count sum of the ``k = 0`` layer.
        steps: layers swept (``K``).
        kept_statistics: statistics whose actions the caller keeps.
        kept_bytes: memory those kept actions take (packed, and any unpacked copies), bytes.
    """
    n_timer = params.n_timer_values
    # Layers k = 1 .. K hold the tuples with sums <= base - k: sum_k C(base - k + 4, 4).
    swept_tuples = comb(base_max_count + 4, 5) - comb(base_max_count - steps + 4, 5)
    per_tuple = max(MIN_TUPLE_BYTES, TUPLE_BYTES + TUPLE_BYTES_PER_TIMER_VALUE * n_timer)
    tuples = n_count_tuples(base_max_count)
    return SolveCost(
        statistics=kept_statistics,
        updates=n_timer * swept_tuples,
        layers=steps,
        peak_bytes=BASE_BYTES + per_tuple * tuples + kept_bytes,
        seconds=as_float(SECONDS_PER_UPDATE * as_float(n_timer * swept_tuples)
                         + SECONDS_PER_TUPLE * as_float(tuples)),
    )


@dataclasses.dataclass
class Solution:
    """Output of :func:`backward_induction` for the kept layers ``k``.

    ``actions[k]`` is the layer's action array of shape ``(n_timer_values,
    n_count_tuples(max_counts[k]))`` packed row-major with ``numpy.packbits``; rows are
    the timer z, columns :func:`statespace.count_index`. ``values[k]`` (only when asked
    for) is the unpacked value array of the same shape.
    """

    max_counts: dict[int, int]
    actions: dict[int, np.ndarray]
    values: dict[int, np.ndarray]


def tuple_quantities(params: ModelParams, max_count: int) -> dict:
    """Per count tuple: negative entropy, predictive P(y=1) and the neighbours' indices.

    Tuples are those with sum <= max_count, in :mod:`~infomax_contingency.core.statespace` index
    order. ``neg_entropy`` is ``-H`` (bits) of every tuple; ``tuples[AGENT]`` and
    ``tuples[BACKGROUND]`` are P(y=1) of the next bit in that period, and
    ``neighbours[(period, y)]`` the index of the tuple one observation ``y`` in ``period``
    later; both are given for tuples with sum <= max_count - 1.
    """
    s1, s2, s3, s4 = partial_sums(max_count)
    p2, q2, p3, q3 = s1, s2 - s1, s3 - s2, s4 - s3
    lam = log_odds(params, p2, q2, p3, q3)
    b = belief_from_log_odds(lam)
    inner = n_count_tuples(max_count - 1)
    # Tuples are in index order, so a tuple's index is its position. One more observation
    # raises the partial sums from the counter it lands in onwards, and the index grows by
    # C(s4 + 3, 3) when s4 grows by one, by C(s3 + 2, 2) when s3 does, by s2 + 1 for s2.
    sums = np.arange(max_count + 1, dtype=np.intp)
    index = np.arange(inner, dtype=np.intp)
    step4 = index + ((sums + 3) * (sums + 2) * (sums + 1) // 6)[s4[:inner]]
    step3 = step4 + ((sums + 2) * (sums + 1) // 2)[s3[:inner]]
    step2 = step3 + (sums + 1)[s2[:inner]]
    return {
        "neg_entropy": -entropy_from_log_odds(lam),
        AGENT: predictive_active(params, AGENT, p2, q2, p3, q3, b)[:inner],
        BACKGROUND: predictive_active(params, BACKGROUND, p2, q2, p3, q3, b)[:inner],
        "neighbours": {  # intp: numpy gathers with native-width indices without converting
            (AGENT, 1): step2 + 1,
            (AGENT, 0): step2,
            (BACKGROUND, 1): step3,
            (BACKGROUND, 0): step4,
        },
    }


def bellman_layer(
    params: ModelParams,
    tuples: dict,
    next_values: np.ndarray,
    max_count: int,
    fixed_actions: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One backward step: ``V_k`` and its actions from ``V_{k-1}``, for counts <= max_count.

    ``V_k(a) = -H(a) + max_u sum_y P(y | a, u) V_{k-1}(f(a, u, y))`` (ties: silence), or,
    with ``fixed_actions``, the same sum for the given action instead of the maximum
    (exact evaluation of a given policy).

    Args:
        params: model parameters.
        tuples: :func:`tuple_quantities` for a max count > ``max_count``.
        next_values: ``V_{k-1}``, shape ``(n_timer_values, >= n_count_tuples(max_count + 1))``.
        max_count: the layer's largest count sum.
        fixed_actions: None to optimise; else boolean actions of shape
            ``(n_timer_values, n_count_tuples(max_count))`` to evaluate.

    Returns:
        ``(values, actions)``, both of shape ``(n_timer_values, n_count_tuples(max_count))``.
    """
    n_timer = params.n_timer_values
    neighbours = tuples["neighbours"]
    periods = [period_of(params, z) for z in range(n_timer)]
    size = n_count_tuples(max_count)
    new_values = np.empty((n_timer, size))
    actions = np.empty((n_timer, size), dtype=bool)
    if fixed_actions is not None:
        if fixed_actions.shape != actions.shape:
            raise ValueError(
                f"fixed actions have shape {fixed_actions.shape}, need {actions.shape}"
            )
        actions[...] = fixed_actions
    for start in range(0, size, CHUNK):
        chunk = slice(start, min(start + CHUNK, size))
        # Expected next value sum_y P(y) V_{k-1} for every timer value z' reached.
        expected = []
        for z_next, period in enumerate(periods):
            row = next_values[z_next]
            if period == SELF:
                expected.append(row[chunk])
                continue
            after_active = row[neighbours[(period, 1)][chunk]]
            after_inactive = row[neighbours[(period, 0)][chunk]]
            after_active -= after_inactive
            after_active *= tuples[period][chunk]
            after_active += after_inactive
            expected.append(after_active)
        vocalize_value = expected[0]
        neg_entropy = tuples["neg_entropy"][chunk]
        for z in range(n_timer):
            silent_value = expected[min(z + 1, n_timer - 1)]
            out_values, out_actions = new_values[z, chunk], actions[z, chunk]
            if fixed_actions is None:
                np.subtract(vocalize_value, silent_value, out=out_values)
                np.greater(out_values, TIE_TOLERANCE, out=out_actions)
                np.maximum(vocalize_value, silent_value, out=out_values)
            else:
                np.copyto(out_values, silent_value)
                np.copyto(out_values, vocalize_value, where=out_actions)
            out_values += neg_entropy
    return new_values, actions


def backward_induction(
    params: ModelParams,
    base_max_count: int,
    steps: int,
    keep: set[int],
    keep_values: bool = False,
    fixed_actions: Callable[[int], np.ndarray] | None = None,
    progress: Progress | None = None,
) -> Solution:
    """Solve ``V_k`` for ``k = 0 .. steps`` over layers with counts summing to ``base - k``.

    Args:
        params: model parameters.
        base_max_count: ``N_0``, the largest count sum of the ``k = 0`` layer.
        steps: the last layer to compute (``K``); requires ``K <= N_0``.
        keep: the layers ``k`` whose actions (and values) are returned.
        keep_values: also return the values of the kept layers (for tests and analysis).
        fixed_actions: None for the optimal policy; else a function of ``k`` giving the
            boolean actions of layer ``k`` (see :func:`bellman_layer`), whose values are
            then computed exactly instead (policy evaluation).
        progress: called after each layer (see :data:`Progress`).
    """
    if steps < 1 or steps > base_max_count:
        raise ValueError(f"need 1 <= steps <= base_max_count, got {steps}, {base_max_count}")
    n_timer = params.n_timer_values
    tuples = tuple_quantities(params, base_max_count)
    values = np.broadcast_to(tuples["neg_entropy"], (n_timer, n_count_tuples(base_max_count)))
    solution = Solution(max_counts={}, actions={}, values={})
    work = [n_count_tuples(base_max_count - k) for k in range(1, steps + 1)]
    total_work, work_done = sum(work), 0
    if progress is not None:
        progress(0, steps, 0.0)

    for k in range(1, steps + 1):
        max_count = base_max_count - k
        given = None if fixed_actions is None else fixed_actions(k)
        values, actions = bellman_layer(params, tuples, values, max_count, given)
        if k in keep:
            solution.max_counts[k] = max_count
            solution.actions[k] = np.packbits(actions)
            if keep_values:
                solution.values[k] = values
        work_done += work[k - 1]
        if progress is not None:
            progress(k, steps, work_done / total_work)
    return solution


def solve_episodic(
    params: ModelParams,
    horizon: int,
    keep_values: bool = False,
    progress: Progress | None = None,
) -> PolicyTable:
    """Episodic table for horizon T: actions for steps ``t = 1 .. T-1``.

    Step ``t`` (counts summing to at most t) uses ``policy_{T-t}``.
    """
    _sweep(EPISODIC, horizon, 0)
    steps = horizon - 1
    solution = backward_induction(
        params, horizon, steps, set(range(1, steps + 1)), keep_values, progress=progress
    )
    layers = [solution.actions[horizon - t] for t in range(1, horizon)]
    max_counts = list(range(1, horizon))
    table = PolicyTable.from_packed_layers(
        params, EPISODIC, horizon, 0, max_counts, layers, SOLVER_VERSION
    )
    if keep_values:
        table.values = [solution.values[horizon - t] for t in range(1, horizon)]
    return table


def solve_receding(
    params: ModelParams,
    horizon: int,
    memory: int,
    keep_values: bool = False,
    progress: Progress | None = None,
) -> PolicyTable:
    """Receding-horizon table ``policy_H`` over statistics with ``n2 + n3 <= M``."""
    _sweep(RECEDING, horizon, memory)
    solution = backward_induction(
        params, memory + horizon, horizon, {horizon}, keep_values, progress=progress
    )
    table = PolicyTable.from_packed_layers(
        params, RECEDING, horizon, memory, [memory], [solution.actions[horizon]], SOLVER_VERSION
    )
    if keep_values:
        table.values = [solution.values[horizon]]
    return table


def solve(
    params: ModelParams,
    mode: str,
    horizon: int,
    memory: int = 0,
    progress: Progress | None = None,
) -> PolicyTable:
    """Solve a table of ``mode`` ``episodic`` (horizon T) or ``receding`` (horizon H, memory M).

    :func:`solve_cost` tells what it will take; ``progress`` is called after each layer.
    """
    _sweep(mode, horizon, memory)
    if mode == EPISODIC:
        return solve_episodic(params, horizon, progress=progress)
    return solve_receding(params, horizon, memory, progress=progress)

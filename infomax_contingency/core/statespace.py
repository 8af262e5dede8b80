"""Indexing of count tuples ``(p2, q2, p3, q3)`` for the DP solver and the policy tables.

Tuples are numbered by the combinatorial number system on their partial sums
``s1 = p2``, ``s2 = p2 + q2``, ``s3 = s2 + p3``, ``s4 = n = s3 + q3``::

    index = C(s1, 1) + C(s2 + 1, 2) + C(s3 + 2, 3) + C(s4 + 3, 4)

This orders tuples by their total ``n`` first, so the tuples with ``n <= N`` are exactly
the first ``C(N + 4, 4)`` indices, whatever N: one numbering serves every DP layer and
every table, and a layer with a larger N extends a smaller one.
"""

from __future__ import annotations

from math import comb

import numpy as np


def n_count_tuples(max_count: int) -> int:
    """Number of tuples ``(p2, q2, p3, q3)`` of non-negative integers with sum <= max_count."""
    return comb(max_count + 4, 4) if max_count >= 0 else 0


def count_index(p2: int, q2: int, p3: int, q3: int) -> int:
    """Index of one count tuple (pure Python integers: fast for a single lookup)."""
    s2 = p2 + q2
    s3 = s2 + p3
    n = s3 + q3
    return (
        p2
        + (s2 + 1) * s2 // 2
        + (s3 + 2) * (s3 + 1) * s3 // 6
        + (n + 3) * (n + 2) * (n + 1) * n // 24
    )


def count_index_array(p2: np.ndarray, q2: np.ndarray, p3: np.ndarray, q3: np.ndarray) -> np.ndarray:
    """Index of arrays of count tuples (int64)."""
    p2, q2, p3, q3 = (np.asarray(v, dtype=np.int64) for v in (p2, q2, p3, q3))
    s2 = p2 + q2
    s3 = s2 + p3
    n = s3 + q3
    return (
        p2
        + (s2 + 1) * s2 // 2
        + (s3 + 2) * (s3 + 1) * s3 // 6
        + (n + 3) * (n + 2) * (n + 1) * n // 24
    )


def partial_sums(max_count: int) -> np.ndarray:
    """Partial sums ``s1 <= s2 <= s3 <= s4`` of all tuples with sum <= max_count, in index order.

    Shape ``(4, n_count_tuples(max_count))``, int32. Built from the colex enumeration of
    4-combinations ``x1 < x2 < x3 < x4 < max_count + 4`` with ``x_j = s_j + j - 1``: the
    combinations with top element x follow all those with a smaller top element.
    """
    if max_count < 0:
        raise ValueError(f"max_count must be >= 0, got {max_count}")
    top = max_count + 4
    combos = np.arange(top, dtype=np.int32)[:, None]  # 1-combinations, one per row
    for k in range(2, 5):
        extended = np.empty((comb(top, k), k), dtype=np.int32)
        start = 0
        for x in range(k - 1, top):
            size = comb(x, k - 1)
            extended[start : start + size, :-1] = combos[:size]
            extended[start : start + size, -1] = x
            start += size
        combos = extended
    return (combos - np.arange(4, dtype=np.int32)).T


def count_tuples(max_count: int) -> np.ndarray:
    """All tuples with sum <= max_count, shape ``(n_count_tuples(max_count), 4)``, in index order.

    Columns are ``p2, q2, p3, q3`` (int32).
    """
    return np.diff(partial_sums(max_count), axis=0, prepend=0).T.copy()

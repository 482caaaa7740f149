"""The order in which to visit planned poses: a short path through joint space.

An open path from a start configuration through every pose once: nearest neighbour first, then
2-opt moves (reversing a stretch of the path) while they shorten it. Lengths are Euclidean in
joint space (rad, or m for prismatic joints).

    >>> import numpy as np
    >>> Q = np.array([[3.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    >>> order_poses(Q, np.zeros(2)).tolist()
    [1, 2, 0]
"""

from __future__ import annotations

import numpy as np

from dream.errors import InputError

MAX_TWO_OPT_ROUNDS = 100   # passes over every pair of path edges
IMPROVEMENT_TOLERANCE = 1e-12


def path_length(Q: np.ndarray, start: np.ndarray, order: np.ndarray) -> float:
    """Joint-space length of the path from `start` (J,) through `Q[order]` (N, J)."""
    points = np.vstack([start[None], np.asarray(Q, float)[np.asarray(order, int)]])
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def _nearest_neighbour(D: np.ndarray) -> list[int]:
    """Visiting order from node 0 (the start) by nearest unvisited node; D (N+1, N+1)."""
    order, left = [0], set(range(1, len(D)))
    while left:
        here = order[-1]
        nxt = min(left, key=lambda j: D[here, j])
        order.append(nxt)
        left.remove(nxt)
    return order


def _two_opt(D: np.ndarray, order: list[int]) -> list[int]:
    """Reverse stretches order[i..j] (never the start) while that shortens the open path."""
    n = len(order)
    for _ in range(MAX_TWO_OPT_ROUNDS):
        improved = False
        for i in range(1, n - 1):
            for j in range(i + 1, n):
                a, b = order[i - 1], order[i]
                c = order[j]
                after = D[b, order[j + 1]] if j + 1 < n else 0.0
                before = D[c, order[j + 1]] if j + 1 < n else 0.0
                change = D[a, c] + after - D[a, b] - before
                if change < -IMPROVEMENT_TOLERANCE:
                    order[i:j + 1] = order[i:j + 1][::-1]
                    improved = True
        if not improved:
            break
    return order


def order_poses(Q: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Indices (N,) into `Q` (N, J) giving a short open path from `start` (J,)."""
    Q = np.asarray(Q, dtype=float)
    start = np.asarray(start, dtype=float)
    if Q.ndim != 2 or start.shape != (Q.shape[1],):
        raise InputError(f"poses must have shape (N, J) and the start (J,), got {Q.shape} and "
                         f"{start.shape}")
    points = np.vstack([start[None], Q])
    D = np.linalg.norm(points[:, None] - points[None], axis=-1)
    order = _two_opt(D, _nearest_neighbour(D))
    return np.array(order[1:], dtype=int) - 1

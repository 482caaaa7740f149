"""The order in which to visit planned poses: a short path through joint space.

An open path from a start configuration through every pose once: nearest neighbour first, then
2-opt moves (reversing a stretch of the path) while they shorten it. Lengths are Euclidean in
joint space (rad, or m for prismatic joints). `order_clear_moves` also keeps the straight
joint-space moves along the path clear of collisions where it can.

    >>> import numpy as np
    >>> Q = np.array([[3.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    >>> order_poses(Q, np.zeros(2)).tolist()
    [1, 2, 0]
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dream.errors import InputError

MAX_TWO_OPT_ROUNDS = 100   # passes over every pair of path edges
IMPROVEMENT_TOLERANCE = 1e-12
BLOCKED_MOVE_PENALTY = 1e3  # added to the length of a move that collides (rad)
MAX_REORDERS = 20          # orderings tried while new colliding moves turn up


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


def order_poses(Q: np.ndarray, start: np.ndarray, penalty: np.ndarray | None = None
                ) -> np.ndarray:
    """Indices (N,) into `Q` (N, J) giving a short open path from `start` (J,); `penalty`
    (N + 1, N + 1), node 0 the start, is added to the length of each move."""
    Q = np.asarray(Q, dtype=float)
    start = np.asarray(start, dtype=float)
    if Q.ndim != 2 or start.shape != (Q.shape[1],):
        raise InputError(f"poses must have shape (N, J) and the start (J,), got {Q.shape} and "
                         f"{start.shape}")
    points = np.vstack([start[None], Q])
    D = np.linalg.norm(points[:, None] - points[None], axis=-1)
    if penalty is not None:
        D = D + penalty
    order = _two_opt(D, _nearest_neighbour(D))
    return np.array(order[1:], dtype=int) - 1


def order_clear_moves(Q: np.ndarray, start: np.ndarray,
                      move_clearance: Callable[[np.ndarray, np.ndarray], float],
                      min_clearance: float, check_start: bool = True
                      ) -> tuple[np.ndarray, np.ndarray]:
    """`order_poses`, avoiding moves whose `move_clearance(q_from, q_to)` (m) is below
    `min_clearance`: such a move is found on the path, made `BLOCKED_MOVE_PENALTY` longer and
    the path ordered again, until the path has no new blocked move. Returns the order and
    the clearance of each of its N moves (from the start first); a move that could not be
    avoided keeps its low clearance. Without `check_start` the move from the start is not
    checked (its clearance is inf)."""
    Q, start = np.asarray(Q, dtype=float), np.asarray(start, dtype=float)
    points = np.vstack([start[None], Q])
    penalty = np.zeros((len(points), len(points)))
    known: dict[tuple[int, int], float] = {}
    for _ in range(MAX_REORDERS):
        order = order_poses(Q, start, penalty)
        nodes = [0, *(order + 1)]
        blocked_new = False
        for a, b in zip(nodes[:-1], nodes[1:], strict=True):
            key = (min(a, b), max(a, b))
            if key not in known:
                known[key] = float("inf") if (0 in key and not check_start) else \
                    move_clearance(points[a], points[b])
                if known[key] < min_clearance:
                    penalty[a, b] = penalty[b, a] = BLOCKED_MOVE_PENALTY
                    blocked_new = True
        if not blocked_new:
            break
    clearances = [known[(min(a, b), max(a, b))] for a, b in zip(nodes[:-1], nodes[1:],
                                                                 strict=True)]
    return order, np.array(clearances)

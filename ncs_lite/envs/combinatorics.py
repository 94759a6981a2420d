"""Appendix E: how many trajectories a complete-goal block-rearrange task space holds.

Initial configurations: C(|S|, k) (cubes as placed; the paper counts cell sets). Each step
moves one of the k cubes to one of the |S| - k free cells: k (|S| - k) successors. A
complete goal needs t >= k steps, so at t = k there are C(|S|, k) (k (|S| - k))^k
trajectories: 4.5e16 for |S| = 16, k = 7. `enumerate_trajectories` walks the space
explicitly on small grids to check the formula.
"""
from __future__ import annotations

from itertools import combinations
from math import comb


def count_trajectories(cells: int, k: int, steps: int | None = None) -> int:
    """C(cells, k) * (k * (cells - k)) ** steps, with steps = k by default."""
    if not 0 < k < cells:
        raise ValueError(f"need 0 < k < cells, got k={k}, cells={cells}")
    steps = k if steps is None else steps
    return comb(cells, k) * (k * (cells - k)) ** steps


def enumerate_trajectories(cells: int, k: int, steps: int | None = None) -> int:
    """Count trajectories by walking them: every start set, every move of every step."""
    if not 0 < k < cells:
        raise ValueError(f"need 0 < k < cells, got k={k}, cells={cells}")
    steps = k if steps is None else steps

    def walk(occupied: frozenset, left: int) -> int:
        if left == 0:
            return 1
        free = [c for c in range(cells) if c not in occupied]
        return sum(walk(occupied - {src} | {dst}, left - 1) for src in occupied for dst in free)

    return sum(walk(frozenset(start), steps) for start in combinations(range(cells), k))

"""The Cantor set and the Cantor staircase (the devil's staircase of the lecture).

Removing the open middle third of [0, 1], then of each remaining piece, and so on, leaves after
`depth` steps 2^depth closed intervals of length 3^-depth: the Cantor set is what remains forever
(dimension log 2 / log 3). The staircase is the Cantor function C: flat on every removed third
(the "steps": one of length 1/3, two of 1/9, four of 1/27, ...) and rising only on the Cantor set.
The steps' total length is 1/3 + 2/9 + 4/27 + ... = 1, yet the uncountably many "wet points" of
the Cantor set lie on no step: after `depth` levels the steps cover 1 - (2/3)^depth and the
2^depth intervals still left (containing the wet points) cover exactly the remaining (2/3)^depth.
"""

from __future__ import annotations

import math

import numpy as np

from ._checks import FractalError, check_int

MAX_SET_DEPTH = 22  # 2^22 = 4.2 million intervals
MAX_MASK_DEPTH = 16  # 3^16 = 43 million cells
MAX_STAIRCASE_DEPTH = 60


def cantor_set(depth: int) -> np.ndarray:
    """The 2^depth closed intervals left after `depth` middle-third removals, sorted.

    Returns:
        (2^depth, 2) float64 [left, right] with right - left = 3^-depth.
    """
    depth = check_int("depth", depth, 0, MAX_SET_DEPTH)
    lefts = np.zeros(1)
    for _ in range(depth):
        lefts = np.concatenate([lefts / 3.0, lefts / 3.0 + 2.0 / 3.0])
    return np.stack([lefts, lefts + 3.0**-depth], axis=1)


def cantor_mask(depth: int) -> np.ndarray:
    """The Cantor set at `depth` as a 1-D boolean image of 3^depth cells (True = in the set),
    for `box_counting_dimension`."""
    depth = check_int("depth", depth, 0, MAX_MASK_DEPTH)
    mask = np.ones(1, dtype=bool)
    for _ in range(depth):
        mask = np.concatenate([mask, np.zeros_like(mask), mask])
    return mask


def cantor_staircase(x, depth: int = 30) -> np.ndarray:
    """The Cantor function C(x), evaluated exactly digit by digit (vectorised).

    Reading the ternary digits of x: a digit 0 or 2 contributes a binary digit 0 or 1; the first
    digit 1 means x lies on a step, whose height is the binary fraction so far plus 2^-k. After
    `depth` digits without a 1 the binary fraction is returned (it is within 2^-depth of C(x)).
    C is 0 for x <= 0 and 1 for x >= 1.

    Arguments:
        x: array-like of finite floats.
        depth: ternary digits read, 1..60 (30 gives C within 1e-9).

    Returns:
        float64 array shaped like x, monotone non-decreasing and continuous in x.
    """
    depth = check_int("depth", depth, 1, MAX_STAIRCASE_DEPTH)
    x = np.asarray(x, dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise FractalError("x: contains non-finite values")
    r = np.clip(x, 0.0, 1.0)
    value = np.zeros_like(r)
    done = r >= 1.0
    value[done] = 1.0
    weight = 0.5
    for _ in range(depth):
        r = 3.0 * r
        digit = np.minimum(np.floor(r), 2.0)
        r = r - digit
        hit = ~done & (digit == 1.0)
        value = np.where(hit, value + weight, value)
        value = np.where(~done & (digit == 2.0), value + weight, value)
        done |= hit
        weight *= 0.5
    return value


def staircase_steps(depth: int) -> np.ndarray:
    """The flat steps of the staircase removed in the first `depth` levels, sorted by position.

    Level k contributes 2^(k-1) steps of length 3^-k; the step on (a, b) has height C((a + b)/2).

    Arguments:
        depth: 0..22 levels (2^depth - 1 steps).

    Returns:
        (2^depth - 1, 3) float64 rows [a, b, height].
    """
    depth = check_int("depth", depth, 0, MAX_SET_DEPTH)
    rows = []
    for k in range(1, depth + 1):
        parents = cantor_set(k - 1)  # each parent interval loses its open middle third at level k
        third = 3.0**-k
        a = parents[:, 0] + third
        heights = (2.0 * np.arange(len(parents)) + 1.0) / 2.0**k
        rows.append(np.stack([a, a + third, heights], axis=1))
    if not rows:
        return np.zeros((0, 3))
    steps = np.concatenate(rows)
    return steps[np.argsort(steps[:, 0], kind="stable")]


def staircase_measure(depth: int) -> tuple[float, float]:
    """(total length of the steps of levels 1..depth, length still uncovered), level by level.

    The steps sum to sum_k 2^(k-1) 3^-k = 1 - (2/3)^depth; the uncovered 2^depth Cantor intervals
    (the wet points' neighbourhoods) measure (2/3)^depth; the two add to 1 at every depth. Works
    for any depth >= 0 (no intervals are listed).
    """
    depth = check_int("depth", depth, 0)
    steps = math.fsum(2.0 ** (k - 1) / 3.0**k for k in range(1, depth + 1))
    uncovered = (2.0 / 3.0) ** depth
    return steps, uncovered

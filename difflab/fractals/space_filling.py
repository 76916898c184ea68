"""Space-filling curves: the Peano curve (3 x 3 refinement) and the Hilbert curve (2 x 2).

At order k the curve visits every cell of a regular grid over the unit square exactly once, each
step moving to an edge-adjacent cell; the vertices are the cell centres. As k grows the polyline
comes arbitrarily close to every point of the square: its box-counting dimension tends to 2.
"""

from __future__ import annotations

import numpy as np

from ._checks import check_int

MAX_PEANO_ORDER = 7  # 9^7 = 4.8 million points
MAX_HILBERT_ORDER = 11  # 4^11 = 4.2 million points


def peano_cells(order: int) -> np.ndarray:
    """Integer cells (x, y) in [0, 3^order)^2 in the order the Peano curve visits them.

    Peano's own definition: write the index t in base 3 as digits a1 a2 a3 ... a_{2k}; then
    x = 0.a1 k^(a2)(a3) k^(a2+a4)(a5) ...,  y = 0.k^(a1)(a2) k^(a1+a3)(a4) ...  (base 3),
    where k(a) = 2 - a reflects a digit and k^m applies it m times (so only the parity counts).
    """
    order = check_int("order", order, 0, MAX_PEANO_ORDER)
    t = np.arange(9**order, dtype=np.int64)
    digits = [(t // 3 ** (2 * order - 1 - p)) % 3 for p in range(2 * order)]  # a1 .. a_{2k}
    x = np.zeros_like(t)
    y = np.zeros_like(t)
    odd_sum = np.zeros_like(t)  # a1 + a3 + ... so far: reflects the y digits
    even_sum = np.zeros_like(t)  # a2 + a4 + ... so far: reflects the x digits
    for i in range(order):
        a_x, a_y = digits[2 * i], digits[2 * i + 1]
        x = 3 * x + np.where(even_sum % 2 == 1, 2 - a_x, a_x)
        odd_sum += a_x
        y = 3 * y + np.where(odd_sum % 2 == 1, 2 - a_y, a_y)
        even_sum += a_y
    return np.stack([x, y], axis=1)


def hilbert_cells(order: int) -> np.ndarray:
    """Integer cells (x, y) in [0, 2^order)^2 in the order the Hilbert curve visits them.

    The classic index-to-cell conversion: at each scale s = 1, 2, 4, ... two bits of the index
    choose the quadrant, and the cell found so far is rotated / reflected into that quadrant.
    """
    order = check_int("order", order, 0, MAX_HILBERT_ORDER)
    t = np.arange(4**order, dtype=np.int64)
    x = np.zeros_like(t)
    y = np.zeros_like(t)
    s = 1
    while s < 2**order:
        rx = (t // 2) & 1
        ry = (t ^ rx) & 1
        flip = (ry == 0) & (rx == 1)
        x = np.where(flip, s - 1 - x, x)  # reflect within the s x s block
        y = np.where(flip, s - 1 - y, y)
        x, y = np.where(ry == 0, y, x), np.where(ry == 0, x, y)  # rotate (swap axes)
        x = x + s * rx
        y = y + s * ry
        t = t // 4
        s *= 2
    return np.stack([x, y], axis=1)


def peano(order: int) -> np.ndarray:
    """The Peano curve of `order` >= 0: (9^order, 2) cell centres in the unit square, from the cell
    at (0, 0) to the cell at (1, 1); consecutive points are 3^-order apart."""
    cells = peano_cells(order)
    return (cells + 0.5) / 3.0**order


def hilbert(order: int) -> np.ndarray:
    """The Hilbert curve of `order` >= 0: (4^order, 2) cell centres in the unit square, from the
    cell at (0, 0) to the cell at (1, 0); consecutive points are 2^-order apart."""
    cells = hilbert_cells(order)
    return (cells + 0.5) / 2.0**order

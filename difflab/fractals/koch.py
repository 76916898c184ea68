"""The Koch curve and the Koch snowflake (the lecture's "infinitely prickly line").

Each iteration replaces every segment a -> b by four segments of a third of its length, the middle
third raised into the two sides of an equilateral triangle (to the left of the direction of travel).
After n iterations the curve has 4^n segments of length 3^-n: length (4/3)^n, and the snowflake,
three curves on the sides of an equilateral triangle, has perimeter P = 3 (4/3)^n.
"""

from __future__ import annotations

import numpy as np

from ._checks import check_int

# Beyond this the curve has more than 4^12 = 16.8 million segments (hundreds of MiB).
MAX_ITERATIONS = 12
_SIN60 = np.sqrt(3.0) / 2.0


def _refine(points: np.ndarray) -> np.ndarray:
    """One Koch step on a polyline (N, 2) -> (4 (N - 1) + 1, 2)."""
    a, b = points[:-1], points[1:]
    d = (b - a) / 3.0
    d_left = np.stack([-d[:, 1], d[:, 0]], axis=1)  # d turned +90 degrees
    peak = a + 1.5 * d + _SIN60 * d_left  # apex of the equilateral bump on the middle third
    out = np.empty((4 * len(a) + 1, 2))
    out[0:-1:4] = a
    out[1::4] = a + d
    out[2::4] = peak
    out[3::4] = a + 2.0 * d
    out[-1] = points[-1]
    return out


def _koch_polyline(start, iterations: int) -> np.ndarray:
    points = np.asarray(start, dtype=np.float64)
    for _ in range(iterations):
        points = _refine(points)
    return points


def koch(iterations: int) -> np.ndarray:
    """The Koch curve after `iterations` refinements, from (0, 0) to (1, 0), bumps pointing up (+y).

    Arguments:
        iterations: n >= 0 (at most 12).

    Returns:
        (4^n + 1, 2) float64 vertices; consecutive vertices are 3^-n apart, so the length is (4/3)^n.
    """
    n = check_int("iterations", iterations, 0, MAX_ITERATIONS)
    return _koch_polyline([[0.0, 0.0], [1.0, 0.0]], n)


def koch_snowflake(iterations: int) -> np.ndarray:
    """The Koch snowflake on the unit-side equilateral triangle (0, 0), (1/2, sqrt3/2), (1, 0).

    The triangle is walked clockwise so that the bumps point outwards.

    Arguments:
        iterations: n >= 0 (at most 11).

    Returns:
        (3 * 4^n + 1, 2) float64 vertices of the closed polygon; the last vertex repeats the first,
        so `polyline_length` gives the perimeter 3 (4/3)^n.
    """
    n = check_int("iterations", iterations, 0, MAX_ITERATIONS - 1)
    triangle = [[0.0, 0.0], [0.5, _SIN60], [1.0, 0.0], [0.0, 0.0]]
    return _koch_polyline(triangle, n)

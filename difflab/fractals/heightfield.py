"""Fractal height fields after Fournier, Fussell and Carpenter (1982): fractional Brownian surfaces
on a (2^level + 1)^2 grid over the unit square, by recursive subdivision with random displacement.

For fractional Brownian motion with Hurst exponent H the height difference over a lag r has
variance sigma^2 r^(2H): the variogram is a power law with slope 2H in log-log axes. Both
generators place each new point p at the mean of its parents q_i plus a Gaussian displacement with
the variance that fBm gives h(p) - mean(h(q_i)) for that configuration of parents:

    Var = (2/m) sum_i g(|q_i - p|) - (1/m^2) sum_ij g(|q_i - q_j|),   g(r) = sigma^2 r^(2H) / 2

(for the midpoint of a segment of length 2d this is FFC's sigma^2 d^(2H) (1 - 2^(2H-2))). H is in
(0, 1): at H = 1 (g = sigma^2 r^2 / 2, the linear fBm t Z) every symmetric configuration's variance
is 0 -- midpoints, diamonds, squares -- so the surface is the corners' planes, not a fractal. The
displacements are independent, so the surfaces are only approximately fBm: the measured variogram
slope falls short of 2H by up to ~0.05 (diamond-square) and ~0.08 (midpoint, H = 0.8).

Refinement is level-independent: step k turns the 2^(k-1) grid into the 2^k grid and draws its
displacements from a generator seeded by (seed, method, k) alone, in a fixed array of shape
(2^k + 1, 2^k + 1) indexed by the new point's cell. So the grid of level L, read every 2^(L-l)
points, is bitwise the grid of level l from the same seed: coarser levels are exact subsets.
"""

from __future__ import annotations

import math

import numpy as np

from ._checks import FractalError, check_float, check_int

MAX_LEVEL = 12  # 4097^2 = 16.8 million heights
_DIAMOND_SQUARE, _MIDPOINT = 1, 2  # stream tags: the two methods draw independent numbers


def _noise(seed: int, method: int, step: int) -> np.ndarray:
    """The standard normals of refinement `step`, one per cell of the 2^step grid."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, method, step]))
    n = 2**step + 1
    return rng.standard_normal((n, n))


def _std(sigma: float, hurst: float, parents) -> float:
    """std of h(p) - mean(h(q_i)) for fBm, parents q_i given as offsets from p (unit-square units).

    With the semivariogram g(r) = sigma^2 r^(2H) / 2 and weights summing to zero,
    Var = (2/m) sum_i g(|q_i|) - (1/m^2) sum_ij g(|q_i - q_j|).
    """
    q = np.asarray(parents, dtype=np.float64)
    m = len(q)
    g = lambda r: 0.5 * sigma**2 * r ** (2.0 * hurst)  # noqa: E731
    pair = np.linalg.norm(q[:, None, :] - q[None, :, :], axis=-1)
    var = 2.0 / m * np.sum(g(np.linalg.norm(q, axis=1))) - np.sum(g(pair)) / m**2
    return math.sqrt(max(var, 0.0))


def _corners(seed: int, method: int, sigma: float) -> np.ndarray:
    # Independent corners of std sigma / sqrt(2): adjacent corners then differ with variance sigma^2 * 1^(2H).
    return _noise(seed, method, 0) * (sigma / math.sqrt(2.0))


def _check(level, hurst, seed, sigma):
    level = check_int("level", level, 0, MAX_LEVEL)
    hurst = check_float("hurst", hurst, 0.0, 1.0, lo_open=True, hi_open=True)  # H = 1: no displacement (notes)
    seed = check_int("seed", seed, 0)
    sigma = check_float("sigma", sigma, 0.0)
    return level, hurst, seed, sigma


def _upsample(h: np.ndarray) -> np.ndarray:
    """The next grid with the old points at even indices and NaN (to be filled) elsewhere."""
    n = 2 * (h.shape[0] - 1) + 1
    out = np.full((n, n), np.nan)
    out[::2, ::2] = h
    return out


def diamond_square(level: int, hurst: float = 0.8, seed: int = 0, sigma: float = 1.0) -> np.ndarray:
    """Heights on a (2^level + 1)^2 grid over the unit square by the diamond-square algorithm.

    Diamond step: each cell centre gets the mean of the cell's 4 corners (distance d = sqrt2 2^-k).
    Square step: each edge midpoint gets the mean of its 4 (3 on the border) axis neighbours
    (d = 2^-k). Both add the fBm displacement for their parents (see the module notes).

    Arguments:
        level: refinement steps, 0..12.
        hurst: Hurst exponent H in (0, 1); high H is smooth, low H rough (dimension 3 - H).
        seed: integer >= 0; the same (level, hurst, seed, sigma) gives bitwise the same grid.
        sigma: height scale: heights over a lag of one side differ with standard deviation ~sigma.

    Returns:
        (2^level + 1, 2^level + 1) float64 heights; [i, j] is at (x, z) = (j, i) / 2^level.
    """
    level, hurst, seed, sigma = _check(level, hurst, seed, sigma)
    h = _corners(seed, _DIAMOND_SQUARE, sigma)
    for k in range(1, level + 1):
        h = _upsample(h)
        noise = _noise(seed, _DIAMOND_SQUARE, k)
        d = 2.0**-k
        # diamond: centres (odd, odd) from the 4 corners of their cell
        centre = 0.25 * (h[:-2:2, :-2:2] + h[:-2:2, 2::2] + h[2::2, :-2:2] + h[2::2, 2::2])
        h[1::2, 1::2] = centre + _std(sigma, hurst, [(-d, -d), (-d, d), (d, -d), (d, d)]) * noise[1::2, 1::2]
        # square: edge midpoints from their up/down/left/right neighbours inside the grid (3 on the border)
        padded = np.pad(h, 1, constant_values=np.nan)
        neighbours = np.stack([padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]])
        inside = ~np.isnan(neighbours)
        mids = np.isnan(h)
        count = inside.sum(axis=0)[mids]
        mean = np.where(inside, neighbours, 0.0).sum(axis=0)[mids] / count
        std = np.where(count == 4, _std(sigma, hurst, [(-d, 0), (d, 0), (0, -d), (0, d)]),
                       _std(sigma, hurst, [(-d, 0), (d, 0), (0, d)]))
        h[mids] = mean + std * noise[mids]
    return h


def midpoint_displacement(level: int, hurst: float = 0.8, seed: int = 0, sigma: float = 1.0) -> np.ndarray:
    """Heights on a (2^level + 1)^2 grid by Fournier-Fussell-Carpenter triangle subdivision.

    The unit square is two triangles split along the diagonal (0, 0)-(1, 1); each step splits every
    triangle into four at its edge midpoints, and each midpoint gets the mean of its edge's two
    ends plus the fBm displacement for that edge. Shared edges get one midpoint, so the
    surface never cracks. The triangulation is the grid's cells split along the (i, j)-(i+1, j+1)
    diagonal, which is how `terrain` meshes every height grid.

    Arguments and returns as for `diamond_square` (an independent random stream).
    """
    level, hurst, seed, sigma = _check(level, hurst, seed, sigma)
    h = _corners(seed, _MIDPOINT, sigma)
    for k in range(1, level + 1):
        h = _upsample(h)
        noise = _noise(seed, _MIDPOINT, k)
        d = 2.0**-k
        s_axis, s_diag = _std(sigma, hurst, [(-d, 0), (d, 0)]), _std(sigma, hurst, [(-d, -d), (d, d)])
        h[1::2, ::2] = 0.5 * (h[:-2:2, ::2] + h[2::2, ::2]) + s_axis * noise[1::2, ::2]  # edges along i
        h[::2, 1::2] = 0.5 * (h[::2, :-2:2] + h[::2, 2::2]) + s_axis * noise[::2, 1::2]  # edges along j
        h[1::2, 1::2] = 0.5 * (h[:-2:2, :-2:2] + h[2::2, 2::2]) + s_diag * noise[1::2, 1::2]  # diagonals
    return h


def _grid(heights) -> np.ndarray:
    """`heights` as a finite float64 grid of at least 17 x 17, or a FractalError naming it."""
    try:
        h = np.asarray(heights, dtype=np.float64)
    except (TypeError, ValueError):
        raise FractalError(f"heights: expected a 2-D grid of numbers, got {type(heights).__name__}") from None
    if h.ndim != 2 or min(h.shape) < 17:
        raise FractalError(f"heights: expected a 2-D grid of at least 17 x 17, got shape {h.shape}")
    bad = np.count_nonzero(~np.isfinite(h))
    if bad:
        raise FractalError(f"heights: {bad} of {h.size} values are not finite (NaN or inf)")
    return h


def _lags(lags, h: np.ndarray) -> np.ndarray:
    """`lags` as int64 grid steps in [1, smaller side - 1] (the default when None), else a FractalError."""
    longest = min(h.shape) - 1
    if lags is None:
        return 2 ** np.arange(2, max(3, int(np.log2(longest // 4)) + 1))
    arr = np.asarray(lags)
    whole = arr.dtype != bool and (np.issubdtype(arr.dtype, np.integer) or (
        np.issubdtype(arr.dtype, np.floating) and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))))
    if arr.ndim != 1 or arr.size == 0 or not whole or np.any(arr < 1) or np.any(arr > longest):
        raise FractalError(f"lags: expected a list of whole grid steps in [1, {longest}] "
                           f"(a {h.shape[0]} x {h.shape[1]} grid), got {np.asarray(lags).tolist()!r}")
    return arr.astype(np.int64)


def variogram(heights, lags=None) -> tuple[np.ndarray, np.ndarray]:
    """Mean squared height difference against lag along the grid's two axes.

    Arguments:
        heights: (N, N) grid of finite heights, N >= 17.
        lags: integer lags in grid steps, each in [1, N - 1]; default 4, 8, 16, ... up to
            (N - 1) // 4. The two finest octaves are left out by default: there the last
            refinement steps' creases (new points beside new points, each with its own
            displacement) add variance above the power law.

    Returns:
        (lags, gamma) with gamma[k] = mean of (h[i + lag, j] - h[i, j])^2 and (h[i, j + lag] - h[i, j])^2.
    """
    h = _grid(heights)
    lags = _lags(lags, h)
    with np.errstate(over="ignore"):  # reported below, as one error
        gamma = np.array([0.5 * (np.mean((h[r:] - h[:-r]) ** 2) + np.mean((h[:, r:] - h[:, :-r]) ** 2))
                          for r in lags])
    if not np.all(np.isfinite(gamma)):
        raise FractalError("heights: height differences too large to square in float64 (beyond ~1e154)")
    return lags, gamma


def variogram_slope(heights, lags=None) -> float:
    """Least-squares slope of log gamma against log lag: 2H for fractional Brownian surfaces.

    Needs at least 2 different lags (the default gives 1 below 33 x 33) and gamma > 0 at each
    (a flat grid has no slope); otherwise a FractalError names the argument.
    """
    used, gamma = variogram(heights, lags)
    if np.unique(used).size < 2:
        hint = " (the default below 33 x 33: give lags, e.g. [1, 2, 4])" if lags is None else ""
        raise FractalError(f"lags: a slope needs at least 2 different lags, got {used.tolist()}{hint}")
    if np.any(gamma == 0.0):
        raise FractalError(f"heights: no height differences at lag {int(used[gamma == 0.0][0])} "
                           "(gamma = 0, e.g. a flat grid): log gamma has no slope")
    return float(np.polyfit(np.log(used), np.log(gamma), 1)[0])

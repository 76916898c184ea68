"""Measures of fractal sets: polyline length, box counting, and the box-counting dimension.

The box-counting dimension of a set is the slope of log N(s) against log(1/s), where N(s) is the
number of boxes of side s that the set touches. A polyline is first densified so that every box it
crosses contains one of its samples; a boolean image (1-D or 2-D) is counted cell by cell.
"""

from __future__ import annotations

import numpy as np

from ._checks import FractalError


def polyline_length(points) -> float:
    """Sum of the lengths of the segments of a polyline (N, D), N >= 1."""
    points = _as_points(points)
    return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


def _as_points(points) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[0] < 1 or points.shape[1] < 1:
        raise FractalError(f"points: expected shape (N, D) with N >= 1, got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise FractalError("points: contain non-finite values")
    return points


def _densify(points: np.ndarray, spacing: float) -> np.ndarray:
    """Samples along the polyline no more than `spacing` apart (vertices included)."""
    a, b = points[:-1], points[1:]
    lengths = np.linalg.norm(b - a, axis=1)
    pieces = np.maximum(1, np.ceil(lengths / spacing).astype(np.int64))
    seg = np.repeat(np.arange(len(a)), pieces)
    # t = k / pieces for k = 0..pieces-1 within each segment
    starts = np.cumsum(pieces) - pieces
    t = (np.arange(pieces.sum()) - np.repeat(starts, pieces)) / np.repeat(pieces, pieces)
    samples = a[seg] + t[:, None] * (b - a)[seg]
    return np.concatenate([samples, points[-1:]], axis=0)


def _default_sizes_polyline(points: np.ndarray) -> np.ndarray:
    """Box sizes 2^-k from a quarter of the extent down to twice the median segment length."""
    extent = float(np.max(np.ptp(points, axis=0)))
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    finest = 2.0 * float(np.median(seg[seg > 0])) if np.any(seg > 0) else extent
    k_lo = int(np.ceil(np.log2(4.0 / extent))) if extent > 0 else 0
    k_hi = int(np.floor(np.log2(1.0 / finest))) if finest > 0 else k_lo
    return 2.0 ** -np.arange(k_lo, max(k_hi, k_lo + 1) + 1)


def _count_polyline(points: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    samples = _densify(points, float(np.min(sizes)) / 4.0)
    origin = samples.min(axis=0)
    counts = []
    for s in sizes:
        counts.append(_distinct_cells(np.floor((samples - origin) / s).astype(np.int64)))
    return np.asarray(counts, dtype=np.int64)


def _distinct_cells(cells: np.ndarray) -> int:
    """Distinct rows of non-negative integer cells (N, D): each row as one int64 key c_0 + r_0 (c_1 +
    r_1 (...)), r_d = max c_d + 1, counted by one flat sort (a row-wise np.unique is ~5x slower); rows
    whose key would pass 2^62 are counted row-wise."""
    ranges = [int(c) + 1 for c in cells.max(axis=0)]
    if float(np.prod(ranges, dtype=np.float64)) >= 2.0 ** 62:
        return len(np.unique(cells, axis=0))
    keys = np.zeros(len(cells), dtype=np.int64)
    for d in reversed(range(cells.shape[1])):
        keys = keys * ranges[d] + cells[:, d]
    return len(np.unique(keys))


def _count_image(mask: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    counts = []
    for s in sizes.astype(np.int64):
        pad = [(0, (-n) % s) for n in mask.shape]
        m = np.pad(mask, pad)
        if m.ndim == 1:
            boxes = m.reshape(-1, s).any(axis=1)
        else:
            boxes = m.reshape(m.shape[0] // s, s, m.shape[1] // s, s).any(axis=(1, 3))
        counts.append(int(np.count_nonzero(boxes)))
    return np.asarray(counts, dtype=np.int64)


def box_counts(points_or_image, sizes=None) -> tuple[np.ndarray, np.ndarray]:
    """Box sizes and the number of boxes of each size that the set touches.

    Arguments:
        points_or_image: a polyline, (N, D) vertices in world units, D = 1, 2 or 3; or a boolean
            image, 1-D (a row of cells, e.g. `cantor_mask`) or 2-D, whose True cells are the set.
            The dtype decides: bool is an image, numbers are vertices, so a 0/1 integer mask is
            refused with advice (`mask.astype(bool)`) rather than read as a 1-D or many-D polyline.
        sizes: box sides, decreasing. Polylines: world units, default 2^-k from a quarter of the
            extent down to twice the median segment length. Images: whole pixels, default
            2^k from a quarter of the smaller side down to 1. Sizes that match the set's own
            scaling (3^k for the Cantor set) remove the log-periodic wobble of the estimate.

    Returns:
        (sizes, counts) as float64 and int64 arrays.
    """
    data = np.asarray(points_or_image)
    if data.dtype == bool:
        if data.ndim not in (1, 2) or data.size == 0:
            raise FractalError(f"image: expected a non-empty 1-D or 2-D boolean array, got shape {data.shape}")
        if not data.any():
            raise FractalError("image: has no True cells to count")
        if sizes is None:
            k_max = max(1, int(np.floor(np.log2(min(data.shape) / 4.0))))
            sizes = 2 ** np.arange(k_max, -1, -1)
        sizes = np.asarray(sizes)
        if sizes.ndim != 1 or len(sizes) < 2 or np.any(sizes < 1) or np.any(sizes != np.round(sizes)):
            raise FractalError(f"sizes: expected at least two whole pixel sizes >= 1, got {sizes!r}")
        return sizes.astype(np.float64), _count_image(data, sizes.astype(np.int64))
    if data.ndim != 2 or not 1 <= data.shape[1] <= 3:
        raise FractalError(f"points_or_image: got shape {data.shape} of dtype {data.dtype}, neither a polyline "
                           "(N, D) of vertices with D in [1, 3] nor a boolean image: for a mask of 0/1 cells "
                           "pass mask.astype(bool)")
    points = _as_points(data)
    if points.shape[0] < 2:
        raise FractalError("points: a polyline needs at least 2 vertices")
    sizes = _default_sizes_polyline(points) if sizes is None else np.asarray(sizes, dtype=np.float64)
    if sizes.ndim != 1 or len(sizes) < 2 or not np.all(np.isfinite(sizes)) or np.any(sizes <= 0):
        raise FractalError(f"sizes: expected at least two positive box sizes, got {sizes!r}")
    return sizes, _count_polyline(points, sizes)


def box_counting_dimension(points_or_image, sizes=None) -> float:
    """Box-counting dimension: the least-squares slope of log N(s) against log(1/s).

    Arguments and defaults as for `box_counts`. A polyline's finest detail should be a few times
    smaller than the smallest box (e.g. Koch at 7 iterations, Hilbert or Peano at order 6 or 5).

    Returns:
        the dimension estimate, a float (1 for a line, 2 for a filled square).
    """
    sizes, counts = box_counts(points_or_image, sizes)
    slope, _ = np.polyfit(np.log(1.0 / sizes), np.log(counts), 1)
    return float(slope)

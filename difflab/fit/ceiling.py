"""Where a float target clips: its ceiling, found from its values and the surfaces they show.

An image file saturates at 1.0 (`targets.py`); float data (a renderer's .npy or EXR) may have been
clipped anywhere or nowhere. A clip shows as ties at the maximum -- but so does a flat-lit surface:
a floor under a directional light straight down holds kd I at every lit pixel, the image's
maximum. What tells them apart: a highlight clips a minority of its surface's pixels, as it clips
only where the light's reflection peaks, whereas a flat-lit surface holds its one value at most
of them. So the maximum is a ceiling when, in some channel, some surface (the object a pixel's
primary ray hits) has at least CENSOR_MIN_TIES ties there, at fewer than half of its pixels; where every surface with ties holds them at most of its pixels, they are flat-lit surfaces,
no clip. (Counted over all values at once, a red floor's ties -- 95 % of the red channel, 6,578 of
6,912 pixels -- were a third of the values: taken for a clip, every lit pixel censored, the floor's
kd left at its start +- inf. And a surface wholly at the clip -- a small white bulb -- must not
hide a highlight clipped beside it: the red ball's ks came out 0.045 for 0.5, chi2 1.7e6.)
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import FitError

CENSOR_MIN_TIES = 3  # ties at the maximum on one surface (this many, under half its pixels) mark a ceiling
ABOVE_TOLERANCE = 1e-6  # relative: a value within this of a given ceiling is at it (float32 rounds a clip by 6e-8)


def refuse_values_above(ceiling: float, values: np.ndarray, entries: np.ndarray, target: str) -> None:
    """FitError when a given `ceiling` lies below some of a target's used values (U, 3) -- those
    of the entries (U, 3) bool that weigh in --, by more than ABOVE_TOLERANCE relative: a ceiling is
    where the target saturates, so no value can exceed it; fitted under it, those values' residuals
    are (value - ceiling) / sigma (a 1.93 under 1.0: chi2 7e5, a MODEL MISMATCH of exact values)."""
    above = values[entries]
    above = above[above > ceiling * (1.0 + ABOVE_TOLERANCE)]
    if above.size:
        raise FitError(f"ceiling: {ceiling:g} is below {above.size} used value{'s' if above.size > 1 else ''} of "
                       f"{target} (largest {above.max():.3g}); a ceiling is the value the target saturates at -- "
                       "give that value, or ceiling=False where the target does not clip")


def primary_objects(record) -> np.ndarray:
    """(H, W) int: the scene object each pixel's first sample hits (-1: none), from a G-buffer
    (`object`, on its sample grid) or a ray tree (each sample's root node, the first of its nodes)."""
    side = int(record.spp_side)
    if hasattr(record, "sample_offset"):  # a RayTree
        objects = np.asarray(record.object)[record.sample_offset[:-1]].reshape(record.grid_shape)
    else:
        objects = np.asarray(record.object)
    return objects[::side, ::side]


def float_ceiling(values: np.ndarray, surfaces: Callable[[], np.ndarray]) -> float:
    """The ceiling of float target values (U, 3) whose pixels show `surfaces()` (U,) (object ids,
    asked for only when the maximum is tied: ~0.03 ms of a first fit's setup to gather): their
    maximum when it marks a clip (see the module docstring), else inf."""
    if not values.size:
        return np.inf
    peak = float(values.max())
    at_peak = values == peak
    if not peak > 0 or np.count_nonzero(at_peak) < CENSOR_MIN_TIES:
        return np.inf
    ids, surface, size = np.unique(surfaces(), return_inverse=True, return_counts=True)
    for channel in range(values.shape[1]):
        ties = np.bincount(surface.reshape(-1)[at_peak[:, channel]], minlength=ids.size)
        if np.any((ties >= CENSOR_MIN_TIES) & (2 * ties < size)):
            return peak  # a surface clipped at a minority of its pixels: a highlight
    return np.inf  # every surface with ties holds them at most of its pixels: flat-lit, no clip

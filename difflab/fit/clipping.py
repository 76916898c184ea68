"""Noisy targets clipped at a bound: the pixels whose mean the clip moves, left out.

A target clipped at its floor (0: an image file's lowest code, or float data with ties at 0) or at
its ceiling records clip(m + sigma Z) where the model m lies near the bound, and the mean of that is
not m: at the floor

    E[max(m + sigma Z, 0)] - m = sigma phi(m / sigma) - m (1 - Phi(m / sigma))

which is 0.40 sigma at m = 0, 0.08 sigma at m = sigma and 0.008 sigma at m = 2 sigma (the ceiling
likewise). Least squares over such pixels is biased: the dark, ambient-lit side of a sphere with
1-3 % noise, saved as an 8-bit PNG (noise clipped at black), gave ka 15-85 % high at 6-12 standard
errors, reported ok. `clipped_band` finds the used pixels whose fitted, unclipped model lies within
BAND sigma of a bound the target is clipped at; `engine.fit` leaves them out (weight 0) and fits
again from the first solution, counting their values as censored -- unless that would leave no more
entries than unknowns: then the first fit is kept, every parameter flagged poorly determined (its
values rest on clipped noise). Only when the noise is real
(sigma above twice the targets' quantisation floor -- the rms rounding of their used values,
`noise.quantisation`, where a noise-free file's sigma sits --: a noise-free render keeps its pixels,
whose residuals are the rounding there) and the fit has no texels.

A zero is not always clipped noise: where no light reaches a surface and nothing is ambient (the
unlit side of a sphere), the target is 0 because the scene is dark there, and the model is exactly
0 too (N.L <= 0). Such a pixel has no residual and no derivative (every part of the colour is 0),
so it moves nothing and needs no refit. So the floor counts as clipped only where MIN_CLIPPED
target values at 0 sit at channels whose fitted model is > 0 (noise clipped away where the fit
says there is signal), and the band holds only channels whose model is > 0 and < BAND sigma.
"""

from __future__ import annotations

import jax
import numpy as np

from .setup import images_jit

BAND = 2.0  # sigmas: the bias left at the band's edge is under 1 % of sigma a pixel
MIN_CLIPPED = 3  # target values at a bound (this many) mark it clipped there


def clipped_band(setup, result) -> list[np.ndarray] | None:
    """Per view (H, W) bool: the used pixels with a channel whose fitted model lies above the floor
    0 by less than BAND sigma, or within BAND sigma of the ceiling, where the target is clipped
    (MIN_CLIPPED values at that bound -- at the floor, at channels whose model is > 0 -- and none
    below the floor); None when there is none, or the fit failed, has texels, or its noise is no
    more than twice the quantisation floor."""
    sigma = result.sigma
    if not result.converged or not np.isfinite(sigma) or sigma <= 2.0 * setup.sigma_floor or \
            any(p.shape is not None for p in setup.layout):
        return None
    bounds = [_clipped_bounds(view, residual) for view, residual in zip(setup.views, result.residuals)]
    if not any(floor or top for floor, top in bounds):
        return None  # (the model images are formed only for a view clipped at a bound)
    flat = setup.layout.flatten({p.key: np.asarray(result.params[p.key], np.float64).reshape(-1)
                                 for p in setup.layout})
    with jax.enable_x64(setup.x64), setup.on_device():
        images = images_jit(setup.problem, np.asarray(flat, setup.dtype))  # numpy: moved with the call
    bands = []
    for view, image, (floor, top) in zip(setup.views, images, bounds):
        model = np.asarray(image, np.float64)
        near = np.zeros(model.shape, bool)
        if floor:
            near |= (model > 0.0) & (model < BAND * sigma)
        if top:
            near |= np.abs(model - view.ceiling) < BAND * sigma
        band = np.zeros(view.used.shape, bool)
        band.reshape(-1)[view.pixels] = near[:, 0] | near[:, 1] | near[:, 2]  # (any over 3: ~5x slower)
        bands.append(band)
    return bands if any(band.any() for band in bands) else None


def _clipped_bounds(view, residual) -> tuple[bool, bool]:
    """(clipped at the floor, clipped at the ceiling) for a view from its target values and its
    residual image (H, W, 3) at the fit: at the floor, MIN_CLIPPED weighted target values at 0 whose
    residual -- the model itself there -- is > 0, and none below 0; at the ceiling, MIN_CLIPPED
    target values at or above it."""
    target = view.values
    top = bool(np.isfinite(view.ceiling)) and np.count_nonzero(target >= view.ceiling) >= MIN_CLIPPED
    floor = view.floor
    if floor.size < MIN_CLIPPED:
        return False, top
    planes = np.asarray(residual).transpose(2, 0, 1).reshape(-1)  # (the report's planes: no copy)
    return bool(np.count_nonzero(np.take(planes, floor) > 0.0) >= MIN_CLIPPED), top

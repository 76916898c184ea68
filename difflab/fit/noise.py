"""The pixel noise of a fit's targets, from its residual images at the solution (`estimate_sigma`,
`views_noise`), the pixels that carry none (`silent_pixels`), the rounding error of their files'
codes (`quantisation`), and how far a reduced chi-square
against an estimated noise spreads for a correct model (`chi2_spread`). `fit.stats` describes what
the fit reports with them."""

from __future__ import annotations

import math

import numpy as np

from ..io import code_step
from .targets import in_channels

MIN_NOISE_PIXELS = 48  # pixel channels
NOISE_BLOCK = 8  # pixels: the side of the blocks whose median L^2 sets the local noise level
CAP_Z2 = 9.0  # an L^2 above 9 times the local noise level (three standard deviations) counts as that level
MEDIAN_CHI2_1 = 0.454936423119572  # the median of a chi-square of 1 degree of freedom
CAP_MEAN = 0.97340891  # E[z^2 if z^2 <= 9 else 1], z ~ N(0, 1): P(chi2_3 <= 9) + P(chi2_1 > 9)
LAPLACIAN_CORRELATION = 2.0 * (70.0 / 36.0) ** 2  # 7.56: a mean of (L / 6)^2 has variance this / M


def _in_blocks(values: np.ndarray) -> np.ndarray:
    """(rows, columns, 3, NOISE_BLOCK, NOISE_BLOCK) a view of `values` (rows NOISE_BLOCK, columns
    NOISE_BLOCK, 3) by block and channel."""
    b = NOISE_BLOCK
    return values.reshape(values.shape[0] // b, b, values.shape[1] // b, b, 3).transpose(0, 2, 4, 1, 3)


def _magnitudes(image, centre) -> np.ndarray:
    """(rows, columns, 3, NOISE_BLOCK^2) |L|, the 3 x 3 Laplacians of an (h + 2, w + 2, 3) image in
    its own precision (float32 residual images), each block's values of a channel in a row (the
    (h, w) grid padded to whole blocks): inf outside the `centre` entries ((h, w, 3) bool) and in
    the padding, NaN where L is. (The kernel [1 -2 1]^T [1 -2 1] as two second differences,
    a - 2 b + c summed in place: the same roundings, fewer temporaries.)"""
    with np.errstate(invalid="ignore"):  # (inf - inf: NaN, not picked)
        rows2 = image[1:-1] * -2.0
        rows2 += image[:-2]
        rows2 += image[2:]
        b, (h, w) = NOISE_BLOCK, centre.shape[:2]
        lap = np.empty((-(-h // b) * b, -(-w // b) * b, 3), rows2.dtype)
        lap[h:], lap[:h, w:] = np.inf, np.inf  # the padding
        inner = lap[:h, :w]
        np.multiply(rows2[:, 1:-1], -2.0, out=inner)
        inner += rows2[:, :-2]
        inner += rows2[:, 2:]
    np.copyto(inner, np.inf, where=~centre)
    out = np.empty((lap.shape[0] // b, lap.shape[1] // b, 3, b * b), lap.dtype)
    np.abs(_in_blocks(lap), out=out.reshape(out.shape[:3] + (b, b)))
    return out


def _middle(ordered: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(...) the two middle values (the same one for an odd count) of the first `count` (...) of
    each sorted row of `ordered` (..., n); the row's first where count is 0."""
    start = np.arange(0, ordered.size, ordered.shape[-1]).reshape(count.shape)  # each row's first, flat
    return (np.take(ordered, start + np.maximum(count - 1, 0) // 2),
            np.take(ordered, start + count // 2))


def _block_levels(square: np.ndarray, ordered: np.ndarray, count: np.ndarray) -> np.ndarray:
    """(rows, columns, 3, 1) the local noise level of each block and channel of L^2 values `square`
    (rows, columns, 3, NOISE_BLOCK^2), `count` (rows, columns, 3) of them picked, first in each
    block's sorted |L| `ordered` (the others: inf or NaN): the median of its picked values /
    MEDIAN_CHI2_1 (the variance of L where L is Gaussian), or where a block has fewer than
    NOISE_BLOCK^2 / 4 picked values the median of its channel's other blocks' (of all its picked
    values when none has as many, 0 when it has none)."""
    low, high = _middle(ordered, count)
    level = (np.square(low, dtype=np.float64) + np.square(high, dtype=np.float64)) / 2.0
    enough = count >= square.shape[-1] // 4
    whole = np.sort(np.where(enough, level, np.inf).reshape(-1, 3).T, axis=-1)  # (3, blocks)
    whole = sum(_middle(whole, np.count_nonzero(enough, axis=(0, 1)))) / 2.0
    if not enough.any(axis=(0, 1)).all():  # a channel without such a block (a small or sparse image)
        values = np.sort(square.transpose(2, 0, 1, 3).reshape(3, -1), axis=-1)  # (NaN after inf)
        picked = np.sum(count, axis=(0, 1))
        whole = np.where(enough.any(axis=(0, 1)), whole, np.where(picked > 0, sum(_middle(values, picked)) / 2.0, 0.0))
    return (np.where(enough, level, whole) / MEDIAN_CHI2_1)[..., None]


def estimate_sigma(images, used_maps, weight_maps=None, *, interior=True) -> tuple[float, int] | None:
    """The Laplacian noise estimate of (H, W, 3) residual images over their used entries -- only
    those whose 3 x 3 neighbourhood is used, when `interior` --: (sigma, M) with

        sigma^2 = sum_c w_c q_c / (36 CAP_MEAN sum_c w_c),   q_c = L_c^2, or v_c where L_c^2 > 9 v_c

    over the M entries c picked (w_c: the entry's weight from `weight_maps`, (H, W, 3) or None for
    1), or None with fewer than MIN_NOISE_PIXELS. L = R * [1 -2 1; -2 4 -2; 1 -2 1] has variance 36
    times the mean of its nine pixels' noise variances (weighted 1, 4, 16 by position, summing to
    36), so sigma^2 is the weighted mean noise variance -- what a chi-square's mean of w r^2 over
    the same weights compares with, noise that varies over the image (a renderer's, with the
    signal) included (a median level reads the median pixel's: a correct fit of noise proportional
    to the signal gave chi2 2.6-15). A model's sharp errors (an edge, a shadow's penumbra, a
    rim) are kept out: an L^2 above CAP_Z2 = 9 (three standard deviations) times its 8 x 8 block's
    noise level v_c (`_block_levels`) counts as v_c; Gaussian noise keeps CAP_MEAN = 0.973 of its
    mean square so, corrected for. A used map is (H, W) bool (every channel of a used pixel) or (H, W, 3) (per
    channel: where some channels have weight 0, their residuals are 0, not noise, and must not
    enter a neighbourhood). (The kernel is [1 -2 1]^T [1 -2 1]: applied as two second differences,
    over the used pixels' bounding box, laid out by block: one sort of each block's |L|, the cap
    and the sums by broadcasting each block's level over its values.)"""
    num = den = 0.0
    count = 0
    for k, (image, used) in enumerate(zip(images, used_maps)):
        pixels = used if used.ndim == 2 else used[..., 0] | used[..., 1] | used[..., 2]
        rows, cols = np.flatnonzero(pixels.any(axis=1)), np.flatnonzero(pixels.any(axis=0))
        if rows.size == 0 or used.shape[0] < 3 or used.shape[1] < 3:
            continue
        top, left = max(rows[0] - 1, 0), max(cols[0] - 1, 0)  # the box, one pixel wider (non-interior case)
        box = (slice(top, min(rows[-1] + 2, used.shape[0])), slice(left, min(cols[-1] + 2, used.shape[1])))
        used, image = used[box], np.asarray(image)[box]  # in its own precision (float32 residual images)
        if used.shape[0] < 3 or used.shape[1] < 3:
            continue
        centre = used[1:-1, 1:-1]
        if interior:
            across = used[:, :-2] & used[:, 1:-1] & used[:, 2:]
            centre = across[:-2] & across[1:-1] & across[2:]
        magnitude = _magnitudes(image, np.repeat(centre[..., None], 3, axis=2) if centre.ndim == 2 else centre)
        blocks = np.square(magnitude, dtype=np.float64)
        weight = blocks < np.inf  # picked: not inf, NaN, nor beyond float64's range
        picked = np.sum(weight, axis=-1, dtype=np.int32)
        magnitude.sort(axis=-1)  # |L| in order is L^2 in order: each block's median from its half-size |L|
        level = _block_levels(blocks, magnitude, picked)
        np.copyto(blocks, level, where=~(blocks <= CAP_Z2 * level))  # capped; inf and NaN too (weight 0)
        if weight_maps is not None and weight_maps[k] is not None:
            inner = weight_maps[k][box][1:-1, 1:-1]
            padded = np.zeros((blocks.shape[0] * NOISE_BLOCK, blocks.shape[1] * NOISE_BLOCK, 3))
            padded[:inner.shape[0], :inner.shape[1]] = inner
            weight = np.where(weight, _in_blocks(padded).reshape(blocks.shape), 0.0)
        num += float(np.sum(np.multiply(blocks, weight, out=blocks)))  # (no BLAS dot: its threads cost ms)
        den += float(np.sum(weight))
        count += int(np.sum(picked))
    if count < MIN_NOISE_PIXELS or den <= 0:
        return None
    return math.sqrt(num / (36.0 * CAP_MEAN * den)), count


def at_ceiling(image, ceiling) -> np.ndarray:
    """(...) bool: the pixels of an image (..., 3) with a channel at or above `ceiling` (three
    comparisons or'ed: numpy's `any` over a last axis of 3 costs ~10x as much)."""
    top = image >= ceiling
    return top[..., 0] | top[..., 1] | top[..., 2]


def silent_pixels(views, r) -> tuple[list[np.ndarray], int]:
    """The used pixels of a fit's views (`records.View`) that carry no noise: target and model both
    exactly 0 in every channel (an unlit side; a renderer's noise scales with its signal), from the
    flat weighted residuals r over every used entry. Returns per view (U,) bool over its used
    pixels, and how many of their entries have weight > 0 (left out of the chi-square's dof)."""
    out, count, offset = [], 0, 0
    for view in views:
        part = r[offset:offset + 3 * view.pixels.size].reshape(-1, 3)
        offset += 3 * view.pixels.size
        zero = view.zeros & (part == 0)  # black in the target, and the model 0 there too
        rows = zero[:, 0] & zero[:, 1] & zero[:, 2]
        count += 3 * int(np.count_nonzero(rows)) if view.weighting is None else \
            int(np.count_nonzero(np.take(view.entries, np.flatnonzero(rows), axis=0)))
        out.append(rows)
    return out, count


def views_noise(views, residual_images, silent, given: float | None, floor: float, fallback=None,
                quantisation: float = 0.0) -> tuple[float | None, int]:
    """The pixel noise sigma of a fit's views, in the targets' units, and the number of Laplacian
    values M it was estimated from (0 when given or taken from `fallback`): `given` -- the noise
    before quantisation, to which the targets' `quantisation` (the rms rounding error of their used
    values, 0 for float data: one sigma serves every view) is added in quadrature: a correct fit
    of an 8-bit file with its true noise 0.002 given came out at chi2 1.2, flagged -- or estimated
    (`estimate_sigma`, each entry weighted by its view's weight) from the plain residual images
    (H, W, 3) at the solution over the used pixels but the `silent` (per view (U,) bool,
    `silent_pixels`) and the censored ones -- per channel where a weight of 0 leaves a used pixel's
    channel out -- and at least `floor` (the quantisation's, `Setup.sigma_floor`). Where too few pixels allow that:
    `fallback` when given (a refit's, the first fit's sigma), else None (unknown)."""
    if given is not None:
        return (math.hypot(given, quantisation) if quantisation else given), 0
    clean = []
    for i, view in enumerate(views):
        left_out = silent[i] if silent else np.zeros(view.pixels.size, bool)
        if np.isfinite(view.ceiling):
            left_out = left_out | at_ceiling(view.values, view.ceiling)
        clean.append(view.used)
        if left_out.any():
            clean[i] = view.used.copy()
            clean[i].reshape(-1)[view.pixels[left_out]] = False
        if view.weighting is not None and not np.all(view.weights > 0):
            clean[i] = in_channels(clean[i]) & (view.weighting > 0)
    estimate = estimate_sigma(residual_images, clean, [view.weighting for view in views])
    if estimate is None:
        return fallback, 0
    return max(estimate[0], floor), estimate[1]


def quantisation(views) -> float:
    """The rms error that rounding to their files' codes adds to the targets' values, over the used
    entries a fit counts (`View.counted`: weight > 0, below the ceiling) but those of black pixels
    (0 in every channel, as silent pixels are: `silent_pixels`):

        sqrt(sum_c w_c q_c^2 / sum_c w_c),   q_c = `io.code_step`(value_c, step, gamma) / sqrt(12)

    (w_c: the entry's weight), 0 for float data (step 0). q is one code step in linear units at
    the entry's value -- an sRGB file's step is 1 / 12.92 of the sample step in the darks, 2.275
    times it at white --, so the mean is what a chi-square's mean of w r^2 over the same entries
    compares with when the residuals are the rounding: the README's teapot, rendered and saved as
    8-bit sRGB, has residual rms 0.00133 over its 1649 used pixels, this 0.00134, the uniform
    (1 / 255) / sqrt(12) = 0.00113 it was taken for (chi2 1.34, mismatch suspected)."""
    num = den = 0.0
    for view in views:
        black = view.zeros[:, 0] & view.zeros[:, 1] & view.zeros[:, 2]
        keep = view.counted & ~black[:, None]
        weight = None if view.weighting is None else view.weights[keep]
        den += float(np.count_nonzero(keep) if weight is None else np.sum(weight))
        if view.step:
            q2 = np.square(code_step(view.values[keep], view.step, view.gamma))
            num += float(np.sum(q2) if weight is None else np.dot(weight, q2))
    return math.sqrt(num / (12.0 * den)) if den > 0 else 0.0


def chi2_spread(dof: int, noise_values: int = 0) -> float:
    """The standard deviation of a reduced chi-square over dof degrees of freedom for a correct model
    (white noise): sqrt(2 / dof) with sigma known; with sigma estimated from M = `noise_values`
    Laplacians of the same residuals (`estimate_sigma`: a mean of squares of L / 6, whose nine
    taps make neighbouring values correlated, sum of squared correlations (70 / 36)^2 = 3.78), the
    ratio of the two means of squares has variance 2 (3.78) / M + 2 / dof - 2 (2 / dof) (the two
    share the noise: covariance 2 / dof), sqrt(7.56 / M - 2 / dof): 0.015 for the ~24k values of a
    96 x 96 image (Monte Carlo over 20 seeds on fitted scenes' masks: 0.014-0.027, within its own
    16 % spread of this)."""
    if noise_values <= 0:
        return math.sqrt(2.0 / dof)
    return math.sqrt(max(LAPLACIAN_CORRELATION / noise_values - 2.0 / dof, 2.0 / dof))

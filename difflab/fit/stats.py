"""Diagnostics at the solution: the noise level, reduced chi-square, the model-mismatch flag,
standard errors, poorly determined parameters and PSNR.

Noise: `sigma` when given, else estimated from the residual images at the solution by Immerkaer's
Laplacian operator with a robust (median) scale, sigma = 1.4826 median |L| / 6, over the pixels
whose 3 x 3 neighbourhood is all used and uncensored -- per channel where weights of 0 leave some
channels of used pixels out -- (L = R * [1 -2 1; -2 4 -2; 1 -2 1] has standard
deviation 6 sigma for white noise). The Laplacian removes what a wrong model leaves smoothly (an
offset, a gradual shading error), so the estimate sees the noise, not the mismatch. With fewer than
MIN_NOISE_PIXELS such pixels (a small, thin or scattered mask) the noise is unknown -- the residuals
alone cannot tell noise from a model's error -- unless given: the fit then reports sigma and chi2 as
nan and `noise_unknown`, and makes no claim about the model. (A refit without clipped pixels takes
the first fit's estimate.) It is floored at the targets' quantisation: one step / sqrt(12) for targets from
8- or 16-bit files (`Setup.sigma_floor`), FLOAT_SIGMA for float data (float32 rounding of a render is ~1e-7).

    chi2_red = sum_i r_i^2 / (sigma^2 (N - p))

over the N uncensored residual entries and p fitted entries.

Silent pixels: a used pixel whose target and fitted model are both exactly 0 in every channel (the
unlit side of an object without ambient light) carries no noise -- a renderer's noise scales with
its signal, so there is none where there is no light -- and says nothing about sigma: such pixels
are left out of the noise estimate (so are their neighbours, whose Laplacian they would damp), else
a large unlit region pulls the median, and sigma, down and flags a correct fit as a mismatch.
Their entries add exactly 0 to the sum of squares and are left out of N too: the chi-square counts
only the entries that can carry noise, so a correct fit still has chi2_red ~ 1 (and s^2 below
estimates the lit pixels' noise). A pixel zero in only some channels stays in both. Where the noise
level varies over the lit pixels (noise proportional to the signal), sigma is a median level and
chi2_red, a mean square over it, exceeds 1 by the spread: (rms / median of the pixels' sigmas)^2.

`model_mismatch` is set when chi2_red is above 1 + 5 sqrt(2 / (N - p)), its statistical spread
(and, for an estimated sigma, above MISMATCH_CHI2 too: `fit_statistics`): the residuals sit far
above the noise, so the image model does not explain the target (wrong image model, wrong specular
model, missing light...) and the fitted values answer a different question. With N <= p the fit is
`underdetermined`: nothing is left to judge the model or the noise by.

Standard errors are those of linearised least squares, in scene units, and assume the model holds:

    cov = s^2 (J^T J)^-1,   s^2 = sum_i r_i^2 / (N - p)

with J the Jacobian of the plain weighted residuals with respect to the values (J^T J from the
solver, or `normal_equations.linearise`). Directions of J^T J that are numerically singular (after scaling its
columns to unit norm) give an infinite standard error to every parameter they involve. A texture's
smoothness prior is not in J^T J (its rows are not residuals of the images): the standard errors are
what the pixels alone determine, linearised at the regularised solution -- a texel only the prior
fills is inf.

A matrix-free fit (more than `FitOptions` DENSE_MAX entries: texels) forms J sparse by column
compression (`sparse_jacobian`) and `covariance_diagonal` inverts J^T J per connected block
(`inverse_diagonal`: banded with the scalars by Schur complement, else sparse LU), dense eigh where
a block is singular; the same numbers as the dense path's, to rounding. Nan where too costly: a
block of more than SPARSE_STATS_MAX entries (or more than `inverse_diagonal.LU_MAX` whose band is
too wide), a singular one of more than DENSE_STATS_MAX. Measured (`experiments/bench/fit_stderr.py`,
2 shared cores, load 2-4): a bilinear texture channel's block takes 0.45 s at 4096 entries, 0.84 s
at 8100 (the limit: a 90 x 90 texture's channel), 1.5 s at 16384 (by SuperLU: 0.1 s at 1024, 1.75
s at 4096, 7 s at 8100); eigh 0.07-0.7 s at 768, 0.5-7 s at 1536 (the limit), 1.5-9.6 s at 2048,
14-25 s at 3072. A fit's statistics phase: 0.03-0.16 s for a 16 x 16 texture, 0.12-0.18 s for a
32 x 32 one (texture alone or with ks), against 0.002-0.009 s without standard errors.

A parameter is *poorly determined* when, even at a noise floor of one 8-bit quantisation step, its
standard error exceeds `rel_tol` |value| + `abs_tol` in some channel. A specular exponent (n, or
roughness m) and the ks of the same material are only read from a highlight together, so when one
of them is poorly determined, so is the other.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import ArpackError, eigsh

from .inverse_diagonal import inverse_diagonal
from .normal_equations import dense, linearise
from .targets import in_channels

QUANTISATION_SIGMA = 1.0 / (255.0 * math.sqrt(12.0))
FLOAT_SIGMA = 1e-5
MISMATCH_CHI2 = 2.0
MIN_NOISE_PIXELS = 48  # pixel channels
SINGULAR_RCOND = 1e-12
PACKED_MAX = 256  # blocks of J^T J inverted dense (eigh) together, up to this many entries
SPARSE_STATS_MAX = 8192  # the most entries of one block of J^T J inverted sparse (measured below)
DENSE_STATS_MAX = 1536  # the most entries of a singular block inverted dense (eigh; measured below)


def median(values: np.ndarray):
    """`np.median` of a 1-D array of finite values, the same number, reordering `values` in place: one
    partition at the upper middle and the largest value below it (numpy partitions at both middles,
    ~10x slower: 0.66 against 0.06 ms for 70k values)."""
    half = values.size // 2
    values.partition(half)
    if values.size % 2:
        return values[half]
    return (values[:half].max() + values[half]) / 2  # in the values' precision, as np.mean of the two


def estimate_sigma(images, used_maps, *, interior=True) -> float | None:
    """The robust Laplacian noise estimate of (H, W, 3) images over their used entries -- only those
    whose 3 x 3 neighbourhood is used, when `interior` -- or None with fewer than MIN_NOISE_PIXELS.
    A used map is (H, W) bool (every channel of a used pixel) or (H, W, 3) (per channel: where some
    channels have weight 0, their residuals are 0, not noise, and must not enter a neighbourhood).
    (The Laplacian kernel is [1 -2 1]^T [1 -2 1]: applied as two second differences, over the used
    pixels' bounding box.)"""
    values = []
    for image, used in zip(images, used_maps):
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
        rows2 = image[1:-1] * -2.0  # a - 2 b + c, summed in place (the same roundings, fewer temporaries)
        rows2 += image[:-2]
        rows2 += image[2:]
        lap = rows2[:, 1:-1] * -2.0
        lap += rows2[:, :-2]
        lap += rows2[:, 2:]
        if centre.ndim == 2:
            picked = np.compress(centre.reshape(-1), lap.reshape(centre.size, -1), axis=0).reshape(-1)
        else:
            picked = lap[centre]
        values.append(np.abs(picked, out=picked))
    values = values[0] if len(values) == 1 else np.concatenate(values or [np.zeros(0)])
    if not np.isfinite(values).all():
        values = values[np.isfinite(values)]
    return float(1.4826 * median(values) / 6.0) if values.size >= MIN_NOISE_PIXELS else None


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
                quantisation: float = 0.0) -> float | None:
    """The pixel noise sigma of a fit's views: `given` -- the noise before quantisation, to which
    the targets' `quantisation` (the coarsest file target's code step / sqrt(12), 0 for float data:
    one sigma serves every view) is added in
    quadrature: a correct fit of an 8-bit file with its true noise 0.002 given came out at chi2
    1.2, flagged -- or estimated from the residual images
    (H, W, 3) at the solution over the used pixels but the `silent` (per view (U,) bool,
    `silent_pixels`) and the censored ones -- per channel where a weight of 0 leaves a used pixel's
    channel out -- and at least `floor` (the quantisation's). Where too few pixels allow that:
    `fallback` when given (a refit's, the first fit's sigma), else None (unknown)."""
    if given is not None:
        return math.hypot(given, quantisation) if quantisation else given
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
    estimate = estimate_sigma(residual_images, clean)
    if estimate is None:
        estimate = fallback
    return None if estimate is None else max(estimate, floor)


@eqx.filter_jit
def _normal_matrix(problem, values):
    """(J^T J, r) of the plain weighted residuals with respect to the values."""
    if problem.loss == "l2" and not problem.smoothness:  # residuals(x) = weighted(values(x)): by parts if it applies
        x = jnp.where(problem.layout.entries("log") > 0, jnp.log(values), values)
        r, gram, _ = linearise(x, problem)
        scale = jnp.where(problem.layout.entries("log") > 0, values, 1.0)
        return gram / (scale[:, None] * scale[None, :]), r
    r, gram, _ = dense(lambda v, p: p.weighted(v), values, problem)
    return gram, r


def normal_matrix(problem, values, solved=None) -> tuple[np.ndarray, np.ndarray]:
    """(J^T J (p, p) float64, r (N,)) of the plain weighted residuals r, J their Jacobian with
    respect to the flat values, over all residual entries: from `solved` = (r, J^T J with respect
    to the solver coordinates x) when the solver returned them for the l2 loss without a texture
    prior (d value / d x = value for log coordinates), else computed (one compiled call)."""
    if solved is not None and problem.loss == "l2" and not problem.smoothness:  # no prior rows in the solver's
        r, gram_x = (np.asarray(a, np.float64) for a in solved)
        log = problem.layout.entries("log") > 0
        scale = np.where(log, np.asarray(values, np.float64), 1.0)
        return gram_x / (scale[:, None] * scale), r  # (np.outer: the same product, slower)
    gram, r = _normal_matrix(problem, values)
    return np.asarray(gram, np.float64), np.asarray(r, np.float64)


def covariance_unscaled(gram: np.ndarray, top: float | None = None) -> np.ndarray:
    """(J^T J)^-1 from J^T J (p, p), with singular directions given infinite variance. Returns
    (p, p); the diagonal is inf for parameters that a singular direction involves. Singular: an
    eigenvalue of the unit-diagonal J^T J at most SINGULAR_RCOND times its largest, or `top` when
    `gram` is a diagonal block of a larger J^T J (`covariance_diagonal`) whose largest that is."""
    norms = np.sqrt(np.maximum(np.diagonal(gram), 0.0))
    zero = norms == 0
    scale = 1.0 / np.where(zero, 1.0, norms)  # (1 for a zero column)
    outer = scale[:, None] * scale
    eigval, eigvec = np.linalg.eigh(gram * outer)
    top = max(float(eigval.max(initial=0.0)) if top is None else top, 1e-300)
    singular = eigval <= SINGULAR_RCOND * top
    inv = np.where(singular, 0.0, 1.0 / np.where(singular, 1.0, eigval))
    cov = (eigvec * inv) @ eigvec.T * outer
    infinite = zero | (np.abs(eigvec[:, singular]) > 1e-6).any(axis=1) if singular.any() else zero
    if infinite.any():
        cov[infinite, :] = np.inf
        cov[:, infinite] = np.inf
    return cov


def covariance_diagonal(gram, skip=None) -> np.ndarray:
    """diag (J^T J)^-1 (p,) as `covariance_unscaled` gives it, from J^T J (p, p): a numpy array, or a
    scipy.sparse matrix (a matrix-free fit's, `sparse_jacobian`); nan at the entries `skip` (p,)
    bool -- whole blocks left out (`sparse_jacobian.stats_blocks`) -- the rest from the others alone.

    A sparse one of up to PACKED_MAX entries is made dense. A larger one is split into its connected
    blocks (entries no residual couples: a texture's channels, texels far apart without a scalar
    beside them, a texel no pixel sees), each judged singular against the largest eigenvalue of the
    whole unit-diagonal J^T J: blocks of up to PACKED_MAX entries by `covariance_unscaled`, packed
    together; larger ones, up to SPARSE_STATS_MAX entries, by `inverse_diagonal` (banded or sparse
    LU) -- or, where that finds a singular direction, by `covariance_unscaled`
    when the block has at most DENSE_STATS_MAX entries. Nan (no standard errors: too costly) on a
    block above SPARSE_STATS_MAX entries, and on a singular one above DENSE_STATS_MAX (which entries
    its singular directions involve takes the block's eigenvectors).

    The largest eigenvalue comes from ARPACK; where that fails (no convergence), from Gershgorin's
    bound (the largest absolute row sum), which is at least the eigenvalue: a block judged regular
    against it is regular against the eigenvalue too."""
    if skip is not None and skip.any():  # (an empty column: inf, as `covariance_unscaled` has it)
        diag = np.where(skip, np.nan, np.inf)
        kept = np.flatnonzero(~skip & (gram.diagonal() > 0))
        if kept.size:
            diag[kept] = covariance_diagonal(gram[kept][:, kept])
        return diag
    if not sp.issparse(gram):
        return np.diag(covariance_unscaled(gram))
    if gram.shape[0] <= PACKED_MAX:
        return np.diag(covariance_unscaled(gram.toarray()))
    gram = gram.tocsr()
    norms = np.sqrt(np.maximum(gram.diagonal(), 0.0))
    scale = 1.0 / np.where(norms == 0, 1.0, norms)
    unit = sp.diags(scale) @ gram @ sp.diags(scale)
    try:
        top = float(eigsh(unit, k=1, which="LA", return_eigenvectors=False)[0])
    except ArpackError:  # no convergence; a J^T J of empty columns (every texel unseen)
        top = float(abs(unit).sum(axis=1).max())
    _, label = connected_components(unit, directed=False)
    blocks = np.split(np.argsort(label, kind="stable"), np.cumsum(np.bincount(label))[:-1])
    diag, packed, packed_size = np.full(gram.shape[0], np.nan), [], 0
    for block in blocks + [np.zeros(0, np.int64)]:  # (an empty block ends the last pack)
        if packed and (not block.size or packed_size + block.size > PACKED_MAX):
            index = np.concatenate(packed)
            diag[index] = np.diag(covariance_unscaled(gram[index][:, index].toarray(), top))
            packed, packed_size = [], 0
        if 0 < block.size <= PACKED_MAX:
            packed.append(block)
            packed_size += block.size
        elif PACKED_MAX < block.size <= SPARSE_STATS_MAX:
            diag[block] = inverse_diagonal(unit[block][:, block], top, SINGULAR_RCOND) * scale[block] ** 2
            if np.isnan(diag[block[0]]) and block.size <= DENSE_STATS_MAX:  # singular
                diag[block] = np.diag(covariance_unscaled(gram[block][:, block].toarray(), top))
    return diag


def finite_gram(gram) -> bool:
    """Whether every entry of J^T J (dense or sparse) is finite."""
    return bool(np.all(np.isfinite(gram.data if sp.issparse(gram) else gram)))


def standard_errors(diag: np.ndarray, sigma2: float) -> np.ndarray:
    """sqrt(diag (J^T J)^-1 * sigma2), inf where the diagonal is (and everywhere for sigma2 inf: an
    underdetermined fit's unknown noise); nan where the diagonal is nan (not formed)."""
    if math.isinf(sigma2):
        return np.where(np.isnan(diag), np.nan, np.inf)
    finite = np.isfinite(diag)
    return np.where(finite, np.sqrt(np.where(finite, np.maximum(diag, 0.0), 0.0) * sigma2), diag)


def fit_statistics(gram, sse: float, entries: int, censored: int, sigma: float, size: int, silent: int = 0,
                   sigma_given: bool = False, skip=None) -> dict:
    """s2 = sse / dof (sse: the sum of squares of the `entries` residuals r; dof = N - p, N entries
    neither censored nor `silent` (noise-free zeros), p = `size` fitted entries the data reach -- a
    texel no pixel reads is not one), chi2 = s2 / sigma^2
    (reduced; nan when sigma is: the noise unknown, the model is not judged), the mismatch flag, and
    diag (J^T J)^-1 (p,) from gram = J^T J (p, p), dense or sparse (`covariance_diagonal`; nan at
    `skip`).

    The flag is raised when chi2 exceeds 1 + 5 sqrt(2 / dof) (five standard deviations of a reduced
    chi-square) and, for an estimated sigma, MISMATCH_CHI2 too: an estimate is a median level, which
    noise that varies over the image (a renderer's, proportional to the signal) lifts chi2 above 1
    by the spread. A given sigma is taken as the truth: POV-Ray's brilliance 1.2 (outside the
    model) fitted with its true sigma 0.01 gave chi2 1.83 over ~3600 entries and was not flagged.
    With dof <= 0 (no more counted entries than unknowns: `underdetermined`) the residuals say
    nothing about the noise or the model: chi2 nan, no flag, s2 = sigma^2 where sigma is known,
    else inf."""
    p = size
    dof = entries - censored - silent - p
    if dof <= 0:
        known = math.isfinite(sigma) and sigma > 0
        return {"s2": sigma * sigma if known else math.inf, "chi2": math.nan, "mismatch": False,
                "diag": covariance_diagonal(gram, skip), "underdetermined": True}
    s2 = sse / dof
    chi2 = math.nan if math.isnan(sigma) else s2 / (sigma * sigma) if sigma > 0 else math.inf
    spread = 1.0 + 5.0 * math.sqrt(2.0 / dof)
    mismatch = bool(chi2 > (spread if sigma_given else max(MISMATCH_CHI2, spread)))
    return {"s2": s2, "chi2": chi2, "mismatch": mismatch, "diag": covariance_diagonal(gram, skip),
            "underdetermined": False}


def poorly_determined(layout, values: dict, stderr_floor: dict, rel_tol=0.1, abs_tol=1e-3, also=()) -> list[str]:
    """Keys of parameters whose noise-floor standard error exceeds rel_tol |value| + abs_tol (inf:
    undetermined; nan, not formed, flags nothing), with ks and n (or m) of one material flagged
    together, and the keys `also` (the textures with texels no pixel sees)."""
    value, err = (layout.flatten(d) for d in (values, stderr_floor))  # every entry at once
    over = np.isinf(err) | (err > rel_tol * np.abs(value) + abs_tol)
    flagged, offset = set(also), 0
    for p in layout:
        if over[offset:offset + p.size].any():
            flagged.add(p.key)
        offset += p.size
    for p in layout:  # the specular pair of a material
        if p.kind in ("ks", "n", "m") and p.key in flagged:
            for q in layout:
                if q.index == p.index and q.kind in ("ks", "n", "m"):
                    flagged.add(q.key)
    return [p.key for p in layout if p.key in flagged]


def psnr(sse: float, weight_total: float) -> float:
    """10 log10(1 / MSE), MSE = sse / weight_total, sse the sum of squares of the weighted residuals
    (peak 1): inf for a perfect fit, -inf when the error overflows, nan without weight."""
    if weight_total <= 0:
        return float("nan")
    mse = sse / weight_total
    if not math.isfinite(mse):
        return float("-inf")
    return float("inf") if mse == 0 else 10.0 * math.log10(1.0 / mse)

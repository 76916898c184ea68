"""Diagnostics at the solution: the noise level, reduced chi-square, the model-mismatch flag,
standard errors, poorly determined parameters and PSNR.

Noise: `sigma` when given, else estimated from the residual images at the solution by Immerkaer's
Laplacian operator with a robust (median) scale, sigma = 1.4826 median |L| / 6, over the pixels
whose 3 x 3 neighbourhood is all used and uncensored (L = R * [1 -2 1; -2 4 -2; 1 -2 1] has standard
deviation 6 sigma for white noise). The Laplacian removes what a wrong model leaves smoothly (an
offset, a gradual shading error), so the estimate sees the noise, not the mismatch. With fewer than
MIN_NOISE_PIXELS such pixels the targets themselves are used (smooth shading adds a little: an
upper estimate). It is floored at the targets' quantisation: one 8-bit step / sqrt(12) for
integer-coded targets, FLOAT_SIGMA for float data (float32 rounding of a render is ~1e-7).

    chi2_red = sum_i r_i^2 / (sigma^2 (N - p))

over the N uncensored residual entries and p fitted entries. `model_mismatch` is set when
chi2_red > MISMATCH_CHI2 (and above 1 + 5 sqrt(2 / (N - p)), its statistical spread): the residuals
sit far above the noise, so the image model does not explain the target (wrong image model, wrong
specular model, missing light...) and the fitted values answer a different question.

Standard errors are those of linearised least squares, in scene units, and assume the model holds:

    cov = s^2 (J^T J)^-1,   s^2 = sum_i r_i^2 / (N - p)

with J the Jacobian of the plain weighted residuals with respect to the values (jax.jacfwd through
the value -> image map). Directions of J^T J that are numerically singular (after scaling its
columns to unit norm) give an infinite standard error to every parameter they involve.

A parameter is *poorly determined* when, even at a noise floor of one 8-bit quantisation step, its
standard error exceeds `rel_tol` |value| + `abs_tol` in some channel. A specular exponent (n, or
roughness m) and the ks of the same material are only read from a highlight together, so when one
of them is poorly determined, so is the other.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

QUANTISATION_SIGMA = 1.0 / (255.0 * math.sqrt(12.0))
FLOAT_SIGMA = 1e-5
MISMATCH_CHI2 = 2.0
MIN_NOISE_PIXELS = 48  # pixel channels
SINGULAR_RCOND = 1e-12
LAPLACIAN = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])


def estimate_sigma(images, used_maps, *, interior=True) -> float | None:
    """The robust Laplacian noise estimate of (H, W, 3) images over their used pixels -- only those
    whose 3 x 3 neighbourhood is used, when `interior` -- or None with fewer than MIN_NOISE_PIXELS."""
    values = []
    for image, used in zip(images, used_maps):
        h, w = used.shape
        if h < 3 or w < 3:
            continue
        centre = used[1:-1, 1:-1]
        if interior:
            centre = np.logical_and.reduce([used[i:h - 2 + i, j:w - 2 + j] for i in range(3) for j in range(3)])
        lap = sum(LAPLACIAN[i, j] * image[i:h - 2 + i, j:w - 2 + j] for i in range(3) for j in range(3))
        values.append(np.abs(lap[centre]).reshape(-1))
    values = np.concatenate(values) if values else np.zeros(0)
    values = values[np.isfinite(values)]
    return float(1.4826 * np.median(values) / 6.0) if values.size >= MIN_NOISE_PIXELS else None


@eqx.filter_jit
def _linearised(problem, values):
    r, jvp = jax.linearize(problem.weighted, values)
    return r, jax.vmap(jvp, out_axes=1)(jnp.eye(values.shape[0], dtype=values.dtype))


def jacobian(problem, values, solved=None) -> tuple[np.ndarray, np.ndarray]:
    """(J (N, p) float64, r (N,)) of the plain weighted residuals with respect to the flat values,
    over all residual entries: from `solved` = (r, J with respect to the solver coordinates x) when
    the solver returned them for the l2 loss (d value / d x = value for log coordinates), else
    computed (one compiled call)."""
    if solved is not None and problem.loss == "l2":
        r, jac_x = (np.asarray(a, np.float64) for a in solved)
        log = problem.layout.entries("log") > 0
        values = np.asarray(values, np.float64)
        return jac_x / np.where(log, values, 1.0), r
    r, jac = _linearised(problem, values)
    return np.asarray(jac, np.float64), np.asarray(r, np.float64)


def covariance_unscaled(jac: np.ndarray) -> np.ndarray:
    """(J^T J)^-1 with singular directions given infinite variance. Returns (p, p); the diagonal
    is inf for parameters that a singular direction involves."""
    p = jac.shape[1]
    norms = np.linalg.norm(jac, axis=0)
    zero = norms == 0
    scale = np.where(zero, 1.0, 1.0 / np.where(zero, 1.0, norms))
    jtj = (jac * scale).T @ (jac * scale)
    eigval, eigvec = np.linalg.eigh(jtj)
    top = max(float(eigval.max(initial=0.0)), 1e-300)
    singular = eigval <= SINGULAR_RCOND * top
    inv = np.where(singular, 0.0, 1.0 / np.where(singular, 1.0, eigval))
    cov = (eigvec * inv) @ eigvec.T * np.outer(scale, scale)
    infinite = zero | (np.abs(eigvec[:, singular]) > 1e-6).any(axis=1) if p else zero
    cov[infinite, :] = np.inf
    cov[:, infinite] = np.inf
    return cov


def standard_errors(diag: np.ndarray, sigma2: float) -> np.ndarray:
    """sqrt(diag (J^T J)^-1 * sigma2), inf where the diagonal is."""
    finite = np.isfinite(diag)
    return np.where(finite, np.sqrt(np.where(finite, np.maximum(diag, 0.0), 0.0) * sigma2), np.inf)


def fit_statistics(jac: np.ndarray | None, r: np.ndarray, censored: int, sigma: float, size: int = 0) -> dict:
    """s2 = sse / dof (dof = N - p, N uncensored entries), chi2 = s2 / sigma^2 (reduced), the
    mismatch flag (chi2 above max(MISMATCH_CHI2, 1 + 5 sqrt(2 / dof))), and diag (J^T J)^-1 (p,);
    jac None (a matrix-free fit of p = `size` entries): diag nan, no covariance is formed."""
    p = jac.shape[1] if jac is not None else size
    sse = float(np.sum(r * r))
    dof = max(r.size - censored - p, 1)
    s2 = sse / dof
    chi2 = s2 / (sigma * sigma) if sigma > 0 else math.inf
    mismatch = bool(chi2 > max(MISMATCH_CHI2, 1.0 + 5.0 * math.sqrt(2.0 / dof)))
    diag = np.diag(covariance_unscaled(jac)) if jac is not None else np.full(p, np.nan)
    return {"s2": s2, "chi2": chi2, "mismatch": mismatch, "diag": diag}


def poorly_determined(layout, values: dict, stderr_floor: dict, rel_tol=0.1, abs_tol=1e-3) -> list[str]:
    """Keys of parameters whose noise-floor standard error exceeds rel_tol |value| + abs_tol, with
    ks and n (or m) of one material flagged together."""
    flagged = set()
    for p in layout:
        value = np.abs(np.asarray(values[p.key], np.float64).reshape(-1))
        err = np.asarray(stderr_floor[p.key]).reshape(-1)
        if not np.all(np.isfinite(err)) or np.any(err > rel_tol * value + abs_tol):
            flagged.add(p.key)
    for p in layout:  # the specular pair of a material
        if p.kind in ("ks", "n", "m") and p.key in flagged:
            for q in layout:
                if q.index == p.index and q.kind in ("ks", "n", "m"):
                    flagged.add(q.key)
    return [p.key for p in layout if p.key in flagged]


def psnr(r: np.ndarray, weight_total: float) -> float:
    """10 log10(1 / MSE) of weighted residuals r (peak 1): inf for a perfect fit, -inf when the
    error overflows, nan without weight."""
    if weight_total <= 0:
        return float("nan")
    with np.errstate(over="ignore", invalid="ignore"):
        mse = float(np.sum(np.square(r)) / weight_total)
    if not math.isfinite(mse):
        return float("-inf")
    return float("inf") if mse == 0 else 10.0 * math.log10(1.0 / mse)

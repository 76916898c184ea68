"""Diagnostics at the solution: standard errors, poorly determined parameters, loss and PSNR.

Standard errors are those of linearised least squares, in scene units:

    cov = sigma^2 (J^T J)^-1,   sigma^2 = sum_i r_i^2 / (count - p)

with J the Jacobian of the plain weighted residuals sqrt(w) (model - target) with respect to the
parameter values (not the solver's unconstrained ones: jax.jacfwd through the value -> image map is
the chain rule). Directions of J^T J that are numerically singular (after scaling its columns to
unit norm) give an infinite standard error to every parameter they involve.

A parameter is *poorly determined* when, even at a noise floor of one 8-bit quantisation step
(sigma >= 1 / (255 sqrt 12)), its standard error exceeds `rel_tol` |value| + `abs_tol` in some
channel. A specular exponent (n, or roughness m) and the ks of the same material are only read from
a highlight together, so when one of them is poorly determined, so is the other.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import numpy as np

QUANTISATION_SIGMA = 1.0 / (255.0 * math.sqrt(12.0))
SINGULAR_RCOND = 1e-12


@eqx.filter_jit
def _jacobian(problem, values):
    return jax.jacfwd(problem.weighted_residuals)(values), problem.weighted_residuals(values)


def jacobian(problem, values: dict, layout) -> tuple[np.ndarray, np.ndarray]:
    """(J (count, p) float64, r (count,)) over the residual entries with weight > 0."""
    weights = np.concatenate([np.asarray(v.sqrt_weight).reshape(-1) for v in problem.views])
    used = weights > 0
    jac, residuals = _jacobian(problem, values)
    columns = []
    for p in layout:
        block = np.concatenate([np.asarray(j[p.key], np.float64).reshape(-1, p.size) for j in jac])
        columns.append(block[used])
    r = np.concatenate([np.asarray(x, np.float64).reshape(-1) for x in residuals])
    return np.concatenate(columns, axis=1), r[used]


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


def standard_errors(problem, values: dict, layout) -> dict:
    """The statistics at `values`: sigma2, stderr (key -> array), stderr at the noise floor,
    count (residual entries used), sse (sum of squared plain residuals)."""
    jac, r = jacobian(problem, values, layout)
    count, p = r.size, jac.shape[1]
    sse = float(np.sum(r * r))
    sigma2 = sse / max(count - p, 1)
    cov = covariance_unscaled(jac)
    diag = np.diag(cov)
    floor2 = max(sigma2, QUANTISATION_SIGMA ** 2)
    stderr, stderr_floor, offset = {}, {}, 0
    for prm in layout:
        block = diag[offset:offset + prm.size]
        finite = np.isfinite(block)
        stderr[prm.key] = np.where(finite, np.sqrt(np.where(finite, block, 0.0) * sigma2), np.inf)
        stderr_floor[prm.key] = np.sqrt(block * floor2)
        offset += prm.size
    return {"sigma2": sigma2, "stderr": stderr, "stderr_floor": stderr_floor, "count": count, "sse": sse}


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


def psnr(problem, values: dict) -> float:
    """10 log10(1 / MSE) over the weighted pixel channels used (peak 1); inf for a perfect fit."""
    r = np.concatenate([np.asarray(x, np.float64).reshape(-1) for x in problem.weighted_residuals(values)])
    w = np.concatenate([np.asarray(v.sqrt_weight, np.float64).reshape(-1) ** 2 for v in problem.views])
    total = float(w.sum())
    if total <= 0:
        return float("nan")
    mse = float(np.sum(r * r) / total)
    return float("inf") if mse == 0 else 10.0 * math.log10(1.0 / mse)

"""Variable projection: the image is affine in ka, kd and ks once the rest (n, m, f0, ...) and the
geometry are fixed, so solve those exactly and search only over the nonlinear rest.

    r(k, theta) = A(theta) k + b(theta)                    (plain weighted residuals)
    k*(theta)   = argmin_k |A k + b|^2                     (normal equations, columns scaled)
    theta*      = argmin_theta |A(theta) k*(theta) + b(theta)|^2     (box Levenberg-Marquardt)

A and b come from the same residuals as every other solver (A = dr/dk, exact because r is affine in
k; b = r at k = 0), so nothing here restates the image model. The linear solve is unconstrained;
when a coefficient comes out negative, the box Levenberg-Marquardt solver polishes from the clipped
solution, which brings it onto its bound 0.
"""

from __future__ import annotations

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import FitError
from . import lm
from .normal_equations import dense
from .params import KINDS

RIDGE = {True: 1e-13, False: 1e-6}  # relative ridge on the scaled normal equations, by x64


def check_applicable(problem) -> None:
    """FitError unless the problem's residuals are affine in some of its parameters."""
    if problem.loss != "l2":
        raise FitError("solver: varpro needs loss='l2' (a robust loss is not linear least squares)")
    if any(p.kind == "intensity" for p in problem.layout):
        raise FitError("solver: varpro cannot fit light intensities (intensity x k is not linear)")
    for view in problem.views:
        if view.ceiling is not None or getattr(getattr(view.model, "formation", None),
                                                                   "clamp_colors", False):
            raise FitError("solver: varpro needs an unclipped image (clipped targets and Gouraud vertex-colour "
                           "clamping are not linear); use 'lm'")
    if not any(KINDS[p.kind].linear for p in problem.layout):
        raise FitError("solver: varpro needs at least one of ka, kd, ks among the params")


def _linear_mask(layout) -> np.ndarray:
    return np.concatenate([np.full(p.size, KINDS[p.kind].linear) for p in layout])


def solve_linear(problem, x):
    """(x with its linear entries replaced by k*, the plain residual at k*) for the nonlinear
    entries of x fixed."""
    linear = _linear_mask(problem.layout)
    lin_idx = np.flatnonzero(linear)
    dtype = x.dtype
    base = jnp.where(linear, 0.0, x)

    def flat(k):
        return problem.weighted(problem.layout.values(base.at[lin_idx].set(k)))

    zeros = jnp.zeros(lin_idx.size, dtype)
    b = flat(zeros)
    a = jax.jacfwd(flat)(zeros)
    norms = jnp.sqrt(jnp.sum(a * a, axis=0))
    scale = jnp.where(norms > 0, 1.0 / jnp.where(norms > 0, norms, 1.0), 0.0)
    a_scaled = a * scale
    gram = a_scaled.T @ a_scaled + RIDGE[dtype == jnp.float64] * jnp.eye(lin_idx.size, dtype=dtype)
    k = scale * jnp.linalg.solve(gram, -(a_scaled.T @ b))
    return base.at[lin_idx].set(k), b + a @ k


@eqx.filter_jit
def _solve_reduced(problem, x0, lower, upper, max_steps, rtol, atol, progress):
    nonlinear = np.flatnonzero(~_linear_mask(problem.layout))

    def reduced(theta, p):
        return solve_linear(p, x0.at[nonlinear].set(theta))[1]

    theta, code, steps, history, _, _ = lm.box_lm(lm.squared(partial(dense, reduced)), x0[nonlinear],
                                                  lower[nonlinear], upper[nonlinear], problem, max_steps=max_steps,
                                                  rtol=rtol, atol=atol, progress=progress)
    x, _ = solve_linear(problem, x0.at[nonlinear].set(theta))
    return x, code, steps, history


def run_varpro(problem, x0: np.ndarray, options, progress):
    """(x, result name, steps, loss history) by variable projection, polished by box LM when a
    linear coefficient came out negative."""
    check_applicable(problem)
    rtol, atol = options.tolerances()
    dtype = problem.ambient.dtype
    lower, upper = (jnp.asarray(b, dtype) for b in problem.layout.bounds())
    x, code, steps, history = _solve_reduced(problem, jnp.asarray(x0, dtype), lower, upper, options.max_steps, rtol,
                                             atol, progress)
    x, steps = np.asarray(x, np.float64), int(steps)
    history = np.asarray(history, np.float64)[:steps].tolist() if options.history else []
    lo, hi = problem.layout.bounds()
    if lm.CODES[int(code)] == "successful" and (np.any(x < lo) or np.any(x > hi)):
        x, code, more, extra, _, _ = lm.solve_box(problem, jnp.asarray(np.clip(x, lo, hi), dtype), lower, upper,
                                            options.max_steps, rtol, atol, progress)
        x, steps = np.asarray(x, np.float64), steps + int(more)
        history += np.asarray(extra, np.float64)[:int(more)].tolist() if options.history else []
    return x, lm.CODES[int(code)], steps, history

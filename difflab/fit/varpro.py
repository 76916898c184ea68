"""Variable projection: the image is affine in ka, kd and ks once the rest (n, m, f0, ...) and the
geometry are fixed, so solve those exactly and search only over the nonlinear rest.

    r(k, theta) = A(theta) k + b(theta)                    (plain weighted residuals)
    k*(theta)   = argmin_k |A k + b|^2                     (normal equations, columns scaled)
    theta*      = argmin_theta |A(theta) k*(theta) + b(theta)|^2     (box Levenberg-Marquardt)

A and b come from the same residuals as every other solver (A = dr/dk, exact because r is affine in
k; b = r at k = 0), so nothing here restates the image model. The linear solve is unconstrained;
when a coefficient comes out negative, the box Levenberg-Marquardt solver polishes from the clipped
solution, which brings it onto its bound 0. With no nonlinear parameter (params ka, kd, ks only)
there is no outer search: k* is the fit, reported as 0 steps (a fit's steps are the outer search's,
as everywhere here: the linear solve is part of each of them), plus the polish's steps when a
coefficient came out of its bounds.

Clipping is not linear. A target with a ceiling that no counted value reaches (an 8- or 16-bit file
below its white) is solved unclipped (`Problem.without_ceilings`), which is the clipped problem's
solution wherever the fitted model stays below the ceilings (`Problem.below_ceilings`); where it
ends at or above one at a counted entry, or a target value reaches its ceiling, varpro raises
FitError: solver "lm" fits such targets, the pixels at the ceiling counted as censored.
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
        if getattr(getattr(view.model, "formation", None), "clamp_colors", False):
            raise FitError("solver: varpro needs an unclamped image (Gouraud vertex-colour clamping is not "
                           "linear); use solver='lm'")
    if not any(KINDS[p.kind].linear for p in problem.layout):
        raise FitError("solver: varpro needs at least one of ka, kd, ks among the params")


def unclipped(problem):
    """The problem varpro solves: `problem` when no target has a ceiling, else the same without its
    ceilings (`Problem.without_ceilings`); FitError when a target value reaches its ceiling."""
    if all(view.ceiling is None for view in problem.views):
        return problem
    out = problem.without_ceilings()
    if out is None:
        clipped = sum(int(np.count_nonzero(np.asarray(view.target) >= np.asarray(view.ceiling)))
                      for view in problem.views if view.ceiling is not None)
        raise FitError(f"solver: varpro needs an unclipped target, and {clipped} target values reach their ceiling "
                       "(the value where it clips: 1.0 for an 8- or 16-bit file; clipped values are censored, not "
                       "linear); use solver='lm', which fits them as censored")
    return out


def _linear_mask(layout) -> np.ndarray:
    return np.concatenate([np.full(p.size, KINDS[p.kind].linear) for p in layout])


def solve_linear(problem, x):
    """(x with its linear entries replaced by k*, the plain residual at k*) for the nonlinear
    entries of x fixed; a coefficient no residual depends on (ka under no ambient light) keeps its
    value in x, as in "lm"."""
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
    k = jnp.where(norms > 0, scale * jnp.linalg.solve(gram, -(a_scaled.T @ b)), x[lin_idx])  # unseen: as it was
    return base.at[lin_idx].set(k), b + a @ k


_solve_direct = eqx.filter_jit(solve_linear)  # every parameter linear: k* from anywhere


@eqx.filter_jit
def _weighted(problem, x):
    return problem.weighted(problem.layout.values(x))


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
    linear coefficient came out negative; FitError when the problem is not linear in its ka, kd, ks
    (`check_applicable`, a clipped target: see the module's docstring)."""
    check_applicable(problem)
    solved = unclipped(problem)
    rtol, atol = options.tolerances()
    dtype = problem.ambient.dtype
    lower, upper = (jnp.asarray(b, dtype) for b in problem.layout.bounds())
    if np.all(_linear_mask(problem.layout)):
        x, r = _solve_direct(solved, jnp.asarray(x0, dtype))
        code, steps, history = lm.SUCCESSFUL if np.all(np.isfinite(np.asarray(r))) else lm.NONFINITE, 0, []
    else:
        x, code, steps, history = _solve_reduced(solved, jnp.asarray(x0, dtype), lower, upper, options.max_steps,
                                                 rtol, atol, progress)
        history = np.asarray(history, np.float64)[:int(steps)].tolist()
    x, steps = np.asarray(x, np.float64), int(steps)
    history = history if options.history else []
    lo, hi = problem.layout.bounds()
    if lm.CODES[int(code)] == "successful" and (np.any(x < lo) or np.any(x > hi)):
        x, code, more, extra, _, _ = lm.solve_box(solved, jnp.asarray(np.clip(x, lo, hi), dtype), lower, upper,
                                                  options.max_steps, rtol, atol, progress)
        x, steps = np.asarray(x, np.float64), steps + int(more)
        history += np.asarray(extra, np.float64)[:int(more)].tolist() if options.history else []
    if solved is not problem and not problem.below_ceilings(_weighted(solved, jnp.asarray(x, dtype))):
        raise FitError("solver: varpro's fit puts the model at or above a target's ceiling (the value where it "
                       "clips: 1.0 for an 8- or 16-bit file) at a pixel that counts, where the target is below it: "
                       "clipping is not linear; use solver='lm', which fits those pixels as censored")
    return x, lm.CODES[int(code)], steps, history

"""Variable projection: the image is affine in ka, kd and ks once n, m and f0 are fixed, so solve
those exactly and search only over the nonlinear rest.

    r(k, theta) = A(theta) k + b(theta)                    (plain weighted residuals)
    k*(theta)   = argmin_k |A k + b|^2                     (normal equations, columns scaled)
    theta*      = argmin_theta |A(theta) k*(theta) + b(theta)|^2     (Levenberg-Marquardt)

A and b come from the same image formation as every other solver (A = dr/dk, exact because r is
affine in k; b = r at k = 0), so nothing here restates the illumination model. The linear solve is
unconstrained: if a coefficient comes out negative, `fit_material` polishes the clipped solution with
the general Levenberg-Marquardt solver, which keeps it >= 0.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from ..errors import FitError
from .params import COLOR_PARAMS, to_value
from .solve import RESULT_NAMES

RIDGE = {True: 1e-13, False: 1e-6}  # relative ridge on the scaled normal equations, by x64


def check_applicable(problem, layout) -> None:
    """FitError unless the problem is affine in its colour parameters."""
    if problem.loss != "l2":
        raise FitError("solver: varpro needs loss='l2' (a robust loss is not linear least squares)")
    if any(p.kind == "intensity" for p in layout):
        raise FitError("solver: varpro cannot fit light intensities (intensity x k is not linear)")
    for v in problem.views:
        if v.clip or v.formation.clamp_colors:
            raise FitError("solver: varpro needs an unclamped image (8-bit targets and Gouraud vertex-colour "
                           "clamping are not linear); use 'lm'")
    if not any(p.kind in COLOR_PARAMS for p in layout):
        raise FitError("solver: varpro needs at least one of ka, kd, ks among the params")


def _split(layout):
    linear = tuple(p for p in layout if p.kind in COLOR_PARAMS)
    nonlinear = tuple(p for p in layout if p.kind not in COLOR_PARAMS)
    return linear, nonlinear


def solve_linear(problem, layout, nl_values: dict):
    """(k*: key -> values, flattened residual at k*) for fixed nonlinear values."""
    linear, _ = _split(layout)
    dtype = problem.ambient.dtype
    zeros = {p.key: jnp.zeros(p.size, dtype) for p in linear}

    def flat(lin):
        return jnp.concatenate([r.reshape(-1) for r in problem.weighted_residuals({**nl_values, **lin})])

    b = flat(zeros)
    jac = jax.jacfwd(flat)(zeros)
    a = jnp.concatenate([jac[p.key].reshape(b.shape[0], p.size) for p in linear], axis=1)
    norms = jnp.sqrt(jnp.sum(a * a, axis=0))
    scale = jnp.where(norms > 0, 1.0 / jnp.where(norms > 0, norms, 1.0), 0.0)
    a_scaled = a * scale
    gram = a_scaled.T @ a_scaled
    gram = gram + RIDGE[dtype == jnp.float64] * jnp.eye(gram.shape[0], dtype=dtype)
    k = scale * jnp.linalg.solve(gram, -(a_scaled.T @ b))
    out, offset = {}, 0
    for p in linear:
        out[p.key] = k[offset:offset + p.size]
        offset += p.size
    return out, b + a @ k


def _reduced_residuals(u, args):
    problem, layout = args
    _, nonlinear = _split(layout)
    nl_values = {p.key: to_value(p, u[p.key]) for p in nonlinear}
    _, r = solve_linear(problem, layout, nl_values)
    return r


@eqx.filter_jit
def _solve_reduced(solver, u0, problem, layout, max_steps):
    sol = optx.least_squares(_reduced_residuals, solver, u0, args=(problem, layout), max_steps=max_steps,
                             throw=False)
    return sol.value, sol.result._value, sol.stats["num_steps"]


_solve_linear_jit = eqx.filter_jit(solve_linear)


def run_varpro(solver, u0: dict, problem, layout, max_steps: int):
    """(values in scene units, result name, steps) by variable projection."""
    _, nonlinear = _split(layout)
    if not nonlinear:
        lin, _ = _solve_linear_jit(problem, layout, {})
        return dict(lin), "successful", 1
    u_nl = {p.key: u0[p.key] for p in nonlinear}
    u, code, steps = _solve_reduced(solver, u_nl, problem, layout, int(max_steps))
    nl_values = {p.key: to_value(p, u[p.key]) for p in nonlinear}
    lin, _ = _solve_linear_jit(problem, layout, nl_values)
    return {**dict(lin), **nl_values}, RESULT_NAMES[int(code)], int(steps)

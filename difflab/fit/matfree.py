"""Matrix-free solves, for fits with too many entries for a dense Jacobian (a texture's texels).

"lm" becomes the box-constrained Levenberg-Marquardt of `lm.py` with the step's normal equations
solved by conjugate gradients instead of a Cholesky factorisation of J^T J:

    (J_F^T J_F + lambda D) dx = -J_F^T r         over the free entries F (fixed ones: dx = 0)

where J v and J^T v come from one linearisation per step (never the N x p matrix; for texels the
image's affine form, `texels.affine_residuals`: per product the texture lookups times one gain per
residual, not the shading model) and an entry is fixed when it sits on a bound and the gradient
pushes it outward. D is diag(J^T J) for the few entries beside the texels (their columns formed
each step: ks, n, ...) and s = |J g|^2 / |g|^2, the curvature along the first gradient, for the
texels (whose columns are alike); CG is preconditioned
by D + lambda D (Jacobi), so the texels and the scalars converge together. CG stops when its
residual is below atol + rtol |J^T r| (as lineax's). The step is projected onto the box; lambda
follows Nielsen's rule, and the stopping tests are `lm.py`'s. "gauss_newton" and "dogleg" use
optimistix's solvers with lineax's CG on the normal equations (`normal_cg`). A step costs one
linearisation, up to `cg_steps` pairs of J v / J^T v, and one residual evaluation.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import FitError
from .lm import LAMBDA0, MAX_STEPS, NONFINITE, RUNNING, SUCCESSFUL

DENSE_SOLVERS = ("bfgs", "varpro")  # keep p x p matrices (BFGS's inverse Hessian) or dense Jacobians


def check_solver(options, layout) -> None:
    """FitError when the fit is matrix-free and its solver needs dense p x p matrices."""
    if options.matrix_free(layout.size) and options.solver in DENSE_SOLVERS:
        raise FitError(f"solver: {options.solver!r} forms dense {layout.size} x {layout.size} matrices; a fit of "
                       f"{layout.size} entries (texels) is solved matrix-free by 'lm', 'gauss_newton', 'dogleg' or "
                       "'adam' (or set linear_solver='dense' to force it)")


def normal_cg(rtol: float, atol: float, cg_steps: int):
    """lineax's conjugate gradients on the normal equations J^T J dx = -J^T r (matrix-free)."""
    import lineax as lx

    return lx.Normal(lx.CG(rtol=rtol, atol=atol, max_steps=cg_steps))


class State(NamedTuple):
    x: jnp.ndarray
    loss: jnp.ndarray
    lam: jnp.ndarray
    nu: jnp.ndarray
    scale: jnp.ndarray
    step: jnp.ndarray
    code: jnp.ndarray
    history: jnp.ndarray


def box_lm_cg(fn, x0, lower, upper, args, *, max_steps: int, rtol, atol, cg_steps: int, exact=(), progress=None):
    """Minimise 0.5 |fn(x, args)|^2 over lower <= x <= upper without forming the Jacobian.

    Arguments and returns as `lm.box_lm`, without r and J: (x, code index into `lm.CODES`, steps,
    history); cg_steps: the most CG iterations per step (until the CG residual is below
    atol + rtol |J^T r|); exact: indices of the few entries (not texels) whose
    Jacobian columns are formed each step, to scale them (Jacobi) -- the rest share s."""
    dtype = x0.dtype
    exact = np.asarray(exact, np.int64)
    x0 = jnp.clip(x0, lower, upper)
    r0 = fn(x0, args)
    loss0 = 0.5 * jnp.sum(r0 * r0)
    state = State(x0, loss0, jnp.asarray(LAMBDA0, dtype), jnp.asarray(2.0, dtype), jnp.asarray(0.0, dtype),
                  jnp.asarray(0), jnp.where(jnp.isfinite(loss0), RUNNING, NONFINITE),
                  jnp.full(max_steps, jnp.nan, dtype))

    def body(s: State) -> State:
        r, jvp, vjp, columns = linearisation(fn, exact, s.x, args)
        g = vjp(r)
        free = ~(((s.x <= lower) & (g > 0)) | ((s.x >= upper) & (g < 0)))
        g_free = jnp.where(free, g, 0.0)
        jg = jvp(g_free)
        gg = jnp.sum(g_free * g_free)
        scale = jnp.where(s.scale > 0, s.scale, jnp.where(gg > 0, jnp.sum(jg * jg) / jnp.where(gg > 0, gg, 1.0), 1.0))
        diag = jnp.full_like(s.x, scale)
        if exact.size:  # the few entries beside the texels: their exact columns' squared norms
            diag = diag.at[exact].set(jnp.maximum(jnp.sum(columns * columns, axis=1), 1e-12 * scale))
        damping = s.lam * diag

        def normal(v):
            v_free = jnp.where(free, v, 0.0)
            return jnp.where(free, vjp(jvp(v_free)) + damping * v_free, v)

        def jacobi(v):
            return jnp.where(free, v / (diag + damping), v)

        # CG until its residual is below atol + rtol |g| (as lineax's CG): near the solution rounding
        # would keep it from the relative test alone.
        dx, _ = jax.scipy.sparse.linalg.cg(normal, -g_free, tol=rtol, atol=atol, maxiter=cg_steps, M=jacobi)
        dx = jnp.where(jnp.isfinite(dx), dx, 0.0)
        x_new = jnp.clip(s.x + dx, lower, upper)
        d = x_new - s.x
        jd = jvp(d)
        r_new = fn(x_new, args)
        loss_new = 0.5 * jnp.sum(r_new * r_new)
        accept = jnp.isfinite(loss_new) & (loss_new < s.loss)
        predicted = -(g @ d + 0.5 * jnp.sum(jd * jd))
        rho = (s.loss - loss_new) / jnp.where(predicted > 0, predicted, 1.0)
        lam = jnp.where(accept, s.lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), s.lam * s.nu)
        nu = jnp.where(accept, 2.0, 2.0 * s.nu)
        small_step = jnp.all(jnp.abs(d) <= atol + rtol * jnp.abs(s.x))
        tol_loss = rtol * s.loss + atol * atol
        small_change = ((s.loss - loss_new) <= tol_loss) & (predicted <= tol_loss)
        step = s.step + 1
        code = jnp.where(small_step | (accept & small_change), SUCCESSFUL,
                         jnp.where(step >= max_steps, MAX_STEPS, RUNNING))
        loss = jnp.where(accept, loss_new, s.loss)
        if progress is not None:
            jax.debug.callback(progress, step, loss)
        return State(jnp.where(accept, x_new, s.x), loss, lam, nu, scale, step, code,
                     s.history.at[s.step].set(loss))

    out = jax.lax.while_loop(lambda s: s.code == RUNNING, body, state)
    return out.x, out.code, out.step, out.history


def linearisation(fn, exact, x, args):
    """r, J v, J^T u and the `exact` entries' Jacobian columns (E, N) of fn(., args) at x, from one
    `jax.linearize` (each product runs the linearised model; for texels its affine form,
    `texels.affine_residuals`)."""
    r, jvp = jax.linearize(lambda y: fn(y, args), x)
    transpose = jax.linear_transpose(jvp, x)
    columns = jax.vmap(jvp)(jnp.eye(x.shape[0], dtype=x.dtype)[exact]) if exact.size else None
    return r, jvp, lambda u: transpose(u)[0], columns


@eqx.filter_jit
def solve_box_cg(problem, x0, lower, upper, max_steps, rtol, atol, cg_steps, progress=None):
    """`box_lm_cg` on a `Problem`'s residuals, compiled once per problem structure and settings."""
    exact = np.flatnonzero(np.concatenate([np.full(p.size, p.shape is None) for p in problem.layout]))
    return box_lm_cg(lambda x, p: p.residuals(x), x0, lower, upper, problem, max_steps=max_steps, rtol=rtol, atol=atol,
                     cg_steps=cg_steps, exact=exact, progress=progress)

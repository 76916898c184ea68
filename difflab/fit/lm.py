"""Box-constrained (projected) Levenberg-Marquardt: the default solver.

Each step forms 0.5 |r|^2, J^T J and J^T r at the current point x (`normal_equations.linearise`: by
forward mode, or in closed form where the image is a sum of known parts; `moments.linearise`: from
sums over the pixels, most of them formed once per solve, where no target is clipped) and solves the
damped normal equations over the free entries

    (J^T J + lambda D) dx = -J^T r,     D = diag(J^T J) (floored),

where an entry is *fixed* when it sits on a bound and the gradient pushes it outward; the step is
projected onto the box, x' = clip(x + dx, lower, upper). A step that lowers the loss 0.5 |r|^2 is
taken and lambda shrinks by Nielsen's rule; otherwise lambda grows -- by Nielsen's factor nu, and at
least to the value whose step is t times as long as the one rejected, t in [0.1, 0.5] the minimum of
the quadratic through the loss at x, its slope along the step and the loss at its end (MINPACK's
trust-region cut, `shrinking_damping`, for up to SPECTRUM_MAX entries): where lambda is far below the
curvature of the direction that failed (n along a faint lobe), nu alone rejected 5 steps in a row
(the Mitsuba diffuse sphere of `bench/fit.py`: 11 steps -> 8; 41 fits of random plastics -- clean,
noisy and clipped -- matte targets from glossy starts and that sphere: 253 steps -> 235, the worst
22 -> 18). So a coefficient whose best value is 0 lands on 0 in one projected step and stays there,
instead of crawling along a softplus.

Stops with "successful" when the next step would change every entry by at most atol + rtol |x|
(tested before the step is taken: a solve that has landed on its minimum is not linearised once more
at a point it would not move from), or when an accepted step lowered the loss -- and the linear model
predicted it would lower it -- by at most rtol of itself (MINPACK's xtol / ftol tests);
"nonlinear_max_steps_reached" after max_steps; "nonfinite" when the loss, J^T J or J^T r at the
start is not finite. A trial step where one is not is rejected like any step that does not lower
the loss, so the point returned always has finite ones (a fit with an infinite loss is never
successful, and a NaN in J^T J never stalls the solve on steps it cannot solve for). Each
step costs one linearisation and one p x p Cholesky solve, as a plain Gauss-Newton step does; the
residual vector is not carried from step to step (only its loss), but formed once at the solution
(with the exact J^T J there, where the steps used `normal_equations`' fast form; the moments' r
too, though their steps form it: kept with each accepted point it cost a select over every entry a
step, 0.1 ms of a 1.7 ms solve of 24768 pixels).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from . import moments
from .normal_equations import by_parts_applies, has_fast_form, linearise

CODES = ("successful", "nonlinear_max_steps_reached", "nonfinite")
SUCCESSFUL, MAX_STEPS, NONFINITE = 0, 1, 2
LAMBDA0 = 1e-3
LAMBDA0_BY_PARTS = 1e-6  # the by-parts model is affine in ka, kd, ks: a first step near Gauss-Newton's
SPECTRUM_MAX = 64  # entries up to which a rejection's cut is formed (its eigh: 0.36 ms at 64, 1.2 at 128)
RUNNING = -1


class State(NamedTuple):
    x: jnp.ndarray
    a: jnp.ndarray
    g: jnp.ndarray
    loss: jnp.ndarray
    lam: jnp.ndarray
    nu: jnp.ndarray
    step: jnp.ndarray
    code: jnp.ndarray
    history: jnp.ndarray
    d: jnp.ndarray
    predicted: jnp.ndarray
    carry: tuple


def free_diagonal(a, g, x, lower, upper):
    """The entries a step may move (not on a bound with the gradient pushing outward) and the
    damping's D = diag(J^T J), floored at 1e-9 of its largest entry (+1e-20): a parameter no pixel
    sees still gets a (huge) damping."""
    held = ((x <= lower) & (g > 0)) | ((x >= upper) & (g < 0))
    diag = jnp.diagonal(a)
    return ~held, jnp.maximum(diag, 1e-9 * jnp.max(diag) + 1e-20)


def projected_step(x, a, g, lam, lower, upper):
    """The damped Gauss-Newton step from x, projected onto the box: d = clip(x + dx) - x with
    (A + lam D) dx = -g over the free entries (an entry on its bound with the gradient pushing
    outward is held), and the decrease of 0.5 |r|^2 the linear model predicts for it,
    -(g.d + 0.5 d.A d). Where the damped matrix is not positive definite to its rounding (the
    Cholesky factor is not finite), d = 0 and the decrease predicted is NaN: the step is made and
    rejected, so lambda grows (it is no sign of convergence)."""
    free, diag = free_diagonal(a, g, x, lower, upper)
    damping = jnp.where(free, lam * diag, 1.0)
    m = jnp.where(free[:, None] & free[None, :], a, 0.0) + jnp.diag(damping)
    dx = jsl.cho_solve(jsl.cho_factor(m), jnp.where(free, -g, 0.0))
    solved = jnp.all(jnp.isfinite(dx))
    d = jnp.clip(x + jnp.where(solved, dx, 0.0), lower, upper) - x
    return d, jnp.where(solved, -(g @ d + 0.5 * d @ (a @ d)), jnp.nan)


def shrinking_damping(a, g, x, lower, upper, lam, shrink):
    """The damping lambda' >= lam whose step from x (`projected_step`'s, before the projection) is
    `shrink` times as long as lam's, in the scaled norm |D^(1/2) dx| -- a trust region cut by that
    factor (More's lmpar in MINPACK). With D^(-1/2) A D^(-1/2) = V diag(w) V^T over the free entries and
    c = V^T D^(-1/2) g, |D^(1/2) dx(lambda)|^2 = sum c_i^2 / (w_i + lambda)^2; Newton's iteration on
    1 / |D^(1/2) dx| - 1 / target, nearly linear in lambda, rises monotonically to the root from lam."""
    free, diag = free_diagonal(a, g, x, lower, upper)
    scale = jnp.sqrt(diag)
    w, v = jnp.linalg.eigh(jnp.where(free[:, None] & free[None, :], a / jnp.outer(scale, scale), 0.0))
    c2 = jnp.square(v.T @ jnp.where(free, g / scale, 0.0))
    w = jnp.maximum(w, 0.0)
    norm2 = lambda lam_: jnp.sum(c2 / jnp.square(w + lam_))  # noqa: E731
    target = shrink * jnp.sqrt(norm2(lam))

    def newton(_, lam_):
        n2 = norm2(lam_)
        slope = jnp.sum(c2 / (w + lam_) ** 3) / n2 ** 1.5
        return jnp.maximum(lam_ + (1.0 / target - 1.0 / jnp.sqrt(n2)) / slope, lam_)

    # a loop, not unrolled: XLA's CPU code runs a loop this small as one call (its small-while
    # hoisting); unrolled, its 16 reductions are 16 thunks on the step's path (+0.02-0.1 ms a solve)
    out = jax.lax.fori_loop(0, 8, newton, lam)
    return jnp.where(jnp.isfinite(out), out, lam)


def squared(linearise):
    """A linearisation (x, args) -> (r, J^T J, J^T r) as `box_lm` takes it: (0.5 |r|^2, J^T J, J^T r),
    its carry passed on."""
    def out(x, args, carry):
        r, a, g = linearise(x, args)
        return 0.5 * jnp.sum(r * r), a, g, carry

    return out


def box_lm(linearise, x0, lower, upper, args, *, max_steps: int, rtol, atol, progress=None, residuals=None,
           exact=None, lambda0=LAMBDA0, carry=()):
    """Minimise 0.5 |r(x)|^2 over lower <= x <= upper.

    Arguments:
        linearise: (x (p,), args, carry) -> (0.5 |r|^2, J^T J (p, p), J^T r (p,), carry) at x
            (`squared` of `normal_equations.linearise` or `normal_equations.dense` of any residual
            function, or `moments.linearise`); the carry it returns is the next step's.
        x0: (p,) start (clipped into the box); lower, upper: (p,) bounds (+-inf allowed).
        max_steps: the most steps (static); rtol, atol: the stopping tolerances above.
        progress: None, or a host callable (step, loss) called after each step.
        residuals: (x, args) -> r (N,; any pytree: `moments.residuals`), formed at the solution
            (None: r is not returned).
        exact: None, or (x, args) -> (r, J^T J, ...) whose J^T J is exact where `linearise`'s only
            steers the steps: r and J^T J at the solution are taken from it instead.
        lambda0: the starting damping (relative to diag(J^T J)): LAMBDA0, Marquardt's; the solves
            on the closed-form normal equations start at LAMBDA0_BY_PARTS (Madsen, Nielsen and
            Tingleff's choice for a start close to the solution in the model's terms: the image is
            affine in ka, kd and ks) -- one step fewer on 3 of 11 recoveries, more on none
            (`experiments/fit_recovery.py`, the Mitsuba diffuse sphere of `bench/fit.py`).
        carry: the first step's carry: buffers the linearisation writes in place, the loop carrying
            them from step to step (`moments.scratch`); () for none.
    Returns:
        (x, code index into CODES, steps, history (max_steps,) the loss after each step (NaN beyond),
        r (N,) (or None) and J^T J (p, p) at x).
    """
    dtype = x0.dtype
    x0 = jnp.clip(x0, lower, upper)
    small = lambda d, x: jnp.all(jnp.abs(d) <= atol + rtol * jnp.abs(x))  # noqa: E731 (MINPACK's xtol)
    p = x0.shape[0]
    # Step -1 only evaluates the start (a step d = 0, so the model is linearised in one place of the
    # program). Each step ends by solving for the next one, d, which the loop's test reads. The
    # residuals are not carried from step to step (only their loss): r at the solution is formed
    # once at the end.
    state = State(x0, jnp.zeros((p, p), dtype), jnp.zeros(p, dtype), jnp.asarray(jnp.inf, dtype),
                  jnp.asarray(lambda0, dtype), jnp.asarray(2.0, dtype), jnp.asarray(-1), jnp.asarray(RUNNING),
                  jnp.full(max_steps, jnp.nan, dtype), jnp.zeros(p, dtype), jnp.asarray(0.0, dtype), carry)

    def body(s: State) -> State:
        first = s.step < 0
        d, predicted = s.d, s.predicted
        x_new = jnp.clip(s.x + d, lower, upper)  # (x + (clip(x + dx) - x) can pass a bound by an ulp)
        loss_new, a_new, g_new, carry_new = linearise(x_new, args, s.carry)
        finite = jnp.isfinite(loss_new) & jnp.all(jnp.isfinite(g_new)) & jnp.all(jnp.isfinite(a_new))
        accept = finite & ((loss_new < s.loss) | first)
        rho = (s.loss - loss_new) / jnp.where(predicted > 0, predicted, 1.0)
        # a rejected step: the quadratic through the loss at x, its slope along d and the loss at
        # x + d puts the minimum at t d, t in [0.1, 0.5] (MINPACK's rule): the next step is cut to t
        # of this one's length -- Nielsen's lam * nu alone needs many rejections to do that where
        # lam is far below the scale of the direction that failed
        slope = s.g @ d
        t = jnp.clip(-0.5 * slope / (loss_new - s.loss - slope), 0.1, 0.5)
        t = jnp.where(finite & jnp.isfinite(t), t, 0.1)
        rejected_lam = s.lam * s.nu
        if p <= SPECTRUM_MAX:  # (larger fits keep Nielsen's)
            # formed on a rejection only (a cond; jnp.where took both sides): its eigh and the thunks
            # around it, 10-40 us a step (the bench's sphere, 1 rejection in 8 steps: XLA's CPU time a
            # solve 2.57 -> 2.45 ms, solves 10 ms apart)
            rejected_lam = jax.lax.cond(accept | first, lambda: rejected_lam, lambda: jnp.maximum(
                rejected_lam, shrinking_damping(s.a, s.g, s.x, lower, upper, s.lam, t)))
        lam = jnp.where(first, s.lam, jnp.where(accept, s.lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3),
                                                 rejected_lam))
        nu = jnp.where(accept, 2.0, 2.0 * s.nu)
        tol_loss = rtol * s.loss + atol * atol
        small_change = ((s.loss - loss_new) <= tol_loss) & (predicted <= tol_loss)
        done = ~first & accept & small_change
        step = s.step + 1
        # The start must have a finite loss; a trial step whose loss is not finite is only rejected.
        code = jnp.where(first & ~finite, NONFINITE, jnp.where(done, SUCCESSFUL,
                                                                jnp.where(step >= max_steps, MAX_STEPS, RUNNING)))
        keep = lambda new, old: jnp.where(accept, new, old)  # noqa: E731
        loss = keep(loss_new, s.loss)
        if progress is not None:
            jax.debug.callback(progress, step, loss)
        history = jnp.where(first, s.history, s.history.at[jnp.maximum(s.step, 0)].set(loss))
        x, a, g = keep(x_new, s.x), keep(a_new, s.a), keep(g_new, s.g)
        return State(x, a, g, loss, lam, nu, step, code, history, *projected_step(x, a, g, lam, lower, upper),
                     carry_new)

    def running(s: State) -> bool:
        # MINPACK's xtol test on the next step: when it would change no entry by more than the
        # tolerance, the solve ends here instead of linearising at a point it would not move from.
        return (s.code == RUNNING) & ((s.step < 0) | ~small(s.d, s.x) | jnp.isnan(s.predicted))

    out = jax.lax.while_loop(running, body, state)
    code = jnp.where(out.code == RUNNING, SUCCESSFUL, out.code)
    if exact is None:  # the loop's J^T J at the solution
        return out.x, code, out.step, out.history, None if residuals is None else residuals(out.x, args), out.a
    r, a = exact(out.x, args)[:2]
    return out.x, code, out.step, out.history, r, a


def _residuals(x, problem):
    return problem.residuals(x)


def solve_problem(problem, x0, lower, upper, *, max_steps: int, rtol, atol, progress=None):
    """`box_lm` on a `Problem`'s residuals: the steps from the moments where they apply (r at the
    solution then per view (3, U), channel-major: `Problem.view_residuals`), else on `linearise`'s fast form
    (r and J^T J at the solution on its exact one); the closed-form normal equations from
    LAMBDA0_BY_PARTS."""
    options = dict(max_steps=max_steps, rtol=rtol, atol=atol, progress=progress,
                   lambda0=LAMBDA0_BY_PARTS if by_parts_applies(problem) else LAMBDA0)
    if moments.applies(problem):
        prepared = moments.prepare(problem, x0)
        return box_lm(partial(moments.linearise, prepared), x0, lower, upper, problem,
                      residuals=partial(moments.residuals, prepared), carry=moments.scratch(prepared, problem),
                      **options)
    return box_lm(squared(partial(linearise, fast=True)), x0, lower, upper, problem, residuals=_residuals,
                  exact=linearise if has_fast_form(problem, x0) else None, **options)


@partial(jax.jit, static_argnames=("max_steps", "progress"))
def solve_box(problem, x0, lower, upper, max_steps, rtol, atol, progress=None):
    """`solve_problem` compiled once per problem structure and max_steps. (A plain jit: a `Problem`
    is a pytree of arrays with its static fields in the tree's structure. A call to a jit of this
    signature that returns x0 costs 18 us on the bench's 256^2 sphere (39 leaves), eqx.filter_jit's
    48 us; the problem's leaves passed flat, 14 us: not worth a cache of them. What a solve costs
    beyond its steps -- 1 step 0.64-0.70 ms, each further one ~0.14-0.16 (8 steps 1.68-1.78 ms,
    solve_box alone in a loop, medians of 60 at load 1) -- is its program's (XLA's profile): the moments'
    `prepare` ~0.18 ms, the start's linearisation ~0.14, the residuals at the solution ~0.08; in a
    fit, ~15-50 us more at each hand-over between XLA's threads, woken from sleep, which
    `moments.linearise` keeps out of the steps' sums of squares and, writing them in place, out of
    the lobes' products (`moments._in_place`), then out of r^2 and its sum too, the last 2 a step
    (`moments._sum_of_squares`); a solve started 10 ms after the last took 2.5-2.7 ms, back to back
    1.7-1.9, before those 2.)"""
    return solve_problem(problem, x0, lower, upper, max_steps=max_steps, rtol=rtol, atol=atol, progress=progress)


@partial(jax.jit, static_argnames=("max_steps",))
def solve_box_batch(problem, x0, targets, lower, upper, max_steps, rtol, atol):
    """Many `solve_problem` solves at once, `jax.vmap` over starts x0 (B, p) and per-view targets
    (B, U, 3): each takes the steps its single fit takes."""
    def one(x0_b, targets_b):
        return solve_problem(problem.with_targets(targets_b), x0_b, lower, upper, max_steps=max_steps, rtol=rtol,
                             atol=atol)

    return jax.vmap(one)(x0, targets)

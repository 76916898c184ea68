"""Solvers behind every fit, chosen by one value object, `FitOptions`.

"lm" is difflab's box-constrained Levenberg-Marquardt (`lm.py`) on the bounded values themselves;
"varpro" solves ka, kd, ks exactly inside an "lm" search over the rest (`varpro.py`: with only ka,
kd, ks fitted, the linear solve alone, 0 steps; a target with a ceiling that no value reaches solved
unclipped, FitError where a target value or the fitted model reaches the ceiling); "gauss_newton",
"dogleg", "bfgs" (optimistix) and "adam" (optax through optimistix) run on unconstrained coordinates
mapped into the bounds (`params.Layout.x_from_free`). Fits with many entries (a texture's texels)
solve each step's normal equations matrix-free by conjugate gradients (`matfree.py`,
`FitOptions.linear_solver`). Failure is a value: each run returns a result code name and never
raises here, but for "varpro" on a problem it cannot model (an input error, not a failed fit).
"""

from __future__ import annotations

import sys
import threading
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import lm
from .matfree import normal_cg, solve_box_cg
from .options import SOLVERS, FitOptions  # noqa: F401  (SOLVERS: re-exported)

SUCCESSFUL = "successful"

class Solved(NamedTuple):
    """A solve's outcome: x (p,) solver coordinates, result code name, steps, loss history, and
    linearised = (r, J^T J) at x (the residuals per view (3, U), `Problem.view_residuals`, and their
    normal matrix in solver coordinates) when the solver has them ("lm"), else None."""

    x: np.ndarray
    result: str
    steps: int
    history: list
    linearised: tuple | None = None


class Progress:
    """A tqdm bar fed from inside the compiled solve, one update per step (through `BAR_FEED`)."""

    def __init__(self, total: int, label: str):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=label, unit="step", leave=False, file=sys.stderr)

    def __call__(self, step, loss):
        self.bar.update(int(step) - self.bar.n)
        self.bar.set_postfix(loss=f"{float(loss):.4g}", refresh=False)

    def close(self):
        self.bar.close()


class BarFeed:
    """The one host callable the compiled solves call after each step (`jax.debug.callback`) when a
    bar is shown: it passes the step on to the bar of the solve now running. Being the same object
    every time, it keeps the solve compiled once (a new bar each fit as the callable compiled the
    solve anew, a second or more per fit). One bar at a time: a solve started while another shows
    its bar takes the feed over."""

    def __init__(self):
        self._lock = threading.Lock()
        self._bar = None

    def __call__(self, step, loss):
        with self._lock:
            bar = self._bar
        if bar is not None:
            bar(step, loss)

    def take(self, bar: Progress):
        with self._lock:
            self._bar = bar

    def release(self, bar: Progress):
        with self._lock:
            if self._bar is bar:
                self._bar = None


BAR_FEED = BarFeed()


class LossRecorder:
    """An optimistix `verbose=` callable that sends each step's loss to the host (the optimistix
    solvers only; "lm" keeps its own history). One instance serves every fit, so the solver's hash
    -- and the compiled solve -- stay the same from call to call."""

    def __init__(self):
        self._lock = threading.Lock()
        self._log = None

    def __call__(self, **kwargs):
        entry = kwargs.get("loss_this_step")
        if entry is not None:
            jax.debug.callback(self._append, entry[1])

    def _append(self, value):
        with self._lock:
            if self._log is not None:
                self._log.append(float(np.asarray(value, np.float64).reshape(-1)[0]))

    def start(self):
        with self._lock:
            self._log = []

    def stop(self) -> list:
        jax.effects_barrier()
        with self._lock:
            log, self._log = self._log or [], None
        return log


RECORDER = LossRecorder()


def optimistix_solver(name: str, rtol: float, atol: float, learning_rate: float, history: bool, linear_solver=None):
    """An optimistix solver by name ("gauss_newton", "dogleg", "bfgs", "adam"); `linear_solver` (a
    lineax solver) replaces the least-squares solvers' default. optimistix and optax are imported
    here, on first use: the default solver needs neither."""
    import optax
    import optimistix as optx

    verbose = RECORDER if history else False
    inner = {} if linear_solver is None else {"linear_solver": linear_solver}
    if name == "gauss_newton":
        return optx.GaussNewton(rtol=rtol, atol=atol, verbose=verbose, **inner)
    if name == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol, verbose=verbose, **inner)
    if name == "bfgs":
        return optx.BFGS(rtol=rtol, atol=atol, verbose=verbose)
    return optx.OptaxMinimiser(optax.adam(learning_rate), rtol=rtol, atol=atol, verbose=verbose)


def _free_residuals(z, problem):
    return problem.residuals(problem.layout.x_from_free(z))


def _free_loss(z, problem):
    r = _free_residuals(z, problem)
    return 0.5 * jnp.sum(r * r)


#: The result codes optimistix (and lineax beneath it) define, by name: `RESULTS.<name>` is public,
#: the table behind it is not, so a result is named by comparing it with each.
OPTIMISTIX_RESULTS = ("successful", "nonlinear_max_steps_reached", "nonlinear_divergence", "nonfinite",
                      "max_steps_reached", "singular", "breakdown", "stagnation", "conlim")


def result_name(result) -> str:
    """optimistix's result (an `optx.RESULTS` item) as its name, or 'unknown: <its message>'."""
    import optimistix as optx

    for name in OPTIMISTIX_RESULTS:
        item = getattr(optx.RESULTS, name, None)
        if item is not None and bool(result == item):
            return name
    return f"unknown: {optx.RESULTS[result]}"


@eqx.filter_jit
def _optimistix(solver, z0, problem, max_steps):
    import optimistix as optx

    if isinstance(solver, optx.OptaxMinimiser):
        sol = optx.minimise(_free_loss, solver, z0, args=problem, max_steps=max_steps, throw=False)
    else:
        sol = optx.least_squares(_free_residuals, solver, z0, args=problem, max_steps=max_steps, throw=False)
    return problem.layout.x_from_free(sol.value), sol.result, sol.stats["num_steps"]


def _box_lm(problem, x0, lower, upper, options: FitOptions, progress, beside=lambda: None) -> Solved:
    """`lm.solve_box` from x0, a `Solved` (its r -- per view (3, U), `Problem.view_residuals` -- and
    J^T J at the solution on the host); `beside()` is called once the solve is dispatched (`run`).
    (Read with np.asarray: int() of a jax scalar costs 16 us, and through the class: the bound method
    of an eqx.Module is one more Module, 24 us.)"""
    rtol, atol = options.tolerances()
    dtype = problem.ambient.dtype
    x, code, steps, history, r, gram = lm.solve_box(problem, np.asarray(x0, dtype), lower, upper, options.max_steps,
                                                   rtol, atol, progress)
    beside()
    steps = int(np.asarray(steps))
    history = np.asarray(history, np.float64)[:steps].tolist() if options.history else []
    name = lm.CODES[int(np.asarray(code))]  # a non-finite start leaves r, J unset
    return Solved(np.asarray(x, np.float64), name, steps, history,
                  None if name == "nonfinite" else (type(problem).view_residuals(problem, r), gram))


def run(problem, x0: np.ndarray, options: FitOptions, label: str = "fit", beside=None):
    """One solve from solver coordinates x0, a `Solved`. `beside`: None, or a callable that does or
    starts what the caller has to do beside the solve (`engine.noise_ahead`'s), called once
    "lm"'s compiled solve is dispatched -- not before: see there -- and before any other solver."""
    beside = beside or (lambda: None)
    rtol, atol = options.tolerances()
    dtype = problem.ambient.dtype
    lower, upper = (np.asarray(b, dtype) for b in problem.layout.bounds())  # numpy: moved with the call
    bar = Progress(options.max_steps, label) if options.show_progress() else None
    progress = None
    if bar is not None:
        BAR_FEED.take(bar)
        progress = BAR_FEED
    matrix_free = options.matrix_free(problem.layout.size)
    try:
        if options.solver == "lm" and matrix_free:
            x, code, steps, history = solve_box_cg(problem, np.asarray(x0, dtype), lower, upper, options.max_steps,
                                                   rtol, atol, options.cg_steps, progress)
            beside()
            steps = int(np.asarray(steps))  # (as `_box_lm` reads them)
            history = np.asarray(history, np.float64)[:steps].tolist() if options.history else []
            return Solved(np.asarray(x, np.float64), lm.CODES[int(np.asarray(code))], steps, history)
        if options.solver == "lm":
            # targets with a ceiling no value reaches: solved unclipped, which holds where the model
            # ends below the ceilings (`Problem.without_ceilings`), else solved again clipped
            clipped = any(view.ceiling is not None for view in problem.views)  # (else no bound method: 28 us)
            unclipped = problem.without_ceilings() if clipped else None
            if unclipped is not None:
                solved = _box_lm(unclipped, x0, lower, upper, options, progress, beside)
                if solved.linearised is not None and problem.below_ceilings(solved.linearised[0]):
                    return solved
            return _box_lm(problem, x0, lower, upper, options, progress, beside)
        beside()
        if options.solver == "varpro":
            from .varpro import run_varpro

            return Solved(*run_varpro(problem, x0, options, progress))
        inner = normal_cg(rtol, atol, options.cg_steps) if matrix_free else None
        solver = optimistix_solver(options.solver, rtol, atol, options.learning_rate, options.history, inner)
        z0 = jnp.asarray(problem.layout.free_from_x(x0), dtype)
        if options.history:
            RECORDER.start()
        try:
            x, result, steps = _optimistix(solver, z0, problem, options.max_steps)
            x = np.asarray(x, np.float64)
        finally:
            history = RECORDER.stop() if options.history else []
        return Solved(x, result_name(result), int(steps), history)
    finally:
        if bar is not None:
            jax.effects_barrier()
            BAR_FEED.release(bar)
            bar.close()

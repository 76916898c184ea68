"""Solvers: optimistix's least-squares solvers and an Adam loop, one compiled solve per problem shape.

Failure is a value: every run returns the solver's result code (`optimistix.RESULTS`, as its name)
and never raises here; `fit_material` decides what to do with it.
"""

from __future__ import annotations

import threading

import equinox as eqx
import jax
import lineax as lx
import numpy as np
import optax
import optimistix as optx

from ..errors import FitError
from .problem import loss_fn, residual_fn

SOLVERS = ("lm", "gauss_newton", "dogleg", "bfgs", "adam", "varpro")
RESULT_NAMES = {int(item._value): name for name, item in optx.RESULTS._name_to_item.items()}
SUCCESSFUL = "successful"


class HistoryRecorder:
    """An optimistix `verbose=` callable that sends each step's loss to the host.

    Solvers call it once per step with keyword pairs (label, value); it records the loss at the point
    the step evaluated (for the trust-region and line-search solvers that includes trial points they
    then reject, so the history need not decrease monotonically), with the unconstrained parameters
    it evaluated (the trajectory; `fit.solve` returns both). One module-level instance serves every fit, so the solver's hash -- and the compiled
    solve -- stay the same from call to call; fits that record history run one at a time."""

    def __init__(self):
        self._lock = threading.Lock()
        self._log = None

    def __call__(self, **kwargs):
        entry = kwargs.get("loss_this_step")
        if entry is not None:
            y = kwargs.get("y", (None, None))[1]
            jax.debug.callback(self._append, entry[1], y)

    def _append(self, value, y):  # runs on the runtime's callback thread
        with self._lock:
            if self._log is not None:
                y = None if y is None else jax.tree.map(lambda a: np.asarray(a, np.float64), y)
                self._log.append((np.asarray(value, np.float64), y))

    def start(self) -> None:
        with self._lock:
            self._log = []

    def stop(self) -> list:
        jax.effects_barrier()
        with self._lock:
            log, self._log = self._log or [], None
        return log


RECORDER = HistoryRecorder()


def make_solver(name: str, rtol: float, atol: float, learning_rate: float = 0.05, history: bool = True):
    """An optimistix solver by name (see `SOLVERS`; "varpro" runs LM on its reduced problem)."""
    verbose = RECORDER if history else False
    if name in ("lm", "varpro"):
        # The damped step through the normal equations (J^T J + lambda I) dx = J^T r: forming the small
        # p x p matrix is one GEMM, several times cheaper than a Householder QR of the tall J, and the
        # damping keeps it positive definite where J^T J alone is singular.
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()), verbose=verbose)
    if name == "gauss_newton":
        return optx.GaussNewton(rtol=rtol, atol=atol, verbose=verbose)
    if name == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol, verbose=verbose)
    if name == "bfgs":
        return optx.BFGS(rtol=rtol, atol=atol, verbose=verbose)
    if name == "adam":
        return optx.OptaxMinimiser(optax.adam(learning_rate), rtol=rtol, atol=atol, verbose=verbose)
    raise FitError(f"solver: unknown solver {name!r}; known: {', '.join(SOLVERS)}")


def _ls_inner(solver, u0, problem, max_steps):
    sol = optx.least_squares(residual_fn, solver, u0, args=problem, max_steps=max_steps, throw=False)
    return sol.value, sol.result._value, sol.stats["num_steps"]


def _min_inner(solver, u0, problem, max_steps):
    sol = optx.minimise(loss_fn, solver, u0, args=problem, max_steps=max_steps, throw=False)
    return sol.value, sol.result._value, sol.stats["num_steps"]


_least_squares = eqx.filter_jit(_ls_inner)
_minimise = eqx.filter_jit(_min_inner)


def run_solver(solver, u0: dict, problem, max_steps: int):
    """One solve: (u, result name, steps). Compiled once per (solver, problem structure, max_steps)."""
    run = _minimise if isinstance(solver, optx.OptaxMinimiser) else _least_squares
    u, code, steps = run(solver, u0, problem, int(max_steps))
    return u, RESULT_NAMES[int(code)], int(steps)


def _batched(run):
    def solve_all(solver, u0, problem, targets, max_steps):
        def one(u0_i, targets_i):
            views = tuple(eqx.tree_at(lambda v: v.target, view, t) for view, t in zip(problem.views, targets_i))
            return run(solver, u0_i, eqx.tree_at(lambda p: p.views, problem, views), max_steps)
        return jax.vmap(one)(u0, targets)
    return eqx.filter_jit(solve_all)


_BATCH = {"least_squares": _batched(_ls_inner), "minimise": _batched(_min_inner)}


def run_solver_vmap(solver, u0: dict, problem, targets: tuple, max_steps: int):
    """Many solves at once with `jax.vmap` over the targets (leading axis B of each view's target) and
    starts (leading axis B of u0). Returns (u, [result names], steps array)."""
    kind = "minimise" if isinstance(solver, optx.OptaxMinimiser) else "least_squares"
    u, codes, steps = _BATCH[kind](solver, u0, problem, targets, int(max_steps))
    return u, [RESULT_NAMES[int(c)] for c in np.asarray(codes)], np.asarray(steps)

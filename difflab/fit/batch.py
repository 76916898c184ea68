"""Batched fits: many independent targets of one view (same geometry, camera and lights), one call.

Two ways, same compiled residuals:
- `vmap=True`: `jax.vmap` over one optimistix solve (throw=False; each element's result code is read
  separately). Every element runs until the slowest has terminated -- a `while_loop` under vmap keeps
  stepping (masked) until all elements are done -- and each element's step count is its own.
- `vmap=False`: a Python loop calling the same compiled solve once per element.
"""

from __future__ import annotations

import copy
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import FitError
from .fit import DEFAULT_TOL, Setup, finish
from .params import initial_values, u_from_values
from .solve import RECORDER, make_solver, run_solver, run_solver_vmap


def _with_target(problem, target):
    view = eqx.tree_at(lambda v: v.target, problem.views[0], target)
    return eqx.tree_at(lambda p: p.views, problem, (view,) + tuple(problem.views[1:]))


def _starts(setup, init, count) -> list[dict]:
    """Each element's starting values: init[key] shared, or batched with one more leading axis of B."""
    starts = []
    for b in range(count):
        chosen = {}
        for p in setup.layout:
            if p.key not in (init or {}):
                continue
            value = np.asarray(init[p.key], np.float64)
            batched = value.ndim == (2 if p.rgb else 1) and value.shape[0] == count
            chosen[p.key] = value[b] if batched else value
        starts.append(initial_values(setup.scene, setup.layout, chosen))
    unknown = set(init or {}) - {p.key for p in setup.layout}
    if unknown:
        raise FitError(f"init: not fitted: {sorted(unknown)}")
    return starts


def fit_batch(scene, images, material=None, params=("ka", "kd", "ks", "n"), *, overrides=None, vmap=True,
              solver="lm", init=None, max_steps=256, rtol=None, atol=None, learning_rate=0.05, x64=True,
              throw=False, history=False, rel_tol=0.1, abs_tol=1e-3, **options) -> list:
    """Fit each of B images independently (see `fit_material` for the arguments).

    Arguments:
        images: (B, H, W, 3) linear float array, or a list of B such images, all of one view.
        overrides: the view's "camera" / "lights" (as in `fit_material`'s (image, overrides) pairs).
        vmap: one vmapped solve (True) or a loop over one compiled solve (False).
        init: name -> start, the same for all, or with a leading axis B for one start each.
        options: the other `fit_material` options that shape the problem (per_channel, bounded, loss,
            loss_scale, masks, weights, device).
    Returns:
        a list of B `FitResult`s; each `seconds` is the batch's solve time divided by B.
    """
    if solver == "varpro":
        raise FitError("solver: fit_batch supports the optimistix solvers, not 'varpro'")
    images = np.asarray(images, np.float64)
    if images.ndim != 4 or images.shape[-1] != 3 or images.shape[0] < 1:
        raise FitError(f"images: expected (B, H, W, 3), got {images.shape}")
    count = images.shape[0]
    start = time.perf_counter()
    first = images[0] if overrides is None else (images[0], overrides)
    setup = Setup(scene, [first], material, params, x64=x64, **options)
    starts = _starts(setup, init, count)
    pixels = np.asarray(setup.problem.views[0].pixels)
    used = images.reshape(count, -1, 3)[:, pixels]  # (B, U, 3): the pixels the fit reads
    nonfinite = [int(np.count_nonzero(~np.isfinite(u))) for u in used]
    timings = {"setup": time.perf_counter() - start}
    code = setup.precheck()
    default_rtol, default_atol = DEFAULT_TOL[setup.x64]
    optimiser = make_solver(solver, default_rtol if rtol is None else rtol, default_atol if atol is None else atol,
                            learning_rate, history)
    with jax.enable_x64(setup.x64):
        targets = jnp.asarray(np.where(np.isfinite(used), used, 0.0), setup.dtype)
        u0s = [u_from_values(setup.layout, start_b, setup.dtype) for start_b in starts]
        if history:
            RECORDER.start()
        t0 = time.perf_counter()
        try:
            if code is not None:
                raw = None
            elif vmap:
                u0 = jax.tree.map(lambda *xs: jnp.stack(xs), *u0s)
                u, names, steps = run_solver_vmap(optimiser, u0, setup.problem, (targets,), max_steps)
                jax.block_until_ready(u)
                raw = [(jax.tree.map(lambda x, b=b: x[b], u), names[b], int(steps[b])) for b in range(count)]
            else:
                raw = []
                for b in range(count):
                    u, name, steps = run_solver(optimiser, u0s[b], _with_target(setup.problem, targets[b]), max_steps)
                    jax.block_until_ready(u)
                    raw.append((u, name, steps))
        finally:
            log = RECORDER.stop() if history else []
        seconds = time.perf_counter() - t0
    timings["solve"] = seconds
    results = []
    for b in range(count):
        element = copy.copy(setup)
        element.problem = _with_target(setup.problem, targets[b])
        element.initial = starts[b]
        hist = [np.asarray(h).reshape(-1)[b if np.asarray(h).size == count else 0] for h, _ in log] if history else []
        if code is not None or nonfinite[b]:
            results.append(finish(element, None, code or "nonfinite_target", 0, seconds / count, [], solver,
                                   timings, rel_tol, abs_tol, throw))
            continue
        u, name, steps = raw[b]
        results.append(finish(element, element.values(u), name, steps, seconds / count, hist, solver, timings,
                               rel_tol, abs_tol, throw))
    return results

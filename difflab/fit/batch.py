"""Batched fits: many independent targets of one view (same geometry, camera and lights), one
prepared `Setup` and one compiled solve.

- `vmap=True` (solver "lm"): `jax.vmap` over the box Levenberg-Marquardt solve. Every element runs
  until the slowest has terminated (a vmapped `while_loop` keeps stepping, masked, until all are
  done); each element keeps its own result code and step count.
- `vmap=False` (or another solver, or a matrix-free fit of many texels): a loop over the same
  compiled solve, with a progress bar.

A target that cannot be fitted (non-finite values under the mask) gets its own failed result; the
others are fitted as usual.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import FitError
from . import lm
from .engine import report, without_clipped
from .matfree import check_solver
from .params import DEFAULT_PARAMS
from .setup import Setup
from .options import FitOptions
from .solvers import Solved, run

SETUP_KEYWORDS = ("method", "per_channel", "bounded", "loss", "loss_scale", "masks", "weights", "sigma", "ceiling",
                  "smoothness", "max_depth", "spp", "device", "threads")


def _element_init(init, count: int, b: int):
    """Element b's starting values: init[key] shared, or with a leading axis of B for one each."""
    if init is None:
        return None
    if not isinstance(init, dict):
        raise FitError(f"init: expected a dict of name -> value, got {type(init).__name__}")
    out = {}
    for key, value in init.items():
        array = np.asarray(value, dtype=object)
        batched = array.ndim >= 1 and array.shape[0] == count and (array.ndim == 2 or count not in (1, 3))
        out[key] = value[b] if batched else value
    return out


def fit_batch(scene, images, material=None, params=DEFAULT_PARAMS, *, overrides=None, vmap=True, init=None,
              options=None, **kwargs) -> list:
    """Fit each of B target images of one view independently.

    Arguments:
        images: (B, H, W, 3) array, or a list of B images of one view (as `fit`'s targets).
        material, params: as `fit_material`.
        overrides: the view's "camera" / "lights" (as in `fit`'s (image, overrides) pairs).
        vmap: one vmapped solve (True, solver "lm") or a loop over one compiled solve.
        init: name -> start, the same for all, or with a leading axis B for one start each.
        options, kwargs: `FitOptions` (and its fields as keywords), and `fit`'s keywords that shape
            the problem (method, per_channel, bounded, loss, masks, weights, sigma, ceiling, ...).
    Returns:
        a list of B `FitResult`s; each `seconds` is the batch's solve time divided by B. In a batch
        the targets share the ceiling found for the first one (or given).
    """
    setup_kwargs = {k: kwargs.pop(k) for k in SETUP_KEYWORDS if k in kwargs}
    options = FitOptions.make(options, **kwargs)
    try:
        images = [np.asarray(image) for image in images]
    except TypeError:
        raise FitError(f"images: expected a list of images, got {type(images).__name__}") from None
    if not images:
        raise FitError("images: no target images given")
    count = len(images)
    start = time.perf_counter()
    first = images[0] if overrides is None else (images[0], overrides)
    setup = Setup(scene, [first], material, params, init=_element_init(init, count, 0), x64=options.x64,
                  **setup_kwargs)
    elements = [setup] + [setup.retarget([_decoded(image, setup, b)], _element_init(init, count, b))
                          for b, image in enumerate(images) if b > 0]
    timings = {"setup": time.perf_counter() - start}
    check_solver(options, setup.layout)
    t0 = time.perf_counter()
    solved = [None] * count
    todo = [b for b in range(count) if elements[b].precheck() is None]
    with jax.enable_x64(setup.x64), setup.on_device():
        if vmap and options.solver == "lm" and not options.matrix_free(setup.layout.size) and todo:
            rtol, atol = options.tolerances()
            lower, upper = (jnp.asarray(v, setup.dtype) for v in setup.layout.bounds())
            x0 = jnp.asarray(np.stack([elements[b].x0 for b in todo]), setup.dtype)
            targets = tuple(jnp.stack([elements[b].problem.views[i].target for b in todo])
                            for i in range(len(setup.views)))
            out = lm.solve_box_batch(setup.problem, x0, targets, lower, upper, options.max_steps, rtol, atol)
            x, codes, steps, history, gram = (np.asarray(a) for a in (*out[:4], out[5]))
            r = setup.problem.view_residuals(out[4])  # per view (B, 3, U)
            for i, b in enumerate(todo):
                hist = history[i, :steps[i]].tolist() if options.history else []
                name = lm.CODES[int(codes[i])]
                solved[b] = Solved(x[i].astype(np.float64), name, int(steps[i]), hist,
                                   None if name == "nonfinite" else (tuple(part[i] for part in r), gram[i]))
        else:
            quiet = FitOptions.make(options, progress=False)
            bar = _bar(len(todo), options)
            for b in todo:
                solved[b] = run(elements[b].problem, elements[b].x0, quiet)
                if bar is not None:
                    bar.update(1)
            if bar is not None:
                bar.close()
    timings["solve"] = time.perf_counter() - t0
    results = []
    with setup.on_device():  # (the reports' JAX work where the solve ran, as `engine.run_fit`'s)
        for b in range(count):
            each = {**timings, "solve": timings["solve"] / count}
            if solved[b] is None:
                results.append(report(elements[b], None, elements[b].precheck(), 0, [], options, each))
            else:
                s = solved[b]
                out = report(elements[b], s.x, s.result, s.steps, s.history, options, each, s.linearised)
                results.append(without_clipped(elements[b], out, options))
    return results


def _decoded(image, setup: Setup, b: int) -> np.ndarray:
    """Target b as linear float data of the view's size (decoded like the first; a private copy,
    `load_target`'s, that `Setup.retarget` keeps), under a ceiling given (`ceiling.refuse_values_above`)."""
    from .ceiling import refuse_values_above
    from .records import take_pixels
    from .targets import load_target

    array = load_target(image, f"images[{b}]")[0]
    view = setup.views[0]
    if array.shape != view.image.shape:  # (not `target`'s: that would form the whole float64 image)
        raise FitError(f"images[{b}]: shape {array.shape}, but the batch's view is {view.image.shape}")
    if setup.ceiling_given:
        refuse_values_above(setup.ceiling_given, take_pixels(array, view.pixels, np.float64), view.entries, f"images[{b}]")
    return array


def _bar(total: int, options: FitOptions):
    if not options.show_progress():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc="batch", unit="fit", leave=False)

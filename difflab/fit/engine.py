"""The fitting engine's front ends: `fit` (one signature for every fit), and `fit_material` /
`fit_scene`, its two classic spellings. All of them prepare a `setup.Setup`, solve it
(`solvers.run`, options in one `FitOptions`) and report it (`report`).

Warp renders each view once -- its G-buffer or its ray tree -- and JAX re-forms the image from it as
often as the solver asks (DESIGN.md, invariant 3).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import FitError
from ..renderers.bandpool import start_beside
from .params import DEFAULT_PARAMS, SCENE_PARAMS, public_value
from .problem import robust
from .result import FitResult
from .setup import Setup
from .options import FitOptions
from .clipping import clipped_band
from .matfree import check_solver
from .solvers import SUCCESSFUL, run
from .sparse_jacobian import sparse_normal_matrix
from .noise import load_noise_kernels, noise_picks, silent_pixels, views_noise
from .sandwich import noise_middle
from .stats import (PRIOR_PULL_MAX, QUANTISATION_SIGMA, degenerate, finite_gram, fit_statistics, normal_matrix,
                    poorly_determined, prior_pull, psnr, singular_rcond, standard_errors, unreached)
from .texels import smoothness_residuals, texel_coverage


def report(setup: Setup, x, result: str, steps: int, history: list, options: FitOptions, timings: dict,
           solved=None, ahead=None) -> FitResult:
    """The FitResult of a solve at solver coordinates x (None: no fit was made): values in scene
    units, standard errors, noise, chi-square, flags; raises FitError for a failure when
    `options.throw`. `solved`: the solver's (r, J^T J) at x, when it has them; `ahead`: the `take` of the
    `NoiseAhead` that `run_fit` started beside the solve (None: the picks and the residual planes' memory
    are formed here)."""
    layout = setup.layout
    public = lambda values: {p.key: public_value(p, values[p.key]) for p in layout}  # noqa: E731
    common = dict(steps=steps, solver=options.solver, initial=public(setup.initial), scene=setup.scene, layout=layout,
                  model=setup.method, censored=setup.censored, nonfinite_left_out=setup.nonfinite_left_out)
    if x is None:
        nan = {p.key: np.full(p.size, np.nan) for p in layout}
        out = FitResult(params=public(setup.initial), stderr=public(nan), loss=float("nan"), psnr=float("nan"),
                        seconds=0.0, converged=False, result=result, poorly_determined=[p.key for p in layout],
                        timings=timings, **common)
    else:
        start = time.perf_counter()
        flat = layout.values(np.asarray(x, np.float64))  # (setup.values, flattened back: the same bits)
        values = layout.unflatten(flat)
        used = setup.weighted_entries
        matrix_free = options.matrix_free(layout.size)
        with jax.enable_x64(setup.x64):
            at = np.asarray(flat, setup.dtype)  # numpy: moved by the compiled calls that need it
            if matrix_free:  # the Jacobian by column compression: J^T J sparse, blocks too large skipped
                gram, r, skip = sparse_normal_matrix(setup.problem, at)
            else:
                (gram, r), skip = normal_matrix(setup.problem, at, solved), None
            rho = r if setup.problem.loss == "l2" else tuple(  # (r: per view (3, U), `Problem.view_residuals`)
                np.asarray(robust(setup.problem.loss, jnp.asarray(part), setup.problem.loss_scale), np.float64)
                for part in r)
            seen = {k: c > options.visible_threshold for k, c in texel_coverage(setup.problem, at, used).items()}
        counted = r if setup.unit_weights else tuple(  # the entries that count (unit weights: every one)
            part[view.entries.T] for part, view in zip(r, setup.views))
        count = sum(part.size for part in counted)
        sse = sum_of_squares(counted)
        loss = 0.5 * sse if rho is counted else 0.5 * sum_of_squares(rho)
        picks, zeros = ahead() if ahead is not None else (None, None)  # (first: the picks are done with the views)
        planes = setup.residual_planes(r, zeros)  # (into memory written beside the solve: `Setup.zero_planes`)
        residuals = [p.transpose(1, 2, 0) for p in planes]  # (H, W, 3) views (np.moveaxis: 2 us more each)
        finite = bool(np.all(np.isfinite(flat)) and math.isfinite(loss) and finite_gram(gram))
        silent, silent_entries = silent_pixels(setup.views, r)
        middle = []  # unequal noise: the sandwich's middle (`noise_middle`), started once the noise levels are read
        same_sum = counted is r and all(part.flags.c_contiguous for part in r)  # (sse summed as noise_middle sums)
        on_levels = None if matrix_free else lambda levels: middle.append(noise_middle(
            setup, at, r, levels, count - setup.censored - silent_entries, sse if same_sum else None))
        sigma, noise_values, share, sigma_range, _ = (
            views_noise(setup.views, planes, silent, setup.sigma_given, setup.sigma_floor, setup.sigma_fallback,
                        setup.quantisation, on_levels, picks) if finite else (float("nan"), 0, 1.0, None, None))
        noise_unknown = finite and sigma is None
        mean_weight = setup.weight_total / count if count else 1.0  # (unit weights: 1)
        sigma = float("nan") if sigma is None else sigma
        if finite:
            unseen = sum(int(np.count_nonzero(~seen[p.key])) * (p.size // seen[p.key].size) for p in layout
                         if p.key in seen)  # texels no pixel reads: no unknowns of the data's
            st = fit_statistics(gram, sse, count, setup.censored, sigma, layout.size - unseen, silent_entries,
                                sigma_given=setup.sigma_given is not None, skip=skip, noise_values=noise_values, noise_share=share,
                                mean_weight=mean_weight, rcond=singular_rcond(setup.x64), sigma_range=sigma_range,
                                middle=middle[0]() if middle and middle[0] else None)
            errors = standard_errors(st["diag"], st["s2"])
            stderr = layout.unflatten(errors)
            quantised = mean_weight * QUANTISATION_SIGMA ** 2  # (as a rule s2 is above it: the floor's are stderr's)
            floor = standard_errors(st["diag"], quantised) if quantised > st["s2"] else errors  # (max(s2, quantised))
            partly_seen = [key for key, on in seen.items() if not on.all()]
            pull = np.abs(pulled_by_prior(setup, flat, gram, st))
            pulled = [key for key, z in layout.unflatten(pull).items()
                      if np.max(z, initial=0.0) > PRIOR_PULL_MAX] if pull.any() else []  # (zeros: no prior)
            flagged = poorly_determined(layout, flat, floor, options.rel_tol, options.abs_tol,
                                        also=partly_seen + pulled)
            chi2, mismatch, suspected = st["chi2"], st["mismatch"], st["suspected"]
            degenerate_keys = degenerate(layout, st["diag"], gram, setup.smoothness > 0)
            fitted = {(q.index, q.kind): values[q.key] for q in layout}
            materials = list(setup.scene.materials.values())
            unreached_keys = unreached(layout, gram, lambda index, kind: fitted.get(
                (index, kind), getattr(materials[index], kind)))
            too_few = st["underdetermined"]
            underdetermined = too_few or bool(degenerate_keys) or bool(unreached_keys)
        else:
            stderr = {p.key: np.full(p.size, np.nan) for p in layout}
            flagged, chi2, mismatch, pull = [p.key for p in layout], float("inf"), True, np.full(1, np.nan)
            suspected = underdetermined = too_few = False
            degenerate_keys, unreached_keys = [], []
            if result == SUCCESSFUL:
                result = "nonfinite"
        lo, hi = layout.bounds()
        on_bound = (x <= lo) | (x >= hi)
        weight_total = setup.weight_total
        out = FitResult(params=public(values), stderr=public(stderr), loss=loss, psnr=psnr(sse, weight_total),
                        seconds=timings.get("solve", 0.0), converged=bool(result == SUCCESSFUL and finite),
                        result=result, history=list(history), poorly_determined=flagged, sigma=float(sigma),
                        chi2=float(chi2), model_mismatch=bool(mismatch), mismatch_suspected=bool(suspected),
                        noise_unknown=noise_unknown, sigma_range=sigma_range,
                        underdetermined=bool(underdetermined), too_few_values=bool(too_few), degenerate=degenerate_keys,
                        unreached=unreached_keys,
                        prior_pull=float(np.max(pull, initial=0.0)),
                        at_bound=[key for key, on in layout.unflatten(on_bound).items() if on.any()] if on_bound.any()
                        else [], residuals=residuals, seen=seen,
                        timings={**timings, "stats": time.perf_counter() - start}, **common)
    if options.throw and not out.converged:
        raise FitError(f"fit did not converge: {out.result} after {out.steps} steps (loss {out.loss:.4g})")
    return out


def sum_of_squares(parts) -> float:
    """sum r^2 over arrays of residuals, by einsum: one pass, no BLAS threads (the first fit's 74k
    entries: 53 us, np.sum(np.square()) 128, np.dot 410 waking its threads)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return sum(float(np.einsum("i,i->", flat, flat)) for flat in (part.reshape(-1) for part in parts))


def pulled_by_prior(setup: Setup, flat, gram, st: dict) -> np.ndarray:
    """(p,) `stats.prior_pull` of a fit's texture smoothness prior at the values `flat` (zeros
    without one): its gradient from `texels.smoothness_residuals` (0.5 |.|^2 is the prior)."""
    if not setup.smoothness > 0:
        return np.zeros(setup.layout.size)
    prior = lambda v: 0.5 * jnp.sum(jnp.square(smoothness_residuals(setup.layout, v, setup.smoothness)))  # noqa: E731
    with jax.enable_x64(True):
        gradient = np.asarray(jax.grad(prior)(jnp.asarray(flat, jnp.float64)), np.float64)
    return prior_pull(gram, st["diag"], st["s2"], gradient)


def run_fit(setup: Setup, options: FitOptions, timings: dict) -> FitResult:
    """Solve a prepared fit and report it (the precheck's result code, without solving, when the
    fit cannot be made); `timings`: the preparation's seconds ("setup", "render"), the solve's and
    the report's are added. The noise estimate's picks are formed beside the solve (`noise_ahead`),
    and left undone or waited for when the solve or the report raises."""
    timings = dict(timings)
    check_solver(options, setup.layout)
    code = setup.precheck()
    if code is not None:
        return report(setup, None, code, 0, [], options, timings)
    ahead = noise_ahead(setup)
    try:
        with setup.on_device():  # (the solve's and the report's JAX work where the problem's arrays are)
            start = time.perf_counter()
            with jax.enable_x64(setup.x64):
                # the noise picks beside the solve: on this thread for "lm", else on a worker (`noise_ahead`)
                out = run(setup.problem, setup.x0, options, beside=None if ahead is None else (
                    ahead.queue.join if options.solver == "lm" else ahead.queue.start))
            timings["solve"] = time.perf_counter() - start
            return report(setup, out.x, out.result, out.steps, out.history, options, timings, out.linearised,
                          ahead.take if ahead is not None else None)
    finally:
        if ahead is not None:  # (after an error: undone, or waited for -- nothing runs on past the call)
            ahead.queue.cancel()


class NoiseAhead(NamedTuple):
    """The noise estimate's picks and the residual planes' memory under way beside the solve: `take()`
    gives them, (picks, zeros), once done."""

    queue: object  # `bandpool.start_beside`'s handle
    formed: list

    def take(self):
        self.queue.join()
        return self.formed[0]


def noise_ahead(setup: Setup) -> NoiseAhead | None:
    """The noise estimate's `noise_picks` -- the targets' alone, for silent pixels all black ones
    (`View.black`) --, the residual planes' memory, its pages written (`Setup.zero_planes`: ~0.2 ms
    of page faults out of the report), the report's Warp kernels loaded (`noise.load_noise_kernels`:
    ~3 ms from Warp's cache, once a process), the targets' `Setup.statistics` (what only the report
    reads) and each view's `View.floor`, which `clipping.clipped_band` reads after the fit (there,
    on a target no longer in cache, ~0.1 ms of first.py's first fit), to be formed beside the
    solve: `run_fit` hands the
    solve (`solvers.run`'s `beside`, called once "lm"'s compiled solve is dispatched, before any
    other solver) the queue's `join` for "lm" -- formed on the calling thread, which only waits
    for the solve meanwhile (XLA runs its loop without the GIL) -- and its `start`
    for the others, a pool worker (`bandpool.start_beside`; none with threads=1 or DIFFLAB_THREADS=1:
    on the caller when the report asks). None with sigma given (no estimate). On the caller rather
    than a worker (the bench's Mitsuba sphere, fits alternating with the worker's in one process,
    medians of 80-100, load 1.5-2.8, 6 runs): first fit 9.38 -> 8.70, 11.83 -> 11.11, 9.32 -> 8.98,
    9.66 -> 9.00, 10.15 -> 10.38, 9.43 -> 8.63 ms; fitted again 5.65 -> 5.56, 7.12 -> 6.77, 5.56 ->
    5.30, 5.39 -> 4.96, 6.07 -> 5.87, 5.75 -> 5.58; the process's CPU time 0.07-0.37 ms less a fit
    (no worker woken, no GIL handed over); the sphere with Gaussian noise 0.01: 12.78 -> 12.21 and
    12.99 -> 12.44, again 7.06 -> 6.93 and 7.35 -> 7.32. (On a worker handed them before the
    dispatch, it took the GIL where the dispatch lets it go and held the solve back until its ~0.6
    ms of Python were done.)"""
    if setup.sigma_given is not None:
        return None
    formed = []

    def targets_alone():
        zeros = setup.zero_planes()
        load_noise_kernels()
        for planes in zeros:
            planes.fill(0.0)  # (their pages written here)
        formed.append((noise_picks(setup.views, [view.black for view in setup.views]), zeros))
        for view in setup.views:
            view.floor  # noqa: B018 (a cached property, formed here)
        setup.statistics  # noqa: B018 (formed on first use: here, off the solve's path)
    return NoiseAhead(start_beside(targets_alone, "cpu", setup.threads, start=False), formed)


def solve(setup: Setup, options=None, **option_fields) -> FitResult:
    """Solve a prepared `Setup` (again: its compiled solve is reused) and report it; `options` and
    keywords as `fit`'s (the precision is the setup's)."""
    options = FitOptions.make(options, **{**option_fields, "x64": setup.x64})
    return run_fit(setup, options, {"setup": 0.0})


def fit(scene, targets, materials=None, params=DEFAULT_PARAMS, *, method=None, options=None, per_channel=True,
        bounded=False, loss="l2", loss_scale=0.05, masks=None, weights=None, init=None, sigma=None, ceiling=None,
        smoothness=0.0, max_depth=None, spp=None, device="cpu", threads=None, **option_fields) -> FitResult:
    """Fit material coefficients (and light intensities) so the rendered images match targets.

        minimise  sum_views sum_pixels  rho( sqrt(w) (min(model(params), ceiling) - target) )^2
                  [+ smoothness sum_texture_neighbours |T_a - T_b|^2]

    where model re-forms the image in JAX from what Warp recorded once per view: the G-buffer
    ("raster") or the ray tree ("raytrace"; reflections, refractions, Beer absorption), chosen from
    the scene unless `method` says (see `arguments.py`). Geometry, light positions, shadows, the index of
    refraction and the tree's shape stay fixed.

    Arguments:
        scene: a Scene, a scene dict, a scene file path, or a `CompiledScene` (`compile_scene`: the
            views with its camera and light positions render their G-buffer / ray tree from it,
            nothing rebuilt). Its values (with `init`) are the start.
        targets: an image ((H, W, 3) linear float array; integer arrays hold sRGB code values and
            are refused with how to decode them; or a file: 8- and 16-bit PNGs decoded by their
            transfer function, sRGB unless a gAMA chunk says otherwise), or a list of images and/or
            (image, overrides) pairs, overrides a dict with a whole "camera" block and/or a whole
            "lights" list (scene file format) for that view. Each image must have its view's
            camera size.
        materials: the material name(s) to fit; default: every material an object uses. Keys are
            "kd" with one material, "red.kd" with several.
        params: any of "ka", "kd", "ks" (RGB), "n", "m", "f0", and with the ray tree "kr", "kt",
            "absorption" (RGB) -- for every fitted material, or "name.kind" for one -- and
            "intensity" (every light's) or "lights[i].intensity"; a tuple or "ka,kd". A kr (kt,
            absorption) named here is fitted for every material it names, or refused (FitError)
            where that material's kr (kt) starts at 0: the recorded tree holds only the rays that
            exist; start it above 0 (scene or `init`). Only `fit_scene`'s defaults (SCENE_PARAMS)
            skip such materials. "texture": the texels of the material's image texture (H_t x W_t x 3
            unknowns; filters "nearest" / "bilinear"; through either image model: the G-buffer
            with Phong shading, or the ray tree, whose nodes keep the uv their texture was read
            at, so texels seen in mirrors count), alone or beside the other kinds; more than
            `FitOptions` DENSE_MAX entries are solved matrix-free ("lm", "gauss_newton", "dogleg",
            "adam").
        method: "raster", "raytrace" or None (from the scene).
        options: a `FitOptions` (solver, max_steps, tolerances, precision, progress, throw, ...);
            its fields may also be given as keywords (`solver="varpro"`, `x64=False`).
        per_channel: RGB values per channel (False: one grey value each). bounded: ka, kd, ks <= 1.
        loss: "l2", "huber" or "cauchy" (`loss_scale`: the residual size where they turn robust).
        masks: per target (H, W) bool (True: the pixel counts); weights: per target (H, W[, 3]) >= 0.
        init: name -> starting value, overriding the scene's (a texture: an (H_t, W_t, 3) image,
            row 0 at the top, which also sets the texel grid, or a value for every texel).
        sigma: the targets' pixel noise (linear units) before quantisation: a file's (the rms
            rounding of the used values, `fit.noise.quantisation`) is added in quadrature; default:
            estimated (see `fit.stats`).
        ceiling: the value where the targets clip (censored pixels: the model need only reach it);
            default: 1.0 for 8/16-bit targets, detected from ties at the maximum for float data;
            False: none. A ceiling given below a used target value is a FitError (`ceiling.py`).
        smoothness: weight of a first-difference prior on fitted texels (0: none); it also fills
            texels that no pixel sees.
        max_depth: the ray tree's depth (default: the scene's; a FitError with the G-buffer).
        spp: samples per pixel of the G-buffer or ray tree (default: the scene's). Both are checked
            as the scene's render block is (a bool is no integer), a FitError naming the keyword.
        device: where Warp renders ("cpu" or "cuda"). threads: CPU threads for the render.
    Returns:
        a `FitResult`: `converged` false and `result` naming why when the fit failed;
        `model_mismatch` when the image model does not explain the targets.
    """
    options = FitOptions.make(options, **option_fields)
    common = dict(method=method, per_channel=per_channel, bounded=bounded, loss=loss, loss_scale=loss_scale,
                  masks=masks, sigma=sigma, ceiling=ceiling, smoothness=smoothness, x64=options.x64,
                  max_depth=max_depth, spp=spp, device=device, threads=threads)
    start = time.perf_counter()
    setup = Setup(scene, targets, materials, params, weights=weights, init=init, **common)
    out = run_fit(setup, options, {"setup": time.perf_counter() - start, "render": setup.render_seconds})
    return without_clipped(setup, out, options)


def without_clipped(setup: Setup, out: FitResult, options: FitOptions) -> FitResult:
    """`out`, or -- when noise clipped at a bound biases it (`clipping.clipped_band`) -- the fit made
    again without the pixels near the clip, from `out`'s values, their values counted as censored.
    When leaving them out would leave no more uncensored entries than unknowns (a mask that lies
    wholly near the clip), `out` is kept, every parameter listed in `poorly_determined`: its values
    rest on pixels whose mean the clip moves, a bias its standard errors do not cover. The refit
    estimates the noise over the pixels it keeps, or takes `out`'s sigma where too few remain. (The
    refit's `Setup` is `setup.reweighted`: the one `Setup` would build with those weights and start.)"""
    band = clipped_band(setup, out)
    if band is None:
        return out
    if _entries_left(setup, band) <= setup.layout.size:
        return dataclasses.replace(out, poorly_determined=[p.key for p in setup.layout])
    start = time.perf_counter()
    kept = [view.weight * ~near[..., None] for view, near in zip(setup.views, band)]
    again = setup.reweighted(kept, out.params)
    again.sigma_fallback = out.sigma  # (the band left out, too few pixels may remain to estimate the noise)
    second = run_fit(again, options, {"setup": time.perf_counter() - start, "render": again.render_seconds})
    left_out = sum(int(np.count_nonzero(view.entries[near.reshape(-1)[view.pixels]]))  # their counted entries
                   for view, near in zip(setup.views, band))
    timings = {key: out.timings.get(key, 0.0) + second.timings.get(key, 0.0)
               for key in {**out.timings, **second.timings}}
    return dataclasses.replace(second, steps=out.steps + second.steps, censored=second.censored + left_out,
                               seconds=out.seconds + second.seconds, timings=timings)


def _entries_left(setup: Setup, band) -> int:
    """The residual entries a fit without the `band` pixels (per view (H, W) bool) would count
    (`View.counted`, outside the band)."""
    return sum(int(np.count_nonzero(view.counted[~near.reshape(-1)[view.pixels]])) for view, near in zip(setup.views, band))


def fit_material(scene, targets, material=None, params=DEFAULT_PARAMS, **kwargs) -> FitResult:
    """`fit` with its classic spelling: `material` (one name or several); every keyword of `fit`.
    The image model follows the scene (ray tree for ray-traced scenes and mirrors / glass)."""
    return fit(scene, targets, material, params, **kwargs)


def fit_scene(scene, targets, materials=None, params=SCENE_PARAMS, *, method="raytrace", **kwargs) -> FitResult:
    """`fit` through the recorded ray tree by default, every material an object uses and the ray
    tracer's kr, kt and absorption among the default params; every keyword of `fit`."""
    return fit(scene, targets, materials, params, method=method, **kwargs)

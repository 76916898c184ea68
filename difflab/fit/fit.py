"""`fit_material`: material coefficients (and light intensities) from images, with optimistix.

Warp renders each view's G-buffer once; JAX re-forms the image from it (`shading.py`) as often as
the solver asks, and the solver only ever sees the residuals (`problem.py`).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import FitError
from .params import build_layout, initial_values, public_value, u_from_values, values_from_u
from .problem import LOSSES, Problem, make_view
from .result import FitResult
from .shading import MaterialTable
from .solve import SOLVERS, SUCCESSFUL, RECORDER, make_solver, run_solver
from .stats import poorly_determined, psnr, standard_errors
from .targets import influence, load_views

DEFAULT_TOL = {True: (1e-8, 1e-10), False: (1e-5, 1e-7)}  # (rtol, atol) by x64


def _materials(scene, material) -> tuple[str, ...]:
    if material is None:
        used = sorted({obj.material for obj in scene.objects}, key=scene.material_names.index)
        if len(used) != 1:
            raise FitError(f"material: the scene uses {len(used)} materials ({', '.join(used)}); name the one(s) "
                           "to fit")
        return (used[0],)
    if isinstance(material, str):
        return (material,)
    material = tuple(material)
    if not material or len(set(material)) != len(material):
        raise FitError(f"material: expected one or more distinct names, got {list(material)}")
    return material


class Setup:
    """A fit prepared: scene, views, layout, the device problem, starting values. Reused by the
    batched fit and the benchmark so that only the solve is timed."""

    def __init__(self, scene, targets, material=None, params=("ka", "kd", "ks", "n"), *, per_channel=True,
                 bounded=False, loss="l2", loss_scale=0.05, masks=None, weights=None, init=None, x64=True,
                 device="cpu"):
        if loss not in LOSSES:
            raise FitError(f"loss: unknown loss {loss!r}; known: {', '.join(LOSSES)}")
        if not (isinstance(loss_scale, (int, float)) and loss_scale > 0):
            raise FitError(f"loss_scale: must be a number > 0, got {loss_scale!r}")
        self.scene, self.views = load_views(scene, targets, masks, weights, device)
        self.materials = _materials(self.scene, material)
        textured = [name for name, mat in self.scene.materials.items() if mat.texture is not None]
        fits_lights = any(str(p).endswith("intensity") for p in ((params,) if isinstance(params, str) else params))
        if textured and (fits_lights or set(textured) & set(self.materials)):
            raise FitError(f"material: {', '.join(textured)} has an image texture, which fit_material's image "
                           "formation does not model; fit the texture with difflab.fit.texture_fit.fit_texture, "
                           "or fit through the ray tree with fit_scene")
        self.layout = build_layout(self.scene, self.materials, params, per_channel, bounded)
        self.initial = initial_values(self.scene, self.layout, init)
        self.x64 = bool(x64)
        self.dtype = jnp.float64 if x64 else jnp.float32
        ids = {self.scene.material_index(name) for name in self.materials}
        all_points = any(p.kind == "intensity" for p in self.layout)
        self.used = [v.mask & (v.weight > 0).any(axis=-1) & influence(v.gbuffer, ids, all_points) for v in self.views]
        self.used_pixels = int(sum(int(u.sum()) for u in self.used))
        self.nonfinite = int(sum(v.nonfinite for v in self.views))
        with jax.enable_x64(self.x64):
            table = MaterialTable.from_scene(self.scene.materials.values(), self.dtype)
            ambient = jnp.asarray(self.scene.ambient, self.dtype)
            views = tuple(make_view(v, u, table, ambient, ids, all_points, self.dtype)
                          for v, u in zip(self.views, self.used))
            self.problem = Problem(views=views, table=table, ambient=ambient,
                                   loss_scale=jnp.asarray(loss_scale, self.dtype), layout=self.layout, loss=loss)
            self.u0 = u_from_values(self.layout, self.initial, self.dtype)

    def values(self, u) -> dict:
        with jax.enable_x64(self.x64):
            return {k: np.asarray(v, np.float64) for k, v in values_from_u(self.layout, u).items()}

    def precheck(self) -> str | None:
        return precheck(self)


def precheck(setup) -> str | None:
    """A difflab result code when a prepared fit cannot be made (non-finite target values under the
    masks, or no pixel that the fitted parameters affect), else None."""
    if setup.nonfinite:
        return "nonfinite_target"
    if setup.used_pixels == 0:
        return "empty_mask"
    return None


def _loss_of(entry) -> float:
    """A history entry as a float: a loss, or a (loss, parameters) pair as `solve` logs them."""
    if isinstance(entry, tuple):
        entry = entry[0]
    return float(np.asarray(entry, np.float64).reshape(-1)[0])


def finish(setup: Setup, values: dict | None, result: str, steps: int, seconds: float, history: list,
            solver: str, timings: dict, rel_tol: float, abs_tol: float, throw: bool) -> FitResult:
    """The FitResult of a solve: values in scene units, standard errors, flags, the result code
    (raising FitError for a failure when `throw`)."""
    layout = setup.layout
    if values is None:  # no fit was made
        params = {p.key: public_value(p, setup.initial[p.key]) for p in layout}
        nan = {p.key: public_value(p, np.full(p.size, np.nan)) for p in layout}
        out = FitResult(params=params, stderr=nan, loss=float("nan"), psnr=float("nan"), steps=0, seconds=seconds,
                        converged=False, result=result, history=[], poorly_determined=[p.key for p in layout],
                        initial=params, solver=solver, timings=timings, scene=setup.scene, layout=layout)
    else:
        start = time.perf_counter()
        with jax.enable_x64(setup.x64):
            jvalues = {k: jnp.asarray(v, setup.dtype) for k, v in values.items()}
            finite = all(np.all(np.isfinite(v)) for v in values.values())
            residuals = setup.problem.residuals_from_values(jvalues)
            loss = float(0.5 * sum(float(jnp.sum(r * r)) for r in residuals))
            if finite and np.isfinite(loss):
                st = standard_errors(setup.problem, jvalues, layout)
                stderr = st["stderr"]
                flagged = poorly_determined(layout, values, st["stderr_floor"], rel_tol, abs_tol)
            else:
                stderr = {p.key: np.full(p.size, np.nan) for p in layout}
                flagged = [p.key for p in layout]
                if result == SUCCESSFUL:
                    result = "nonfinite"
            fit_psnr = psnr(setup.problem, jvalues)
        timings = {**timings, "stats": time.perf_counter() - start}
        out = FitResult(
            params={p.key: public_value(p, values[p.key]) for p in layout},
            stderr={p.key: public_value(p, stderr[p.key]) for p in layout},
            loss=loss, psnr=fit_psnr, steps=steps, seconds=seconds,
            converged=bool(result == SUCCESSFUL and finite and np.isfinite(loss)), result=result,
            history=[_loss_of(h) for h in history], poorly_determined=flagged,
            initial={p.key: public_value(p, setup.initial[p.key]) for p in layout}, solver=solver,
            timings=timings, scene=setup.scene, layout=layout)
    if throw and not out.converged:
        raise FitError(f"fit did not converge: {out.result} after {out.steps} steps (loss {out.loss:.4g})")
    return out


def solve(setup: Setup, solver="lm", *, max_steps=256, rtol=None, atol=None, learning_rate=0.05, history=True):
    """Run one solver on a prepared fit: (values in scene units, result name, steps, seconds, log), where
    log is [(loss, unconstrained parameters)] per step when `history` (the latter None for solvers
    that do not report them)."""
    if solver not in SOLVERS:
        raise FitError(f"solver: unknown solver {solver!r}; known: {', '.join(SOLVERS)}")
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise FitError(f"max_steps: must be an integer >= 1, got {max_steps!r}")
    default_rtol, default_atol = DEFAULT_TOL[setup.x64]
    rtol = default_rtol if rtol is None else float(rtol)
    atol = default_atol if atol is None else float(atol)
    optimiser = make_solver(solver, rtol, atol, learning_rate, history)
    if history:
        RECORDER.start()
    start = time.perf_counter()
    try:
        with jax.enable_x64(setup.x64):
            if solver == "varpro":
                from .varpro import check_applicable, run_varpro

                check_applicable(setup.problem, setup.layout)
                values, result, steps = run_varpro(optimiser, setup.u0, setup.problem, setup.layout, max_steps)
                values = {k: np.asarray(v, np.float64) for k, v in values.items()}
                if result == SUCCESSFUL and any(np.any(values[p.key] < 0) for p in setup.layout):
                    # the unconstrained linear solve went negative: polish within the constraints
                    u = u_from_values(setup.layout, {k: np.maximum(v, 0.0) for k, v in values.items()}, setup.dtype)
                    u, result, more = run_solver(make_solver("lm", rtol, atol, history=history), u, setup.problem,
                                                 max_steps)
                    values, steps = setup.values(u), steps + more
            else:
                u, result, steps = run_solver(optimiser, setup.u0, setup.problem, max_steps)
                jax.block_until_ready(u)
                values = setup.values(u)
    finally:
        log = RECORDER.stop() if history else []
    return values, result, steps, time.perf_counter() - start, log


def fit_material(scene, targets, material=None, params=("ka", "kd", "ks", "n"), *, solver="lm", per_channel=True,
                 bounded=False, loss="l2", loss_scale=0.05, masks=None, weights=None, init=None, max_steps=256,
                 rtol=None, atol=None, learning_rate=0.05, x64=True, throw=False, device="cpu", history=True,
                 rel_tol=0.1, abs_tol=1e-3) -> FitResult:
    """Fit material coefficients (and optionally light intensities) so the rendered image matches targets.

        minimise  sum_views sum_pixels  rho( sqrt(w) (render(params) - target) )^2

    where render is the rasterizer's image formation re-done in JAX on each view's G-buffer (rendered
    once by Warp; geometry, shadows and light directions stay fixed).

    Arguments:
        scene: a Scene, a scene dict, or a scene file path. Its values are the starting point.
        targets: an image ((H, W, 3) linear float array, or a file: 8-bit files are sRGB-decoded and
            the model is clipped to [0, 1] to match), or a list of images and/or (image, overrides)
            pairs; overrides is a dict with a whole "camera" block and/or a whole "lights" list (scene
            file format) for that view. Each view is rendered at its target's size.
        material: the material name, or several names; default: the scene's only material.
        params: any of "ka", "kd", "ks" (RGB; one grey value with per_channel=False), "n", "m", "f0",
            "intensity" (every light's; RGB) or "lights[i].intensity"; a tuple or "ka,kd".
        solver: "lm" (Levenberg-Marquardt), "gauss_newton", "dogleg", "bfgs", "adam" (optax Adam with
            `learning_rate`), or "varpro" (exact linear solve for ka, kd, ks inside an LM search over
            n, m, f0).
        bounded: keep ka, kd, ks in [0, 1] (sigmoid) instead of >= 0 (softplus).
        loss: "l2", "huber" or "cauchy" (`loss_scale`: the residual size where they turn robust).
        masks: per target (H, W) bool (True: the pixel counts); weights: per target (H, W[, 3]) >= 0.
        init: name -> starting value, overriding the scene's.
        max_steps, rtol, atol: solver limits (tolerances default by precision).
        x64: compute in float64. throw: raise FitError instead of returning a failed result.
        device: where Warp renders the G-buffers ("cpu" or "cuda").
        history: record the loss at each step. rel_tol, abs_tol: the poorly-determined threshold.
    Returns:
        a `FitResult`; `converged` false and `result` naming why when the fit failed.
    """
    start = time.perf_counter()
    setup = Setup(scene, targets, material, params, per_channel=per_channel, bounded=bounded, loss=loss,
                  loss_scale=loss_scale, masks=masks, weights=weights, init=init, x64=x64, device=device)
    return run_fit(setup, solver, time.perf_counter() - start, max_steps=max_steps, rtol=rtol, atol=atol,
                   learning_rate=learning_rate, history=history, rel_tol=rel_tol, abs_tol=abs_tol, throw=throw)


def run_fit(setup, solver: str, setup_seconds: float, *, max_steps, rtol, atol, learning_rate, history, rel_tol,
            abs_tol, throw) -> FitResult:
    """Solve a prepared fit (a `Setup` or anything with its interface) and report it: the result code
    of `precheck` without solving when the fit cannot be made, else `solve` then `finish`."""
    timings = {"setup": setup_seconds}
    code = setup.precheck()
    if code is not None:
        return finish(setup, None, code, 0, 0.0, [], solver, timings, rel_tol, abs_tol, throw)
    values, result, steps, seconds, log = solve(setup, solver, max_steps=max_steps, rtol=rtol, atol=atol,
                                               learning_rate=learning_rate, history=history)
    timings["solve"] = seconds
    return finish(setup, values, result, steps, seconds, log, solver, timings, rel_tol, abs_tol, throw)

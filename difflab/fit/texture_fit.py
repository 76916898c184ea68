"""Fitting a texture: a spatially varying coefficient (a texture of unknown texels) from rendered images.

Given the G-buffer of each view, a sample of the textured material is *affine* in the texels:

    sample_s = a_s + F_s * sum_k w_sk T[i_sk]          (per channel)

where T[i_sk], w_sk are the sample's filter taps (texel indices and bilinear / nearest weights at
its uv, exactly the Warp kernel's), F_s is what the textured coefficient multiplies (the illumination
model lit with that coefficient 1 and the others 0: `lighting.jax_model.target_only`) and a_s the rest
of the model (the coefficient 0); fog blends both, and pixels are the spp x spp box mean of
samples. So the residual r(T) = pixels(T) - target is linear in T with a sparse Jacobian (4 taps per
sample), applied matrix-free: optimistix's Levenberg-Marquardt (or Gauss-Newton) with lineax's
conjugate gradients on the normal equations (lx.Normal(lx.CG)) as the inner solve scales to hundreds of
thousands of texels. An optional smoothness prior adds sqrt(smoothness) x the differences of
neighbouring texels (its normal matrix is the texture's graph Laplacian), which also fixes texels
no sample sees.

Warp runs once per view (the G-buffer, before the fit); the loop evaluates only JAX (DESIGN.md,
invariant 3). Shading: Phong (the shading points are the samples). Filters: "nearest" and
"bilinear" (the magnification filters; level 0 only).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from ..errors import FitError
from ..lighting.jax_model import fog_factor, lights_to_jax, shade, surface_material, target_only, textured_material
from ..lighting.warp_model import FOG_NONE, SPECULAR_MODELS, TEXTURE_TARGET_IDS
from .cache import enable_compilation_cache
from .materials import MaterialTable

enable_compilation_cache()

FIT_FILTERS = ("nearest", "bilinear")
RESULT_NAMES = {int(item._value): name for name, item in optx.RESULTS._name_to_item.items()}


class TextureView(NamedTuple):
    """One view's sparse sampling operator and affine shading terms (numpy, built once).

    sample: (S,) flat indices of the textured samples on the (H', W') sample grid; texel (S, K) and
    weight (S, K): their taps into the (H_t * W_t) texels (texture orientation, row 0 = v 0);
    offset, gain: (S, 3) the a_s and F_s above (fog included); rest: (H', W', 3) every other sample's
    fixed colour (0 at the textured ones); spp_side; target: (H, W, 3) the image to match."""

    sample: np.ndarray
    texel: np.ndarray
    weight: np.ndarray
    offset: np.ndarray
    gain: np.ndarray
    rest: np.ndarray
    spp_side: int
    target: np.ndarray


@dataclass(frozen=True)
class TextureFitResult:
    """texture: (H_t, W_t, 3) fitted linear texels, image orientation (row 0 at the top, as
    `load_texture`); visible: (H_t, W_t) bool, texels the views constrain (total tap weight times
    gain above `visible_threshold`); loss: 0.5 sum r^2 at the solution; rmse: of the pixel residuals;
    steps; seconds; result: optimistix's result code name; converged: result == "successful";
    n_params: number of unknowns."""

    texture: np.ndarray
    visible: np.ndarray
    loss: float
    rmse: float
    steps: int
    seconds: float
    result: str
    converged: bool
    n_params: int


def texture_taps(uv: np.ndarray, shape: tuple[int, int], filter: str, wrap: str) -> tuple[np.ndarray, np.ndarray]:
    """Texel indices and weights (N, K) of `filter` at level 0 of an (H_t, W_t) texture for uv (N, 2),
    with the Warp kernel's conventions (`renderers.texture.sampling`: texel centres at half-integers, wrap on
    the integer index)."""
    h, w = shape
    uv = np.asarray(uv, np.float32)
    if filter == "nearest":
        col = np.floor(uv[:, 0] * np.float32(w))
        row = np.floor(uv[:, 1] * np.float32(h))
        return (wrap_np(row, h, wrap) * w + wrap_np(col, w, wrap))[:, None], np.ones((uv.shape[0], 1), np.float32)
    if filter != "bilinear":
        raise FitError(f"filter: texture fitting supports {FIT_FILTERS}, got {filter!r}")
    x = uv[:, 0] * np.float32(w) - np.float32(0.5)
    y = uv[:, 1] * np.float32(h) - np.float32(0.5)
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    cols = [wrap_np(x0, w, wrap), wrap_np(x0 + 1, w, wrap)]
    rows = [wrap_np(y0, h, wrap), wrap_np(y0 + 1, h, wrap)]
    index = np.stack([rows[0] * w + cols[0], rows[0] * w + cols[1], rows[1] * w + cols[0], rows[1] * w + cols[1]], 1)
    weight = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return index, weight.astype(np.float32)


def wrap_np(i: np.ndarray, n: int, wrap: str) -> np.ndarray:
    """`renderers.texture.sampling.wrap_index` in numpy: integer-valued float indices -> [0, n - 1]."""
    i = np.where(np.isfinite(i), i, 0.0).astype(np.float64)
    if wrap == "clamp":
        i = np.clip(i, 0, n - 1)
    elif wrap == "mirror":
        i = np.mod(i, 2 * n)
        i = np.where(i >= n, 2 * n - 1 - i, i)
    else:
        i = np.mod(i, n)
    return np.clip(i, 0, n - 1).astype(np.int64)


def _affine_terms(gbuffer, sample, scene, mat):
    """F_s and a_s at the textured samples: the illumination model (jax_model) lit with the target
    coefficient 1 and the others 0, and with the target coefficient 0; fog applied to both."""
    pts = gbuffer.points
    light_dist = np.where(np.isfinite(pts.light_dist[sample]), pts.light_dist[sample], np.inf)
    lights = lights_to_jax(tuple(scene.lights), jnp.float64)
    base = surface_material(MaterialTable.from_scene([mat], jnp.float64), 0, jnp.int32(0))  # the one table
    target_id = TEXTURE_TARGET_IDS[mat.texture_target]
    model = SPECULAR_MODELS[gbuffer.specular]
    ambient = jnp.asarray(gbuffer.ambient, jnp.float64)
    def f64(x):
        return jnp.asarray(x, jnp.float64)

    at = (f64(pts.normal[sample]), f64(pts.view[sample]), lights, f64(pts.light_dir[sample]), f64(light_dist),
          f64(pts.visibility[sample]), ambient)
    gain = np.asarray(shade(target_only(base, target_id), model, *at))
    offset = np.asarray(shade(textured_material(base, target_id, jnp.zeros(3)), model, *at))
    mode, fog_color, start, end, density = gbuffer.fog
    if mode != FOG_NONE:
        f = np.asarray(fog_factor(mode, jnp.asarray(gbuffer.depth.reshape(-1)[sample]), start, end, density))[:, None]
        gain, offset = f * gain, f * offset + (1.0 - f) * np.asarray(fog_color)
    return gain, offset


def texture_view(gbuffer, target, scene, material: str, shape: tuple[int, int], filter: str | None = None,
                 wrap: str | None = None) -> TextureView:
    """The sampling operator and affine terms of one rendered view (Phong G-buffer) for the texture of
    `material` (its filter / wrap unless given), an (H_t, W_t) texture of unknowns."""
    if gbuffer.shading != "phong":
        raise FitError("texture fit: needs a Phong-shaded G-buffer (shading points = samples), "
                       f"got {gbuffer.shading!r}")
    names = list(scene.materials)
    if material not in names:
        raise FitError(f"material: {material!r} is not in the scene ({', '.join(names)})")
    mat = scene.materials[material]
    mat_id = names.index(material)
    filter = filter or mat.filter
    wrap = wrap or mat.wrap
    target = np.asarray(target, np.float64)
    grid = gbuffer.mask.shape
    side = gbuffer.spp_side
    if target.shape != (grid[0] // side, grid[1] // side, 3):
        raise FitError(f"target: expected shape {(grid[0] // side, grid[1] // side, 3)}, got {target.shape}")
    flat_material = gbuffer.material.reshape(-1)
    sample = np.flatnonzero(flat_material == mat_id)
    if sample.size == 0:
        raise FitError(f"material {material!r}: no sample of this view shows it")
    texel, weight = texture_taps(gbuffer.uv.reshape(-1, 2)[sample], shape, filter, wrap)

    with jax.enable_x64(True):
        gain, offset = _affine_terms(gbuffer, sample, scene, mat)
    # Samples of nothing keep the background; the view must show no other material.
    rest = np.where(gbuffer.mask[..., None], 0.0, np.asarray(gbuffer.background, np.float64))
    rest = np.broadcast_to(rest, grid + (3,)).copy()
    others = gbuffer.mask & (gbuffer.material != mat_id)
    if others.any():
        raise FitError(f"texture fit: the view shows other materials besides {material!r}; crop or hide them")
    rest.reshape(-1, 3)[sample] = 0.0
    return TextureView(sample=sample, texel=texel, weight=weight, offset=offset, gain=gain, rest=rest, spp_side=side,
                       target=target)


def _pixels(texels, view: TextureView):
    """The view's image (H, W, 3) for texels (N_t, 3)."""
    sampled = jnp.sum(view.weight[..., None] * texels[view.texel], axis=1)  # (S, 3)
    values = view.offset + view.gain * sampled
    grid = view.rest.reshape(-1, 3).at[view.sample].set(values).reshape(view.rest.shape)
    side = view.spp_side
    if side == 1:
        return grid
    h, w = grid.shape[0] // side, grid.shape[1] // side
    return grid.reshape(h, side, w, side, 3).mean(axis=(1, 3))


def _residuals(texels, args):
    views, shape, smoothness = args
    parts = [(_pixels(texels, v) - v.target).reshape(-1) for v in views]
    if smoothness > 0.0:
        grid = texels.reshape(shape + (3,))
        scale = jnp.sqrt(smoothness)
        parts += [scale * (grid[:, 1:] - grid[:, :-1]).reshape(-1), scale * (grid[1:] - grid[:-1]).reshape(-1)]
    return jnp.concatenate(parts)


def fit_texture(views, shape: tuple[int, int], *, smoothness: float = 0.0, solver: str = "lm", init=0.5,
                max_steps: int = 50, cg_steps: int = 500, rtol: float = 1e-10, atol: float = 1e-10,
                visible_threshold: float = 1e-3, x64: bool = True, throw: bool = False) -> TextureFitResult:
    """Fit an (H_t, W_t) RGB texture of unknowns to the target images of `views` (`texture_view`s).

    minimise 0.5 sum_views |pixels(T) - target|^2 + 0.5 smoothness sum |T_neighbour - T|^2

    Arguments:
        views: TextureView list (one per rendered image).
        shape: (H_t, W_t) texels.
        smoothness: weight of the first-difference prior (0: none).
        solver: "lm" (optimistix.LevenbergMarquardt) or "gauss_newton", both with lineax.NormalCG
            (matrix-free: J v and J^T v by autodiff; `cg_steps` iterations at most per solve).
        init: starting texel value (scalar or (H_t, W_t, 3) image orientation).
        max_steps: outer iterations; rtol, atol: optimistix's and CG's tolerances.
        throw: raise FitError when the solver does not succeed (else the code is in `.result`).
    Returns:
        TextureFitResult (failure is a value: `.result`, `.converged`).
    """
    views = list(views)
    if not views:
        raise FitError("views: need at least one view")
    h, w = shape
    start = time.perf_counter()
    with jax.enable_x64(x64):
        dtype = jnp.float64 if x64 else jnp.float32
        cast = [TextureView(*(jnp.asarray(f, dtype) if isinstance(f, np.ndarray) and f.dtype.kind == "f" else
                              (jnp.asarray(f) if isinstance(f, np.ndarray) else f) for f in v)) for v in views]
        init = np.asarray(init, np.float64)
        y0 = (np.broadcast_to(init, (h, w, 3)) if init.ndim else np.full((h, w, 3), float(init)))
        y0 = jnp.asarray(np.flipud(y0).reshape(-1, 3), dtype)
        inner = lx.Normal(lx.CG(rtol=rtol, atol=atol, max_steps=cg_steps))  # CG on J^T J (NormalCG)
        if solver == "lm":
            method = optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=inner)
        elif solver == "gauss_newton":
            method = optx.GaussNewton(rtol=rtol, atol=atol, linear_solver=inner)
        else:
            raise FitError(f"solver: expected 'lm' or 'gauss_newton', got {solver!r}")
        args = (cast, (h, w), float(smoothness))
        sol = optx.least_squares(_residuals, method, y0, args=args, max_steps=max_steps, throw=False)
        texels = sol.value
        r = _residuals(texels, (cast, (h, w), 0.0))
        loss = float(0.5 * jnp.sum(_residuals(texels, args) ** 2))
        rmse = float(jnp.sqrt(jnp.mean(r ** 2)))
        steps = int(sol.stats["num_steps"])
        code = RESULT_NAMES.get(int(sol.result._value), str(sol.result))
        coverage = np.zeros(h * w)
        for v in views:
            np.add.at(coverage, np.asarray(v.texel).reshape(-1),
                      (np.asarray(v.weight) * np.asarray(v.gain).mean(axis=1, keepdims=True)).reshape(-1))
        texture = np.flipud(np.asarray(texels, np.float64).reshape(h, w, 3)).astype(np.float32)
    result = TextureFitResult(texture=texture, visible=np.flipud(coverage.reshape(h, w) > visible_threshold),
                              loss=loss, rmse=rmse, steps=steps, seconds=time.perf_counter() - start, result=code,
                              converged=code == "successful", n_params=h * w * 3)
    if throw and not result.converged:
        raise FitError(f"texture fit did not converge: {code} after {steps} steps (rmse {rmse:.3g})")
    return result

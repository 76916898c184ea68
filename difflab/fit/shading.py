"""Image formation in JAX from a Warp G-buffer: the same image the rasterizer composed, differentiable.

The rasterizer evaluates the illumination model at shading points (every covered sample for Phong
shading, every face for flat, every vertex twice for Gouraud) and records what each point saw: its
normal, view direction, and per light the direction, distance and shadow-ray visibility. Each sample
is then a weighted sum of three points' colours (Gouraud: optionally clamped to [0, 1] first), the
background where nothing was hit, OpenGL fog by depth, and finally an spp_side x spp_side box filter.

Here the colours of the points come from `lighting.jax_model.shade` -- the one illumination model --
and the rest of the composition is repeated in `jax.numpy`. Only materials and light intensities are
inputs: geometry, visibility and the light directions are fixed by the G-buffer, so an optimisation
loop shades the same points again and again without running Warp (DESIGN.md, invariant 3).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..lighting.jax_model import LightsJ, MaterialJ, fog_factor, lights_to_jax, shade
from ..lighting.warp_model import FOG_NONE, SPECULAR_MODELS


class MaterialTable(NamedTuple):
    """M materials stacked, indexed by material id: ka, kd, ks, ka2, kd2 (M, 3); n, m, f0 (M,).

    ka2 / kd2 are the checker's second cell (equal to ka / kd for materials without a checker, as in
    `warp_model.material_struct`)."""

    ka: jnp.ndarray
    kd: jnp.ndarray
    ks: jnp.ndarray
    n: jnp.ndarray
    m: jnp.ndarray
    f0: jnp.ndarray
    ka2: jnp.ndarray
    kd2: jnp.ndarray

    @classmethod
    def from_scene(cls, materials, dtype=jnp.float32) -> MaterialTable:
        """From scene `Material`s in material-id order (a Scene's `materials.values()`)."""
        materials = list(materials)

        def stack(get, shape):
            values = np.asarray([get(mat) for mat in materials], np.float64).reshape((len(materials),) + shape)
            return jnp.asarray(values, dtype=dtype)

        def second(name):
            return lambda mat: getattr(mat.checker, name) if mat.checker is not None else getattr(mat, name[:2])

        return cls(ka=stack(lambda m: m.ka, (3,)), kd=stack(lambda m: m.kd, (3,)), ks=stack(lambda m: m.ks, (3,)),
                   n=stack(lambda m: m.n, ()), m=stack(lambda m: m.m, ()), f0=stack(lambda m: m.f0, ()),
                   ka2=stack(second("ka2"), (3,)), kd2=stack(second("kd2"), (3,)))


class PointsJ(NamedTuple):
    """Shading points as JAX arrays (see `render.frame.ShadingPoints`): normal, view (N, 3); material,
    cell (N,) int32; light_dir (N, P, 3); light_dist, visibility (N, P)."""

    normal: jnp.ndarray
    view: jnp.ndarray
    material: jnp.ndarray
    cell: jnp.ndarray
    light_dir: jnp.ndarray
    light_dist: jnp.ndarray
    visibility: jnp.ndarray

    def take(self, index) -> PointsJ:
        """The points at `index` (a 1-D integer array)."""
        return PointsJ(*(field[index] for field in self))


class ComposeJ(NamedTuple):
    """Per-sample composition on the (H', W') sample grid: mask (bool), depth (0 where empty),
    point_index (H', W', 3) int32 (clipped to valid points), point_weight (H', W', 3); background,
    fog_color (3,); fog_start, fog_end, fog_density scalars."""

    mask: jnp.ndarray
    depth: jnp.ndarray
    point_index: jnp.ndarray
    point_weight: jnp.ndarray
    background: jnp.ndarray
    fog_color: jnp.ndarray
    fog_start: jnp.ndarray
    fog_end: jnp.ndarray
    fog_density: jnp.ndarray


class Formation(NamedTuple):
    """The static (hashable) settings of image formation: specular model (int), fog mode (int),
    spp_side, and whether Gouraud vertex colours are clamped to [0, 1]."""

    specular: int
    fog_mode: int
    spp_side: int
    clamp_colors: bool


def gbuffer_arrays(gbuffer, dtype=jnp.float32) -> tuple[PointsJ, ComposeJ, Formation]:
    """Split a `GBuffer` into JAX arrays (points, composition) and its static settings."""
    pts = gbuffer.points
    count = max(int(pts.material.shape[0]), 1)

    def f(x):
        return jnp.asarray(np.asarray(x, np.float64), dtype=dtype)

    def pad(x, fill):  # a G-buffer with no points still needs one row to gather from
        x = np.asarray(x)
        if x.shape[0]:
            return x
        return np.full((1,) + x.shape[1:], fill, dtype=x.dtype)

    points = PointsJ(
        normal=f(pad(pts.normal, 0.0)), view=f(pad(pts.view, 0.0)),
        material=jnp.asarray(pad(pts.material, -1), jnp.int32), cell=jnp.asarray(pad(pts.cell, 0), jnp.int32),
        light_dir=f(pad(pts.light_dir, 0.0)),
        light_dist=f(np.where(np.isfinite(pad(pts.light_dist, 1.0)), pad(pts.light_dist, 1.0), np.inf)),
        visibility=f(pad(pts.visibility, 0.0)),
    )
    mode, color, start, end, density = gbuffer.fog
    mask = np.asarray(gbuffer.mask, bool)
    compose = ComposeJ(
        mask=jnp.asarray(mask), depth=f(np.where(mask, gbuffer.depth, 0.0)),
        point_index=jnp.asarray(np.clip(gbuffer.point_index, 0, count - 1), jnp.int32),
        point_weight=f(np.where(mask[..., None], gbuffer.point_weight, 0.0)),
        background=f(gbuffer.background), fog_color=f(color), fog_start=f(start), fog_end=f(end),
        fog_density=f(density),
    )
    formation = Formation(specular=SPECULAR_MODELS[gbuffer.specular], fog_mode=int(mode),
                          spp_side=int(gbuffer.spp_side), clamp_colors=bool(gbuffer.clamp_vertex_colors))
    return points, compose, formation


def point_colors(points: PointsJ, table: MaterialTable, lights: LightsJ, ambient, specular: int):
    """The illumination model at each point with its material (checker cell 1: ka2 / kd2); 0 where
    a point has no material. Returns (N, 3)."""
    has_material = points.material >= 0
    mat_id = jnp.where(has_material, points.material, 0)
    second = (points.cell == 1)[:, None]
    mat = MaterialJ(
        ka=jnp.where(second, table.ka2[mat_id], table.ka[mat_id]),
        kd=jnp.where(second, table.kd2[mat_id], table.kd[mat_id]),
        ks=table.ks[mat_id], n=table.n[mat_id], m=table.m[mat_id], f0=table.f0[mat_id],
    )
    color = shade(mat, specular, points.normal, points.view, lights, points.light_dir, points.light_dist,
                  points.visibility, ambient)
    return jnp.where(has_material[:, None], color, 0.0)


def compose(colors, comp: ComposeJ, formation: Formation):
    """Samples from point colours (weights, clamp, background, fog), box-filtered to (H, W, 3) pixels."""
    gathered = colors[comp.point_index]  # (H', W', 3 points, 3 channels)
    if formation.clamp_colors:
        gathered = jnp.clip(gathered, 0.0, 1.0)
    surface = jnp.sum(comp.point_weight[..., None] * gathered, axis=-2)
    if formation.fog_mode != FOG_NONE:
        f = fog_factor(formation.fog_mode, comp.depth, comp.fog_start, comp.fog_end, comp.fog_density)[..., None]
        surface = f * surface + (1.0 - f) * comp.fog_color
    samples = jnp.where(comp.mask[..., None], surface, comp.background)
    side = formation.spp_side
    if side == 1:
        return samples
    h, w = samples.shape[0] // side, samples.shape[1] // side
    return samples.reshape(h, side, w, side, 3).mean(axis=(1, 3))


def shade_gbuffer(gbuffer, materials, lights, ambient=None, *, dtype=jnp.float32):
    """The rasterizer's image re-formed in JAX from its G-buffer, for given materials and lights.

        pixel = box_filter( fog( sum_k w_k * shade(point_k) ) )   (background where nothing was hit)

    Arguments:
        gbuffer: a `render.frame.GBuffer` (from `render_frame(...).gbuffer`).
        materials: a `MaterialTable`, or scene `Material`s in material-id order (e.g.
            `scene.materials.values()`).
        lights: a `LightsJ`, or scene `Light`s (their directions / distances / visibility are the
            G-buffer's; only intensity, attenuation and spot settings are read from here).
        ambient: (3,) Ia; default: the G-buffer's.
    Returns:
        (H, W, 3) JAX array of linear RGB, equal to `Frame.image` (to float32 rounding) when the
        arguments are the scene's own.
    """
    points, comp, formation = gbuffer_arrays(gbuffer, dtype)
    table = materials if isinstance(materials, MaterialTable) else MaterialTable.from_scene(materials, dtype)
    lights = lights if isinstance(lights, LightsJ) else lights_to_jax(tuple(lights), dtype)
    ambient = jnp.asarray(gbuffer.ambient if ambient is None else ambient, dtype)
    return _shade_jit(points, comp, table, lights, ambient, formation)


@functools.partial(jax.jit, static_argnames="formation")
def _shade_jit(points, comp, table, lights, ambient, formation):
    colors = point_colors(points, table, lights, ambient, formation.specular)
    return compose(colors, comp, formation)

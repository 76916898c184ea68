"""Image formation in JAX from a Warp G-buffer: the same image the rasterizer composed, differentiable.

The rasterizer evaluates the illumination model at shading points (every covered sample for Phong
shading, every face for flat, every vertex twice for Gouraud) and records what each point saw: its
normal, view direction, and per light the direction, distance and shadow-ray visibility. Each sample
is then a weighted sum of three points' colours (Gouraud: optionally clamped to [0, 1] first), the
background where nothing was hit, OpenGL fog by depth, and finally an spp_side x spp_side box filter.

Here the colours of the points come from `lighting.jax_model.shade` -- the one illumination model --
and the rest of the composition is repeated in `jax.numpy`. Only materials and light intensities are
inputs: geometry, visibility and the light directions are fixed by the G-buffer, so an optimisation
loop shades the same points again and again without running Warp (DESIGN.md, invariant 3). What the
geometry alone decides (per point and light: falloff times visibility times N.L, the specular lobe's
cosine and its logarithm; `jax_model.LightGeometry`) is computed once, when the model is built, and
a pixel that is exactly one point's colour (one sample, weight 1, no fog or clamping: Phong and flat
shading at spp 1) skips the composition, so each evaluation is a few operations per point and light.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import FitError
from ..lighting.jax_model import (LightGeometry, LightsJ, fog_factor, light_geometry, lights_to_jax, shade_geometry,
                                  sum_axis, textured_surface)
from ..lighting.warp_model import FOG_NONE, SPECULAR_MODELS
from ..renderers.frame import POINT_ROWS, point_row_columns
from .materials import MaterialTable
from .problem import assembled, take_rows_of
from .texels import pixel_texels, point_texels


class PointsJ(NamedTuple):
    """Shading points as JAX arrays (see `renderers.frame.ShadingPoints`): normal, view (N, 3); material,
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


class PointRows(NamedTuple):
    """Shading points as two arrays (`pixel_arrays`): rows (R, K) float32, the fields POINT_ROWS side
    by side (`ShadingPoints.rows`; cell as int32 bits, K = 7 + 5 P), and material (R,) int32: what the
    device model is built from -- two arguments to move (`_device_model`)."""

    rows: np.ndarray
    material: np.ndarray

    def points(self) -> PointsJ:
        """The `PointsJ` of these points: numpy views of the rows, or in a jitted function their slices."""
        field = {k: self.rows[:, columns] for k, columns in point_row_columns(self.rows.shape[1]).items()}
        cell = field["cell"][:, 0]
        cell = cell.view(np.int32) if isinstance(cell, np.ndarray) else jax.lax.bitcast_convert_type(cell, jnp.int32)
        return PointsJ(normal=field["normal"], view=field["view"], material=self.material, cell=cell,
                       light_dir=field["light_dir"].reshape(self.rows.shape[0], -1, 3), light_dist=field["light_dist"],
                       visibility=field["visibility"])


def point_rows(pts, rows: np.ndarray) -> PointRows:
    """The `PointRows` of a G-buffer's points `pts` (`ShadingPoints`) at `rows`: one take of its
    `rows` block where it has one, else of each field, side by side."""
    if pts.rows is not None:
        block, material = take_rows_of([pts.rows, pts.material], rows)  # (one buffer)
    else:
        columns = [np.take(getattr(pts, k).reshape(pts.material.shape[0], -1), rows, axis=0) for k in POINT_ROWS]
        block = np.concatenate([c.astype(np.int32, copy=False).view(np.float32) if k == "cell" else
                                c.astype(np.float32, copy=False) for k, c in zip(POINT_ROWS, columns)], 1)
        material = np.take(pts.material, rows)
    return PointRows(rows=block, material=np.asarray(material, np.int32))


class ComposeJ(NamedTuple):
    """How U pixels are composed from S = spp_side^2 samples each: mask (U, S) bool (a surface was
    hit); depth (U, S) (0 where empty, and everywhere from a fit's G-buffer without fog, which has
    none: read only by fog); point_index (U, S, 3) int32 into the points given with it;
    point_weight (U, S, 3) (0 where empty); background, fog_color (3,); fog_start, fog_end,
    fog_density scalars."""

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
    whether Gouraud vertex colours are clamped to [0, 1], and direct: each pixel is its own point's
    colour (the points are in pixel order; no composition)."""

    specular: int
    fog_mode: int
    clamp_colors: bool
    direct: bool = False


def pixel_arrays(gbuffer, pixels=None, dtype=jnp.float32, covered: bool = False
                 ) -> tuple[PointRows, ComposeJ | None, Formation, np.ndarray]:
    """The G-buffer cut down to what `pixels` need, as numpy arrays (`GBufferModel.build` moves them to
    the device in one call).

    Arguments:
        gbuffer: a `GBuffer`.
        pixels: (U,) flat pixel indices (row * width + column); default: every pixel, in order.
        covered: every one of `pixels` is known covered (`own_points`).
    Returns:
        (points, composition, formation, point_ids): only the R shading points the pixels' samples
        use, as `PointRows` (point_ids (R,) are their indices in `gbuffer.points`; real fields in
        the G-buffer's own precision, float32: a jitted user casts them exactly), and the composition
        of the U pixels with point indices renumbered into them (None when `formation.direct`: pixel
        i is point i).
    """
    side = int(gbuffer.spp_side)
    height, width = gbuffer.material.shape[0] // side, gbuffer.material.shape[1] // side  # (not the mask: a fit
    # frame's is formed on first read, `raster.gbuffer._FitGBuffer`)
    pixels = np.arange(height * width) if pixels is None else np.asarray(pixels, np.int64).reshape(-1)
    pts = gbuffer.points
    mode, color, start, end, density = gbuffer.fog
    fog_mode, clamp_colors = int(mode), bool(gbuffer.clamp_vertex_colors)
    point_ids = None
    if points_may_be_pixels(gbuffer):
        point_ids = own_points(gbuffer, pixels, covered)
    # direct: each pixel is one point's colour (the points, in pixel order, are the pixels)
    formation = Formation(specular=SPECULAR_MODELS[gbuffer.specular], fog_mode=fog_mode, clamp_colors=clamp_colors,
                          direct=point_ids is not None)
    comp = None
    if point_ids is None:
        if side == 1:
            samples = pixels[:, None]  # (U, S) flat sample indices
        else:
            row, col = np.divmod(pixels, width)
            di, dj = (x.reshape(-1) for x in np.meshgrid(np.arange(side), np.arange(side), indexing="ij"))
            samples = (row[:, None] * side + di) * (width * side) + col[:, None] * side + dj
        take = lambda array, *channels: np.take(array.reshape(-1, *channels), samples, axis=0)  # noqa: E731 (numpy's
        mask = take(np.asarray(gbuffer.mask, bool))  # fast gather: several times an index expression's speed)
        if gbuffer.point_index is None:  # a fit's Phong frame (`fit_frame`): each sample its own point, weight 1
            index = np.repeat(samples.astype(np.int32)[..., None], 3, axis=-1)
            weight = mask[..., None] * np.array([1, 0, 0], np.float32)
        else:
            index = take(gbuffer.point_index, 3)
            weight = take(gbuffer.point_weight, 3)
        if not mask.all():  # an empty sample's points are not read
            index, weight = np.where(mask[..., None], index, 0), np.where(mask[..., None], weight, 0.0)
        point_ids = np.unique(index[mask]) if mask.any() else np.zeros(0, np.int64)
        point_ids = point_ids[point_ids < pts.material.shape[0]]
        local = np.searchsorted(point_ids, index).clip(0, max(point_ids.size - 1, 0))
        real = np.dtype(dtype)
        comp = ComposeJ(
            mask=mask, depth=np.zeros(mask.shape, real) if gbuffer.depth is None else  # (no fog: not read)
            np.where(mask, take(gbuffer.depth), 0.0).astype(real),
            point_index=np.asarray(local, np.int32), point_weight=weight.astype(real),
            background=np.asarray(gbuffer.background, real), fog_color=np.asarray(color, real),
            fog_start=np.asarray(start, real), fog_end=np.asarray(end, real), fog_density=np.asarray(density, real))
    if point_ids.size:
        points = point_rows(pts, point_ids.astype(np.intp, copy=False))
    else:  # nothing hit: one dummy point with no material (colour 0), never used
        n_lights = pts.light_dir.shape[1] if pts.light_dir.ndim == 3 else 0
        rows = np.zeros((1, 7 + 5 * n_lights), np.float32)
        rows[:, point_row_columns(rows.shape[1])["light_dist"]] = 1.0
        points = PointRows(rows=rows, material=np.full(1, -1, np.int32))
    return points, comp, formation, point_ids


def points_may_be_pixels(gbuffer) -> bool:
    """Whether a pixel of the G-buffer can be exactly one point's colour (`own_points`; then
    `Formation.direct`): one sample a pixel, no fog, no vertex colours clamped."""
    return int(gbuffer.spp_side) == 1 and int(gbuffer.fog[0]) == FOG_NONE and not bool(gbuffer.clamp_vertex_colors)


def own_points(gbuffer, pixels, covered: bool = False) -> np.ndarray | None:
    """At spp 1, the point of each pixel in `pixels` (U,) (point_ids) when each is covered and
    exactly its point's colour (point weights (1, 0, 0), a valid first point index), else None.
    Under Phong shading the points are the samples, in sample order (`GBuffer.light_dir`): a covered
    pixel's point is the pixel itself, and only the mask is read. `covered`: the caller knows each
    is (a fit's pixels used: `Setup._model`), the mask is not read (the bench's 24.7k: ~20 us of a
    first fit's cold setup)."""
    if not covered and not np.take(gbuffer.mask.reshape(-1), pixels).all():
        return None
    if gbuffer.shading == "phong":
        return pixels
    weight = np.take(gbuffer.point_weight.reshape(-1, 3), pixels, axis=0)
    if not ((weight[:, 0] == 1.0).all() and not weight[:, 1:].any()):  # (1, 0, 0): ~2x a compare with it
        return None
    point_ids = np.take(gbuffer.point_index.reshape(-1, 3), pixels, axis=0)[:, 0]
    return point_ids if point_ids.max(initial=0) < gbuffer.points.material.shape[0] else None


def point_colors(material, cell, geometry: LightGeometry, table: MaterialTable, intensity, ambient, specular: int,
                 texel=None, targets=None):
    """The illumination model (`jax_model.shade_geometry`) at points with material ids `material`
    (N,) (-1: none, colour 0), checker cells `cell` (N,), their `LightGeometry` (N, P) and texture
    values `texel` (N, 3) modulating their texture's target, one of the TARGET_* ids `targets`
    (`jax_model.textured_surface`; None: none / all); intensity (P, 3). Returns (N, 3)."""
    has_material = material >= 0
    mat = textured_surface(table, jnp.where(has_material, material, 0), cell, texel, targets)
    color = shade_geometry(mat, specular, geometry, intensity, ambient)
    return jnp.where(has_material[:, None], color, 0.0)


def compose(colors, comp: ComposeJ, formation: Formation):
    """Pixels (U, 3) from point colours (R, 3): per sample the weighted colours of its points (Gouraud:
    optionally clamped to [0, 1] first), background where empty, fog; then the mean of each pixel's
    samples (the box filter)."""
    gathered = colors[comp.point_index]  # (U, S, 3 points, 3 channels)
    if formation.clamp_colors:
        gathered = jnp.clip(gathered, 0.0, 1.0)
    surface = sum_axis(comp.point_weight[..., None] * gathered, -2)
    if formation.fog_mode != FOG_NONE:
        f = fog_factor(formation.fog_mode, comp.depth, comp.fog_start, comp.fog_end, comp.fog_density)[..., None]
        surface = f * surface + (1.0 - f) * comp.fog_color
    samples = jnp.where(comp.mask[..., None], surface, comp.background)
    return sum_axis(samples, 1) / samples.shape[1]


def shade_gbuffer(gbuffer, materials, lights, ambient=None, *, dtype=jnp.float32):
    """The rasterizer's image re-formed in JAX from its G-buffer, for given materials and lights.

        pixel = box_filter( fog( sum_k w_k * shade(point_k) ) )   (background where nothing was hit)

    Arguments:
        gbuffer: a `renderers.frame.GBuffer` (from `render_frame(...).gbuffer`).
        materials: a `MaterialTable`, or scene `Material`s in material-id order (e.g.
            `scene.materials.values()`).
        lights: a `LightsJ`, or scene `Light`s (their directions / distances / visibility are the
            G-buffer's; only intensity, attenuation and spot settings are read from here).
        ambient: (3,) Ia; default: the G-buffer's.
    Returns:
        (H, W, 3) JAX array of linear RGB, equal to `Frame.image` (to float32 rounding) when the
        arguments are the scene's own. A textured material's samples take the G-buffer's filtered
        texel (`GBuffer.texture`) times the coefficient the texture targets, as the renderer does
        under Phong shading (a ray-traced G-buffer is Phong's); under flat and Gouraud shading the
        texel modulates interpolated lighting, which is not formed here: a FitError.
    """
    table = materials if isinstance(materials, MaterialTable) else MaterialTable.from_scene(materials, dtype)
    lights = lights if isinstance(lights, LightsJ) else lights_to_jax(tuple(lights), dtype)
    ambient = jnp.asarray(gbuffer.ambient if ambient is None else ambient, dtype)
    side = int(gbuffer.spp_side)
    shape = (gbuffer.mask.shape[0] // side, gbuffer.mask.shape[1] // side, 3)
    model = GBufferModel.build(gbuffer, None, lights, dtype, fixed_texels=True)
    textured = [m for m in model.material_ids if m >= 0 and int(table.texture_target[m]) >= 0]
    if textured and model.texel is None:
        raise FitError(f"shade_gbuffer: materials[{textured[0]}] has an image texture, which the {gbuffer.shading} "
                       "G-buffer's image model does not form (textures are re-formed under phong shading only)")
    return _pixels_jit(model, table, lights, ambient).reshape(shape)


def is_one_of(ids: np.ndarray, chosen) -> np.ndarray:
    """ids == any of `chosen` (a few material ids), elementwise: comparisons, for a handful (`np.isin`
    sorts: ~50x their cost on a 256 x 256 G-buffer)."""
    chosen = [int(m) for m in chosen]
    if len(chosen) > 8:
        return np.isin(ids, chosen)
    if len(chosen) == 1:  # (one pass)
        return ids == chosen[0]
    out = np.zeros(ids.shape, bool)
    for m in chosen:
        out |= ids == m
    return out


def distinct_ids(ids: np.ndarray) -> tuple:
    """The distinct values of an int array of ids >= -1, sorted: one pass each for min and max when
    they are equal (a single material: ~20x faster than counting), else counted."""
    low, high = (int(ids.min()), int(ids.max())) if ids.size else (0, -1)
    if low == high:
        return (low,)
    return tuple(int(m) - 1 for m in np.flatnonzero(np.bincount(ids + 1)))


def influence(gbuffer, material_ids, any_surface: bool) -> np.ndarray:
    """(H, W) bool: pixels whose colour depends on the fitted materials (or on any surface when
    light intensities are fitted); read only (at spp 1 the latter is the G-buffer's own mask)."""
    if any_surface:
        touched = gbuffer.mask
    else:
        touched = is_one_of(gbuffer.material, material_ids)
        if gbuffer.shading != "phong":  # a sample's colour mixes its points': look at those
            point_material = gbuffer.points.material
            if point_material.size:
                index = np.clip(gbuffer.point_index, 0, point_material.size - 1)
                from_points = is_one_of(point_material[index], material_ids) & (gbuffer.point_weight != 0)
                touched = touched | (gbuffer.mask & from_points.any(axis=-1))
    side = gbuffer.spp_side
    if side == 1:  # a sample is a pixel
        return touched
    h, w = touched.shape[0] // side, touched.shape[1] // side
    return touched.reshape(h, side, w, side).any(axis=(1, 3))


class GBufferModel(eqx.Module):
    """The G-buffer image model of U pixels: their points' material ids, checker cells and
    `LightGeometry` under the lights it was built for, the composition and the formation
    (`pixel_arrays`), and -- when texels are fitted -- each point's taps into the table's stacked
    texels (rows (R, K), -1: none; tap_weight (R, K); targets: the TARGET_* ids those textures
    modulate; see `texels.py`); or -- `shade_gbuffer` -- texel (R, 3): each point's filtered texel,
    `GBuffer.texture` at its sample (Phong shading: the points are the samples), fixed; material_ids:
    the distinct material ids among its points (static).
    `pixels` is the (U, 3) image for given materials, light intensities (the lights' other fields
    are those it was built with) and ambient."""

    material: jnp.ndarray
    cell: jnp.ndarray
    geometry: LightGeometry
    comp: ComposeJ | None
    formation: Formation = eqx.field(static=True)
    taps: jnp.ndarray | None = None
    tap_weight: jnp.ndarray | None = None
    targets: tuple | None = eqx.field(static=True, default=None)
    material_ids: tuple = eqx.field(static=True, default=())
    texel: jnp.ndarray | None = None

    @classmethod
    def build(cls, gbuffer, pixels, lights: LightsJ, dtype, texels=None, fixed_texels=False,
              covered: bool = False) -> GBufferModel:
        """`texels`: a `texels.TexelSource` for the fitted textures, or None; `fixed_texels`: the
        points' texels from `GBuffer.texture` (`texel`), where the G-buffer has them under Phong shading;
        `covered`: see `pixel_arrays`."""
        points, comp, formation, point_ids = pixel_arrays(gbuffer, pixels, dtype, covered)
        kinds = tuple(sorted(set(np.asarray(lights.kind).tolist())))  # the terms the geometry needs
        flat = PointRows(points.rows.reshape(-1), points.material)  # (see `_device_model`)
        material, cell, geometry, comp = _device_model(flat, comp, lights, formation.specular, kinds)
        taps = tap_weight = None
        if texels is not None:
            rows, weight = texels.taps(gbuffer, point_ids)
            if point_ids.size == 0:  # the dummy point of `pixel_arrays`
                rows, weight = np.full((1, 4), -1, np.int32), np.zeros((1, 4))
            taps, tap_weight = jnp.asarray(rows), jnp.asarray(np.asarray(weight, np.float64), dtype)
        texel = None
        if fixed_texels and gbuffer.shading == "phong" and gbuffer.texture is not None and point_ids.size:
            texel = jnp.asarray(np.take(gbuffer.texture.reshape(-1, 3), point_ids, axis=0), dtype)
        return assembled(cls, material=material, cell=cell, geometry=geometry, comp=comp, formation=formation,
                         taps=taps, tap_weight=tap_weight, targets=None if texels is None else texels.targets,
                         material_ids=distinct_ids(points.material), texel=texel)  # (the dummy point's id: -1)

    def point_texels(self, texels):
        """(R, 3) each point's texture value from the stacked `texels` (its filter taps)."""
        return point_texels(texels, self.taps, self.tap_weight)

    def texel_reads(self) -> tuple[np.ndarray, np.ndarray]:
        """(pixel, texel) int64 pairs (M,): the stacked fitted texels each of the U pixels reads --
        its points' taps (direct: pixel i is point i; composed: the points of its samples)."""
        if self.formation.direct:
            point = np.arange(self.material.shape[0])
            return pixel_texels(point, point, self.taps)
        index = np.asarray(self.comp.point_index).reshape(self.comp.point_index.shape[0], -1)  # (U, 3 S)
        pixel = np.repeat(np.arange(index.shape[0]), index.shape[1])
        return pixel_texels(pixel, index.reshape(-1), self.taps)

    def pixels(self, table: MaterialTable, lights: LightsJ, ambient, texel=None):
        """`texel` (R, 3): the points' texture values (default: `point_texels(table.texels)`, or the
        fixed `self.texel`)."""
        if texel is None:
            texel = self.texel if self.taps is None else self.point_texels(table.texels)
        colors = point_colors(self.material, self.cell, self.geometry, table, lights.intensity, ambient,
                              self.formation.specular, texel, self.targets)
        return colors if self.formation.direct else compose(colors, self.comp, self.formation)


@partial(jax.jit, static_argnums=(3, 4))
def _device_model(points: PointRows, comp: ComposeJ | None, lights: LightsJ, specular: int, kinds: tuple):
    """(material ids, cells, `LightGeometry`, composition) on the device from `pixel_arrays`' numpy
    arrays, the rows flattened (shaped back here: XLA's CPU code converts and reads an (N, 3)
    argument at a fraction of a flat one's speed -- 0.47 against 0.65 ms for 24768 points): one call
    moves them all; a light distance that is not finite is infinite (a directional light's).
    `kinds`: the lights' LIGHT_TYPES ids (`light_falloff`)."""
    real = lambda field: field.astype(lights.intensity.dtype)  # noqa: E731 (float32 G-buffer values, exactly)
    points = points._replace(rows=points.rows.reshape(points.material.shape[0], -1)).points()
    distance = real(points.light_dist)
    geometry = light_geometry(specular, real(points.normal), real(points.view), lights, real(points.light_dir),
                              jnp.where(jnp.isfinite(distance), distance, jnp.inf), real(points.visibility), kinds)
    return points.material, points.cell, geometry, comp


@eqx.filter_jit
def _pixels_jit(model, table, lights, ambient):
    return model.pixels(table, lights, ambient)

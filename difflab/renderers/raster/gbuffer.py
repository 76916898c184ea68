"""The rasterizer's G-buffer: the arrays stages 4-6 fill, in the structs the kernels read (kept
between frames: `CompiledScene.reusable_structs`), and the numpy `GBuffer` a frame returns."""

from __future__ import annotations

import functools

import numpy as np

from ..._warp import wp

from ...lighting.warp_model import fog_params
from ..frame import POINT_ROWS, GBuffer, ShadingPoints
from ..host import ROWS, to_host
from . import resolve, shade


def point_fields(count: int, samples: bool) -> list[tuple]:
    """(field, shape, dtype, zero where a sample is empty) of the arrays of `count` shading points
    (`resolve.PointsW`); the G-buffer's `samples` keep no shadow-ray start (geometric normal, object
    skipped), and their material is written where empty."""
    kept = 0 if samples else count
    return [("position", count, wp.vec3, True), ("normal", count, wp.vec3, True), ("view", count, wp.vec3, True),
            ("material", count, wp.int32, False), ("cell", count, wp.int32, True), ("duv_dx", count, wp.vec2, True),
            ("duv_dy", count, wp.vec2, True), ("geo_normal", kept, wp.vec3, False), ("ignore", kept, wp.int32, False)]


def gbuffer_fields(count: int) -> list[tuple]:
    """`point_fields` of stage 4's other per-sample outputs (`resolve.GBufferW`): zero where empty,
    or written everywhere."""
    return [("face", count, wp.int32, False), ("bary", count, wp.vec3, True), ("depth", count, wp.float32, False),
            ("uv", count, wp.vec2, True), ("object", count, wp.int32, False), ("point_index", count, wp.vec3i, False),
            ("point_weight", count, wp.vec3, True)]


def lit_fields(n_lights: int, n_points: int, n_samples: int) -> list[tuple]:
    """`point_fields` of stage 6's outputs for the G-buffer (`shade.LitW`), all zero where not
    written (an empty point's): per point and light, direction, distance, visibility (one zero
    column without lights); per point its colour and texture factor; per sample its texel (written
    by stage 6 when the points are the samples, else by stage 7 on textured samples)."""
    per_light = (n_points, max(n_lights, 1))
    return [("light_dir", per_light, wp.vec3, True), ("light_dist", per_light, wp.float32, True),
            ("visibility", per_light, wp.float32, True), ("color", max(n_points, 1), wp.vec3, True),
            ("factor", max(n_points, 1), wp.vec3, True), ("texel", n_samples, wp.vec3, True)]


def filled(struct, name: str, fields: list[tuple], array):
    """`struct` with each field's array `array(f"{name}.{field}", shape, dtype, zero)`."""
    for field, shape, dtype, zero in fields:
        setattr(struct, field, array(f"{name}.{field}", shape, dtype, zero))
    return struct


def fit_skips(compiled) -> frozenset:
    """The fields a fit's G-buffer (`driver.rasterize(geometry_only=True)`, Phong shading) does not
    form, as nothing of the fit reads them (`fit.shading`, `fit.texels`, `fit.ceiling`, `fit.edges`
    read the mask and material, object, the points' normal, view, cell and light geometry, and uv
    for fitted texels): their arrays are empty (nothing to clear or write; the kernels skip an empty
    field) and the GBuffer's are None. Always the points' colours and texture factors (no point is
    lit), the texels (a fit samples its own), the uv derivatives, each sample's face and barycentrics,
    its position (a sphere's hit is kept in `gbuffer_layout`'s scratch instead) and its point index
    and weight (each Phong sample is its own point, weight (1, 0, 0): `fit.shading.pixel_arrays`
    forms them from the mask where it composes); the depth without fog (only fog reads it); uv in a
    compiled scene without a texture (it is formed only where one of its device materials samples
    one; a view's scene does not change them). The names hold in every struct of the layout
    (PointsW, GBufferW, LitW); face and bary go together (`resolve_into` writes bary where face is
    formed). The 256^2 bench sphere's fit frame (one light): its arrays 7.7 -> 3.7 MB,
    6.0 -> 3.2 MB of them cleared (and 0.6 MB of sphere hits written to the scratch): see
    `api.fit_frame` for the times."""
    skips = {"color", "factor", "texel", "duv_dx", "duv_dy", "face", "bary", "position", "point_index", "point_weight"}
    if compiled.scene.fog is None:
        skips.add("depth")
    if not compiled.textures.pyramids:
        skips.add("uv")
    return frozenset(skips)


def gbuffer_arrays(compiled, n_samples: int, phong: bool, geometry_only: bool = False):
    """Stage 4's arrays for the G-buffer, and stage 6's when the points are the samples (`phong`), in
    their structs (`CompiledScene.reusable_structs`: an earlier frame's when free): (samples, out, lit
    or None, found, stale, views), `views` their `HostViews` (`to_gbuffer`), `found` the PointsW where `resolve.sphere_rays` keeps each sample's sphere
    hit (samples itself, or a fit's scratch), `stale` the buffer of those that must start zero when an
    earlier frame left it, for the caller to zero (else None: new memory); `geometry_only`: a fit's
    (its `fit_skips` fields empty), kept apart from a full G-buffer's (fits and G-buffer renders of one compiled
    scene in turn each find their own free), its POINT_ROWS the columns of one block under Phong
    shading (`ShadingPoints.rows`; the material apart: the mask and the influence map read it whole,
    ~7x as fast as a column), and never stale: its pass writes every entry of a covered sample and
    zeroes those of an uncovered one that held a point in the buffer's last frame
    (`shade.gbuffer_row`), so nothing is cleared (the 256^2 bench sphere's 3.2 MB: a pool worker's
    memset beside the assembly, 60-150 us, which woke it there and held back its half of the
    z-buffer)."""
    skips = fit_skips(compiled) if geometry_only else None
    layout = gbuffer_layout(n_samples, phong, skips, len(compiled.scene.lights))
    structs, stale, views = compiled.reusable_structs("fit gbuffer" if geometry_only else "gbuffer", layout)
    return (structs[0], structs[1], structs[2] if phong else None, structs[-1] if geometry_only else structs[0],
            None if geometry_only else stale, views)


@functools.lru_cache(maxsize=32)
def gbuffer_layout(n_samples: int, phong: bool, skips: frozenset | None, n_lights: int) -> tuple:
    """The structs and fields of `gbuffer_arrays`, as `CompiledScene.reusable_structs` takes them
    (shapes as tuples), made once per frame size and kept: gbuffer_arrays in a fit's frame ~17 -> 4 us
    (the kept structs' layout then equal item by item by identity). `skips`: a fit's (`fit_skips`),
    with a last PointsW of scratch for the sphere hits (position and view per sample, never cleared:
    written and read back by the row's own thread; the position kept in the G-buffer instead, or a
    scratch of one row per band, measured no faster on the bench sphere and a teapot, interleaved
    at loads 1-4), or None."""
    layout = [(resolve.PointsW, point_fields(n_samples, True)), (resolve.GBufferW, gbuffer_fields(n_samples))]
    if phong:
        layout.append((shade.LitW, lit_fields(n_lights, n_samples, n_samples)))
    if skips is not None:
        layout = [(struct, [(field, 0, dtype, False) if field in skips else
                            (field, shape, dtype, ROWS if phong and field in POINT_ROWS else zero)
                            for field, shape, dtype, zero in fields]) for struct, fields in layout]
        layout.append((resolve.PointsW, [(field, n_samples if field in ("position", "view") else 0, dtype, False)
                                         for field, unused, dtype, unused in point_fields(n_samples, True)]))
    return tuple((struct, tuple((field, (shape,) if isinstance(shape, int) else tuple(shape), dtype, zero)
                                for field, shape, dtype, zero in fields)) for struct, fields in layout)


def to_gbuffer(scene, settings, side: int, grid: tuple[int, int], samples, out, points, n_points: int,
               lit, clamp_colors: bool, geometry_only: bool = False, kept=None) -> GBuffer:
    """The device buffers of stages 4-6 as a numpy `GBuffer` on the sample grid; `geometry_only`
    (a fit's record: `driver.rasterize`): the fields it does not form (`fit_skips`) are None, and the
    others read-only (the compiled scene's next fit frame reuses their memory uncleared:
    `gbuffer_arrays`). `kept` (with `geometry_only`, on the CPU, where the GBuffer's arrays are views
    of the device arrays): the `HostViews` of its structs, where that GBuffer is kept, made once per
    struct set and scene settings -- a frame's GBuffer is then a copy of it with its own mask (a
    fit's first frame: to_gbuffer 139 -> 30 us, medians of 40 at load ~1)."""
    if kept is None:
        return _gbuffer(scene, settings, side, grid, samples, out, points, n_points, lit, clamp_colors, geometry_only)
    key = (grid, side, settings.shading, settings.specular, clamp_colors, scene.ambient, scene.background, scene.fog)
    if kept.kept is None or kept.kept[0] != key:
        kept.keep((key, _gbuffer(scene, settings, side, grid, samples, out, points, n_points, lit, clamp_colors,
                                 True)), _viewed)
    frame = _copy(kept.kept[1], _FitGBuffer, points=_copy(kept.kept[1].points))
    del frame.__dict__["mask"]  # (this frame's: formed from its material on first read)
    return frame


class _FitGBuffer(GBuffer):
    """A fit frame's `GBuffer` (`to_gbuffer`'s kept one, copied): its mask formed from its own
    material on first read -- a fit whose pixels are those of its fitted materials reads only its
    shape (`fit.shading.pixel_arrays`), where forming it cost ~15 us of a cold frame."""

    @functools.cached_property
    def mask(self) -> np.ndarray:
        return self.material >= 0


def _viewed(kept) -> list:
    """The numpy arrays of a kept (key, GBuffer) and every ndarray up their `base` chains: an array
    derived from any of them refers to one of those (numpy's base of a view of a view is the first
    array up the chain that does not view another ndarray)."""
    out = {}
    for record in (kept[1], kept[1].points):
        for value in vars(record).values():
            while isinstance(value, np.ndarray):
                out[id(value)] = value
                value = value.base
    return list(out.values())


def _copy(record, kind=None, **fields):
    """A frozen dataclass's copy with `fields` replaced (`dataclasses.replace` without its __init__),
    as a `kind` (default: the record's class)."""
    out = object.__new__(kind or type(record))
    out.__dict__.update(vars(record), **fields)
    return out


def _gbuffer(scene, settings, side, grid, samples, out, points, n_points, lit, clamp_colors, geometry_only):
    """`to_gbuffer`'s GBuffer, made afresh (`geometry_only`: a fit's, every array read-only)."""
    def host(array):
        return fixed(to_host(array))

    def fixed(array):
        if geometry_only:
            array.flags.writeable = False
        return array

    def on_grid(array, *channels):
        return None if geometry_only and array.shape[0] == 0 else host(array).reshape(*grid, *channels)

    def per_point(array, count=None):
        return None if geometry_only and array.shape[0] == 0 else host(array)[:count]

    material, normal, rows = on_grid(samples.material), host(points.normal), None
    if normal.strides[0] != normal.shape[1] * normal.itemsize:  # POINT_ROWS: one block's columns, normals first
        rows = np.lib.stride_tricks.as_strided(normal, (normal.shape[0], normal.strides[0] // normal.itemsize),
                                               normal.strides, writeable=False)
    fog = fog_params(scene.fog)
    return GBuffer(
        mask=material >= 0, depth=on_grid(out.depth), position=on_grid(samples.position, 3),
        normal=on_grid(samples.normal, 3), uv=on_grid(out.uv, 2), material=material,
        object=on_grid(out.object), face=on_grid(out.face), bary=on_grid(out.bary, 3),
        point_index=on_grid(out.point_index, 3), point_weight=on_grid(out.point_weight, 3),
        points=ShadingPoints(
            position=per_point(points.position), normal=normal, view=host(points.view),
            material=host(points.material), cell=host(points.cell), light_dir=host(lit.light_dir),
            light_dist=host(lit.light_dist), visibility=host(lit.visibility),
            color=per_point(lit.color, n_points), texture_factor=per_point(lit.factor, n_points), rows=rows),
        shading=settings.shading, specular=settings.specular, spp_side=side,
        ambient=fixed(np.asarray(scene.ambient, np.float32)),
        background=fixed(np.asarray(scene.background, np.float32)),
        clamp_vertex_colors=clamp_colors, fog=(fog[0], fixed(fog[1]), *fog[2:]),
        duv_dx=on_grid(samples.duv_dx, 2), duv_dy=on_grid(samples.duv_dy, 2), texture=on_grid(lit.texel, 3),
    )

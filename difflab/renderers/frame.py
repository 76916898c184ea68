"""What a render returns: the image and the G-buffer it was shaded from.

The G-buffer is laid out so that the JAX model can reproduce the image exactly: the illumination
model is evaluated at *shading points* (every covered sample for Phong shading, every face for flat,
every vertex twice -- front and back -- for Gouraud), and each sample's colour is a weighted sum of
three points' colours (`point_index`, `point_weight`), then background and fog, then the spp x spp
box filter of the sample grid down to pixels.
"""

from __future__ import annotations

import functools

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import RenderError


@dataclass(frozen=True)
class ShadingPoints:
    """N points where the illumination model is evaluated, and what it saw there (P lights).

    position, normal (unit, facing the viewer), view (unit, to the viewer): (N, 3) float32;
    material: (N,) int32 (-1: nothing); cell: (N,) int32 checker cell; light_dir: (N, P, 3) unit
    direction to each light; light_dist: (N, P) (inf for directional lights); visibility: (N, P) in
    [0, 1] from shadow rays; color: (N, 3) the Warp model's radiance.

    Textures under flat and Gouraud shading: a textured material's point `color` is lit with the
    texture's target coefficient set to 0, and `texture_factor` (N, 3) is what a texel multiplies
    (the point lit with only that coefficient, the others 0); each sample then adds its own
    texel times the interpolated factor (see `GBuffer`). Zero elsewhere (and always under Phong).
    A fit's own rasterized frame under Phong shading (`renderers.api.fit_frame`) forms neither, nor
    `position`: None there.

    rows: None, or (N, K) float32 whose columns hold the POINT_ROWS fields side by side, in that
    order (cell as int32 bits; K = 7 + 5 P), each field a view of its columns: a fit's rasterized
    frame on the CPU, whose points a fit gathers in one take of rows (`fit.shading.pixel_arrays`;
    ~50 us for 24768 of 65536 points, ~200 us field by field)."""

    position: np.ndarray | None
    normal: np.ndarray
    view: np.ndarray
    material: np.ndarray
    cell: np.ndarray
    light_dir: np.ndarray
    light_dist: np.ndarray
    visibility: np.ndarray
    color: np.ndarray | None
    texture_factor: np.ndarray | None = None
    rows: np.ndarray | None = None


POINT_ROWS = ("normal", "view", "cell", "light_dir", "light_dist", "visibility")  # `ShadingPoints.rows`' fields


def point_row_columns(width: int) -> dict[str, slice]:
    """Each POINT_ROWS field's columns in a `ShadingPoints.rows` of `width` = 7 + 5 P columns (P
    light columns: the lights, or one zero column without any)."""
    n_lights = (width - 7) // 5
    widths = (3, 3, 1, 3 * n_lights, n_lights, n_lights)
    starts = np.cumsum((0,) + widths).tolist()
    return {k: slice(a, b) for k, a, b in zip(POINT_ROWS, starts, starts[1:])}


@dataclass(frozen=True)
class GBuffer:
    """Per-sample buffers on the sample grid (height*spp_side, width*spp_side), row 0 at the top.

    mask: bool, a surface is there; depth: eye-space distance along the view axis (inf where empty);
    position, normal: (.., 3) world-space surface point and shading normal; uv: (.., 2);
    material, object, face: int32 ids (-1 where empty); bary: (.., 3) weights of the face's vertices.
    `face` indexes the triangles the rasterizer drew, `compiled.raster(shading).faces` for the
    frame's shading (the mesh objects' `n_mesh_faces` first, then the analytic spheres' and planes'
    tessellation, Phong's spheres coarser), not `compiled.faces` (the mesh triangles alone): a face
    id >= n_mesh_faces is a tessellated sphere's or plane's;
    point_index (.., 3) int32 and point_weight (.., 3): which shading points make the sample's colour.
    duv_dx, duv_dy (.., 2): the exact screen-space derivatives of the interpolated uv per sample step
    (the Jacobian columns texture filtering uses). Under Phong shading a sample on an analytic
    sphere is the sphere's own point on its eye ray, with normal (p - c) / r, uv the sphere's there
    and its derivatives over the sample's footprint, as the ray tracer has them (`bary` and `face`
    still name the triangle that covered it); texture (.., 3): the filtered texel at each sample
    of a textured material (0 elsewhere). A fit's own rasterized frame under Phong shading
    (`renderers.api.fit_frame`) forms only what the fit reads: `face`, `bary`, `position`,
    `point_index`, `point_weight` (each sample its own point), the uv derivatives and `texture`
    are None there, `depth` too without fog, and `uv` in a scene without a texture
    (`renderers.raster.gbuffer.fit_skips`).

    A sample of a textured material (texture replacing its `texture_target` coefficient) is
    - Phong: shaded with the coefficient replaced by `texture` at that sample (its own point);
    - flat / Gouraud (OpenGL-style per-fragment texturing): sum_k w_k color_k + texture *
      sum_k w_k texture_factor_k (each term clamped to [0, 1] first when `clamp_vertex_colors`),
      i.e. the target term's lighting is interpolated and the texture modulates it per sample.
    """

    mask: np.ndarray
    depth: np.ndarray | None
    position: np.ndarray | None
    normal: np.ndarray
    uv: np.ndarray | None
    material: np.ndarray
    object: np.ndarray
    face: np.ndarray | None
    bary: np.ndarray | None
    point_index: np.ndarray | None
    point_weight: np.ndarray | None
    points: ShadingPoints
    shading: str
    specular: str
    spp_side: int
    ambient: np.ndarray
    background: np.ndarray
    clamp_vertex_colors: bool
    fog: tuple  # (mode, color, start, end, density) as `lighting.warp_model.fog_params`
    duv_dx: np.ndarray | None = None
    duv_dy: np.ndarray | None = None
    texture: np.ndarray | None = None

    @property
    def light_dir(self) -> np.ndarray:
        """Per-light directions; per sample (H', W', P, 3) for Phong shading, per point otherwise."""
        return self._per_sample(self.points.light_dir)

    @property
    def light_dist(self) -> np.ndarray:
        return self._per_sample(self.points.light_dist)

    @property
    def visibility(self) -> np.ndarray:
        return self._per_sample(self.points.visibility)

    def _per_sample(self, values: np.ndarray) -> np.ndarray:
        if self.shading == "phong":
            return values.reshape(self.mask.shape + values.shape[1:])
        return values


@dataclass(frozen=True)
class Frame:
    """A rendered frame: `image` (H, W, 3) float32 linear RGB, its `gbuffer`, `stats` (counts, timings,
    non-finite pixels) and, from the ray tracer, its recorded `ray_tree`.

    A rasterized frame carries its G-buffer (`buffers`). A ray-traced frame carries `gbuffer_source`
    instead, which builds the G-buffer of its primary hits from the ray tree (the tree's root nodes,
    `raytrace.gbuffer.tree_gbuffer`: shading "phong", two-sided shading normals facing the incoming
    ray, mesh-only `face` ids, no uv derivatives) the first time `gbuffer` is read, and keeps it: a
    frame whose G-buffer is never read never builds it. `gbuffer` raises RenderError for a frame
    with neither (`render`'s and `raytrace(record_tree=False)`'s, adaptive supersampling's)."""

    image: np.ndarray
    buffers: GBuffer | None
    stats: dict = field(default_factory=dict)
    ray_tree: object = None
    gbuffer_source: Callable[[], GBuffer] | None = field(default=None, repr=False, compare=False)

    @functools.cached_property  # (kept in the instance's __dict__: a frozen dataclass allows it)
    def gbuffer(self) -> GBuffer:
        if self.buffers is not None:
            return self.buffers
        if self.gbuffer_source is None:
            raise RenderError(f"gbuffer: this {self.stats.get('method', 'raytrace')} frame kept no G-buffer "
                              f"(nor a recorded ray tree to build one from); render it with render_frame "
                              f"(method 'raster' or 'raytrace'), which keeps it -- not render, "
                              f"raytrace(record_tree=False) or adaptive supersampling")
        return self.gbuffer_source()


def box_downsample(samples: np.ndarray, side: int) -> np.ndarray:
    """Average side x side blocks of an (H*side, W*side, C) sample grid into (H, W, C) pixels."""
    if side == 1:
        return samples
    h, w = samples.shape[0] // side, samples.shape[1] // side
    return samples.reshape(h, side, w, side, *samples.shape[2:]).mean(axis=(1, 3), dtype=np.float64).astype(samples.dtype)

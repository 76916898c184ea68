"""The G-buffer of a ray-traced frame: its recorded ray tree's root nodes (the primary hits) laid out
on the sample grid as the rasterizer's `GBuffer`, built when `Frame.gbuffer` is first read.

Sample s (row i, column j of the grid, s = i * cols + j) is root node `tree.sample_offset[s]`.
Where the ray tracer's buffers differ from the rasterizer's (see `tree_gbuffer`): `face` numbers mesh
triangles only (-1 on the exact spheres and planes), `bary` is 0 off mesh triangles, `uv` is set only
where a textured material was hit, and there are no uv derivatives.
"""

from __future__ import annotations

import numpy as np

from ...lighting.warp_model import fog_params
from ..camera import camera_frame
from ..frame import GBuffer, ShadingPoints


def triangle_weights(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(M, 3) float32 barycentric weights (w0, w1, w2) of points p on triangles (a, b, c), all (M, 3):
    p = w0 a + w1 b + w2 c, w0 = 1 - w1 - w2, (w1, w2) solving the 2 x 2 normal equations of
    p - a = w1 (b - a) + w2 (c - a) in float64 (the least-squares weights for a point off the plane).
    A zero-area triangle, which no ray hits, gives (1, 0, 0)."""
    p, a, b, c = (np.asarray(x, np.float64) for x in (p, a, b, c))
    e1, e2, d = b - a, c - a, p - a
    d11, d12, d22 = (e1 * e1).sum(-1), (e1 * e2).sum(-1), (e2 * e2).sum(-1)
    d1, d2 = (d * e1).sum(-1), (d * e2).sum(-1)
    det = d11 * d22 - d12 * d12
    det = np.where(det > 0.0, det, np.inf)
    w1, w2 = (d22 * d1 - d12 * d2) / det, (d11 * d2 - d12 * d1) / det
    return np.stack([1.0 - w1 - w2, w1, w2], -1).astype(np.float32)


def tree_gbuffer(tree, scene, vertices: np.ndarray, faces: np.ndarray) -> GBuffer:
    """The `GBuffer` of the primary hits of `tree` (a `RayTree`) rendered from `scene` (its camera,
    ambient, background and fog), whose mesh triangles are `faces` (F, 3) into `vertices` (V, 3) --
    the compiled scene's `meshes()` arrays, which the tree's face ids index.

    On the grid `tree.grid_shape` = (H * spp_side, W * spp_side) (with "stratified" sampling each
    sample's ray passes through its jittered point in its cell):
      mask      the primary ray hit a surface (root material >= 0).
      depth     (p - eye) . forward, the eye-space distance along the view axis, as the rasterizer's
                for both projections (the quantity fog is computed from); inf where empty.
      position, normal  the hit point and the shading normal (unit; exact on spheres and planes,
                interpolated vertex normals on smooth meshes), turned to face the incoming ray: the
                ray tracer's surfaces are two-sided, so it is the normal the hit was shaded with.
                0 where empty.
      material, object  ids, -1 where empty.
      face      index of the mesh triangle hit in `compiled.faces` (the mesh triangles alone), -1 on
                an analytic sphere or plane and where empty. The rasterizer's `face` indexes
                `compiled.raster(shading).faces`, whose first `n_mesh_faces` rows are these same triangles:
                on mesh hits the two agree, on spheres and planes the rasterizer gives a tessellation
                triangle (>= n_mesh_faces) where this gives -1.
      bary      (w0, w1, w2) of the hit on triangle `face` (p = sum_k w_k vertices[faces[face, k]],
                `triangle_weights` of the recorded hit point), 0 elsewhere (no triangle).
      uv        where a textured material was hit, the texture coordinates it was read at (the
                tree's `uv`); 0 elsewhere -- the ray tracer computes uv only where a texture reads it,
                the rasterizer interpolates it on every covered sample.
      texture   the texel at those samples (the tree's `texel`), 0 elsewhere.
      duv_dx, duv_dy  None: the ray tracer filters textures from its rays' footprints (a primary
                hit's sample, a secondary ray's differentials), not from screen-space uv derivatives.
      point_index (s, s, s), point_weight (1, 0, 0): every sample is its own shading point, as under
                the rasterizer's Phong shading (`shading` "phong").
    `points` (one per sample, in sample order): the root nodes' position, normal, view, material,
    cell, light_dir, light_dist, visibility (P lights), `color` their local colour (the illumination
    model's radiance there, before fog; the background where the ray hit nothing, where the
    rasterizer's points hold 0 -- compose from `mask` either way) and `texture_factor` 0 (as Phong).
    With max_depth 1 and no fog, `points.color` on the grid is the frame's sample colours."""
    root = tree.sample_offset[:-1]
    grid = tuple(tree.grid_shape)

    def on_grid(values: np.ndarray) -> np.ndarray:
        return values.reshape(*grid, *values.shape[1:])

    def at_roots(values: np.ndarray, channels: int) -> np.ndarray:  # texture arrays: empty without textures
        return values[root] if values.shape[0] else np.zeros((root.size, channels), np.float32)

    material, face, position = tree.material[root], tree.face[root], tree.position[root]
    mask = material >= 0
    eye = np.asarray(scene.camera.eye, np.float64)
    depth = np.where(mask, (position.astype(np.float64) - eye) @ camera_frame(scene.camera)[2], np.inf)
    bary = np.zeros((root.size, 3), np.float32)
    on_mesh = np.flatnonzero(face >= 0)
    corners = vertices[faces[face[on_mesh]]]  # (M, 3 corners, 3)
    bary[on_mesh] = triangle_weights(position[on_mesh], corners[:, 0], corners[:, 1], corners[:, 2])
    samples = np.arange(root.size, dtype=np.int32)
    texel = at_roots(tree.texel, 3)
    return GBuffer(
        mask=on_grid(mask), depth=on_grid(depth.astype(np.float32)), position=on_grid(position),
        normal=on_grid(tree.normal[root]), uv=on_grid(at_roots(tree.uv, 2)), material=on_grid(material),
        object=on_grid(tree.object[root]), face=on_grid(face), bary=on_grid(bary),
        point_index=on_grid(np.repeat(samples[:, None], 3, axis=1)),
        point_weight=on_grid(np.tile(np.array([1.0, 0.0, 0.0], np.float32), (root.size, 1))),
        points=ShadingPoints(
            position=position, normal=tree.normal[root], view=tree.view[root], material=material,
            cell=tree.cell[root], light_dir=tree.light_dir[root], light_dist=tree.light_dist[root],
            visibility=tree.visibility[root], color=tree.local[root],
            texture_factor=np.zeros((root.size, 3), np.float32)),
        shading="phong", specular=tree.specular, spp_side=int(tree.spp_side),
        ambient=np.asarray(scene.ambient, np.float32), background=np.asarray(scene.background, np.float32),
        clamp_vertex_colors=False, fog=fog_params(scene.fog), texture=on_grid(texel),
    )

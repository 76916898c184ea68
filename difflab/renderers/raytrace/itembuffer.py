"""The item buffer (Weghorst, Hooper and Greenberg 1984; the lecture's "speeding up ray tracing"):
primary visibility from the rasterizer's z-buffer instead of primary rays through the BVH.

The rasterizer's stages 1-3 (clip, assemble, z-buffer) run on the sample grid and leave, per sample,
the nearest face. That face names what the primary ray sees: a mesh triangle, or (for the faces that
tessellate spheres and planes) the analytic object behind them. The ray tracer then intersects its
primary ray with that one surface only -- exactly, so the hit point and normal are the ray tracer's
own. Where the hinted surface is missed (a sample on a tessellated silhouette or a shared edge), the
primary ray falls back to the full `closest_hit`; where the z-buffer is empty the ray sees the
background. The image therefore equals the ray-traced one except on silhouettes, where the
tessellation and the exact surface disagree by less than half a sample.
"""

from __future__ import annotations

import numpy as np

from ..._warp import wp
from ..camera import camera_struct
from ..raster.driver import zbuffer
from ..trace import (HIT_NONE, HIT_PLANE, HIT_SPHERE, HIT_TRIANGLE, SceneGeomW, closest_hit, no_hit, ray_plane,
                    ray_sphere, ray_triangle, surface_hit)

wp.set_module_options({"enable_backward": False})

BARY_TOLERANCE = 1.0e-5  # barycentric slack accepting a hinted triangle at a sample on its edge


@wp.struct
class ItemBufferW:
    """Per-sample primary hints: `kind` (HIT_NONE / TRIANGLE / SPHERE / PLANE) and `index` (face,
    sphere or plane index). `use` = 0 turns the item buffer off (primary rays are traced)."""

    use: int
    kind: wp.array2d(dtype=wp.int32)
    index: wp.array2d(dtype=wp.int32)
    vertices: wp.array(dtype=wp.vec3)
    faces: wp.array2d(dtype=wp.int32)


@wp.func
def hinted_hit(geom: SceneGeomW, item: ItemBufferW, i: int, j: int, origin: wp.vec3, direction: wp.vec3,
               t_max: float):
    """The primary hit of sample (i, j) from its item-buffer hint; `closest_hit` if the hint misses."""
    kind = item.kind[i, j]
    k = item.index[i, j]
    if kind == HIT_NONE:
        return no_hit(t_max)
    if kind == HIT_TRIANGLE:
        a = item.vertices[item.faces[k, 0]]
        b = item.vertices[item.faces[k, 1]]
        c = item.vertices[item.faces[k, 2]]
        t, b1, b2 = ray_triangle(origin, direction, a, b, c)
        if t > 0.0 and t < t_max and b1 >= -BARY_TOLERANCE and b2 >= -BARY_TOLERANCE \
                and b1 + b2 <= 1.0 + BARY_TOLERANCE:
            hit = surface_hit(geom, HIT_TRIANGLE, k, t, origin, direction)
            hit.normal = wp.normalize(wp.cross(b - a, c - a))
            hit.u = 1.0 - b1 - b2  # Warp's mesh_query_ray convention: p = u a + v b + (1 - u - v) c
            hit.v = b1
            return hit
    else:
        t = float(-1.0)
        if kind == HIT_SPHERE:
            t = ray_sphere(origin, direction, geom.sphere_center[k], geom.sphere_radius[k], 0.0)
        else:
            t = ray_plane(origin, direction, geom.plane_point[k], geom.plane_normal[k], 0.0)
        if t > 0.0 and t < t_max:
            return surface_hit(geom, kind, k, t, origin, direction)
    return closest_hit(geom, origin, direction, 0.0, t_max, -1)


def visible_faces(compiled, width: int, height: int, threads: int | None = None) -> np.ndarray:
    """Nearest face per sample of a width x height grid (-1: empty), from the rasterizer's
    clip / assemble / z-buffer stages (no back-face culling)."""
    tris, key = zbuffer(compiled, camera_struct(compiled.scene.camera, width, height), 0, threads)
    keys = key.numpy()
    empty = keys == np.iinfo(np.int64).max
    faces = np.full(keys.shape, -1, np.int32)
    faces[~empty] = tris.face.numpy()[keys[~empty] & 0xFFFFFFFF]  # the key's low 32 bits hold the slot
    return faces.reshape(height, width)


def item_buffer(compiled, width: int, height: int, threads: int | None = None) -> ItemBufferW:
    """The item buffer of a width x height sample grid: per sample, which surface the primary ray hits."""
    faces = visible_faces(compiled, width, height, threads)
    kind = np.full(faces.shape, HIT_NONE, np.int32)
    index = np.full(faces.shape, -1, np.int32)
    covered = faces >= 0
    mesh = covered & (faces < compiled.n_mesh_faces)
    kind[mesh], index[mesh] = HIT_TRIANGLE, faces[mesh]
    analytic = covered & ~mesh
    if analytic.any():
        objects = compiled.face_object[faces[analytic]]
        lookup_kind = np.full(len(compiled.scene.objects), HIT_NONE, np.int32)
        lookup_index = np.full(len(compiled.scene.objects), -1, np.int32)
        for hit_kind, owners in [(HIT_SPHERE, compiled.geom.sphere_object), (HIT_PLANE, compiled.geom.plane_object)]:
            owners = owners.numpy()
            lookup_kind[owners], lookup_index[owners] = hit_kind, np.arange(owners.size, dtype=np.int32)
        kind[analytic], index[analytic] = lookup_kind[objects], lookup_index[objects]
    return item_struct(compiled, kind, index)


def item_struct(compiled, kind: np.ndarray | None = None, index: np.ndarray | None = None) -> ItemBufferW:
    """An `ItemBufferW` from per-sample (kind, index) arrays; without them, a disabled one."""
    device = compiled.device
    out = ItemBufferW()
    out.use = int(kind is not None)
    if kind is None:
        kind = index = np.zeros((1, 1), np.int32)
    out.kind = wp.array(kind, dtype=wp.int32, device=device)
    out.index = wp.array(index, dtype=wp.int32, device=device)
    out.vertices = compiled.arrays["vertices"]
    out.faces = compiled.arrays["faces"]
    return out

"""The item buffer (Weghorst, Hooper and Greenberg 1984; the lecture's "speeding up ray tracing"):
primary visibility of the mesh triangles from the rasterizer's z-buffer instead of the BVH.

The rasterizer's stages 1-3 (clip, assemble, z-buffer) run over the mesh triangles only, on the
sample grid, and leave per sample the nearest triangle (its *hint*). A primary ray then finds

- the nearest sphere or plane exactly, as every ray does (`trace.analytic_hit`);
- the nearest mesh triangle before it from its hint A, intersected with the BVH's own watertight
  test (Woop, Benthin and Wald 2013: the same t, u, v bits as `mesh_query_ray`), *provided the hint
  is unambiguous*: A is hit with every barycentric at least BARY_MARGIN (so no triangle sharing
  an edge or vertex with A is), and no triangle among the hints of the four neighbouring samples
  (where a triangle that the z-buffer's snapped coverage left out at this sample shows) that does
  not share a vertex with A is `nearer`: hit at or before A, or with its plane met clearly (by
  PLANE_GAP) before A -- a nearer surface next to the sample, such as the one behind a crack the
  rasterizer leaves where a shared edge runs exactly through sample centres. An empty hint (or a
  hint behind the sphere or plane) is unambiguous when no neighbour's triangle is nearer than the
  far plane (or that sphere or plane).

An ambiguous sample asks the BVH (`trace.mesh_hit`), so the hit is the BVH's own everywhere --
except where a triangle no sample of the 3 x 3 neighbourhood sees (thinner than a sample) crosses
the sample within the rasterizer's fixed-point snapping, where a crack hides a surface less than
PLANE_GAP in front of the one it shows, or where two surfaces coincide (z-fighting, which the BVH
too resolves by rounding). The near and far planes are the ray's own (it starts on the near plane
and ends at the far one, where the rasterizer clips).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..._warp import wp
from ..camera import camera_struct
from ..raster.coverage import NO_HIT
from ..raster.driver import zbuffer
from ..trace import HitW, SceneGeomW, analytic_hit, finish_hit, mesh_hit, triangle_hit

wp.set_module_options({"enable_backward": False})

BARY_MARGIN = 1.0e-4  # a hint hit closer than this (in barycentrics) to an edge of its triangle asks the BVH
PLANE_GAP = 1.0e-3  # relative depth gap telling a neighbour's plane from the hit's (see `nearer`)
NO_TRIANGLE = wp.constant(-1)  # resolve_hint: no mesh triangle before the nearest sphere / plane (if any)
ASK_BVH = wp.constant(-2)  # resolve_hint: an ambiguous hint, the BVH finds the mesh hit
SLOT_BITS = wp.constant(wp.int64(4294967295))  # the z-buffer key's low 32 bits: the screen slot
NEIGHBOUR_DI = wp.constant(wp.vec4i(-1, 1, 0, 0))  # the four neighbouring samples: up, down, left, right
NEIGHBOUR_DJ = wp.constant(wp.vec4i(0, 0, -1, 1))


@wp.struct
class ItemBufferW:
    """The mesh triangles' z-buffer on the sample grid (`rows` x `cols`): `key` per sample (NO_HIT or
    depth << 32 | slot) and `slot_face`, the triangle of each slot; and the mesh itself. `use` = 0:
    no item buffer (every primary ray asks the BVH)."""

    use: int
    rows: int
    cols: int
    key: wp.array(dtype=wp.int64)
    slot_face: wp.array(dtype=wp.int32)
    vertices: wp.array(dtype=wp.vec3)
    faces: wp.array2d(dtype=wp.int32)
    face_normal: wp.array(dtype=wp.vec3)  # unit
    asked: wp.array(dtype=wp.int32)  # per row: the ambiguous samples, whose mesh hit came from the BVH


@wp.func_native("""
float t = 0.0f, u = 0.0f, v = 0.0f, sign = 0.0f;
if (wp::intersect_ray_tri_woop(start, dir, a, b, c, t, u, v, sign, nullptr))
    return wp::vec4(t, u, v, 1.0f);
return wp::vec4(0.0f, 0.0f, 0.0f, 0.0f);
""")
def woop_triangle(start: wp.vec3, dir: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec4:
    """`mesh_query_ray`'s triangle test (Warp's intersect_ray_tri_woop): (t, u, v, 1) on a hit, else 0."""
    ...


@wp.func
def hint(item: ItemBufferW, i: int, j: int):
    """The mesh triangle nearest at sample (i, j) in the z-buffer; -1: none, or (i, j) off the grid."""
    if i < 0 or i >= item.rows or j < 0 or j >= item.cols:
        return -1
    key = item.key[i * item.cols + j]
    if key == NO_HIT:
        return -1
    return item.slot_face[int(key & SLOT_BITS)]


@wp.func
def corner(item: ItemBufferW, face: int, k: int):
    return item.vertices[item.faces[face, k]]


@wp.func
def shares_vertex(item: ItemBufferW, face: int, other: int):
    """Whether mesh triangles `face` and `other` have a vertex in common (neighbours in the mesh)."""
    for k in range(3):
        v = item.faces[other, k]
        if v == item.faces[face, 0] or v == item.faces[face, 1] or v == item.faces[face, 2]:
            return True
    return False


@wp.func
def nearer(item: ItemBufferW, face: int, origin: wp.vec3, direction: wp.vec3, t_limit: float):
    """Whether mesh triangle `face` may be what the ray meets first, before t_limit: its plane is met
    clearly before (a nearer surface next to the sample: a crack, or an occluder's edge), or the
    triangle itself is hit at 0 <= t <= t_limit (`woop_triangle`, asked only when the plane is
    met within PLANE_GAP of t_limit)."""
    normal = item.face_normal[face]
    d_n = wp.dot(direction, normal)
    if d_n == 0.0:
        return False
    t = wp.dot(corner(item, face, 0) - origin, normal) / d_n
    if t < 0.0 or t > t_limit * (1.0 + PLANE_GAP):
        return False
    if t < t_limit * (1.0 - PLANE_GAP):
        return True
    hit = woop_triangle(origin, direction, corner(item, face, 0), corner(item, face, 1), corner(item, face, 2))
    return hit[3] > 0.0 and hit[0] <= t_limit


@wp.func
def resolve_hint(item: ItemBufferW, i: int, j: int, origin: wp.vec3, direction: wp.vec3, found: HitW):
    """The mesh part of sample (i, j)'s primary hit before `found` (its nearest sphere or plane, or a
    miss at the far plane): (triangle, NO_TRIANGLE or ASK_BVH; (t, u, v)) from its hint (module doc)."""
    face = hint(item, i, j)
    best = wp.vec4(0.0)
    t_limit = found.t  # a neighbour's triangle met before this makes the sample ambiguous
    if face >= 0:
        best = woop_triangle(origin, direction, corner(item, face, 0), corner(item, face, 1), corner(item, face, 2))
        u = best[1]
        v = best[2]
        if best[3] == 0.0 or u < BARY_MARGIN or v < BARY_MARGIN or 1.0 - u - v < BARY_MARGIN:
            return ASK_BVH, wp.vec3(0.0)
        if best[0] < found.t:  # mesh_query_ray keeps 0 <= t < max_t; woop's t is >= 0
            t_limit = best[0]
        else:
            face = NO_TRIANGLE  # the sphere or plane is in front
    tested = int(-1)  # the last neighbour's triangle tested (neighbours mostly repeat one)
    for k in range(4):
        other = hint(item, i + NEIGHBOUR_DI[k], j + NEIGHBOUR_DJ[k])
        if other >= 0 and other != face and other != tested:
            if face < 0 or not shares_vertex(item, face, other):
                if nearer(item, other, origin, direction, t_limit):
                    return ASK_BVH, wp.vec3(0.0)
            tested = other
    return face, wp.vec3(best[0], best[1], best[2])


@wp.func
def item_hit(geom: SceneGeomW, item: ItemBufferW, i: int, j: int, origin: wp.vec3, direction: wp.vec3, t_max: float):
    """`closest_hit(geom, origin, direction, 0, t_max, -1)` of sample (i, j)'s primary ray, bit for
    bit, its mesh part from the item buffer (the BVH where the sample is ambiguous, counted)."""
    found = analytic_hit(geom, origin, direction, 0.0, t_max, -1)
    face, tuv = resolve_hint(item, i, j, origin, direction, found)
    if face == ASK_BVH:
        item.asked[i] = item.asked[i] + 1
        return mesh_hit(geom, origin, direction, 0.0, found, -1)
    if face == NO_TRIANGLE:
        return finish_hit(geom, found, origin, direction)
    a = corner(item, face, 0)
    normal = wp.normalize(wp.cross(corner(item, face, 1) - a, corner(item, face, 2) - a))  # as mesh_query_ray's
    return triangle_hit(geom, face, tuv[0], tuv[1], tuv[2], normal, origin, direction)


def item_buffer(compiled, width: int, height: int, threads: int | None = None) -> ItemBufferW:
    """The item buffer of a width x height sample grid: the z-buffer of the mesh triangles (the first
    `n_mesh_faces` of the compiled scene, and their vertices), no back-face culling. It lives in the
    rasterizer's per-frame arrays of `compiled`: valid until this thread's next z-buffer of it."""
    n_faces, n_vertices = compiled.n_mesh_faces, compiled.n_mesh_vertices
    arrays = dict(compiled.arrays, faces=compiled.arrays["faces"][:n_faces],
                  vertices=compiled.arrays["vertices"][:n_vertices])
    meshes = replace(compiled, faces=compiled.faces[:n_faces], vertices=compiled.vertices[:n_vertices], arrays=arrays)
    tris, key = zbuffer(meshes, camera_struct(compiled.scene.camera, width, height), 0, threads)
    return item_struct(compiled, height, width, key, tris.face)


def asked_bvh(item: ItemBufferW) -> int:
    """How many samples' mesh hits the item buffer left to the BVH (ambiguous hints)."""
    return int(item.asked.numpy().astype(np.int64).sum()) if item.use else 0


def item_struct(compiled, rows: int = 0, cols: int = 0, key=None, slot_face=None) -> ItemBufferW:
    """An `ItemBufferW` of a z-buffer `key` and its `slot_face`; without them, a disabled one."""
    device = compiled.device
    out = ItemBufferW()
    out.use = int(key is not None)
    out.rows, out.cols = rows, cols
    if key is None:
        key = wp.empty(1, dtype=wp.int64, device=device)
        slot_face = wp.empty(1, dtype=wp.int32, device=device)
    out.key, out.slot_face = key, slot_face
    out.vertices = compiled.arrays["vertices"]
    out.faces = compiled.arrays["faces"]
    out.face_normal = compiled.arrays["face_normal"]
    out.asked = wp.zeros(max(rows, 1), dtype=wp.int32, device=device)
    return out

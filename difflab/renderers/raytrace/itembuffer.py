"""The item buffer (Weghorst, Hooper and Greenberg 1984; the lecture's "speeding up ray tracing"):
primary visibility of the mesh triangles from the rasterizer's z-buffer instead of the BVH.

The rasterizer's stages 1-3 (clip, assemble, z-buffer) run over the mesh triangles only, on the
sample grid, and leave per sample the nearest triangle (its *hint*). A primary ray then finds

- the nearest sphere or plane exactly, as every ray does (`intersect.analytic_hit`);
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

Per view, `hints_kernel` decodes the z-buffer into a grid of hints and `edge_row` flags the
samples with a neighbour's hint to check (a triangle sharing no vertex with the sample's: occluding
edges, cracks, silhouettes -- under 1 % of a smooth mesh's samples); the others skip the checks.
Like the BVH, the item buffer is kept with the compiled scene (per thread, camera and sample grid).

The z-buffer leaves back faces out (`culls_back_faces`) when the mesh triangles are the closed,
outward-facing surfaces of solids (`geometry.solid_pieces`), no piece of them passes through itself
(`selfcross.py`: a self-intersection can turn a region inside out) and they lie beyond the near
plane: a primary ray then starts outside every solid, so the first triangle it meets is one it
enters, a front face, and the back faces change no hint -- except, as without culling, on triangles
thinner than the fixed-point snapping (whose snapped winding may flip). Otherwise every triangle
is drawn.

An ambiguous sample asks the BVH (`intersect.mesh_hit`), so the hit is the BVH's own everywhere --
except where a triangle no sample of the 3 x 3 neighbourhood sees (thinner than a sample) crosses
the sample within the rasterizer's fixed-point snapping, where a crack hides a surface less than
PLANE_GAP in front of the one it shows, or where two surfaces coincide (z-fighting, which the BVH
too resolves by rounding). The near and far planes are the ray's own (it starts on the near plane
and ends at the far one, where the rasterizer clips).
"""

from __future__ import annotations

import itertools

import numpy as np

from ..._warp import wp
from ...geometry import solid_pieces
from ..camera import camera_frame, camera_struct
from ..intersect import HitW, SceneGeomW, analytic_hit, finish_hit, mesh_hit, triangle_hit, woop_triangle
from ..launch import load_kernels
from ..raster.coverage import NO_HIT
from ..raster.driver import mark_key_cleared, zbuffer
from .selfcross import passes_through_itself

wp.set_module_options({"enable_backward": False})

BARY_MARGIN = 1.0e-4  # a hint hit closer than this (in barycentrics) to an edge of its triangle asks the BVH
PLANE_GAP = 1.0e-3  # relative depth gap telling a neighbour's plane from the hit's (see `nearer`)
NO_TRIANGLE = wp.constant(-1)  # resolve_hint: no mesh triangle before the nearest sphere / plane (if any)
ASK_BVH = wp.constant(-2)  # resolve_hint: an ambiguous hint, the BVH finds the mesh hit
ITEM_BUFFER_VIEW = "item buffer of"  # scratch-pool note: ((camera, width, height), culled) of the kept item buffer
SOLID_MESHES = "solid meshes"  # compiled.built: the mesh vertices' bounding box when solids (`culls_back_faces`), else None
NEAR_MARGIN = 1.0e-4  # back faces are culled when the meshes lie this far (relative) beyond the near plane
SLOT_BITS = wp.constant(wp.int64(4294967295))  # the z-buffer key's low 32 bits: the screen slot
NEIGHBOUR_DI = wp.constant(wp.vec4i(-1, 1, 0, 0))  # the four neighbouring samples: up, down, left, right
NEIGHBOUR_DJ = wp.constant(wp.vec4i(0, 0, -1, 1))


@wp.struct
class ItemBufferW:
    """Per sample of the `rows` x `cols` grid, the mesh triangle nearest in the z-buffer (-1: none),
    in `face` with a border of -1 one sample wide (sample (i, j) at face[i + 1, j + 1]); and the mesh
    itself. `use` = 0: no item buffer (every primary ray asks the BVH)."""

    use: int
    face: wp.array2d(dtype=wp.int32)
    edge: wp.array2d(dtype=wp.uint8)  # per sample: 1 where the neighbours' hints must be checked (`edge_row`)
    vertices: wp.array(dtype=wp.vec3)
    faces: wp.array2d(dtype=wp.int32)
    face_normal: wp.array(dtype=wp.vec3)  # unit
    asked: wp.array(dtype=wp.int32)  # per row: the ambiguous samples, whose mesh hit came from the BVH


@wp.func(inline=True)
def hint(item: ItemBufferW, i: int, j: int):
    """The mesh triangle nearest at sample (i, j) in the z-buffer; -1: none, or (i, j) just off the grid."""
    return item.face[i + 1, j + 1]


@wp.func(inline=True)
def corner(item: ItemBufferW, face: int, k: int):
    return item.vertices[item.faces[face, k]]


@wp.func
def shares_vertex(corners: wp.vec3i, faces: wp.array2d(dtype=wp.int32), other: int):
    """Whether mesh triangle `other` has one of the vertices `corners` (a neighbour in the mesh)."""
    a = faces[other, 0]
    b = faces[other, 1]
    c = faces[other, 2]
    return (a == corners[0] or a == corners[1] or a == corners[2] or b == corners[0] or b == corners[1]
            or b == corners[2] or c == corners[0] or c == corners[1] or c == corners[2])


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


@wp.func(inline=True)
def resolve_hint(item: ItemBufferW, i: int, j: int, origin: wp.vec3, direction: wp.vec3, found: HitW):
    """The mesh part of sample (i, j)'s primary hit before `found` (its nearest sphere or plane, or a
    miss at the far plane): (triangle, NO_TRIANGLE or ASK_BVH; (t, u, v); the triangle's unit
    winding normal, as `mesh_query_ray` reports it) from its hint (module doc)."""
    face = hint(item, i, j)
    corners = wp.vec3i(-1, -1, -1)  # the hint's vertices (none: -1)
    best = wp.vec4(0.0)
    normal = wp.vec3(0.0)
    t_limit = found.t  # a neighbour's triangle met before this makes the sample ambiguous
    if face >= 0:
        corners = wp.vec3i(item.faces[face, 0], item.faces[face, 1], item.faces[face, 2])
        a = item.vertices[corners[0]]
        b = item.vertices[corners[1]]
        c = item.vertices[corners[2]]
        best = woop_triangle(origin, direction, a, b, c)
        u = best[1]
        v = best[2]
        if best[3] == 0.0 or u < BARY_MARGIN or v < BARY_MARGIN or 1.0 - u - v < BARY_MARGIN:
            return ASK_BVH, wp.vec3(0.0), normal
        normal = wp.normalize(wp.cross(b - a, c - a))  # as mesh_query_ray's
        if best[0] < found.t:  # mesh_query_ray keeps 0 <= t < max_t; woop's t is >= 0
            t_limit = best[0]
        else:
            face = NO_TRIANGLE  # the sphere or plane is in front: every neighbour's triangle is checked
            corners = wp.vec3i(-2, -2, -2)  # (no vertex has a negative index)
    if item.edge[i, j] == wp.uint8(0) and corners[0] != -2:
        return face, wp.vec3(best[0], best[1], best[2]), normal  # no neighbour's hint to check (`edge_row`)
    ambiguous = bool(False)
    tested = int(-1)  # the last neighbour's triangle checked (neighbours mostly repeat one)
    for k in range(4):
        other = hint(item, i + NEIGHBOUR_DI[k], j + NEIGHBOUR_DJ[k])
        if other >= 0 and other != face and other != tested:
            tested = other
            if not shares_vertex(corners, item.faces, other):
                ambiguous = ambiguous or nearer(item, other, origin, direction, t_limit)
    if ambiguous:
        return ASK_BVH, wp.vec3(0.0), normal
    return face, wp.vec3(best[0], best[1], best[2]), normal


@wp.func(inline=True)
def item_hit(geom: SceneGeomW, item: ItemBufferW, i: int, j: int, origin: wp.vec3, direction: wp.vec3, t_max: float):
    """`closest_hit(geom, origin, direction, 0, t_max, -1)` of sample (i, j)'s primary ray, bit for
    bit, its mesh part from the item buffer (the BVH where the sample is ambiguous, counted)."""
    found = analytic_hit(geom, origin, direction, 0.0, t_max, -1)
    face, tuv, normal = resolve_hint(item, i, j, origin, direction, found)
    if face == ASK_BVH:
        wp.atomic_add(item.asked, i, 1)  # (on CUDA a row's samples are traced by threads of their own)
        return mesh_hit(geom, origin, direction, 0.0, found, -1)
    if face == NO_TRIANGLE:
        return finish_hit(geom, found, origin, direction)
    return triangle_hit(geom, face, tuv[0], tuv[1], tuv[2], normal, origin, direction)


@wp.kernel
def hints_kernel(row0: int, n_faces: int, key: wp.array(dtype=wp.int64), slot_face: wp.array(dtype=wp.int32),
                 face: wp.array2d(dtype=wp.int32)):
    """Sample row row0 + tid of the bordered `face` grid (its row row0 + tid + 1, border columns
    included) from the z-buffer's keys (depth << 32 | slot, or NO_HIT), each key reset to NO_HIT once
    read (the rasterizer's next z-buffer starts cleared). Slot s < n_faces is face s itself; only
    the extra slots of faces clipped to quads (after those) look their face up."""
    i = row0 + wp.tid()
    cols = face.shape[1] - 2
    face[i + 1, 0] = -1
    face[i + 1, cols + 1] = -1
    for j in range(cols):
        f = int(-1)
        k = key[i * cols + j]
        if k != NO_HIT:
            f = int(k & SLOT_BITS)
            if f >= n_faces:
                f = slot_face[f]
            key[i * cols + j] = NO_HIT
        face[i + 1, j + 1] = f


@wp.func
def edge_row(i: int, face: wp.array2d(dtype=wp.int32), faces: wp.array2d(dtype=wp.int32),
             edge: wp.array2d(dtype=wp.uint8)):
    """Row i of `edge`: 1 where a neighbouring sample's hint is a triangle that `resolve_hint` must
    check -- one sharing no vertex with the sample's own hint (any one, for a sample with none)."""
    for j in range(edge.shape[1]):
        own = face[i + 1, j + 1]
        corners = wp.vec3i(-1, -1, -1)
        if own >= 0:
            corners = wp.vec3i(faces[own, 0], faces[own, 1], faces[own, 2])
        flag = wp.uint8(0)
        for k in range(4):
            other = face[i + 1 + NEIGHBOUR_DI[k], j + 1 + NEIGHBOUR_DJ[k]]
            if other >= 0 and other != own and not shares_vertex(corners, faces, other):
                flag = wp.uint8(1)
        edge[i, j] = flag


@wp.kernel
def edges_kernel(row0: int, face: wp.array2d(dtype=wp.int32), faces: wp.array2d(dtype=wp.int32),
                 edge: wp.array2d(dtype=wp.uint8)):
    """Row row0 + tid of `edge` (`edge_row`)."""
    edge_row(row0 + wp.tid(), face, faces, edge)


@wp.kernel
def seam_edges_kernel(rows: wp.array(dtype=wp.int32), face: wp.array2d(dtype=wp.int32),
                      faces: wp.array2d(dtype=wp.int32), edge: wp.array2d(dtype=wp.uint8)):
    """Row rows[tid] of `edge` (`edge_row`)."""
    edge_row(rows[wp.tid()], face, faces, edge)


def item_buffer(compiled, width: int, height: int, threads: int | None = None) -> tuple[ItemBufferW, bool, bool]:
    """The item buffer of a width x height sample grid: the z-buffer of the mesh triangles (the
    compiled scene's `meshes()`: a `raster()` copy's tessellation is not drawn), their back faces left out where
    `culls_back_faces` allows. Like the BVH it is kept with the compiled scene (whose geometry and
    camera are fixed), in this thread's per-frame arrays: a later render of the same sample grid
    reuses it. Returns it, whether it was kept, and whether back faces were left out.

    Each row band of the z-buffer is decoded by its own thread as soon as its keys are final (while
    they are in its cache): its hints, then the edge flags of the rows whose four neighbours are in
    the band; the first and last row of each band (a *seam*: a neighbour in the next band) are
    flagged once every band is done."""
    compiled = compiled.meshes()
    pool, view, device = compiled.scratch_pool(), (compiled.scene.camera, width, height), compiled.device
    face = compiled.scratch("item buffer", (height + 2, width + 2), wp.int32, fill=-1)  # border rows stay -1
    edge = compiled.scratch("item buffer edges", (height, width), wp.uint8)
    kept = pool.get(ITEM_BUFFER_VIEW)
    if kept is not None and kept[0] == view:
        return item_struct(compiled, face, edge), True, kept[1]
    pool.pop(ITEM_BUFFER_VIEW, None)  # until the new one is complete
    n_faces, arrays = compiled.n_mesh_faces, compiled.arrays  # the mesh triangles only (`CompiledScene.meshes`)
    load_kernels(device, hints_kernel, edges_kernel, seam_edges_kernel)
    seams = set()

    def decode_band(tris, key, begin: int, end: int) -> None:
        wp.launch(hints_kernel, dim=end - begin, inputs=[begin, n_faces, key, tris.face, face], device=device)
        if end - begin > 2:
            wp.launch(edges_kernel, dim=end - begin - 2, inputs=[begin + 1, face, arrays["faces"], edge], device=device)
        seams.update((begin, end - 1))

    cull = culls_back_faces(compiled, threads)
    unused, key = zbuffer(compiled, camera_struct(compiled.scene.camera, width, height), int(cull), threads, decode_band)
    mark_key_cleared(compiled, key)  # hints_kernel reset every key
    rows = wp.array(sorted(seams), dtype=wp.int32, device=device)
    wp.launch(seam_edges_kernel, dim=rows.shape[0], inputs=[rows, face, arrays["faces"], edge], device=device)
    pool[ITEM_BUFFER_VIEW] = (view, cull)
    return item_struct(compiled, face, edge), False, cull


def culls_back_faces(compiled, threads: int | None = None) -> bool:
    """Whether the item buffer may leave the mesh triangles' back faces out of its z-buffer: they are
    the closed surfaces of solids, facing out (`geometry.solid_pieces`), no piece passes through
    itself (`selfcross.passes_through_itself`), and their bounding box lies beyond the near plane by
    NEAR_MARGIN (relative to the coordinates' size), so every primary ray starts outside every solid
    and its first mesh hit, entering one, is a front face (module doc). The meshes are asked once
    per compiled scene; the camera's 8 box corners are tested on each call (nothing kept per camera)."""
    if SOLID_MESHES not in compiled.built:
        vertices = compiled.vertices
        pieces = solid_pieces(vertices, compiled.faces)
        solid = pieces is not None and not passes_through_itself(bvh(compiled), *pieces, threads=threads)
        compiled.built[SOLID_MESHES] = (vertices.min(axis=0), vertices.max(axis=0)) if solid else None
    box = compiled.built[SOLID_MESHES]
    if box is None:
        return False
    camera = compiled.scene.camera
    corners = np.array(list(itertools.product(*zip(*box))), np.float64)
    eye = np.asarray(camera.eye, np.float64)
    size = camera.near + np.abs(corners).max() + np.abs(eye).max()
    return bool(((corners - eye) @ camera_frame(camera)[2]).min() > camera.near + NEAR_MARGIN * size)


def bvh(compiled) -> wp.Mesh:
    """The compiled scene's BVH over its mesh triangles (built now if no ray has needed it yet)."""
    compiled.traceable()
    return compiled.built["bvh"]


def forget_item_buffer(compiled) -> None:
    """Drop this thread's kept item buffer of `compiled`: the next render makes it again."""
    compiled.scratch_pool().pop(ITEM_BUFFER_VIEW, None)


def asked_bvh(item: ItemBufferW) -> int:
    """How many samples' mesh hits the item buffer left to the BVH (ambiguous hints)."""
    return int(item.asked.numpy().astype(np.int64).sum()) if item.use else 0


def item_struct(compiled, face=None, edge=None) -> ItemBufferW:
    """An `ItemBufferW` of a bordered `face` grid and its `edge` flags; without them, a disabled one."""
    device = compiled.device
    out = ItemBufferW()
    out.use = int(face is not None)
    out.face = face if face is not None else wp.empty((1, 1), dtype=wp.int32, device=device)
    out.edge = edge if edge is not None else wp.empty((1, 1), dtype=wp.uint8, device=device)
    out.vertices = compiled.arrays["vertices"]
    out.faces = compiled.arrays["faces"]
    out.face_normal = compiled.arrays["face_normal"]
    out.asked = wp.zeros(max(out.face.shape[0] - 2, 1), dtype=wp.int32, device=device)
    return out

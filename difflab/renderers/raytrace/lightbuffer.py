"""The light buffer (Haines and Greenberg, 1986): shadow rays that test only candidate occluders.

Around every point or spot light sits a cube of directions, each face cut into R x R cells. A cell
lists every surface that can be seen from the light through it -- the only surfaces a shadow ray
from a point in that direction can hit on its way to the light -- sorted by a lower bound of their
distance to the light ("z-ordered"). A shadow ray from p looks up the cell of p - L, tests the list
in order, and stops at the first opaque hit, or at the first candidate that starts farther from the
light than p. Directional lights keep the ordinary BVH query.

Cells: d = p - L, a = the axis of d's largest |component|, s = its sign; face = 2 a + (s < 0); with
(b, c) the other two axes in increasing order, u = d_b / |d_a| and v = d_c / |d_a| in [-1, 1];
column = floor((u + 1) R / 2), row = floor((v + 1) R / 2), both clamped to [0, R - 1].

A triangle (or a sphere's bounding box) entirely on the face's side of the light projects to a
convex region whose bounding box of cells is a conservative candidate set; one that straddles the
plane through the light is listed in every cell of that face; planes are listed everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._warp import wp

from ...lighting.warp_model import MaterialW
from ..trace import HIT_PLANE, HIT_SPHERE, HIT_TRIANGLE, MAX_SHADOW_CROSSINGS, SceneGeomW, ray_plane, ray_triangle

wp.set_module_options({"enable_backward": False})

DEFAULT_RESOLUTION = 32  # cells per cube-face edge for ~10^4 triangles (see `auto_resolution`)


@wp.struct
class LightBufferW:
    """The candidate lists of every light, as kernels see them. `light_cell0[q]` is light q's first
    cell (-1: no buffer, use the BVH); cell k's candidates are entries cell_start[k] .. cell_start[k+1]."""

    use: int
    resolution: int
    light_cell0: wp.array(dtype=wp.int32)
    cell_start: wp.array(dtype=wp.int32)
    kind: wp.array(dtype=wp.int32)  # trace.HIT_TRIANGLE / HIT_SPHERE / HIT_PLANE
    index: wp.array(dtype=wp.int32)
    near: wp.array(dtype=float)  # lower bound of the candidate's distance to the light
    tests: wp.array(dtype=wp.int64)  # (1,): candidates tested by every shadow ray together


@wp.func
def cube_cell(d: wp.vec3, resolution: int):
    """The cell of direction d (see the module docstring)."""
    ax = wp.abs(d[0])
    ay = wp.abs(d[1])
    az = wp.abs(d[2])
    a = int(0)
    major = ax
    b = float(d[1])
    c = float(d[2])
    if ay > major:
        a = 1
        major = ay
        b = d[0]
        c = d[2]
    if az > major:
        a = 2
        major = az
        b = d[0]
        c = d[1]
    face = 2 * a
    if d[a] < 0.0:
        face = face + 1
    r = float(resolution)
    col = wp.clamp(int(wp.floor((b / major + 1.0) * 0.5 * r)), 0, resolution - 1)
    row = wp.clamp(int(wp.floor((c / major + 1.0) * 0.5 * r)), 0, resolution - 1)
    return (face * resolution + row) * resolution + col


@wp.func
def crossings_of(geom: SceneGeomW, vertices: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=wp.int32), kind: int,
                 index: int, origin: wp.vec3, l: wp.vec3, distance: float):
    """How many times the segment origin + t l, 0 < t < distance, crosses candidate (kind, index)."""
    if kind == HIT_TRIANGLE:
        t, b1, b2 = ray_triangle(origin, l, vertices[faces[index, 0]], vertices[faces[index, 1]],
                                 vertices[faces[index, 2]])
        if t > 0.0 and t < distance and b1 >= 0.0 and b2 >= 0.0 and b1 + b2 <= 1.0:
            return 1
        return 0
    if kind == HIT_SPHERE:
        oc = geom.sphere_center[index] - origin
        h = wp.dot(l, oc)
        closest = oc - h * l
        radius = geom.sphere_radius[index]
        disc = radius * radius - wp.dot(closest, closest)
        if disc < 0.0:
            return 0
        s = wp.sqrt(disc)
        count = int(0)
        if h - s > 0.0 and h - s < distance:
            count = count + 1
        if h + s > 0.0 and h + s < distance:
            count = count + 1
        return count
    t = ray_plane(origin, l, geom.plane_point[index], geom.plane_normal[index], 0.0)
    if t > 0.0 and t < distance:
        return 1
    return 0


@wp.func
def candidate_object(geom: SceneGeomW, kind: int, index: int):
    if kind == HIT_TRIANGLE:
        return geom.face_object[index]
    if kind == HIT_SPHERE:
        return geom.sphere_object[index]
    return geom.plane_object[index]


@wp.func
def candidate_material(geom: SceneGeomW, kind: int, index: int):
    if kind == HIT_TRIANGLE:
        return geom.face_material[index]
    if kind == HIT_SPHERE:
        return geom.sphere_material[index]
    return geom.plane_material[index]


@wp.func
def buffered_visibility(geom: SceneGeomW, lb: LightBufferW, vertices: wp.array(dtype=wp.vec3),
                        faces: wp.array2d(dtype=wp.int32), materials: wp.array(dtype=MaterialW), q: int,
                        light_p: wp.vec3, p: wp.vec3, l: wp.vec3, distance: float, ignore_object: int,
                        transparent: int):
    """`trace.shadow_ray` through light q's buffer, (visibility, cut): 0 at the first opaque candidate
    crossed, else the product of kt over transparent crossings -- (0, 1) past MAX_SHADOW_CROSSINGS of
    them with no opaque candidate crossed (a ray that would otherwise reach the light), as there."""
    cell = lb.light_cell0[q] + cube_cell(p - light_p, lb.resolution)
    reach = wp.length(p - light_p)
    visibility = float(1.0)
    crossed = int(0)
    tested = int(0)
    for e in range(lb.cell_start[cell], lb.cell_start[cell + 1]):
        if lb.near[e] >= reach:
            break  # z-ordered: this candidate and every later one lie beyond p
        kind = lb.kind[e]
        index = lb.index[e]
        if candidate_object(geom, kind, index) != ignore_object:
            tested = tested + 1
            n = crossings_of(geom, vertices, faces, kind, index, p, l, distance)
            if n > 0:
                kt = materials[candidate_material(geom, kind, index)].kt
                if transparent == 0 or kt <= 0.0:
                    crossed = 0
                    visibility = 0.0
                    break
                for _ in range(n):
                    visibility = visibility * kt
                crossed = crossed + n
    wp.atomic_add(lb.tests, 0, wp.int64(tested))
    if crossed > MAX_SHADOW_CROSSINGS:
        return 0.0, 1
    return visibility, 0


# ----------------------------------------------------------------------------- building (numpy)

@dataclass
class LightBuffer:
    """The host side of a light buffer: `warp` for kernels, and per light the candidate count of every
    cell (`counts[q]`: (6, R, R), None for a directional light) for figures and statistics."""

    warp: LightBufferW
    counts: list
    entries: int


def cell_ranges(points: np.ndarray, light: np.ndarray, axis: int, sign: float, resolution: int):
    """For K-point convex sets (N, K, 3): per set its (row0, row1, col0, col1) cell box on cube face
    (axis, sign), and whether it appears on that face at all."""
    b, c = [k for k in range(3) if k != axis]
    rel = points - light
    depth = sign * rel[..., axis]
    ahead, behind = (depth > 1e-12).all(axis=1), (depth <= 1e-12).all(axis=1)
    safe = np.where(depth > 1e-12, depth, 1.0)
    u, v = rel[..., b] / safe, rel[..., c] / safe
    lo_u, hi_u, lo_v, hi_v = u.min(1), u.max(1), v.min(1), v.max(1)
    seen = ~behind & (~ahead | ((hi_u >= -1) & (lo_u <= 1) & (hi_v >= -1) & (lo_v <= 1)))
    full = ~ahead  # straddles the plane through the light: the whole face
    cell = lambda x: np.clip(np.floor((x + 1.0) * 0.5 * resolution), 0, resolution - 1).astype(np.int64)  # noqa: E731
    col0, col1 = np.where(full, 0, cell(lo_u)), np.where(full, resolution - 1, cell(hi_u))
    row0, row1 = np.where(full, 0, cell(lo_v)), np.where(full, resolution - 1, cell(hi_v))
    return row0, row1, col0, col1, seen


def expand(ids, row0, row1, col0, col1, face, resolution):
    """(primitive id, cell) pairs of every cell in each primitive's box."""
    widths, heights = col1 - col0 + 1, row1 - row0 + 1
    counts = widths * heights
    owner = np.repeat(np.arange(len(ids)), counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    rows = row0[owner] + k // widths[owner]
    cols = col0[owner] + k % widths[owner]
    return ids[owner], (face * resolution + rows) * resolution + cols


def light_entries(light: np.ndarray, prims: list, resolution: int):
    """(kind, index, near, cell) arrays of one light's buffer. `prims`: (kind, points (N, K, 3),
    near (N,), everywhere) per primitive kind."""
    kinds, indices, nears, cells = [], [], [], []
    for kind, points, near, everywhere in prims:
        if not len(near):
            continue
        ids = np.arange(len(near))
        for axis in range(3):
            for s, sign in enumerate((1.0, -1.0)):
                face = 2 * axis + s
                if everywhere:
                    full = np.zeros(len(ids), np.int64)
                    owner, cell = expand(ids, full, full + resolution - 1, full, full + resolution - 1, face, resolution)
                else:
                    row0, row1, col0, col1, seen = cell_ranges(points, light, axis, sign, resolution)
                    owner, cell = expand(ids[seen], row0[seen], row1[seen], col0[seen], col1[seen], face, resolution)
                kinds.append(np.full(len(owner), kind))
                indices.append(owner)
                nears.append(near[owner])
                cells.append(cell)
    return [np.concatenate(x) if x else np.zeros(0) for x in (kinds, indices, nears, cells)]


def scene_primitives(compiled) -> list:
    """Every ray-traced surface as (kind, convex point set, lower bound of distance function, everywhere)."""
    geom = compiled.geom
    triangles = compiled.vertices[compiled.faces]
    centres = geom.sphere_center.numpy().astype(np.float64)
    radii = geom.sphere_radius.numpy().astype(np.float64)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    boxes = centres[:, None, :] + radii[:, None, None] * corners[None]
    return [(HIT_TRIANGLE, triangles, None, False), (HIT_SPHERE, boxes, (centres, radii), False),
            (HIT_PLANE, None, (geom.plane_point.numpy(), geom.plane_normal.numpy()), True)]


def near_bounds(kind, points, extra, light):
    """A lower bound of each primitive's distance to the light."""
    if kind == HIT_TRIANGLE:
        centroid = points.mean(axis=1)
        radius = np.linalg.norm(points - centroid[:, None], axis=-1).max(axis=1)
        return np.maximum(np.linalg.norm(centroid - light, axis=1) - radius, 0.0)
    if kind == HIT_SPHERE:
        centres, radii = extra
        return np.maximum(np.linalg.norm(centres - light, axis=1) - radii, 0.0)
    point, normal = extra
    return np.abs(((light - point) * normal).sum(axis=1))


def auto_resolution(triangles: int) -> int:
    """Cells per cube-face edge growing as sqrt(triangles) (the power of 2 nearest to 32 at 10^4
    triangles, clamped to 16 .. 256), so that a cell lists about as many candidates at any mesh size.
    Measured on the lecture scene (experiments/bench/speedups.py): at ~10^5 triangles a 32-cell cube
    left 179 candidates per shadow ray, a 128-cell one 16."""
    return int(np.clip(2 ** round(np.log2(DEFAULT_RESOLUTION * np.sqrt(max(triangles, 1) / 1e4))), 16, 256))


def build_light_buffer(compiled, resolution: int | None = None) -> LightBuffer:
    """The light buffer of a compiled scene: candidates of every point and spot light, z-ordered,
    on cubes of `resolution` cells per face edge (None: `auto_resolution` of the mesh size); of
    the mesh triangles alone (`meshes()`) and the exact spheres and planes."""
    compiled = compiled.meshes()
    scene, device = compiled.scene, compiled.device
    resolution = auto_resolution(compiled.n_mesh_faces) if resolution is None else int(resolution)
    cells_per_light = 6 * resolution * resolution
    cell0, counts, per_cells, kinds, indices, nears = [], [], [], [], [], []
    base = 0
    prims = scene_primitives(compiled)
    for light in scene.lights:
        if light.type == "directional":
            cell0.append(-1)
            counts.append(None)
            continue
        position = np.asarray(light.position, float)
        per_kind = [(kind, points, near_bounds(kind, points, extra, position), everywhere)
                    for kind, points, extra, everywhere in prims]
        kind, index, near, cell = light_entries(position, per_kind, resolution)
        order = np.lexsort((near, cell))
        per_cell = np.bincount(cell.astype(np.int64), minlength=cells_per_light)
        cell0.append(base)
        base += cells_per_light
        counts.append(per_cell.reshape(6, resolution, resolution))
        per_cells.append(per_cell)
        kinds.append(kind[order])
        indices.append(index[order])
        nears.append(near[order])
    offsets = np.concatenate([[0], np.cumsum(np.concatenate(per_cells))]).astype(np.int32) if per_cells else \
        np.zeros(2, np.int32)
    cat = lambda xs, dtype: np.concatenate(xs).astype(dtype) if xs else np.zeros(1, dtype)  # noqa: E731
    out = LightBufferW()
    out.use = 1
    out.resolution = int(resolution)
    out.light_cell0 = wp.array(np.asarray(cell0, np.int32).reshape(-1) if cell0 else np.full(1, -1, np.int32),
                               dtype=wp.int32, device=device)
    out.cell_start = wp.array(offsets, dtype=wp.int32, device=device)
    out.kind = wp.array(cat(kinds, np.int32), dtype=wp.int32, device=device)
    out.index = wp.array(cat(indices, np.int32), dtype=wp.int32, device=device)
    out.near = wp.array(cat(nears, np.float32), dtype=float, device=device)
    out.tests = wp.zeros(1, dtype=wp.int64, device=device)
    return LightBuffer(warp=out, counts=counts, entries=int(sum(len(k) for k in kinds)))


def no_light_buffer(compiled) -> LightBufferW:
    """A switched-off buffer (kernels take the BVH path)."""
    out = LightBufferW()
    out.use = 0
    out.resolution = 1
    device = compiled.device
    out.light_cell0 = wp.full(1, -1, dtype=wp.int32, device=device)
    out.cell_start = wp.zeros(2, dtype=wp.int32, device=device)
    out.kind = wp.zeros(1, dtype=wp.int32, device=device)
    out.index = wp.zeros(1, dtype=wp.int32, device=device)
    out.near = wp.zeros(1, dtype=float, device=device)
    out.tests = wp.zeros(1, dtype=wp.int64, device=device)
    return out

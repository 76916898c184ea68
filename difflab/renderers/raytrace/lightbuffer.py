"""The light buffer (Haines and Greenberg, 1986): shadow rays that test only candidate occluders.

Around every point or spot light sits a cube of directions, each face cut into R x R cells. A cell
lists every surface that can be seen from the light through it -- the only surfaces a shadow ray
from a point in that direction can hit on its way to the light -- sorted by a lower bound of their
distance to the light ("z-ordered"). A shadow ray from p looks up the cell of p - L and finds the
nearest surface among its candidates (stopping at the first that starts farther from the light than
p) with the BVH path's own tests and choice (`buffered_hit`: the BVH's watertight `woop_triangle`,
not another triangle test, so that a ray grazing an edge is blocked or not alike), and walks on past
transparent ones as `trace.shadow_ray` does (`trace.shadow_step`): the visibility is the BVH's, bit
for bit. Directional lights keep the ordinary BVH query.

Cells: d = p - L, a = the axis of d's largest |component|, s = its sign; face = 2 a + (s < 0); with
(b, c) the other two axes in increasing order, u = d_b / |d_a| and v = d_c / |d_a| in [-1, 1];
column = floor((u + 1) R / 2), row = floor((v + 1) R / 2), both clamped to [0, R - 1].

The lists are conservative for float32 rays: a shadow ray's line passes the light only within a few
ulps (its offset origin, its rounded direction), its cell is looked up and its triangles tested in
float32. So every surface is listed as if grown by DILATION x the light's scale (the largest
coordinate of the light and of `objects_scale`) (2^-12: ~2000 ulps, under 1e-3 of a cell at R =
256) on every side: a triangle (or a sphere's bounding box) whose grown set lies on the face's side of the light projects within its corners' cell box widened
accordingly (`cell_ranges`); one that reaches the plane through the light is listed in every cell
of that face; planes are listed everywhere; the distance bounds are lowered by sqrt(3) x the growth.
A ray whose line passes the light farther than a quarter of that growth, less TRUST_ULPS of its
rounding (`follows_cell`: an origin far out on a plane, a transparent walk stepped off its line at
a grazing crossing) asks the BVH instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._warp import wp

from ...lighting.warp_model import MaterialW
from ..intersect import HIT_PLANE, HIT_SPHERE, HIT_TRIANGLE, SceneGeomW, closest_hit, finish_hit, no_hit, ray_plane, \
    ray_sphere, triangle_hit, woop_triangle
from ..trace import MAX_SHADOW_CROSSINGS, SHADOW_CUT, SHADOW_GOES_ON, max_abs, shadow_step

wp.set_module_options({"enable_backward": False})

DEFAULT_RESOLUTION = 32  # cells per cube-face edge for ~10^4 triangles (see `auto_resolution`)
DILATION = 2.0 ** -12  # candidates are listed for their surface grown by this x the light's scale (module doc)
TRUST_ULPS = 64.0  # float32 ulps of |origin| + scale a ray's tests may be off by (`follows_cell`)


@wp.struct
class LightBufferW:
    """The candidate lists of every light, as kernels see them. `light_cell0[q]` is light q's first
    cell (-1: no buffer, use the BVH); cell k's candidates are entries cell_start[k] .. cell_start[k+1]."""

    use: int
    resolution: int
    opaque: int  # 1: no surface of the scene has kt > 0 (a shadow ray stops at its first blocker)
    light_cell0: wp.array(dtype=wp.int32)
    cell_start: wp.array(dtype=wp.int32)
    kind: wp.array(dtype=wp.int32)  # intersect.HIT_TRIANGLE / HIT_SPHERE / HIT_PLANE
    index: wp.array(dtype=wp.int32)
    near: wp.array(dtype=float)  # lower bound of the candidate's grown surface's distance to the light
    scale: wp.array(dtype=float)  # per light: max(|light|, `objects_scale`), what its lists' DILATION is a fraction of


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
def follows_cell(lb: LightBufferW, q: int, light_p: wp.vec3, origin: wp.vec3, l: wp.vec3):
    """Whether the shadow ray from `origin` along unit `l` keeps to the cell of `origin`: its line passes
    the light closer than the lists' dilation allows, with room for the float32 rounding of this
    test, of the cell's look-up and of the triangle test (module doc)."""
    w = light_p - origin
    off_line = wp.length(w - wp.dot(w, l) * l)
    rounding = TRUST_ULPS * 1.1920928955078125e-07 * (max_abs(origin) + lb.scale[q])
    return off_line + rounding <= 0.25 * DILATION * lb.scale[q]


@wp.func
def buffered_hit(geom: SceneGeomW, lb: LightBufferW, vertices: wp.array(dtype=wp.vec3),
                 faces: wp.array2d(dtype=wp.int32), q: int, light_p: wp.vec3, origin: wp.vec3, l: wp.vec3, t_max: float,
                 ignore_object: int, first: int):
    """`intersect.closest_hit(geom, origin, l, 0, t_max, ignore_object)` among the candidates of origin's
    cell of light q: the same tests (`ray_sphere`, `ray_plane`, the BVH's `woop_triangle` with its
    0 <= t < t_max), the same choice (the nearest sphere or plane, a sphere before a plane and the
    lower index at equal t; a triangle only when strictly nearer) -- the same hit, as long as
    `follows_cell` -- and how many candidates it tested. Stops at the first candidate lying beyond
    origin (z-order); with `first` set, at the first candidate hit (a shadow ray that no surface lets
    through -- transparent shadows off, or no kt > 0 in the scene -- needs only to know that
    something is: a hit that is not the nearest, but a hit whenever the BVH finds one;
    `trace.leaving_skip` never skips a mesh, so no triangle is skipped)."""
    cell = lb.light_cell0[q] + cube_cell(origin - light_p, lb.resolution)
    reach = wp.length(origin - light_p)
    hit = no_hit(t_max)
    face = int(-1)
    found = wp.vec4(0.0)
    nearest = t_max  # the nearest triangle's t
    tested = int(0)
    for e in range(lb.cell_start[cell], lb.cell_start[cell + 1]):
        if lb.near[e] >= reach:
            break  # z-ordered: this candidate and every later one lie beyond origin
        k = lb.index[e]
        if lb.kind[e] == HIT_TRIANGLE:
            tested = tested + 1
            tri = woop_triangle(origin, l, vertices[faces[k, 0]], vertices[faces[k, 1]], vertices[faces[k, 2]])
            if tri[3] > 0.0 and (tri[0] < nearest or (tri[0] == nearest and face >= 0 and k < face)):
                nearest = tri[0]
                face = k
                found = tri
                if first == 1:
                    break
        elif lb.kind[e] == HIT_SPHERE:
            if geom.sphere_object[k] != ignore_object:
                tested = tested + 1
                t = ray_sphere(origin, l, geom.sphere_center[k], geom.sphere_radius[k], 0.0)
                if t > 0.0 and (t < hit.t or (t == hit.t and (hit.kind == HIT_PLANE or (hit.kind == HIT_SPHERE
                                                                                         and k < hit.index)))):
                    hit.t = t
                    hit.kind = HIT_SPHERE
                    hit.index = k
                    if first == 1:
                        break
        elif geom.plane_object[k] != ignore_object:
            tested = tested + 1
            t = ray_plane(origin, l, geom.plane_point[k], geom.plane_normal[k], 0.0)
            if t > 0.0 and (t < hit.t or (t == hit.t and hit.kind == HIT_PLANE and k < hit.index)):
                hit.t = t
                hit.kind = HIT_PLANE
                hit.index = k
                if first == 1:
                    break
    if face >= 0 and found[0] < hit.t and geom.face_object[face] != ignore_object:
        a = vertices[faces[face, 0]]
        normal = wp.cross(vertices[faces[face, 1]] - a, vertices[faces[face, 2]] - a)  # as mesh_query_ray's
        return triangle_hit(geom, face, found[0], found[1], found[2], wp.normalize(normal), origin, l), tested
    return finish_hit(geom, hit, origin, l), tested


@wp.func
def buffered_visibility(geom: SceneGeomW, lb: LightBufferW, vertices: wp.array(dtype=wp.vec3),
                        faces: wp.array2d(dtype=wp.int32), materials: wp.array(dtype=MaterialW), q: int,
                        light_p: wp.vec3, p: wp.vec3, l: wp.vec3, distance: float, ignore_object: int,
                        transparent: int):
    """`trace.shadow_ray` with light q's buffer, (visibility, cut, candidates tested): the same walk
    (`shadow_step`), each surface found among its cell's candidates (`buffered_hit`) while the ray
    `follows_cell`, else through the BVH -- the same surfaces, hence the same visibility, bit for bit."""
    first = int(0)  # no surface lets light through: the first blocker found will do
    if transparent == 0 or lb.opaque == 1:
        first = 1
    visibility = float(1.0)
    origin = p
    remaining = distance
    tested = int(0)
    for crossing in range(MAX_SHADOW_CROSSINGS + 1):
        hit = no_hit(remaining)
        if follows_cell(lb, q, light_p, origin, l):
            hit, n = buffered_hit(geom, lb, vertices, faces, q, light_p, origin, l, remaining, ignore_object, first)
            tested = tested + n
        else:
            hit = closest_hit(geom, origin, l, 0.0, remaining, ignore_object)
        verdict, visibility, origin, remaining = shadow_step(geom, materials, hit, crossing, transparent, visibility,
                                                             origin, l, remaining, ignore_object)
        if verdict != SHADOW_GOES_ON:
            return visibility, int(verdict == SHADOW_CUT), tested
    return 0.0, 1, tested  # (not reached: the last pass returns)


# ----------------------------------------------------------------------------- building (numpy)

@dataclass
class LightBuffer:
    """The host side of a light buffer: `warp` for kernels, and per light the candidate count of every
    cell (`counts[q]`: (6, R, R), None for a directional light) for figures and statistics."""

    warp: LightBufferW
    counts: list
    entries: int


def cell_ranges(points: np.ndarray, light: np.ndarray, axis: int, sign: float, resolution: int, grow: float):
    """For K-point convex sets (N, K, 3), each grown by `grow` along every axis (Minkowski sum with a
    cube): per set its (row0, row1, col0, col1) cell box on cube face (axis, sign), and whether it
    appears on that face at all. A grown set whose depth d along the face's axis stays > 0 projects
    within the box of its points' (u, v) widened by grow (1 + max |u|) / (min d - grow) (and so for
    v): a shift e (|e_i| <= grow) moves u = x_b / x_a by (e_b - u e_a) / (x_a + e_a)."""
    b, c = [k for k in range(3) if k != axis]
    rel = points - light
    depth = sign * rel[..., axis]
    near_depth = depth.min(axis=1) - grow
    ahead, behind = near_depth > 1e-12, depth.max(axis=1) + grow <= 0.0
    safe = np.where(depth > 1e-12, depth, 1.0)
    u, v = rel[..., b] / safe, rel[..., c] / safe
    wide = grow / np.where(ahead, near_depth, 1.0)
    margin_u, margin_v = wide * (1.0 + np.abs(u).max(1)), wide * (1.0 + np.abs(v).max(1))
    lo_u, hi_u, lo_v, hi_v = u.min(1) - margin_u, u.max(1) + margin_u, v.min(1) - margin_v, v.max(1) + margin_v
    seen = ~behind & (~ahead | ((hi_u >= -1) & (lo_u <= 1) & (hi_v >= -1) & (lo_v <= 1)))
    full = ~ahead  # reaches the plane through the light: the whole face
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


def light_entries(light: np.ndarray, prims: list, resolution: int, grow: float):
    """(kind, index, near, cell) arrays of one light's buffer, its surfaces grown by `grow`. `prims`:
    (kind, points (N, K, 3), near (N,), everywhere) per primitive kind."""
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
                    row0, row1, col0, col1, seen = cell_ranges(points, light, axis, sign, resolution, grow)
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


def objects_scale(prims: list) -> float:
    """The largest |coordinate| of every mesh vertex and sphere's box; with a light's own, what the
    float32 rounding of a shadow ray's origin and direction, and of its tests, is a few ulps of."""
    return float(max([np.abs(points).max(initial=0.0) for _, points, _, everywhere in prims if not everywhere],
                     default=0.0))


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
    cell0, scales, counts, per_cells, kinds, indices, nears = [], [], [], [], [], [], []
    base = 0
    prims = scene_primitives(compiled)
    objects = objects_scale(prims)  # (the scan over every primitive, once for all the lights)
    for light in scene.lights:
        if light.type == "directional":
            cell0.append(-1)
            scales.append(0.0)
            counts.append(None)
            continue
        position = np.asarray(light.position, np.float32).astype(float)  # where the kernels see it
        scale = max(float(np.abs(position).max()), objects)
        grow = DILATION * scale
        per_kind = [(kind, points, np.maximum(near_bounds(kind, points, extra, position) - np.sqrt(3.0) * grow, 0.0),
                     everywhere) for kind, points, extra, everywhere in prims]
        kind, index, near, cell = light_entries(position, per_kind, resolution, grow)
        order = np.lexsort((near, cell))
        per_cell = np.bincount(cell.astype(np.int64), minlength=cells_per_light)
        cell0.append(base)
        scales.append(scale)
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
    out.opaque = int(all(material.kt <= 0 for material in scene.materials.values()))
    out.light_cell0 = wp.array(np.asarray(cell0, np.int32).reshape(-1) if cell0 else np.full(1, -1, np.int32),
                               dtype=wp.int32, device=device)
    out.cell_start = wp.array(offsets, dtype=wp.int32, device=device)
    out.kind = wp.array(cat(kinds, np.int32), dtype=wp.int32, device=device)
    out.index = wp.array(cat(indices, np.int32), dtype=wp.int32, device=device)
    out.near = wp.array(cat(nears, np.float32), dtype=float, device=device)
    out.scale = wp.array(np.asarray(scales, np.float32).reshape(-1) if scales else np.zeros(1, np.float32),
                         dtype=float, device=device)
    return LightBuffer(warp=out, counts=counts, entries=int(sum(len(k) for k in kinds)))


def no_light_buffer(compiled) -> LightBufferW:
    """A switched-off buffer (kernels take the BVH path)."""
    out = LightBufferW()
    out.use = 0
    out.resolution = 1
    out.opaque = 1
    device = compiled.device
    out.light_cell0 = wp.full(1, -1, dtype=wp.int32, device=device)
    out.cell_start = wp.zeros(2, dtype=wp.int32, device=device)
    out.kind = wp.zeros(1, dtype=wp.int32, device=device)
    out.index = wp.zeros(1, dtype=wp.int32, device=device)
    out.near = wp.zeros(1, dtype=float, device=device)
    out.scale = wp.zeros(1, dtype=float, device=device)
    return out

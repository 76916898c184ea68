"""The rasterizer: vertices -> clip space -> near-plane clipping -> z-buffer -> shading points -> image.

Stages (each a kernel; per-pixel ones are launched in row bands on all cores):
1. `clip_vertices_kernel`  world -> clip space.
2. `assemble_kernel`       clip each triangle against the near plane (z_clip >= -w_clip) into at most
                           two triangles, divide by w, map to raster space, snap to 1/256 sample
                           (fixed point), drop degenerate ones, cull back faces on request.
3. `raster_kernel`         for every sample centre inside a triangle (exact integer edge functions with
                           a top-left-style fill rule: a shared edge's samples go to exactly one
                           triangle) write min(depth, triangle) into a 64-bit visibility key: the
                           z-buffer test and a deterministic tie-break in one atomic.
4. `resolve_kernel`        per sample: barycentrics of the winning triangle, perspective-correct
                           (b_k / w_k renormalised) or affine, the original triangle's weights, and the
                           surface there (position, normal, uv, material, depth) — the G-buffer.
5. shading points          phong: every covered sample; flat: every face (lit at its centroid with the
                           face normal); gouraud: every vertex, twice (front and back normal, OpenGL's
                           two-sided lighting).
6. `light_points_kernel`   per point and light: direction, distance, shadow-ray visibility, and the
                           colour from the one illumination model.
7. `compose_kernel`        per sample: the weighted colours of its points (gouraud: the vertex colours
                           interpolated, optionally clamped to [0, 1] first), background, fog.
"""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import (LightW, MaterialW, ambient_term, checker_cell, fog_factor, light_term, light_vector,
                                   surface_material, target_only, textured_material)
from ..camera import CameraW, view_direction
from ..texture.sampling import TexturesW, sample_texture
from ..trace import SceneGeomW, light_visibility

wp.set_module_options({"enable_backward": False})

SUBPIXEL = 256  # fixed-point steps per sample
GUARD = 4194304.0  # |raster coordinate| clamp (samples) keeping int64 edge products exact
DEPTH_LEVELS = 2147483647.0  # depth quantisation of the visibility key (31 bits)
NO_HIT = wp.constant(wp.int64(9223372036854775807))
FLAT, GOURAUD, PHONG_SHADING = 0, 1, 2
SHADING_MODELS = {"flat": FLAT, "gouraud": GOURAUD, "phong": PHONG_SHADING}


@wp.struct
class PointsW:
    """Shading points: where the illumination model is evaluated."""

    position: wp.array(dtype=wp.vec3)
    normal: wp.array(dtype=wp.vec3)  # unit shading normal, facing the viewer
    geo_normal: wp.array(dtype=wp.vec3)  # unit geometric normal, facing the viewer
    view: wp.array(dtype=wp.vec3)  # unit direction to the viewer
    material: wp.array(dtype=wp.int32)  # -1: nothing here
    cell: wp.array(dtype=wp.int32)  # checker cell 0 / 1
    ignore: wp.array(dtype=wp.int32)  # object shadow rays skip (convex analytic surfaces), else -1
    uv: wp.array(dtype=wp.vec2)  # texture coordinates (samples only; zero at flat / Gouraud points)
    duv_dx: wp.array(dtype=wp.vec2)  # d(uv)/dx, d(uv)/dy per sample of the sample grid (samples only)
    duv_dy: wp.array(dtype=wp.vec2)


@wp.kernel
def clip_vertices_kernel(begin: int, vertices: wp.array(dtype=wp.vec3), view_proj: wp.mat44,
                         clip: wp.array(dtype=wp.vec4)):
    k = begin + wp.tid()
    p = vertices[k]
    clip[k] = view_proj * wp.vec4(p[0], p[1], p[2], 1.0)


@wp.func
def near_crossing(ia: int, ib: int, ca: wp.vec4, cb: wp.vec4, wa: wp.vec3, wb: wp.vec3):
    """Where edge a-b meets z = -w, computed from the lower vertex index so both triangles sharing
    the edge get bitwise the same point. Returns (clip position, original barycentric weights)."""
    if ia > ib:
        tmp_c = ca
        ca = cb
        cb = tmp_c
        tmp_w = wa
        wa = wb
        wb = tmp_w
    da = ca[2] + ca[3]
    db = cb[2] + cb[3]
    t = da / (da - db)
    return ca + t * (cb - ca), wa + t * (wb - wa)


@wp.func
def to_screen(c: wp.vec4, width: int, height: int):
    """Clip -> (x_raster, y_raster, z_ndc, 1/w) in float64, x and y clamped to the guard band."""
    one = wp.float64(1.0)
    guard = wp.float64(GUARD)
    inv_w = one / wp.float64(c[3])
    x = wp.clamp((wp.float64(c[0]) * inv_w + one) * wp.float64(0.5 * float(width)), -guard, guard)
    y = wp.clamp((one - wp.float64(c[1]) * inv_w) * wp.float64(0.5 * float(height)), -guard, guard)
    return wp.vec4d(x, y, wp.float64(c[2]) * inv_w, inv_w)


@wp.func
def snap(x: wp.float64):
    return wp.int64(wp.round(x * wp.float64(SUBPIXEL)))


@wp.func
def edge(ax: wp.int64, ay: wp.int64, bx: wp.int64, by: wp.int64, px: wp.int64, py: wp.int64):
    """Twice the signed area of (a, b, p), exact in 64-bit integers."""
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@wp.func
def owns_edge(ax: wp.int64, ay: wp.int64, bx: wp.int64, by: wp.int64):
    """Fill rule for samples exactly on edge a->b: the edge's direction lies in a fixed half-plane,
    so of two triangles sharing the edge (traversing it in opposite directions) exactly one owns it."""
    return (by > ay) or (by == ay and bx < ax)


@wp.func
def emit(slot: int, s0: wp.vec4d, s1: wp.vec4d, s2: wp.vec4d, w0: wp.vec3, w1: wp.vec3, w2: wp.vec3, cull: int,
         screen: wp.array2d(dtype=wp.vec4d), weight: wp.array2d(dtype=wp.vec3), facing: wp.array(dtype=wp.int32),
         rows: wp.array2d(dtype=wp.int32)):
    """Store one screen triangle, wound so its integer area is positive; facing +1 front, -1 back,
    0 not drawn (degenerate, or culled); and the rows of sample centres it may cover, for binning."""
    area = edge(snap(s0[0]), snap(s0[1]), snap(s1[0]), snap(s1[1]), snap(s2[0]), snap(s2[1]))
    facing[slot] = 0
    if area == wp.int64(0):
        return
    side = 1  # counter-clockwise in NDC (y up) is clockwise in raster space (y down): area < 0
    if area > wp.int64(0):
        side = -1
    if cull == 1 and side < 0:
        return
    facing[slot] = side
    half = wp.float64(0.5)
    rows[slot, 0] = int(wp.ceil(wp.min(s0[1], wp.min(s1[1], s2[1])) - half))
    rows[slot, 1] = int(wp.floor(wp.max(s0[1], wp.max(s1[1], s2[1])) - half))
    screen[slot, 0] = s0
    weight[slot, 0] = w0
    if side > 0:
        screen[slot, 1] = s2
        screen[slot, 2] = s1
        weight[slot, 1] = w2
        weight[slot, 2] = w1
    else:
        screen[slot, 1] = s1
        screen[slot, 2] = s2
        weight[slot, 1] = w1
        weight[slot, 2] = w2


@wp.kernel
def assemble_kernel(begin: int, faces: wp.array2d(dtype=wp.int32), clip: wp.array(dtype=wp.vec4), cull: int,
                    width: int, height: int, screen: wp.array2d(dtype=wp.vec4d), weight: wp.array2d(dtype=wp.vec3),
                    facing: wp.array(dtype=wp.int32), rows: wp.array2d(dtype=wp.int32)):
    f = begin + wp.tid()
    for k in range(2):
        facing[2 * f + k] = 0
        rows[2 * f + k, 0] = 1  # empty row range [1, 0]: binned nowhere
        rows[2 * f + k, 1] = 0
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    c0 = clip[i0]
    c1 = clip[i1]
    c2 = clip[i2]
    e0 = wp.vec3(1.0, 0.0, 0.0)
    e1 = wp.vec3(0.0, 1.0, 0.0)
    e2 = wp.vec3(0.0, 0.0, 1.0)
    in0 = c0[2] + c0[3] >= 0.0
    in1 = c1[2] + c1[3] >= 0.0
    in2 = c2[2] + c2[3] >= 0.0
    count = int(in0) + int(in1) + int(in2)
    if count == 0:
        return
    if count == 3:
        emit(2 * f, to_screen(c0, width, height), to_screen(c1, width, height), to_screen(c2, width, height),
             e0, e1, e2, cull, screen, weight, facing, rows)
        return
    # Rotate (keeping the winding) so that vertex a is the odd one out: the only vertex inside
    # (count 1) or the only one outside (count 2).
    ia = i0
    ib = i1
    ic = i2
    ca = c0
    cb = c1
    cc = c2
    wa = e0
    wb = e1
    wc = e2
    odd1 = in1
    odd2 = in2
    if count == 2:
        odd1 = not in1
        odd2 = not in2
    if odd1:
        ia = i1
        ib = i2
        ic = i0
        ca = c1
        cb = c2
        cc = c0
        wa = e1
        wb = e2
        wc = e0
    elif odd2:
        ia = i2
        ib = i0
        ic = i1
        ca = c2
        cb = c0
        cc = c1
        wa = e2
        wb = e0
        wc = e1
    cab, wab = near_crossing(ia, ib, ca, cb, wa, wb)
    cac, wac = near_crossing(ia, ic, ca, cc, wa, wc)
    sab = to_screen(cab, width, height)
    sac = to_screen(cac, width, height)
    if count == 1:  # a inside: triangle (a, ab, ac)
        emit(2 * f, to_screen(ca, width, height), sab, sac, wa, wab, wac, cull, screen, weight, facing, rows)
    else:  # a outside: quad (ab, b, c, ac)
        sb = to_screen(cb, width, height)
        sc = to_screen(cc, width, height)
        emit(2 * f, sab, sb, sc, wab, wb, wc, cull, screen, weight, facing, rows)
        emit(2 * f + 1, sab, sc, sac, wab, wc, wac, cull, screen, weight, facing, rows)


@wp.func
def screen_barycentrics(screen: wp.array2d(dtype=wp.vec4d), slot: int, i: int, j: int):
    """Whether sample (i, j) is inside triangle `slot` (exact integer edge functions) and its
    screen-space barycentrics (float64)."""
    s0 = screen[slot, 0]
    s1 = screen[slot, 1]
    s2 = screen[slot, 2]
    x0 = snap(s0[0])
    y0 = snap(s0[1])
    x1 = snap(s1[0])
    y1 = snap(s1[1])
    x2 = snap(s2[0])
    y2 = snap(s2[1])
    px = wp.int64(j * SUBPIXEL + SUBPIXEL // 2)
    py = wp.int64(i * SUBPIXEL + SUBPIXEL // 2)
    b0 = edge(x1, y1, x2, y2, px, py)
    b1 = edge(x2, y2, x0, y0, px, py)
    b2 = edge(x0, y0, x1, y1, px, py)
    inside = True
    if b0 < wp.int64(0) or (b0 == wp.int64(0) and not owns_edge(x1, y1, x2, y2)):
        inside = False
    if b1 < wp.int64(0) or (b1 == wp.int64(0) and not owns_edge(x2, y2, x0, y0)):
        inside = False
    if b2 < wp.int64(0) or (b2 == wp.int64(0) and not owns_edge(x0, y0, x1, y1)):
        inside = False
    # Coverage is decided on the snapped integers; the weights come from the unsnapped float64
    # vertices, so interpolation carries no snapping error.
    cx = wp.float64(j) + wp.float64(0.5)
    cy = wp.float64(i) + wp.float64(0.5)
    e0 = (s2[0] - s1[0]) * (cy - s1[1]) - (s2[1] - s1[1]) * (cx - s1[0])
    e1 = (s0[0] - s2[0]) * (cy - s2[1]) - (s0[1] - s2[1]) * (cx - s2[0])
    e2 = (s1[0] - s0[0]) * (cy - s0[1]) - (s1[1] - s0[1]) * (cx - s0[0])
    area = e0 + e1 + e2
    if area == wp.float64(0.0):  # a sliver only the snapped vertices give an area
        return inside, wp.vec3d(wp.float64(1.0), wp.float64(0.0), wp.float64(0.0))
    return inside, wp.vec3d(e0 / area, e1 / area, e2 / area)


@wp.func
def vertex_uv(weight: wp.array2d(dtype=wp.vec3), slot: int, k: int, uv0: wp.vec2, uv1: wp.vec2, uv2: wp.vec2):
    """uv at corner k of screen triangle `slot` (a clipped corner carries original-triangle weights)."""
    w = weight[slot, k]
    return w[0] * uv0 + w[1] * uv1 + w[2] * uv2


@wp.func
def uv_derivatives(screen: wp.array2d(dtype=wp.vec4d), weight: wp.array2d(dtype=wp.vec3), slot: int, i: int, j: int,
                   perspective_correct: int, uv0: wp.vec2, uv1: wp.vec2, uv2: wp.vec2):
    """Exact d(uv)/dx and d(uv)/dy at sample (i, j) of the interpolation the resolve stage uses.

    Screen barycentrics b_k are affine in (x, y); perspective-correct ones are B_k = c_k / S with
    c_k = b_k / w_k and S = sum c_k, so dB_k = (dc_k - B_k dS) / S (quotient rule); uv = sum B_k uv_k."""
    s0 = screen[slot, 0]
    s1 = screen[slot, 1]
    s2 = screen[slot, 2]
    cx = wp.float64(j) + wp.float64(0.5)
    cy = wp.float64(i) + wp.float64(0.5)
    e0 = (s2[0] - s1[0]) * (cy - s1[1]) - (s2[1] - s1[1]) * (cx - s1[0])
    e1 = (s0[0] - s2[0]) * (cy - s2[1]) - (s0[1] - s2[1]) * (cx - s2[0])
    e2 = (s1[0] - s0[0]) * (cy - s0[1]) - (s1[1] - s0[1]) * (cx - s0[0])
    area = e0 + e1 + e2
    if area == wp.float64(0.0):
        return wp.vec2(0.0), wp.vec2(0.0)
    b = wp.vec3d(e0, e1, e2) / area
    db_dx = wp.vec3d(s1[1] - s2[1], s2[1] - s0[1], s0[1] - s1[1]) / area
    db_dy = wp.vec3d(s2[0] - s1[0], s0[0] - s2[0], s1[0] - s0[0]) / area
    if perspective_correct == 1:
        q = wp.vec3d(s0[3], s1[3], s2[3])  # 1 / w per corner
        c = wp.cw_mul(b, q)
        total = c[0] + c[1] + c[2]
        big_b = c / total
        dc_dx = wp.cw_mul(db_dx, q)
        dc_dy = wp.cw_mul(db_dy, q)
        db_dx = (dc_dx - big_b * (dc_dx[0] + dc_dx[1] + dc_dx[2])) / total
        db_dy = (dc_dy - big_b * (dc_dy[0] + dc_dy[1] + dc_dy[2])) / total
    ua = vertex_uv(weight, slot, 0, uv0, uv1, uv2)
    ub = vertex_uv(weight, slot, 1, uv0, uv1, uv2)
    uc = vertex_uv(weight, slot, 2, uv0, uv1, uv2)
    dx = wp.vec3(float(db_dx[0]), float(db_dx[1]), float(db_dx[2]))
    dy = wp.vec3(float(db_dy[0]), float(db_dy[1]), float(db_dy[2]))
    return dx[0] * ua + dx[1] * ub + dx[2] * uc, dy[0] * ua + dy[1] * ub + dy[2] * uc


@wp.kernel
def raster_kernel(row_begin: int, row_end: int, slots: wp.array(dtype=wp.int32), screen: wp.array2d(dtype=wp.vec4d),
                  width: int, key: wp.array(dtype=wp.int64)):
    slot = slots[wp.tid()]  # the triangles binned to this band of rows
    s0 = screen[slot, 0]
    s1 = screen[slot, 1]
    s2 = screen[slot, 2]
    # Sample (i, j) is centred at (j + 0.5, i + 0.5): the candidates lie in the bounding box.
    half = wp.float64(0.5)
    j_lo = wp.max(int(wp.ceil(wp.min(s0[0], wp.min(s1[0], s2[0])) - half)), 0)
    j_hi = wp.min(int(wp.floor(wp.max(s0[0], wp.max(s1[0], s2[0])) - half)), width - 1)
    i_lo = wp.max(int(wp.ceil(wp.min(s0[1], wp.min(s1[1], s2[1])) - half)), row_begin)
    i_hi = wp.min(int(wp.floor(wp.max(s0[1], wp.max(s1[1], s2[1])) - half)), row_end - 1)
    for i in range(i_lo, i_hi + 1):
        for j in range(j_lo, j_hi + 1):
            inside, b = screen_barycentrics(screen, slot, i, j)
            if inside:
                z_ndc = float(b[0] * s0[2] + b[1] * s1[2] + b[2] * s2[2])  # z_ndc is affine in screen space
                if z_ndc >= -1.0 and z_ndc <= 1.0:
                    depth = wp.int64((z_ndc + 1.0) * 0.5 * DEPTH_LEVELS)
                    wp.atomic_min(key, i * width + j, depth * wp.int64(4294967296) + wp.int64(slot))


@wp.func
def write_point(points: PointsW, k: int, p: wp.vec3, normal: wp.vec3, geo: wp.vec3, view: wp.vec3, mat: int,
                materials: wp.array(dtype=MaterialW), obj: int, analytic: bool):
    """Store shading point k; its checker cell, and the object its shadow rays skip (convex analytic ones)."""
    points.position[k] = p
    points.normal[k] = normal
    points.geo_normal[k] = geo
    points.view[k] = view
    points.material[k] = mat
    points.cell[k] = 0
    if materials[mat].checker_size > 0.0:
        points.cell[k] = checker_cell(p, geo, materials[mat].checker_size)
    points.ignore[k] = -1
    if analytic:
        points.ignore[k] = obj


@wp.kernel
def resolve_kernel(
    row0: int, key: wp.array(dtype=wp.int64), screen: wp.array2d(dtype=wp.vec4d), weight: wp.array2d(dtype=wp.vec3),
    facing: wp.array(dtype=wp.int32), faces: wp.array2d(dtype=wp.int32), vertices: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3), uvs: wp.array(dtype=wp.vec2), face_normal: wp.array(dtype=wp.vec3),
    face_material: wp.array(dtype=wp.int32), face_object: wp.array(dtype=wp.int32),
    materials: wp.array(dtype=MaterialW), cam: CameraW, perspective_correct: int, shading: int,
    n_mesh_faces: int, n_vertices: int,
    out_face: wp.array(dtype=wp.int32), out_bary: wp.array(dtype=wp.vec3), out_depth: wp.array(dtype=float),
    out_uv: wp.array(dtype=wp.vec2), out_object: wp.array(dtype=wp.int32), samples: PointsW,
    point_index: wp.array2d(dtype=wp.int32), point_weight: wp.array(dtype=wp.vec3),
):
    ii, j = wp.tid()
    i = row0 + ii
    s = i * cam.width + j
    samples.material[s] = -1
    out_face[s] = -1
    out_object[s] = -1
    out_depth[s] = wp.inf
    point_index[s, 0] = s
    point_index[s, 1] = s
    point_index[s, 2] = s
    point_weight[s] = wp.vec3(0.0)
    k = key[s]
    if k == NO_HIT:
        return
    slot = int(k % wp.int64(4294967296))
    inside, bd = screen_barycentrics(screen, slot, i, j)
    if perspective_correct == 1:  # b_k / w_k, renormalised
        bd = wp.vec3d(bd[0] * screen[slot, 0][3], bd[1] * screen[slot, 1][3], bd[2] * screen[slot, 2][3])
        bd = bd / (bd[0] + bd[1] + bd[2])
    b = wp.vec3(float(bd[0]), float(bd[1]), float(bd[2]))
    wb = b[0] * weight[slot, 0] + b[1] * weight[slot, 1] + b[2] * weight[slot, 2]
    f = slot // 2
    v0 = faces[f, 0]
    v1 = faces[f, 1]
    v2 = faces[f, 2]
    p = wb[0] * vertices[v0] + wb[1] * vertices[v1] + wb[2] * vertices[v2]
    view = view_direction(cam, p)
    side = float(facing[slot])
    geo = side * face_normal[f]
    normal = geo
    if shading != FLAT:
        normal = side * wp.normalize(wb[0] * normals[v0] + wb[1] * normals[v1] + wb[2] * normals[v2])
    mat = face_material[f]
    out_face[s] = f
    out_bary[s] = wb
    out_depth[s] = wp.dot(p - cam.eye, cam.forward)
    uv = wb[0] * uvs[v0] + wb[1] * uvs[v1] + wb[2] * uvs[v2]
    out_uv[s] = uv
    duv_dx, duv_dy = uv_derivatives(screen, weight, slot, i, j, perspective_correct, uvs[v0], uvs[v1], uvs[v2])
    samples.uv[s] = uv
    samples.duv_dx[s] = duv_dx
    samples.duv_dy[s] = duv_dy
    out_object[s] = face_object[f]
    write_point(samples, s, p, normal, geo, view, mat, materials, face_object[f], f >= n_mesh_faces)
    if shading == PHONG_SHADING:
        point_weight[s] = wp.vec3(1.0, 0.0, 0.0)
    elif shading == FLAT:
        point_index[s, 0] = f
        point_index[s, 1] = f
        point_index[s, 2] = f
        point_weight[s] = wp.vec3(1.0, 0.0, 0.0)
    else:  # gouraud: vertex colours, the back-face copies after the first n_vertices
        offset = 0
        if side < 0.0:
            offset = n_vertices
        point_index[s, 0] = v0 + offset
        point_index[s, 1] = v1 + offset
        point_index[s, 2] = v2 + offset
        point_weight[s] = wb


@wp.kernel
def flat_points_kernel(faces: wp.array2d(dtype=wp.int32), vertices: wp.array(dtype=wp.vec3),
                       face_normal: wp.array(dtype=wp.vec3), face_material: wp.array(dtype=wp.int32),
                       face_object: wp.array(dtype=wp.int32), materials: wp.array(dtype=MaterialW),
                       cam: CameraW, n_mesh_faces: int, points: PointsW):
    """One point per face: its centroid, with the face normal turned toward the viewer."""
    f = wp.tid()
    p = (vertices[faces[f, 0]] + vertices[faces[f, 1]] + vertices[faces[f, 2]]) / 3.0
    view = view_direction(cam, p)
    normal = face_normal[f]
    if wp.dot(normal, view) < 0.0:
        normal = -normal
    write_point(points, f, p, normal, normal, view, face_material[f], materials, face_object[f], f >= n_mesh_faces)


@wp.kernel
def gouraud_points_kernel(vertices: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                          vertex_material: wp.array(dtype=wp.int32), vertex_object: wp.array(dtype=wp.int32),
                          vertex_analytic: wp.array(dtype=wp.int32), materials: wp.array(dtype=MaterialW),
                          cam: CameraW, points: PointsW):
    """Two points per vertex: the front copy with the vertex normal, the back copy (index + V) with
    its negation, for back-facing triangles (OpenGL's two-sided lighting)."""
    k, back = wp.tid()
    p = vertices[k]
    normal = normals[k]
    if back == 1:
        normal = -normal
    write_point(points, k + back * vertices.shape[0], p, normal, normal, view_direction(cam, p), vertex_material[k],
                materials, vertex_object[k], vertex_analytic[k] == 1)


@wp.kernel
def light_points_kernel(
    begin: int, points: PointsW, lights: wp.array(dtype=LightW), materials: wp.array(dtype=MaterialW),
    geom: SceneGeomW, specular: int, ambient: wp.vec3, shadows: int, transparent: int,
    light_dir: wp.array2d(dtype=wp.vec3), light_dist: wp.array2d(dtype=float), visibility: wp.array2d(dtype=float),
    color: wp.array(dtype=wp.vec3), textures: TexturesW, points_are_samples: int,
    factor: wp.array(dtype=wp.vec3), texel: wp.array(dtype=wp.vec3),
):
    """ka Ia + sum_p s_p light_term_p at each point, recording L_p, d_p and s_p.

    Textured materials: where the points are the samples (Phong) the texture is sampled here and
    modulates its target coefficient (`texel[k]` records the value). Elsewhere (flat, Gouraud) the
    point's `color` is lit with the target coefficient 0 and `factor` is what that coefficient
    multiplies (lit with it 1, the others 0); compose adds texel * factor per sample."""
    k = begin + wp.tid()
    factor[k] = wp.vec3(0.0)
    mat_id = points.material[k]
    if mat_id < 0:
        color[k] = wp.vec3(0.0)
        return
    p = points.position[k]
    mat = surface_material(materials[mat_id], points.cell[k])
    split = False
    unit = mat
    if mat.texture >= 0:
        if points_are_samples == 1:
            value = sample_texture(textures, mat.texture, points.uv[k], points.duv_dx[k], points.duv_dy[k],
                                   mat.texture_filter, mat.texture_wrap)
            texel[k] = value
            mat = textured_material(mat, mat.texture_target, value)
        else:
            split = True
            unit = target_only(mat, mat.texture_target)
            mat = textured_material(mat, mat.texture_target, wp.vec3(0.0))
    total = ambient_term(mat, ambient)
    unit_total = ambient_term(unit, ambient)
    for q in range(lights.shape[0]):
        l, d = light_vector(lights[q], p)
        s = float(1.0)
        if shadows == 1 and wp.dot(points.geo_normal[k], l) > 0.0:
            origin = p + geom.epsilon * points.geo_normal[k]
            s = light_visibility(geom, materials, origin, l, d - geom.epsilon, points.ignore[k], transparent)
        light_dir[k, q] = l
        light_dist[k, q] = d
        visibility[k, q] = s
        if s > 0.0:
            total = total + s * light_term(lights[q], mat, specular, points.normal[k], points.view[k], l, d)
            if split:
                unit_total = unit_total + s * light_term(lights[q], unit, specular, points.normal[k], points.view[k],
                                                         l, d)
    color[k] = total
    if split:
        factor[k] = unit_total


@wp.func
def clamp01(c: wp.vec3):
    return wp.vec3(wp.clamp(c[0], 0.0, 1.0), wp.clamp(c[1], 0.0, 1.0), wp.clamp(c[2], 0.0, 1.0))


@wp.func
def blend_points(values: wp.array(dtype=wp.vec3), point_index: wp.array2d(dtype=wp.int32), w: wp.vec3, s: int,
                 clamp_colors: int):
    """sum_k w_k values[point k of sample s], each value clamped to [0, 1] first when asked (OpenGL)."""
    out = wp.vec3(0.0)
    for k in range(3):
        c = values[point_index[s, k]]
        if clamp_colors == 1:
            c = clamp01(c)
        out = out + w[k] * c
    return out


@wp.kernel
def compose_kernel(row0: int, width: int, mask_material: wp.array(dtype=wp.int32), depth: wp.array(dtype=float),
                   point_index: wp.array2d(dtype=wp.int32), point_weight: wp.array(dtype=wp.vec3),
                   color: wp.array(dtype=wp.vec3), clamp_colors: int, background: wp.vec3, fog_mode: int,
                   fog_color: wp.vec3, fog_start: float, fog_end: float, fog_density: float,
                   image: wp.array(dtype=wp.vec3), materials: wp.array(dtype=MaterialW), textures: TexturesW,
                   samples: PointsW, per_fragment: int, factor: wp.array(dtype=wp.vec3),
                   texel: wp.array(dtype=wp.vec3)):
    """Sample colour = sum_k w_k colour_k (+ texel * sum_k w_k factor_k for a textured material under
    flat / Gouraud shading, the texture sampled per sample: `per_fragment`), then fog."""
    ii, j = wp.tid()
    s = (row0 + ii) * width + j
    mat_id = mask_material[s]
    if mat_id < 0:
        image[s] = background
        return
    out = blend_points(color, point_index, point_weight[s], s, clamp_colors)
    if per_fragment == 1 and materials[mat_id].texture >= 0:
        mat = materials[mat_id]
        modulated = blend_points(factor, point_index, point_weight[s], s, clamp_colors)
        value = sample_texture(textures, mat.texture, samples.uv[s], samples.duv_dx[s], samples.duv_dy[s],
                               mat.texture_filter, mat.texture_wrap)
        texel[s] = value
        out = out + wp.cw_mul(value, modulated)
    f = fog_factor(fog_mode, depth[s], fog_start, fog_end, fog_density)
    image[s] = f * out + (1.0 - f) * fog_color

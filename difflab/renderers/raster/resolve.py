"""Rasterizer stages 4-5: the G-buffer and the shading points.

Stage 4 (`resolve_kernel`), per sample: barycentrics of the winning triangle, perspective-correct
(b_k / w_k renormalised) or affine, the original triangle's weights, and the surface there
(position, normal, uv and its exact screen derivatives, material, depth). Stage 5, the points where
the illumination model is evaluated: phong, every covered sample; flat, every face (lit at its
centroid with the face normal); gouraud, every vertex twice (front and back normal, OpenGL's
two-sided lighting). Each sample records which three points make its colour and their weights.
"""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import MaterialW, checker_cell
from ..camera import CameraW, view_direction
from ...vocabulary import FLAT, PHONG_SHADING
from .coverage import NO_HIT, screen_barycentrics

wp.set_module_options({"enable_backward": False})

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

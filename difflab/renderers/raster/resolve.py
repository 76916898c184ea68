"""Rasterizer stages 4-5: the G-buffer and the shading points.

Stage 4 (`resolve_kernel`), per sample: barycentrics of the winning triangle, perspective-correct
(b_k / w_k renormalised) or affine, the original triangle's weights, and the surface there
(position, normal, uv and its exact screen derivatives, material, depth; under Phong shading, on an
analytic sphere, the sphere's own point on the sample's eye ray, its normal and uv there, as the ray
tracer finds them: `sphere_sample`). Stage 5, the points where
the illumination model is evaluated: phong, every covered sample; flat, every face (lit at its
centroid with the face normal); gouraud, every vertex twice (front and back normal, OpenGL's
two-sided lighting). Each sample records which three points make its colour and their weights.
"""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import MaterialW, checker_cell
from ...vocabulary import FLAT, PHONG_SHADING
from ..camera import CameraW, line_point, primary_ray, view_direction
from ..launch import dealt_span
from ..texture.footprint import pixel_footprint, sphere_uv, sphere_uv_jacobian
from ..trace import HIT_SPHERE, leaving_skip, sphere_point
from .coverage import NO_HIT, edge_weights, float_barycentrics

wp.set_module_options({"enable_backward": False})


@wp.struct
class RasterMeshW:
    """The compiled triangles as the raster kernels read them."""

    faces: wp.array2d(dtype=wp.int32)
    vertices: wp.array(dtype=wp.vec3)
    normals: wp.array(dtype=wp.vec3)  # unit vertex normals
    uvs: wp.array(dtype=wp.vec2)
    face_normal: wp.array(dtype=wp.vec3)  # unit geometric (winding) normal
    face_material: wp.array(dtype=wp.int32)
    face_object: wp.array(dtype=wp.int32)
    vertex_material: wp.array(dtype=wp.int32)  # of a face using the vertex (Gouraud's vertex points)
    vertex_object: wp.array(dtype=wp.int32)
    object_kind: wp.array(dtype=wp.int32)  # per scene object: trace.HIT_SPHERE / HIT_PLANE / HIT_TRIANGLE (mesh)
    sphere_center: wp.array(dtype=wp.vec3)  # per scene object: an analytic sphere's centre and radius (else 0),
    sphere_radius: wp.array(dtype=float)  # float32 as the ray tracer's (`compile.ray_geometry`)


@wp.struct
class ScreenW:
    """Stage 2's screen triangles in slots: face f's first in slot f, second ones after (see `clip`)."""

    screen: wp.array2d(dtype=wp.vec4d)  # (x_raster, y_raster, z_ndc, 1/w) per corner
    weight: wp.array2d(dtype=wp.vec3)  # per corner, its weights over the original face's vertices
    facing: wp.array(dtype=wp.int32)  # +1 front, -1 back, 0 not drawn
    face: wp.array(dtype=wp.int32)  # the face each slot belongs to


@wp.struct
class PointW:
    """One shading point: where the illumination model is evaluated."""

    p: wp.vec3
    normal: wp.vec3  # unit shading normal, facing the viewer
    geo: wp.vec3  # unit geometric normal, facing the viewer
    view: wp.vec3  # unit direction to the viewer
    material: int  # -1: nothing here
    cell: int  # checker cell 0 / 1
    ignore: int  # object its shadow rays skip (`trace.leaving_skip`), else -1


@wp.struct
class PointsW:
    """Shading points in arrays (the G-buffer's samples, or flat / Gouraud points)."""

    position: wp.array(dtype=wp.vec3)
    normal: wp.array(dtype=wp.vec3)
    geo_normal: wp.array(dtype=wp.vec3)  # what shadow rays start from: empty for the G-buffer's samples (lit
    ignore: wp.array(dtype=wp.int32)  # where resolved, or not at them), kept for flat / Gouraud points
    view: wp.array(dtype=wp.vec3)
    material: wp.array(dtype=wp.int32)
    cell: wp.array(dtype=wp.int32)
    duv_dx: wp.array(dtype=wp.vec2)  # d(uv)/dx, d(uv)/dy per sample of the sample grid (samples only)
    duv_dy: wp.array(dtype=wp.vec2)


@wp.struct
class SampleW:
    """What a covered sample sees: the face and its interpolation weights, and the surface point."""

    face: int
    slot: int
    weights: wp.vec3  # over the face's vertices: perspective-correct or affine
    side: float  # +1 the face's front is seen, -1 its back
    point: PointW
    sphere: int  # 1: the point is on the analytic sphere the face tessellates (`sphere_sample`), else 0
    area: wp.float64  # the slot's edge values' sum there (`edge_weights`)
    perspective: wp.vec3d  # perspective-correct: c_k / total, c_k = e_k / w_k of its edge values e_k
    total: wp.float64  # sum c_k


@wp.func(inline=True)
def make_point(p: wp.vec3, normal: wp.vec3, geo: wp.vec3, view: wp.vec3, mat: int,
               materials: wp.array(dtype=MaterialW), mesh: RasterMeshW, obj: int, outward: wp.vec3):
    """A shading point of object `obj`, with its checker cell and the object its shadow rays skip.

    That is the ray tracer's rule, `leaving_skip`, for a ray leaving along `geo`: shadow rays are
    cast only where geo . L > 0, and geo is +-`outward` (the stored face or vertex normal, outward
    on a sphere's tessellation), so every L gives the same answer as geo. A sphere seen from
    inside is not skipped: its far wall shadows the inside from a light outside."""
    point = PointW()
    point.p = p
    point.normal = normal
    point.geo = geo
    point.view = view
    point.material = mat
    point.cell = 0
    if materials[mat].checker_size > 0.0:
        point.cell = checker_cell(p, geo, materials[mat].checker_size)
    point.ignore = leaving_skip(mesh.object_kind[obj], obj, outward, geo)
    return point


@wp.func
def store_point(points: PointsW, k: int, point: PointW):
    """Point k into `points`; its shadow rays' start (geometric normal, object skipped) only where
    `points` keeps them (flat / Gouraud points, lit in a pass of their own), its position only
    where kept (not in a fit's G-buffer)."""
    if points.position.shape[0] > 0:
        points.position[k] = point.p
    points.normal[k] = point.normal
    points.view[k] = point.view
    points.material[k] = point.material
    points.cell[k] = point.cell
    if points.geo_normal.shape[0] > 0:
        points.geo_normal[k] = point.geo
        points.ignore[k] = point.ignore


@wp.func
def load_point(points: PointsW, k: int):
    point = PointW()
    point.p = points.position[k]
    point.normal = points.normal[k]
    point.geo = points.geo_normal[k]
    point.view = points.view[k]
    point.material = points.material[k]
    point.cell = points.cell[k]
    point.ignore = points.ignore[k]
    return point


@wp.func
def vertex_uv(weight: wp.array2d(dtype=wp.vec3), slot: int, k: int, uv0: wp.vec2, uv1: wp.vec2, uv2: wp.vec2):
    """uv at corner k of screen triangle `slot` (a clipped corner carries original-triangle weights)."""
    w = weight[slot, k]
    return w[0] * uv0 + w[1] * uv1 + w[2] * uv2


@wp.func
def uv_derivatives(screen: wp.array2d(dtype=wp.vec4d), weight: wp.array2d(dtype=wp.vec3), slot: int, area: wp.float64,
                   perspective_correct: int, big_b: wp.vec3d, total: wp.float64, uv0: wp.vec2, uv1: wp.vec2,
                   uv2: wp.vec2):
    """Exact d(uv)/dx and d(uv)/dy of the interpolation the resolve stage uses, at the sample where
    slot `slot` has edge values summing to `area` (`edge_weights`) and, perspective-correct, the
    weights big_b = c / total (`sample_weights`).

    Screen barycentrics b_k = e_k / A are affine in (x, y), de_k/dx = y_{k+1} - y_{k+2} and
    de_k/dy = x_{k+2} - x_{k+1}; perspective-correct ones are B_k = c_k / S with c_k = e_k / w_k
    and S = sum c_k (A cancels), so dB_k = (dc_k - B_k dS) / S (quotient rule); uv = sum B_k uv_k."""
    s0 = screen[slot, 0]
    s1 = screen[slot, 1]
    s2 = screen[slot, 2]
    if area == wp.float64(0.0):
        return wp.vec2(0.0), wp.vec2(0.0)
    de_dx = wp.vec3d(s1[1] - s2[1], s2[1] - s0[1], s0[1] - s1[1])
    de_dy = wp.vec3d(s2[0] - s1[0], s0[0] - s2[0], s1[0] - s0[0])
    db_dx = wp.vec3d()
    db_dy = wp.vec3d()
    if perspective_correct == 1:
        q = wp.vec3d(s0[3], s1[3], s2[3])  # 1 / w per corner
        dc_dx = wp.cw_mul(de_dx, q)
        dc_dy = wp.cw_mul(de_dy, q)
        inv_total = wp.float64(1.0) / total
        db_dx = (dc_dx - big_b * (dc_dx[0] + dc_dx[1] + dc_dx[2])) * inv_total
        db_dy = (dc_dy - big_b * (dc_dy[0] + dc_dy[1] + dc_dy[2])) * inv_total
    else:
        db_dx = de_dx / area
        db_dy = de_dy / area
    ua = vertex_uv(weight, slot, 0, uv0, uv1, uv2)
    ub = vertex_uv(weight, slot, 1, uv0, uv1, uv2)
    uc = vertex_uv(weight, slot, 2, uv0, uv1, uv2)
    dx = wp.vec3(float(db_dx[0]), float(db_dx[1]), float(db_dx[2]))
    dy = wp.vec3(float(db_dy[0]), float(db_dy[1]), float(db_dy[2]))
    return dx[0] * ua + dx[1] * ub + dx[2] * uc, dy[0] * ua + dy[1] * ub + dy[2] * uc


@wp.func(inline=True)
def covering(key: wp.int64, tris: ScreenW):
    """The slot whose triangle a covered sample sees (its visibility key is `key`), that slot's face
    and the side seen, in a SampleW holding nothing else."""
    slot = int(key % wp.int64(4294967296))
    sample = SampleW()
    sample.face = tris.face[slot]
    sample.slot = slot
    sample.side = float(tris.facing[slot])
    return sample


@wp.func(inline=True)
def sample_weights(key: wp.int64, tris: ScreenW, perspective_correct: int, i: int, j: int, mesh: RasterMeshW,
                   sphere_weights: int):
    """Which face covered sample (i, j) sees (its visibility key is `key`, `covering`) and with what
    weights: barycentrics of the winning slot, perspective-correct (b_k / w_k renormalised) or
    affine, carried to the original face. Only `point.material` of the returned sample is filled in.
    `sphere_weights` 0: a sample on an analytic sphere is left without weights (zero), for a Phong
    pass that reads none there (`shade.phong_gbuffer_kernel`)."""
    sample = covering(key, tris)
    slot = sample.slot
    if sphere_weights == 0:  # (returned here: a branch around the weights below slowed a Phong mesh's pass 6-13 %)
        if mesh.object_kind[mesh.face_object[sample.face]] == HIT_SPHERE:
            return sample
    screen = tris.screen
    weight = tris.weight
    bd = wp.vec3d()
    if perspective_correct == 1:  # b_k / w_k renormalised: c_k = e_k / w_k, as b_k = e_k / area and area cancels
        e, area = edge_weights(screen[slot, 0], screen[slot, 1], screen[slot, 2], i, j)
        c = wp.vec3d(e[0] * screen[slot, 0][3], e[1] * screen[slot, 1][3], e[2] * screen[slot, 2][3])
        sample.total = c[0] + c[1] + c[2]
        bd = c * (wp.float64(1.0) / sample.total)  # one division
        sample.perspective = bd
        sample.area = area
    else:
        b_screen, area = float_barycentrics(screen[slot, 0], screen[slot, 1], screen[slot, 2], i, j)
        bd = b_screen
        sample.area = area
    b = wp.vec3(float(bd[0]), float(bd[1]), float(bd[2]))
    sample.weights = b[0] * weight[slot, 0] + b[1] * weight[slot, 1] + b[2] * weight[slot, 2]
    return sample


@wp.func(inline=True)
def sample_position(sample: SampleW, mesh: RasterMeshW):
    """The world-space point a sample sees."""
    f = sample.face
    wb = sample.weights
    return wb[0] * mesh.vertices[mesh.faces[f, 0]] + wb[1] * mesh.vertices[mesh.faces[f, 1]] \
        + wb[2] * mesh.vertices[mesh.faces[f, 2]]


@wp.func
def sphere_ray(mesh: RasterMeshW, cam: CameraW, obj: int, side: float, i: int, j: int):
    """Where sample (i, j)'s eye ray (`camera.primary_ray` through its centre, from
    `camera.line_point`) meets analytic sphere `obj` (`trace.sphere_point`, the ray tracer's
    formula) -- its near root where the face's front is seen (side +1), its far root where its back
    is (from inside) -- and the ray's unit direction d. The facets are inscribed, so the ray through
    a covered sample meets the sphere (a miss by rounding: the tangent point)."""
    x = float(j) + 0.5
    y = float(i) + 0.5
    unused, direction = primary_ray(cam, x, y)
    p = sphere_point(mesh.sphere_center[obj], mesh.sphere_radius[obj], line_point(cam, x, y), direction,
                     int(side < 0.0))
    return p, direction


@wp.func
def sphere_sample(mesh: RasterMeshW, materials: wp.array(dtype=MaterialW), mat: int, obj: int, p: wp.vec3,
                  direction: wp.vec3):
    """The point of analytic sphere `obj` that a sample sees under Phong shading, p where its eye ray
    of direction d meets it (`sphere_ray`): the normal (p - c) / r, turned toward the ray as the ray
    tracer turns it, and the view -d."""
    outward = wp.normalize(p - mesh.sphere_center[obj])
    normal = outward
    if wp.dot(direction, outward) > 0.0:
        normal = -outward
    return make_point(p, normal, normal, -direction, mat, materials, mesh, obj, outward)


@wp.func
def sphere_rays(key: wp.array(dtype=wp.int64), partial: wp.array(dtype=wp.int64), tris: ScreenW, mesh: RasterMeshW,
                cam: CameraW, found: PointsW, i: int, j0: int, j1: int):
    """`sphere_ray` at samples (i, j), j in [j0, j1), on analytic spheres, ahead of `resolve_into`
    over them (Phong shading, `shade.phong_gbuffer_kernel`): p as found.position, -d as found.view, read
    back by `resolve_sample` (`found`: the G-buffer's samples, or a fit's scratch where its
    G-buffer keeps no position: `gbuffer.gbuffer_layout`). A loop of its own: each sample's chain
    of square roots and divisions is independent of the next one's, and the CPU overlaps several
    where the loop is this short, not inside the whole per-sample pass (the 256^2 bench sphere's
    Phong G-buffer pass ~0.95 -> ~0.76 ms of CPU a half, interleaved medians of 150 at load 2.5;
    the scan costs a frame of background ~1 ns a sample: a tiny sphere's 0.13 -> 0.17 ms). Keys as
    `resolve_into` reads them; none is reset here. Nothing to find in a scene without analytic
    spheres. Returns whether the scene has any."""
    spheres = int(0)
    for obj in range(mesh.object_kind.shape[0]):
        if mesh.object_kind[obj] == HIT_SPHERE:
            spheres = 1
    if spheres == 0:
        return 0
    for j in range(j0, j1):
        s = i * cam.width + j
        k = key[s]
        if partial.shape[0] > 0:
            k = wp.min(k, partial[s])
        if k != NO_HIT:
            sample = covering(k, tris)
            obj = mesh.face_object[sample.face]
            if mesh.object_kind[obj] == HIT_SPHERE:
                p, direction = sphere_ray(mesh, cam, obj, sample.side, i, j)
                found.position[s] = p
                found.view[s] = -direction
    return 1


@wp.func(inline=True)
def resolve_sample(key: wp.int64, tris: ScreenW, mesh: RasterMeshW, materials: wp.array(dtype=MaterialW),
                   cam: CameraW, perspective_correct: int, shading: int, i: int, j: int, found: PointsW,
                   sphere_weights: int):
    """`sample_weights` (`sphere_weights`: its) and the surface point there: under Phong shading on
    an analytic sphere the sphere's own (`sphere_sample`: the facets decide only coverage and depth
    order) at its eye ray's hit, which `sphere_rays` found (`found`; an empty PointsW(): found here);
    else the face's interpolated position with the face's normal (flat) or the interpolated vertex
    normals, both facing the viewer side the face shows."""
    sample = sample_weights(key, tris, perspective_correct, i, j, mesh, sphere_weights)
    f = sample.face
    obj = mesh.face_object[f]
    if shading == PHONG_SHADING and mesh.object_kind[obj] == HIT_SPHERE:
        sample.sphere = 1
        p = wp.vec3()
        direction = wp.vec3()
        if found.position.shape[0] > 0:
            p = found.position[i * cam.width + j]
            direction = -found.view[i * cam.width + j]
        else:
            p, direction = sphere_ray(mesh, cam, obj, sample.side, i, j)
        sample.point = sphere_sample(mesh, materials, mesh.face_material[f], obj, p, direction)
        return sample
    wb = sample.weights
    side = sample.side
    p = sample_position(sample, mesh)
    geo = side * mesh.face_normal[f]
    normal = geo
    if shading != FLAT:
        normal = side * wp.normalize(wb[0] * mesh.normals[mesh.faces[f, 0]] + wb[1] * mesh.normals[mesh.faces[f, 1]]
                                     + wb[2] * mesh.normals[mesh.faces[f, 2]])
    sample.point = make_point(p, normal, geo, view_direction(cam, p), mesh.face_material[f], materials, mesh, obj,
                              mesh.face_normal[f])
    return sample


@wp.func
def sample_uv(sample: SampleW, tris: ScreenW, mesh: RasterMeshW, cam: CameraW, perspective_correct: int, i: int,
              j: int):
    """uv at covered sample (i, j) and its screen derivatives d(uv)/dx, d(uv)/dy: on a sphere's own
    point (`sphere_sample`) the sphere's uv there (`sphere_uv`) and its Jacobian over the sample's
    footprint on the tangent plane (`pixel_footprint`, one sample wide; `sphere_uv_jacobian`), as
    the ray tracer forms them; else the face's interpolated uv and the exact derivatives of that
    interpolation."""
    if sample.sphere == 1:
        obj = mesh.face_object[sample.face]
        center = mesh.sphere_center[obj]
        p = sample.point.p
        dpdx, dpdy = pixel_footprint(cam, float(j) + 0.5, float(i) + 0.5, 1.0, p, sample.point.geo)
        duv_dx, duv_dy = sphere_uv_jacobian(p, center, mesh.sphere_radius[obj], dpdx, dpdy)
        return sphere_uv(p, center), duv_dx, duv_dy
    f = sample.face
    wb = sample.weights
    uv0 = mesh.uvs[mesh.faces[f, 0]]
    uv1 = mesh.uvs[mesh.faces[f, 1]]
    uv2 = mesh.uvs[mesh.faces[f, 2]]
    duv_dx, duv_dy = uv_derivatives(tris.screen, tris.weight, sample.slot, sample.area, perspective_correct,
                                    sample.perspective, sample.total, uv0, uv1, uv2)
    return wb[0] * uv0 + wb[1] * uv1 + wb[2] * uv2, duv_dx, duv_dy


@wp.func(inline=True)
def sample_points(sample: SampleW, mesh: RasterMeshW, shading: int, s: int, n_vertices: int):
    """Which three shading points make sample s's colour (indices, weights): itself (phong), its face
    (flat), or its face's vertices (gouraud; the back-face copies after the first n_vertices)."""
    if shading == PHONG_SHADING:
        return wp.vec3i(s, s, s), wp.vec3(1.0, 0.0, 0.0)
    f = sample.face
    if shading == FLAT:
        return wp.vec3i(f, f, f), wp.vec3(1.0, 0.0, 0.0)
    offset = 0
    if sample.side < 0.0:
        offset = n_vertices
    return wp.vec3i(mesh.faces[f, 0] + offset, mesh.faces[f, 1] + offset, mesh.faces[f, 2] + offset), sample.weights


@wp.struct
class GBufferW:
    """Stage 4's per-sample outputs (the G-buffer)."""

    face: wp.array(dtype=wp.int32)
    bary: wp.array(dtype=wp.vec3)
    depth: wp.array(dtype=float)
    uv: wp.array(dtype=wp.vec2)
    object: wp.array(dtype=wp.int32)
    point_index: wp.array(dtype=wp.vec3i)
    point_weight: wp.array(dtype=wp.vec3)


@wp.func
def resolve_into(key: wp.array(dtype=wp.int64), partial: wp.array(dtype=wp.int64), tris: ScreenW, mesh: RasterMeshW,
                 materials: wp.array(dtype=MaterialW), cam: CameraW, perspective_correct: int, shading: int,
                 n_vertices: int, out: GBufferW, samples: PointsW, found: PointsW, sphere_weights: int, i: int,
                 j: int):
    """Stage 4 at sample (i, j): its G-buffer entries (empty ones where nothing covers it: the
    non-zero ones only, as `samples` and `out` are zero when the kernel starts). Its key is the
    lesser of `key` and `partial` (a z-buffer drawn in two; `partial` empty otherwise), both reset.
    `found`, `sphere_weights`: see `resolve_sample`. Returns whether it is covered, and its point, uv
    and uv derivatives as stored (what a Phong pass lights next, without reading them back); an
    uncovered sample's point is empty but for its material: the one the sample held before (a fit's
    G-buffer, not cleared, zeroes the sample's entries where that is a point's: `shade.gbuffer_row`).
    An empty array of `out` or `samples` is a field the G-buffer does not keep (a fit's,
    `gbuffer.fit_skips`): not written (nor are the point indices and weights formed without
    `point_index`), and without `duv_dx` uv and its derivatives are formed only where the sample's
    material has a texture (uv 0 elsewhere, as the ray tracer's G-buffer has it)."""
    s = i * cam.width + j
    k = key[s]
    if partial.shape[0] > 0:
        other = partial[s]
        if other != NO_HIT:
            partial[s] = NO_HIT  # the next frame's z-buffer starts cleared
            k = wp.min(k, other)
    if k == NO_HIT:  # its other entries stay as cleared: zero
        missed = PointW()
        missed.material = samples.material[s]
        samples.material[s] = -1
        if out.face.shape[0] > 0:
            out.face[s] = -1
        out.object[s] = -1
        if out.depth.shape[0] > 0:
            out.depth[s] = wp.inf
        if out.point_index.shape[0] > 0:
            out.point_index[s] = wp.vec3i(s, s, s)
        return False, missed, wp.vec2(0.0), wp.vec2(0.0), wp.vec2(0.0)
    key[s] = NO_HIT  # the next frame's z-buffer starts cleared
    sample = resolve_sample(k, tris, mesh, materials, cam, perspective_correct, shading, i, j, found, sphere_weights)
    store_point(samples, s, sample.point)
    uv = wp.vec2(0.0)
    duv_dx = wp.vec2(0.0)
    duv_dy = wp.vec2(0.0)
    derivatives = samples.duv_dx.shape[0] > 0
    if derivatives or (out.uv.shape[0] > 0 and materials[sample.point.material].texture >= 0):  # (else 0)
        uv, duv_dx, duv_dy = sample_uv(sample, tris, mesh, cam, perspective_correct, i, j)
        if derivatives:
            samples.duv_dx[s] = duv_dx
            samples.duv_dy[s] = duv_dy
    if out.uv.shape[0] > 0:  # (0 where untextured: a fit's G-buffer is not cleared)
        out.uv[s] = uv
    if out.face.shape[0] > 0:
        out.face[s] = sample.face
        out.bary[s] = sample.weights
    if out.depth.shape[0] > 0:
        out.depth[s] = wp.dot(sample.point.p - cam.eye, cam.forward)
    out.object[s] = mesh.face_object[sample.face]
    if out.point_index.shape[0] > 0:
        index, weight = sample_points(sample, mesh, shading, s, n_vertices)
        out.point_index[s] = index
        out.point_weight[s] = weight
    return True, sample.point, uv, duv_dx, duv_dy


@wp.kernel
def resolve_kernel(row0: int, row_step: int, span: int, key: wp.array(dtype=wp.int64),
                   partial: wp.array(dtype=wp.int64), tris: ScreenW, mesh: RasterMeshW,
                   materials: wp.array(dtype=MaterialW), cam: CameraW, perspective_correct: int, shading: int,
                   n_vertices: int, out: GBufferW, samples: PointsW):
    """Stage 4, `span` samples of a row per thread (`launch.launch_row_loops`)."""
    i, j0, j1, unused = dealt_span(row0, row_step, span, cam.width, wp.tid())
    for j in range(j0, j1):
        resolve_into(key, partial, tris, mesh, materials, cam, perspective_correct, shading, n_vertices, out, samples,
                     PointsW(), 1, i, j)

"""Ray queries against a compiled scene: analytic spheres and planes, and triangles through Warp's BVH.

The rasterizer's shadow rays and the ray tracer's every ray ask `closest_hit` (or its parts: the
analytic surfaces `analytic_hit`, then the BVH `mesh_hit`, which the item and light buffers also use).
A hit records its distance t along the unit ray, what was hit (kind, index, object, material), the
geometric normal (as stored: outward for spheres, the plane's normal, the triangle's winding normal)
and the triangle's barycentrics in Warp's `mesh_query_ray` convention: p = u p0 + v p1 + (1 - u - v) p2.
Where a ray leaving a hit starts, and the shadow rays' walk through transparent surfaces, are `trace`'s.
"""

from __future__ import annotations

from .._warp import wp

wp.set_module_options({"enable_backward": False})

HIT_NONE, HIT_TRIANGLE, HIT_SPHERE, HIT_PLANE = 0, 1, 2, 3


@wp.struct
class SceneGeomW:
    """The scene's ray-traceable geometry. `mesh` is 0 when the scene has no triangle meshes."""

    mesh: wp.uint64
    face_material: wp.array(dtype=wp.int32)
    face_object: wp.array(dtype=wp.int32)
    sphere_center: wp.array(dtype=wp.vec3)
    sphere_radius: wp.array(dtype=float)
    sphere_material: wp.array(dtype=wp.int32)
    sphere_object: wp.array(dtype=wp.int32)
    plane_point: wp.array(dtype=wp.vec3)
    plane_normal: wp.array(dtype=wp.vec3)
    plane_tangent: wp.array(dtype=wp.vec3)  # u's direction on the plane (`Plane.uv_frame`)
    plane_bitangent: wp.array(dtype=wp.vec3)  # v's direction
    plane_anchor: wp.array(dtype=wp.vec3)  # where uv is measured from (`tessellate.plane_uv_anchor`)
    plane_anchor_uv: wp.array(dtype=wp.vec2)  # its uv
    plane_material: wp.array(dtype=wp.int32)
    plane_object: wp.array(dtype=wp.int32)
    epsilon: float  # the least offset of a rasterized point's shadow rays, scene units (`compile.object_offset`)


@wp.struct
class HitW:
    t: float
    kind: int
    index: int
    object: int
    material: int
    normal: wp.vec3  # geometric normal, unit, as stored (not flipped toward the ray)
    u: float
    v: float

@wp.func
def ray_sphere(origin: wp.vec3, direction: wp.vec3, center: wp.vec3, radius: float, t_min: float):
    """Smallest root t > t_min of |o + t d - c| = r for a unit d, or -1. Uses the stable form
    h = d.(c - o), disc = r^2 - |o + h d - c|^2 (no cancellation for far spheres)."""
    oc = center - origin
    h = wp.dot(direction, oc)
    closest = oc - h * direction
    disc = radius * radius - wp.dot(closest, closest)
    if disc < 0.0:
        return -1.0
    s = wp.sqrt(disc)
    t = h - s
    if t > t_min:
        return t
    t = h + s
    if t > t_min:
        return t
    return -1.0


@wp.func
def ray_plane(origin: wp.vec3, direction: wp.vec3, point: wp.vec3, normal: wp.vec3, t_min: float):
    """t > t_min where the ray meets the plane (p - point).normal = 0, or -1 (parallel or behind)."""
    denom = wp.dot(direction, normal)
    if wp.abs(denom) < 1.0e-12:
        return -1.0
    t = wp.dot(point - origin, normal) / denom
    if t > t_min:
        return t
    return -1.0


@wp.func
def ray_triangle(origin: wp.vec3, direction: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3):
    """Moller-Trumbore: (t, b1, b2) with origin + t direction = (1 - b1 - b2) a + b1 b + b2 c, or
    t = -1 when the ray is parallel to the triangle's plane. The caller tests the barycentrics."""
    e1 = b - a
    e2 = c - a
    pvec = wp.cross(direction, e2)
    det = wp.dot(e1, pvec)
    if wp.abs(det) < 1.0e-30:
        return -1.0, 0.0, 0.0
    inv_det = 1.0 / det
    tvec = origin - a
    b1 = wp.dot(tvec, pvec) * inv_det
    qvec = wp.cross(tvec, e1)
    b2 = wp.dot(direction, qvec) * inv_det
    return wp.dot(e2, qvec) * inv_det, b1, b2


@wp.func_native("""
float t = 0.0f, u = 0.0f, v = 0.0f, sign = 0.0f;
if (wp::intersect_ray_tri_woop(start, dir, a, b, c, t, u, v, sign, nullptr))
    return wp::vec4(t, u, v, 1.0f);
return wp::vec4(0.0f, 0.0f, 0.0f, 0.0f);
""")
def woop_triangle(start: wp.vec3, dir: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec4:
    """`mesh_query_ray`'s own triangle test (Warp's watertight intersect_ray_tri_woop: Woop, Benthin
    and Wald 2013): (t, u, v, 1) on a hit, t >= 0 and start + t dir = u a + v b + (1 - u - v) c,
    else 0. Whatever asks a mesh triangle what the BVH would answer uses it, bit for bit."""
    ...


@wp.func
def no_hit(t_max: float):
    """A miss (nothing before t_max)."""
    hit = HitW()
    hit.t = t_max
    hit.kind = HIT_NONE
    hit.index = -1
    hit.object = -1
    hit.material = -1
    return hit


@wp.func(inline=True)
def surface_hit(geom: SceneGeomW, kind: int, index: int, t: float, origin: wp.vec3, direction: wp.vec3):
    """The hit on sphere / plane / triangle `index` at t: its object, material and geometric normal
    (a triangle's normal, u and v are left for the caller, which has them from its intersection)."""
    hit = no_hit(t)
    hit.kind = kind
    hit.index = index
    if kind == HIT_SPHERE:
        hit.object = geom.sphere_object[index]
        hit.material = geom.sphere_material[index]
        hit.normal = wp.normalize(origin + t * direction - geom.sphere_center[index])
    elif kind == HIT_PLANE:
        hit.object = geom.plane_object[index]
        hit.material = geom.plane_material[index]
        hit.normal = geom.plane_normal[index]
    elif kind == HIT_TRIANGLE:
        hit.object = geom.face_object[index]
        hit.material = geom.face_material[index]
    return hit


@wp.func(inline=True)
def analytic_hit(geom: SceneGeomW, origin: wp.vec3, direction: wp.vec3, t_min: float, t_max: float,
                 ignore_object: int):
    """The nearest sphere or plane with t_min < t < t_max along a unit ray, skipping object
    `ignore_object`: only its t, kind and index (`finish_hit` completes it)."""
    hit = no_hit(t_max)
    for k in range(geom.sphere_center.shape[0]):
        if geom.sphere_object[k] != ignore_object:
            t = ray_sphere(origin, direction, geom.sphere_center[k], geom.sphere_radius[k], t_min)
            if t > 0.0 and t < hit.t:
                hit.t = t
                hit.kind = HIT_SPHERE
                hit.index = k
    for k in range(geom.plane_point.shape[0]):
        if geom.plane_object[k] != ignore_object:
            t = ray_plane(origin, direction, geom.plane_point[k], geom.plane_normal[k], t_min)
            if t > 0.0 and t < hit.t:
                hit.t = t
                hit.kind = HIT_PLANE
                hit.index = k
    return hit


@wp.func(inline=True)
def triangle_hit(geom: SceneGeomW, face: int, t: float, u: float, v: float, normal: wp.vec3, origin: wp.vec3,
                 direction: wp.vec3):
    """The hit on mesh triangle `face` as `mesh_query_ray` reports it (t, u, v, unit winding normal)."""
    out = surface_hit(geom, HIT_TRIANGLE, face, t, origin, direction)
    out.u = u
    out.v = v
    out.normal = wp.normalize(normal)
    return out


@wp.func(inline=True)
def finish_hit(geom: SceneGeomW, hit: HitW, origin: wp.vec3, direction: wp.vec3):
    """An `analytic_hit` (or a miss) with its object, material and normal."""
    if hit.kind == HIT_NONE:
        return hit
    return surface_hit(geom, hit.kind, hit.index, hit.t, origin, direction)


@wp.func(inline=True)
def mesh_hit(geom: SceneGeomW, origin: wp.vec3, direction: wp.vec3, t_min: float, hit: HitW, ignore_object: int):
    """The nearest mesh triangle before `hit` (an `analytic_hit`) through the BVH, else `hit` finished."""
    if geom.mesh != wp.uint64(0):
        query = wp.mesh_query_ray(geom.mesh, origin + t_min * direction, direction, hit.t - t_min)
        if query.result and geom.face_object[query.face] != ignore_object:
            return triangle_hit(geom, query.face, query.t + t_min, query.u, query.v, query.normal, origin, direction)
    return finish_hit(geom, hit, origin, direction)


@wp.func
def closest_hit(geom: SceneGeomW, origin: wp.vec3, direction: wp.vec3, t_min: float, t_max: float,
                ignore_object: int):
    """The nearest surface with t_min < t < t_max along a unit ray, skipping object `ignore_object`."""
    return mesh_hit(geom, origin, direction, t_min, analytic_hit(geom, origin, direction, t_min, t_max, ignore_object),
                    ignore_object)

"""Rays that leave a surface: where a new ray starts off a hit, and the shadow rays' walk to a light.

The hits come from `intersect` (`closest_hit` and its parts). Where a ray leaves a surface (as
pbrt-v4's OffsetRayOrigin and Mitsuba 3's spawn_ray do): the hit
point is computed from the surface, not as origin + t d (`hit_point`), so that its float32 error is
a few ulps of its own coordinates and the surface's, whatever the ray's origin (an eye 5000 away
put ulp(5000) = 5e-4 into origin + t d); an orthographic view's primary hit is seen from its
ray's point beside the target (`hit_from`), and a sphere's normal is taken at the point found
(`normal_at`). A new ray starts `ray_offset` -- RAY_OFFSET_ULPS x 2^-23 x those coordinates
-- off it, measured along the geometric normal on the side it travels to (`spawn_origin`: along
the ray itself, so that a refracted ray's path is not shifted): enough that neither that point's
rounding nor the next intersection test's puts the surface in front of it. The offset depends on
where the hit is, not on where the eye or the far plane is, and scales with the scene (8 x 2^-23:
2.9e-6 at coordinates of 3; 2 was the least that showed no acne in tests/test_raytrace_offsets.py,
1 shadowed 1 % of a faceted sphere's lit facets 1e4 from the origin).

Shadow rays (`shadow_ray`; the rasterizer's `light_visibility`; the light buffer's walk steps with the
same `shadow_step`) pass through transparent surfaces, multiplying their kt, up to MAX_SHADOW_CROSSINGS.
"""

from __future__ import annotations

import numpy as np
from .._warp import wp

from ..lighting.warp_model import MaterialW
from ..scene import Plane, Sphere
from .intersect import HIT_NONE, HIT_PLANE, HIT_SPHERE, HIT_TRIANGLE, HitW, SceneGeomW, closest_hit, no_hit, \
    ray_triangle

wp.set_module_options({"enable_backward": False})

RAY_OFFSET_ULPS = 8.0  # a new ray starts this many x 2^-23 of its hit's coordinates off the surface (`ray_offset`)
SPAWN_GRAZING = 0.125  # |cos| below which a new ray steps off along the normal, not along itself (`spawn_origin`)
#: Transparent surfaces a shadow ray may pass through: one that meets another (the 256th) counts as
#: blocked, as a ray cut by max_depth contributes black. 255 is what the ray tree's per-material
#: crossing counts (uint8) hold; the walk is a loop (Warp unrolls none past 16), so a higher cap
#: costs nothing where fewer surfaces are crossed. The ray tracer counts the cut rays, those that
#: would otherwise reach the light (`frame.stats["shadow_rays_cut"]`; a ray an opaque surface blocks
#: anywhere is blocked, not cut); the light buffer's rays are cut and counted alike.
MAX_SHADOW_CROSSINGS = 255


def object_kinds(objects) -> np.ndarray:
    """Per scene object the kind of surface a ray meets on it: HIT_SPHERE, HIT_PLANE or (meshes)
    HIT_TRIANGLE, as int32."""
    kinds = {Sphere: HIT_SPHERE, Plane: HIT_PLANE}
    return np.array([kinds.get(type(obj), HIT_TRIANGLE) for obj in objects], np.int32)


@wp.func
def leaving_skip(kind: int, obj: int, outward: wp.vec3, direction: wp.vec3):
    """The object a ray leaving a point of object `obj` (a surface of `kind`, with `outward` its
    sphere's outward normal there) in unit `direction` cannot meet again, -1 for none: a plane
    always; a sphere when the ray leaves it outwards (direction . outward > 0: a convex surface is
    behind it), not when it goes in (it meets the far wall); a mesh never (it may be concave)."""
    if kind == HIT_PLANE:
        return obj
    if kind == HIT_SPHERE and wp.dot(direction, outward) > 0.0:
        return obj
    return -1


@wp.func
def max_abs(v: wp.vec3):
    return wp.max(wp.abs(v[0]), wp.max(wp.abs(v[1]), wp.abs(v[2])))


@wp.func
def sphere_point(center: wp.vec3, radius: float, origin: wp.vec3, direction: wp.vec3, far: int):
    """Where the unit ray meets the sphere, at its near root h - s (`far` 0) or far root h + s
    (`far` 1), h = d.(c - o): c - f -+ s d, f = c - (the ray's point nearest c), s = half the chord
    (Ray Tracing Gems ch. 7: no large t in it), moved radially onto the sphere (pbrt-v4: a reflected
    direction several bounces deep is unit only to a few ulps, which s d carried). A ray that
    misses by rounding (|f| > r, s clamped to 0) gives the sphere's point nearest it (tangent)."""
    oc = center - origin
    h = wp.dot(direction, oc)
    f = oc - h * direction
    s = wp.sqrt(wp.max(radius * radius - wp.dot(f, f), 0.0))
    q = -f - s * direction
    if far == 1:
        q = -f + s * direction
    return center + (radius / wp.length(q)) * q  # |q| = r, or |f| > r: never 0


@wp.func
def hit_point(geom: SceneGeomW, hit: HitW, origin: wp.vec3, direction: wp.vec3):
    """Where `hit` (not a miss) of the unit ray lies, computed from its surface (module doc): on a
    sphere `sphere_point` at the root the hit found; on a plane origin + t d
    moved onto the plane along its normal; on a triangle the blend of its corners by the hit's
    barycentrics (pbrt-v4)."""
    if hit.kind == HIT_SPHERE:
        center = geom.sphere_center[hit.index]
        return sphere_point(center, geom.sphere_radius[hit.index], origin, direction,
                            int(hit.t > wp.dot(direction, center - origin)))  # beyond h: the far root, h + s
    if hit.kind == HIT_PLANE:
        normal = geom.plane_normal[hit.index]
        point = geom.plane_point[hit.index]
        p = origin + (wp.dot(point - origin, normal) / wp.dot(direction, normal)) * direction
        return p - wp.dot(p - point, normal) * normal
    return wp.mesh_eval_position(geom.mesh, hit.index, hit.u, hit.v)


@wp.func
def normal_at(geom: SceneGeomW, hit: HitW, p: wp.vec3):
    """`hit`'s geometric normal at its `hit_point` p: a sphere's (p - c) / |p - c| from that point
    (`intersect.surface_hit` took it from origin + t d), the others' as found."""
    if hit.kind == HIT_SPHERE:
        return wp.normalize(p - geom.sphere_center[hit.index])
    return hit.normal


@wp.func
def hit_from(geom: SceneGeomW, hit: HitW, origin: wp.vec3, line: wp.vec3, direction: wp.vec3):
    """`hit` (not a miss) of the unit ray from `origin`, seen from `line`, another point of the ray's
    line (one float32 holds more precisely: `camera.line_point`): t measured from there, and a
    triangle's barycentrics found again from there (`ray_triangle`), for `hit_point` to use."""
    out = no_hit(hit.t - wp.dot(line - origin, direction))
    out.kind = hit.kind
    out.index = hit.index
    out.object = hit.object
    out.material = hit.material
    out.normal = hit.normal
    out.u = hit.u
    out.v = hit.v
    if hit.kind == HIT_TRIANGLE:
        mesh = wp.mesh_get(geom.mesh)
        t, b1, b2 = ray_triangle(line, direction, mesh.points[mesh.indices[3 * hit.index]],
                                 mesh.points[mesh.indices[3 * hit.index + 1]],
                                 mesh.points[mesh.indices[3 * hit.index + 2]])
        if t != -1.0:  # (-1: parallel to its plane)
            out.u = 1.0 - b1 - b2
            out.v = b1
    return out


@wp.func
def ray_offset(geom: SceneGeomW, hit: HitW, p: wp.vec3):
    """How far (scene units) a ray leaving `hit` at its `hit_point` p starts off the surface:
    RAY_OFFSET_ULPS x 2^-23 x the largest coordinate whose float32 rounding reaches p or an
    intersection test with the surface -- max_i |p_i|, and a sphere's max_i |c_i| + r, a plane's
    max_i |point_i|, a triangle's corners' max |v_i|."""
    scale = max_abs(p)
    if hit.kind == HIT_SPHERE:
        scale = wp.max(scale, max_abs(geom.sphere_center[hit.index]) + geom.sphere_radius[hit.index])
    elif hit.kind == HIT_PLANE:
        scale = wp.max(scale, max_abs(geom.plane_point[hit.index]))
    else:
        mesh = wp.mesh_get(geom.mesh)
        for k in range(3):
            scale = wp.max(scale, max_abs(mesh.points[mesh.indices[3 * hit.index + k]]))
    return RAY_OFFSET_ULPS * 1.1920928955078125e-07 * scale


@wp.func
def point_offset(geom: SceneGeomW, p: wp.vec3):
    """`ray_offset` for a rasterized point p, whose triangle is not known here: RAY_OFFSET_ULPS x
    2^-23 x max_i |p_i|, and at least `geom.epsilon` (the same of the objects' largest coordinate)."""
    return wp.max(geom.epsilon, RAY_OFFSET_ULPS * 1.1920928955078125e-07 * max_abs(p))


@wp.func
def spawn_origin(p: wp.vec3, normal: wp.vec3, direction: wp.vec3, offset: float):
    """Where a ray leaving surface point p in unit `direction` starts: `offset` off the surface (unit
    geometric `normal`), on the side the ray travels to -- along the ray itself, offset / |d.n| on
    (so its line still passes through p: a refracted ray is not shifted), unless the ray leaves
    within SPAWN_GRAZING of the surface (|d.n| < that), then along the normal."""
    cos = wp.dot(direction, normal)
    if wp.abs(cos) >= SPAWN_GRAZING:
        return p + (offset / wp.abs(cos)) * direction
    if cos >= 0.0:
        return p + offset * normal
    return p - offset * normal


@wp.func
def past_surface(geom: SceneGeomW, hit: HitW, origin: wp.vec3, direction: wp.vec3):
    """Where a unit ray from `origin` that crosses `hit` (not a miss) goes on from: `spawn_origin`
    beyond the surface, and how far along the ray that is from `origin`."""
    p = hit_point(geom, hit, origin, direction)
    beyond = spawn_origin(p, hit.normal, direction, ray_offset(geom, hit, p))
    return beyond, wp.dot(beyond - origin, direction)


@wp.func
def opaque_ahead(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), hit: HitW, origin: wp.vec3, l: wp.vec3,
                 remaining: float, ignore_object: int):
    """1 if an opaque (kt = 0) surface lies past transparent `hit` within `remaining` along unit l
    from `origin`, walking on through every transparent one (only a cut shadow ray asks), else 0."""
    while True:
        origin, step = past_surface(geom, hit, origin, l)
        remaining = remaining - step
        if remaining <= 0.0:
            return 0
        hit = closest_hit(geom, origin, l, 0.0, remaining, ignore_object)
        if hit.kind == HIT_NONE:
            return 0
        if materials[hit.material].kt <= 0.0:
            return 1


SHADOW_GOES_ON, SHADOW_LIT, SHADOW_BLOCKED, SHADOW_CUT = 0, 1, 2, 3  # `shadow_step`'s verdicts


@wp.func
def shadow_step(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), hit: HitW, crossing: int, transparent: int,
                visibility: float, origin: wp.vec3, l: wp.vec3, remaining: float, ignore_object: int):
    """What a shadow ray makes of the nearest surface `hit` it meets (or a miss) as its `crossing`-th
    (from 0): (verdict, visibility, origin, remaining). A miss: SHADOW_LIT. An opaque surface, or any
    with `transparent` off: SHADOW_BLOCKED, visibility 0. A transparent one (kt > 0): visibility x kt
    and the ray goes on from `past_surface` (SHADOW_GOES_ON; SHADOW_LIT if that passes the light),
    except the one past MAX_SHADOW_CROSSINGS: visibility 0, SHADOW_CUT where the ray would otherwise
    reach the light, SHADOW_BLOCKED where an opaque surface lies further on (`opaque_ahead`, through
    the BVH). `shadow_ray` and the light buffer's walk (`lightbuffer.buffered_visibility`) both step
    with it."""
    if hit.kind == HIT_NONE:
        return SHADOW_LIT, visibility, origin, remaining
    kt = materials[hit.material].kt
    if transparent == 0 or kt <= 0.0:
        return SHADOW_BLOCKED, 0.0, origin, remaining
    if crossing == MAX_SHADOW_CROSSINGS:
        if opaque_ahead(geom, materials, hit, origin, l, remaining, ignore_object) == 1:
            return SHADOW_BLOCKED, 0.0, origin, remaining
        return SHADOW_CUT, 0.0, origin, remaining
    beyond, step = past_surface(geom, hit, origin, l)
    verdict = SHADOW_GOES_ON
    if remaining - step <= 0.0:
        verdict = SHADOW_LIT
    return verdict, visibility * kt, beyond, remaining - step


@wp.func(inline=True)
def shadow_ray(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), p: wp.vec3, l: wp.vec3, distance: float,
               ignore_object: int, transparent: int):
    """(visibility in [0, 1], cut) of a light at `distance` along unit `l` from p, through the BVH.

    An opaque surface in between gives 0. With `transparent` set, each surface with kt > 0 crossed
    multiplies the visibility by kt (the ray is not refracted), up to MAX_SHADOW_CROSSINGS of them:
    a ray meeting one more gives 0, and cut = 1 where it would otherwise reach the light (no opaque
    surface lies further on: `shadow_step`). The caller offsets p off the surface.
    Inlined, as `light_visibility`: see there.
    """
    visibility = float(1.0)
    origin = p
    remaining = distance
    for crossing in range(MAX_SHADOW_CROSSINGS + 1):
        hit = closest_hit(geom, origin, l, 0.0, remaining, ignore_object)
        verdict, visibility, origin, remaining = shadow_step(geom, materials, hit, crossing, transparent, visibility,
                                                             origin, l, remaining, ignore_object)
        if verdict != SHADOW_GOES_ON:
            return visibility, int(verdict == SHADOW_CUT)
    return 0.0, 1  # (not reached: the last pass returns)


@wp.func(inline=True)
def light_visibility(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), p: wp.vec3, l: wp.vec3,
                     distance: float, ignore_object: int, transparent: int):
    """`shadow_ray`'s visibility alone (the rasterizer's shadow rays). Inlined with `shadow_ray`:
    the CPU compiler kept it a call, which copies `geom` (~800 bytes, a `rep movsq`) per shadow ray,
    ~40 % of its cost. The 256^2 bench sphere on its floor with shadows: its fit frame's Phong pass
    2.25 -> 1.59 ms of CPU a band, the frame's kernels 5.5 -> 4.4 ms, a render's 6.2 -> 5.1, a
    G-buffer frame's 9.5 -> 7.8 (interleaved medians at loads 3-4, the passes' row loops kept apart
    from shadow rays: `shade.phong_gbuffer_kernel`); the ray tracer's the same. The rasterizer's
    shade module compiles in ~25 s instead of ~13 (once: Warp's cache keeps it)."""
    visibility, cut = shadow_ray(geom, materials, p, l, distance, ignore_object, transparent)
    return visibility


@wp.func
def count_shadow_crossings(geom: SceneGeomW, materials: wp.array(dtype=MaterialW), p: wp.vec3, l: wp.vec3,
                           distance: float, ignore_object: int, crossings: wp.array3d(dtype=wp.int32), k: int,
                           q: int):
    """Walk `shadow_ray`'s transparent shadow ray again (one that was not blocked nor cut: at most
    MAX_SHADOW_CROSSINGS crossings), by its steps (`shadow_step`), adding 1 to crossings[k, q,
    material] for every transparent surface it crosses, so that its visibility prod(kt) can be
    re-evaluated for new kt."""
    visibility = float(1.0)
    origin = p
    remaining = distance
    for crossing in range(MAX_SHADOW_CROSSINGS):
        hit = closest_hit(geom, origin, l, 0.0, remaining, ignore_object)
        verdict, visibility, origin, remaining = shadow_step(geom, materials, hit, crossing, 1, visibility, origin, l,
                                                             remaining, ignore_object)
        if hit.kind == HIT_NONE or verdict == SHADOW_BLOCKED:
            return
        crossings[k, q, hit.material] = crossings[k, q, hit.material] + 1
        if verdict != SHADOW_GOES_ON:
            return

"""Pixel footprints: how far a sample's surface point moves across the sample (dp/dx, dp/dy) and what
that makes of the texture coordinates (d(uv)/dx, d(uv)/dy), which drive the mip-map and EWA filters
(`sampling.sample_texture`); and the uv of analytic planes and spheres.

For ray hits (the ray tracer's rule, and the rasterizer's on an analytic sphere's Phong samples; on
triangles the rasterizer computes the same Jacobian analytically from its perspective-correct
interpolation on its sample grid): `pixel_footprint` intersects the rays through the raster points
(x +- w/2, y) and (x, y +- w/2) with the tangent plane at the hit and returns dp/dx, dp/dy (central
differences over one sample, w pixels wide: 1 / side under side x side supersampling); a secondary
ray carries its sample's ray differentials (`primary_differentials`, reflected and refracted at each
surface by `raytrace.optics`) and `ray_footprint` moves them onto the surface it meets; and
`triangle_uv_derivatives`, `plane_uv_derivatives` and `sphere_uv_jacobian` turn dp/dx, dp/dy into
d(uv)/dx, d(uv)/dy for triangles, planes and spheres with the uv conventions of
`scene.Plane.uv_frame` and `geometry.uv_sphere`.
"""

from __future__ import annotations

from ..._warp import wp

from ..camera import CameraW, primary_ray

wp.set_module_options({"enable_backward": False})


@wp.func
def onto_plane(origin: wp.vec3, direction: wp.vec3, p: wp.vec3, normal: wp.vec3):
    """Where the ray origin + t direction meets the plane through p with `normal` (p if parallel)."""
    denom = wp.dot(direction, normal)
    if wp.abs(denom) < 1.0e-12:
        return p
    return origin + (wp.dot(p - origin, normal) / denom) * direction


@wp.func
def pixel_footprint(cam: CameraW, x: float, y: float, width: float, p: wp.vec3, normal: wp.vec3):
    """dp/dx, dp/dy of a primary hit p (raster point (x, y) of `cam`'s grid, surface `normal`) over a
    sample `width` raster units wide: the rays through (x +- width/2, y) and (x, y +- width/2) met
    with the tangent plane at p, differenced."""
    h = 0.5 * width
    o_r, d_r = primary_ray(cam, x + h, y)
    o_l, d_l = primary_ray(cam, x - h, y)
    o_d, d_d = primary_ray(cam, x, y + h)
    o_u, d_u = primary_ray(cam, x, y - h)
    dpdx = onto_plane(o_r, d_r, p, normal) - onto_plane(o_l, d_l, p, normal)
    dpdy = onto_plane(o_d, d_d, p, normal) - onto_plane(o_u, d_u, p, normal)
    return dpdx, dpdy


@wp.func
def primary_differentials(cam: CameraW, direction: wp.vec3, width: float):
    """The differentials of the primary ray in unit `direction` over a sample `width` raster units
    wide (Igehy's ray differentials): how its origin and its direction change across the sample,
    (dp/dx, dp/dy, dd/dx, dd/dy). The camera-plane offset moves by e_x = 2 w / W half_w right and
    e_y = -2 w / H half_h up (`camera.primary_ray`); an orthographic ray's origin moves by them, a
    perspective ray's direction d = v / |v| (v = forward + offset) by (e - d (d.e)) / |v|."""
    e_x = (2.0 * width / float(cam.width)) * cam.half_w * cam.right
    e_y = (-2.0 * width / float(cam.height)) * cam.half_h * cam.up
    if cam.perspective == 0:
        return e_x, e_y, wp.vec3(0.0), wp.vec3(0.0)
    scale = wp.dot(direction, cam.forward)  # 1 / |v|: v's forward component is 1
    return wp.vec3(0.0), wp.vec3(0.0), scale * (e_x - direction * wp.dot(direction, e_x)), \
        scale * (e_y - direction * wp.dot(direction, e_y))


@wp.func
def ray_footprint(direction: wp.vec3, normal: wp.vec3, dpdx: wp.vec3, dpdy: wp.vec3):
    """dp/dx, dp/dy on the tangent plane with `normal` of a ray arriving along unit `direction` whose
    positional differentials there are dpdx, dpdy (its origin's plus the distance travelled times
    its direction's: Igehy's transfer): each moved along the ray onto the plane."""
    denom = wp.dot(direction, normal)
    if wp.abs(denom) < 1.0e-6:
        denom = 1.0e-6
    return dpdx - direction * (wp.dot(dpdx, normal) / denom), dpdy - direction * (wp.dot(dpdy, normal) / denom)


@wp.func
def triangle_uv_derivatives(p0: wp.vec3, p1: wp.vec3, p2: wp.vec3, uv0: wp.vec2, uv1: wp.vec2, uv2: wp.vec2,
                            dpdx: wp.vec3, dpdy: wp.vec3):
    """d(uv)/dx, d(uv)/dy on a triangle: dp = dpdu du + dpdv dv solved in least squares, where
    (dpdu, dpdv) is the triangle's uv frame. Zero for a triangle with degenerate uvs."""
    e1 = p1 - p0
    e2 = p2 - p0
    a1 = uv1 - uv0
    a2 = uv2 - uv0
    det_uv = a1[0] * a2[1] - a1[1] * a2[0]
    if wp.abs(det_uv) < 1.0e-20:
        return wp.vec2(0.0), wp.vec2(0.0)
    dpdu = (a2[1] * e1 - a1[1] * e2) / det_uv
    dpdv = (a1[0] * e2 - a2[0] * e1) / det_uv
    g00 = wp.dot(dpdu, dpdu)
    g01 = wp.dot(dpdu, dpdv)
    g11 = wp.dot(dpdv, dpdv)
    det = g00 * g11 - g01 * g01
    if wp.abs(det) < 1.0e-30:
        return wp.vec2(0.0), wp.vec2(0.0)
    rx = wp.vec2(wp.dot(dpdu, dpdx), wp.dot(dpdv, dpdx))
    ry = wp.vec2(wp.dot(dpdu, dpdy), wp.dot(dpdv, dpdy))
    dx = wp.vec2(g11 * rx[0] - g01 * rx[1], g00 * rx[1] - g01 * rx[0]) / det
    dy = wp.vec2(g11 * ry[0] - g01 * ry[1], g00 * ry[1] - g01 * ry[0]) / det
    return dx, dy


@wp.func
def plane_uv(p: wp.vec3, anchor: wp.vec3, tangent: wp.vec3, bitangent: wp.vec3, anchor_uv: wp.vec2):
    """A plane's uv ((p - anchor).t, (p - anchor).b) + anchor_uv, with its `Plane.uv_frame` (t, b)
    and `tessellate.plane_uv_anchor` (the eye's foot on the plane and its uv, reduced by whole
    periods of a repeating texture), compiled once into `SceneGeomW`; the rasterizer's plane grid
    takes the same uv at its vertices."""
    d = p - anchor
    return wp.vec2(wp.dot(d, tangent), wp.dot(d, bitangent)) + anchor_uv


@wp.func
def plane_uv_derivatives(dpdx: wp.vec3, dpdy: wp.vec3, tangent: wp.vec3, bitangent: wp.vec3):
    """d(uv)/dx, d(uv)/dy on a plane: uv is linear in p, so they are dp/dx, dp/dy on (t, b)."""
    return wp.vec2(wp.dot(dpdx, tangent), wp.dot(dpdx, bitangent)), wp.vec2(wp.dot(dpdy, tangent),
                                                                            wp.dot(dpdy, bitangent))


@wp.func
def sphere_uv(p: wp.vec3, center: wp.vec3):
    """uv = (lon / 2 pi, lat / pi) of `geometry.uv_sphere`: direction (sin lat cos lon, -cos lat,
    -sin lat sin lon) from the centre; u in [0, 1), v = 0 at the south pole (-y)."""
    d = wp.normalize(p - center)
    lon = wp.atan2(-d[2], d[0])
    if lon < 0.0:
        lon = lon + 2.0 * wp.pi
    lat = wp.acos(wp.clamp(-d[1], -1.0, 1.0))
    return wp.vec2(lon / (2.0 * wp.pi), lat / wp.pi)


@wp.func
def sphere_uv_jacobian(p: wp.vec3, center: wp.vec3, radius: float, dpdx: wp.vec3, dpdy: wp.vec3):
    """d(uv)/dx, d(uv)/dy of `sphere_uv` at p on the sphere (centre c, radius r) for the tangent
    steps dp/dx, dp/dy of a sample's footprint: its Jacobian there (the chain rule; no seam, no
    transcendental -- central differences of `sphere_uv`, as taken before, cost four atan2 / acos
    pairs, and differ from it by the second order of the step, most near the poles). With
    d = (p - c) / r and rho^2 = d_x^2 + d_z^2: du = (d_z dd_x - d_x dd_z) / (2 pi rho^2),
    dv = dd_y / (pi rho), dd = dp / r. At a pole (rho^2 under 1e-12) rho^2 is held at 1e-12: u
    spans all longitudes there, the filter's widest footprint."""
    d = (p - center) / radius
    rho2 = wp.max(d[0] * d[0] + d[2] * d[2], 1.0e-12)
    su = 1.0 / (2.0 * wp.pi * radius * rho2)
    sv = 1.0 / (wp.pi * radius * wp.sqrt(rho2))
    return wp.vec2(su * (d[2] * dpdx[0] - d[0] * dpdx[2]), sv * dpdx[1]), \
        wp.vec2(su * (d[2] * dpdy[0] - d[0] * dpdy[2]), sv * dpdy[1])

"""Where a ray meets a surface: the pending ray, the surface as shading sees it, and the Fresnel split.

Surfaces are two-sided: the geometric and shading normals are flipped to face the incoming ray
(so inside a refracting object they point inwards). A ray hitting the side its geometric normal
points to is *entering* (eta = n_out / ior, n_out the index of the medium around the object, 1 in
air); from the other side it is *leaving* (eta = ior / n_out) -- where the object is transparent
(kt > 0). An opaque one has no inside: eta = n_out / ior on both its sides, whatever its winding or
its plane's normal sign (`SurfaceW.eta`, from the ray's media: `nesting.crossing`).
New rays start the hit's own `trace.ray_offset` off the surface (a few float32 ulps of its
coordinates, from its `trace.hit_point`), measured along the geometric normal on the side they
travel to, stepped along the ray itself (`trace.spawn_origin`); a ray leaving a sphere outwards,
and every ray leaving a plane, also skips that object (it cannot meet it again).

The split between the reflected and the refracted child: the reflected one takes kr F_r, the
refracted one kt F_t, with (F_r, F_t) = (1, 1) without Fresnel weighting and (F, 1 - F) with it,
F = F(cos_i, eta) (`optics.fresnel`) at every surface, opaque (kt = 0) or not. Total internal
reflection leaves no refracted ray: F = 1, and the share the refracted ray would have taken,
kt (1 - F) = 0 with Fresnel weighting, kt without it, goes to the reflected ray, which then takes
kr F_r + kt T (T: `SplitW.tir_share`, 1 without Fresnel, else 0), as POV-Ray traces it.
"""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import LightW, MaterialW, checker_cell, surface_material, textured_material
from ...vocabulary import FRESNEL_NONE
from ..camera import CameraW, near_distance, primary_ray
from ..intersect import HIT_PLANE, HIT_TRIANGLE, HitW, SceneGeomW
from ..texture.footprint import pixel_footprint, plane_uv, plane_uv_derivatives, primary_differentials, ray_footprint, \
    sphere_uv, sphere_uv_jacobian, triangle_uv_derivatives
from ..texture.sampling import TexturesW, sample_texture
from ..trace import leaving_skip, ray_offset, spawn_origin
from .lightbuffer import LightBufferW
from .nesting import MediaW, crossing
from .optics import fresnel, reflect, refract, refracted_differential
from .tree import PRIMARY, REFLECTED

wp.set_module_options({"enable_backward": False})


@wp.struct
class MeshDataW:
    """Triangle vertices, unit vertex normals (smooth shading), uvs and faces of the compiled scene."""

    vertices: wp.array(dtype=wp.vec3)
    normals: wp.array(dtype=wp.vec3)
    uvs: wp.array(dtype=wp.vec2)
    faces: wp.array2d(dtype=wp.int32)


@wp.struct
class SceneW:
    """The compiled scene as the ray tracer's kernels see it."""

    geom: SceneGeomW
    mesh: MeshDataW
    lights: wp.array(dtype=LightW)
    materials: wp.array(dtype=MaterialW)
    textures: TexturesW
    light_buffer: LightBufferW  # candidate occluders per light direction (`use` 0: shadow rays ask the BVH)
    probe_coincident: int  # 1: two or more objects are transparent, a refracting hit looks for a coincident
    # transparent surface (`nesting.crossing`)


@wp.struct
class DifferentialsW:
    """A ray's differentials over one sample (Igehy 1999): how its origin and its unit direction
    change from the ray through one side of the sample to the other's, across x and across y
    (`texture.footprint.primary_differentials`); reflection and refraction carry them on
    (`child_differentials`), ignoring the surfaces' curvature."""

    dpdx: wp.vec3
    dpdy: wp.vec3
    dddx: wp.vec3
    dddy: wp.vec3


@wp.struct
class RayW:
    """A ray waiting on the walk's stack."""

    origin: wp.vec3  # where it is traced from: `start` moved `SurfaceW.offset` off the surface (primary: onto
    # the near plane)
    start: wp.vec3  # the surface point it leaves, where its absorption counts from (the primary ray:
    # `camera.primary_ray`'s origin, or the last surface before the near plane: `medium.primary_medium`)
    direction: wp.vec3  # unit
    weight: wp.vec3  # path weight, before this ray's own absorption
    diff: DifferentialsW  # its footprint over one sample (texture filtering)
    depth: int  # 1 for the primary ray
    parent: int  # the parent's node index within the sample (-1: the primary ray)
    kind: int  # tree.PRIMARY / REFLECTED / REFRACTED
    media: MediaW  # the transparent objects it travels inside (`nesting`): the innermost's medium
    skip: int  # the object it cannot meet again, -1: none


@wp.struct
class SurfaceW:
    """A hit as shading sees it: two-sided, checker cell and texture applied to the material."""

    p: wp.vec3  # the hit point (`trace.hit_point`)
    offset: float  # how far rays leaving it start off it (`trace.ray_offset`)
    geo: wp.vec3  # unit geometric normal, facing the incoming ray
    normal: wp.vec3  # unit shading normal, facing the incoming ray
    view: wp.vec3  # unit direction back along the incoming ray
    entering: int  # 1 where the ray hit the side the stored normal points to
    eta: float  # n_outside / n_inside there, the ratio Snell and Fresnel take (`nesting.crossing`)
    beyond: MediaW  # what a ray refracted there travels in
    cell: int  # checker cell 0 / 1
    uv: wp.vec2  # where a textured material read its texture (`hit_texel`), else 0
    texel: wp.vec3  # the texture value a textured material took, else 0
    dpdx: wp.vec3  # the sample's footprint on the surface (`hit_footprint`)
    dpdy: wp.vec3
    mat: MaterialW


@wp.struct
class SplitW:
    """How a hit divides its ray between the reflected and the refracted child."""

    refracts: int  # 0 under total internal reflection
    t_dir: wp.vec3  # the refracted direction (where refracts = 1)
    fresnel: float  # F (0 where Fresnel weighting is off; 1 under TIR)
    f_r: float  # the reflected child's weight is weight * (kr * f_r + kt * tir_share)
    f_t: float  # the refracted child's weight is weight * kt * f_t (0 under TIR)
    tir_share: float  # under TIR, the refracted ray's share that goes to the reflected one (1 - F
    # with Fresnel weighting, = 0; 1 without), else 0


@wp.func
def new_ray(start: wp.vec3, origin: wp.vec3, direction: wp.vec3, weight: wp.vec3, diff: DifferentialsW, depth: int,
            parent: int, kind: int, media: MediaW, skip: int):
    ray = RayW()
    ray.origin = origin
    ray.start = start
    ray.direction = direction
    ray.weight = weight
    ray.diff = diff
    ray.depth = depth
    ray.parent = parent
    ray.kind = kind
    ray.media = media
    ray.skip = skip
    return ray


@wp.func
def sample_xy(points: wp.array2d(dtype=wp.vec2), side: int, i: int, j: int):
    """Raster position of sample (i, j): `driver.sample_points`' grid pattern for side > 0 (computed
    as it does, in float64: the same float32 values), else (side 0) read from `points`."""
    if side == 1:  # the same values: j + 0.5 is exact in float32 (j < 2^23)
        return wp.vec2(float(j) + 0.5, float(i) + 0.5)
    if side > 1:
        half = wp.float64(0.5)
        step = wp.float64(side)
        return wp.vec2(float((wp.float64(j) + half) / step), float((wp.float64(i) + half) / step))
    return points[i, j]


@wp.func
def primary_sample(points: wp.array2d(dtype=wp.vec2), side: int, cam: CameraW, far: float, i: int, j: int):
    """Sample (i, j)'s raster position and primary ray: it leaves `camera.primary_ray`'s origin
    (the eye, perspective) and is traced from where it crosses the near plane, `near` further on
    (where the rasterizer clips), to the far plane, t_far beyond that (where the rasterizer clips too).
    Returns xy, the ray's start (the eye), its unit direction, near and t_far."""
    xy = sample_xy(points, side, i, j)
    start, direction = primary_ray(cam, xy[0], xy[1])
    near = near_distance(cam, direction)
    return xy, start, direction, near, (far - cam.near) / wp.dot(direction, cam.forward)


@wp.func
def primary_diff(cam: CameraW, direction: wp.vec3, near: float, width: float):
    """The differentials of the primary ray in unit `direction` over a sample `width` pixels wide,
    at its origin `near` on from its start (`primary_sample`)."""
    dpdx, dpdy, dddx, dddy = primary_differentials(cam, direction, width)
    diff = DifferentialsW()
    diff.dpdx = dpdx + near * dddx
    diff.dpdy = dpdy + near * dddy
    diff.dddx = dddx
    diff.dddy = dddy
    return diff


@wp.func(inline=True)
def shading_normal(mesh: MeshDataW, hit: HitW):
    """Unit shading normal at a hit: interpolated vertex normals on triangles, else the geometric one."""
    if hit.kind != HIT_TRIANGLE:
        return hit.normal
    f = hit.index
    w2 = 1.0 - hit.u - hit.v
    blend = hit.u * mesh.normals[mesh.faces[f, 0]] + hit.v * mesh.normals[mesh.faces[f, 1]] \
        + w2 * mesh.normals[mesh.faces[f, 2]]
    if wp.length_sq(blend) == 0.0:  # catch degenerate normals: fall back to the face's own
        return hit.normal
    return wp.normalize(blend)


@wp.func
def hit_footprint(ray: RayW, hit: HitW, geo: wp.vec3):
    """dp/dx, dp/dy of the ray's sample on the surface it meets (unit normal `geo`): its
    differentials carried to the hit (`ray_footprint`: exact for plane mirrors). (A primary ray's
    t is from its origin, or any point of its line where its directions do not spread.)"""
    d = ray.diff
    return ray_footprint(ray.direction, geo, d.dpdx + hit.t * d.dddx, d.dpdy + hit.t * d.dddy)


@wp.func
def hit_texel(scene: SceneW, mat: MaterialW, hit: HitW, p: wp.vec3, dpdx: wp.vec3, dpdy: wp.vec3):
    """uv and the texture value at a hit. uv: interpolated vertex uvs (triangles), the plane's
    `Plane.uv`, or the sphere's (lon / 2 pi, lat / pi), filtered over the sample's footprint
    dp/dx, dp/dy."""
    uv = wp.vec2(0.0)
    duv_dx = wp.vec2(0.0)
    duv_dy = wp.vec2(0.0)
    mesh = scene.mesh
    if hit.kind == HIT_TRIANGLE:
        f = hit.index
        i0 = mesh.faces[f, 0]
        i1 = mesh.faces[f, 1]
        i2 = mesh.faces[f, 2]
        uv = hit.u * mesh.uvs[i0] + hit.v * mesh.uvs[i1] + (1.0 - hit.u - hit.v) * mesh.uvs[i2]
        duv_dx, duv_dy = triangle_uv_derivatives(mesh.vertices[i0], mesh.vertices[i1], mesh.vertices[i2],
                                                 mesh.uvs[i0], mesh.uvs[i1], mesh.uvs[i2], dpdx, dpdy)
    elif hit.kind == HIT_PLANE:
        tangent = scene.geom.plane_tangent[hit.index]
        bitangent = scene.geom.plane_bitangent[hit.index]
        uv = plane_uv(p, scene.geom.plane_anchor[hit.index], tangent, bitangent, scene.geom.plane_anchor_uv[hit.index])
        duv_dx, duv_dy = plane_uv_derivatives(dpdx, dpdy, tangent, bitangent)
    else:
        center = scene.geom.sphere_center[hit.index]
        uv = sphere_uv(p, center)
        duv_dx, duv_dy = sphere_uv_jacobian(p, center, scene.geom.sphere_radius[hit.index], dpdx, dpdy)
    return uv, sample_texture(scene.textures, mat.texture, uv, duv_dx, duv_dy, mat.texture_filter, mat.texture_wrap)


@wp.func(inline=True)
def surface_at(scene: SceneW, cam: CameraW, hit: HitW, ray: RayW, p: wp.vec3, xy: wp.vec2, width: float):
    """The surface `ray` meets at `hit` (not a miss), at its `trace.hit_point` p: two-sided normals,
    checker cell, the footprint of its sample (`hit_footprint`), texture -- filtered over a primary
    hit's sample (`width` pixels wide) as the rasterizer does (`pixel_footprint`), over the
    footprint otherwise."""
    surf = SurfaceW()
    d = ray.direction
    surf.p = p
    surf.offset = ray_offset(scene.geom, hit, p)
    surf.geo = hit.normal
    surf.normal = shading_normal(scene.mesh, hit)
    surf.entering = int(wp.dot(d, surf.geo) < 0.0)
    if surf.entering == 0:
        surf.geo = -surf.geo
        surf.normal = -surf.normal
    surf.view = -d
    base = scene.materials[hit.material]
    eta, beyond = crossing(scene.geom, scene.materials, ray.media, hit, surf.entering, d, p, surf.offset,
                           scene.probe_coincident)
    surf.eta = eta
    surf.beyond = beyond
    surf.cell = int(0)
    if base.checker_size > 0.0:
        surf.cell = checker_cell(surf.p, surf.geo, base.checker_size)
    surf.mat = surface_material(base, surf.cell)
    surf.uv = wp.vec2(0.0)
    surf.texel = wp.vec3(0.0)
    dpdx, dpdy = hit_footprint(ray, hit, surf.geo)
    surf.dpdx = dpdx
    surf.dpdy = dpdy
    if surf.mat.texture >= 0:
        if ray.kind == PRIMARY:
            dpdx, dpdy = pixel_footprint(cam, xy[0], xy[1], width, p, surf.geo)
        uv, texel = hit_texel(scene, surf.mat, hit, surf.p, dpdx, dpdy)
        surf.uv = uv
        surf.texel = texel
        surf.mat = textured_material(surf.mat, surf.mat.texture_target, surf.texel)
    return surf


@wp.func
def fresnel_split(d: wp.vec3, surf: SurfaceW, mode: int):
    """The Fresnel split of a ray arriving along `d` (see the module doc)."""
    split = SplitW()
    eta = surf.eta
    refracts, t_dir = refract(d, surf.normal, eta)
    split.refracts = refracts
    split.t_dir = t_dir
    split.fresnel = 0.0
    split.f_r = 1.0
    split.f_t = 1.0
    split.tir_share = 0.0
    if mode != FRESNEL_NONE:  # at every surface: kr F weights an opaque mirror's reflection too
        split.fresnel = fresnel(mode, wp.clamp(-wp.dot(d, surf.normal), 0.0, 1.0), eta)
        split.f_r = split.fresnel
        split.f_t = 1.0 - split.fresnel
    if split.refracts == 0:  # total internal reflection: the refracted share goes to the reflected ray
        split.tir_share = split.f_t  # (F is exactly 1 here: `refract` and `fresnel` test eta sin_i > 1 alike)
        split.fresnel = 1.0
        split.f_r = 1.0
        split.f_t = 0.0
    return split


@wp.func
def skip_object(geom: SceneGeomW, hit: HitW, direction: wp.vec3):
    """The object a ray leaving this hit in `direction` cannot meet again (-1: none): `leaving_skip`
    (hit.normal is a sphere's outward normal), the rule the rasterizer's shadow rays follow too."""
    return leaving_skip(hit.kind, hit.object, hit.normal, direction)


@wp.func
def child_differentials(parent: RayW, surf: SurfaceW, direction: wp.vec3, kind: int):
    """The differentials of the ray a hit spawns in unit `direction`: its origins spread over the
    sample's footprint there, its directions the parent's reflected (dr = dd - 2 (dd.N) N) or
    refracted (`optics.refracted_differential`) about the shading normal, its change ignored."""
    diff = DifferentialsW()
    diff.dpdx = surf.dpdx
    diff.dpdy = surf.dpdy
    d = parent.diff
    if kind == REFLECTED:
        diff.dddx = reflect(d.dddx, surf.normal)
        diff.dddy = reflect(d.dddy, surf.normal)
    else:
        diff.dddx = refracted_differential(d.dddx, parent.direction, surf.normal, direction, surf.eta)
        diff.dddy = refracted_differential(d.dddy, parent.direction, surf.normal, direction, surf.eta)
    return diff


@wp.func
def child_ray(geom: SceneGeomW, parent: RayW, node: int, hit: HitW, surf: SurfaceW, direction: wp.vec3,
              weight: wp.vec3, kind: int, media: MediaW):
    """The ray a hit spawns in `direction`, inside `media`: started `surf.offset` off the surface on
    the side it leaves to."""
    return new_ray(surf.p, spawn_origin(surf.p, surf.geo, direction, surf.offset), direction, weight,
                   child_differentials(parent, surf, direction, kind), parent.depth + 1, node, kind, media,
                   skip_object(geom, hit, direction))

"""The Whitted ray tracer's kernel: one thread per sample walks its ray tree depth first.

Warp has no recursion, so the tree is walked with an explicit stack of pending rays (origin,
direction, weight, depth, parent node, kind, medium, object to skip). Depth-first order keeps the
stack within `max_depth` entries: at most one pending sibling per level, plus the two children just
pushed. Each popped ray is one *node*: its hit is lit by the one illumination model (ambient plus,
per light, visibility times `light_term`) and the node adds

    weight * local            (or weight * background where the ray hits nothing)

to the sample. A node at depth k < max_depth spawns a reflected ray with weight
weight * kr * F_r and a refracted ray with weight weight * kt * F_t, where (F_r, F_t) = (1, 1)
without Fresnel weighting (or at opaque surfaces, kt = 0) and (F, 1 - F) with it; total internal
reflection leaves no refracted ray (F_t = 0, F = 1). A ray travelling inside a medium (refracted
into an object, until it refracts out) is multiplied by Beer's exp(-alpha d) over its length d,
alpha being that object's absorption. A child is not traced when its weight is 0, when its depth
would pass `max_depth` (it then contributes black), or -- Hall's adaptive control -- when the largest
channel of its weight before its own absorption is below `threshold`.

Surfaces are two-sided: the geometric and shading normals are flipped to face the incoming ray
(so inside a refracting object they point inwards). A ray hitting the side its geometric normal
points to is *entering* (eta = 1 / ior); from the other side it is *leaving* (eta = ior).
New rays start `epsilon` (scene units, from `compile_scene`) off the surface along the geometric
normal on the side they travel to; a ray leaving a sphere outwards, and every ray leaving a plane,
also skips that object (it cannot meet it again). Shadow rays are cast as the rasterizer casts them:
to lights on the front side of the geometric normal (a light behind it is left to the model's
N.L gating), transparent occluders multiplying by kt when `transparent` is set.

With `record` set, the same walk writes every node into the flat arrays of `TreeW` at the sample's
offset (see `rt_tree.RayTree` for the layout); without it, it counts nodes per sample so that
the recording pass can be allocated exactly.
"""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import LightW, MaterialW, ambient_term, checker_cell, fog_factor, light_term, \
    light_vector, surface_material, textured_material
from ..camera import CameraW, primary_ray
from ..texture.sampling import TexturesW, cone_footprint, pixel_footprint, plane_uv, plane_uv_derivatives, sample_texture, \
    sphere_uv, sphere_uv_derivatives, triangle_uv_derivatives
from .itembuffer import ItemBufferW, hinted_hit
from .optics import FRESNEL_NONE, beer, fresnel, reflect, refract
from ..trace import HIT_NONE, HIT_PLANE, HIT_SPHERE, HIT_TRIANGLE, HitW, SceneGeomW, closest_hit, \
    count_shadow_crossings, light_visibility

wp.set_module_options({"enable_backward": False})

PRIMARY, REFLECTED, REFRACTED = 0, 1, 2
RAY_KINDS = ("primary", "reflection", "refraction")
COUNT_PRIMARY, COUNT_SHADOW, COUNT_REFLECTED, COUNT_REFRACTED = 0, 1, 2, 3
STACK_SIZE = 64  # = scene.view.MAX_DEPTH_LIMIT: a depth-first walk never holds more pending rays
StackVec3 = wp.types.matrix(shape=(STACK_SIZE, 3), dtype=wp.float32)  # one row per pending ray
StackInt = wp.types.matrix(shape=(STACK_SIZE, 5), dtype=wp.int32)  # depth, parent, kind, medium, ignore
StackFloat = wp.types.vector(length=STACK_SIZE, dtype=wp.float32)  # path length from the eye to the ray's origin


@wp.struct
class TraceParamsW:
    """Render settings as the kernel sees them."""

    max_depth: int
    shadows: int
    transparent: int
    specular: int  # lighting.warp_model.SPECULAR_MODELS
    fresnel: int  # rt_optics.FRESNEL_MODES
    threshold: float  # Hall's adaptive control (0: off)
    ambient: wp.vec3
    background: wp.vec3
    far: float  # camera far plane: primary rays end there (as the rasterizer clips)
    fog_mode: int
    fog_color: wp.vec3
    fog_start: float
    fog_end: float
    fog_density: float
    record: int
    count_crossings: int  # record the materials transparent shadow rays cross
    spread: float  # texture footprint: a sample's width per unit path length, 2 tan(fov_y / 2) / rows


@wp.struct
class MeshDataW:
    """Triangle vertices, unit vertex normals (smooth shading), uvs and faces of the compiled scene."""

    vertices: wp.array(dtype=wp.vec3)
    normals: wp.array(dtype=wp.vec3)
    uvs: wp.array(dtype=wp.vec2)
    faces: wp.array2d(dtype=wp.int32)


@wp.struct
class TreeW:
    """Flat per-node outputs of the recording pass (N nodes, P lights); see rt_tree.RayTree."""

    offset: wp.array2d(dtype=wp.int32)  # per sample: index of its first node
    sample: wp.array(dtype=wp.int32)
    parent: wp.array(dtype=wp.int32)
    kind: wp.array(dtype=wp.int32)
    depth: wp.array(dtype=wp.int32)
    material: wp.array(dtype=wp.int32)
    object: wp.array(dtype=wp.int32)
    face: wp.array(dtype=wp.int32)
    cell: wp.array(dtype=wp.int32)
    medium: wp.array(dtype=wp.int32)
    distance: wp.array(dtype=float)
    position: wp.array(dtype=wp.vec3)
    normal: wp.array(dtype=wp.vec3)
    view: wp.array(dtype=wp.vec3)
    local: wp.array(dtype=wp.vec3)
    texel: wp.array(dtype=wp.vec3)  # the texture value the node's material took (textured materials)
    fresnel: wp.array(dtype=float)
    fresnel_r: wp.array(dtype=float)
    fresnel_t: wp.array(dtype=float)
    light_dir: wp.array2d(dtype=wp.vec3)
    light_dist: wp.array2d(dtype=float)
    visibility: wp.array2d(dtype=float)
    crossings: wp.array3d(dtype=wp.int32)  # (node, light, material): transparent crossings of the shadow ray


@wp.func
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
def hit_texel(tex: TexturesW, mat: MaterialW, mesh: MeshDataW, geom: SceneGeomW, cam: CameraW, hit: HitW,
              p: wp.vec3, geo: wp.vec3, d: wp.vec3, xy: wp.vec2, primary: int, path: float, spread: float):
    """The texture value at a hit. uv: interpolated vertex uvs (triangles), the plane's world axes,
    or the sphere's (lon / 2 pi, lat / pi). Footprint: a primary ray's pixel footprint on the tangent
    plane (as the rasterizer's derivatives), a secondary ray's cone of width spread x path length
    from the eye (the pixel cone carried along the path, ignoring curvature)."""
    dpdx = wp.vec3(0.0)
    dpdy = wp.vec3(0.0)
    if primary == 1:
        dpdx, dpdy = pixel_footprint(cam, xy[0], xy[1], p, geo)
    else:
        dpdx, dpdy = cone_footprint(d, geo, spread * path)
    uv = wp.vec2(0.0)
    duv_dx = wp.vec2(0.0)
    duv_dy = wp.vec2(0.0)
    if hit.kind == HIT_TRIANGLE:
        f = hit.index
        i0 = mesh.faces[f, 0]
        i1 = mesh.faces[f, 1]
        i2 = mesh.faces[f, 2]
        uv = hit.u * mesh.uvs[i0] + hit.v * mesh.uvs[i1] + (1.0 - hit.u - hit.v) * mesh.uvs[i2]
        duv_dx, duv_dy = triangle_uv_derivatives(mesh.vertices[i0], mesh.vertices[i1], mesh.vertices[i2],
                                                 mesh.uvs[i0], mesh.uvs[i1], mesh.uvs[i2], dpdx, dpdy)
    elif hit.kind == HIT_PLANE:
        normal = geom.plane_normal[hit.index]
        uv = plane_uv(p, normal)
        duv_dx, duv_dy = plane_uv_derivatives(dpdx, dpdy, normal)
    else:
        center = geom.sphere_center[hit.index]
        uv = sphere_uv(p, center)
        duv_dx, duv_dy = sphere_uv_derivatives(p, center, dpdx, dpdy)
    return sample_texture(tex, mat.texture, uv, duv_dx, duv_dy, mat.texture_filter, mat.texture_wrap)


@wp.func
def skip_object(geom: SceneGeomW, hit: HitW, direction: wp.vec3):
    """The object a ray leaving this hit in `direction` cannot meet again (-1: none): a plane always,
    a sphere when the ray leaves outwards (hit.normal is the sphere's outward normal)."""
    if hit.kind == HIT_PLANE:
        return hit.object
    if hit.kind == HIT_SPHERE and wp.dot(direction, hit.normal) > 0.0:
        return hit.object
    return -1


@wp.func
def spawn_origin(p: wp.vec3, geo_normal: wp.vec3, direction: wp.vec3, epsilon: float):
    """p moved epsilon off the surface, to the side `direction` leaves on."""
    if wp.dot(direction, geo_normal) >= 0.0:
        return p + epsilon * geo_normal
    return p - epsilon * geo_normal


@wp.func
def max3(v: wp.vec3):
    return wp.max(v[0], wp.max(v[1], v[2]))


@wp.kernel
def whitted_kernel(
    row0: int, points: wp.array2d(dtype=wp.vec2), cam: CameraW, geom: SceneGeomW, mesh: MeshDataW,
    lights: wp.array(dtype=LightW), materials: wp.array(dtype=MaterialW), params: TraceParamsW,
    item: ItemBufferW, tree: TreeW, textures: TexturesW,
    color: wp.array2d(dtype=wp.vec3), fog: wp.array2d(dtype=float), node_count: wp.array2d(dtype=wp.int32),
    rays: wp.array2d(dtype=wp.int32), depth_hist: wp.array2d(dtype=wp.int32),
):
    ii, j = wp.tid()
    i = row0 + ii
    xy = points[i, j]
    origin, direction = primary_ray(cam, xy[0], xy[1])
    t_far = (params.far - wp.dot(origin - cam.eye, cam.forward)) / wp.dot(direction, cam.forward)
    base = int(0)
    if params.record == 1:
        base = tree.offset[i, j]
    n_lights = lights.shape[0]

    stack_origin = StackVec3()
    stack_start = StackVec3()  # the surface point a ray leaves (its origin before the epsilon offset)
    stack_dir = StackVec3()
    stack_weight = StackVec3()
    stack_info = StackInt()
    stack_path = StackFloat()
    stack_path[0] = 0.0
    stack_origin[0] = origin
    stack_start[0] = origin
    stack_dir[0] = direction
    stack_weight[0] = wp.vec3(1.0)
    stack_info[0, 0] = 1  # depth
    stack_info[0, 1] = -1  # parent node (local index)
    stack_info[0, 2] = PRIMARY
    stack_info[0, 3] = -1  # medium: material id of the object the ray travels inside, -1 outside
    stack_info[0, 4] = -1  # object to skip
    sp = int(1)
    count = int(0)
    total = wp.vec3(0.0)
    fog_f = float(1.0)

    while sp > 0:
        sp = sp - 1
        o = stack_origin[sp]
        start = stack_start[sp]
        d = stack_dir[sp]
        w = stack_weight[sp]
        depth = stack_info[sp, 0]
        parent = stack_info[sp, 1]
        kind = stack_info[sp, 2]
        medium = stack_info[sp, 3]
        skip = stack_info[sp, 4]
        path = stack_path[sp]
        node = count
        count = count + 1
        wp.atomic_add(depth_hist, i, depth - 1, 1)

        hit = HitW()
        if kind == PRIMARY:
            wp.atomic_add(rays, i, COUNT_PRIMARY, 1)
            if item.use == 1:
                hit = hinted_hit(geom, item, i, j, o, d, t_far)
            else:
                hit = closest_hit(geom, o, d, 0.0, t_far, -1)
        else:
            if kind == REFLECTED:
                wp.atomic_add(rays, i, COUNT_REFLECTED, 1)
            else:
                wp.atomic_add(rays, i, COUNT_REFRACTED, 1)
            hit = closest_hit(geom, o, d, 0.0, wp.inf, skip)
        distance = wp.inf
        if hit.kind != HIT_NONE:
            distance = wp.length(o + hit.t * d - start)  # from the surface, not the offset origin
        if medium >= 0:  # Beer absorption along this ray inside its medium
            w = wp.cw_mul(w, beer(materials[medium].absorption, distance))
        if params.record == 1:
            k = base + node
            tree.sample[k] = i * points.shape[1] + j
            tree.parent[k] = -1
            if parent >= 0:
                tree.parent[k] = base + parent
            tree.kind[k] = kind
            tree.depth[k] = depth
            tree.medium[k] = medium
            tree.distance[k] = distance
            tree.material[k] = hit.material
            tree.object[k] = hit.object
            tree.face[k] = -1
            if hit.kind == HIT_TRIANGLE:
                tree.face[k] = hit.index
        if hit.kind == HIT_NONE:
            total = total + wp.cw_mul(w, params.background)
            if params.record == 1:
                tree.local[base + node] = params.background
            continue

        # The surface, two-sided: both normals face the incoming ray.
        p = o + hit.t * d
        geo = hit.normal
        normal = shading_normal(mesh, hit)
        entering = wp.dot(d, geo) < 0.0
        if not entering:
            geo = -geo
            normal = -normal
        view = -d
        base_mat = materials[hit.material]
        cell = int(0)
        if base_mat.checker_size > 0.0:
            cell = checker_cell(p, geo, base_mat.checker_size)
        mat = surface_material(base_mat, cell)
        texel = wp.vec3(0.0)
        if mat.texture >= 0:
            texel = hit_texel(textures, mat, mesh, geom, cam, hit, p, geo, d, xy, int(kind == PRIMARY),
                              path + hit.t, params.spread)
            mat = textured_material(mat, mat.texture_target, texel)
        if kind == PRIMARY:
            fog_f = fog_factor(params.fog_mode, wp.dot(p - cam.eye, cam.forward), params.fog_start, params.fog_end,
                               params.fog_density)

        # Local illumination: the one model, with a shadow ray per light.
        local = ambient_term(mat, params.ambient)
        for q in range(n_lights):
            l, light_d = light_vector(lights[q], p)
            s = float(1.0)
            if params.shadows == 1 and wp.dot(geo, l) > 0.0:
                wp.atomic_add(rays, i, COUNT_SHADOW, 1)
                s = light_visibility(geom, materials, p + geom.epsilon * geo, l, light_d - geom.epsilon,
                                     skip_object(geom, hit, l), params.transparent)
                if params.count_crossings == 1 and s > 0.0:
                    count_shadow_crossings(geom, materials, p + geom.epsilon * geo, l, light_d - geom.epsilon,
                                           skip_object(geom, hit, l), tree.crossings, base + node, q)
            if s > 0.0:
                local = local + s * light_term(lights[q], mat, params.specular, normal, view, l, light_d)
            if params.record == 1:
                tree.light_dir[base + node, q] = l
                tree.light_dist[base + node, q] = light_d
                tree.visibility[base + node, q] = s
        total = total + wp.cw_mul(w, local)

        # Fresnel split between the reflected and the refracted ray.
        eta = base_mat.ior
        if entering:
            eta = 1.0 / base_mat.ior
        refracts, t_dir = refract(d, normal, eta)
        f_value = float(0.0)
        f_r = float(1.0)
        f_t = float(1.0)
        if base_mat.kt > 0.0:
            if params.fresnel != FRESNEL_NONE:
                f_value = fresnel(params.fresnel, wp.clamp(-wp.dot(d, normal), 0.0, 1.0), eta)
                f_r = f_value
                f_t = 1.0 - f_value
            if refracts == 0:  # total internal reflection
                f_value = 1.0
                f_r = 1.0
                f_t = 0.0
        if params.record == 1:
            k = base + node
            tree.cell[k] = cell
            tree.position[k] = p
            tree.normal[k] = normal
            tree.view[k] = view
            tree.local[k] = local
            tree.texel[k] = texel
            tree.fresnel[k] = f_value
            tree.fresnel_r[k] = f_r
            tree.fresnel_t[k] = f_t

        if depth < params.max_depth:
            # Refracted ray pushed first, so the reflected one is walked first.
            w_t = w * (base_mat.kt * f_t)
            if refracts == 1 and max3(w_t) > 0.0 and max3(w_t) >= params.threshold:
                stack_origin[sp] = spawn_origin(p, geo, t_dir, geom.epsilon)
                stack_start[sp] = p
                stack_dir[sp] = t_dir
                stack_weight[sp] = w_t
                stack_info[sp, 0] = depth + 1
                stack_info[sp, 1] = node
                stack_info[sp, 2] = REFRACTED
                stack_info[sp, 3] = -1
                if entering:
                    stack_info[sp, 3] = hit.material
                stack_info[sp, 4] = skip_object(geom, hit, t_dir)
                stack_path[sp] = path + hit.t
                sp = sp + 1
            w_r = w * (base_mat.kr * f_r)
            if max3(w_r) > 0.0 and max3(w_r) >= params.threshold:
                r_dir = reflect(d, normal)
                stack_origin[sp] = spawn_origin(p, geo, r_dir, geom.epsilon)
                stack_start[sp] = p
                stack_dir[sp] = r_dir
                stack_weight[sp] = w_r
                stack_info[sp, 0] = depth + 1
                stack_info[sp, 1] = node
                stack_info[sp, 2] = REFLECTED
                stack_info[sp, 3] = medium
                stack_info[sp, 4] = skip_object(geom, hit, r_dir)
                stack_path[sp] = path + hit.t
                sp = sp + 1

    fog[i, j] = fog_f
    color[i, j] = fog_f * total + (1.0 - fog_f) * params.fog_color
    node_count[i, j] = count

"""The Whitted ray tracer's kernel: a thread walks each of its samples' ray trees depth first -- a
row of samples per thread on the CPU (a call copies its struct arguments, once a row this way), a
sample per thread on CUDA (`launch.launch_row_loops`).

Warp has no recursion, so the tree is walked with an explicit stack of pending rays (`RayW`).
Depth-first order keeps the stack within `max_depth` entries: at most one pending sibling per
level, plus the two children just pushed. Each popped ray is one *node*: its hit is lit by the one
illumination model (`shade_hit`: ambient plus, per light, visibility times `light_term`) and the
node adds

    weight * local            (or weight * background where the ray hits nothing)

to the sample. A node at depth k < max_depth spawns a reflected ray with weight
weight * (kr F_r + kt T) and a refracted ray with weight weight * kt F_t (`surface.fresnel_split`;
T > 0 only under total internal reflection, where no refracted ray exists).
A ray travelling inside a medium (refracted into an object, until it refracts out) is multiplied
by Beer's exp(-alpha d) over its length d, alpha being that medium's absorption: the innermost of
the transparent objects the ray carries (`nesting`: media nest, glass in water). A child is not
traced when its weight is 0, when its depth would pass `max_depth` (it then contributes black), or
-- Hall's adaptive control -- when the largest channel of its weight before its own absorption is
below `threshold`.

A primary ray's mesh hit comes from the item buffer (`itembuffer.py`: the rasterizer's z-buffer,
the same hit as the BVH's) when the kernel is given one. Shadow rays are cast as the rasterizer
casts them: to lights on the front side of the geometric normal (a light behind it is left to the
model's N.L gating), transparent occluders multiplying by kt when `transparent` is set (up to
`trace.MAX_SHADOW_CROSSINGS` of them: past that a shadow ray counts as blocked and is counted in
COUNT_SHADOW_CUT) -- through the BVH, or through the light buffer's candidate lists (`lightbuffer.py`)
when the scene struct carries one.

With `record` set, the same walk writes every node into the flat arrays of `record.TreeW` at the
sample's offset (see `tree.RayTree` for the layout); without it, it counts nodes per sample so that
the recording pass can be allocated exactly.
"""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import FogW, LightW, MaterialW, ambient_term, fog_blend, light_term, light_vector
from ...vocabulary import MAX_DEPTH_LIMIT
from ..camera import CameraW, line_point
from ..intersect import HIT_NONE, HitW, SceneGeomW, closest_hit
from ..launch import dealt_span
from ..trace import count_shadow_crossings, hit_from, hit_point, normal_at, shadow_ray, spawn_origin
from .itembuffer import ItemBufferW, item_hit
from .lightbuffer import LightBufferW, buffered_visibility
from .medium import primary_medium
from .nesting import MediaW, medium_of
from .optics import beer, reflect
from .record import LightRecW, TreeW, light_arrays, record_light, record_ray, record_surface
from .surface import RayW, SceneW, SurfaceW, child_ray, fresnel_split, new_ray, primary_diff, primary_sample, \
    skip_object, \
    surface_at
from .tree import PRIMARY, REFLECTED, REFRACTED

wp.set_module_options({"enable_backward": False})

COUNT_PRIMARY, COUNT_SHADOW, COUNT_REFLECTED, COUNT_REFRACTED = 0, 1, 2, 3  # columns of TraceOutW.rays
COUNT_SHADOW_CUT = 4  # column of the shadow rays cut past trace.MAX_SHADOW_CROSSINGS (among COUNT_SHADOW's)
COUNT_SHADOW_TESTS = 5  # column of the candidates the light buffer's shadow rays tested (`buffered_visibility`)
COUNT_COLUMNS = 6


@wp.struct
class TraceParamsW:
    """Render settings as the kernel sees them."""

    max_depth: int
    shadows: int
    transparent: int
    specular: int  # vocabulary.SPECULAR_MODELS
    fresnel: int  # vocabulary.FRESNEL_MODES
    threshold: float  # Hall's adaptive control (0: off)
    ambient: wp.vec3
    background: wp.vec3
    far: float  # camera far plane: primary rays end there (as the rasterizer clips)
    fog: FogW
    record: int
    count_crossings: int  # record the materials transparent shadow rays cross
    footprint: float  # a sample's width in pixels (1 / side), what texture filters cover (`surface.surface_at`)
    side: int  # > 0: the regular grid of `side` x `side` samples per pixel; 0: the samples are `points`
    media: MediaW  # the transparent objects around a perspective camera's eye (`medium.camera_media`)
    start_check: int  # 1: each primary ray finds its own media (`medium.primary_medium`), 0: `media` are every ray's


@wp.struct
class TraceOutW:
    """Per-sample outputs (on the sample grid), and per-row ray statistics."""

    color: wp.array2d(dtype=wp.vec3)
    fog: wp.array2d(dtype=float)  # the fog blend of the primary hit (1: none)
    node_count: wp.array2d(dtype=wp.int32)
    rays: wp.array2d(dtype=wp.int32)  # (rows, COUNT_COLUMNS): rays traced per COUNT_* kind, COUNT_SHADOW_CUT/_TESTS
    depth_hist: wp.array2d(dtype=wp.int32)  # (rows, max_depth): rays traced per depth
    nonfinite: wp.array(dtype=wp.int32)  # per thread (`launch.dealt_span`'s slot): samples whose colour is not finite


@wp.func(inline=True)
def trace_ray(geom: SceneGeomW, item: ItemBufferW, out: TraceOutW, ray: RayW, i: int, j: int, t_far: float):
    """The nearest hit of a popped ray (the primary one up to the far plane, through the item buffer
    when it is on), counted in the statistics of row i (a primary ray by `trace_spans`, once a row)."""
    if ray.kind == PRIMARY:
        if item.use == 1:
            return item_hit(geom, item, i, j, ray.origin, ray.direction, t_far)
        return closest_hit(geom, ray.origin, ray.direction, 0.0, t_far, -1)
    wp.atomic_add(out.depth_hist, i, ray.depth - 1, 1)
    if ray.kind == REFLECTED:
        wp.atomic_add(out.rays, i, COUNT_REFLECTED, 1)
    else:
        wp.atomic_add(out.rays, i, COUNT_REFRACTED, 1)
    return closest_hit(geom, ray.origin, ray.direction, 0.0, wp.inf, ray.skip)


@wp.func(inline=True)
def shade_hit(geom: SceneGeomW, lights: wp.array(dtype=LightW), materials: wp.array(dtype=MaterialW),
              buffer: LightBufferW, vertices: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=wp.int32),
              params: TraceParamsW, hit: HitW, surf: SurfaceW, rec: LightRecW, k: int, rays: wp.array2d(dtype=wp.int32),
              i: int):
    """Local illumination at a hit, the one model with a shadow ray per light: ka Ia + sum_p s_p
    light_term_p. Records what each light contributed at node k when recording. (Its arguments are
    the few arrays it reads: a CPU call copies them.)"""
    local = ambient_term(surf.mat, params.ambient)
    for q in range(lights.shape[0]):
        l, light_d = light_vector(lights[q], surf.p)
        s = float(1.0)
        if params.shadows == 1 and wp.dot(surf.geo, l) > 0.0:
            wp.atomic_add(rays, i, COUNT_SHADOW, 1)
            origin = spawn_origin(surf.p, surf.geo, l, surf.offset)
            reach = light_d - wp.dot(origin - surf.p, l) - surf.offset  # ends the offset short of the light
            skip = skip_object(geom, hit, l)
            cut = int(0)
            if buffer.use == 1 and buffer.light_cell0[q] >= 0:
                s, cut, tested = buffered_visibility(geom, buffer, vertices, faces, materials, q, lights[q].position,
                                                     origin, l, reach, skip, params.transparent)
                wp.atomic_add(rays, i, COUNT_SHADOW_TESTS, tested)
            else:
                s, cut = shadow_ray(geom, materials, origin, l, reach, skip, params.transparent)
            if cut == 1:
                wp.atomic_add(rays, i, COUNT_SHADOW_CUT, 1)
            if params.count_crossings == 1 and s > 0.0:
                count_shadow_crossings(geom, materials, origin, l, reach, skip, rec.crossings, k, q)
        if s > 0.0:
            local = local + s * light_term(lights[q], surf.mat, params.specular, surf.normal, surf.view, l, light_d)
        if params.record == 1:
            record_light(rec, k, q, l, light_d, s)
    return local


@wp.func(inline=True)
def located(geom: SceneGeomW, hit: HitW, ray: RayW, line: wp.vec3, perspective: int):
    """`hit` (a miss: as it is) and its `trace.hit_point`. An orthographic view's primary hit is seen
    from `line`, its ray's point beside the target (`camera.line_point`, `trace.hit_from`), and a
    sphere's normal taken at the point found (`trace.normal_at`): neither carries the rounding of
    the ray's origin on the eye's plane, however far the eye."""
    if hit.kind == HIT_NONE:
        return hit, wp.vec3(0.0)
    if ray.kind == PRIMARY and perspective == 0:
        found = hit_from(geom, hit, ray.origin, line, ray.direction)
        p = hit_point(geom, found, line, ray.direction)
        found.normal = normal_at(geom, found, p)
        return found, p
    return hit, hit_point(geom, hit, ray.origin, ray.direction)


@wp.func
def worth_tracing(weight: wp.vec3, threshold: float):
    """Whether a child of this weight is traced: not zero, and not under Hall's threshold."""
    largest = wp.max(weight[0], wp.max(weight[1], weight[2]))
    return largest > 0.0 and largest >= threshold


def make_whitted_kernel(stack_size: int):
    """The walk (`trace_spans`) and its kernel for trees whose stack never holds more than `stack_size`
    rays: a depth-first walk to depth D holds at most D (at most one pending sibling per level,
    plus the two children just pushed), and the stack is allocated and cleared per sample, so a
    shallow render should not pay for MAX_DEPTH_LIMIT entries."""

    @wp.func
    def trace_spans(points: wp.array2d(dtype=wp.vec2), cam: CameraW, scene: SceneW, params: TraceParamsW,
                    item: ItemBufferW, tree: TreeW, out: TraceOutW, i: int, j0: int, j1: int, slot: int):
        """Walk the ray tree of every sample (i, j), j in [j0, j1): its colour, fog blend and node
        count into `out`, the non-finite ones counted at out.nonfinite[slot]; the row's primary rays
        by the span starting it. (One call per row on the CPU: a call copies its struct arguments.)"""
        rec = light_arrays(tree)
        nonfinite = int(0)
        for j in range(j0, j1):
            xy, start, direction, near, t_far = primary_sample(points, params.side, cam, params.far, i, j)
            base = int(0)
            if params.record == 1:
                base = tree.offset[i, j]
            origin = start + near * direction
            line = line_point(cam, xy[0], xy[1])
            media = params.media
            if params.start_check == 1:  # its absorption counts from `start` in `media`
                media, start = primary_medium(scene.geom, scene.materials, start, direction, near, params.media,
                                              cam.perspective, scene.probe_coincident)
            diff = primary_diff(cam, direction, near, params.footprint)
            first = new_ray(start, origin, direction, wp.vec3(1.0), diff, 1, -1, PRIMARY, media, -1)
            if wp.static(stack_size > 1):  # (a one-ray stack is the primary ray alone: no array to clear)
                stack = wp.zeros(shape=stack_size, dtype=RayW)
                stack[0] = first
            sp = int(1)
            count = int(0)
            total = wp.vec3(0.0)
            fog_f = float(1.0)

            while sp > 0:
                sp = sp - 1
                ray = first
                if wp.static(stack_size > 1):
                    ray = stack[sp]
                node = count
                count = count + 1
                hit, p = located(scene.geom, trace_ray(scene.geom, item, out, ray, i, j, t_far), ray, line,
                                 cam.perspective)
                distance = wp.inf  # from the surface (not the offset origin); Beer's law and the record need it
                if hit.kind != HIT_NONE:
                    distance = wp.length(p - ray.start)
                w = ray.weight
                medium = medium_of(ray.media)
                if medium >= 0:  # Beer absorption along this ray inside its medium
                    w = wp.cw_mul(w, beer(scene.materials[medium].absorption, distance))
                if params.record == 1:
                    record_ray(tree, base, node, i * out.color.shape[1] + j, ray, hit, distance)
                if hit.kind == HIT_NONE:
                    total = total + wp.cw_mul(w, params.background)
                    if params.record == 1:
                        tree.local[base + node] = params.background
                    continue

                surf = surface_at(scene, cam, hit, ray, p, xy, params.footprint)
                if ray.kind == PRIMARY:
                    fog_f = fog_blend(params.fog, wp.dot(surf.p - cam.eye, cam.forward))
                local = shade_hit(scene.geom, scene.lights, scene.materials, scene.light_buffer, scene.mesh.vertices,
                                  scene.mesh.faces, params, hit, surf, rec, base + node, out.rays, i)
                total = total + wp.cw_mul(w, local)
                if params.record == 0 and ray.depth >= params.max_depth:
                    continue  # a leaf nobody records: no split to compute
                split = fresnel_split(ray.direction, surf, params.fresnel)
                if params.record == 1:
                    record_surface(tree, base + node, surf, local, split)

                if wp.static(stack_size > 1):  # (a one-ray stack is max_depth 1: no children)
                    if ray.depth < params.max_depth:  # refracted child pushed first: the reflected one is walked first
                        w_t = w * (surf.mat.kt * split.f_t)
                        if split.refracts == 1 and worth_tracing(w_t, params.threshold):
                            stack[sp] = child_ray(scene.geom, ray, node, hit, surf, split.t_dir, w_t, REFRACTED,
                                                  surf.beyond)
                            sp = sp + 1
                        w_r = w * (surf.mat.kr * split.f_r + surf.mat.kt * split.tir_share)
                        if worth_tracing(w_r, params.threshold):
                            r_dir = reflect(ray.direction, surf.normal)
                            stack[sp] = child_ray(scene.geom, ray, node, hit, surf, r_dir, w_r, REFLECTED, ray.media)
                            sp = sp + 1

            out.fog[i, j] = fog_f
            color = fog_f * total + (1.0 - fog_f) * params.fog.color
            out.color[i, j] = color
            out.node_count[i, j] = count
            if not wp.isfinite(color):
                nonfinite = nonfinite + 1
        out.nonfinite[slot] = nonfinite
        if j0 == 0:
            out.rays[i, COUNT_PRIMARY] = out.color.shape[1]  # a primary ray per sample, all at depth 1
            out.depth_hist[i, 0] = out.color.shape[1]

    @wp.kernel(module="unique", enable_backward=False)
    def whitted_kernel(row0: int, row_step: int, span: int, points: wp.array2d(dtype=wp.vec2), cam: CameraW,
                       scene: SceneW, params: TraceParamsW, item: ItemBufferW, tree: TreeW, out: TraceOutW):
        """`span` samples of a row per thread (`launch.launch_row_loops`)."""
        i, j0, j1, slot = dealt_span(row0, row_step, span, out.color.shape[1], wp.tid())
        trace_spans(points, cam, scene, params, item, tree, out, i, j0, j1, slot)

    return whitted_kernel


STACK_SIZES = (1, 8, MAX_DEPTH_LIMIT)  # one kernel each, compiled on first use
_whitted_kernels: dict[int, object] = {}


def whitted_kernel(max_depth: int):
    """The ray-tree kernel with the smallest stack that holds a walk to `max_depth`."""
    size = next(size for size in STACK_SIZES if size >= max_depth)
    if size not in _whitted_kernels:
        _whitted_kernels[size] = make_whitted_kernel(size)
    return _whitted_kernels[size]

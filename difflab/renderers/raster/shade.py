"""Rasterizer stages 6-7: light the shading points, then compose every sample's colour.

Stage 6 (`light_points_kernel`), per point and light: direction, distance, shadow-ray visibility, and
the colour from the one illumination model. Stage 7 (`compose_kernel`), per sample: the weighted
colours of its points (gouraud: the vertex colours interpolated, optionally clamped to [0, 1]
first), the texture per fragment under flat / Gouraud, background and fog.

`phong_gbuffer_kernel` is stages 4 and 6 in one pass for the G-buffer under Phong shading (each
sample resolved, then lit as its own point: what `resolve_kernel` then `light_points_kernel` store).

`image_kernel` is stages 4, 6 and 7 fused per sample, with the same functions, for renders that
need only the image: nothing of the G-buffer is stored. Phong's points are its samples, lit there;
flat / Gouraud points are lit on a sample's first use into a cache of the CPU thread (see
`PointCacheW`), so only the points visible samples read are lit, in one pass over the samples.
"""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import (FogW, LightW, MaterialW, ambient_term, fog_blend, light_term, light_vector,
                                   surface_material, target_only, textured_material)
from ...vocabulary import FOG_NONE, PHONG_SHADING
from ..camera import CameraW
from ..launch import dealt_span
from ..texture.sampling import TexturesW, sample_texture
from ..trace import SceneGeomW, light_visibility, point_offset
from .coverage import NO_HIT
from .flat_gouraud import mesh_point
from .resolve import (GBufferW, PointsW, PointW, RasterMeshW, SampleW, ScreenW, load_point, resolve_into,
                      resolve_sample, sample_points, sample_position, sample_uv, sample_weights, sphere_rays)

wp.set_module_options({"enable_backward": False})

GEOMETRY_ONLY = wp.constant(2)  # `phong_gbuffer_kernel`'s record mode of a fit's G-buffer: light geometry, no colours


@wp.struct
class LightingW:
    """What lighting a point needs: the scene's lights, materials, textures and ray geometry, and
    the render settings that change the result."""

    lights: wp.array(dtype=LightW)
    materials: wp.array(dtype=MaterialW)
    textures: TexturesW
    geom: SceneGeomW  # shadow rays
    specular: int
    ambient: wp.vec3
    shadows: int
    transparent: int


@wp.struct
class LitW:
    """Stage 6's outputs per point (N points, P lights)."""

    light_dir: wp.array2d(dtype=wp.vec3)
    light_dist: wp.array2d(dtype=float)
    visibility: wp.array2d(dtype=float)
    color: wp.array(dtype=wp.vec3)
    factor: wp.array(dtype=wp.vec3)  # textures under flat / Gouraud (see `light_point`)
    texel: wp.array(dtype=wp.vec3)  # per sample: the texture value there


@wp.func(inline=True)
def light_sample(point: PointW, lighting: LightingW, q: int):
    """Light q seen from a point: the unit direction L to it, its distance d and the shadow ray's
    visibility s (1 without shadows, or where geo . L <= 0: no shadow ray is cast)."""
    l, d = light_vector(lighting.lights[q], point.p)
    s = float(1.0)
    if lighting.shadows == 1 and wp.dot(point.geo, l) > 0.0:
        geom = lighting.geom
        offset = point_offset(geom, point.p)  # along geo, not the ray: Gouraud's geo is a vertex normal
        s = light_visibility(geom, lighting.materials, point.p + offset * point.geo, l, d - offset, point.ignore,
                             lighting.transparent)
    return l, d, s


@wp.func(inline=True)
def record_geometry(point: PointW, lighting: LightingW, lit: LitW, k: int):
    """Per light, L_p, d_p and s_p (`light_sample`) recorded as point k, and nothing else: a fit's
    G-buffer (`GEOMETRY_ONLY`), whose image model shades the recorded geometry itself."""
    for q in range(lighting.lights.shape[0]):
        l, d, s = light_sample(point, lighting, q)
        lit.light_dir[k, q] = l
        lit.light_dist[k, q] = d
        lit.visibility[k, q] = s


@wp.func(inline=True)
def light_point(point: PointW, lighting: LightingW, textured: int, texel: wp.vec3, lit: LitW, k: int, record: int):
    """ka Ia + sum_p s_p light_term_p at a point. `record`: 0 the colour alone; 1 the colour, and
    L_p, d_p, s_p recorded as point k (`record_geometry` records them alone).

    Textured materials: `textured` = 1 where the texel is known at the point (a sample): it modulates
    its target coefficient. Otherwise (flat, Gouraud points) the colour is lit with the target
    coefficient 0, and the second value returned, the *factor*, is what that coefficient multiplies
    (lit with it 1, the others 0): compose adds texel * factor per sample. Returns (colour, factor)."""
    materials = lighting.materials
    mat = surface_material(materials[point.material], point.cell)
    split = False
    unit = mat
    if mat.texture >= 0:
        if textured == 1:
            mat = textured_material(mat, mat.texture_target, texel)
        else:
            split = True
            unit = target_only(mat, mat.texture_target)
            mat = textured_material(mat, mat.texture_target, wp.vec3(0.0))
    total = ambient_term(mat, lighting.ambient)
    unit_total = ambient_term(unit, lighting.ambient)
    for q in range(lighting.lights.shape[0]):
        l, d, s = light_sample(point, lighting, q)
        if record == 1:
            lit.light_dir[k, q] = l
            lit.light_dist[k, q] = d
            lit.visibility[k, q] = s
        if s > 0.0:
            total = total + s * light_term(lighting.lights[q], mat, lighting.specular, point.normal, point.view, l, d)
            if split:
                unit_total = unit_total + s * light_term(lighting.lights[q], unit, lighting.specular, point.normal,
                                                         point.view, l, d)
    if not split:
        unit_total = wp.vec3(0.0)
    return total, unit_total


@wp.func
def texel_at(lighting: LightingW, mat_id: int, uv: wp.vec2, duv_dx: wp.vec2, duv_dy: wp.vec2):
    """The filtered texel of material `mat_id`'s texture at uv (0 for an untextured material)."""
    mat = lighting.materials[mat_id]
    if mat.texture < 0:
        return wp.vec3(0.0)
    return sample_texture(lighting.textures, mat.texture, uv, duv_dx, duv_dy, mat.texture_filter, mat.texture_wrap)


@wp.func(inline=True)
def finite3(c: wp.vec3):
    """Whether all three channels are finite: c_k * 0 is 0 for finite c_k, NaN for inf or NaN
    (cheaper than three isfinite calls, and no sum to overflow)."""
    return c[0] * 0.0 + c[1] * 0.0 + c[2] * 0.0 == 0.0


@wp.func(inline=True)
def light_into(point: PointW, lighting: LightingW, textured: int, texel: wp.vec3, lit: LitW, k: int):
    """Stage 6 at point k: its colour and texture factor (`light_point`), and per light its
    direction, distance and visibility (the G-buffer's). `lit` is zero when the kernel starts:
    nothing is written for an empty point. Returns the colour. Inlined: with the shadow rays inlined
    (`trace.light_visibility`) the CPU compiler made it a call, which copies `lighting` per point."""
    color, factor = light_point(point, lighting, textured, texel, lit, k, 1)
    lit.color[k] = color
    if textured == 0:  # (else zero, as cleared)
        lit.factor[k] = factor
    return color


@wp.kernel
def light_points_kernel(begin: int, end: int, chunk: int, points: PointsW, lighting: LightingW, lit: LitW):
    """Stage 6 over flat / Gouraud points [begin, end), `chunk` consecutive points per thread."""
    first = begin + wp.tid() * chunk
    for k in range(first, wp.min(first + chunk, end)):
        if points.material[k] >= 0:
            unused = light_into(load_point(points, k), lighting, 0, wp.vec3(0.0), lit, k)


@wp.func(inline=True)
def gbuffer_row(key: wp.array(dtype=wp.int64), partial: wp.array(dtype=wp.int64), tris: ScreenW, mesh: RasterMeshW,
                cam: CameraW, perspective_correct: int, out: GBufferW, samples: PointsW, found: PointsW,
                lighting: LightingW, lit: LitW, record: int, weights: int, i: int, j0: int, j1: int):
    """`phong_gbuffer_kernel`'s samples (i, j), j in [j0, j1): each resolved and lit; returns how many
    have a colour with a NaN or infinite channel. A fit's G-buffer (`GEOMETRY_ONLY`) is not cleared
    (`gbuffer.gbuffer_arrays`): a covered sample's entries are all written, and an uncovered one's
    that held a point in the buffer's last frame (material >= 0 before, `resolve_into`) are zeroed
    here; the others are zero already (new memory is, and every frame leaves them so). In a fit's
    frames of one view that is none: the bench sphere's pass ~3 us of CPU a half slower (a load of
    each uncovered sample's material), against the 3.2 MB memset it had before."""
    bad = int(0)
    for j in range(j0, j1):
        covered, point, uv, duv_dx, duv_dy = resolve_into(key, partial, tris, mesh, lighting.materials, cam,
                                                          perspective_correct, PHONG_SHADING, mesh.vertices.shape[0],
                                                          out, samples, found, weights, i, j)
        if covered:
            s = i * cam.width + j
            texel = wp.vec3(0.0)
            if lit.texel.shape[0] > 0 and lighting.materials[point.material].texture >= 0:  # (else zero, as cleared)
                texel = texel_at(lighting, point.material, uv, duv_dx, duv_dy)
                lit.texel[s] = texel
            if record == GEOMETRY_ONLY:
                record_geometry(point, lighting, lit, s)
            elif not finite3(light_into(point, lighting, 1, texel, lit, s)):
                bad += 1
        elif record == GEOMETRY_ONLY and point.material >= 0:  # a point here in the last frame
            s = i * cam.width + j
            samples.normal[s] = wp.vec3(0.0)
            samples.view[s] = wp.vec3(0.0)
            samples.cell[s] = 0
            if out.uv.shape[0] > 0:
                out.uv[s] = wp.vec2(0.0)
            for q in range(lit.light_dir.shape[1]):
                lit.light_dir[s, q] = wp.vec3(0.0)
                lit.light_dist[s, q] = 0.0
                lit.visibility[s, q] = 0.0
    return bad


@wp.kernel
def phong_gbuffer_kernel(row0: int, row_step: int, span: int, key: wp.array(dtype=wp.int64),
                         partial: wp.array(dtype=wp.int64), tris: ScreenW, mesh: RasterMeshW, cam: CameraW,
                         perspective_correct: int, out: GBufferW, samples: PointsW, found: PointsW,
                         lighting: LightingW, lit: LitW, record: int, nonfinite: wp.array(dtype=wp.int32)):
    """Stages 4 and 6 under Phong shading, `span` samples of a row per thread (`launch.launch_row_loops`):
    each sample resolved (its G-buffer entries, `resolve_into`), then lit as its own shading point, its
    texel sampled there (`light_into`); nonfinite[slot] counts the thread's samples whose colour has a
    NaN or infinite channel (`launch.dealt_span`).
    `record` GEOMETRY_ONLY (a fit's G-buffer, whose skipped fields' arrays are empty: `resolve_into`):
    no colours (none counted; only the light geometry is recorded, `record_geometry`), and no texel
    sampled where the G-buffer keeps none; else 1. The thread's points on analytic spheres are found
    first (`sphere_rays`, into `found`: `samples`, or a fit's scratch); where the
    G-buffer keeps no barycentrics (a fit's) their samples' face weights are not formed, as nothing
    reads them (`sample_weights`: the 256^2 bench sphere's pass 753 -> 694 us of CPU a half; in a
    scene without analytic spheres every sample's are, as before: a Phong mesh's pass kept its speed).
    The row loop (`gbuffer_row`) is written twice, with shadows and without: the compiler then drops
    the inlined shadow rays (`trace.light_visibility`) from the loop of a scene without them, which
    they slowed ~3 % (the bench sphere's fit frame alone, interleaved at load ~3: 592 -> 612 us of
    CPU a band with them in it, 587 without). Without shadows it is written once more for a fit's
    G-buffer, `record` the constant GEOMETRY_ONLY there: the compiler drops the lighting (`light_into`)
    from that loop (the bench sphere's first fits, medians of 60 a process, alternating: 613 -> 605
    and 633 -> 614 us a half; in a slow phase 657 -> 639 and 720 -> 689, 9 of 12 pairs lower; ABBA
    of whole fits: within their noise, render -0.01/+0.02 ms; the module's compile 16 -> 17 s,
    its object 466 -> 589 kB). Its time is its float32 square roots and divisions (a
    profile of first fits: ~40 % of it in `sphere_rays`' chain, most of the rest in the
    normalisations of the sphere's normal and of the light vector), which results bitwise the same
    keep as they are."""
    i, j0, j1, slot = dealt_span(row0, row_step, span, cam.width, wp.tid())
    weights = int(sphere_rays(key, partial, tris, mesh, cam, found, i, j0, j1) == 0 or out.bary.shape[0] > 0)
    if lighting.shadows == 1:
        nonfinite[slot] = gbuffer_row(key, partial, tris, mesh, cam, perspective_correct, out, samples, found,
                                      lighting, lit, record, weights, i, j0, j1)
    elif record == GEOMETRY_ONLY:
        nonfinite[slot] = gbuffer_row(key, partial, tris, mesh, cam, perspective_correct, out, samples, found,
                                      lighting, lit, GEOMETRY_ONLY, weights, i, j0, j1)
    else:
        nonfinite[slot] = gbuffer_row(key, partial, tris, mesh, cam, perspective_correct, out, samples, found,
                                      lighting, lit, record, weights, i, j0, j1)


@wp.struct
class PointCacheW:
    """The flat / Gouraud shading points `render` lights on first use, one cache per CPU thread:
    point k's colour and texture factor (as `light_point` gives them) hold for this frame where
    stamp[k] == frame (a number no other frame of the compiled scene has)."""

    color: wp.array(dtype=wp.vec3)
    factor: wp.array(dtype=wp.vec3)
    stamp: wp.array(dtype=wp.int32)
    frame: int


@wp.func(inline=True)
def cache_point(cache: PointCacheW, mesh: RasterMeshW, cam: CameraW, shading: int, lighting: LightingW, k: int):
    """Stages 5 and 6 for flat / Gouraud point k into `cache`, unless this frame lit it there."""
    if cache.stamp[k] != cache.frame:
        color, factor = light_point(mesh_point(mesh, lighting.materials, cam, shading, k), lighting, 0, wp.vec3(0.0),
                                    LitW(), k, 0)
        cache.color[k] = color
        cache.factor[k] = factor
        cache.stamp[k] = cache.frame


@wp.kernel
def light_mesh_points_kernel(begin: int, end: int, chunk: int, mesh: RasterMeshW, cam: CameraW, shading: int,
                             lighting: LightingW, cache: PointCacheW):
    """Every flat / Gouraud point [begin, end) into `cache` before the image is formed (CUDA, where
    the image kernel's threads would share one cache)."""
    first = begin + wp.tid() * chunk
    for k in range(first, wp.min(first + chunk, end)):
        cache_point(cache, mesh, cam, shading, lighting, k)


@wp.func(inline=True)
def clamp01(c: wp.vec3):
    return wp.vec3(wp.clamp(c[0], 0.0, 1.0), wp.clamp(c[1], 0.0, 1.0), wp.clamp(c[2], 0.0, 1.0))


@wp.func(inline=True)
def blend_points(values: wp.array(dtype=wp.vec3), index: wp.vec3i, w: wp.vec3, clamp_colors: int):
    """sum_k w_k values[index_k], each value clamped to [0, 1] first when asked (OpenGL)."""
    out = wp.vec3(0.0)
    for k in range(3):
        c = values[index[k]]
        if clamp_colors == 1:
            c = clamp01(c)
        out = out + w[k] * c
    return out


@wp.func(inline=True)
def fragment_color(color: wp.array(dtype=wp.vec3), factor: wp.array(dtype=wp.vec3), index: wp.vec3i, w: wp.vec3,
                   clamp_colors: int, texel: wp.vec3, per_fragment: int):
    """A sample's colour from its points' colours and texture factors: sum_k w_k colour_k, plus
    texel * sum_k w_k factor_k for a textured material under flat / Gouraud shading (`per_fragment`)."""
    out = blend_points(color, index, w, clamp_colors)
    if per_fragment == 1:
        out = out + wp.cw_mul(texel, blend_points(factor, index, w, clamp_colors))
    return out


@wp.func(inline=True)
def fogged(fog: FogW, color: wp.vec3, z: float):
    """`color` at eye distance z blended toward the fog colour, f C + (1 - f) C_fog (`fog_blend`);
    without fog, `color` as it is."""
    if fog.mode == FOG_NONE:
        return color
    f = fog_blend(fog, z)
    return f * color + (1.0 - f) * fog.color


@wp.func
def compose_into(samples: PointsW, uv: wp.array(dtype=wp.vec2), depth: wp.array(dtype=float),
                 point_index: wp.array(dtype=wp.vec3i), point_weight: wp.array(dtype=wp.vec3), lit: LitW,
                 lighting: LightingW, clamp_colors: int, per_fragment: int, background: wp.vec3, fog: FogW,
                 image: wp.array(dtype=wp.vec3), s: int):
    """Stage 7 from the G-buffer at sample s: its colour, then fog."""
    mat_id = samples.material[s]
    if mat_id < 0:
        image[s] = background
        return
    textured = int(per_fragment == 1 and lighting.materials[mat_id].texture >= 0)
    texel = wp.vec3(0.0)
    if textured == 1:
        texel = texel_at(lighting, mat_id, uv[s], samples.duv_dx[s], samples.duv_dy[s])
        lit.texel[s] = texel
    image[s] = fogged(fog, fragment_color(lit.color, lit.factor, point_index[s], point_weight[s], clamp_colors, texel,
                                          textured), depth[s])


@wp.kernel
def compose_kernel(row0: int, row_step: int, span: int, width: int, samples: PointsW, uv: wp.array(dtype=wp.vec2),
                   depth: wp.array(dtype=float), point_index: wp.array(dtype=wp.vec3i),
                   point_weight: wp.array(dtype=wp.vec3), lit: LitW, lighting: LightingW, clamp_colors: int,
                   per_fragment: int, background: wp.vec3, fog: FogW, image: wp.array(dtype=wp.vec3)):
    """Stage 7, `span` samples of a row per thread (`launch.launch_row_loops`)."""
    i, j0, j1, unused = dealt_span(row0, row_step, span, width, wp.tid())
    for j in range(j0, j1):
        compose_into(samples, uv, depth, point_index, point_weight, lit, lighting, clamp_colors, per_fragment,
                     background, fog, image, i * width + j)


@wp.func(inline=True)
def image_sample(key: wp.int64, tris: ScreenW, mesh: RasterMeshW, cam: CameraW, lighting: LightingW,
                 cache: PointCacheW, perspective_correct: int, shading: int, clamp_colors: int, fog: FogW, i: int,
                 j: int, s: int):
    """The colour of covered sample (i, j) (index s) as `compose_kernel` gives it from the G-buffer.
    Under flat / Gouraud shading its points are lit into `cache` on first use."""
    sample = SampleW()
    p = wp.vec3(0.0)
    if shading == PHONG_SHADING:  # the whole surface point, lit here
        sample = resolve_sample(key, tris, mesh, lighting.materials, cam, perspective_correct, shading, i, j, PointsW(),
                                1)
        p = sample.point.p
    else:  # the weights of the face's points, and the point only where fog needs its depth
        sample = sample_weights(key, tris, perspective_correct, i, j, mesh, 1)
        if fog.mode != FOG_NONE:
            p = sample_position(sample, mesh)
    mat_id = mesh.face_material[sample.face]
    texel = wp.vec3(0.0)
    textured = int(lighting.materials[mat_id].texture >= 0)
    if textured == 1:
        uv, duv_dx, duv_dy = sample_uv(sample, tris, mesh, cam, perspective_correct, i, j)
        texel = texel_at(lighting, mat_id, uv, duv_dx, duv_dy)
    out = wp.vec3(0.0)
    if shading == PHONG_SHADING:
        out, unused = light_point(sample.point, lighting, 1, texel, LitW(), 0, 0)
    else:
        index, weight = sample_points(sample, mesh, shading, s, mesh.vertices.shape[0])
        for c in range(3):
            cache_point(cache, mesh, cam, shading, lighting, index[c])
        out = fragment_color(cache.color, cache.factor, index, weight, clamp_colors, texel, textured)
    return fogged(fog, out, wp.dot(p - cam.eye, cam.forward))


@wp.func(inline=True)
def image_row(key: wp.array(dtype=wp.int64), tris: ScreenW, mesh: RasterMeshW, cam: CameraW, lighting: LightingW,
              cache: PointCacheW, perspective_correct: int, shading: int, clamp_colors: int, paint_background: int,
              background: wp.vec3, fog: FogW, image: wp.array(dtype=wp.vec3), i: int, j0: int, j1: int):
    """`image_kernel`'s samples (i, j), j in [j0, j1); returns how many have a NaN or infinite channel."""
    bad = int(0)
    for j in range(j0, j1):
        s = i * cam.width + j
        k = key[s]
        if k == NO_HIT:
            if paint_background == 1:
                image[s] = background
        else:
            key[s] = NO_HIT
            c = image_sample(k, tris, mesh, cam, lighting, cache, perspective_correct, shading, clamp_colors, fog, i,
                             j, s)
            image[s] = c
            if not finite3(c):
                bad += 1
    return bad


@wp.kernel
def image_kernel(row0: int, row_step: int, span: int, key: wp.array(dtype=wp.int64), tris: ScreenW,
                 mesh: RasterMeshW, cam: CameraW, lighting: LightingW, cache: PointCacheW, perspective_correct: int,
                 shading: int, clamp_colors: int, paint_background: int, background: wp.vec3, fog: FogW,
                 image: wp.array(dtype=wp.vec3), nonfinite: wp.array(dtype=wp.int32)):
    """Stages 4, 6 (Phong; flat / Gouraud points on first use) and 7 fused, `span` samples of a row
    per thread (`launch.launch_band`: on the CPU a row, the kernel's arguments read once per row):
    the image `compose_kernel` gives from the G-buffer, without storing it; uncovered samples get
    `background` unless `paint_background` is 0 (a zeroed image, black background). Each key read
    is reset to NO_HIT (the next frame's z-buffer starts cleared); nonfinite[slot] counts the
    thread's samples with a NaN or infinite channel (`launch.dealt_span`). The row loop
    (`image_row`) is written twice, with shadows and without, as `phong_gbuffer_kernel`'s (the bench
    sphere's render alone, interleaved at loads 3-4: its kernels' CPU +2 % with the inlined shadow
    rays in its one loop, -3 % with the loop written twice)."""
    i, j0, j1, slot = dealt_span(row0, row_step, span, cam.width, wp.tid())
    if lighting.shadows == 1:
        nonfinite[slot] = image_row(key, tris, mesh, cam, lighting, cache, perspective_correct, shading, clamp_colors,
                                    paint_background, background, fog, image, i, j0, j1)
    else:
        nonfinite[slot] = image_row(key, tris, mesh, cam, lighting, cache, perspective_correct, shading, clamp_colors,
                                    paint_background, background, fog, image, i, j0, j1)

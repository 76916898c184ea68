"""Rasterizer stages 6-7: light the shading points, then compose every sample's colour.

Stage 6 (`light_points_kernel`), per point and light: direction, distance, shadow-ray visibility, and
the colour from the one illumination model. Stage 7 (`compose_kernel`), per sample: the weighted
colours of its points (gouraud: the vertex colours interpolated, optionally clamped to [0, 1]
first), the texture per fragment under flat / Gouraud, background and fog.
"""

from __future__ import annotations

from ..._warp import wp

from ...lighting.warp_model import (FogW, LightW, MaterialW, ambient_term, fog_blend, light_term, light_vector,
                                   surface_material, target_only, textured_material)
from ..texture.sampling import TexturesW, sample_texture
from ..trace import SceneGeomW, light_visibility
from .resolve import PointsW

wp.set_module_options({"enable_backward": False})

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
                   color: wp.array(dtype=wp.vec3), clamp_colors: int, background: wp.vec3, fog: FogW,
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
    f = fog_blend(fog, depth[s])
    image[s] = f * out + (1.0 - f) * fog.color

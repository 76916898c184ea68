"""The illumination model, Warp half. Every Warp kernel in difflab lights surfaces with these functions.

For a surface point with unit normal N, unit direction to the viewer V, and per light p the unit
direction to the light L_p, its distance d_p and visibility s_p in [0, 1]:

    I = ka * Ia + sum_p  s_p * att_p * spot_p * Ip * (kd * max(N.L_p, 0) + ks * S_p)

    att_p  = 1 / (kc + kl d_p + kq d_p^2)               (1 for directional lights)
    spot_p = max(-L_p.D, 0)^exponent inside the cone, 0 outside (1 for other lights)
    S_p    = max(R.V, 0)^n,  R = 2 N (N.L) - L          ("phong")
           = max(N.H, 0)^n,  H = normalize(L + V)       ("blinn")
           = F(V.H) D(N.H) / (4 N.V)                     ("torrance": Schlick F with f0, Beckmann D with m)
    S_p = 0 where N.L_p <= 0.

`jax_model.py` beside this file implements the same functions under the same names; a parity test
holds them equal. The sum over lights is written by each kernel, because the visibility s_p comes
from its own shadow rays: a kernel computes `ambient_term` + sum of `visibility * light_term`.
"""

from __future__ import annotations

import math

import numpy as np
from .._warp import wp
# The ids kernels switch on, from the one vocabulary (SPECULAR_MODELS, FOG_NONE and the TEXTURE_*_IDS
# tables are also imported from here by the renderers and the fit).
from ..vocabulary import (BECKMANN_MIN_COS, BLINN, DIRECTIONAL, FOG_EXP, FOG_EXP2, FOG_LINEAR, FOG_MODES, FOG_NONE,
                          LIGHT_TYPES, PHONG, SPECULAR_MODELS, SPOT, TARGET_KA, TARGET_KD, TEXTURE_FILTER_IDS,
                          TEXTURE_TARGET_IDS, TEXTURE_WRAP_IDS)


@wp.struct
class LightW:
    """One light. kind: POINT / DIRECTIONAL / SPOT. direction: unit, the way the light travels."""

    kind: int
    position: wp.vec3
    direction: wp.vec3
    intensity: wp.vec3
    attenuation: wp.vec3  # (kc, kl, kq)
    cos_cutoff: float  # cosine of the spot cone's half-angle
    exponent: float  # spot exponent


@wp.struct
class MaterialW:
    """One material: the local model's coefficients and the ray tracer's kr, kt, ior, absorption."""

    ka: wp.vec3
    kd: wp.vec3
    ks: wp.vec3
    n: float  # Phong / Blinn exponent
    m: float  # Beckmann roughness (torrance)
    f0: float  # Schlick reflectance at normal incidence (torrance)
    kr: float
    kt: float
    ior: float
    absorption: wp.vec3  # Beer coefficient alpha, per unit length
    checker_size: float  # 0: no checker
    ka2: wp.vec3
    kd2: wp.vec3
    texture: int  # index into the scene's textures, -1: none
    texture_filter: int  # TEXTURE_FILTER_IDS
    texture_wrap: int  # TEXTURE_WRAP_IDS
    texture_target: int  # TARGET_KA / TARGET_KD / TARGET_KS: the coefficient the texture modulates


@wp.func
def light_vector(light: LightW, p: wp.vec3):
    """Unit direction from p to the light and the distance to it (inf for directional lights)."""
    if light.kind == DIRECTIONAL:
        return -light.direction, float(wp.inf)
    delta = light.position - p
    return wp.normalize(delta), wp.length(delta)


@wp.func
def light_falloff(light: LightW, l: wp.vec3, d: float):
    """att * spot: 1/(kc + kl d + kq d^2) times the spotlight cone factor (both 1 where absent)."""
    if light.kind == DIRECTIONAL:
        return 1.0
    att = 1.0 / (light.attenuation[0] + light.attenuation[1] * d + light.attenuation[2] * d * d)
    if light.kind == SPOT:
        cos_axis = -wp.dot(l, light.direction)
        if cos_axis < light.cos_cutoff:
            return 0.0
        att = att * wp.pow(wp.max(cos_axis, 0.0), light.exponent)
    return att


@wp.func
def specular_factor(model: int, normal: wp.vec3, v: wp.vec3, l: wp.vec3, n: float, m: float, f0: float):
    """S: the specular lobe of the chosen model; 0 where N.L <= 0."""
    n_dot_l = wp.dot(normal, l)
    if n_dot_l <= 0.0:
        return 0.0
    if model == PHONG:
        r = 2.0 * n_dot_l * normal - l
        return wp.pow(wp.max(wp.dot(r, v), 0.0), n)
    h = wp.normalize(l + v)
    n_dot_h = wp.max(wp.dot(normal, h), 0.0)
    if model == BLINN:
        return wp.pow(n_dot_h, n)
    n_dot_v = wp.dot(normal, v)
    if n_dot_v <= 0.0 or n_dot_h <= BECKMANN_MIN_COS:
        return 0.0
    cos2 = n_dot_h * n_dot_h
    sin2 = wp.length_sq(wp.cross(normal, h))  # not 1 - cos2: that cancels near the peak
    beckmann = wp.exp(-sin2 / (cos2 * m * m)) / (wp.pi * m * m * cos2 * cos2)
    fresnel = f0 + (1.0 - f0) * wp.pow(1.0 - wp.max(wp.dot(v, h), 0.0), 5.0)
    return fresnel * beckmann / (4.0 * n_dot_v)


@wp.func
def light_term(light: LightW, mat: MaterialW, model: int, normal: wp.vec3, v: wp.vec3, l: wp.vec3, d: float):
    """att * spot * Ip * (kd max(N.L, 0) + ks S), per channel, for an unshadowed light."""
    diffuse = wp.max(wp.dot(normal, l), 0.0)
    spec = specular_factor(model, normal, v, l, mat.n, mat.m, mat.f0)
    return light_falloff(light, l, d) * wp.cw_mul(light.intensity, mat.kd * diffuse + mat.ks * spec)


@wp.func
def ambient_term(mat: MaterialW, ambient: wp.vec3):
    """ka * Ia, per channel."""
    return wp.cw_mul(mat.ka, ambient)


@wp.func
def checker_cell(p: wp.vec3, geo_normal: wp.vec3, size: float):
    """Checker cell (0 or 1) of p: (floor(a/size) + floor(b/size)) mod 2 over the two world axes
    other than the normal's dominant one (x and z for a floor): world position, not the image uv."""
    ax = wp.abs(geo_normal[0])
    ay = wp.abs(geo_normal[1])
    az = wp.abs(geo_normal[2])
    a = p[0]
    b = p[2]
    if ax >= ay and ax >= az:
        a = p[1]
    elif az > ay:
        b = p[1]
    cells = int(wp.floor(a / size)) + int(wp.floor(b / size))
    return cells - 2 * (cells // 2)


@wp.func
def surface_material(mat: MaterialW, cell: int):
    """The material at a point: checker cell 1 swaps in ka2 / kd2."""
    out = mat
    if cell == 1:
        out.ka = mat.ka2
        out.kd = mat.kd2
    return out


@wp.func
def textured_material(mat: MaterialW, target: int, value: wp.vec3):
    """The material with coefficient `target` (TARGET_KA / KD / KS) modulated by a texel:
    k -> k * value per channel (OpenGL's GL_MODULATE; with k = 1 the texel is the coefficient)."""
    out = mat
    if target == TARGET_KA:
        out.ka = wp.cw_mul(mat.ka, value)
    elif target == TARGET_KD:
        out.kd = wp.cw_mul(mat.kd, value)
    else:
        out.ks = wp.cw_mul(mat.ks, value)
    return out


@wp.func
def target_only(mat: MaterialW, target: int):
    """The material with every coefficient 0 but `target`: lit, it gives the factor a texel
    multiplies (the model is linear in ka, kd and ks)."""
    out = mat
    out.ka = wp.vec3(0.0)
    out.kd = wp.vec3(0.0)
    out.ks = wp.vec3(0.0)
    if target == TARGET_KA:
        out.ka = mat.ka
    elif target == TARGET_KD:
        out.kd = mat.kd
    else:
        out.ks = mat.ks
    return out


@wp.func
def fog_factor(mode: int, z: float, start: float, end: float, density: float):
    """OpenGL fog blend f in [0, 1] at eye distance z: linear (end-z)/(end-start), exp e^(-density z),
    exp2 e^(-(density z)^2); the fogged colour is f C + (1 - f) C_fog."""
    f = 1.0
    if mode == FOG_LINEAR:
        f = (end - z) / (end - start)
    elif mode == FOG_EXP:
        f = wp.exp(-density * z)
    elif mode == FOG_EXP2:
        f = wp.exp(-(density * z) * (density * z))
    return wp.clamp(f, 0.0, 1.0)


@wp.struct
class FogW:
    """OpenGL fog as kernels see it: `mode` a FOG_MODES id, `color` linear RGB, `start` / `end` eye
    distances (scene units, linear fog), `density` per scene unit (exp, exp2)."""

    mode: int
    color: wp.vec3
    start: float
    end: float
    density: float


@wp.func
def fog_blend(fog: FogW, z: float):
    """`fog_factor` of `fog` at eye distance z."""
    return fog_factor(fog.mode, z, fog.start, fog.end, fog.density)


def fog_struct(fog) -> FogW:
    """A `FogW` from a scene `Fog` (or None: no fog), through `fog_params`."""
    out = FogW()
    mode, color, out.start, out.end, out.density = fog_params(fog)
    out.mode, out.color = mode, wp.vec3(*color)
    return out


def light_struct(light) -> LightW:
    """A `LightW` from a scene `Light`."""
    out = LightW()
    out.kind = LIGHT_TYPES[light.type]
    out.position = wp.vec3(*(light.position or (0.0, 0.0, 0.0)))
    out.direction = wp.vec3(*(light.direction or (0.0, -1.0, 0.0)))
    out.intensity = wp.vec3(*light.intensity)
    out.attenuation = wp.vec3(*light.attenuation)
    out.cos_cutoff = float(math.cos(math.radians(light.cutoff_deg))) if light.type == "spot" else -2.0
    out.exponent = float(light.exponent)
    return out


def material_struct(mat, texture_id: int = -1) -> MaterialW:
    """A `MaterialW` from a scene `Material`; `texture_id` indexes the scene's textures (the
    material's texture is used only when it has one and texture_id >= 0)."""
    out = MaterialW()
    out.ka, out.kd, out.ks = wp.vec3(*mat.ka), wp.vec3(*mat.kd), wp.vec3(*mat.ks)
    out.n, out.m, out.f0 = float(mat.n), float(mat.m), float(mat.f0)
    out.kr, out.kt, out.ior = float(mat.kr), float(mat.kt), float(mat.ior)
    out.absorption = wp.vec3(*mat.absorption)
    checker = mat.checker
    out.checker_size = float(checker.size) if checker is not None else 0.0
    out.ka2 = wp.vec3(*(checker.ka2 if checker is not None else mat.ka))
    out.kd2 = wp.vec3(*(checker.kd2 if checker is not None else mat.kd))
    out.texture = int(texture_id) if getattr(mat, "texture", None) is not None else -1
    out.texture_filter = TEXTURE_FILTER_IDS[getattr(mat, "filter", "bilinear")]
    out.texture_wrap = TEXTURE_WRAP_IDS[getattr(mat, "wrap", "repeat")]
    out.texture_target = TEXTURE_TARGET_IDS[getattr(mat, "texture_target", "kd")]
    return out


def lights_to_warp(lights, device: str) -> wp.array:
    """Scene lights as a Warp array of `LightW` (length 0 allowed)."""
    structs = [light_struct(light) for light in lights]
    return wp.array(structs, dtype=LightW, device=device) if structs else wp.empty(0, dtype=LightW, device=device)


def materials_to_warp(materials, device: str, texture_ids=None) -> wp.array:
    """Scene materials (in order) as a Warp array of `MaterialW`, indexed by material id.
    `texture_ids`: per material its texture's index in the scene's textures (-1 or None: none)."""
    materials = list(materials)
    ids = [-1] * len(materials) if texture_ids is None else [(-1 if t is None else t) for t in texture_ids]
    structs = [material_struct(mat, t) for mat, t in zip(materials, ids)]
    if not structs:
        structs = [MaterialW()]
    return wp.array(structs, dtype=MaterialW, device=device)


def fog_params(fog) -> tuple[int, np.ndarray, float, float, float]:
    """(mode, colour, start, end, density) of a scene `Fog` (or None) for kernels."""
    if fog is None:
        return FOG_NONE, np.zeros(3, np.float32), 0.0, 1.0, 0.0
    return FOG_MODES[fog.mode], np.asarray(fog.color, np.float32), float(fog.start), float(fog.end), float(fog.density)

"""The illumination model, JAX half: the same functions as `warp_model.py`, under the same names.

    I = ka * Ia + sum_p  s_p * att_p * spot_p * Ip * (kd * max(N.L_p, 0) + ks * S_p)

(see `warp_model.py` for the terms). Arrays broadcast NumPy-style; vectors have a trailing axis of
3. Every function has finite values and finite gradients everywhere in the parameter domain: powers
x^n are taken as exp(n log x) only where x > 0 (0^n is 1 for n = 0, else 0, as C's pow), zero-length
vectors normalise to zero, and each `where` keeps NaN out of its untaken branch.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..vocabulary import (BECKMANN_MIN_COS, BLINN, DIRECTIONAL, FOG_EXP, FOG_EXP2, FOG_LINEAR, LIGHT_TYPES, PHONG,
                          SPOT, TARGET_KA, TARGET_KD, TEXTURE_TARGET_IDS, TORRANCE)


class LightsJ(NamedTuple):
    """P lights as arrays: kind (P,), position / direction / intensity / attenuation (P, 3),
    cos_cutoff / exponent (P,). Field names are those of `warp_model.LightW`."""

    kind: jnp.ndarray
    position: jnp.ndarray
    direction: jnp.ndarray
    intensity: jnp.ndarray
    attenuation: jnp.ndarray
    cos_cutoff: jnp.ndarray
    exponent: jnp.ndarray


class MaterialJ(NamedTuple):
    """Local-model coefficients, each broadcastable to the points shaded: ka, kd, ks (..., 3);
    n, m, f0 (...). Field names are those of `warp_model.MaterialW`."""

    ka: jnp.ndarray
    kd: jnp.ndarray
    ks: jnp.ndarray
    n: jnp.ndarray
    m: jnp.ndarray
    f0: jnp.ndarray


def dot(a, b):
    """a . b over the trailing axis (as a chain of adds: see `sum_axis`)."""
    return sum_axis(a * b, -1)


def sum_axis(x, axis: int):
    """x summed over a short axis as a chain of adds; 0 for an empty axis. (XLA's CPU reduction over
    a tiny axis, after a gather, is several times slower than the adds -- most of all in float32.)"""
    parts = [jnp.take(x, i, axis=axis) for i in range(x.shape[axis])]
    if not parts:
        return jnp.zeros(tuple(d for i, d in enumerate(x.shape) if i != axis % x.ndim), x.dtype)
    return sum(parts[1:], parts[0])


def normalize(x):
    """x / |x|, and 0 for a zero vector (as wp.normalize), with finite gradients at 0."""
    sq = dot(x, x)[..., None]
    positive = sq > 0.0
    return x * jnp.where(positive, 1.0 / jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)


def safe_log(x):
    """log x where x > 0, else 0 (the logarithm `power_of` takes)."""
    return jnp.log(jnp.where(x > 0.0, x, 1.0))


def flat_exp(x):
    """exp(x), computed on x flattened and kept apart from what follows: XLA's CPU code evaluates a
    transcendental fused over an array whose last axis is 1 long (per point and light, one light)
    element by element -- several times slower than over the flat array."""
    return jax.lax.optimization_barrier(jnp.exp(x.reshape(-1))).reshape(x.shape)


def power_of(x, log_x, n):
    """x^n for x >= 0 from x and log_x = `safe_log(x)`, with C's pow at 0 (0^0 = 1, 0^n = 0) and
    finite gradients in x and n. (A caller that raises fixed x to many n keeps log_x.)"""
    return jnp.where(x > 0.0, flat_exp(n * log_x), jnp.where(n == 0.0, 1.0, 0.0))


def safe_pow(x, n):
    """x^n for x >= 0 with C's pow at 0 (0^0 = 1, 0^n = 0) and finite gradients in x and n."""
    return power_of(x, safe_log(x), n)


def light_vector(light: LightsJ, p):
    """Unit direction from p to the light and the distance to it (inf for directional lights)."""
    directional = (light.kind == DIRECTIONAL)[..., None]
    delta = light.position - p
    l = jnp.where(directional, -light.direction, normalize(delta))
    d = jnp.where(directional[..., 0], jnp.inf, jnp.sqrt(dot(delta, delta)))
    return l, d


def light_falloff(light: LightsJ, l, d, kinds=None):
    """att * spot: 1/(kc + kl d + kq d^2) times the spotlight cone factor (both 1 where absent).
    `kinds`: the LIGHT_TYPES ids the lights have, when known (a collection of ints): the terms of
    kinds not among them are left out -- the same values, without a spot cone's power per point when
    no light is a spot."""
    has = lambda kind: kinds is None or kind in kinds  # noqa: E731
    directional = light.kind == DIRECTIONAL
    if has(DIRECTIONAL):
        d = jnp.where(directional, 0.0, d)  # keep inf out of the untaken branch
    kc, kl, kq = light.attenuation[..., 0], light.attenuation[..., 1], light.attenuation[..., 2]
    att = 1.0 / (kc + kl * d + kq * d * d)
    if has(SPOT):
        cos_axis = -dot(l, light.direction)
        spot = jnp.where(cos_axis < light.cos_cutoff, 0.0, safe_pow(jnp.maximum(cos_axis, 0.0), light.exponent))
        att = jnp.where(light.kind == SPOT, att * spot, att)
    return jnp.where(directional, 1.0, att) if has(DIRECTIONAL) else att


class LobeGeometry(NamedTuple):
    """What the specular lobe reads from the geometry alone (`lobe_geometry`): cos = max(R.V, 0)
    (Phong) or max(N.H, 0) (Blinn, Torrance) and log_cos = `safe_log(cos)`; for Torrance only (else
    None): valid (N.V > 0 and N.H > BECKMANN_MIN_COS), cos2 = N.H^2 (1 where not valid), sin2 =
    |N x H|^2, n_dot_v (1 where not valid) and schlick = (1 - max(V.H, 0))^5."""

    cos: jnp.ndarray
    log_cos: jnp.ndarray
    valid: jnp.ndarray | None = None
    cos2: jnp.ndarray | None = None
    sin2: jnp.ndarray | None = None
    n_dot_v: jnp.ndarray | None = None
    schlick: jnp.ndarray | None = None


def lobe_geometry(model: int, normal, v, l) -> LobeGeometry:
    """The geometric inputs of the specular lobe of `model` (a Python int) at unit N, V, L."""
    if model == PHONG:
        r = 2.0 * dot(normal, l)[..., None] * normal - l
        cos = jnp.maximum(dot(r, v), 0.0)
        return LobeGeometry(cos, safe_log(cos))
    h = normalize(l + v)
    cos = jnp.maximum(dot(normal, h), 0.0)
    if model == BLINN:
        return LobeGeometry(cos, safe_log(cos))
    n_dot_v = dot(normal, v)
    valid = (n_dot_v > 0.0) & (cos > BECKMANN_MIN_COS)
    axis = jnp.cross(normal, h)
    return LobeGeometry(cos, safe_log(cos), valid=valid, cos2=jnp.where(valid, cos * cos, 1.0),
                        sin2=dot(axis, axis),  # not 1 - cos2: that cancels near the peak
                        n_dot_v=jnp.where(valid, n_dot_v, 1.0), schlick=(1.0 - jnp.maximum(dot(v, h), 0.0)) ** 5)


def lobe(model: int, g: LobeGeometry, n, m, f0):
    """The specular lobe of `model` from its geometry: cos^n (Phong, Blinn), or Torrance-Sparrow's
    F D / (4 N.V) with Beckmann D (roughness m) and Schlick's F (f0)."""
    if model != TORRANCE:
        return power_of(g.cos, g.log_cos, n)
    beckmann = flat_exp(-g.sin2 / (g.cos2 * m * m)) / (math.pi * m * m * g.cos2 * g.cos2)
    fresnel = f0 + (1.0 - f0) * g.schlick
    return jnp.where(g.valid, fresnel * beckmann / (4.0 * g.n_dot_v), 0.0)


def specular_factor(model: int, normal, v, l, n, m, f0):
    """S: the specular lobe of the chosen model (a Python int); 0 where N.L <= 0."""
    return jnp.where(dot(normal, l) > 0.0, lobe(model, lobe_geometry(model, normal, v, l), n, m, f0), 0.0)


def light_term(light: LightsJ, mat: MaterialJ, model: int, normal, v, l, d):
    """att * spot * Ip * (kd max(N.L, 0) + ks S), per channel, for an unshadowed light."""
    diffuse = jnp.maximum(dot(normal, l), 0.0)
    spec = specular_factor(model, normal, v, l, mat.n, mat.m, mat.f0)
    return light_falloff(light, l, d)[..., None] * light.intensity * (
        mat.kd * diffuse[..., None] + mat.ks * spec[..., None]
    )


def ambient_term(mat: MaterialJ, ambient):
    """ka * Ia, per channel."""
    return mat.ka * ambient


def textured_material(mat: MaterialJ, target: int, value) -> MaterialJ:
    """The material with coefficient `target` (TARGET_KA / KD / KS, a Python int) modulated by
    texels `value` (broadcastable to (..., 3)): k -> k * value."""
    name = _target_name(target)
    return mat._replace(**{name: getattr(mat, name) * value})


def target_only(mat: MaterialJ, target: int) -> MaterialJ:
    """The material with every coefficient 0 but `target` (lit: the factor a texel multiplies)."""
    zero = jnp.zeros_like(jnp.asarray(mat.kd))
    name = _target_name(target)
    return mat._replace(**{k: (getattr(mat, k) if k == name else zero) for k in ("ka", "kd", "ks")})


def surface_material(table, material_id, cell) -> MaterialJ:
    """The coefficients at shading points, as `warp_model.surface_material`: material `material_id`
    (int array, >= 0) of a stacked table (fields ka, kd, ks, ka2, kd2 (M, 3); n, m, f0 (M,)), with a
    checker's second cell (cell == 1) taking ka2 / kd2."""
    material_id = jnp.asarray(material_id)
    second = (jnp.asarray(cell) == 1)[..., None]
    row = lambda column: table_row(column, material_id)  # noqa: E731
    return MaterialJ(ka=jnp.where(second, row(table.ka2), row(table.ka)),
                     kd=jnp.where(second, row(table.kd2), row(table.kd)),
                     ks=row(table.ks), n=row(table.n), m=row(table.m), f0=row(table.f0))


SELECT_ROWS = 16  # tables of up to this many rows are read by a chain of selects


def table_row(column, index):
    """column[index] for a table column (M, ...) and an int array index in [0, M): a chain of
    selects when M <= SELECT_ROWS (XLA's CPU gather costs more per point than a few compares:
    ~2x for a whole G-buffer image model), else a gather."""
    if not 0 < column.shape[0] <= SELECT_ROWS:
        return column[index]
    trailing = (1,) * (column.ndim - 1)
    out = jnp.broadcast_to(column[0], index.shape + column.shape[1:])
    for m in range(1, column.shape[0]):
        out = jnp.where((index == m).reshape(index.shape + trailing), column[m], out)
    return out


def textured_surface(table, material_id, cell, texel, targets=None) -> MaterialJ:
    """`surface_material` with each point's texture value `texel` (..., 3) multiplying the
    coefficient its material's texture targets (`table.texture_target`, -1: none); texel None: no
    texture anywhere; `targets`: the TARGET_* ids that can occur (default: all)."""
    mat = surface_material(table, material_id, cell)
    if texel is None:
        return mat
    target = table.texture_target[material_id]
    for t in sorted(set(TEXTURE_TARGET_IDS.values()) if targets is None else targets):
        textured = textured_material(mat, t, texel)
        on = (target == t)[..., None]
        mat = mat._replace(**{k: jnp.where(on, getattr(textured, k), getattr(mat, k)) for k in ("ka", "kd", "ks")})
    return mat


def _target_name(target: int) -> str:
    return "ka" if target == TARGET_KA else "kd" if target == TARGET_KD else "ks"


def fog_factor(mode: int, z, start, end, density):
    """OpenGL fog blend f in [0, 1] at eye distance z (see `warp_model.fog_factor`)."""
    if mode == FOG_LINEAR:
        f = (end - z) / (end - start)
    elif mode == FOG_EXP:
        f = jnp.exp(-density * z)
    elif mode == FOG_EXP2:
        f = jnp.exp(-((density * z) ** 2))
    else:
        f = jnp.ones_like(z)
    return jnp.clip(f, 0.0, 1.0)


class LightGeometry(NamedTuple):
    """Per point and light (..., P), what neither the material nor the light's intensity changes:
    diffuse = s att spot max(N.L, 0), weight = s att spot [N.L > 0] (s: visibility) and the specular
    lobe's geometry. `shade_geometry` turns it into colours for any coefficients and intensities."""

    diffuse: jnp.ndarray
    weight: jnp.ndarray
    lobe: LobeGeometry


def light_geometry(model: int, normal, v, lights: LightsJ, l, d, visibility, kinds=None) -> LightGeometry:
    """The `LightGeometry` of points: normal, v (..., 3); l (..., P, 3), d, visibility (..., P);
    `kinds` as `light_falloff`'s."""
    n_dot_l = dot(normal[..., None, :], l)
    s = visibility * light_falloff(lights, l, d, kinds)
    return LightGeometry(diffuse=s * jnp.maximum(n_dot_l, 0.0), weight=jnp.where(n_dot_l > 0.0, s, 0.0),
                         lobe=lobe_geometry(model, normal[..., None, :], v[..., None, :], l))


def shade_parts(mat: MaterialJ, model: int, geometry: LightGeometry, intensity, ambient):
    """The local model's three parts, each (..., 3): Ia, sum_p Ip diffuse_p and sum_p Ip weight_p S_p
    (S_p under mat's n, m, f0), so that colour = ka Ia + kd (sum_p Ip diffuse_p) + ks (sum_p Ip weight_p
    S_p): the colour is linear in ka, kd and ks. intensity (P, 3)."""
    shape = geometry.diffuse.shape[:-1] + (3,)
    spec = geometry.weight * lobe(model, geometry.lobe, jnp.expand_dims(mat.n, -1), jnp.expand_dims(mat.m, -1),
                                  jnp.expand_dims(mat.f0, -1))
    return (jnp.broadcast_to(ambient, shape), sum_axis(intensity * geometry.diffuse[..., None], -2),
            sum_axis(intensity * spec[..., None], -2))


def shade_geometry(mat: MaterialJ, model: int, geometry: LightGeometry, intensity, ambient):
    """ka Ia + sum_p Ip (kd diffuse_p + ks weight_p S_p): the local model on a `LightGeometry`;
    intensity (P, 3). Returns (..., 3)."""
    return combine_parts(mat, shade_parts(mat, model, geometry, intensity, ambient))


def combine_parts(mat: MaterialJ, parts):
    """ka Ia + kd D + ks S from `shade_parts`' (Ia, D, S)."""
    ambient_part, diffuse, specular = parts
    return mat.ka * ambient_part + mat.kd * diffuse + mat.ks * specular


def shade(mat: MaterialJ, model: int, normal, v, lights: LightsJ, l, d, visibility, ambient):
    """The whole local model at points: ka Ia + sum_p s_p light_term_p.

    Arguments:
        mat: coefficients broadcastable to the points (..., 3) / (...).
        normal, v: (..., 3) unit shading normal and direction to the viewer.
        lights: P lights; l (..., P, 3), d (..., P), visibility (..., P): per-light direction,
            distance and shadow-ray visibility at each point.
        ambient: (3,) Ia.
    Returns:
        (..., 3) linear RGB radiance.
    """
    return shade_geometry(mat, model, light_geometry(model, normal, v, lights, l, d, visibility), lights.intensity,
                          ambient)


def stack_fields(records: list, widths: dict, dtype) -> dict:
    """The fields of N records as column views of one (N, K) array (one numpy build, not one per
    field: a fit's lights and materials ~18 small arrays -> 1): `records[k]` holds record k's values
    in the order of `widths` (name -> 0 for a scalar, else its length), each field (N,) or (N, width)."""
    vector = [width > 0 for width in widths.values()]
    flat = []
    for record in records:
        for value, is_vector in zip(record, vector):
            if is_vector:
                flat.extend(value)
            else:
                flat.append(value)
    columns = sum(max(width, 1) for width in widths.values())
    rows = np.array(flat, np.dtype(dtype)).reshape(len(records), columns)  # (each value rounded once, as by astype)
    out, start = {}, 0
    for name, width in widths.items():
        out[name] = rows[:, start] if width == 0 else rows[:, start:start + width]
        start += max(width, 1)
    return out


LIGHT_FIELDS = {"position": 3, "direction": 3, "intensity": 3, "attenuation": 3, "cos_cutoff": 0, "exponent": 0}


def lights_to_jax(lights, dtype=jnp.float32, *, host: bool = False, records=None) -> LightsJ:
    """Scene lights as a `LightsJ` of arrays (P may be 0), moved to the device in one transfer
    (`host`: numpy arrays, for a caller that moves them with others); `records`: their
    `light_records`, where the caller formed them already."""
    records = light_records(lights) if records is None else records
    fields = stack_fields([values for values, _ in records], LIGHT_FIELDS, dtype)
    kind = np.asarray([kind for _, kind in records], dtype=np.int32).reshape(len(records))
    arrays = LightsJ(kind=kind, **fields)
    return arrays if host else jax.device_put(arrays)


def light_records(lights) -> list:
    """What `lights_to_jax` stacks of each light: (its LIGHT_FIELDS values, its LIGHT_TYPES id) --
    plain Python values, compared with == (`fit.setup.Setup._problem`)."""
    return [((light.position or (0.0, 0.0, 0.0), light.direction or (0.0, -1.0, 0.0), light.intensity,
              light.attenuation, math.cos(math.radians(light.cutoff_deg)) if light.type == "spot" else -2.0,
              light.exponent), LIGHT_TYPES[light.type]) for light in lights]

"""Optics of the ray tree: mirror reflection, Snell refraction, Fresnel weights, Beer absorption.

All directions are unit vectors. `d` is the incoming ray's direction (travelling toward the surface)
and `normal` the shading normal turned to face it (dot(d, normal) <= 0). eta = n1 / n2 is the ratio
of the refractive indices on the incoming and the outgoing side.

    reflect:  r = d - 2 (d.N) N                              (the lecture's R = 2N(N.L) - L, L = -d)
    refract:  cos_i = -d.N,  k = 1 - eta^2 (1 - cos_i^2);  k < 0: total internal reflection,
              else  t = eta d + (eta cos_i - sqrt(k)) N      (Snell: sin_t = eta sin_i)
    Fresnel (unpolarised dielectric, F = reflected fraction; F = 1 under total internal reflection):
      "exact":   F = (r_s^2 + r_p^2) / 2,  r_s = (eta cos_i - cos_t) / (eta cos_i + cos_t),
                                            r_p = (eta cos_t - cos_i) / (eta cos_t + cos_i)
      "schlick": F = R0 + (1 - R0) (1 - c)^5,  R0 = ((1 - eta) / (1 + eta))^2, c = cos_i entering a
                 denser medium (eta <= 1), c = cos_t leaving it (the form that stays right past
                 the critical angle)
      both:      F = 0 exactly at eta = 1 (no interface), where Schlick's form would give (1 - c)^5
    Beer:     exp(-alpha d) per channel, exactly 1 where alpha = 0 (also for d = inf).
"""

from __future__ import annotations

from ..._warp import wp

from ...vocabulary import FRESNEL_EXACT, FRESNEL_SCHLICK

wp.set_module_options({"enable_backward": False})


@wp.func
def reflect(d: wp.vec3, normal: wp.vec3):
    """Mirror direction of d about the normal."""
    return d - 2.0 * wp.dot(d, normal) * normal


@wp.func
def refract(d: wp.vec3, normal: wp.vec3, eta: float):
    """(ok, t): the Snell direction for eta = n1 / n2; ok = 0 under total internal reflection
    (eta sin_i > 1), when t is the zero vector."""
    cos_i = wp.clamp(-wp.dot(d, normal), 0.0, 1.0)
    k = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
    if k < 0.0:
        return 0, wp.vec3(0.0)
    return 1, wp.normalize(eta * d + (eta * cos_i - wp.sqrt(k)) * normal)


@wp.func
def refracted_differential(dd: wp.vec3, d: wp.vec3, normal: wp.vec3, t: wp.vec3, eta: float):
    """How `refract`'s unit t = eta d + (eta cos_i - cos_t) N changes with a change dd of the unit d
    (N unchanged: surface curvature ignored; Igehy 1999): dt = eta dd + (eta - eta^2 cos_i / cos_t)
    dcos_i N, dcos_i = -dd.N, cos_i = -d.N, cos_t = -t.N (kept >= 1e-6 at grazing exits)."""
    cos_i = -wp.dot(d, normal)
    cos_t = wp.max(-wp.dot(t, normal), 1.0e-6)
    return eta * dd - (eta - eta * eta * cos_i / cos_t) * wp.dot(dd, normal) * normal


@wp.func
def fresnel_exact(cos_i: float, eta: float):
    """Unpolarised dielectric reflectance for eta = n1 / n2 (1 under total internal reflection)."""
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    if sin2_t >= 1.0:
        return 1.0
    cos_t = wp.sqrt(1.0 - sin2_t)
    r_s = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_p = (eta * cos_t - cos_i) / (eta * cos_t + cos_i)
    return 0.5 * (r_s * r_s + r_p * r_p)


@wp.func
def fresnel_schlick(cos_i: float, eta: float):
    """Schlick's approximation, with cos_t in place of cos_i when leaving the denser medium."""
    r0 = (1.0 - eta) / (1.0 + eta)
    r0 = r0 * r0
    c = cos_i
    if eta > 1.0:
        sin2_t = eta * eta * (1.0 - cos_i * cos_i)
        if sin2_t >= 1.0:
            return 1.0
        c = wp.sqrt(1.0 - sin2_t)
    return r0 + (1.0 - r0) * wp.pow(1.0 - c, 5.0)


@wp.func
def fresnel(mode: int, cos_i: float, eta: float):
    """F for the chosen mode (FRESNEL_NONE gives 0: the caller then uses the plain kr / kt); exactly
    0 at eta = 1, where there is no interface (Schlick's (1 - c)^5 and the exact form's float32
    rounding, up to ~6e-10, are not)."""
    if eta == 1.0:
        return 0.0
    if mode == FRESNEL_EXACT:
        return fresnel_exact(cos_i, eta)
    if mode == FRESNEL_SCHLICK:
        return fresnel_schlick(cos_i, eta)
    return 0.0


@wp.func
def beer(alpha: wp.vec3, distance: float):
    """exp(-alpha d) per channel; 1 where alpha = 0 (so d = inf in a clear medium stays finite)."""
    out = wp.vec3(1.0)
    for c in range(3):
        if alpha[c] > 0.0:
            out[c] = wp.exp(-alpha[c] * distance)
    return out

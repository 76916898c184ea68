"""What is fitted, and how: parameter names, sizes, and the reparameterisations that keep them valid.

The solver works on unconstrained numbers u; the scene sees values in its own units:

    ka, kd, ks, light intensity   k = softplus(u) - softplus(U_FLOOR)   (>= 0, exactly 0 at the floor)
                      (bounded)   k = sigmoid(u)                        (in [0, 1])
    n (Phong / Blinn exponent), m (Beckmann roughness)   = exp(u)
    f0 (Schlick reflectance)                             = sigmoid(u)

u is clipped to a finite range first, so a coefficient whose best value is 0 stops at 0 (its
gradient vanishes there and the solver stops moving it) instead of walking u to -infinity.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import FitError

COLOR_PARAMS = ("ka", "kd", "ks")
SCALAR_PARAMS = ("n", "m", "f0")
MATERIAL_PARAMS = COLOR_PARAMS + SCALAR_PARAMS
LIGHT_PARAM = re.compile(r"^lights\[(\d+)\]\.intensity$")
U_FLOOR = -20.0  # softplus(-20) = 2e-9: below this a coefficient is 0
U_CEIL = 30.0
LOG_RANGE = (-12.0, 12.0)  # n, m in [6e-6, 1.6e5]
LOGIT_RANGE = 20.0
START_FLOOR = 1e-2  # a coefficient starting at 0 starts here instead (0 is the floor, with no gradient)


@dataclass(frozen=True)
class Param:
    """One fitted quantity. key: its name in `FitResult.params` ("kd", or "red.kd" when several
    materials are fitted, or "lights[0].intensity"); kind: "ka" | "kd" | "ks" | "n" | "m" | "f0" |
    "intensity"; index: material id or light index; size: 3 (RGB) or 1 (grey / scalar);
    transform: "softplus" | "sigmoid" | "exp"."""

    key: str
    kind: str
    index: int
    size: int
    transform: str

    @property
    def rgb(self) -> bool:
        return self.kind in COLOR_PARAMS or self.kind == "intensity"


def softplus_inverse(x):
    return x + np.log(-np.expm1(-x))


def to_value(param: Param, u):
    """Unconstrained u -> value in scene units (JAX, differentiable)."""
    if param.transform == "softplus":
        return jax.nn.softplus(jnp.clip(u, U_FLOOR, U_CEIL)) - jax.nn.softplus(U_FLOOR)
    if param.transform == "sigmoid":
        return jax.nn.sigmoid(jnp.clip(u, -LOGIT_RANGE, LOGIT_RANGE))
    return jnp.exp(jnp.clip(u, *LOG_RANGE))


def to_unconstrained(param: Param, value) -> np.ndarray:
    """Value in scene units -> u (numpy), moved inside the valid range where needed."""
    value = np.asarray(value, np.float64).reshape(param.size)
    if param.transform == "softplus":
        value = np.where(value <= 0.0, START_FLOOR, value)
        return softplus_inverse(value + math.log1p(math.exp(U_FLOOR)))
    if param.transform == "sigmoid":
        value = np.clip(np.where(value <= 0.0, START_FLOOR, value), 1e-6, 1.0 - 1e-6)
        return np.log(value) - np.log1p(-value)
    return np.log(np.clip(value, math.exp(LOG_RANGE[0]) * 10, math.exp(LOG_RANGE[1]) / 10))


def build_layout(scene, materials, params, per_channel=True, bounded=False) -> tuple[Param, ...]:
    """The fitted parameters for `materials` (names) and `params` (names: "kd" for every fitted
    material, "red.kd" for one of them; "intensity" means every light's intensity,
    "lights[i].intensity" one light's). Raises FitError for unknown names."""
    if isinstance(params, str):
        params = tuple(p.strip() for p in params.split(",") if p.strip())
    params = tuple(params)
    if not params:
        raise FitError("params: nothing to fit (give at least one of ka, kd, ks, n, m, f0, intensity)")
    if len(set(params)) != len(params):
        raise FitError(f"params: duplicate names in {list(params)}")
    names = scene.material_names
    qualify = len(materials) > 1
    for name in materials:
        if name not in names:
            raise FitError(f"material: undefined material {name!r} (defined: {', '.join(names) or 'none'})")
    wanted = []  # (material, kind): "kd" for every fitted material, "red.kd" for one
    for p in params:
        head, _, tail = p.rpartition(".")
        if head in materials and tail in MATERIAL_PARAMS:
            wanted.append((head, tail))
        elif p in MATERIAL_PARAMS:
            wanted.extend((name, p) for name in materials)
    layout = []
    for name in materials:
        mat_id = names.index(name)
        for p in MATERIAL_PARAMS:
            if (name, p) not in wanted:
                continue
            key = f"{name}.{p}" if qualify else p
            if p in COLOR_PARAMS:
                layout.append(Param(key, p, mat_id, 3 if per_channel else 1, "sigmoid" if bounded else "softplus"))
            else:
                layout.append(Param(key, p, mat_id, 1, "sigmoid" if p == "f0" else "exp"))
    for p in params:
        head, _, tail = p.rpartition(".")
        if p in MATERIAL_PARAMS or (head in materials and tail in MATERIAL_PARAMS):
            continue
        if p == "intensity":
            indices = range(len(scene.lights))
        elif (match := LIGHT_PARAM.match(p)) is not None:
            indices = [int(match.group(1))]
        else:
            raise FitError(f"params: unknown parameter {p!r}; known: {', '.join(MATERIAL_PARAMS)}, intensity, "
                           "lights[i].intensity")
        for i in indices:
            if i >= len(scene.lights):
                raise FitError(f"params: {p!r}: the scene has {len(scene.lights)} light(s)")
            layout.append(Param(f"lights[{i}].intensity", "intensity", i, 3 if per_channel else 1, "softplus"))
    if not layout:
        raise FitError("params: nothing to fit")
    return tuple(layout)


def scene_value(scene, param: Param) -> np.ndarray:
    """The parameter's current value in the scene (grey: the mean of the RGB triple), shape (size,)."""
    if param.kind == "intensity":
        raw = scene.lights[param.index].intensity
    else:
        raw = getattr(list(scene.materials.values())[param.index], param.kind)
    raw = np.asarray(raw, np.float64).reshape(-1)
    return raw if param.size == raw.size else np.full(param.size, raw.mean())


def initial_values(scene, layout, init=None) -> dict:
    """Starting values in scene units: `init[key]` where given, else the scene's."""
    init = dict(init or {})
    unknown = set(init) - {p.key for p in layout}
    if unknown:
        raise FitError(f"init: not fitted: {sorted(unknown)} (fitted: {[p.key for p in layout]})")
    out = {}
    for p in layout:
        value = np.asarray(init[p.key], np.float64).reshape(-1) if p.key in init else scene_value(scene, p)
        if value.size == 1 and p.size == 3:
            value = np.repeat(value, 3)
        if value.size != p.size or not np.all(np.isfinite(value)) or np.any(value < 0):
            raise FitError(f"init[{p.key!r}]: expected {p.size} finite value(s) >= 0, got {value.tolist()}")
        out[p.key] = value
    return out


def values_from_u(layout, u: dict) -> dict:
    return {p.key: to_value(p, u[p.key]) for p in layout}


def u_from_values(layout, values: dict, dtype) -> dict:
    return {p.key: jnp.asarray(to_unconstrained(p, values[p.key]), dtype) for p in layout}


def apply_values(layout, values: dict, table, lights_per_view):
    """The material table and each view's lights with the fitted values written in."""
    for p in layout:
        if p.kind == "intensity":
            continue
        value = values[p.key]
        field = getattr(table, p.kind)
        if p.kind in COLOR_PARAMS:
            field = field.at[p.index].set(jnp.broadcast_to(value, (3,)))  # a checker's ka2 / kd2 stay
        else:
            field = field.at[p.index].set(value[0])
        table = table._replace(**{p.kind: field})
    out_lights = []
    for lights in lights_per_view:
        intensity = lights.intensity
        for p in layout:
            if p.kind == "intensity":
                intensity = intensity.at[p.index].set(jnp.broadcast_to(values[p.key], (3,)))
        out_lights.append(lights._replace(intensity=intensity))
    return table, tuple(out_lights)


def public_value(param: Param, value) -> float | list:
    """A value as the scene file writes it: an RGB list for colour parameters, else a float."""
    value = np.asarray(value, np.float64).reshape(-1)
    if param.rgb:
        return [float(x) for x in np.broadcast_to(value, (3,))]
    return float(value[0])

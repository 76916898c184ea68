"""What `fit_scene` fits, and how the values reach the ray tree's materials.

The parameters are those of `params.py` (ka, kd, ks, n, m, f0, with its reparameterisations) plus the
ray tracer's kr, kt (sigmoid: in [0, 1]) and absorption (softplus: >= 0, RGB). The solvers see one
flat vector u; `ValueMap` turns it into values (`params.to_value` per transform) and writes them into
the stacked materials with one gather per material field.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..errors import DifflabError, FitError
from .params import COLOR_PARAMS, Param, to_value
from .raytree import TreeMaterials

TREE_PARAMS = ("ka", "kd", "ks", "n", "m", "f0", "kr", "kt", "absorption")
DEFAULT_PARAMS = ("ka", "kd", "ks", "n", "kr", "kt", "absorption")
RGB_KINDS = COLOR_PARAMS + ("absorption",)
TRANSFORMS = {"ka": "softplus", "kd": "softplus", "ks": "softplus", "absorption": "softplus", "n": "exp",
              "m": "exp", "f0": "sigmoid", "kr": "sigmoid", "kt": "sigmoid"}


@dataclass(frozen=True)
class TreeParam(Param):
    """A fitted quantity of `fit_scene` (see `params.Param`); kind may also be "kr", "kt" or
    "absorption" (RGB, like ka / kd / ks)."""

    @property
    def rgb(self) -> bool:
        return self.kind in RGB_KINDS


def _applies(mat, kind: str) -> bool:
    """Whether a generic parameter name covers this material: kr only where kr > 0, kt and the
    absorption only where kt > 0 (the recorded tree has no such rays otherwise)."""
    if kind == "kr":
        return mat.kr > 0
    if kind in ("kt", "absorption"):
        return mat.kt > 0
    return True


def build_tree_layout(scene, materials, params, per_channel=True) -> tuple[TreeParam, ...]:
    """The fitted parameters: "kd" means every fitted material's kd (kr only where kr > 0; kt and
    absorption only where kt > 0), "mirror.kr" one material's. Raises FitError for unknown names and
    for a qualified kr / kt / absorption whose rays the start values do not trace."""
    if isinstance(params, str):
        params = tuple(p.strip() for p in params.split(",") if p.strip())
    params = tuple(params)
    if not params:
        raise FitError(f"params: nothing to fit (give some of {', '.join(TREE_PARAMS)})")
    if len(set(params)) != len(params):
        raise FitError(f"params: duplicate names in {list(params)}")
    wanted = set()
    for p in params:
        head, _, tail = p.rpartition(".")
        if p in TREE_PARAMS:
            wanted.update((name, p) for name in materials if _applies(scene.materials[name], p))
        elif head in materials and tail in TREE_PARAMS:
            mat = scene.materials[head]
            if not _applies(mat, tail):
                weight = "kr" if tail == "kr" else "kt"
                raise FitError(f"params: {p!r}: {head}.{weight} is 0 at the start, so the recorded ray tree has no "
                               f"{'reflected' if weight == 'kr' else 'refracted'} rays from it; start {weight} > 0 "
                               "(scene or init)")
            wanted.add((head, tail))
        elif head and tail in TREE_PARAMS:
            raise FitError(f"params: {p!r}: {head!r} is not among the fitted materials ({', '.join(materials)})")
        else:
            raise FitError(f"params: unknown parameter {p!r}; known: {', '.join(TREE_PARAMS)} (or 'material.name')")
    qualify = len(materials) > 1
    layout = []
    for name in materials:
        index = scene.material_names.index(name)
        for kind in TREE_PARAMS:
            if (name, kind) in wanted:
                size = 3 if kind in RGB_KINDS and per_channel else 1
                layout.append(TreeParam(f"{name}.{kind}" if qualify else kind, kind, index, size, TRANSFORMS[kind]))
    if not layout:
        raise FitError(f"params: nothing to fit in {list(params)} for materials {list(materials)} (kr needs kr > 0 "
                       "at the start, kt and absorption kt > 0)")
    return tuple(layout)


FIELDS = ("ka", "kd", "ks", "n", "m", "f0", "kr", "kt", "absorption")
TRANSFORM_CODES = ("softplus", "sigmoid", "exp")


class ValueMap(eqx.Module):
    """Where the fitted values go, as index arrays (one gather per material field, whatever the
    number of parameters): code (p,) the transform of each entry of the flat parameter vector
    (index into TRANSFORM_CODES); index[field] the entry each element of that material field takes
    (-1: not fitted, the base value stays)."""

    code: jnp.ndarray
    index: dict

    @classmethod
    def build(cls, layout, n_materials: int) -> ValueMap:
        code = np.concatenate([np.full(p.size, TRANSFORM_CODES.index(p.transform)) for p in layout]).astype(np.int32)
        index = {f: np.full((n_materials, 3) if f in RGB_KINDS else (n_materials,), -1, np.int32) for f in FIELDS}
        offset = 0
        for p in layout:
            entries = np.arange(offset, offset + p.size)
            index[p.kind][p.index] = np.broadcast_to(entries, (3,)) if p.kind in RGB_KINDS else entries[0]
            offset += p.size
        return cls(code=jnp.asarray(code), index={f: jnp.asarray(i) for f, i in index.items()})

    def values_of(self, u):
        """The flat unconstrained vector u -> values in scene units (`params.to_value` per transform)."""
        out = jnp.zeros_like(u)
        for code, transform in enumerate(TRANSFORM_CODES):
            out = jnp.where(self.code == code, to_value(Param("", "", 0, 1, transform), u), out)
        return out

    def fill(self, v, mats: TreeMaterials) -> TreeMaterials:
        """The materials with the flat values v written in (a checker's ka2 / kd2 stay)."""
        def put(name, base):
            idx = self.index[name]
            return jnp.where(idx >= 0, v[jnp.maximum(idx, 0)], base)

        table = mats.table._replace(**{f: put(f, getattr(mats.table, f)) for f in ("ka", "kd", "ks", "n", "m", "f0")})
        return mats._replace(table=table, kr=put("kr", mats.kr), kt=put("kt", mats.kt),
                             absorption=put("absorption", mats.absorption))


def flatten(layout, values: dict):
    """key -> value (or unconstrained u) as one vector in layout order."""
    return jnp.concatenate([jnp.broadcast_to(jnp.reshape(jnp.asarray(values[p.key]), (-1,)), (p.size,))
                            for p in layout])


def unflatten(layout, vector) -> dict:
    """One vector back to key -> (size,) arrays."""
    out, offset = {}, 0
    for p in layout:
        out[p.key] = vector[offset:offset + p.size]
        offset += p.size
    return out


def apply_init(scene, materials, init):
    """The scene with the starting values `init` (key -> value, keys "kind" for a single fitted
    material or "name.kind") written into its materials."""
    out = dict(scene.materials)
    for key, value in dict(init or {}).items():
        head, _, kind = str(key).rpartition(".")
        name = head or (materials[0] if len(materials) == 1 else None)
        if kind not in TREE_PARAMS or name not in materials:
            raise FitError(f"init[{key!r}]: expected 'kind' (one fitted material) or 'material.kind' with kind one "
                           f"of {', '.join(TREE_PARAMS)} and material one of {', '.join(materials)}")
        value = np.asarray(value, np.float64).reshape(-1)
        if value.size not in ((1, 3) if kind in RGB_KINDS else (1,)) or not np.all(np.isfinite(value)):
            raise FitError(f"init[{key!r}]: expected a finite number{' or RGB triple' if kind in RGB_KINDS else ''}, "
                           f"got {value.tolist()}")
        new = tuple(np.broadcast_to(value, (3,)).tolist()) if kind in RGB_KINDS else float(value[0])
        try:
            out[name] = dataclasses.replace(out[name], **{kind: new})  # validated again: SceneError names it
        except DifflabError as exc:
            raise FitError(f"init[{key!r}]: {exc}") from None
    return dataclasses.replace(scene, materials=out)

"""The one material table of the fits: every fittable field of every material, stacked by id."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..lighting.jax_model import stack_fields
from ..lighting.warp_model import TEXTURE_TARGET_IDS


FIELDS = {"ka": 3, "kd": 3, "ks": 3, "n": 0, "m": 0, "f0": 0, "ka2": 3, "kd2": 3, "kr": 0, "kt": 0, "absorption": 3}


def _field(mat, name: str):
    """A material's value of a `MaterialTable` field: ka2 / kd2 the checker's second cell, or the
    material's own ka / kd without a checker."""
    if name in ("ka2", "kd2"):
        return getattr(mat.checker, name) if mat.checker is not None else getattr(mat, name[:2])
    return getattr(mat, name)


class MaterialTable(NamedTuple):
    """M materials stacked by material id (a Scene's `materials.values()` order).

    ka, ka2, kd, kd2, ks (M, 3); n, m, f0, kr, kt (M,); absorption (M, 3) per unit length;
    texture_target (M,) int32: the TARGET_* id of the coefficient an image texture modulates (-1:
    none). ka2 / kd2 are the checker's second cell (equal to ka / kd without a checker, as in
    `warp_model.material_struct`). texels: (T, 3) the fitted textures' texels stacked (`texels.py`;
    None when no texture is fitted). `lighting.jax_model.surface_material` reads the local part.
    """

    ka: jnp.ndarray
    ka2: jnp.ndarray
    kd: jnp.ndarray
    kd2: jnp.ndarray
    ks: jnp.ndarray
    n: jnp.ndarray
    m: jnp.ndarray
    f0: jnp.ndarray
    kr: jnp.ndarray
    kt: jnp.ndarray
    absorption: jnp.ndarray
    texture_target: jnp.ndarray
    texels: jnp.ndarray | None = None

    @classmethod
    def from_scene(cls, materials, dtype=jnp.float32, *, host: bool = False, records=None) -> MaterialTable:
        """From scene `Material`s in material-id order, moved to the device in one transfer (`host`:
        numpy arrays, for a caller that moves them with others); `records`: their `material_records`,
        where the caller formed them already."""
        records = material_records(materials) if records is None else records
        fields = stack_fields([values for values, _ in records], FIELDS, dtype)
        table = cls(**fields, texture_target=np.asarray([target for _, target in records], np.int32).reshape(-1))
        return table if host else jax.device_put(table)


def material_records(materials) -> list:
    """What `MaterialTable.from_scene` stacks of each material: (its FIELDS values, the TARGET_* id of
    its texture's coefficient, -1: none) -- plain Python values, compared with == (`Setup._problem`)."""
    return [([_field(mat, name) for name in FIELDS], TEXTURE_TARGET_IDS[mat.texture_target] if mat.texture is not None
             else -1) for mat in materials]

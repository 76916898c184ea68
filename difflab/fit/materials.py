"""The one material table of the fits: every fittable field of every material, stacked by id."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..lighting.warp_model import TEXTURE_TARGET_IDS


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
    def from_scene(cls, materials, dtype=jnp.float32, *, host: bool = False) -> MaterialTable:
        """From scene `Material`s in material-id order, moved to the device in one transfer (`host`:
        numpy arrays, for a caller that moves them with others)."""
        materials = list(materials)
        real = np.dtype(dtype)

        def stack(get, shape):
            values = np.asarray([get(mat) for mat in materials], np.float64).reshape((len(materials),) + shape)
            return values.astype(real)

        def field(name, shape):
            return stack(lambda mat: getattr(mat, name), shape)

        def second(name):
            return stack(lambda mat: getattr(mat.checker, name) if mat.checker is not None else getattr(mat, name[:2]),
                         (3,))

        targets = [TEXTURE_TARGET_IDS[m.texture_target] if m.texture is not None else -1 for m in materials]
        table = cls(
            ka=field("ka", (3,)), kd=field("kd", (3,)), ks=field("ks", (3,)), n=field("n", ()), m=field("m", ()),
            f0=field("f0", ()), ka2=second("ka2"), kd2=second("kd2"), kr=field("kr", ()), kt=field("kt", ()),
            absorption=field("absorption", (3,)), texture_target=np.asarray(targets, np.int32).reshape(-1))
        return table if host else jax.device_put(table)

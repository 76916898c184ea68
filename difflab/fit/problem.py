"""The fitting problem as a JAX pytree: the views (an image model each, fixed by one Warp render, and
the target), the materials' base values, where the fitted values go, and the residuals.

    r_i = rho( sqrt(w_i) * (min(model_i, c) - target_i) )

over every channel of the pixels that count in every view (in the mask, weight > 0, influenced by a
fitted parameter). c is the target's ceiling: a pixel recorded at the ceiling (a clipped highlight)
only says the model reaches it, so the model is clipped there too (c = inf for unclipped targets).
rho is the identity (l2) or rescales r so that r^2 is the Huber or Cauchy loss of r. A texture's
smoothness prior (`texels.smoothness_residuals`) is appended after the pixels' entries. The residuals
are not divided by their count: J^T J then grows with the image, and the damping of the
Levenberg-Marquardt solver is small against it from the first step.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..lighting.jax_model import LightsJ
from .materials import MaterialTable
from .texels import affine_residuals, smoothness_residuals, stacked_texels

LOSSES = ("l2", "huber", "cauchy")
TABLE_KINDS = ("ka", "kd", "ks", "n", "m", "f0", "kr", "kt", "absorption")


class ViewJ(eqx.Module):
    """One view on the device, cut down to the U pixels that count: its image model (a
    `shading.GBufferModel` or a `raytree.TreeModel`), lights, target (U, 3) and sqrt(weight) (U, 3,
    or a scalar 1 when every weight is 1: nothing to move or multiply), the target's ceiling (None:
    the target is not clipped -- a static difference, so unclipped residuals carry no min / compare
    per pixel), and intensity_index (P, 3): the entry of the flat value vector each of its lights'
    intensity channels takes (-1: not fitted)."""

    model: eqx.Module
    lights: LightsJ
    target: jnp.ndarray
    sqrt_weight: jnp.ndarray
    ceiling: jnp.ndarray | None
    intensity_index: jnp.ndarray

    def recorded(self, image):
        """The model's pixels as the target records them: min(image, ceiling)."""
        return image if self.ceiling is None else jnp.minimum(image, self.ceiling)

    def uncensored(self, image):
        """Where the model is below the ceiling (its derivatives reach the residual); True without one."""
        return True if self.ceiling is None else image < self.ceiling


@functools.lru_cache(maxsize=64)
def value_index(layout, n_materials: int, n_lights: int) -> dict:
    """kind -> int32 array of the flat-vector entry each material (or light) field takes (-1: the
    base value stays): (M, 3) for RGB kinds, (M,) for scalars, (P, 3) for "intensity" (a texture's
    texels are contiguous slices: `texels.stacked_texels`). Formed once per layout and counts:
    read-only arrays in a shared dict, not to be changed."""
    index = {k: np.full((n_materials, 3) if k in ("ka", "kd", "ks", "absorption") else (n_materials,), -1, np.int32)
             for k in TABLE_KINDS}
    index["intensity"] = np.full((n_lights, 3), -1, np.int32)
    offset = 0
    for p in layout:
        if p.shape is None:
            entries = np.arange(offset, offset + p.size)
            target = index[p.kind]
            target[p.index] = np.broadcast_to(entries, (3,)) if target.ndim == 2 else entries[0]
        offset += p.size
    for array in index.values():
        array.setflags(write=False)
    return index


def assembled(cls, **fields):
    """`cls(**fields)` for an `eqx.Module` with the dataclass constructor (default values filled
    in), made as JAX's `tree_unflatten` makes one: without `eqx.Module`'s checks of every leaf given
    (a `Problem` of one view, its `ViewJ` and `GBufferModel`: ~65 us hot, ~0.2 ms of a first fit's
    setup, against ~6 us). Only for modules with none of what that constructor adds: no converters,
    `__check_init__`, `__post_init__`, `default_factory` or `init=False` fields."""
    out = object.__new__(cls)
    for name, default in _defaults(cls):
        value = fields.pop(name, default)
        if value is dataclasses.MISSING:
            raise TypeError(f"{cls.__name__}: no {name} given")
        object.__setattr__(out, name, value)
    if fields:
        raise TypeError(f"{cls.__name__} has no field {', '.join(fields)}")
    return out


@functools.cache
def _defaults(cls) -> tuple:
    """(name, default) of each field of the dataclass `cls`, in order: `assembled`'s, asked once per
    class (`dataclasses.fields` filters the fields at each call: ~1 us hot, 3-4 calls a first fit)."""
    return tuple((field.name, field.default) for field in dataclasses.fields(cls))


def replaced(module, **changes):
    """`module` with the fields `changes` replaced, made by `assembled` (eqx.tree_at walks the tree:
    ~0.12 ms a call in a first fit)."""
    kept = {name: getattr(module, name) for name, _ in _defaults(type(module))}
    return assembled(type(module), **{**kept, **changes})


@jax.jit
def to_device(tree):
    """A pytree of numpy arrays as JAX arrays (copies), moved in one call: a jitted identity, whose
    dispatch moves every leaf at once (`jax.device_put` costs some 60 us a leaf on the CPU)."""
    return tree


@functools.lru_cache(maxsize=64)
def device_index(layout, n_materials: int, n_lights: int, default_device) -> dict:
    """`value_index` but "intensity" (each view's: `ViewJ.intensity_index`) on the device -- a
    problem's `index` --, moved once per layout, counts and default device (device arrays are
    immutable): among a problem's other small arrays (`records.DEVICE_COPIES`, when it compared their
    bytes) its 9 arrays cost each first fit's setup ~20 us."""
    return to_device({k: v for k, v in value_index(layout, n_materials, n_lights).items() if k != "intensity"})


def take_rows(array, rows, dtype=None) -> np.ndarray:
    """array[rows] along its first axis for an int array `rows` of valid indices, in `dtype`
    (default: the array's), as a numpy array whose data start on a 64-byte boundary: JAX's CPU
    client moves such an array to the device in place, not by a copy (a 24768 x 3 float64 target:
    0.03 ms against 0.10), so it is never written to. (numpy's `take`: several times the speed of
    an index expression.)"""
    return take_rows_of([array], rows, dtype)[0]


def take_rows_of(arrays, rows, dtype=None) -> list[np.ndarray]:
    """`take_rows` of several arrays at the same `rows`, their results carved from one buffer (each
    from a 64-byte boundary; one allocation, not one each)."""
    dtypes = [np.dtype(array.dtype if dtype is None else dtype) for array in arrays]
    out = carved([(rows.size,) + array.shape[1:] for array in arrays], dtypes)
    for array, part in zip(arrays, out):
        if part.dtype == array.dtype:
            np.take(array, rows, axis=0, out=part, mode="clip")  # (valid rows: "clip" takes them unbuffered)
        else:
            part[...] = np.take(array, rows, axis=0)
    return out


def on_boundary(array: np.ndarray) -> np.ndarray:
    """`array`, or a copy of it whose data start on a 64-byte boundary where its own do not (or it
    is not contiguous): a jitted call takes such a numpy array in place (`take_rows`)."""
    if array.flags.c_contiguous and array.ctypes.data % 64 == 0:
        return array
    out = carved([array.shape], [array.dtype])[0]
    out[...] = array
    return out


def carved(shapes, dtypes) -> list[np.ndarray]:
    """Empty arrays of these shapes and dtypes carved from one buffer, each from a 64-byte boundary."""
    sizes = [math.prod(shape) * np.dtype(kind).itemsize for shape, kind in zip(shapes, dtypes)]
    starts = list(itertools.accumulate([-(-size // 64) * 64 for size in sizes], initial=0))  # (np.cumsum: ~2 us more)
    raw = np.empty(starts[-1] + 64, np.uint8)
    base = -raw.ctypes.data % 64
    return [raw[base + start:base + start + size].view(kind).reshape(shape)
            for shape, kind, start, size in zip(shapes, dtypes, starts, sizes)]


def _put(index, values, base):
    return jnp.where(index >= 0, values[jnp.maximum(index, 0)], base)


def robust(kind: str, r, scale):
    """r rescaled so that r'^2 = rho(r^2): Huber (quadratic within `scale`, linear beyond) or Cauchy
    (scale^2 log(1 + r^2 / scale^2)); finite with finite gradients at r = 0."""
    if kind == "l2":
        return r
    sq = r * r
    small = sq <= (scale * scale if kind == "huber" else 1e-30)
    safe_sq = jnp.where(small, 1.0, sq)
    if kind == "huber":
        ratio = 2.0 * scale / jnp.sqrt(safe_sq) - scale * scale / safe_sq
    else:
        ratio = scale * scale * jnp.log1p(safe_sq / (scale * scale)) / safe_sq
    return r * jnp.where(small, 1.0, jnp.sqrt(ratio))


class Problem(eqx.Module):
    """Everything the residuals need. Arrays are leaves (one compiled solve serves any targets of
    the same shapes); the parameter layout, the loss and a texture's smoothness weight are static.
    Values travel as one flat vector in layout order (`params.Layout`); `index` says where they go in
    the material table (`value_index`; fitted texels: `texels.stacked_texels`)."""

    views: tuple
    table: MaterialTable
    ambient: jnp.ndarray
    index: dict
    loss_scale: jnp.ndarray
    layout: object = eqx.field(static=True)
    loss: str = eqx.field(static=True)
    smoothness: float = eqx.field(static=True, default=0.0)

    def materials(self, values) -> MaterialTable:
        """The table with the flat values written in (a checker's ka2 / kd2 stay)."""
        table = self.table._replace(**{k: _put(index, values, getattr(self.table, k)) for k, index in self.index.items()})
        texels = stacked_texels(self.layout, values)
        return table if texels is None else table._replace(texels=texels)

    def point_texels(self, values) -> tuple:
        """Each view's points' texture values (R, 3) for flat values (fitted texels only)."""
        texels = stacked_texels(self.layout, values)
        return tuple(view.model.point_texels(texels) for view in self.views)

    def images(self, values, texels=None) -> tuple:
        """The model's pixels (U, 3) of each view for flat values in scene units; `texels`: each
        view's points' texture values (default: `point_texels(values)`)."""
        table = self.materials(values)
        out = []
        for i, view in enumerate(self.views):
            lights = view.lights._replace(intensity=_put(view.intensity_index, values, view.lights.intensity))
            out.append(view.model.pixels(table, lights, self.ambient, *(() if texels is None else (texels[i],))))
        return tuple(out)

    def weighted(self, values, texels=None):
        """sqrt(w) (min(model, ceiling) - target) of every view, flattened (N,): the plain residuals
        in image units (no robust loss)."""
        return jnp.concatenate([(view.sqrt_weight * (view.recorded(image) - view.target)).reshape(-1)
                                for view, image in zip(self.views, self.images(values, texels))])

    def residuals(self, x, texels=None):
        """What the least-squares solvers see, for solver coordinates x (`Layout.values`); `texels`
        as `images` (the texels' entries of x then reach only the smoothness prior); without them a
        texel fit's residuals are `texels.affine_residuals` (the same values, a faster derivative)."""
        if texels is None and any(p.shape is not None for p in self.layout):
            return affine_residuals(x, problem=self)
        values = self.layout.values(x)
        data = robust(self.loss, self.weighted(values, texels), self.loss_scale)
        return jnp.concatenate([data, smoothness_residuals(self.layout, values, self.smoothness)])

    def without_ceilings(self) -> Problem | None:
        """The problem with no view clipped (every `ViewJ.ceiling` None), when some view has a ceiling
        that no target value reaches and the loss is l2 (a robust loss's residuals do not give the
        model back: `below_ceilings`); else None. Its solution is this problem's wherever the model
        stays below the ceilings there (`below_ceilings`): the clip is then inactive around it, and
        the residuals, J^T J and J^T r are the same -- and its solve may step on the column moments
        (`moments.py`), which a clipped target cannot (an 8-bit file's targets have ceiling 1)."""
        clipped = [view.ceiling is not None for view in self.views]
        if self.loss != "l2" or not any(clipped) or any(_reaches(view) for view, on in zip(self.views, clipped) if on):
            return None
        return replaced(self, views=tuple(replaced(view, ceiling=None) for view in self.views))

    def view_residuals(self, r) -> tuple:
        """Weighted residuals as numpy arrays per view (..., 3, U), channel-major -- the one layout
        the report reads them in (`moments.residuals` forms them so) -- from a solve's r: such a
        tuple already, or flat (..., N) in the problem's order (`weighted`: each view's (U, 3)
        entries pixel by pixel), given as transposed views of it, not copies."""
        if isinstance(r, tuple):
            return tuple(np.asarray(part) for part in r)
        r, out, offset = np.asarray(r), [], 0
        for view in self.views:
            size = view.target.size
            out.append(np.swapaxes(r[..., offset:offset + size].reshape(*r.shape[:-1], -1, 3), -1, -2))
            offset += size
        return tuple(out)

    def below_ceilings(self, r) -> bool:
        """Whether the model is below every view's ceiling at each entry that counts (weight > 0),
        given the weighted residuals r (flat, or per view: `view_residuals`) of the problem without
        its ceilings: the model there is target + r / sqrt(w)."""
        for view, part in zip(self.views, self.view_residuals(r)):
            if view.ceiling is None:
                continue
            target = np.asarray(view.target).T  # (3, U), as the residuals
            sqrt_weight = np.asarray(view.sqrt_weight).T
            if sqrt_weight.ndim:  # (else every weight is 1: no selection, ~0.2 ms of a first fit)
                counts = sqrt_weight > 0
                target, part, sqrt_weight = target[counts], part[counts], sqrt_weight[counts]
            model = target + part / sqrt_weight
            if not np.all(model < np.asarray(view.ceiling)):
                return False
        return True

    def with_targets(self, targets) -> Problem:
        """The same problem with other targets, one (U, 3) array per view."""
        views = tuple(eqx.tree_at(lambda v: v.target, view, t) for view, t in zip(self.views, targets))
        return eqx.tree_at(lambda p: p.views, self, views)


def _reaches(view) -> bool:
    """Whether a target value that counts (weight > 0) reaches the view's ceiling (a value at the
    ceiling with weight 0 is no clip the fit sees)."""
    target, sqrt_weight = np.asarray(view.target), np.asarray(view.sqrt_weight)
    return bool(np.any((target if sqrt_weight.ndim == 0 else target[sqrt_weight > 0]) >= np.asarray(view.ceiling)))


"""The residuals and the Gauss-Newton normal equations at a point: what each step of the box
Levenberg-Marquardt solver (`lm.py`) and the statistics at the solution (`stats.py`) need,

    r (N,),   A = J^T J (p, p),   g = J^T r (p,)      (J = dr/dx, x the solver coordinates)

Two ways to the same numbers:

- dense (`dense`): J by forward-mode autodiff (one column per entry), then two products. Any
  residual function: robust losses, light intensities, the ray tree, composed pixels.
- by parts (`by_parts`), for the l2 loss on G-buffer views whose pixels are single points
  (`shading.Formation.direct`: Phong or flat shading at spp 1) with only ka, kd, ks, n, m, f0
  fitted (no texels, no prior rows). The colour is ka Ia + kd D + ks S(n, m, f0)
  (`jax_model.shade_parts`), so J's columns are known in closed form: sqrt(w) Ia, sqrt(w) D and
  sqrt(w) S for the linear coefficients (ka, kd only where the checker cell is the first: the
  second takes ka2, kd2), sqrt(w) ks dS/dt for t = n, m, f0 (one forward-mode tangent each), and 0
  where a pixel is censored (the model is above the ceiling). A row (a pixel channel) touches only
  its own material's entries of its own channel, so J^T J is summed per material and channel from
  q x q blocks (q: the fitted kinds; one product of (U, q + 1) columns per channel, batched over the
  3 channels, per material) and never formed as a dense (N, p) J.

`linearise` picks the second when it applies (a static property of the problem). Its `fast`
form -- what the solver's steps use where a target is clipped (the others step on the column
moments of `moments.py`, and so do targets with a ceiling no value reaches while the model ends
below it: `Problem.without_ceilings`) -- takes the columns' products in float32 when the fit runs in
float64 (the (3, q, U) columns written and multiplied at half the width: ~0.25 ms of ~0.7 a step on
26k pixels), while r and J^T r stay in float64 (J^T r from the float32 columns and the float64 r):
a gradient whose rounding is proportional to r leaves the point the solver converges to where it
was, and the damped normal matrix only steers the steps. The statistics at the solution use the
exact form.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..lighting.jax_model import combine_parts, shade_parts, surface_material
from .shading import GBufferModel

SLOTS = ("ka", "kd", "ks", "n", "m", "f0")
LINEAR = ("ka", "kd", "ks")


def dense(fn, x, args):
    """(r, J^T J, J^T r) of residuals fn(x, args), J by forward mode."""
    r, jvp = jax.linearize(lambda y: fn(y, args), x)
    jac = jax.vmap(jvp, out_axes=1)(jnp.eye(x.shape[0], dtype=x.dtype))
    return r, jac.T @ jac, jac.T @ r


def by_parts_terms(loss: str, smoothness, layout) -> bool:
    """Whether the loss, the prior and the fitted kinds allow `by_parts`: the l2 loss, no smoothness
    prior, only material coefficients and lobes (`SLOTS`) -- its image model aside."""
    return loss == "l2" and not smoothness and all(p.kind in SLOTS for p in layout)


def by_parts_applies(problem) -> bool:
    """Whether `by_parts` can linearise the problem (see the module docstring)."""
    return by_parts_terms(problem.loss, problem.smoothness, problem.layout) and all(
        isinstance(v.model, GBufferModel) and v.model.formation.direct and v.model.taps is None for v in problem.views)


def slot_columns(layout, n_materials: int) -> tuple[tuple, dict]:
    """(the fitted kinds among SLOTS, in order; material id -> (3, q) int array: the flat-vector
    entry each channel's slot takes, layout.size where that material's kind is not fitted)."""
    from .problem import value_index

    index = value_index(layout, n_materials, 0)
    slots = tuple(k for k in SLOTS if any(p.kind == k for p in layout))
    columns = {}
    for m in sorted({p.index for p in layout}):
        cols = np.stack([np.broadcast_to(index[k][m], (3,)) for k in slots], axis=-1)
        columns[m] = np.where(cols >= 0, cols, layout.size)
    return slots, columns


def material_rows(model, material: int, array):
    """`array` (..., U) on the rows (points) of `material`, 0 on the others (itself when the model
    shows no other)."""
    return array if model.material_ids == (material,) else jnp.where(model.material == material, array, 0.0)


def by_parts(problem, x, fast: bool = False):
    """(r, J^T J, J^T r) in closed form (see the module docstring); `by_parts_applies(problem)`.
    `fast`: J^T J from float32 columns (float64 fits; see the module docstring)."""
    layout = problem.layout
    values = layout.values(x)
    table = problem.materials(values)
    slots, columns = slot_columns(layout, table.ka.shape[0])
    p = layout.size
    low = jnp.float32 if fast else x.dtype  # the columns' precision
    gram = jnp.zeros((p + 1, p + 1), x.dtype)  # row / column p collects what is not fitted
    grad = jnp.zeros(p + 1, x.dtype)
    residuals = []
    for view in problem.views:
        model = view.model
        if len(model.material_ids) == 1 and model.material_ids[0] >= 0:  # one material: its row, no per-point lookup
            has_material = jnp.ones(model.material.shape, bool)
            mat = surface_material(table, model.material_ids[0], model.cell)
        else:
            has_material = model.material >= 0
            mat = surface_material(table, jnp.where(has_material, model.material, 0), model.cell)

        def parts(n, m, f0):
            return shade_parts(mat._replace(n=n, m=m, f0=f0), model.formation.specular, model.geometry,
                               view.lights.intensity, problem.ambient)

        ambient_part, diffuse, specular = parts(mat.n, mat.m, mat.f0)
        image = jnp.where(has_material[:, None], combine_parts(mat, (ambient_part, diffuse, specular)), 0.0)
        r = view.sqrt_weight * (view.recorded(image) - view.target)
        live = view.sqrt_weight * (has_material[:, None] & view.uncensored(image))  # 0 where censored
        first_cell = (model.cell != 1)[:, None]
        column = {"ka": live * ambient_part * first_cell, "kd": live * diffuse * first_cell, "ks": live * specular}
        for kind in slots:
            if kind not in LINEAR:
                tangent = {k: jnp.zeros_like(mat.n) for k in ("n", "m", "f0")}
                tangent[kind] = jnp.ones_like(mat.n)
                _, d_spec = jax.jvp(lambda n, m, f0: parts(n, m, f0)[2], (mat.n, mat.m, mat.f0),
                                    (tangent["n"], tangent["m"], tangent["f0"]))
                column[kind] = live * mat.ks * d_spec
        w = jnp.stack([column[k].T.astype(low) for k in slots], axis=1)  # (3 channels, q, U): rows of U
        for material, cols in columns.items():
            if material not in model.material_ids:
                continue
            # this material's rows, per channel every product of two columns summed over the pixels in
            # one batched product (3, q, q), and their products with r
            mine = material_rows(model, material, w)
            gram = gram.at[cols[:, :, None], cols[:, None, :]].add(jnp.einsum("ciu,cju->cij", mine, w).astype(x.dtype))
            grad = grad.at[cols].add(jnp.sum(mine * r.T[:, None, :], axis=-1, dtype=x.dtype))
        residuals.append(r.reshape(-1))
    scale = jnp.where(layout.entries("log") > 0, values, 1.0)  # d value / d x
    return (jnp.concatenate(residuals), scale[:, None] * gram[:p, :p] * scale[None, :], scale * grad[:p])


def has_fast_form(problem, x) -> bool:
    """Whether `linearise(x, problem, fast=True)` differs from the exact form: by parts, in float64."""
    return x.dtype == jnp.float64 and by_parts_applies(problem)


def linearise(x, problem, fast: bool = False):
    """(r, J^T J, J^T r) of `problem.residuals` at solver coordinates x, by parts where that
    applies (`fast`: its solver-step form), else dense."""
    if by_parts_applies(problem):
        return by_parts(problem, x, fast)
    return dense(lambda y, prob: prob.residuals(y), x, problem)

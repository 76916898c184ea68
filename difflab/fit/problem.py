"""The fitting problem as a JAX pytree: views (fixed G-buffer arrays and targets), the materials'
base values, and the residual function the solvers see.

    r_i = rho( sqrt(w_i) * (model_i - target_i) )

over every channel of the pixels that count in every view (in the mask, weight > 0, showing a fitted
material), where rho is the identity (l2) or rescales r so that r^2 is the Huber or Cauchy loss of r.
The residuals are not divided by their count: J^T J then grows with the image, and the
Levenberg-Marquardt damping (which starts at lambda = 1) is small against it from the first step.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..lighting.jax_model import LightsJ, lights_to_jax
from .params import apply_values, values_from_u
from .shading import ComposeJ, Formation, MaterialTable, PointsJ, compose, pixel_arrays, point_colors

LOSSES = ("l2", "huber", "cauchy")


class ViewJ(eqx.Module):
    """One view on the device, cut down to the U pixels that count (in the mask, weight > 0, and
    showing a fitted material): the R shading points those pixels use, which of them are re-shaded
    each step (`active`: a fitted material's, or all when light intensities are fitted), the fixed
    colours of the others, the composition, the view's lights, and its target and sqrt(weight) (U, 3)."""

    points: PointsJ
    active: jnp.ndarray
    base_colors: jnp.ndarray
    comp: ComposeJ
    lights: LightsJ
    target: jnp.ndarray
    sqrt_weight: jnp.ndarray
    pixels: jnp.ndarray
    formation: Formation = eqx.field(static=True)
    clip: bool = eqx.field(static=True)


_point_colors_jit = jax.jit(point_colors, static_argnums=4)


def make_view(view, used: np.ndarray, table: MaterialTable, ambient, material_ids, all_points: bool, dtype) -> ViewJ:
    """A `ViewJ` from a `targets.View` and its (H, W) bool map of pixels used."""
    pixels = np.flatnonzero(used)
    points, comp, formation, _ = pixel_arrays(view.gbuffer, pixels, dtype)
    lights = lights_to_jax(view.scene.lights, dtype)
    base_colors = _point_colors_jit(points, table, lights, ambient, formation.specular)
    material = np.asarray(points.material)
    active = np.ones(material.shape, bool) if all_points else np.isin(material, list(material_ids))
    target = view.target.reshape(-1, 3)[pixels]
    weight = view.weight.reshape(-1, 3)[pixels]
    return ViewJ(points=points, active=jnp.asarray(active), base_colors=base_colors, comp=comp, lights=lights,
                 target=jnp.asarray(target, dtype), sqrt_weight=jnp.asarray(np.sqrt(weight), dtype),
                 pixels=jnp.asarray(pixels, jnp.int32), formation=formation, clip=view.clip)


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
    """Everything the residual function needs. Arrays are leaves (so one compiled solve serves any
    targets of the same shapes); the parameter layout and the loss are static."""

    views: tuple
    table: MaterialTable
    ambient: jnp.ndarray
    loss_scale: jnp.ndarray
    layout: tuple = eqx.field(static=True)
    loss: str = eqx.field(static=True)

    def images(self, values: dict) -> tuple:
        """The model's pixels (U, 3) of each view (those the fit uses) for values in scene units."""
        table, lights = apply_values(self.layout, values, self.table, [v.lights for v in self.views])
        out = []
        for view, view_lights in zip(self.views, lights):
            shaded = point_colors(view.points, table, view_lights, self.ambient, view.formation.specular)
            colors = jnp.where(view.active[:, None], shaded, view.base_colors)
            out.append(compose(colors, view.comp, view.formation))
        return tuple(out)

    def weighted_residuals(self, values: dict) -> tuple:
        """sqrt(w) (model - target) per view, (U, 3) each: the plain residuals (no robust loss,
        no normalisation), in image units."""
        out = []
        for view, image in zip(self.views, self.images(values)):
            if view.clip:  # an 8-bit target saturates at 1: so does the model
                image = jnp.clip(image, 0.0, 1.0)
            out.append(view.sqrt_weight * (image - view.target))
        return tuple(out)

    def residuals_from_values(self, values: dict) -> tuple:
        return tuple(robust(self.loss, r, self.loss_scale) for r in self.weighted_residuals(values))

    def residuals(self, u: dict) -> tuple:
        """What the least-squares solvers see, for unconstrained parameters u."""
        return self.residuals_from_values(values_from_u(self.layout, u))


def residual_fn(u, problem: Problem):
    return problem.residuals(u)


def loss_fn(u, problem: Problem):
    """0.5 sum r^2: the scalar the minimisers (BFGS through least_squares, Adam) see."""
    return 0.5 * sum(jnp.sum(r * r) for r in problem.residuals(u))

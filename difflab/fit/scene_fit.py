"""`fit_scene`: several materials of one scene at once, through reflections and refractions.

Warp ray-traces each view once and records its ray tree (`renderers.raytrace.tree.RayTree`); JAX re-forms the
image from the tree (`raytree.py`) as often as the solver asks, so the lecture's whole Whitted model

    I = ka Ia + sum_p s_p att_p spot_p Ip (kd N.L + ks S) + kr F_r I_r e^(-alpha d) + kt F_t I_t e^(-alpha d)

is fitted -- ka, kd, ks, n (or m, f0), kr, kt and the absorption alpha of every chosen material --
with the optimistix solvers of `fit_material` (`solve.py`), its parameterisation (`params.py`) and
its diagnostics (`stats.py`), and returns the same `FitResult`.

The index of refraction is held fixed: it bends the refracted rays and sets the Fresnel factors, so
it changes the tree itself, which stays as recorded for the whole fit. So does the tree's shape:
a material's kr (kt) is fitted only where it starts > 0, since a zero weight records no child rays.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DifflabError, FitError
from ..lighting.jax_model import LightsJ, lights_to_jax
from ..renderers.api import as_scene, render_frame
from .fit import precheck, run_fit
from .params import initial_values, u_from_values
from .problem import LOSSES, robust
from .result import FitResult
from .raytree import TreeJ, TreeMaterials, evaluate_tree, tree_image, tree_influence, tree_to_jax
from .solve import SOLVERS
from .targets import prepared_targets
from .tree_params import DEFAULT_PARAMS, ValueMap, apply_init, build_tree_layout, flatten, unflatten

TREE_SOLVERS = tuple(s for s in SOLVERS if s != "varpro")


def _materials(scene, materials) -> tuple[str, ...]:
    names = scene.material_names
    if materials is None:
        used = {obj.material for obj in scene.objects}
        return tuple(name for name in names if name in used)
    if isinstance(materials, str):
        materials = (materials,)
    materials = tuple(materials)
    if not materials or len(set(materials)) != len(materials):
        raise FitError(f"materials: expected one or more distinct names, got {list(materials)}")
    for name in materials:
        if name not in names:
            raise FitError(f"materials: undefined material {name!r} (defined: {', '.join(names) or 'none'})")
    return materials


# -- the problem -------------------------------------------------------------------------------------


class TreeViewJ(eqx.Module):
    """One view on the device: the ray tree of the U pixels that count, the view's lights and
    background, its target and sqrt(weight) (U, 3)."""

    tree: TreeJ
    lights: LightsJ
    background: jnp.ndarray
    target: jnp.ndarray
    sqrt_weight: jnp.ndarray
    pixels: jnp.ndarray
    clip: bool = eqx.field(static=True)


class TreeProblem(eqx.Module):
    """The residual function of `fit_scene` (the interface of `problem.Problem`, so that `solve.py`
    and `stats.py` serve it unchanged). The solvers see one flat vector u of unconstrained values:
    one leaf keeps the compiled solve small however many parameters there are."""

    views: tuple
    mats: TreeMaterials
    value_map: ValueMap
    ambient: jnp.ndarray
    loss_scale: jnp.ndarray
    layout: tuple = eqx.field(static=True)
    loss: str = eqx.field(static=True)

    def images_from_vector(self, v) -> tuple:
        """Each view's model pixels (U, 3) for the flat values v (scene units, layout order)."""
        mats = self.value_map.fill(v, self.mats)
        return tuple(tree_image(view.tree, mats, view.lights, self.ambient, view.background) for view in self.views)

    def images(self, values: dict) -> tuple:
        return _images_jit(self, flatten(self.layout, values))

    def _weighted(self, images) -> tuple:
        out = []
        for view, image in zip(self.views, images):
            if view.clip:  # an 8-bit target saturates at 1: so does the model
                image = jnp.clip(image, 0.0, 1.0)
            out.append(view.sqrt_weight * (image - view.target))
        return tuple(out)

    def weighted_residuals(self, values: dict) -> tuple:
        """sqrt(w) (model - target) per view, (U, 3) each, for values in scene units (key -> value)."""
        return self._weighted(self.images(values))

    def residuals_from_values(self, values: dict) -> tuple:
        return tuple(robust(self.loss, r, self.loss_scale) for r in self.weighted_residuals(values))

    def residuals(self, u) -> tuple:
        """What the solvers see, for the flat unconstrained vector u."""
        images = self.images_from_vector(self.value_map.values_of(u))
        return tuple(robust(self.loss, r, self.loss_scale) for r in self._weighted(images))


@eqx.filter_jit
def _images_jit(problem: TreeProblem, v):  # compiled once per problem shape, also when called eagerly
    return problem.images_from_vector(v)


@dataclass(frozen=True)
class TreeView:
    """One target, its mask / weight, and the ray tree recorded for it (see `targets.View`)."""

    target: np.ndarray
    mask: np.ndarray
    weight: np.ndarray
    clip: bool
    nonfinite: int
    tree: object
    scene: object
    image: np.ndarray  # the Warp render at the start values


def record_views(scene, targets, masks=None, weights=None, *, max_depth=None, spp=None, device="cpu",
                 threads=None) -> list[TreeView]:
    """One `TreeView` per target: its camera / lights override applied at the target's size, ray-traced
    once by Warp with the tree recorded (adaptive_threshold 0, so that no child is cut by weight)."""
    render = {"method": "raytrace", "adaptive_threshold": 0.0}
    if max_depth is not None:
        render["max_depth"] = max_depth
    if spp is not None:
        render["spp"] = spp
    views = []
    for view_scene, image, clip, mask, weight, nonfinite in prepared_targets(scene, targets, masks, weights, render):
        frame = render_frame(view_scene, device=device, threads=threads)
        views.append(TreeView(target=image, mask=mask, weight=weight, clip=clip, nonfinite=nonfinite,
                              tree=frame.ray_tree, scene=view_scene, image=frame.image))
    return views


class SceneSetup:
    """A `fit_scene` prepared: views with their recorded trees, layout, the device problem, start.
    It has the interface of `fit.Setup`, so `fit.solve` runs it."""

    def __init__(self, scene, targets, materials=None, params=DEFAULT_PARAMS, *, per_channel=True, loss="l2",
                 loss_scale=0.05, masks=None, weights=None, init=None, x64=True, max_depth=None, spp=None,
                 device="cpu", threads=None):
        if loss not in LOSSES:
            raise FitError(f"loss: unknown loss {loss!r}; known: {', '.join(LOSSES)}")
        if not (isinstance(loss_scale, (int, float)) and loss_scale > 0):
            raise FitError(f"loss_scale: must be a number > 0, got {loss_scale!r}")
        try:
            scene = as_scene(scene)
        except DifflabError as exc:
            raise FitError(f"scene: {exc}") from None
        self.materials = _materials(scene, materials)
        scene = apply_init(scene, self.materials, init)  # the trees are recorded at the start values
        self.scene = scene
        self.layout = build_tree_layout(scene, self.materials, params, per_channel)
        if len(self.materials) == 1:  # keys are plain ("kr"); accept "glass.kr" too
            init = {str(k).rpartition(".")[2] if str(k).startswith(self.materials[0] + ".") else k: v
                    for k, v in (init or {}).items()}
        unknown = set(init or {}) - {p.key for p in self.layout}
        if unknown:
            raise FitError(f"init: not fitted: {sorted(unknown)} (fitted: {[p.key for p in self.layout]})")
        self.initial = initial_values(scene, self.layout)
        self.views = record_views(scene, targets, masks, weights, max_depth=max_depth, spp=spp, device=device,
                                  threads=threads)
        self.x64 = bool(x64)
        self.dtype = jnp.float64 if x64 else jnp.float32
        ids = sorted({p.index for p in self.layout})
        crossing = sorted({p.index for p in self.layout if p.kind == "kt"})
        self.used = [v.mask & (v.weight > 0).any(axis=-1) & tree_influence(v.tree, ids, crossing) for v in self.views]
        self.used_pixels = int(sum(int(u.sum()) for u in self.used))
        self.nonfinite = int(sum(v.nonfinite for v in self.views))
        with jax.enable_x64(self.x64):
            mats = TreeMaterials.from_scene(scene.materials.values(), self.dtype)
            ambient = jnp.asarray(scene.ambient, self.dtype)
            views = tuple(self._view(v, u) for v, u in zip(self.views, self.used))
            value_map = ValueMap.build(self.layout, len(scene.materials))
            self.problem = TreeProblem(views=views, mats=mats, value_map=value_map, ambient=ambient,
                                       loss_scale=jnp.asarray(loss_scale, self.dtype), layout=self.layout, loss=loss)
            self.u0 = flatten(self.layout, u_from_values(self.layout, self.initial, self.dtype))

    def _view(self, view: TreeView, used: np.ndarray) -> TreeViewJ:
        pixels = np.flatnonzero(used)
        f = lambda x: jnp.asarray(np.asarray(x, np.float64), self.dtype)  # noqa: E731
        return TreeViewJ(tree=tree_to_jax(view.tree, pixels, self.dtype),
                         lights=lights_to_jax(view.scene.lights, self.dtype), background=f(view.scene.background),
                         target=f(view.target.reshape(-1, 3)[pixels]),
                         sqrt_weight=f(np.sqrt(view.weight.reshape(-1, 3)[pixels])),
                         pixels=jnp.asarray(pixels, jnp.int32), clip=view.clip)

    def values(self, u) -> dict:
        with jax.enable_x64(self.x64):
            values = unflatten(self.layout, self.problem.value_map.values_of(jnp.asarray(u, self.dtype)))
            return {k: np.asarray(v, np.float64) for k, v in values.items()}

    def precheck(self) -> str | None:
        return precheck(self)

    def render(self, values: dict | None = None) -> list[np.ndarray]:
        """Each view's full image (H, W, 3) float32 from its tree at `values` (scene units; default:
        the start), pixels outside the fit's masks included."""
        values = self.initial if values is None else values
        out = []
        with jax.enable_x64(self.x64):
            vector = flatten(self.layout, {k: jnp.asarray(np.asarray(v, np.float64), self.dtype)
                                           for k, v in values.items()})
            mats = self.problem.value_map.fill(vector, self.problem.mats)
            for view, jview in zip(self.views, self.problem.views):
                tree = tree_to_jax(view.tree, None, self.dtype)
                image = evaluate_tree(tree, mats, jview.lights, self.problem.ambient, jview.background)
                out.append(np.asarray(image, np.float32).reshape(view.target.shape))
        return out


def fit_scene(scene, targets, materials=None, params=DEFAULT_PARAMS, *, solver="lm", per_channel=True, loss="l2",
              loss_scale=0.05, masks=None, weights=None, init=None, max_steps=256, rtol=None, atol=None,
              learning_rate=0.05, x64=True, throw=False, max_depth=None, spp=None, device="cpu", threads=None,
              history=True, rel_tol=0.1, abs_tol=1e-3) -> FitResult:
    """Fit the materials of a ray-traced scene -- reflection, refraction and absorption included -- to
    target images, several materials and several views at once.

        minimise  sum_views sum_pixels  rho( sqrt(w) (raytrace(params) - target) )^2

    where raytrace re-forms the Whitted ray tracer's image in JAX from each view's ray tree, recorded
    once by Warp at the start values (`raytree.py`).

    Held fixed (they change the tree itself): the index of refraction `ior`, the geometry, the lights'
    positions, and the tree's shape. A material's kr is fitted only where it starts > 0, and kt and
    absorption only where kt starts > 0 (a zero weight traces no child rays, so the tree could not
    see the value move); asking for one of those by its qualified name ("glass.kt") raises FitError.
    Keep the start values > 0 for every kr / kt whose true value is.

    Arguments:
        scene: a Scene, a scene dict or a scene file path. Its values (with `init`) are the start.
        targets: as `fit_material`: an image (array or file), or a list of images and/or
            (image, overrides) pairs, overrides a dict with a whole "camera" block and/or a whole
            "lights" list; each view is ray-traced at its target's size.
        materials: the material names to fit; default: every material an object uses.
        params: any of "ka", "kd", "ks" (RGB), "n", "m", "f0", "kr", "kt", "absorption" (RGB) for
            every fitted material, or "name.kind" for one (a tuple, or "ka,kd").
        solver: "lm", "gauss_newton", "dogleg", "bfgs" or "adam" (variable projection is not offered).
        per_channel: RGB values per channel (False: one grey value each).
        loss, loss_scale, masks, weights, max_steps, rtol, atol, learning_rate, x64, throw, history,
            rel_tol, abs_tol: as `fit_material`.
        init: key -> starting value (keys as in `FitResult.params`, e.g. "mirror.kr").
        max_depth, spp: override the scene's ray-tree depth and samples per pixel for the fit.
        device: where Warp traces ("cpu" or "cuda"). threads: CPU threads for the trace.
    Returns:
        a `FitResult` (keys "name.kind" when several materials are fitted); `converged` false and
        `result` naming why when the fit failed.
    """
    if solver not in TREE_SOLVERS:
        raise FitError(f"solver: fit_scene offers {', '.join(TREE_SOLVERS)}, got {solver!r}")
    start = time.perf_counter()
    setup = SceneSetup(scene, targets, materials, params, per_channel=per_channel, loss=loss, loss_scale=loss_scale,
                       masks=masks, weights=weights, init=init, x64=x64, max_depth=max_depth, spp=spp, device=device,
                       threads=threads)
    return run_fit(setup, solver, time.perf_counter() - start, max_steps=max_steps, rtol=rtol, atol=atol,
                   learning_rate=learning_rate, history=history, rel_tol=rel_tol, abs_tol=abs_tol, throw=throw)


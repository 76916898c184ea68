"""Fitting a texture from rendered views: the classic spelling of the one engine's texel fit.

`fit_texture(views, shape)` is `engine.fit(scene, targets, material, params=("texture",))` with
each view's camera and lights as that target's overrides (`texels.py` holds the image model: the
G-buffer with each sample's filter taps into the texels; the engine solves it matrix-free and
reports a `FitResult` -- `.texture`, `.visible`, `.rmse`, `.n_params` read the one texture).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..errors import FitError
from ..scene.material import TEXTURE_WRAPS
from .engine import fit
from .options import FitOptions
from .texels import FIT_FILTERS, texture_taps  # noqa: F401  (re-exported: the taps of the Warp sampler)


@dataclass(frozen=True)
class TextureView:
    """One rendered view of the textured material: scene (its camera and lights), target (H, W, 3)
    linear float, material name, filter / wrap (None: the material's), mask (H, W) bool (None: every
    pixel that shows the material counts)."""

    scene: object
    target: np.ndarray
    material: str
    filter: str | None = None
    wrap: str | None = None
    mask: np.ndarray | None = None


def texture_view(gbuffer, target, scene, material: str, shape: tuple[int, int], filter: str | None = None,
                 wrap: str | None = None, mask=None) -> TextureView:
    """A view for `fit_texture`: its scene, target and material, checked against its rendered
    G-buffer (Phong shading, the material in view, the target's size) and the (H_t, W_t) texel
    grid `shape`; `mask` (H, W) bool restricts the pixels used. Raises FitError naming the argument."""
    if gbuffer.shading != "phong":
        raise FitError(f"gbuffer: fitting texels needs a Phong-shaded G-buffer (shading points = samples), "
                       f"got {gbuffer.shading!r}")
    names = list(scene.materials)
    if material not in names:
        raise FitError(f"material: {material!r} is not in the scene ({', '.join(names)})")
    _check_shape(shape)
    for name, value, known in (("filter", filter, FIT_FILTERS), ("wrap", wrap, TEXTURE_WRAPS)):
        if value is not None and value not in known:
            raise FitError(f"{name}: texture fitting supports {', '.join(known)}, got {value!r}")
    side = gbuffer.spp_side
    size = (gbuffer.mask.shape[0] // side, gbuffer.mask.shape[1] // side, 3)
    target = np.asarray(target)
    if target.shape != size:
        raise FitError(f"target: expected shape {size}, got {target.shape}")
    if not np.any(gbuffer.material == names.index(material)):
        raise FitError(f"material {material!r}: no sample of this view shows it")
    return TextureView(scene=scene, target=target, material=material, filter=filter, wrap=wrap, mask=mask)


def _check_shape(shape) -> tuple[int, int]:
    if (not isinstance(shape, (tuple, list)) or len(shape) != 2
            or not all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s >= 1 for s in shape)):
        raise FitError(f"shape: expected (H_t, W_t), two integers >= 1, got {shape!r}")
    return int(shape[0]), int(shape[1])


def fit_texture(views, shape: tuple[int, int], *, smoothness: float = 0.0, solver: str = "lm", init=0.5,
                max_steps: int = 50, cg_steps: int = 500, rtol: float = 1e-10, atol: float = 1e-10,
                visible_threshold: float = 1e-3, x64: bool = True, throw: bool = False):
    """Fit an (H_t, W_t) RGB texture of unknowns to the targets of `views` (`texture_view`s).

        minimise 0.5 sum_views |pixels(T) - target|^2 + 0.5 smoothness sum |T_neighbour - T|^2

    Arguments:
        views: TextureView list (one per rendered image), all of one material of one scene.
        shape: (H_t, W_t) texels.
        smoothness: weight of the first-difference prior (0: none).
        solver: "lm" (box-constrained Levenberg-Marquardt) or "gauss_newton" (optimistix), both
            matrix-free (CG on the normal equations, `cg_steps` iterations at most per step) for
            more than 256 unknowns; "dogleg" and "adam" as `FitOptions`.
        init: starting texel value (scalar, RGB, or (H_t, W_t, 3) image orientation).
        max_steps, rtol, atol, x64, throw: as `FitOptions`; visible_threshold: a texel is seen when
            the pixels change by more than this per unit texel, summed.
    Returns:
        `FitResult` (failure is a value: `.result`, `.converged`): `.texture` (H_t, W_t, 3),
        `.visible` (H_t, W_t) bool, `.rmse`, `.n_params`, and the engine's statistics.
    """
    views = list(views)
    if not views:
        raise FitError("views: need at least one view")
    if not all(isinstance(v, TextureView) for v in views):
        raise FitError("views: expected TextureViews (from texture_view)")
    h, w = _check_shape(shape)
    first = views[0]
    for i, view in enumerate(views[1:], 1):
        if view.material != first.material or view.scene.materials != first.scene.materials:
            raise FitError(f"views[{i}]: its material differs from views[0]'s ({first.material!r})")
    try:
        start = np.broadcast_to(np.asarray(init, np.float64), (h, w, 3))
    except ValueError:
        raise FitError(f"init: expected a number, an RGB triple or an {(h, w, 3)} texture, got shape "
                       f"{np.shape(init)}") from None
    mat = first.scene.materials[first.material]
    mat = dataclasses.replace(mat, filter=first.filter or mat.filter, wrap=first.wrap or mat.wrap)
    scene = dataclasses.replace(first.scene, materials={**first.scene.materials, first.material: mat})
    targets = []
    for view in views:
        block = view.scene.to_dict()
        targets.append((view.target, {"camera": block["camera"], "lights": block["lights"]}))
    options = FitOptions(solver=solver, max_steps=max_steps, rtol=rtol, atol=atol, cg_steps=cg_steps,
                         visible_threshold=visible_threshold, x64=x64, throw=throw)
    return fit(scene, targets, first.material, ("texture",), method="raster", masks=[v.mask for v in views],
               init={"texture": start}, smoothness=smoothness, ceiling=False, options=options)

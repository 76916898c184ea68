"""Targets in: images (arrays or files), their per-view camera / lights, masks and weights; and the
one Warp render per view that gives the G-buffer the fit shades again and again."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import DifflabError, FitError
from ..io import load_image
from ..renderers.api import as_scene
from ..renderers.frame import GBuffer

OVERRIDE_KEYS = ("camera", "lights")
EIGHT_BIT = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclass(frozen=True)
class View:
    """One target and what it was seen with. target (H, W, 3) float64 (0 where masked out); mask
    (H, W) bool: pixels that count; weight (H, W, 3) >= 0 (0 outside the mask); clip: the target came
    from an 8-bit file, so the model is clipped to [0, 1] before comparing; nonfinite: non-finite
    target values inside the mask; gbuffer: the view's G-buffer; scene: the scene of this view."""

    target: np.ndarray
    mask: np.ndarray
    weight: np.ndarray
    clip: bool
    nonfinite: int
    gbuffer: GBuffer
    scene: object


def _is_path(x) -> bool:
    return isinstance(x, (str, os.PathLike))


def normalise_targets(targets) -> list[tuple[object, dict]]:
    """[(image or path, overrides dict)] from the accepted forms of `targets`."""
    if _is_path(targets) or (isinstance(targets, np.ndarray) and targets.ndim == 3):
        targets = [targets]
    if isinstance(targets, tuple) and len(targets) == 2 and isinstance(targets[1], dict):
        targets = [targets]
    try:
        targets = list(targets)
    except TypeError:
        raise FitError(f"targets: expected a list of images, paths or (image, overrides) pairs, "
                       f"got {type(targets).__name__}") from None
    if not targets:
        raise FitError("targets: no target images given")
    out = []
    for i, item in enumerate(targets):
        overrides = {}
        if isinstance(item, (tuple, list)) and len(item) == 2 and (item[1] is None or isinstance(item[1], dict)):
            item, overrides = item[0], dict(item[1] or {})
        unknown = set(overrides) - set(OVERRIDE_KEYS)
        if unknown:
            raise FitError(f"targets[{i}]: unknown override(s) {sorted(unknown)}; a view may replace only "
                           f"{' and '.join(OVERRIDE_KEYS)}")
        out.append((item, overrides))
    return out


def load_target(item, where: str) -> tuple[np.ndarray, bool]:
    """(image (H, W, 3) float64, from an 8-bit file?)."""
    if _is_path(item):
        try:
            image = load_image(item)
        except DifflabError as exc:
            raise FitError(f"{where}: {exc}") from None
        return image.astype(np.float64), str(item).lower().endswith(EIGHT_BIT)
    image = np.asarray(item)
    if image.ndim != 3 or image.shape[-1] not in (3, 4) or not np.issubdtype(image.dtype, np.number):
        raise FitError(f"{where}: expected an (H, W, 3) image, got shape {image.shape} of {image.dtype}")
    return image[..., :3].astype(np.float64), False


def per_view(values, count: int, name: str) -> list:
    """One value per view: None, a single mask / weight for all views, or a list of `count`."""
    if values is None:
        return [None] * count
    if isinstance(values, np.ndarray) or _is_path(values):
        values = [values] * count
    values = list(values)
    if len(values) != count:
        raise FitError(f"{name}: expected one per target ({count}), got {len(values)}")
    return values


def view_mask(value, shape, where) -> np.ndarray:
    """A view's boolean mask (H, W) from None (all), an array or an image path."""
    if value is None:
        return np.ones(shape, bool)
    if _is_path(value):
        value = load_image(value, srgb=False)[..., 0] > 0.5
    mask = np.asarray(value)
    if mask.ndim == 3:
        mask = mask[..., 0]
    if mask.shape != shape:
        raise FitError(f"{where}: expected shape {shape}, got {mask.shape}")
    return mask.astype(bool)


def view_weight(value, shape, where) -> np.ndarray:
    """A view's non-negative per-pixel weights broadcast to (H, W, 3) (None: all 1)."""
    if value is None:
        return np.ones(shape + (3,))
    weight = np.asarray(value, np.float64)
    if weight.ndim == 2:
        weight = weight[..., None]
    try:
        weight = np.broadcast_to(weight, shape + (3,)).copy()
    except ValueError:
        raise FitError(f"{where}: expected shape {shape} or {shape + (3,)}, got {np.shape(value)}") from None
    if not np.all(np.isfinite(weight)) or np.any(weight < 0):
        raise FitError(f"{where}: weights must be finite and >= 0")
    return weight


def prepared_targets(scene, targets, masks, weights, render: dict):
    """For each target: (its view's scene, target image, clip, mask, weight, count of non-finite
    masked values). A view's scene is `scene` with the target's camera / lights override, the
    camera resized to the target, and the `render` settings; non-finite target values are zeroed
    (and counted, so that the fit reports them)."""
    items = normalise_targets(targets)
    masks = per_view(masks, len(items), "masks")
    weights = per_view(weights, len(items), "weights")
    for i, ((item, overrides), mask, weight) in enumerate(zip(items, masks, weights)):
        where = f"targets[{i}]"
        image, clip = load_target(item, where)
        height, width = image.shape[:2]
        try:
            camera = overrides.get("camera")
            camera = dict(camera if camera is not None else scene.camera.to_dict(), width=width, height=height)
            view_scene = scene.with_overrides(camera=camera, lights=overrides.get("lights"), render=render)
        except DifflabError as exc:
            raise FitError(f"{where}: {exc}") from None
        mask = view_mask(mask, (height, width), f"masks[{i}]")
        weight = view_weight(weight, (height, width), f"weights[{i}]") * mask[..., None]
        finite = np.isfinite(image)
        nonfinite = int(np.count_nonzero(~finite & mask[..., None]))
        yield view_scene, np.where(finite & mask[..., None], image, 0.0), clip, mask, weight, nonfinite


def load_views(scene, targets, masks=None, weights=None, device="cpu") -> tuple[object, list[View]]:
    """The scene (validated) and one `View` per target, each with its G-buffer rendered once.

    A view's camera is the scene's (or its override's) with width and height set to the target's."""
    from ..renderers.api import render_frame

    scene = as_scene(scene)
    views = []
    for view_scene, image, clip, mask, weight, nonfinite in prepared_targets(scene, targets, masks, weights,
                                                                             {"method": "raster"}):
        gbuffer = render_frame(view_scene, device=device).gbuffer
        views.append(View(target=image, mask=mask, weight=weight, clip=clip, nonfinite=nonfinite,
                          gbuffer=gbuffer, scene=view_scene))
    return scene, views


def influence(gbuffer: GBuffer, material_ids, any_surface: bool) -> np.ndarray:
    """(H, W) bool: pixels whose colour depends on the fitted materials (or on any surface when
    light intensities are fitted)."""
    if any_surface:
        touched = gbuffer.mask
    else:
        touched = np.isin(gbuffer.material, np.asarray(list(material_ids), np.int32))
        if gbuffer.shading != "phong":  # a sample's colour mixes its points': look at those
            point_material = gbuffer.points.material
            if point_material.size:
                index = np.clip(gbuffer.point_index, 0, point_material.size - 1)
                from_points = np.isin(point_material[index], list(material_ids)) & (gbuffer.point_weight != 0)
                touched = touched | (gbuffer.mask & from_points.any(axis=-1))
    side = gbuffer.spp_side
    h, w = touched.shape[0] // side, touched.shape[1] // side
    return touched.reshape(h, side, w, side).any(axis=(1, 3))

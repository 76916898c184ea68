"""Targets in: images (arrays or files), their per-view camera / lights, masks and weights, checked
at the boundary.

Image arrays are linear RGB floats. Integer arrays (what Pillow returns: 8-bit sRGB code values) are
refused with a message saying how to decode them -- never read as linear -- and so are boolean,
complex and object arrays. Image files are read by `io.load_image` (8- and 16-bit files decoded by
their transfer function, sRGB unless a PNG says otherwise); a decoded file saturates at 1.0: its
ceiling, where highlights clip, and its samples are quantised in steps of 1 / (2^bits - 1). A target
must have its view's camera size.
"""

from __future__ import annotations

import os
import numpy as np

from ..errors import DifflabError, FitError
from ..io import load_image, sample_bits

OVERRIDE_KEYS = ("camera", "lights")


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


def load_target(item, where: str) -> tuple[np.ndarray, float | None]:
    """(image (H, W, 3) linear floats -- a copy of an array, in its own precision; float64 from a file --, its
    sample step: 1 / 255 for 8-bit image files, 1 / 65535 for 16-bit ones (their ceiling is 1.0),
    None for float data)."""
    if _is_path(item):
        try:
            image, bits = load_image(item), sample_bits(item)
        except DifflabError as exc:
            raise FitError(f"{where}: {exc}") from None
        return np.asarray(image, np.float64), (None if bits is None else 1.0 / (2 ** bits - 1))
    if not isinstance(item, np.ndarray) and not hasattr(item, "__array__"):
        raise FitError(f"{where}: expected an image array or a file path, got {type(item).__name__}")
    image = np.asarray(item)
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise FitError(f"{where}: expected an (H, W, 3) image, got shape {image.shape} of {image.dtype}")
    image = image[..., :3]
    if image.dtype.kind in "iu":
        raise FitError(f"{where}: an integer image ({image.dtype}) holds sRGB code values, not linear light; pass "
                       "the file's path, or decode it: difflab.io.srgb_to_linear(image / 255.0) for 8-bit, with "
                       "ceiling=1.0 for its clipped highlights")
    if image.dtype.kind != "f":
        raise FitError(f"{where}: an image of dtype {image.dtype} is refused; give linear RGB floats")
    return np.array(image), None  # (a copy: the fit reads it later)


def per_view(values, count: int, name: str) -> list:
    """One value per view: None, a single mask / weight for all views, or a list of `count`."""
    if values is None:
        return [None] * count
    if isinstance(values, np.ndarray) or _is_path(values):
        values = [values] * count
    if not isinstance(values, (list, tuple)):
        raise FitError(f"{name}: expected an array, an image path or a list of one per target, "
                       f"got {type(values).__name__}")
    values = list(values)
    if len(values) != count:
        raise FitError(f"{name}: expected one per target ({count}), got {len(values)}")
    return values


def _numeric(value, where: str) -> np.ndarray:
    """A real-valued (or boolean) array, or FitError naming the argument."""
    array = np.asarray(value) if isinstance(value, np.ndarray) or hasattr(value, "__array__") else None
    if array is None:
        try:
            array = np.asarray(value, np.float64)
        except (TypeError, ValueError):
            array = np.asarray([], object)
    if array.dtype.kind not in "biuf":
        raise FitError(f"{where}: expected a real-valued array, got {type(value).__name__} of {array.dtype}")
    return array.astype(np.float64) if array.dtype.kind != "b" else array


def view_mask(value, shape, where) -> np.ndarray:
    """A view's boolean mask (H, W) from None (all), an array or an image path."""
    if value is None:
        return np.ones(shape, bool)
    if _is_path(value):
        try:
            value = load_image(value, srgb=False)[..., 0] > 0.5
        except DifflabError as exc:
            raise FitError(f"{where}: {exc}") from None
    mask = _numeric(value, where)
    if mask.ndim == 3:
        mask = mask[..., 0]
    if mask.shape != shape:
        raise FitError(f"{where}: expected shape {shape}, got {mask.shape}")
    return mask.astype(bool)


def view_weight(value, shape, where) -> np.ndarray:
    """A view's non-negative per-pixel weights (an array) broadcast to (H, W, 3)."""
    weight = _numeric(value, where)
    if weight.ndim == 2:
        weight = weight[..., None]
    try:
        weight = np.broadcast_to(weight, shape + (3,))  # read-only: the caller's product is the copy
    except ValueError:
        raise FitError(f"{where}: expected shape {shape} or {shape + (3,)}, got {np.shape(value)}") from None
    if not np.all(np.isfinite(weight)) or np.any(weight < 0):
        raise FitError(f"{where}: weights must be finite and >= 0")
    return weight


def in_channels(mask) -> np.ndarray:
    """(H, W, 3) bool: an (H, W) mask repeated over the channels (numpy broadcasts over 3 slowly)."""
    return np.repeat(mask.reshape(-1), 3).reshape(mask.shape + (3,))


def nonfinite_count(image, mask) -> int:
    """How many values of an (H, W, 3) image inside the (H, W) mask are not finite."""
    finite = np.isfinite(image)
    return 0 if finite.all() else int(np.count_nonzero(~finite & in_channels(mask)))


def prepared_targets(scene, targets, masks, weights, render: dict):
    """For each target: (its view's scene, target image (`load_target`: a copy, in its own precision),
    sample step (`load_target`), mask, weight, count of non-finite masked values). A view's scene is
    `scene` with the target's camera / lights override and the `render` settings; the target must have
    that camera's size. The weight is (H, W, 3) float64, 0 outside the mask, or None when not given
    (1 inside the mask)."""
    items = normalise_targets(targets)
    masks = per_view(masks, len(items), "masks")
    weights = per_view(weights, len(items), "weights")
    for i, ((item, overrides), mask, weight) in enumerate(zip(items, masks, weights)):
        where = f"targets[{i}]"
        image, step = load_target(item, where)
        height, width = image.shape[:2]
        try:
            same = not overrides and all(getattr(scene.render, k) == v for k, v in render.items())
            view_scene = scene if same else scene.with_overrides(camera=overrides.get("camera"),
                                                                 lights=overrides.get("lights"), render=render)
        except DifflabError as exc:
            raise FitError(f"{where}: {exc}") from None
        camera = view_scene.camera
        if (camera.height, camera.width) != (height, width):
            raise FitError(f"{where}: the image is {width}x{height} (width x height) but its view's camera renders "
                           f"{camera.width}x{camera.height}; resize the target or set the camera's width / height")
        mask = view_mask(mask, (height, width), f"masks[{i}]")
        if weight is not None:
            weight = view_weight(weight, (height, width), f"weights[{i}]") * in_channels(mask)
        yield view_scene, image, step, mask, weight, nonfinite_count(image, mask)

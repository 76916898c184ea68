"""Targets in: images (arrays or files), their per-view camera / lights, masks and weights, checked
at the boundary.

Image arrays are linear RGB floats. Integer arrays and integer .npy files (code values: what
Pillow returns, or a 16-bit file read by another reader) are refused with a message saying how to
decode them for their dtype -- never read as linear (`io.refuse_code_values`, the one rule) --,
and so are boolean, complex and object arrays, and grey images (files and arrays with one colour
channel, a palette PNG of greys only too: `_refuse_grey`), which are not equal R, G, B. Image files
are read by `io.read_image` (as `load_image`: 8- and 16-bit files decoded by their transfer
function, sRGB unless a PNG says otherwise); a decoded file saturates at 1.0: its ceiling, where highlights clip, and its samples
are quantised in steps of 1 / (2^bits - 1). A target must have its view's camera size.
"""

from __future__ import annotations

import os
import numpy as np

from ..errors import DifflabError, FitError
from ..io import image_file, read_image, read_npy, refuse_code_values
from ..limits import short_path
from ..picture import read_picture

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


def load_target(item, where: str) -> tuple[np.ndarray, float | None, float | None]:
    """(image (H, W, 3) linear floats -- a copy of an array, in its own precision; from a file its
    float32 values as decoded (`io.read_image`; as float64 they cost a first fit of a 256 x 256 8-bit
    PNG ~0.04 ms more) --, its sample step: 1 / 255 for 8-bit image files, 1 / 65535 for 16-bit ones (their ceiling is 1.0),
    None for float data, and the file's gamma as `io.read_image` decoded it: None for sRGB (or float
    data), 1.0 for linear samples -- with the step, what `io.code_step` needs)."""
    if _is_path(item):
        try:
            image, bits, channels, gamma = read_image(item)
        except DifflabError as exc:
            raise FitError(f"{where}: {exc}") from None
        if channels == 1:  # 8- or 16-bit, 1-bit, with alpha or not, a grey palette, a .npy (H, W), (H, W, 1 or 2)
            _refuse_grey(f"{where} ({short_path(item)})", "a grey image file")
        return image, (None if bits is None else 1.0 / (2 ** bits - 1)), gamma
    if not isinstance(item, np.ndarray) and not hasattr(item, "__array__"):
        raise FitError(f"{where}: expected an image array or a file path, got {type(item).__name__}")
    image = np.asarray(item)
    if image.ndim == 2 or (image.ndim == 3 and image.shape[-1] in (1, 2)):
        _refuse_grey(where, f"an array of shape {image.shape}")
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise FitError(f"{where}: expected an (H, W, 3) image, got shape {image.shape} of {image.dtype}")
    image = image[..., :3]
    try:
        refuse_code_values(image.dtype, where)
    except DifflabError as exc:
        raise FitError(str(exc)) from None
    if image.dtype.kind != "f":
        raise FitError(f"{where}: an image of dtype {image.dtype} is refused; give linear RGB floats")
    return np.array(image), None, None  # (a copy: the fit reads it later)


def _refuse_grey(where: str, what: str) -> None:
    """The one rule for a grey target: difflab renders 3 channels (linear RGB), and a grey image is not
    taken for equal R, G and B -- a luminance camera does not see them equal --; FitError naming the
    target, its channel count and the scene's, and how to make equal RGB if that is what is meant."""
    raise FitError(f"{where}: {what} has 1 colour channel (grey) but the scene renders 3 (linear RGB); "
                   "a grey target is not fitted as equal R, G, B: give an RGB image -- if equal RGB is meant, "
                   "np.repeat(grey[..., None], 3, axis=-1) of the (H, W) grey values, or the file saved as RGB")


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


def _mask_rule(values: np.ndarray) -> np.ndarray:
    """(H, W) bool from mask values in [0, 1], (H, W), (H, W, 3) or (H, W, 4) (colour and alpha): a
    pixel is in where its colour's brightest channel is > 0.5 and its alpha, if any, > 0.5."""
    if values.ndim == 2:
        return values.copy() if values.dtype == bool else values > 0.5  # (a bool compared with 0.5: 10x a copy)
    inside = values[..., :3].max(axis=-1) > 0.5
    return inside & (values[..., 3] > 0.5) if values.shape[-1] == 4 else inside


def mask_array(value, where: str) -> np.ndarray:
    """(H, W) bool from a mask array -- (H, W), (H, W, 3) or (H, W, 4) -- of bools or of 0 and 1
    only (`_mask_rule`); any other value (NaN, -1, 255, 0.5) is a FitError naming the mask and them."""
    values = _numeric(value, where)
    if values.ndim not in (2, 3) or (values.ndim == 3 and values.shape[-1] not in (3, 4)):
        raise FitError(f"{where}: expected a mask of shape (H, W), (H, W, 3) or (H, W, 4), got {values.shape}")
    if values.dtype.kind != "b":
        bad = np.unique(values[(values != 0) & (values != 1)])  # (NaN != 0: bad too)
        if bad.size:
            count = np.count_nonzero((values != 0) & (values != 1))
            values = f"{count} value{'s are' if count > 1 else ' is'}"
            raise FitError(f"{where}: a mask holds bools or only 0 and 1; {values} not: "
                           f"{', '.join(f'{v:g}' for v in bad[:5])}{', ...' if bad.size > 5 else ''}")
    return _mask_rule(values)


def load_mask(path, where: str) -> np.ndarray:
    """(H, W) bool from a mask file: a .npy array (`mask_array`), or a picture whose samples are
    taken as they are, s / (2^bits - 1) without decoding, by `_mask_rule`: white or any bright
    colour is in, black or transparent (alpha <= 0.5) out. FitError naming the mask and the file."""
    try:
        path = image_file(path)
        array = read_npy(path) if path.suffix.lower() == ".npy" else None
        samples = read_picture(path, alpha=True)[0] if array is None else None
    except DifflabError as exc:
        raise FitError(f"{where}: {exc}") from None
    if array is not None:
        return mask_array(array, f"{where} ({short_path(path)})")
    return _mask_rule(samples / np.float32(np.iinfo(samples.dtype).max))


def view_mask(value, shape, where) -> np.ndarray:
    """A view's boolean mask (H, W) from None (all), an array (`mask_array`) or a file (`load_mask`)."""
    if value is None:
        return np.ones(shape, bool)
    mask = load_mask(value, where) if _is_path(value) else mask_array(value, where)
    if mask.shape != shape:
        raise FitError(f"{where}: expected shape {shape}, got {mask.shape}")
    return mask


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


def nonfinite_count(image, pixels=None) -> int:
    """How many values of an (H, W, 3) image -- or of its rows at the flat indices `pixels` -- are
    not finite."""
    finite = np.isfinite(image if pixels is None else image.reshape(-1, 3)[pixels])
    return 0 if finite.all() else int(np.count_nonzero(~finite))


def prepared_targets(scene, targets, masks, weights, render: dict):
    """For each target: (its view's scene, target image (`load_target`: a copy, in its own precision),
    sample step and gamma (`load_target`), mask, weight, count of its non-finite values (all: which
    of them the fit would read is known once the pixels it uses are, `Setup._used`), labels: (the
    target's, e.g. "targets[0] (a.png)"; the mask's, e.g. "masks[0] (m.png)", or None without one)).
    A view's scene is
    `scene` with the target's camera / lights override and the `render` settings; the target must have
    that camera's size. The weight is (H, W, 3) float64, 0 outside the mask, or None when not given
    (1 inside the mask)."""
    items = normalise_targets(targets)
    masks = per_view(masks, len(items), "masks")
    weights = per_view(weights, len(items), "weights")
    for i, ((item, overrides), mask, weight) in enumerate(zip(items, masks, weights)):
        where = f"targets[{i}]"
        image, step, gamma = load_target(item, where)
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
        labels = (_label(where, item), None if masks[i] is None else _label(f"masks[{i}]", masks[i]))
        yield view_scene, image, step, gamma, mask, weight, nonfinite_count(image), labels


def _label(where: str, item) -> str:
    """`where`, and the file's name when `item` is a path: how messages name a target or mask."""
    return f"{where} ({short_path(item)})" if _is_path(item) else where


def nonfinite_detail(labels, views, shown: str, showing) -> str:
    """Why a fit has "nonfinite_target": per view with non-finite target values at the pixels it
    uses, how many values (NaN, inf) and pixels, naming the target and its mask; where none of
    those pixels shows `shown` (e.g. "material red") -- per view, `showing` (H, W) bool: the pixels
    that do -- (a surface it lights, a mirror reflecting it), that a mask can leave them out."""
    parts = []
    for (target, mask), view, shows in zip(labels, views, showing):
        if view.nonfinite:
            inside = view.used[..., None]
            nan = int(np.count_nonzero(np.isnan(view.image) & inside))
            bad = (~np.isfinite(view.image) & inside).any(axis=-1)
            pixels = int(np.count_nonzero(bad))
            values = f"{view.nonfinite} non-finite value{'s' if view.nonfinite > 1 else ''}"
            hint = "" if np.any(bad & shows) else \
                f" -- none of them shows {shown}: leave them out with a mask (masks= / --mask)"
            parts.append(f"{target} holds {values} ({nan} NaN, {view.nonfinite - nan} inf) "
                         f"in {pixels} pixel{'s' if pixels > 1 else ''} the fit uses"
                         f"{f' inside {mask}' if mask else ''}{hint}")
    return "; ".join(parts)


def empty_detail(labels, views, shown: str) -> str:
    """Why a fit has "empty_mask" (no view uses a pixel): per view, what its mask holds and whether
    any of those pixels shows `shown` (e.g. "material(s) red") -- or that the weights are 0 there."""
    parts = []
    for (target, mask), view in zip(labels, views):
        inside = int(np.count_nonzero(view.mask))
        showing = int(np.count_nonzero(view.mask & view.touched))
        if mask is None:
            parts.append(f"{target}: no pixel shows {shown}")
        elif inside == 0:
            parts.append(f"{target}: the mask {mask} selects no pixel (none is bright and opaque)")
        elif showing == 0:
            parts.append(f"{target}: the mask {mask} holds {inside} pixels, none showing {shown}")
        else:
            parts.append(f"{target}: the weights are 0 at the {showing} pixels of the mask {mask} showing {shown}")
    return "; ".join(parts)

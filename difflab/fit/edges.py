"""Interior masks: the pixels at least `margin` pixels from every edge in the image.

difflab samples a pixel at its centre (spp = 1) or on a fixed spp x spp grid. An anti-aliased
image -- Mitsuba's film, POV-Ray with +A, a camera's lens and sensor -- averages the pixel's area
through a filter instead, so each pixel an edge crosses holds a mix of both sides weighted by
coverage. difflab's model cannot reproduce those pixels from its samples, and a fit that counts
them puts the mix into the coefficients (a Mitsuba diffuse sphere: kd 3 % low, a faint specular
lobe faking the darkened rim, chi2 ~ 400). `interior_mask` keeps the pixels whose whole
(2 margin + 1) x (2 margin + 1) neighbourhood shows one region; a fit given it as its mask
(`difflab fit --edge-margin N`, `difflab fit-batch --edge-margin N`) compares only those.

A region is what the scene's G-buffer records per sample: the object and material seen, and for
Phong-shaded (and ray-traced) records also the checker cell and each light's shadow-ray
visibility, so that silhouettes, object and material boundaries, checker edges and shadow edges
all count, and so does the image's border (what lies beyond it is unknown). Edges seen only in
reflections or refractions, a spotlight's cone edge and texture detail do not.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..errors import DifflabError, FitError


def check_margin(value, where: str = "margin", given=None) -> int:
    """`value` as a margin in pixels, an integer >= 0 (a bool is not one), else FitError naming `where`
    and what was given (`given`, else `value`)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise FitError(f"{where}: expected an integer number of pixels >= 0, got {value if given is None else given!r}")
    return int(value)


def margin_text(text: str, where: str = "--edge-margin") -> int:
    """A margin read from the command line ("2"): `check_margin` of its integer, naming the text."""
    try:
        value = int(text.strip())
    except ValueError:
        value = None
    return check_margin(value, where, text)


def region_keys(gbuffer) -> list[np.ndarray]:
    """Per-sample arrays (on the G-buffer's sample grid) whose change between two samples marks an
    edge: object and material ids, and under Phong shading (every ray-traced record) the checker
    cell and each light's visibility. (The renderers cast shadow rays only from surfaces facing
    the light, visibility 1 elsewhere: the terminator, where a surface turns away, is no edge.)
    Flat and Gouraud records keep cells and visibility per face or vertex, which their shading
    spreads smoothly anyway."""
    keys = [gbuffer.object, gbuffer.material]
    if gbuffer.shading == "phong":
        keys.append(np.asarray(gbuffer.points.cell).reshape(gbuffer.mask.shape))
        visibility = gbuffer.visibility
        keys.extend(visibility[..., p] for p in range(visibility.shape[-1]))
    return keys


def _window(values: np.ndarray, margin: int, reduce) -> np.ndarray:
    """`reduce` (np.min or np.max) of `values` over the (2 margin + 1)^2 square around each pixel (the
    image's border extended outwards)."""
    out = np.pad(values, margin, mode="edge")
    for axis in (0, 1):
        out = reduce(sliding_window_view(out, 2 * margin + 1, axis=axis), axis=-1)
    return out


def interior_mask(source, *, margin: int = 2, device=None, method=None, spp=None) -> np.ndarray:
    """(H, W) bool: True at the pixels at least `margin` pixels (in rows and columns) from every edge,
    i.e. every sample of the pixel and of its neighbours up to `margin` away shows one region (see
    the module doc), and at least `margin` from the image's border, which counts as an edge (a
    silhouette just beyond it mixes the border pixels unseen: a Mitsuba sphere whose top touches the
    frame, fitted at 48 x 48, reads kd 1.8 % off with its border rows, 0.6 % without). Background
    pixels far from objects are kept (a fit uses no pixel its materials do not reach). margin 0:
    every pixel.

    Arguments:
        source: a Scene, scene dict or scene file (rendered with its own render settings, or the
            `method` / `spp` given), a `CompiledScene`, or a `Frame` from `render_frame` (its
            G-buffer read).
        margin: pixels, an integer >= 0. 1 leaves out the pixels next to an edge, what a box
            filter of one pixel mixes; 2 (default) also covers a filter up to ~2 pixels wide
            (Mitsuba's default gaussian: radius 2) and a silhouette that difflab's tessellated
            sphere places up to half a pixel off.
        device: where a scene is rendered ("cpu" default; a CompiledScene renders on its own).
        method, spp: a scene's record as a fit given them makes it ("raster" / "raytrace", samples
            per pixel; None: the scene's own), as `render_frame` takes them.
    Raises FitError for a margin that is not an integer >= 0 (naming `margin`); RenderError for a
    scene that cannot be rendered, or a Frame that kept no G-buffer.
    """
    from ..renderers.api import render_frame
    from ..renderers.frame import Frame

    margin = check_margin(margin)
    if isinstance(source, Frame):
        frame = source
    else:
        frame = render_frame(source, image=False, method=method, spp=spp,
                             **({} if device is None else {"device": device}))
    gbuffer = frame.gbuffer
    side = gbuffer.spp_side
    height, width = gbuffer.mask.shape[0] // side, gbuffer.mask.shape[1] // side
    keep = np.ones((height, width), bool)
    if margin == 0:
        return keep
    for key in region_keys(gbuffer):
        blocks = np.asarray(key).reshape(height, side, width, side)
        low, high = blocks.min(axis=(1, 3)), blocks.max(axis=(1, 3))
        keep &= _window(low, margin, np.min) == _window(high, margin, np.max)
    keep[:margin], keep[-margin:], keep[:, :margin], keep[:, -margin:] = False, False, False, False
    return keep


def margin_masks(scene, targets, masks, margin: int, device=None, method=None, spp=None, materials=None,
                 params=None) -> list[np.ndarray] | None:
    """Per view of `targets` (`fit`'s forms: images, paths, (image, overrides) pairs), its mask
    (`masks`: None, one for all or one per view; arrays or files) intersected with the
    `interior_mask` of the view's scene (`scene` under the view's camera / lights, recorded as the
    fit of `materials` / `params` (None: `fit`'s defaults) records it: with its `spp` (None: the
    scene's) and its image model, `method` or the one the fit chooses, `arguments.choose_method`);
    `masks` as given when margin is 0. What `difflab fit --edge-margin` and a batch line's
    edge_margin give the fit."""
    from ..renderers.compile import as_scene
    from ..scene import RenderSettings
    from .arguments import choose_method
    from .params import DEFAULT_PARAMS, fitted_materials
    from .targets import normalise_targets, per_view, view_mask
    from .texels import wants_texels

    margin = check_margin(margin, "edge_margin")
    if margin == 0:
        return masks
    try:  # (named as the fit names it)
        scene = as_scene(scene)
    except DifflabError as exc:
        raise FitError(f"scene: {exc}") from None
    method = choose_method(scene, fitted_materials(scene, materials), method,
                           wants_texels(DEFAULT_PARAMS if params is None else params))
    try:  # the fit's method and spp, checked as the fit checks them
        RenderSettings.parse({**scene.render.to_dict(), **({} if method is None else {"method": method}),
                              **({} if spp is None else {"spp": spp})}, "")
    except DifflabError as exc:
        raise FitError(str(exc)) from None
    views = normalise_targets(targets)
    out = []
    for i, ((_, overrides), mask) in enumerate(zip(views, per_view(masks, len(views), "masks"))):
        view = scene.with_overrides(camera=overrides.get("camera"), lights=overrides.get("lights")) \
            if overrides else scene
        interior = interior_mask(view, margin=margin, device=device, method=method, spp=spp)
        out.append(interior if mask is None else interior & view_mask(mask, interior.shape, f"masks[{i}]"))
    return out

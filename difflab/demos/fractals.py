"""Fractal pictures for the command line and the demo: curves drawn as figures, sets rendered."""

from __future__ import annotations

import numbers
import tempfile
from pathlib import Path

import numpy as np

from ..fractals import (box_counting_dimension, cantor_staircase, hilbert, julia, koch_snowflake, mandelbrot,
                        mandelbulb, peano, polyline_length, terrain, terrain_scene)
from ..errors import RenderError
from ..fractals._checks import FractalError, check_int
from ..fractals.cantor import MAX_STAIRCASE_DEPTH
from ..io import save_image
from ..limits import CURVE_PIXEL_BYTES, require_image, require_memory, require_triangles
from ..renderers.api import render
from ..vocabulary import FRACTAL_CURVES as CURVES
from ..vocabulary import FRACTAL_IMAGES as IMAGES
from ..vocabulary import FRACTAL_KINDS as KINDS
from .figures import image_grid, save_figure


#: Work budget of `fractal_figure` (so of `difflab fractal --order`): a curve of at most 2^20 vertices
#: (koch 9, peano 6, hilbert 10) is drawn and box-counted in ~4 s and ~170 MiB on 2 cores, each order
#: more takes 4 (9) times that; a terrain of at most 2^21 triangles (level 10) renders in ~16 s and
#: ~1 GB, level 11 would take a minute and 4 GB. Measured 2026-11-30 with `difflab fractal`.
MAX_CURVE_VERTICES = 2 ** 20
MAX_TERRAIN_TRIANGLES = 2 ** 21
#: Peak bytes a curve vertex costs through its points, box counting and drawing (measured 158-172:
#: koch 8 -> 9, hilbert 9 -> 10).
CURVE_VERTEX_BYTES = 190


def curve_vertices(kind: str, order: int) -> int:
    """Vertices of a curve's polyline at `order` (the cantor staircase is always 4097 samples)."""
    return {"koch": 3 * 4 ** order + 1, "peano": 9 ** order, "hilbert": 4 ** order}.get(kind, 4097)


def _largest(count, lo: int, cap: int) -> int:
    order = lo
    while count(order + 1) <= cap:
        order += 1
    return order


#: Orders `fractal_figure` accepts per kind (the work budget above; cantor: the staircase's digits).
ORDER_RANGES = {**{kind: (0, _largest(lambda n, kind=kind: curve_vertices(kind, n), 0, MAX_CURVE_VERTICES))
                   for kind in ("koch", "peano", "hilbert")},
                "cantor": (1, MAX_STAIRCASE_DEPTH),
                "terrain": (1, _largest(lambda n: 2 * 4 ** n, 1, MAX_TERRAIN_TRIANGLES))}


def check_order(kind: str, order, name: str = "order") -> int:
    """`order` of a curve or the terrain as an int within ORDER_RANGES[kind] and priced against the
    memory budget (curve vertices x CURVE_VERTEX_BYTES, terrain triangles x TRIANGLE_BYTES), before
    anything is built; else a FractalError / RenderError naming `name` (the CLI's `--order`)."""
    lo, hi = ORDER_RANGES[kind]
    if isinstance(order, bool) or not isinstance(order, numbers.Integral) or not lo <= order <= hi:
        why = {"cantor": "the staircase's ternary digits",
               "terrain": f"levels up to {hi}: at most {MAX_TERRAIN_TRIANGLES} triangles, rendered in seconds"}.get(
            kind, f"orders up to {hi}: at most {MAX_CURVE_VERTICES} curve vertices, drawn and box-counted in seconds")
        raise FractalError(f"{name}: the {kind} fractal takes {lo}..{hi} ({why}), got {order!r}")
    label = name if name.startswith("-") else f"{name} ="
    if kind == "terrain":
        require_triangles(2 * 4 ** order, f"{label} {order}: the terrain", RenderError)
    elif kind != "cantor":
        count = curve_vertices(kind, order)
        require_memory(count * CURVE_VERTEX_BYTES, f"{label} {order}: the {kind} curve ({count} vertices)",
                       RenderError)
    return int(order)


def curve_points(kind: str, order: int) -> tuple[np.ndarray, str]:
    """The polyline of a curve fractal and a caption with its measures."""
    if kind == "koch":
        points = koch_snowflake(order)
        return points, f"Koch snowflake, n = {order}: perimeter {polyline_length(points):.6g} = 3 (4/3)^{order}"
    if kind in ("peano", "hilbert"):
        points = (peano if kind == "peano" else hilbert)(order)
        return points, f"{kind.capitalize()} curve, order {order}: {len(points)} cells, length {polyline_length(points):.4g}"
    x = np.linspace(0.0, 1.0, curve_vertices(kind, order))
    return np.stack([x, cantor_staircase(x, depth=order)], axis=1), \
        f"Cantor staircase, depth {order}: 1/2 on [1/3, 2/3], steps summing to 1"


def draw_curve(kind: str, order: int, path: Path, width: int = 512, height: int = 512, titled: bool = True) -> str:
    """Draw a curve fractal to `path` (atomically); returns its caption (with a box-counting dimension).

    titled: the caption as title, on a square figure of max(width, 256) pixels cropped to what is
    drawn (the demo's figures); else an image of exactly width x height pixels, the curve fit into it
    with equal axes and no title (`difflab fractal KIND --width W --height H`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    width, height = (max(width, 256),) * 2 if titled else (check_int("width", width, 1), check_int("height", height, 1))
    require_image(width, height, f"{kind}: a figure of", CURVE_PIXEL_BYTES, RenderError)
    points, caption = curve_points(kind, order)
    if kind != "cantor" and len(points) > 16:
        caption += f", box-counting dimension {box_counting_dimension(points):.3f}"
    fig = plt.figure(figsize=(width / 100, height / 100), dpi=100)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0)) if not titled else fig.add_subplot()
    ax.plot(points[:, 0], points[:, 1], lw=0.8, color="#1f4e79")
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    if titled:
        ax.set_title(caption, fontsize=7)
    else:
        ax.margins(0.02)
        ax.set_axis_off()
    save_figure(fig, Path(path), tight=titled)
    return caption


def render_set(kind: str, width: int, height: int, *, order: int = 7, seed: int = 0, hurst: float = 0.8,
               max_iter: int = 256, device: str = "cpu", progress=None) -> np.ndarray:
    """A linear RGB image of a 2D set, the Mandelbulb, or a fractal terrain (rasterized with shadows).

    progress: None, or called as progress(done, total): a set's rows computed (of height), the
    terrain's steps (of 3: the heights, its band meshes written, the render; ~4, 10 and 10 s at
    level 10)."""
    if kind == "mandelbrot":
        return mandelbrot(width, height, max_iter=max_iter, device=device, progress=progress)
    if kind == "julia":
        return julia(width, height, max_iter=max_iter, device=device, progress=progress)
    if kind == "mandelbulb":
        return mandelbulb(width, height, device=device, progress=progress)
    tick = progress or (lambda done, total: None)
    mesh = terrain(level=order, hurst=hurst, seed=seed)
    tick(1, 3)
    with tempfile.TemporaryDirectory() as folder:
        scene = terrain_scene(mesh, folder, width=width, height=height)
        tick(2, 3)
        image = render(scene, device=device)
    tick(3, 3)
    return image


SET_TITLES = {
    "terrain": "fractal terrain (diamond-square, H = {hurst}, level {order}), rasterized with shadows",
    "mandelbrot": "Mandelbrot set, z <- z^2 + c, smooth colouring ({max_iter} iterations)",
    "julia": "Julia set, c = -0.8 + 0.156i ({max_iter} iterations)",
    "mandelbulb": "Mandelbulb (power 8), ray marched, lit by the illumination model, soft shadows",
}


def fractal_figure(kind: str, path: Path, width: int, height: int, *, titled: bool = True, order_name: str = "order",
                   progress=None, **options) -> str:
    """Write one fractal picture to `path`; returns what it shows. When `titled` (the demo's
    figures) a curve is drawn with its caption as title and a set with its title above the image;
    else (`difflab fractal KIND -o out.png`) either is the bare width x height image. `order` is
    checked by `check_order` (its range and memory), errors naming it `order_name` (the CLI: --order).
    progress: `render_set`'s, for the sets and the terrain (a curve is drawn in seconds at most)."""
    if kind in ORDER_RANGES:
        options["order"] = check_order(kind, options.get("order", 4 if kind in CURVES else 7), order_name)
    if kind in CURVES:
        return draw_curve(kind, options["order"], path, width, height, titled=titled)
    image = render_set(kind, width, height, progress=progress, **options)
    values = {"hurst": options.get("hurst", 0.8), "order": options.get("order", 7), "max_iter": options.get("max_iter", 256)}
    caption = SET_TITLES[kind].format(**values) + f" ({width}x{height})"
    if not titled:
        save_image(path, image)
        return caption
    image_grid([image], [caption], path, columns=1)
    return caption


def gallery(out: Path, size: int) -> list[tuple[Path, str]]:
    """The demo's fractal gallery: one figure per kind."""
    orders = {"koch": 4, "peano": 3, "hilbert": 5, "cantor": 8, "terrain": 6}
    written = []
    for kind in KINDS:
        path = Path(out) / f"fractal_{kind}.png"
        caption = fractal_figure(kind, path, size, size * 3 // 4, order=orders.get(kind, 7))
        written.append((path, caption))
    return written

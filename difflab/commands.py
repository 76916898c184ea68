"""Subcommands of the `difflab` command line: each `add_*` registers one and sets its `func`."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from .errors import RenderError
from .files import add_force
from .vocabulary import FRACTAL_KINDS, MAX_DEPTH_LIMIT, METHODS, SHADING_MODELS, SPECULAR_MODELS


def run_render(args) -> int:
    from .files import refuse_overwrite, write_together
    from .io import write_image
    from .renderers.api import prepare, render

    out = Path(args.output)
    linear = out.with_suffix(".npy") if args.linear and out.suffix.lower() != ".npy" else None  # (.npy is linear)
    refuse_overwrite(out, *([linear] if linear else []), force=args.force)
    scene = prepare(args.scene, args.width, args.height, method=args.method, shading=args.shading,
                    specular=args.specular, max_depth=args.max_depth, spp=args.spp)
    method = scene.render.method
    refuse_unused(args, method)
    start = time.perf_counter()
    image = render(scene, device=args.device)  # the image alone: no G-buffer, no recorded ray tree
    seconds = time.perf_counter() - start
    write_together({path: lambda temporary, path=path: write_image(temporary, image, name=path)
                    for path in ([out, linear] if linear else [out])})  # the image and its linear copy: both or neither
    print(f"wrote {out} ({image.shape[1]}x{image.shape[0]}, {method}, {seconds:.3f} s)" +
          (f" and {linear}" if linear else ""))
    return 0


def refuse_unused(args, method: str) -> None:
    """DifflabError for a render flag the renderer of `method` does not use (`--shading` with the ray
    tracer, `--max-depth` with the rasterizer: `renderers.api.NOT_USED`), whatever its value."""
    from .renderers.api import NOT_USED

    unused, why = NOT_USED[method]
    for name in unused:
        if getattr(args, name, None) is not None:
            flag = "--" + name.replace("_", "-")
            raise RenderError(f"{flag}: does not apply to this render's method {method!r} ({why.replace('method=', '--method ')})")


def output_ending(*suffixes):
    """argparse type of an output file: a path ending in one of `suffixes` (any case), else the
    one-line exit-2 error naming them (Pillow would write a JPEG or TIFF of a linear image silently;
    `fit` would write JSON under a .png name). An existing folder passes here: the output check
    (`cli.check_outputs`) names it as a folder."""
    def check(text: str) -> str:
        if Path(text).suffix.lower() not in suffixes and not Path(text).is_dir():
            raise argparse.ArgumentTypeError(f"{text!r}: give a file name ending in {' or '.join(suffixes)}")
        return text
    return check


def add_render(sub) -> None:
    p = sub.add_parser("render", help="render a scene file to an image")
    p.add_argument("scene", help="scene JSON file")
    p.add_argument("-o", "--output", required=True, type=output_ending(".png", ".npy"),
                   help="output image: .png (8-bit sRGB) or .npy (linear floats)")
    p.add_argument("--method", choices=METHODS, help="renderer (default: the scene's)")
    p.add_argument("--shading", choices=tuple(SHADING_MODELS),
                   help="shading model, rasterizer only (default: the scene's)")
    p.add_argument("--specular", choices=tuple(SPECULAR_MODELS), help="specular term (default: the scene's)")
    p.add_argument("--width", type=int, help="image width in pixels (default: the scene camera's)")
    p.add_argument("--height", type=int, help="image height in pixels (default: the scene camera's)")
    p.add_argument("--spp", type=int, help="samples per pixel, a perfect square: 1, 4, 9, ... (default: the scene's)")
    p.add_argument("--max-depth", type=int,
                   help=f"ray-tree depth, 1..{MAX_DEPTH_LIMIT}, ray tracer only (default: the scene's)")
    p.add_argument("--linear", action="store_true", help="also write the linear float image beside it as .npy")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    add_force(p)
    p.set_defaults(func=run_render)


def run_demo(args) -> int:
    from .demos import run_demo as demo
    from .files import refuse_overwrite

    refuse_overwrite(args.output, force=args.force)
    demo(Path(args.output), quick=args.quick)
    return 0


def add_demo(sub) -> None:
    p = sub.add_parser("demo", help="write the lecture's comparison figures to a folder")
    p.add_argument("-o", "--output", default="difflab-demo", help="folder for the figures")
    p.add_argument("--quick", action="store_true", help="smaller images")
    add_force(p)
    p.set_defaults(func=run_demo, output_is_folder=True)


def run_fractal(args) -> int:
    from .demos.fractals import CURVES, fractal_figure
    from .files import refuse_overwrite

    refuse_overwrite(args.output, force=args.force)
    options = {"order": args.order} if args.order is not None else {}
    if args.kind not in CURVES:
        options.update(seed=args.seed, hurst=args.hurst, max_iter=args.max_iter, device=args.device)
        if args.kind in ("mandelbrot", "julia", "mandelbulb"):
            for key in ("order", "seed", "hurst"):
                options.pop(key, None)
        else:
            options.pop("max_iter")
    caption = fractal_figure(args.kind, Path(args.output), args.width, args.height, titled=False, **options)
    print(f"wrote {args.output}: {caption}")
    return 0


def add_fractal(sub) -> None:
    p = sub.add_parser("fractal", help="draw a fractal curve or render a fractal set")
    p.add_argument("kind", choices=FRACTAL_KINDS)
    p.add_argument("-o", "--output", required=True, type=output_ending(".png"), help="output PNG")
    p.add_argument("--order", type=int, help="iterations / order / depth / terrain level (default: 4 for a curve, 7 "
                   "for the terrain)")
    p.add_argument("--width", type=int, default=640, help="image width in pixels")
    p.add_argument("--height", type=int, default=480, help="image height in pixels")
    p.add_argument("--seed", type=int, default=0, help="terrain seed")
    p.add_argument("--hurst", type=float, default=0.8, help="terrain roughness, the Hurst exponent in (0, 1)")
    p.add_argument("--max-iter", type=int, default=256, help="escape-time iterations")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    add_force(p)
    p.set_defaults(func=run_fractal)


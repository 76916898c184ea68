"""Subcommands of the `difflab` command line: each `add_*` registers one and sets its `func`."""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path

from .errors import RenderError
from .files import add_force
from .vocabulary import FRACTAL_KINDS, FRACTAL_OPTIONS, MAX_DEPTH_LIMIT, METHODS, SHADING_MODELS, SPECULAR_MODELS


def run_render(args) -> int:
    from .files import refuse_overwrite, write_together
    from .io import write_image
    from .renderers.api import NOT_USED, prepare, render

    out = Path(args.output)
    linear = out.with_suffix(".npy") if args.linear and out.suffix.lower() != ".npy" else None  # (.npy is linear)
    refuse_overwrite(out, *([linear] if linear else []), force=args.force)
    scene = prepare(args.scene, args.width, args.height, method=args.method, shading=args.shading,
                    specular=args.specular, max_depth=args.max_depth, spp=args.spp)
    method = scene.render.method
    unused, why = NOT_USED[method]
    refuse_unused(args, unused, f"this render's method {method!r} ({why.replace('method=', '--method ')})")
    start = time.perf_counter()
    image = render(scene, device=args.device)  # the image alone: no G-buffer, no recorded ray tree
    seconds = time.perf_counter() - start
    write_together({path: lambda temporary, path=path: write_image(temporary, image, name=path)
                    for path in ([out, linear] if linear else [out])})  # the image and its linear copy: both or neither
    print(f"wrote {out} ({image.shape[1]}x{image.shape[0]}, {method}, {seconds:.3f} s)" +
          (f" and {linear}" if linear else ""))
    return 0


def refuse_unused(args, unused, context: str) -> None:
    """RenderError for a flag among `unused` that was given (not None), whatever its value: what
    `context` does not read is refused, not ignored (`--shading` with the ray tracer, `--hurst` with
    the Mandelbrot set). The flags of such options default to None."""
    for name in unused:
        if getattr(args, name, None) is not None:
            raise RenderError(f"--{name.replace('_', '-')}: does not apply to {context}")


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
    from .demos import is_demo_folder
    from .demos import run_demo as demo
    from .files import refuse_overwrite

    if not is_demo_folder(args.output):  # the demo's own folder is written again, as a batch's is resumed
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
    from .demos.fractals import fractal_figure
    from .files import refuse_overwrite

    used = FRACTAL_OPTIONS[args.kind]
    every = dict.fromkeys(name for names in FRACTAL_OPTIONS.values() for name in names)
    unused = [name for name in every if name not in used]
    reads = ", ".join("--" + name.replace("_", "-") for name in used)
    refuse_unused(args, unused, f"the {args.kind} fractal (it reads {reads})")
    refuse_overwrite(args.output, force=args.force)
    options = {name: getattr(args, name) for name in used if getattr(args, name) is not None}
    with progress_bar(args.kind, "step" if args.kind == "terrain" else "row") as progress:
        caption = fractal_figure(args.kind, Path(args.output), args.width, args.height, titled=False,
                                 order_name="--order", progress=progress, **options)
    print(f"wrote {args.output}: {caption}")
    return 0


@contextlib.contextmanager
def progress_bar(label: str, unit: str):
    """A callback progress(done, total) that draws a tqdm bar on stderr where stderr is a terminal
    (quiet otherwise, as `fit`'s and `fit-batch`'s bars), cleared when the block ends."""
    from tqdm import tqdm

    with tqdm(desc=label, unit=unit, leave=False, disable=None, file=sys.stderr, dynamic_ncols=True, delay=0.5) as bar:
        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        yield progress


def add_fractal(sub) -> None:
    p = sub.add_parser("fractal", help="draw a fractal curve or render a fractal set")
    p.add_argument("kind", choices=FRACTAL_KINDS)
    p.add_argument("-o", "--output", required=True, type=output_ending(".png"), help="output PNG")
    p.add_argument("--width", type=int, default=640, help="image width in pixels")
    p.add_argument("--height", type=int, default=480, help="image height in pixels")
    # Options a kind does not read (vocabulary.FRACTAL_OPTIONS) are errors: their defaults are None.
    p.add_argument("--order", type=int, help="iterations / order / depth / terrain level, curves and terrain "
                   "(default: 4 for a curve, 7 for the terrain)")
    p.add_argument("--seed", type=int, help="terrain seed (default: 0)")
    p.add_argument("--hurst", type=float, help="terrain roughness, the Hurst exponent in (0, 1) (default: 0.8)")
    p.add_argument("--max-iter", type=int, help="escape iterations, mandelbrot and julia (default: 256)")
    p.add_argument("--device", help="cpu or cuda, the sets and the terrain (default: cpu)")
    add_force(p)
    p.set_defaults(func=run_fractal)

"""`difflab fit`: fit materials to target images and write the fitted scene.

    difflab fit SCENE.json TARGET.png [TARGET2.png ...] --material NAME[,NAME2] [--params ka,kd,ks,n]
                [--method raster|raytrace] [--solver lm] [--sigma S] [--mask M.png] [--edge-margin N]
                [--spp N] [--max-depth D] [--init NAME=VALUE] -o fitted.json

The image model is the scene's (the recorded ray tree for ray-traced scenes and mirrors / glass,
else the G-buffer) unless --method says. Prints the fit summary -- values ± standard errors, PSNR,
noise, reduced chi-square, flags -- writes the fitted scene and a report of the fit beside it
(atomically), and exits with:

    0  converged, and the image model explains the targets
    2  invalid input (nothing written)
    3  the solver did not converge (files written, the status in the report)
    4  converged, but MODEL MISMATCH: the residuals sit far above the noise (files written); the
       fitted values answer a different question than asked -- try --method raytrace, other params
       or another specular model; for another renderer's anti-aliased image, --edge-margin 2
       (docs/foreign-targets.md). (Not from noise that is not white: with a NOISE NOT WHITE line,
       chi2 is above 2 even at the higher of its two levels.)
    5  converged, but not settled (`FitResult.not_judged`): NOISE UNKNOWN (too few used pixels
       have used neighbours to estimate the noise: a small, thin or scattered mask -- give --sigma),
       MISMATCH SUSPECTED (sigma estimated: chi2 above its spread but not above 2 -- give --sigma
       to judge the model; with NOISE NOT WHITE -- the noise reads differently between neighbouring
       pixels and pixels 2 apart: a pixel filter or a blur, dithering -- chi2 between the verdicts
       at its two levels: give --sigma, the targets' true noise) or UNDERDETERMINED (no more target
       values than unknowns: the model is not judged either; or parameters the images fix only in
       combination, named: their values are undetermined, the model still judged where the values
       are enough -- with a mismatch too, the exit is 4; both can hold, each printed)

A fitted texture (--params texture) is written beside the scene as OUTPUT_STEM.MATERIAL.texture.npy
(linear float32; OUTPUT_STEM.textureI.npy, I the material's index, where its name is not a plain
word), and the fitted scene's material names that file; the report names it too, with the texels'
statistics (not the texels). The fitted scene, its texture files and the report are written together: all or none (a full disk while writing any leaves the old files, if
any).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from ..errors import EXIT_MODEL_MISMATCH, EXIT_NOT_CONVERGED, EXIT_NOT_JUDGED, EXIT_OK, FitError


def ceiling_value(text: str):
    """argparse type of --ceiling: a number > 0, or "none" (also "inf"): no ceiling -- the API's
    rule (`arguments.check_ceiling`), read from text."""
    from .arguments import check_ceiling

    word = text.strip().lower()
    try:
        return check_ceiling(False if word == "none" else float(word))
    except (ValueError, FitError):
        raise argparse.ArgumentTypeError(f"{text!r}: give a number > 0, or none (the targets do not clip)") from None


def init_value(text: str) -> tuple[str, object]:
    """argparse type of --init: NAME=VALUE, VALUE a number or comma-separated numbers (an RGB
    triple), as (name, float or list); the fit checks the name and the value (`params.apply_init`)."""
    name, equals, value = text.partition("=")
    try:
        numbers = [float(v) for v in value.split(",")] if equals and name.strip() else None
    except ValueError:
        numbers = None
    if numbers is None:
        raise argparse.ArgumentTypeError(f"{text!r}: give NAME=VALUE, VALUE a number or an RGB triple (n=200, "
                                         "kd=0.5,0.4,0.3)")
    return name.strip(), numbers[0] if len(numbers) == 1 else numbers


def in_option_words(text: str) -> str:
    """An engine's message in this command's words: --method raytrace, not method='raytrace';
    --ceiling none, not ceiling=False; --spp / --max-depth / --ceiling / --edge-margin / --init for
    the keywords a message starts with, --mask[i] for masks[i]."""
    text = re.sub(r"method='(\w+)'", r"--method \1", text).replace("ceiling=False", "--ceiling none")
    text = re.sub(r"^init\['([^']*)'\]", r"--init \1", text)
    text = re.sub(r"^masks\[", "--mask[", text)
    return re.sub(r"^(spp|max_depth|ceiling|edge_margin):", lambda m: "--" + m.group(1).replace("_", "-") + ":", text)


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `fit` subcommand to an argparse subparsers object."""
    from ..commands import output_ending
    from ..files import add_force
    from .options import SOLVERS

    p = subparsers.add_parser("fit", help="fit material coefficients to target images",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="scene file (JSON); its values are the starting point")
    p.add_argument("targets", nargs="+", help="target images: 8-bit pictures and 16-bit PNG / TIFF, decoded as sRGB unless a "
                   "PNG's gAMA chunk (without an sRGB chunk) gives another gamma (1.0: linear); .npy holds linear "
                   "floats")
    p.add_argument("--material", action="append", required=True,
                   help="material(s) to fit: a name, or several comma-separated (or the option repeated)")
    p.add_argument("--method", choices=("raster", "raytrace"), default=None,
                   help="image model: the G-buffer (raster) or the recorded ray tree (default: the ray tree for "
                        "a ray-traced scene, a mirror or glass (kr or kt > 0) or a textured material; else the G-buffer)")
    p.add_argument("--sigma", type=float, default=None, help="the targets' pixel noise (default: estimated)")
    p.add_argument("--ceiling", type=ceiling_value, default=None, metavar="VALUE|none",
                   help="where the targets clip (their values there are censored), or none: they do not (default: 1 "
                        "for PNG / TIFF; for .npy the maximum, when some surface has 3 or more values there, at "
                        "under half of its pixels: a clipped highlight)")
    p.add_argument("--spp", type=int, default=None, metavar="N",
                   help="samples per pixel of the recorded G-buffer / ray tree, a perfect square (default: the "
                        "scene's render.spp); to emulate an anti-aliased target's box filter")
    p.add_argument("--max-depth", type=int, default=None, metavar="D",
                   help="the ray tree's depth, the primary ray counting as 1 (default: the scene's; ray tree only)")
    p.add_argument("--init", action="append", type=init_value, default=None, metavar="NAME=VALUE",
                   help="a start value overriding the scene's, e.g. n=200 or kd=0.5,0.4,0.3 (repeat the option for "
                        "more): another start when a fit sits in a local minimum")
    p.add_argument("--params", default=None,
                   help="comma-separated: ka, kd, ks, n (phong, blinn), m, f0 (torrance), kr, kt, absorption, "
                        "texture, intensity, lights[i].intensity, or material.kind (default ka,kd,ks,n; ka,kd,ks,m "
                        "under the torrance model)")
    p.add_argument("--solver", default="lm", choices=SOLVERS)
    p.add_argument("-o", "--output", required=True, type=output_ending(".json"),
                   help="where to write the fitted scene (JSON: a name ending in .json)")
    p.add_argument("--report", type=output_ending(".json"),
                   help="where to write the fit report (JSON, .json; default: OUTPUT with .fit.json)")
    p.add_argument("--mask", action="append", help="mask image per target (white: counts)")
    p.add_argument("--edge-margin", default="0", metavar="N",
                   help="count only pixels at least N pixels from every silhouette, object, checker or shadow edge "
                        "(with --mask: inside both): an anti-aliased target (Mitsuba, POV-Ray +A, a camera) mixes "
                        "the pixels an edge crosses, which difflab samples at their centres; 2 is usually enough "
                        "(difflab.interior_mask; docs/foreign-targets.md)")
    p.add_argument("--grey", action="store_true", help="fit one grey value per coefficient, not RGB")
    p.add_argument("--bounded", action="store_true", help="keep ka, kd, ks in [0, 1]")
    p.add_argument("--loss", default="l2", choices=("l2", "huber", "cauchy"))
    p.add_argument("--max-steps", type=int, default=256)
    p.add_argument("--float32", action="store_true", help="compute in float32 (default float64)")
    p.add_argument("--device", default="cpu", help="where Warp renders the G-buffers (cpu | cuda)")
    add_force(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..files import refuse_overwrite, write_json, write_together
    from ..io import write_image
    from .edges import margin_masks, margin_text
    from .engine import fit
    from .params import DEFAULT_PARAMS, name_list
    from .result import drop_texture_files, texture_files_beside

    output = Path(args.output)
    report = Path(args.report) if args.report else output.with_name(output.stem + ".fit.json")
    if output.resolve() == report.resolve():
        raise FitError(f"--report: the same file as -o/--output ({output}): the report would replace the fitted scene")
    refuse_overwrite(output, report, *texture_files_beside(output.parent, output.stem), force=args.force)
    if args.max_steps < 1:
        raise FitError(f"--max-steps: must be >= 1, got {args.max_steps}")
    masks = args.mask
    if masks is not None and len(masks) != len(args.targets):
        raise FitError(f"--mask: give one per target ({len(args.targets)}), got {len(masks)}")
    margin = margin_text(args.edge_margin, "--edge-margin")
    materials = [name for item in args.material for name in name_list(item, "--material")]
    params = DEFAULT_PARAMS if args.params is None else name_list(args.params, "--params")
    init = None if args.init is None else dict(args.init)
    try:
        if margin:  # the interior of the record the fit makes
            masks = margin_masks(args.scene, list(args.targets), masks, margin, device=args.device, method=args.method,
                                 spp=args.spp, materials=materials, params=params)
        result = fit(args.scene, list(args.targets), materials, params, method=args.method, solver=args.solver,
                     per_channel=not args.grey, bounded=args.bounded, loss=args.loss, masks=masks, sigma=args.sigma,
                     ceiling=args.ceiling, max_steps=args.max_steps, x64=not args.float32, device=args.device,
                     spp=args.spp, max_depth=args.max_depth, init=init)
    except FitError as exc:  # the engine's advice in this command's words
        raise FitError(in_option_words(str(exc))) from None
    if result.no_fit() is not None:  # one error line (exit 2), not a table of start values +- nan
        raise FitError(f"no fit made: {result.no_fit()}")
    print(result.table())
    contents = {output: result.scene_dict(output.stem), report: {
        "scene": str(args.scene), "targets": [str(t) for t in args.targets], "materials": materials,
        **result.to_dict(output.stem, output.parent)}}
    textures = result.texture_files(output.stem)
    writers = {output.with_name(name): lambda temporary, texels=texels: write_image(temporary, texels)
               for name, texels in textures.items()}
    writers.update({path: lambda temporary, data=data: write_json(temporary, data) for path, data in contents.items()})
    write_together(writers)  # every file written before any is renamed onto its path
    drop_texture_files(output.parent, output.stem, keep=textures)  # an earlier run's (--force), as a batch does
    *first, last = map(str, writers)
    print(f"wrote {', '.join(first)} and {last}")
    if not result.converged:
        return EXIT_NOT_CONVERGED
    if result.model_mismatch:
        return EXIT_MODEL_MISMATCH
    return EXIT_NOT_JUDGED if result.not_judged else EXIT_OK

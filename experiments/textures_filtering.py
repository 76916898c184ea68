"""Texture filtering on a receding checkerboard: nearest, bilinear, mip-map (nearest level), trilinear
and EWA against a 32x32-supersampled ground truth; and a kd-texture fit at scale.

For each filter: RMSE over the image and over the far region (the rows nearest the horizon), a moire
measure (RMS error energy above 1/8 cycle per pixel in the far region; `difflab.demos.textures.moire`) and the
median render time. Theory predicts EWA <= trilinear < nearest-level mip < bilinear ~ nearest.
The fit part recovers a random kd texture (H_t x W_t x 3 unknowns) from two noise-free Phong renders
with Levenberg-Marquardt + CG, and reports its size, time and error on visible texels.

Writes experiments/results/textures_filtering.{csv,json,png}, prints a one-line summary.

    python experiments/textures_filtering.py            # 320x240, texture fit 128x128 (49k unknowns)
    python experiments/textures_filtering.py --small    # 96x72, 32x32
"""

from __future__ import annotations

import argparse
import csv
import io
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

import difflab
from difflab.demos import image_grid
from difflab.io import save_image, write_json_atomic, write_text_atomic
from difflab.demos.textures import FILTER_ORDER, FILTER_TITLES, checker_texture, compare_filters

RESULTS = Path(__file__).resolve().parent / "results"
SEED = 0


def texture_fit_run(size: int, pixels: int, folder: Path) -> dict:
    """Fit a random (size x size x 3) kd texture from two views of a textured quad."""
    from difflab.fit.texture_fit import fit_texture, texture_view
    from difflab.renderers.api import as_scene

    truth = np.random.default_rng(SEED).uniform(0.1, 0.9, (size, size, 3)).astype(np.float32)
    path = folder / "truth.npy"
    np.save(path, truth)
    views = []
    for eye in [(0, 0, 3), (0.8, 0.4, 2.8)]:
        scene = as_scene({
            "camera": {"eye": list(eye), "target": [0, 0, 0], "fov_y": 40, "width": pixels, "height": pixels},
            "ambient": [0.1] * 3,
            "lights": [{"type": "point", "position": [1, 2, 4]}, {"type": "directional", "direction": [0, 0, -1],
                                                                  "intensity": [0.3] * 3}],
            "materials": {"m": {"ka": 0.2, "kd": 1, "ks": 0.3, "n": 20, "texture": str(path), "wrap": "clamp"}},
            "objects": [{"type": "mesh", "builtin": "quad", "material": "m",
                         "transform": {"rotate_deg": [90, 0, 0], "scale": 2.0}}],
            "render": {"shadows": False}})
        frame = difflab.render_frame(scene)
        views.append(texture_view(frame.gbuffer, frame.image, scene, "m", (size, size)))
    result = fit_texture(views, (size, size), solver="gauss_newton")
    err = np.abs(result.texture - truth)[result.visible]
    return {"texels": f"{size}x{size}", "unknowns": result.n_params, "pixels": f"{pixels}x{pixels} x 2 views",
            "solver": "optimistix.GaussNewton + lineax Normal(CG)", "result": result.result, "steps": result.steps,
            "seconds": round(result.seconds, 3), "max_error_visible": float(err.max()),
            "visible_fraction": float(result.visible.mean()), "pixel_rmse": result.rmse}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--small", action="store_true", help="small sizes (a quick check)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    width, height, n_ref, fit_size, fit_pixels = (96, 72, 32, 32, 96) if args.small else (320, 240, 32, 128, 384)
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        texture = save_image(Path(tmp) / "checker.png", checker_texture())
        images, table = compare_filters(texture, width, height, n_reference=n_ref, repeats=3)
        fit = texture_fit_run(fit_size, fit_pixels, Path(tmp))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(table[0]))
    writer.writeheader()
    writer.writerows({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()} for row in table)
    write_text_atomic(args.out / "textures_filtering.csv", buffer.getvalue())
    image_grid([images[k] for k in ["reference", *FILTER_ORDER]],
               [f"ground truth ({n_ref}x{n_ref} supersampled)"] +
               [f"{FILTER_TITLES[r['filter']]}: RMSE {r['rmse']:.3f}" for r in table],
               args.out / "textures_filtering.png", columns=3)
    rmse = {r["filter"]: r["rmse"] for r in table}
    order_holds = (rmse["ewa"] <= rmse["trilinear"] < rmse["mipmap"] < min(rmse["bilinear"], rmse["nearest"]))
    write_json_atomic(args.out / "textures_filtering.json", {
        "what": "receding checkerboard texture, filters vs supersampled ground truth; kd texture fit",
        "image": [width, height], "reference_supersampling": n_ref, "texture": "64x64, 2x2 checks, repeat",
        "filters": table, "order_holds": bool(order_holds), "texture_fit": fit, "seed": SEED,
        "versions": {"python": sys.version.split()[0], "numpy": np.__version__, "difflab": difflab.__version__
                     if hasattr(difflab, "__version__") else "dev", "platform": platform.platform()},
    })
    order = "holds" if order_holds else "VIOLATED"
    print("textures_filtering: RMSE " + ", ".join(f"{k} {v:.4f}" for k, v in rmse.items())
          + f"; order {order}; fit {fit['unknowns']} unknowns in {fit['seconds']:.1f} s,"
          f" max error {fit['max_error_visible']:.2e} ({fit['result']}) -> {args.out}")
    return 0 if order_holds else 3


if __name__ == "__main__":
    sys.exit(main())

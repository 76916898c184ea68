"""How well do the classic Phong and Blinn models approximate physically based materials?

Targets: a diffuse, a plastic and a rough-metal sphere rendered by a physically based renderer --
Mitsuba 3 when it is installed (`pip install mitsuba`; optional), otherwise difflab's own "torrance"
specular model (Cook-Torrance: Beckmann distribution, Schlick Fresnel), which is what this run can
do without it. For each target, fit ka, kd, ks (RGB) and n of the Phong and of the Blinn model with
Levenberg-Marquardt, and report the residual (RMSE, PSNR) of each fit: the error that remains is the
models' mismatch, not noise.

Writes experiments/results/fit_mismatch.{csv,json,png}; prints a one-line summary.

    python experiments/fit_mismatch.py            # 96x96
    python experiments/fit_mismatch.py --small    # 32x32
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_common import RESULTS, SEED, scene_dict, versions, write_csv  # noqa: E402

MATERIALS = {  # the physically based truth: kd, ks, Beckmann roughness m, Schlick f0
    "diffuse": {"ka": [0.05, 0.05, 0.05], "kd": [0.2, 0.5, 0.8], "ks": [0.0, 0.0, 0.0], "m": 0.5, "f0": 0.04},
    "plastic": {"ka": [0.05, 0.02, 0.02], "kd": [0.7, 0.1, 0.1], "ks": [1.0, 1.0, 1.0], "m": 0.15, "f0": 0.04},
    "rough_metal": {"ka": [0.02, 0.02, 0.02], "kd": [0.02, 0.02, 0.02], "ks": [0.9, 0.6, 0.3], "m": 0.35, "f0": 0.9},
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true")
    args = parser.parse_args(argv)
    size = 32 if args.small else 96
    try:
        import mitsuba  # noqa: F401

        reference = "mitsuba available, but its scene export is not implemented here: using difflab 'torrance'"
    except ImportError:
        reference = "mitsuba not installed (optional): targets rendered with difflab's 'torrance' model instead"
    print(reference)

    from difflab.fit import fit_material
    from difflab.io import write_json_atomic
    from difflab.render.api import render_frame
    from difflab.scene import Scene

    rows, images = [], []
    for name, truth in MATERIALS.items():
        target_scene = Scene.from_dict(scene_dict(size, red=truth, specular="torrance"))
        target = render_frame(target_scene).image
        row_images = [target]
        for model in ("phong", "blinn"):
            scene = target_scene.with_overrides(render={"specular": model})
            init = {"ka": truth["ka"], "kd": np.maximum(truth["kd"], 0.05).tolist(), "ks": [0.3] * 3, "n": 20.0}
            result = fit_material(scene, [target], "red", init=init, history=False, max_steps=500)
            fitted = render_frame(result.to_scene()).image
            rmse = float(np.sqrt(np.mean((fitted - target) ** 2)))  # whole image
            rows.append({"material": name, "model": model, "result": result.result, "steps": result.steps,
                         "rmse": rmse, "psnr_fit_pixels": result.psnr, "n": result.params["n"],
                         **{f"{k}_{c}": v for k in ("ka", "kd", "ks") for c, v in zip("rgb", result.params[k])}})
            row_images.append(fitted)
        images.append(row_images)

    RESULTS.mkdir(parents=True, exist_ok=True)
    write_csv(RESULTS / "fit_mismatch.csv", rows)
    write_json_atomic(RESULTS / "fit_mismatch.json", {"seed": SEED, "size": size, "reference": reference,
                                                      "rows": rows, "versions": versions()})
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(len(images), 3, figsize=(7.5, 2.5 * len(images)))
    for i, (name, row_images) in enumerate(zip(MATERIALS, images)):
        for j, (title, im) in enumerate(zip(("target", "Phong fit", "Blinn fit"), row_images)):
            ax[i, j].imshow(np.clip(im, 0, 1) ** (1 / 2.2))
            ax[i, j].set_title(f"{name}: {title}", fontsize=8)
            ax[i, j].axis("off")
    fig.tight_layout()
    fig.savefig(RESULTS / "fit_mismatch.png", dpi=100)
    print("fit_mismatch: PSNR of the fitted pixels " + ", ".join(
        f"{r['material']}/{r['model']} {r['psnr_fit_pixels']:.1f} dB" for r in rows) + f" -> {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How well do the classic Phong and Blinn models approximate physically based materials?

Targets: a diffuse, a plastic and a rough-metal sphere rendered by a physically based renderer --
Mitsuba 3 when it is installed (`pip install mitsuba`; optional: its `diffuse`, `roughplastic` and
`roughconductor` BSDFs with a Beckmann distribution, direct illumination from the same point light,
64 samples per pixel, composited onto difflab's render of the rest of the scene and fitted on the
sphere's interior pixels), otherwise difflab's own "torrance" specular model (Cook-Torrance:
Beckmann distribution, Schlick Fresnel). For each target, fit ka, kd, ks (RGB) and n of the Phong and of the Blinn model with
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


def mitsuba_sphere(scene, name: str, truth: dict) -> np.ndarray:
    """Mitsuba 3's image of the scene's red sphere alone (direct light from its point light), linear RGB.

    The Beckmann alpha is the material's m (the same slope parameter); the diffuse reflectance is
    kd; the conductor's specular reflectance is ks; plastic's dielectric interface has ior 1.5."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    camera, light, sphere = scene.camera, scene.lights[0], scene.objects[0]
    rgb = lambda v: {"type": "rgb", "value": list(v)}  # noqa: E731
    bsdf = {
        "diffuse": {"type": "diffuse", "reflectance": rgb(truth["kd"])},
        "plastic": {"type": "roughplastic", "distribution": "beckmann", "alpha": truth["m"], "int_ior": 1.5,
                    "diffuse_reflectance": rgb(truth["kd"])},
        "rough_metal": {"type": "roughconductor", "distribution": "beckmann", "alpha": truth["m"],
                        "specular_reflectance": rgb(truth["ks"])},
    }[name]
    mi_scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": camera.fov_y, "fov_axis": "y",
                   "to_world": mi.ScalarTransform4f().look_at(origin=list(camera.eye), target=list(camera.target),
                                                              up=list(camera.up)),
                   "film": {"type": "hdrfilm", "width": camera.width, "height": camera.height,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": 64, "seed": SEED}},
        # difflab's kd I cos / (d^2 / d0^2) equals Mitsuba's (kd / pi) I_mi cos / d^2 when I_mi = pi d0^2 I
        "light": {"type": "point", "position": list(light.position),
                  "intensity": rgb(np.pi / light.attenuation[2] * np.asarray(light.intensity))},
        "sphere": {"type": "sphere", "center": list(sphere.center), "radius": sphere.radius, "bsdf": bsdf},
    })
    return np.asarray(mi.render(mi_scene), np.float32)[..., :3]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true")
    args = parser.parse_args(argv)
    size = 32 if args.small else 96
    try:
        import mitsuba  # noqa: F401

        reference = f"Mitsuba {mitsuba.__version__} (scalar_rgb, direct illumination, 64 spp)"
    except ImportError:
        mitsuba = None
        reference = "mitsuba not installed (optional): targets rendered with difflab's 'torrance' model instead"
    print(reference)

    from difflab.fit import fit_material
    from difflab.io import write_json_atomic
    from difflab.renderers.api import render_frame
    from difflab.scene import Scene

    rows, images = [], []
    # Inverse-square falloff normalised at the sphere's centre (kq = 1 / d0^2), as a physical point light.
    light_position, centre = np.array([3.0, 4.0, 3.0]), np.array([0.0, 1.0, 0.0])
    d0_squared = float(np.sum((light_position - centre) ** 2))
    lights = [{"type": "point", "position": light_position.tolist(), "intensity": [1.0, 1.0, 1.0],
               "attenuation": [0.0, 0.0, 1.0 / d0_squared]}]
    for name, truth in MATERIALS.items():
        target_scene = Scene.from_dict(scene_dict(size, red=truth, specular="torrance", lights=lights))
        frame = render_frame(target_scene)
        target, mask = frame.image, None
        if mitsuba is not None:
            sphere = frame.gbuffer.mask & (frame.gbuffer.material == target_scene.material_index("red"))
            target = np.where(sphere[..., None], mitsuba_sphere(target_scene, name, truth), target)
            # interior pixels only: Mitsuba's pixels integrate over their area, difflab samples centres
            mask = sphere.copy()
            mask[1:-1, 1:-1] &= sphere[:-2, 1:-1] & sphere[2:, 1:-1] & sphere[1:-1, :-2] & sphere[1:-1, 2:]
        row_images = [target]
        for model in ("phong", "blinn"):
            scene = target_scene.with_overrides(render={"specular": model})
            init = {"ka": truth["ka"], "kd": np.maximum(truth["kd"], 0.05).tolist(), "ks": [0.3] * 3, "n": 20.0}
            result = fit_material(scene, [target], "red", init=init, history=False, max_steps=500,
                                  masks=None if mask is None else [mask])
            fitted = render_frame(result.to_scene()).image
            rmse = float(np.sqrt(np.mean((fitted - target) ** 2)))  # whole image
            on = np.ones(target.shape[:2], bool) if mask is None else mask
            relative = float(np.sqrt(np.mean((fitted[on] - target[on]) ** 2)) / np.mean(target[on]))
            rows.append({"material": name, "model": model, "result": result.result, "steps": result.steps,
                         "rmse": rmse, "relative_rmse_fit_pixels": relative, "psnr_fit_pixels": result.psnr, "n": result.params["n"],
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
    print("fit_mismatch: relative RMSE (PSNR) of the fitted pixels " + ", ".join(
        f"{r['material']}/{r['model']} {100 * r['relative_rmse_fit_pixels']:.2f}% ({r['psnr_fit_pixels']:.1f} dB)"
        for r in rows) + f" -> {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

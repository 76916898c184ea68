"""Fits to targets difflab did not make: POV-Ray 3.7 and Mitsuba 3 renders, saved as a user gets
them (8-bit sRGB PNG with clipped highlights, 16-bit PNG, float EXR read into .npy).

Cases (`CASES`): where the models coincide the fit must recover the truth; where the foreign
renderer shows an effect difflab's model lacks, the fit must say so (`model_mismatch`, `difflab fit`
exit code 4) instead of reporting success on a wrong answer.

  a_phong       POV-Ray Phong sphere on a plane (models coincide; the red highlight clips in 8 bits)
  b_mirror      POV-Ray mirror sphere (reflection kr) reflecting a plane: fitted through the ray tree
  c_brilliance  POV-Ray `brilliance 3`: diffuse (N.L)^3, which no ka / kd / ks / n reproduces
  c_area_light  POV-Ray area light: soft shadows on the fitted floor (difflab's shadows are hard; the
                floor's ka / kd are the truth, the penumbra is what the model lacks)
  d_diffuse     Mitsuba diffuse sphere: kd = reflectance / pi, ks 0 (at its bound)
  e_plastic     Mitsuba rough plastic (Beckmann lobe), highlight clipped in 8 bits: no Phong lobe fits

each from its 8-bit sRGB PNG, 16-bit PNG (sRGB; POV-Ray also linear), float EXR (read into .npy),
and the float render with 3 % seeded Gaussian noise saved as 8-bit PNG ("png8_noise": the noise
clips at black), where recovering means every parameter within 3 standard errors of the truth.

Each is fitted with `difflab.fit_material` / `fit_scene` and `load_image`, and with the `difflab fit`
command line (`difflab.cli.main`, in this process: the exit code a shell would get). Writes
experiments/results/foreign_targets.{json,png} and prints the table.

    python experiments/foreign_targets.py                    # 96x96
    python experiments/foreign_targets.py --size 48
    python experiments/foreign_targets.py --write-fixtures   # tests/data/foreign (48x48), then stops
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_common import RESULTS, SEED, versions  # noqa: E402
from foreign_render import (mitsuba_dict, mitsuba_module, pov_scene, read_exr, render_mitsuba,  # noqa: E402
                            render_pov, write_mitsuba)

FIXTURES = Path(__file__).resolve().parents[1] / "tests" / "data" / "foreign"
FORMATS = ("png8", "png16", "png16lin", "float", "png8_noise")
NOISE = 0.03  # "png8_noise": seeded Gaussian noise of this sigma on the float render, then 8-bit sRGB (clipped)
CAMERA = {"eye": [0, 1.2, 4], "target": [0, 0.6, 0], "up": [0, 1, 0], "fov_y": 40}
PHONG = {"ka": [0.1, 0.05, 0.02], "kd": [0.7, 0.2, 0.1], "ks": [0.5, 0.5, 0.5], "n": 24.0}
MIRROR = {"ka": [0.02, 0.02, 0.03], "kd": [0.1, 0.1, 0.15], "ks": [0.6, 0.6, 0.6], "n": 60.0, "kr": 0.6}
FLOOR = {"ka": [0.1, 0.1, 0.1], "kd": [0.8, 0.6, 0.3]}
REFLECTANCE = [0.2, 0.5, 0.8]


def pov_dict(size: int, materials: dict, background=(0.0, 0.0, 0.0)) -> dict:
    """A sphere ("red" or "mirror") on a plane ("floor") under one point light, ray traced."""
    sphere = next(name for name in materials if name != "floor")
    return {"camera": {**CAMERA, "width": size, "height": size}, "ambient": [0.2, 0.2, 0.2],
            "background": list(background),
            "lights": [{"type": "point", "position": [3, 4, 3], "intensity": [1, 1, 1]}],
            "materials": materials,
            "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": sphere},
                        {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
            "render": {"method": "raytrace", "specular": "phong", "shadows": True, "max_depth": 5}}


def mitsuba_scene_dict(size: int, material: dict, intensity: float) -> dict:
    """The sphere alone under a 1 / d^2 point light, no ambient (Mitsuba's scene)."""
    return {"camera": {**CAMERA, "width": size, "height": size}, "ambient": [0, 0, 0], "background": [0, 0, 0],
            "lights": [{"type": "point", "position": [3, 4, 3], "intensity": [intensity] * 3,
                        "attenuation": [0, 0, 1]}],
            "materials": {"red": material},
            "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"}],
            "render": {"method": "raster", "specular": "phong", "shadows": False}}


def perturbed(values: dict, factor=0.3) -> dict:
    """Each entry scaled by 1 + factor or 1 - factor, alternating: the fit's start."""
    out, sign = {}, 1.0
    for key, value in values.items():
        array = np.asarray(value, float).reshape(-1)
        signs = np.array([sign * (-1) ** i for i in range(array.size)])
        sign = -sign
        scaled = (array * (1 + factor * signs)).tolist()
        out[key] = scaled if np.ndim(value) else scaled[0]
    return out


def case_table(size: int) -> dict:
    """name -> the case: the difflab scene at its start values, the fitted material and params, the
    truth (None where the models differ), what the fit must report, and how the target is made."""
    def with_start(scene, material, truth, params):
        start = copy.deepcopy(scene)
        start["materials"][material].update(perturbed({k: truth[k] for k in params}))
        return start

    phong = pov_dict(size, {"red": PHONG, "floor": FLOOR})
    mirror = pov_dict(size, {"mirror": MIRROR, "floor": FLOOR}, background=(0.3, 0.4, 0.6))
    floor_params = ("ka", "kd")
    diffuse_truth = {"kd": (np.asarray(REFLECTANCE) / np.pi).tolist(), "ks": [0.0] * 3}
    diffuse = mitsuba_scene_dict(size, {"ka": [0, 0, 0], "kd": [0.1] * 3, "ks": [0.2] * 3, "n": 10.0}, 40.0)
    plastic = mitsuba_scene_dict(size, {"ka": [0, 0, 0], "kd": [0.1] * 3, "ks": [0.2] * 3, "n": 10.0}, 40.0)
    cases = {
        "a_phong": {"renderer": "povray", "scene": with_start(phong, "red", PHONG, PHONG), "truth_scene": phong,
                    "material": "red", "params": ["ka", "kd", "ks", "n"], "truth": PHONG, "expect": "recover",
                    "tolerance": 0.03},
        "b_mirror": {"renderer": "povray", "scene": with_start(mirror, "mirror", MIRROR, MIRROR),
                     "truth_scene": mirror, "material": "mirror", "params": ["ka", "kd", "ks", "n", "kr"],
                     "truth": MIRROR, "expect": "recover", "tolerance": 0.05},
        "c_brilliance": {"renderer": "povray", "scene": with_start(phong, "red", PHONG, PHONG), "truth_scene": phong,
                         "finish_extra": {"red": "brilliance 3"}, "material": "red",
                         "params": ["ka", "kd", "ks", "n"], "truth": None, "expect": "mismatch"},
        "c_area_light": {"renderer": "povray", "scene": with_start(phong, "floor", FLOOR, floor_params),
                         "truth_scene": phong, "light_extra": "area_light <1, 0, 0>, <0, 0, 1>, 5, 5",
                         "material": "floor", "params": list(floor_params),
                         "truth": {k: FLOOR[k] for k in floor_params}, "expect": "mismatch"},
        "d_diffuse": {"renderer": "mitsuba", "scene": diffuse, "material": "red", "params": ["kd", "ks", "n"],
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": REFLECTANCE}},
                      "truth": diffuse_truth, "expect": "recover", "tolerance": 0.02},
        "e_plastic": {"renderer": "mitsuba", "scene": plastic, "material": "red", "params": ["kd", "ks", "n"],
                      "bsdf": {"type": "roughplastic", "distribution": "beckmann", "alpha": 0.1, "int_ior": 1.5,
                               "diffuse_reflectance": {"type": "rgb", "value": [0.6, 0.15, 0.1]}},
                      "truth": None, "expect": "mismatch"},
    }
    return cases


def make_targets(name: str, case: dict, folder: Path) -> dict:
    """Render a case's targets into `folder`: format -> file ("float": a .npy read from the EXR)."""
    size = case["scene"]["camera"]["width"]
    files = {}
    if case["renderer"] == "povray":
        source = pov_scene(case["truth_scene"], finish_extra=case.get("finish_extra"),
                           light_extra=case.get("light_extra", ""))
        for fmt, suffix in (("png8", ".png"), ("png16", "_16.png"), ("png16lin", "_16lin.png"), ("exr", ".exr")):
            files[fmt] = render_pov(source, folder / f"{name}{suffix}", size, size, fmt)
        (folder / f"{name}.pov").write_text(source)
    else:
        mi = mitsuba_module()
        description = mitsuba_dict(case["scene"], case["bsdf"], spp=64, seed=SEED)
        image = render_mitsuba(mi, description)
        for fmt, suffix in (("png8", ".png"), ("png16", "_16.png"), ("exr", ".exr")):
            files[fmt] = write_mitsuba(mi, image, folder / f"{name}{suffix}", fmt)
        (folder / f"{name}.mitsuba.json").write_text(json.dumps(description, indent=1) + "\n")
        from difflab import interior_mask, save_image

        # Mitsuba integrates a pixel's area (an anti-aliased render), difflab samples its centre: edge
        # pixels differ by coverage, not shading; the fit reads the pixels 2 in from every edge
        files["mask"] = save_image(folder / f"{name}_mask.png", interior_mask(case["scene"], margin=2), srgb=False)
    exr = read_exr(files.pop("exr"))
    if exr is not None:
        from difflab import save_image

        files["float"] = save_image(folder / f"{name}.npy", exr)
        noisy = exr + np.random.default_rng(SEED).normal(0.0, NOISE, exr.shape).astype(np.float32)
        files["png8_noise"] = save_image(folder / f"{name}_noise.png", noisy)
    return files


def fit_case(case: dict, target: Path, mask: Path | None):
    """The public API's fit of one target file: `fit_scene` for a reflecting material, else `fit_material`."""
    import difflab

    scene = difflab.Scene.from_dict(case["scene"])
    masks = None if mask is None else [mask]
    if "kr" in case["params"]:
        return difflab.fit_scene(scene, [target], [case["material"]], case["params"], masks=masks, progress=False)
    return difflab.fit_material(scene, [target], case["material"], case["params"], masks=masks, progress=False)


def cli_exit(case: dict, target: Path, mask: Path | None, folder: Path) -> int:
    """`difflab fit` on the case (its scene file and target file): the exit code."""
    from difflab.cli import main
    from difflab.scene import Scene, save_scene

    scene = folder / "scene.json"
    save_scene(Scene.from_dict(case["scene"]), scene)
    argv = ["fit", str(scene), str(target), "--material", case["material"], "--params", ",".join(case["params"]),
            "-o", str(folder / "fitted.json"), "--force"] + (["--mask", str(mask)] if mask else [])
    return main(argv)


def errors(result, truth: dict | None) -> dict | None:
    """Per parameter: the largest error relative to max(|truth|, 0.05) over channels (a truth of 0,
    ks of a matte sphere, is measured against 0.05), or None without a truth."""
    if truth is None:
        return None
    return {k: float(np.max(np.abs(np.asarray(result.params[k]) - np.asarray(v)) /
                            np.maximum(np.abs(np.asarray(v)), 0.05))) for k, v in truth.items()}


def zscores(result, truth: dict | None) -> dict | None:
    """Per parameter: the largest |fitted - truth| / stderr over channels, or None without a truth."""
    if truth is None:
        return None
    return {k: float(np.max(np.abs(np.asarray(result.params[k]) - np.asarray(v)) / np.asarray(result.stderr[k])))
            for k, v in truth.items()}


def verdict(case: dict, result, err: dict | None, z: dict | None, noisy: bool) -> str:
    """"recovered" / "flagged" (what the case asks), "suspected" (a foreign effect: `mismatch_suspected`,
    not judged), "failed honestly" (not ok, and says so), or "WRONG & OK" (a success reported on a
    wrong answer, or a mismatch not flagged). A noisy target is recovered when every parameter lies
    within 3 standard errors of the truth; a foreign effect is "unseen under noise" when the noisy
    target's residuals sit at its noise (chi2 within its spread: ok)."""
    if case["expect"] == "mismatch":
        if result.model_mismatch:
            return "flagged"
        if result.mismatch_suspected:
            return "suspected"
        if noisy and result.converged:  # the data do not show the effect: the model explains them to their noise
            return "unseen under noise"
        return "WRONG & OK" if result.converged else "failed honestly"
    if noisy and z is not None and max(z.values()) <= 3.0:
        return "recovered" if result.ok else "right, flagged"
    if not noisy and err is not None and max(err.values()) <= case["tolerance"]:
        return "recovered" if result.ok else "right, flagged"
    return "WRONG & OK" if result.ok else "failed honestly"


def row(name: str, fmt: str, case: dict, result, code: int | None) -> dict:
    err, z = errors(result, case["truth"]), zscores(result, case["truth"])
    return {"case": name, "format": fmt, "expect": case["expect"], "truth": case["truth"],
            "params": {k: v for k, v in result.params.items()}, "stderr": {k: v for k, v in result.stderr.items()},
            "rel_error": err, "z": z, "psnr": result.psnr,
            "chi2": result.chi2, "sigma": result.sigma, "model_mismatch": result.model_mismatch,
            "mismatch_suspected": result.mismatch_suspected,
            "censored": result.censored, "at_bound": result.at_bound, "poorly_determined": result.poorly_determined,
            "converged": result.converged, "result": result.result, "steps": result.steps, "model": result.model,
            "cli_exit": code, "verdict": verdict(case, result, err, z, fmt.endswith("noise"))}


def print_table(rows: list[dict]) -> None:
    print(f"{'case':<13} {'format':<10} {'max rel err':>11} {'max z':>6} {'psnr':>6} {'chi2':>9} {'mism':>4} {'cens':>5} "
          f"{'at_bound':<9} {'poorly':<10} {'conv':>4} {'exit':>4}  verdict")
    for r in rows:
        err = f"{max(r['rel_error'].values()):.4f}" if r["rel_error"] else "-"
        z = f"{max(r['z'].values()):.1f}" if r["z"] else "-"
        print(f"{r['case']:<13} {r['format']:<10} {err:>11} {z:>6} {r['psnr']:6.1f} {r['chi2']:9.3g} "
              f"{'yes' if r['model_mismatch'] else 'susp' if r['mismatch_suspected'] else 'no':>4} {r['censored']:5d} {','.join(r['at_bound']) or '-':<9} "
              f"{','.join(r['poorly_determined']) or '-':<10} {'yes' if r['converged'] else 'no':>4} "
              f"{'-' if r['cli_exit'] is None else r['cli_exit']:>4}  {r['verdict']}")


def figure(panels: list, path: Path) -> None:
    """Per case: target, fit, residual (8-bit targets)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(len(panels), 3, figsize=(7.5, 2.4 * len(panels)), squeeze=False)
    for i, (name, target, fitted, residual, r) in enumerate(panels):
        ax[i, 0].imshow(np.clip(target, 0, 1) ** (1 / 2.2))
        ax[i, 0].set_title(f"{name}: target (8-bit)", fontsize=8)
        ax[i, 1].imshow(np.clip(fitted, 0, 1) ** (1 / 2.2))
        ax[i, 1].set_title(f"fit: PSNR {r['psnr']:.1f} dB, chi2 {r['chi2']:.3g}", fontsize=8)
        lim = max(float(np.abs(residual).max()), 1e-6)
        im = ax[i, 2].imshow(residual.mean(axis=-1), cmap="RdBu_r", vmin=-lim, vmax=lim)
        ax[i, 2].set_title(f"residual ({'MISMATCH' if r['model_mismatch'] else 'no flag'}; {r['verdict']})",
                           fontsize=8)
        fig.colorbar(im, ax=ax[i, 2], fraction=0.046)
        for a in ax[i]:
            a.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_fixtures(size: int) -> None:
    """tests/data/foreign: per case its 8-bit PNG (and 16-bit PNGs of a_phong, sRGB and linear, and
    of d_diffuse), the start scene, the POV-Ray source / Mitsuba scene, Mitsuba's masks, and cases.json."""
    from difflab.io import write_json_atomic

    FIXTURES.mkdir(parents=True, exist_ok=True)
    index = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, case in case_table(size).items():
            files = make_targets(name, case, Path(tmp))
            keep = [files["png8"]] + [files[f] for f in ("png16", "png16lin") if f in files and
                                      name in ("a_phong", "d_diffuse")]
            keep += [files["mask"]] if "mask" in files else []
            keep += list(Path(tmp).glob(f"{name}.pov")) + list(Path(tmp).glob(f"{name}.mitsuba.json"))
            for path in keep:
                (FIXTURES / path.name).write_bytes(path.read_bytes())
            write_json_atomic(FIXTURES / f"{name}.scene.json", case["scene"])
            index[name] = {k: case.get(k) for k in ("renderer", "material", "params", "truth", "expect", "tolerance")}
            index[name]["mask"] = files["mask"].name if "mask" in files else None
    write_json_atomic(FIXTURES / "cases.json", {"size": size, "regenerate": "python experiments/foreign_targets.py "
                                                "--write-fixtures", "cases": index})
    print(f"wrote {len(index)} cases to {FIXTURES}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=96)
    parser.add_argument("--write-fixtures", action="store_true", help="write tests/data/foreign (48x48) and stop")
    parser.add_argument("--only", action="append", help="run only these cases (repeatable)")
    args = parser.parse_args(argv)
    if args.write_fixtures:
        write_fixtures(48)
        return 0
    import difflab
    from difflab.io import write_json_atomic

    rows, panels = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for name, case in case_table(args.size).items():
            if args.only and name not in args.only:
                continue
            folder = Path(tmp) / name
            folder.mkdir()
            files = make_targets(name, case, folder)
            mask = files.get("mask")
            for fmt in FORMATS:
                if fmt not in files:
                    continue
                result = fit_case(case, files[fmt], mask)
                code = cli_exit(case, files[fmt], mask, folder) if fmt == "png8" else None
                rows.append(row(name, fmt, case, result, code))
                if fmt == "png8":
                    fitted = difflab.render(result.to_scene())
                    panels.append((name, difflab.load_image(files[fmt]), fitted, result.residuals[0], rows[-1]))
    print_table(rows)
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_json_atomic(RESULTS / "foreign_targets.json", {"size": args.size, "seed": SEED, "rows": rows,
                                                          "versions": versions()})
    figure(panels, RESULTS / "foreign_targets.png")
    wrong = [f"{r['case']}/{r['format']}" for r in rows if r["verdict"] == "WRONG & OK"]
    print(f"foreign_targets: {len(rows)} fits, {len(wrong)} reported success on a wrong answer"
          f"{': ' + ', '.join(wrong) if wrong else ''} -> {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

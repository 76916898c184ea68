"""The mappings docs/foreign-targets.md states, each checked by a render of the other renderer and a
difflab fit (or a pixel comparison) at 64-96 px: camera (POV-Ray's horizontal `angle`, Mitsuba's
default fov_axis "x"), POV-Ray's left-handed z, light units (Mitsuba point light, diffuse
reflectance, a constant environment), POV-Ray's fade_power 1 and 2, pixel filters (box, gaussian),
anti-aliasing and the edge margin, and 8-bit / 16-bit / float files.

    python experiments/foreign_mappings.py            # every check (~2 minutes on 2 cores)
    python experiments/foreign_mappings.py --only fade

Prints one row per check -- what it compares and the measured numbers -- and writes
experiments/results/foreign_mappings.json. Needs povray (apt-get install povray) and mitsuba
(pip install mitsuba); a check whose renderer is missing is reported as skipped.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_common import RESULTS, versions  # noqa: E402
from foreign_render import (mitsuba_dict, mitsuba_module, pov_scene, read_exr, render_mitsuba,  # noqa: E402
                            render_pov)

CAMERA = {"eye": [0, 1.2, 4], "target": [0, 0.6, 0], "up": [0, 1, 0], "fov_y": 40}
PHONG = {"ka": [0.1, 0.03, 0.015], "kd": [0.7, 0.2, 0.1], "ks": [0.6] * 3, "n": 30.0}
START = {"ka": [0.05] * 3, "kd": [0.4] * 3, "ks": [0.3] * 3, "n": 15.0}
REFLECTANCE = [0.2, 0.5, 0.8]


def pov_sphere(width: int, height: int, attenuation=(1, 0, 0), intensity=1.6) -> dict:
    """POV-Ray's case: a Phong sphere under one point light and ambient 0.2, ray traced, no floor."""
    return {"camera": {**CAMERA, "width": width, "height": height}, "ambient": [0.2] * 3, "background": [0, 0, 0],
            "lights": [{"type": "point", "position": [3, 4, 3], "intensity": [intensity] * 3,
                        "attenuation": list(attenuation)}],
            "materials": {"red": dict(PHONG)},
            "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"}],
            "render": {"method": "raytrace", "specular": "phong", "shadows": False}}


def mitsuba_sphere(width: int, height: int, ambient=0.0) -> dict:
    """Mitsuba's case: a sphere under a 1 / d^2 point light of intensity 40 (and a constant
    environment `ambient`), kd = reflectance / pi, ka = reflectance."""
    rho = np.asarray(REFLECTANCE)
    return {"camera": {**CAMERA, "width": width, "height": height}, "ambient": [ambient] * 3, "background": [0, 0, 0],
            "lights": [{"type": "point", "position": [3, 4, 3], "intensity": [40.0] * 3, "attenuation": [0, 0, 1]}],
            "materials": {"red": {"ka": rho.tolist(), "kd": (rho / np.pi).tolist(), "ks": [0.0] * 3}},
            "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"}],
            "render": {"method": "raster", "specular": "phong", "shadows": False}}


def fov_x(camera: dict) -> float:
    """The horizontal field of view (degrees) of difflab's vertical fov_y: 2 atan(tan(fov_y / 2) W / H)."""
    return math.degrees(2 * math.atan(math.tan(math.radians(camera["fov_y"]) / 2) * camera["width"] / camera["height"]))


def mitsuba_image(mi, scene: dict, spp: int, *, rfilter="box", fov_axis="y", environment=0.0, seed=1) -> np.ndarray:
    """Mitsuba's render of `scene` (diffuse reflectance REFLECTANCE): its sensor's fov given along
    `fov_axis` ("x": Mitsuba's default, the horizontal angle), `rfilter` its pixel filter, a
    constant environment of radiance `environment` when > 0."""
    description = mitsuba_dict(scene, {"type": "diffuse", "reflectance": {"type": "rgb", "value": REFLECTANCE}},
                               spp=spp, seed=seed)
    sensor = description["sensor"]
    sensor["film"] = {**sensor["film"], "rfilter": {"type": rfilter}}
    if fov_axis == "x":
        del sensor["fov_axis"]  # Mitsuba's default
        sensor["fov"] = fov_x(scene["camera"])
    if environment > 0:
        description["environment"] = {"type": "constant", "radiance": {"type": "rgb", "value": [environment] * 3}}
    return render_mitsuba(mi, description)


def fitted(scene: dict, target, params, margin=0, **keywords):
    """difflab's fit of `target` from START's values of `params`, counting the pixels `margin` from
    every edge (0: all); `keywords` (method, spp, sigma) go to `fit_material`."""
    import difflab

    begin = copy.deepcopy(scene)
    begin["materials"]["red"].update({k: v for k, v in START.items() if k in params})
    masks = [difflab.interior_mask(scene, margin=margin)] if margin else None
    return difflab.fit_material(begin, [target], "red", tuple(params), masks=masks, progress=False, **keywords)


def report(name: str, what: str, result, truth: dict) -> dict:
    """One row: the fit's largest relative error (a truth below 0.05 measured against 0.05), its
    largest |error| / stderr, chi2 and verdict."""
    rel = max(float(np.max(np.abs(np.asarray(result.params[k]) - np.asarray(v)) / np.maximum(np.abs(v), 0.05)))
              for k, v in truth.items() if k in result.params)
    z = max(float(np.max(np.abs(np.asarray(result.params[k]) - np.asarray(v)) / np.asarray(result.stderr[k])))
            for k, v in truth.items() if k in result.params)
    verdict = "MODEL MISMATCH" if result.model_mismatch else "suspected" if result.mismatch_suspected else \
        "ok" if result.ok else result.result
    return {"check": name, "what": what, "max_rel_error": rel, "max_z": z, "chi2": result.chi2, "verdict": verdict,
            "params": result.params}


def pixels(name: str, what: str, theirs: np.ndarray, ours: np.ndarray, mask: np.ndarray) -> dict:
    """One row: the largest and mean |difference| of two images over the mask's pixels."""
    diff = np.abs(theirs - ours)[mask]
    return {"check": name, "what": what, "max_abs_diff": float(diff.max()), "mean_abs_diff": float(diff.mean()),
            "peak": float(ours[mask].max())}


def check_camera(folder: Path, mi) -> list:
    """POV-Ray at 96 x 64 with angle = fov_x (z negated) against difflab's ray tracer, and with
    angle = fov_y (the wrong axis); Mitsuba's default fov_axis with fov = fov_x, and with fov_y."""
    import difflab

    rows = []
    scene = pov_sphere(96, 64)
    ours = difflab.render(scene)
    interior = difflab.interior_mask(scene, margin=1)
    if folder is not None:
        source = pov_scene(scene)
        exr = read_exr(render_pov(source, folder / "camera.exr", 96, 64, "exr"))
        rows.append(pixels("pov_angle", "POV angle = 2 atan(tan(fov_y/2) W/H) = %.2f, z negated" % fov_x(scene["camera"]),
                           exr, ours, interior))
        wrong = source.replace(f"angle {fov_x(scene['camera']):.9g}", f"angle {scene['camera']['fov_y']:.9g}")
        exr_wrong = read_exr(render_pov(wrong, folder / "camera_wrong.exr", 96, 64, "exr"))
        rows.append(pixels("pov_angle_wrong", "POV angle = fov_y (40): the wrong axis", exr_wrong, ours, interior))
        rows.append(report("pov_camera_fit", "POV 96x64 EXR, ka kd ks n fitted (ray tree)",
                           fitted(scene, exr, ("ka", "kd", "ks", "n")), PHONG))
    if mi is not None:
        mscene = mitsuba_sphere(96, 64)
        ours = difflab.render(mscene, spp=16)
        inner = difflab.interior_mask(mscene, margin=1)
        for axis, fov, label in (("x", None, "Mitsuba default fov_axis x, fov = fov_x = %.2f" % fov_x(mscene["camera"])),
                                 ("y", None, "Mitsuba fov_axis y, fov = fov_y = 40")):
            rows.append(pixels(f"mitsuba_fov_{axis}", label, mitsuba_image(mi, mscene, 64, fov_axis=axis), ours, inner))
        wrong = mitsuba_dict(mscene, {"type": "diffuse", "reflectance": {"type": "rgb", "value": REFLECTANCE}}, 64, 1)
        del wrong["sensor"]["fov_axis"]  # fov 40 read as horizontal
        rows.append(pixels("mitsuba_fov_wrong", "Mitsuba default fov_axis x, fov = 40 (fov_y): the wrong axis",
                           render_mitsuba(mi, wrong), ours, inner))
    return rows


def check_lights(folder: Path, mi) -> list:
    """Mitsuba point light + diffuse (kd = rho / pi), with and without the edge margin; a constant
    environment L (ambient L, ka = rho); POV-Ray's fade_power 2 and 1 as attenuations."""
    rows = []
    if mi is not None:
        scene = mitsuba_sphere(96, 96)
        target = mitsuba_image(mi, scene, 64)
        truth = {"kd": scene["materials"]["red"]["kd"], "ks": [0.0] * 3}
        for margin, spp in ((0, 1), (2, 1), (2, 4)):
            rows.append(report(f"mitsuba_point_m{margin}_spp{spp}", f"Mitsuba point I -> I, (0,0,1); rho -> kd = "
                               f"rho/pi; 64 spp box; edge margin {margin}, fit spp {spp}",
                               fitted(scene, target, ("kd", "ks", "n"), margin, spp=spp), truth))
        env = mitsuba_sphere(96, 96, ambient=0.3)
        target = mitsuba_image(mi, env, 64, environment=0.3)
        truth = {"ka": env["materials"]["red"]["ka"], "kd": env["materials"]["red"]["kd"]}
        rows.append(report("mitsuba_constant_env", "Mitsuba constant environment L = 0.3 -> ambient 0.3, ka = rho; "
                           "64 spp box; margin 2", fitted(env, target, ("ka", "kd"), 2), truth))
    if folder is not None:
        for power, attenuation in ((2, (0.5, 0.0, 0.5 / 9.0)), (1, (0.5, 0.5 / 3.0, 0.0)), (2, (1.0, 0.0, 0.1))):
            scene = pov_sphere(96, 96, attenuation=attenuation)
            source = pov_scene(scene)
            exr = read_exr(render_pov(source, folder / "fade.exr", 96, 96, "exr"))
            fade = source.split("fade_distance")[1].split("}")[0].strip()
            rows.append(report(f"pov_fade_power_{power}", f"POV fade_distance {fade} -> attenuation {list(attenuation)}",
                               fitted(scene, exr, ("ka", "kd", "ks", "n")), PHONG))
        plain = pov_sphere(96, 96)
        source = pov_scene(plain)
        light = source.index("light_source")
        zero = source[:light] + source[light:].replace("}", "fade_distance 0 fade_power 2 }", 1)
        rows.append(pixels("pov_fade_distance_0", "POV 3.7 fade_distance 0 fade_power 2 against no fade (no 1 / d^2)",
                           read_exr(render_pov(zero, folder / "zero.exr", 96, 96, "exr")),
                           read_exr(render_pov(source, folder / "plain.exr", 96, 96, "exr")),
                           np.ones((96, 96), bool)))
    return rows


def check_pixels(folder: Path, mi) -> list:
    """Pixel filters (Mitsuba box / gaussian, 16 spp, with an environment for noise; the gaussian's
    noise also given as measured from two seeds), POV-Ray's +A anti-aliasing, and POV-Ray's 8-bit,
    16-bit and float files through either image model."""
    import difflab

    rows = []
    if mi is not None:
        env = mitsuba_sphere(96, 96, ambient=0.3)
        truth = {"ka": env["materials"]["red"]["ka"], "kd": env["materials"]["red"]["kd"]}
        for rfilter in ("box", "gaussian"):
            target = mitsuba_image(mi, env, 16, rfilter=rfilter, environment=0.3)
            rows.append(report(f"mitsuba_{rfilter}", f"Mitsuba {rfilter} filter, 16 spp, environment 0.3; margin 2",
                               fitted(env, target, ("ka", "kd"), 2), truth))
        other = mitsuba_image(mi, env, 16, rfilter="gaussian", environment=0.3, seed=2)
        used = difflab.interior_mask(env, margin=2) & difflab.render_frame(env).gbuffer.mask
        sigma = float(np.std((target - other)[used]) / math.sqrt(2))  # two seeds' difference: sqrt(2) sigma
        rows.append(report("mitsuba_gaussian_sigma", f"the same, sigma = std(seed 1 - seed 2) / sqrt 2 = {sigma:.4f} "
                           f"given", fitted(env, target, ("ka", "kd"), 2, sigma=sigma), truth))
    if folder is not None:
        scene = pov_sphere(96, 96)
        source = pov_scene(scene)
        plain = read_exr(render_pov(source, folder / "plain.exr", 96, 96, "exr"))
        inner = difflab.interior_mask(scene, margin=2) & difflab.render_frame(scene).gbuffer.mask
        for options in (("+A0.1", "+R3"), ("+A0.1", "+R3", "-J")):
            smooth = read_exr(render_pov(source, folder / "aa.exr", 96, 96, "exr", options=options))
            changed = int(np.count_nonzero((np.abs(smooth - plain).max(axis=-1) > 2e-3) & inner))
            rows.append({"check": f"pov_aa_changes{'_nojitter' if '-J' in options else ''}",
                         "what": f"POV {' '.join(options)}: pixels 2 or more from an edge changed by > 2e-3",
                         "changed": changed, "of": int(np.count_nonzero(inner))})
        for fmt, options, margin, spp in (("png8", ("+A0.1", "+R3"), 2, 1), ("exr", ("+A0.1", "+R3"), 0, 1),
                                          ("exr", ("+A0.1", "+R3"), 2, 1), ("exr", ("+A0.0", "+R3", "-J"), 2, 4)):
            path = render_pov(source, folder / f"aa.{'exr' if fmt == 'exr' else 'png'}", 96, 96, fmt, options=options)
            rows.append(report(f"pov_aa_{fmt}_m{margin}_spp{spp}", f"POV {' '.join(options)}, {fmt}; margin {margin}, "
                               f"fit spp {spp}", fitted(scene, read_exr(path) if fmt == "exr" else path,
                                                        ("ka", "kd", "ks", "n"), margin, spp=spp), PHONG))
        for fmt in ("png8", "png16", "png16lin", "exr"):
            path = render_pov(source, folder / f"sphere_{fmt}.{'exr' if fmt == 'exr' else 'png'}", 96, 96, fmt)
            target = read_exr(path) if fmt == "exr" else path
            for method in ("raytrace",) if fmt == "png16lin" else ("raytrace", "raster"):
                rows.append(report(f"pov_{fmt}_{method}", f"POV {fmt} (no +A), {method} image model",
                                   fitted(scene, target, ("ka", "kd", "ks", "n"), method=method), PHONG))
        # two ways to get the encoding wrong: linear floats written into an 8-bit PNG without a gAMA
        # chunk (read back as sRGB), and an sRGB PNG's code values / 255 passed as linear floats
        from PIL import Image

        linear = read_exr(folder / "sphere_exr.exr")
        Image.fromarray((np.clip(linear, 0, 1) * 255 + 0.5).astype(np.uint8)).save(folder / "linear8.png")
        codes = np.asarray(Image.open(folder / "sphere_png8.png").convert("RGB"), np.float32) / 255
        for name, target, what in (("pov_linear_in_png8", folder / "linear8.png", "linear values in an 8-bit PNG, "
                                    "no gAMA"), ("pov_codes_as_floats", codes, "8-bit sRGB codes / 255 as floats")):
            rows.append(report(name, what, fitted(scene, target, ("ka", "kd", "ks", "n")), PHONG))
    return rows


CHECKS = {"camera": check_camera, "lights": check_lights, "pixels": check_pixels}


def print_rows(rows: list) -> None:
    for r in rows:
        if "changed" in r:
            print(f"{r['check']:<22} {r['changed']} of {r['of']} pixels  {r['what']}")
        elif "max_abs_diff" in r:
            print(f"{r['check']:<22} max |diff| {r['max_abs_diff']:.2e}  mean {r['mean_abs_diff']:.2e}  "
                  f"(peak {r['peak']:.3f})  {r['what']}")
        else:
            print(f"{r['check']:<22} rel err {r['max_rel_error']:.4f}  z {r['max_z']:6.1f}  chi2 {r['chi2']:8.3g}  "
                  f"{r['verdict']:<15} {r['what']}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append", choices=sorted(CHECKS), help="run only these checks (repeatable)")
    args = parser.parse_args(argv)
    from difflab.io import write_json_atomic

    import shutil

    mi = mitsuba_module()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) if shutil.which("povray") else None
        for name, check in CHECKS.items():
            if args.only and name not in args.only:
                continue
            found = check(folder, mi)
            print_rows(found)
            rows += found
    if mi is None or folder is None:
        print(f"skipped: {'Mitsuba ' if mi is None else ''}{'POV-Ray' if folder is None else ''} checks (not installed)")
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_json_atomic(RESULTS / "foreign_mappings.json", {"rows": rows, "versions": versions()})
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: fitting ka, kd, ks (RGB) and n to a 256x256 target, Levenberg-Marquardt versus Adam.

Measures wall time and iterations of one fit, including compilation (first call after
`jax.clear_caches()`) and after it (median over repeats), for LM, Adam, variable projection, LM in
float32; and a batch of independent fits, `jax.vmap` over one LM solve versus a loop over the same
compiled solve. Ratios are against LM measured in the same run. Mitsuba 3 is compared when installed.

Writes experiments/results/bench_fit.json and prints a table.

    python experiments/bench/fit.py            # 256x256, 5 repeats, batch of 8 at 64x64
    python experiments/bench/fit.py --small    # 64x64, 2 repeats, batch of 4 at 32x32
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fit_common import RESULTS, SEED, perturb, rel_error, scene_dict, versions  # noqa: E402


DIFFUSE_TRUTH = [0.2, 0.5, 0.8]


def newest_libllvm() -> str | None:
    """The newest system libLLVM of major version >= 17 (Dr.Jit's LLVM backend emits `fmaximum`,
    which older LLVMs cannot lower on x86: Debian 12 needs `apt-get install libllvm19`), or None."""
    found = []
    for path in glob.glob("/usr/lib/*/libLLVM*.so*") + glob.glob("/lib/*/libLLVM*.so*"):
        match = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
        if match and int(match.group(1)) >= 17:
            found.append((int(match.group(1)), path))
    return max(found)[1] if found else None


def mitsuba_diffuse_loop(size: int, iterations: int) -> dict:
    """Mitsuba 3 (llvm_ad_rgb) recovering a sphere's diffuse reflectance by gradient descent (Adam,
    lr 0.05, 4 spp per step, from 0.5 grey) against a 64-spp target of the same scene: the way a
    physically based inverse renderer fits a material. Raises ImportError without Mitsuba."""
    libllvm = newest_libllvm()
    if libllvm and "DRJIT_LIBLLVM_PATH" not in os.environ:
        os.environ["DRJIT_LIBLLVM_PATH"] = libllvm
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1.2, 4], target=[0, 0.6, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size, "pixel_format": "rgb"}},
        "light": {"type": "point", "position": [3, 4, 3], "intensity": {"type": "rgb", "value": [40.0] * 3}},
        "sphere": {"type": "sphere", "center": [0, 1, 0], "radius": 1,
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": DIFFUSE_TRUTH}}},
    })
    target = mi.render(scene, spp=64, seed=SEED)
    params = mi.traverse(scene)
    key = "sphere.bsdf.reflectance.value"
    params[key] = mi.Color3f(0.5, 0.5, 0.5)
    params.update()
    opt = mi.ad.Adam(lr=0.05)
    opt[key] = params[key]
    params.update(opt)
    start = time.perf_counter()
    for it in range(iterations):
        image = mi.render(scene, params, spp=4, seed=it + 1)
        dr.backward(dr.mean(dr.square(image - target)))
        opt.step()
        value = opt[key]
        opt[key] = dr.select(value < 0.0, 0.0, dr.select(value > 1.0, 1.0, value))  # (dr.clip: LLVM fmaximum)
        params.update(opt)
    seconds = time.perf_counter() - start
    found = np.array(params[key], np.float64).reshape(-1)[:3]
    return {"variant": "llvm_ad_rgb", "iterations": iterations, "seconds": seconds,
            "seconds_per_iteration": seconds / iterations, "found": found.tolist(),
            "max_rel_error": float(np.max(np.abs(found - DIFFUSE_TRUTH) / DIFFUSE_TRUTH))}


def difflab_diffuse_fit(size: int) -> dict:
    """difflab's LM on the matching problem: kd of a Lambert sphere (ks = 0) from one exact target."""
    from difflab.fit import fit_material
    from difflab.renderers.api import render_frame
    from difflab.scene import Scene

    scene = Scene.from_dict(scene_dict(size, red={"kd": DIFFUSE_TRUTH, "ks": [0.0] * 3}))
    target = render_frame(scene).image
    times = []
    for _ in range(3):
        result = fit_material(scene, [target], "red", ("kd",), init={"kd": [0.5] * 3}, history=False)
        times.append(result.seconds)
    return {"steps": result.steps, "first_call_s": times[0], "median_s": statistics.median(times[1:]),
            "max_rel_error": float(np.max(np.abs(np.asarray(result.params["kd"]) - DIFFUSE_TRUTH) / DIFFUSE_TRUTH))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true")
    parser.add_argument("--size", type=int)
    parser.add_argument("--repeats", type=int)
    parser.add_argument("--adam-steps", type=int, default=2000)
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_fit.json")
    args = parser.parse_args(argv)
    size = args.size or (64 if args.small else 256)
    repeats = args.repeats or (2 if args.small else 5)

    import jax

    from difflab.fit import Setup, fit_batch, solve
    from difflab.io import write_json_atomic
    from difflab.renderers.api import render_frame
    from difflab.scene import Scene

    rng = np.random.default_rng(SEED)
    truth = {"ka": [0.1, 0.05, 0.02], "kd": [0.7, 0.2, 0.1], "ks": [0.5, 0.4, 0.3], "n": 24.0}
    scene = Scene.from_dict(scene_dict(size))
    target = render_frame(scene).image
    start = perturb(truth, rng)

    configs = [("lm", {"solver": "lm"}, True), ("adam", {"solver": "adam", "max_steps": args.adam_steps,
                                                         "learning_rate": 0.02}, True),
               ("varpro", {"solver": "varpro"}, True), ("lm_float32", {"solver": "lm"}, False)]
    rows = []
    for name, opts, x64 in configs:
        jax.clear_caches()
        setup = Setup(scene, [target], "red", init=start, x64=x64)
        times = []
        for i in range(repeats + 1):
            values, result, steps, seconds, _ = solve(setup, history=False, **opts)
            times.append(seconds)
        err = rel_error({k: values[k] for k in truth}, truth)
        rows.append({"method": name, "x64": x64, "result": result, "steps": steps,
                     "first_call_s": times[0], "median_s": statistics.median(times[1:]),
                     "max_rel_error": max(err.values()), "used_pixels": setup.used_pixels})

    lm = rows[0]
    for row in rows:
        row["ratio_to_lm"] = row["median_s"] / lm["median_s"]

    # batched fits: B independent targets of one view
    batch_size, batch_px = (4, 32) if args.small else (8, 64)
    small_scene = Scene.from_dict(scene_dict(batch_px))
    images = np.stack([render_frame(Scene.from_dict(scene_dict(batch_px, red={"kd": rng.uniform(0.2, 0.8, 3).tolist()})))
                       .image for _ in range(batch_size)])
    batch = {}
    for vmap in (True, False):
        times = []
        for _ in range(repeats + 1):
            t0 = time.perf_counter()
            results = fit_batch(small_scene, images, "red", ("kd", "n"), vmap=vmap, init={"kd": [0.5] * 3, "n": 18.0})
            times.append(time.perf_counter() - t0)
        batch["vmap" if vmap else "loop"] = {
            "first_call_s": times[0], "median_s": statistics.median(times[1:]),
            "solve_median_s": results[0].timings["solve"], "results": sorted({r.result for r in results}),
            "steps": [r.steps for r in results]}

    try:
        mitsuba = mitsuba_diffuse_loop(size, iterations=20 if args.small else 100)
        mitsuba_kd = difflab_diffuse_fit(size)
        mitsuba = {**mitsuba, "difflab_same_problem": mitsuba_kd,
                   "summary": f"Mitsuba 3 Adam recovering a diffuse reflectance: {mitsuba['iterations']} iterations "
                              f"in {mitsuba['seconds']:.2f} s ({mitsuba['seconds_per_iteration'] * 1e3:.0f} ms each), "
                              f"max rel. error {mitsuba['max_rel_error']:.2e}; difflab LM on the same kd problem: "
                              f"{mitsuba_kd['steps']} steps, {mitsuba_kd['median_s']:.3f} s, max rel. error "
                              f"{mitsuba_kd['max_rel_error']:.2e}"}
    except ImportError:
        mitsuba = "not installed: Mitsuba comparison skipped"

    report = {"what": f"fit ka, kd, ks (RGB) and n to a {size}x{size} Phong target from a 30% perturbed start",
              "seed": SEED, "repeats": repeats, "size": size, "rows": rows,
              "batch": {"size": batch_size, "pixels": batch_px, **batch}, "mitsuba": mitsuba, "versions": versions()}
    write_json_atomic(args.out, report)
    print(f"{'method':<12} {'result':<28} {'steps':>6} {'first (s)':>10} {'median (s)':>11} {'x LM':>7} {'max rel err':>12}")
    for r in rows:
        print(f"{r['method']:<12} {r['result']:<28} {r['steps']:>6} {r['first_call_s']:>10.3f} {r['median_s']:>11.4f} "
              f"{r['ratio_to_lm']:>7.2f} {r['max_rel_error']:>12.2e}")
    b = report["batch"]
    print(f"batch of {batch_size} at {batch_px}x{batch_px}: vmap {b['vmap']['median_s']:.3f} s "
          f"(solve {b['vmap']['solve_median_s']:.3f} s), loop {b['loop']['median_s']:.3f} s "
          f"(solve {b['loop']['solve_median_s']:.3f} s)")
    print(mitsuba["summary"] if isinstance(mitsuba, dict) else f"Mitsuba: {mitsuba}")
    print(f"summary: {size}x{size} LM {lm['median_s']:.3f} s after compilation ({lm['steps']} steps, "
          f"{lm['first_call_s']:.1f} s with compilation); Adam {rows[1]['median_s'] / lm['median_s']:.1f}x slower "
          f"({rows[1]['steps']} steps, {rows[1]['result']}); wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

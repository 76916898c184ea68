"""Benchmark of the fitting engine, every figure measured in the same run.

1. Steps and per-step cost of the box Levenberg-Marquardt solve (ka, kd, ks RGB and n, a size x size
   Phong target, 30 % perturbed start) against a plain JAX step on the same pixels (jax.jacfwd of
   the same residuals + a Cholesky solve of the damped normal equations), in float64 and float32;
   the warm wall time of a whole `fit_material` call (setup, solve, statistics).
2. A fresh process that loads a scene file and a target and fits: wall time with the persistent
   compilation cache warm, and with an empty one.
3. Batches: B targets of one view, vmap and loop, throughput against B x one fit.
4. Mitsuba 3 (when installed): a Lambertian sphere rendered by Mitsuba (64 spp, direct light) is the
   target. Mitsuba's own Adam loop (llvm_ad_rgb, 4 spp per step) recovers the reflectance; difflab
   fits kd, ks and n to the same image. Timed on Mitsuba's side: the Adam loop from its first
   iteration (each iteration's render, backward pass, Adam step, clamp and parameter update) until
   the reflectance is within 1 % (0.1 %) of the truth in every channel; not timed: `mi.load_dict`,
   the target's render. Timed on difflab's side: whole warm `fit_material` calls on a compiled
   scene, two ways: the *first fit of the view* (its kept views dropped before each call, so the
   G-buffer is rendered and the image model cut: target checks, render, arrays, the solve, the
   statistics and the result) and the *fit again* of the same view (the compiled scene keeps the
   view's G-buffer and model arrays, `fit.records`: no render), each of the other of two Mitsuba
   renders (two seeds) than the fit just before it, so nothing a fit of one target computed can
   serve the next. The first fits and fits again are timed interleaved (each fit again right after
   a render has cooled the caches), then fits again in a row, as a series of targets of one view is
   fitted (the two targets alternating). Not timed: `compile_scene` (the
   counterpart of `mi.load_dict`), the mask, and the first call of the process (JIT compilation;
   reported apart). Printed: the times, their ratios (difflab = 1/N of Mitsuba's time to 1 %),
   difflab's steps and stages, kd against reflectance / pi, and ks.

Writes experiments/results/bench_fit.json and prints a table.

    python experiments/bench/fit.py            # 256x256, 5 repeats, batches of up to 16 at 64x64
    python experiments/bench/fit.py --small    # 64x64, 2 repeats, batches of up to 8 at 32x32
    python experiments/bench/fit.py --only mitsuba --repeats 9   # the Mitsuba comparison alone
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fit_common import RESULTS, SEED, perturb, rel_error, scene_dict, versions  # noqa: E402
from timing import median_seconds  # noqa: E402

REFLECTANCE = [0.2, 0.5, 0.8]
LIGHT = {"position": [3.0, 4.0, 3.0], "intensity": 40.0}
FRESH = """
import sys, time
t0 = time.perf_counter()
import numpy as np
from difflab import fit_material, load_image, load_scene
scene = load_scene(sys.argv[1])
result = fit_material(scene, [load_image(sys.argv[2])], "red", history=False, progress=False)
print(result.result, result.steps, time.perf_counter() - t0)
"""


def newest_libllvm() -> str | None:
    """The newest system libLLVM of major version >= 17 (Dr.Jit's LLVM backend emits `fmaximum`,
    which older LLVMs cannot lower on x86: Debian 12 needs `apt-get install libllvm19`), or None."""
    found = []
    for path in glob.glob("/usr/lib/*/libLLVM*.so*") + glob.glob("/lib/*/libLLVM*.so*"):
        match = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
        if match and int(match.group(1)) >= 17:
            found.append((int(match.group(1)), path))
    return max(found)[1] if found else None


def per_step(scene, target, start, repeats: int) -> list[dict]:
    """The engine's LM against a plain JAX Jacobian + Cholesky step on the same problem, in float64
    and float32. The per-step cost is marginal -- (t(long solve) - t(1-step solve)) / (its extra
    steps), tolerances 0 so that the solve keeps stepping until a step changes nothing (float32
    gets there after ~7 steps, float64 runs all 12) -- so the fixed cost of a call does not count;
    every timing is interleaved (short, long, plain step, whole solve; float64, float32) so that a
    busy machine slows all alike."""
    import jax
    import jax.numpy as jnp
    import jax.scipy.linalg as jsl

    from difflab.fit import Setup, solve

    @jax.jit
    def plain(problem, x):
        r = problem.residuals(x)
        jac = jax.jacfwd(problem.residuals)(x)
        a = jac.T @ jac + 1e-3 * jnp.diag(jnp.diagonal(jac.T @ jac))
        return x + jsl.cho_solve(jsl.cho_factor(a), -jac.T @ r)

    runs = {}
    for x64 in (True, False):
        setup = Setup(scene, [target], "red", init=start, x64=x64)
        first = time.perf_counter()
        result = solve(setup, history=False, progress=False)
        first = time.perf_counter() - first
        with jax.enable_x64(x64):  # the plain step's inputs on JAX's default device, every core (the engine's
            # closed-form fits run on a client of one thread, `Setup.jax_device`, where a forward-mode step is slower)
            plain_inputs = jax.device_put((setup.problem, jnp.asarray(setup.x0, setup.dtype)), jax.devices()[0])
        runs[x64] = {"setup": setup, "plain": plain_inputs, "result": result, "first": first,
                     "short": [], "long": [], "base": [], "solves": []}

    def timed(setup, steps):
        out = solve(setup, max_steps=steps, rtol=0.0, atol=0.0, history=False, progress=False)
        return out.seconds, out.steps

    def plain_time(run):
        with jax.enable_x64(run["setup"].x64):
            return median_seconds(lambda: jax.block_until_ready(plain(*run["plain"])), 3)

    for run in runs.values():  # compile every length
        timed(run["setup"], 1), timed(run["setup"], 12), plain_time(run)
    for _ in range(max(repeats, 7)):
        for run in runs.values():
            run["short"].append(timed(run["setup"], 1))
            run["long"].append(timed(run["setup"], 12))
            run["base"].append(plain_time(run))
            run["solves"].append(solve(run["setup"], history=False, progress=False).seconds)
    out = []
    for x64, run in runs.items():
        extra = run["long"][0][1] - run["short"][0][1]
        step = (statistics.median(t for t, _ in run["long"]) - statistics.median(t for t, _ in run["short"])) / \
            max(extra, 1)
        baseline = statistics.median(run["base"])
        err = rel_error(run["result"].params, TRUTH)
        out.append({"x64": x64, "result": run["result"].result, "steps": run["result"].steps,
                    "first_call_s": run["first"], "solve_s": statistics.median(run["solves"]), "step_s": step,
                    "extra_steps": extra, "plain_step_s": baseline, "step_ratio": step / baseline,
                    "max_rel_error": max(err.values()),
                    "used_pixels": run["setup"].used_pixels})
    return out


def fresh_process(scene, target, cache_dir: str | None) -> dict:
    """Wall time of a new Python process that loads the scene file and the target and fits."""
    from difflab.io import save_image
    from difflab.scene import save_scene

    with tempfile.TemporaryDirectory() as folder:
        scene_path, target_path = Path(folder) / "scene.json", Path(folder) / "target.npy"
        save_scene(scene, scene_path)
        save_image(target_path, target)
        env = dict(os.environ)
        if cache_dir is not None:
            env["DIFFLAB_CACHE_DIR"] = cache_dir
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", FRESH, str(scene_path), str(target_path)], env=env,
                             capture_output=True, text=True, check=True)
        wall = time.perf_counter() - t0
    code, steps, inside = out.stdout.split()[-3:]
    return {"wall_s": wall, "inside_s": float(inside), "result": code, "steps": int(steps)}


def batches(rng, sizes, px: int) -> list[dict]:
    """Throughput of fit_batch (vmap and loop) against B x a single fit of the same view."""
    from difflab.fit import fit_batch
    from difflab.renderers.api import render_frame
    from difflab.scene import Scene

    scene = Scene.from_dict(scene_dict(px))
    images = np.stack([render_frame(Scene.from_dict(scene_dict(px, red={"kd": rng.uniform(0.2, 0.8, 3).tolist()})))
                       .image for _ in range(max(sizes))])
    rows = []
    for vmap in (True, False):
        for b in sizes:
            def run():
                return fit_batch(scene, images[:b], "red", ("kd", "n"), vmap=vmap, init={"kd": [0.5] * 3, "n": 18.0},
                                 history=False, progress=False)

            results = run()  # compile for this batch size
            seconds = median_seconds(run, 3)
            rows.append({"vmap": vmap, "batch": b, "seconds": seconds, "per_fit_s": seconds / b,
                         "converged": sum(r.converged for r in results)})
    for row in rows:
        one = next(r for r in rows if r["vmap"] == row["vmap"] and r["batch"] == 1)
        row["efficiency"] = one["seconds"] * row["batch"] / row["seconds"]
    return rows


def mitsuba_comparison(size: int, iterations: int, repeats: int) -> dict:
    """Mitsuba's Adam loop and difflab's fit on one Mitsuba target (raises ImportError without it)."""
    libllvm = newest_libllvm()
    if libllvm and "DRJIT_LIBLLVM_PATH" not in os.environ:
        os.environ["DRJIT_LIBLLVM_PATH"] = libllvm
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "sensor": {"type": "perspective", "fov": 40, "fov_axis": "y",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 1.2, 4], target=[0, 0.6, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size, "pixel_format": "rgb",
                            "rfilter": {"type": "box"}}},
        "light": {"type": "point", "position": LIGHT["position"],
                  "intensity": {"type": "rgb", "value": [LIGHT["intensity"]] * 3}},
        "sphere": {"type": "sphere", "center": [0, 1, 0], "radius": 1,
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": REFLECTANCE}}},
    })
    # two renders (other seeds, other noise): difflab's repeated fits alternate them, so nothing one
    # target's fit computed can serve the next; Mitsuba's loop fits the first
    target, other = (mi.render(scene, spp=64, seed=SEED + k) for k in (0, 1))
    targets = [np.asarray(image, np.float32)[..., :3] for image in (target, other)]
    params = mi.traverse(scene)
    key = "sphere.bsdf.reflectance.value"
    params[key] = mi.Color3f(0.5, 0.5, 0.5)
    params.update()
    opt = mi.ad.Adam(lr=0.05)
    opt[key] = params[key]
    params.update(opt)
    trace = []
    start = time.perf_counter()
    for it in range(iterations):
        image = mi.render(scene, params, spp=4, seed=it + 1)
        dr.backward(dr.mean(dr.square(image - target)))
        opt.step()
        value = opt[key]
        opt[key] = dr.select(value < 0.0, 0.0, dr.select(value > 1.0, 1.0, value))  # (dr.clip: LLVM fmaximum)
        params.update(opt)
        found = np.array(params[key], np.float64).reshape(-1)[:3]
        trace.append((time.perf_counter() - start, float(np.max(np.abs(found - REFLECTANCE) / REFLECTANCE))))

    def time_to(tol):
        return next((t for t, err in trace if err < tol), None)

    mitsuba = {"iterations": iterations, "seconds": trace[-1][0], "final_max_rel_error": trace[-1][1],
               "time_to_1pct_s": time_to(1e-2), "time_to_0.1pct_s": time_to(1e-3)}
    difflab = difflab_on_mitsuba_target(size, targets, repeats)
    return {"mitsuba": mitsuba, "difflab": difflab, "load_1min": os.getloadavg()[0],
            "xla_threads": os.environ.get("DIFFLAB_JAX_THREADS", "").strip() or "all"}


def difflab_on_mitsuba_target(size: int, targets: list, repeats: int) -> dict:
    """kd, ks, n of a sphere fitted to Mitsuba's images: kd should be reflectance / pi, ks 0 (its
    bound). Each fit is of the other of `targets` (two renders of the scene) than the fit before it.
    Mitsuba's pixels integrate over their area, difflab samples centres: the fit reads the sphere's
    interior pixels (2 pixels in from its silhouette, `difflab.interior_mask`). Reported: the
    fit of targets[0]."""
    from difflab import compile_scene, interior_mask
    from difflab.fit import fit_material
    from difflab.fit.records import STORE
    from difflab.scene import Scene

    d = scene_dict(size, red={"ka": [0.0] * 3, "kd": [0.1] * 3, "ks": [0.2] * 3, "n": 10.0},
                   lights=[{"type": "point", "position": LIGHT["position"], "intensity": [LIGHT["intensity"]] * 3,
                            "attenuation": [0, 0, 1]}])
    d["ambient"], d["background"] = [0, 0, 0], [0, 0, 0]
    d["objects"] = d["objects"][:1]  # the sphere alone, as in Mitsuba's scene
    d["render"]["shadows"] = False
    scene = Scene.from_dict(d)
    mask = interior_mask(d, margin=2)

    compiled = compile_scene(scene)

    def run(first_of_view: bool, which: int):
        if first_of_view:
            compiled.built.pop(STORE, None)  # the views kept: none (the next fit renders its G-buffer)
        t0 = time.perf_counter()
        result = fit_material(compiled, [targets[which]], "red", ("kd", "ks", "n"), masks=[mask], history=False,
                              progress=False)
        return result, time.perf_counter() - t0, which

    first_call = run(True, 0)[1]
    busy0 = others_busy()
    timed, fits = {True: [], False: []}, 1  # fits made so far: fit k is of targets[k % 2], the other one each time
    for _ in range(repeats):  # interleaved: a first fit of the view, then the same view again
        for first_of_view in (True, False):
            timed[first_of_view].append(run(first_of_view, fits % 2))
            fits += 1
    in_row = [run(False, k % 2) for k in range(fits, fits + repeats)]  # a series of targets of one view
    busy1 = others_busy()

    def stages(runs) -> dict:
        return {"wall_s": statistics.median(t for _, t, _ in runs),
                **{f"{k}_s": statistics.median(r.timings[k] for r, _, _ in runs) for k in ("setup", "render", "solve",
                                                                                           "stats")}}

    done = timed[True] + timed[False] + in_row
    for which in (0, 1):  # every fit of one target came out the same
        same = [r for r, _, w in done if w == which]
        assert all(r.steps == same[0].steps and r.params == same[0].params for r in same)
    result = next(r for r, _, w in done if w == 0)
    kd_error = np.abs(np.asarray(result.params["kd"]) * np.pi - REFLECTANCE) / REFLECTANCE
    return {"result": result.result, "steps": result.steps, "first_call_s": first_call,
            "first_fit": stages(timed[True]), "again": stages(timed[False]), "in_row": stages(in_row),
            "kd_times_pi": (np.asarray(result.params["kd"]) * np.pi).tolist(), "kd_max_rel_error": float(kd_error.max()),
            "ks": result.params["ks"], "at_bound": result.at_bound, "chi2": result.chi2,
            "others_cores": busy0 and (busy1[0] - busy0[0] - busy1[1] + busy0[1]) / (busy1[2] - busy0[2])}


def others_busy() -> tuple[float, float, float] | None:
    """(CPU seconds the machine spent busy, of which this process's, wall seconds) now, from /proc/stat
    (None without it). The fits' times depend on a free second core: on the 2-core VM, of 16 processes in a
    row (20 first / again fits each, medians), those during which other processes used ~1 core took first
    9.4-11.0 ms, render 2.4-2.7, again 5.4-6.6; those with ~0.1: 7.4-8.7, 1.8-1.9, 4.4-5.0 ms. The 1-min
    load average does not tell such 4-s runs apart. (/proc/stat counts in ticks of 10 ms: over the ~0.3 s of
    the bench's fits, +-0.1 core.)"""
    try:
        with open("/proc/stat") as f:
            ticks = [int(x) for x in f.readline().split()[1:]]
    except OSError:
        return None
    busy = sum(ticks[:3]) + sum(ticks[5:7])  # user nice system irq softirq (not idle, iowait, steal)
    return busy / os.sysconf("SC_CLK_TCK"), time.process_time(), time.perf_counter()


TRUTH = {"ka": [0.1, 0.05, 0.02], "kd": [0.7, 0.2, 0.1], "ks": [0.5, 0.4, 0.3], "n": 24.0}


SECTIONS = ("steps", "fresh", "batch", "mitsuba")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true")
    parser.add_argument("--size", type=int)
    parser.add_argument("--repeats", type=int)
    parser.add_argument("--adam-steps", type=int)
    parser.add_argument("--only", choices=SECTIONS, action="append", help="run only these sections (repeatable)")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_fit.json")
    args = parser.parse_args(argv)
    size = args.size or (64 if args.small else 256)
    repeats = args.repeats or (2 if args.small else 5)
    sections = args.only or SECTIONS

    from difflab.fit import fit_material
    from difflab.io import write_json_atomic
    from difflab.renderers.api import render_frame
    from difflab.scene import Scene

    rng = np.random.default_rng(SEED)
    scene = Scene.from_dict(scene_dict(size))
    target = render_frame(scene).image
    start = perturb(TRUTH, rng)
    report = {"what": f"fit ka, kd, ks (RGB) and n to a {size}x{size} Phong target from a 30 % perturbed start; "
                      "batches; a fresh process; Mitsuba 3 on its own target", "seed": SEED, "size": size,
              "repeats": repeats, "versions": versions()}
    if "steps" in sections:
        report["per_step"] = per_step(scene, target, start, repeats)
        fit_material(scene, [target], "red", init=start, history=False, progress=False)
        report["warm_fit_material_s"] = median_seconds(
            lambda: fit_material(scene, [target], "red", init=start, history=False, progress=False), repeats)
    if "fresh" in sections:
        start_scene = Scene.from_dict(scene_dict(size, red=start))
        with tempfile.TemporaryDirectory() as empty:
            report["fresh_process"] = {
                "warm_cache": (fresh_process(start_scene, target, None), fresh_process(start_scene, target, None))[1],
                "empty_cache": fresh_process(start_scene, target, empty)}
    if "batch" in sections:
        report["batch"] = batches(rng, (1, 2, 4, 8) if args.small else (1, 2, 4, 8, 16), 32 if args.small else 64)
    if "mitsuba" in sections:
        try:
            report["mitsuba"] = mitsuba_comparison(size, args.adam_steps or (60 if args.small else 200), repeats)
            m, d = report["mitsuba"]["mitsuba"], report["mitsuba"]["difflab"]
            for way in ("first_fit", "again", "in_row"):
                report["mitsuba"][f"mitsuba_1pct_over_difflab_{way}"] = (m["time_to_1pct_s"] / d[way]["wall_s"]
                                                                         if m["time_to_1pct_s"] else None)
        except ImportError as exc:
            report["mitsuba"] = f"not installed ({exc}): Mitsuba comparison skipped"
    write_json_atomic(args.out, report)
    print_report(report)
    print(f"wrote {args.out}")
    return 0


def print_report(report: dict) -> None:
    if "per_step" in report:
        steps = report["per_step"]
        print(f"{'precision':<10} {'result':<12} {'steps':>5} {'first (s)':>10} {'solve (s)':>10} {'step (ms)':>10} "
              f"{'plain JAX step (ms)':>20} {'ratio':>6} {'max rel err':>12}")
        for r in steps:
            print(f"{'float64' if r['x64'] else 'float32':<10} {r['result']:<12} {r['steps']:>5} "
                  f"{r['first_call_s']:>10.2f} {r['solve_s']:>10.4f} {r['step_s'] * 1e3:>10.2f} "
                  f"{r['plain_step_s'] * 1e3:>20.2f} {r['step_ratio']:>6.2f} {r['max_rel_error']:>12.1e}")
        print(f"float32 / float64 solve time: {steps[1]['solve_s'] / steps[0]['solve_s']:.2f}; warm fit_material "
              f"(setup + solve + statistics): {report['warm_fit_material_s']:.3f} s")
    if "fresh_process" in report:
        fresh = report["fresh_process"]
        print(f"fresh process (load scene + target, fit): warm cache {fresh['warm_cache']['wall_s']:.2f} s, "
              f"empty cache {fresh['empty_cache']['wall_s']:.2f} s")
    for vmap in (True, False) if "batch" in report else ():
        cells = ", ".join(f"B={r['batch']}: {r['per_fit_s'] * 1e3:.1f} ms/fit ({r['efficiency'] * 100:.0f} %)"
                          for r in report["batch"] if r["vmap"] == vmap)
        print(f"batch {'vmap' if vmap else 'loop'} (throughput vs B x one fit): {cells}")
    mitsuba = report.get("mitsuba")
    if isinstance(mitsuba, dict):
        m, d = mitsuba["mitsuba"], mitsuba["difflab"]
        fmt = lambda s: "not reached" if s is None else f"{s:.2f} s"  # noqa: E731
        print(f"Mitsuba 3 Adam ({m['iterations']} iterations, {m['seconds']:.1f} s): 1 % at "
              f"{fmt(m['time_to_1pct_s'])}, 0.1 % at {fmt(m['time_to_0.1pct_s'])}; difflab kd, ks, n on the same "
              f"target: {d['steps']} steps ({d['first_call_s']:.1f} s first call of the process), kd x pi "
              f"within {d['kd_max_rel_error'] * 100:.2f} % of the reflectance, ks max {max(d['ks']):.2g} "
              f"(at bound: {d['at_bound']})")
        for way, label in (("first_fit", "first fit of the view (G-buffer rendered)"),
                           ("again", "the view fitted again right after a first fit (G-buffer and arrays kept)"),
                           ("in_row", "the view fitted again, fits in a row (a series of targets of one view)")):
            w, ratio = d[way], mitsuba[f"mitsuba_1pct_over_difflab_{way}"]
            share = f"1/{ratio:.1f} of Mitsuba's time to 1 %" if ratio else "Mitsuba did not reach 1 %"
            print(f"difflab warm, {label}: {w['wall_s'] * 1e3:.1f} ms = {share} (setup {w['setup_s'] * 1e3:.1f} ms "
                  f"of which the Warp render {w['render_s'] * 1e3:.1f} ms, solve {w['solve_s'] * 1e3:.1f} ms, "
                  f"statistics {w['stats_s'] * 1e3:.1f} ms)")
        others = d.get("others_cores")
        others = "" if others is None else \
            f"; other processes used {max(others, 0.0):.1f} of {os.cpu_count()} cores in the fits"
        print(f"(goal: 1/50 or less; medians, first / again interleaved, then the fits in a row; load average "
              f"{mitsuba['load_1min']:.1f} after the run; DIFFLAB_JAX_THREADS={mitsuba['xla_threads']}{others})")
    elif mitsuba is not None:
        print(f"Mitsuba: {mitsuba}")


if __name__ == "__main__":
    sys.exit(main())

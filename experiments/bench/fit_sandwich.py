"""Benchmark of the standard errors under unequal noise (`fit.sandwich`), every figure measured in the same run.

1. Cost: the statistics phase (`FitResult.timings["stats"]`) and the whole warm `fit_material` call
   of bench/fit.py's first fit -- a size x size Lambertian sphere under a point light, kd, ks, n
   fitted on its interior (`interior_mask`) on a compiled scene whose kept views are dropped before
   each call -- against a difflab render whose noise is 1 % of each value (unequal by channel and
   intensity, as a Monte Carlo render's: the sandwich is formed), with the sandwich, with its middle
   waited for as soon as it is started (JAX's J^T diag(r^2) J not run beside the rest of the noise
   estimate), and with it switched off (the pooled form: `engine.noise_middle` returning None),
   interleaved, medians.
2. Coverage: over `seeds` targets of tests/test_fit_sandwich.py's 48 x 48 Phong sphere (ka, kd,
   ks, n fitted), the share of |fitted - truth| <= 2 stderr of ka, kd, ks per channel and their rms
   z-score, sandwich and pooled, for per-channel noise (0.003, 0.003, 0.012) and noise of 5 % of
   each value.

Writes experiments/results/bench_fit_sandwich.json and prints a table.

    python experiments/bench/fit_sandwich.py            # 256 px, 30 repeats, 40 seeds
    python experiments/bench/fit_sandwich.py --small    # 96 px, 10 repeats, 20 seeds
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(HERE), str(HERE / "experiments"), str(HERE / "tests")]
RESULTS = HERE / "experiments" / "results"
REFLECTANCE = np.array([0.2, 0.5, 0.8])
NOISES = {"per-channel": lambda rng, exact: rng.standard_normal(exact.shape) * np.array([0.003, 0.003, 0.012]),
          "5 % of value": lambda rng, exact: rng.standard_normal(exact.shape) * 0.05 * exact}


def switched(mode: str):
    """Set the sandwich on ("sandwich"), on with its middle waited for at once ("waited"), or off
    ("pooled")."""
    from difflab.fit import engine, sandwich

    def waited(*args):
        started = sandwich.noise_middle(*args)
        matrix = None if started is None else started()
        return None if matrix is None else lambda: matrix

    engine.noise_middle = {"sandwich": sandwich.noise_middle, "waited": waited, "pooled": lambda *args: None}[mode]


def cost(size: int, repeats: int) -> dict:
    """Median stats phase and warm wall time (ms) of the first fit per `switched` mode, interleaved."""
    import difflab
    from difflab.fit.records import STORE
    from fit_common import scene_dict

    d = scene_dict(size, red={"ka": [0.0] * 3, "kd": (REFLECTANCE / np.pi).tolist(), "ks": [0.0] * 3, "n": 10.0},
                   lights=[{"type": "point", "position": [3.0, 4.0, 3.0], "intensity": [40.0] * 3,
                            "attenuation": [0, 0, 1]}])
    d["ambient"], d["background"], d["objects"], d["render"]["shadows"] = [0, 0, 0], [0, 0, 0], d["objects"][:1], False
    scene = difflab.Scene.from_dict(d)
    exact = difflab.render(scene)
    target = (exact * (1 + 0.01 * np.random.default_rng(0).standard_normal(exact.shape))).astype(np.float32)
    mask = difflab.interior_mask(scene)
    compiled = difflab.compile_scene(scene)

    def run():
        compiled.built.pop(STORE, None)  # the first fit of the view: G-buffer rendered, model cut
        start = time.perf_counter()
        r = difflab.fit_material(compiled, [target], "red", ("kd", "ks", "n"), masks=[mask], history=False,
                                 progress=False)
        return time.perf_counter() - start, r

    out, modes = {}, ("sandwich", "waited", "pooled")
    for mode in modes:
        switched(mode)
        run()  # (compilation)
    samples = {mode: [] for mode in modes}
    for _ in range(repeats):
        for mode in modes:
            switched(mode)
            wall, r = run()
            samples[mode].append((wall, r.timings["stats"]))
            out["stderr_" + mode] = {k: np.asarray(v).tolist() for k, v in r.stderr.items()}
    switched("sandwich")
    for mode in modes:
        out[mode] = {"wall_ms": 1e3 * statistics.median(s[0] for s in samples[mode]),
                     "stats_ms": 1e3 * statistics.median(s[1] for s in samples[mode])}
    return out


def coverage(seeds: int) -> dict:
    """Per noise and form: coverage of |z| <= 2 and rms z per channel (ka, kd, ks pooled)."""
    import difflab
    from test_fit_helpers import TRUTH, make_scene, target_of

    scene = make_scene(size=48)
    compiled, exact = difflab.compile_scene(scene), target_of(scene)
    truth = np.array([TRUTH[k] for k in ("ka", "kd", "ks")])
    out = {}
    for name, noise in NOISES.items():
        for form in ("sandwich", "pooled"):
            switched(form)
            rng, z = np.random.default_rng(0), []
            for _ in range(seeds):
                target = (exact + noise(rng, exact)).astype(np.float32)
                r = difflab.fit_material(compiled, [target], "red", ("ka", "kd", "ks", "n"), ceiling=False,
                                         progress=False)
                fitted = np.array([r.params[k] for k in ("ka", "kd", "ks")])
                z.append((fitted - truth) / np.array([r.stderr[k] for k in ("ka", "kd", "ks")]))
            z = np.array(z)
            out[f"{name}, {form}"] = {"coverage": (np.abs(z) <= 2).mean(axis=(0, 1)).tolist(),
                                      "rms_z": np.sqrt(np.mean(np.square(z), axis=(0, 1))).tolist()}
    switched("sandwich")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="96 px, 10 repeats, 20 seeds")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_fit_sandwich.json")
    args = parser.parse_args()
    size, repeats, seeds = (96, 10, 20) if args.small else (256, 30, 40)
    report = {"load": os.getloadavg(), "size": size, "repeats": repeats, "seeds": seeds}
    report["cost"] = cost(size, repeats)
    on, waited, off = (report["cost"][mode] for mode in ("sandwich", "waited", "pooled"))
    print(f"load {report['load'][0]:.1f}; first fit, {size}^2 sphere, 1 % noise of each value, medians of {repeats}:")
    print(f"  stats {on['stats_ms']:.2f} ms with the sandwich, {waited['stats_ms']:.2f} with its middle waited for at "
          f"once, {off['stats_ms']:.2f} pooled (+{on['stats_ms'] - off['stats_ms']:.2f}); wall {on['wall_ms']:.2f} / "
          f"{waited['wall_ms']:.2f} / {off['wall_ms']:.2f} ms")
    report["coverage"] = coverage(seeds)
    print(f"coverage of |fitted - truth| <= 2 stderr per channel (R, G, B) and rms z, 48^2 sphere, {seeds} seeds:")
    for name, row in report["coverage"].items():
        print(f"  {name:<24} " + " ".join(f"{c:.3f}" for c in row["coverage"]) + "   rms z "
              + " ".join(f"{v:.2f}" for v in row["rms_z"]))
    from difflab.io import write_json_atomic

    write_json_atomic(args.out, report)


if __name__ == "__main__":
    main()

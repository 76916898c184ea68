"""Recovery error and standard-error coverage versus image noise.

For each noise level sigma (Gaussian, seeded, added to a linear target), fit ka, kd, ks (RGB) and n
with Levenberg-Marquardt from a 30% perturbed start, T trials each, and record the relative error per
parameter and whether the truth lies within 1, 2 and 3 reported standard errors. Linearised least
squares predicts coverage of about 68 / 95 / 99.7 %.

Writes experiments/results/fit_noise.{csv,json,png}; prints a one-line summary.

    python experiments/fit_noise.py            # 64x64, 5 levels x 20 trials
    python experiments/fit_noise.py --small    # 24x24, 3 levels x 4 trials
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_common import RESULTS, SEED, perturb, scene_dict, versions, write_csv  # noqa: E402

TRUTH = {"ka": [0.1, 0.05, 0.02], "kd": [0.7, 0.2, 0.1], "ks": [0.5, 0.4, 0.3], "n": 24.0}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true")
    args = parser.parse_args(argv)
    size, levels, trials = (24, [0.003, 0.01, 0.03], 4) if args.small else (64, [0.001, 0.003, 0.01, 0.03, 0.1], 20)

    from difflab.fit import fit_material
    from difflab.io import write_json_atomic
    from difflab.renderers.api import render_frame
    from difflab.scene import Scene

    rng = np.random.default_rng(SEED)
    scene = Scene.from_dict(scene_dict(size))
    clean = render_frame(scene).image.astype(np.float64)
    rows = []
    for sigma in levels:
        for t in range(trials):
            noisy = clean + rng.normal(0.0, sigma, clean.shape)
            result = fit_material(scene, [noisy], "red", init=perturb(TRUTH, rng), history=False)
            for key, truth in TRUTH.items():
                value, err = np.atleast_1d(result.params[key]), np.atleast_1d(result.stderr[key])
                z = np.abs(value - truth) / err
                for c in range(value.size):
                    rows.append({"sigma": sigma, "trial": t, "param": f"{key}[{c}]" if value.size > 1 else key,
                                 "truth": float(np.atleast_1d(truth)[c]), "value": float(value[c]),
                                 "stderr": float(err[c]), "rel_error": float(abs(value[c] / np.atleast_1d(truth)[c] - 1)),
                                 "z": float(z[c]), "converged": result.converged,
                                 "poorly_determined": key in result.poorly_determined})
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_csv(RESULTS / "fit_noise.csv", rows)
    summary = []
    for sigma in levels:
        mine = [r for r in rows if r["sigma"] == sigma]
        z = np.array([r["z"] for r in mine])
        summary.append({"sigma": sigma, "median_rel_error": float(np.median([r["rel_error"] for r in mine])),
                        "coverage_1": float(np.mean(z <= 1)), "coverage_2": float(np.mean(z <= 2)),
                        "coverage_3": float(np.mean(z <= 3)),
                        "converged": float(np.mean([r["converged"] for r in mine]))})
    write_json_atomic(RESULTS / "fit_noise.json", {"seed": SEED, "size": size, "trials": trials, "summary": summary,
                                                   "versions": versions()})
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].loglog(levels, [s["median_rel_error"] for s in summary], "o-")
    ax[0].set_xlabel("noise sigma")
    ax[0].set_ylabel("median relative error")
    for k, ideal in ((1, 0.683), (2, 0.954), (3, 0.997)):
        ax[1].semilogx(levels, [s[f"coverage_{k}"] for s in summary], "o-", label=f"within {k} stderr")
        ax[1].axhline(ideal, ls=":", color="grey")
    ax[1].set_xlabel("noise sigma")
    ax[1].set_ylabel("coverage")
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(RESULTS / "fit_noise.png", dpi=100)
    worst3 = min(s["coverage_3"] for s in summary)
    print(f"fit_noise: {len(levels)} noise levels x {trials} trials at {size}x{size}; 3-stderr coverage >= "
          f"{worst3:.1%} (ideal 99.7%); median error at sigma={levels[-1]}: {summary[-1]['median_rel_error']:.2e} "
          f"-> {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Recovery of random materials from synthetic targets, for each solver.

For K seeded random plastics (ka, kd, ks per channel, n), render a noise-free target, fit from a 30%
perturbed start with each solver, and record: the result code, steps and wall time (after
compilation), and the final relative error per parameter.

Writes experiments/results/fit_recovery.{csv,json,png}; prints a one-line summary.

    python experiments/fit_recovery.py            # 64x64, 10 materials
    python experiments/fit_recovery.py --small    # 24x24, 2 materials
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_common import RESULTS, SEED, perturb, random_material, rel_error, scene_dict, versions, write_csv  # noqa: E402

SOLVERS = ("lm", "gauss_newton", "dogleg", "bfgs", "adam", "varpro")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true")
    parser.add_argument("--count", type=int)
    parser.add_argument("--size", type=int)
    args = parser.parse_args(argv)
    count, size = args.count or (2 if args.small else 10), args.size or (24 if args.small else 64)

    import jax

    from difflab.fit import Setup, solve
    from difflab.io import write_json_atomic
    from difflab.renderers.api import render_frame
    from difflab.scene import Scene

    rng = np.random.default_rng(SEED)
    rows = []
    for k in range(count):
        truth = random_material(rng)
        scene = Scene.from_dict(scene_dict(size, red=truth))
        target = render_frame(scene).image
        start = perturb(truth, rng)
        for solver in SOLVERS:
            setup = Setup(scene, [target], "red", init=start)
            max_steps = 3000 if solver == "adam" else 500
            options = {"learning_rate": 0.02} if solver == "adam" else {}
            solve(setup, solver=solver, max_steps=max_steps, history=False, **options)  # compile
            result = solve(setup, solver=solver, max_steps=max_steps, history=False, **options)
            err = rel_error(result.params, truth)
            rows.append({"material": k, "solver": solver, "result": result.result, "steps": result.steps,
                         "seconds": result.seconds, **{f"err_{p}": e for p, e in err.items()},
                         "max_err": max(err.values())})
        jax.clear_caches() if k % 4 == 3 else None

    RESULTS.mkdir(parents=True, exist_ok=True)
    write_csv(RESULTS / "fit_recovery.csv", rows)
    summary = {}
    for solver in SOLVERS:
        mine = [r for r in rows if r["solver"] == solver]
        summary[solver] = {
            "converged": sum(r["result"] == "successful" for r in mine), "runs": len(mine),
            "median_steps": float(np.median([r["steps"] for r in mine])),
            "median_seconds": float(np.median([r["seconds"] for r in mine])),
            "median_max_err": float(np.median([r["max_err"] for r in mine])),
            "worst_max_err": float(np.max([r["max_err"] for r in mine]))}
    write_json_atomic(RESULTS / "fit_recovery.json", {"seed": SEED, "size": size, "count": count, "summary": summary,
                                                      "rows": rows, "versions": versions()})
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for i, solver in enumerate(SOLVERS):
        mine = [r for r in rows if r["solver"] == solver]
        ax[0].scatter([i] * len(mine), [max(r["max_err"], 1e-16) for r in mine], s=12)
        ax[1].scatter([i] * len(mine), [r["seconds"] for r in mine], s=12)
    for a, label in zip(ax, ["max relative error", "seconds (after compilation)"]):
        a.set_xticks(range(len(SOLVERS)), SOLVERS, rotation=30)
        a.set_yscale("log")
        a.set_ylabel(label)
    fig.suptitle(f"recovery from a 30% perturbed start, {count} random materials, {size}x{size}")
    fig.tight_layout()
    fig.savefig(RESULTS / "fit_recovery.png", dpi=100)
    lm = summary["lm"]
    print(f"fit_recovery: LM converged {lm['converged']}/{lm['runs']}, median {lm['median_steps']:.0f} steps, "
          f"{lm['median_seconds']:.3f} s, worst error {lm['worst_max_err']:.1e}; "
          + ", ".join(f"{s} {v['converged']}/{v['runs']}" for s, v in summary.items()) + f" -> {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

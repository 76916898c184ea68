"""How many views make ks and n well determined?

The light sits behind the sphere, so from the first camera no highlight is visible and ks and n are
poorly determined. Cameras are added one at a time on an orbit towards the light; with each set of
views (noisy targets, seeded) LM fits ka, kd, ks (RGB) and n, and we record the relative standard
errors of ks and n and whether the fit flags them as poorly determined. A second sweep adds lights
instead of views (one camera, 1..4 lights around the sphere).

Writes experiments/results/fit_views.{csv,json,png}; prints a one-line summary.

    python experiments/fit_views.py            # 64x64, up to 4 views / lights
    python experiments/fit_views.py --small    # 24x24, up to 3
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fit_common import RESULTS, SEED, perturb, scene_dict, versions, write_csv  # noqa: E402

TRUTH = {"ka": [0.1, 0.05, 0.02], "kd": [0.7, 0.2, 0.1], "ks": [0.5, 0.4, 0.3], "n": 24.0}
NOISE = 0.01


def camera(size, angle_deg):
    a = math.radians(angle_deg)
    return {"eye": [4 * math.sin(a), 1.2, 4 * math.cos(a)], "target": [0, 0.8, 0], "up": [0, 1, 0], "fov_y": 40,
            "width": size, "height": size}


def light(angle_deg):
    a = math.radians(angle_deg)
    return {"type": "point", "position": [3 * math.sin(a), 3.0, 3 * math.cos(a)], "intensity": [1, 1, 1]}


def fit_row(scene, views, rng, sweep, count):
    from difflab.fit import fit_material
    from difflab.renderers.api import render_frame

    targets = []
    for overrides in views:
        clean = render_frame(scene.with_overrides(**overrides)).image
        targets.append((clean + rng.normal(0, NOISE, clean.shape), overrides))
    result = fit_material(scene, targets, "red", init=perturb(TRUTH, rng), history=False)
    rel = {k: float(np.max(np.asarray(result.stderr[k]) / np.abs(np.asarray(result.params[k])))) for k in ("ks", "n")}
    return {"sweep": sweep, "count": count, "result": result.result, "rel_stderr_ks": rel["ks"],
            "rel_stderr_n": rel["n"], "ks_flagged": "ks" in result.poorly_determined,
            "n_flagged": "n" in result.poorly_determined,
            "n_error": abs(result.params["n"] / TRUTH["n"] - 1)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true")
    args = parser.parse_args(argv)
    size, most = (24, 3) if args.small else (64, 4)

    from difflab.io import write_json_atomic
    from difflab.scene import Scene

    rng = np.random.default_rng(SEED)
    base = Scene.from_dict(scene_dict(size, red=TRUTH, lights=[light(180)]))  # straight behind
    rows = []
    angles = [0, 60, 120, 180][:most]
    for k in range(1, most + 1):
        views = [{"camera": camera(size, a)} for a in angles[:k]]
        rows.append(fit_row(base, views, rng, "views", k))
    light_angles = [180, 0, 90, -90][:most]
    for k in range(1, most + 1):
        rows.append(fit_row(base, [{"lights": [light(a) for a in light_angles[:k]]}], rng, "lights", k))

    RESULTS.mkdir(parents=True, exist_ok=True)
    write_csv(RESULTS / "fit_views.csv", rows)
    write_json_atomic(RESULTS / "fit_views.json", {"seed": SEED, "size": size, "noise": NOISE, "rows": rows,
                                                   "versions": versions()})
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for a, sweep in zip(ax, ("views", "lights")):
        mine = [r for r in rows if r["sweep"] == sweep]
        for key in ("ks", "n"):
            a.semilogy([r["count"] for r in mine], [min(r[f"rel_stderr_{key}"], 1e6) for r in mine], "o-", label=key)
        a.axhline(0.1, ls=":", color="grey")
        a.set_xlabel(f"number of {sweep}")
        a.set_ylabel("relative standard error")
        a.legend()
    fig.tight_layout()
    fig.savefig(RESULTS / "fit_views.png", dpi=100)
    first_ok = next((r["count"] for r in rows if r["sweep"] == "views" and not (r["ks_flagged"] or r["n_flagged"])),
                    None)
    print(f"fit_views: with the light behind the sphere, ks and n are flagged from 1 view "
          f"({rows[0]['ks_flagged'] and rows[0]['n_flagged']}) and well determined from {first_ok} view(s); "
          f"rel stderr of n: " + ", ".join(f"{r['rel_stderr_n']:.2g}" for r in rows if r["sweep"] == "views")
          + f" -> {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark of the standard errors of matrix-free (texel) fits, every figure measured in the same run.

1. The statistics phase of a fit (`FitResult.timings["stats"]`: the sparse Jacobian by column
   compression, J^T J, diag (J^T J)^-1, noise, flags) of an H_t x H_t bilinear kd texture -- alone
   and with ks beside it -- on a quad seen in W x W pixels with noise 0.02 (16^2 texels / 48 px,
   32^2 / 96 px): the first call (compilation; persistent cache off) and the median of the warm
   calls (`solve` on the same `Setup` again), in a fresh process per tree; with `--old TREE`
   (another checkout, e.g. the code before this feature, whose stderr were nan) in processes
   interleaved with this tree's.
2. The size limits of `fit.stats`: `covariance_unscaled` (eigh) of a dense p x p J^T J, and
   `inverse_diagonal` of a unit-diagonal block with a bilinear texture channel's pattern (texels
   coupled to their 8 neighbours; its SuperLU factors have the fill of a real 64^2 texture
   channel's, 222,506 entries): banded (Takahashi) and by SuperLU (one solve per unit vector),
   medians of the repeats.

Writes experiments/results/bench_fit_stderr.json and prints a table.

    python experiments/bench/fit_stderr.py                   # 5 repeats
    python experiments/bench/fit_stderr.py --small           # 16^2 only, 2 repeats, limits up to 2048
    python experiments/bench/fit_stderr.py --old /tmp/oldtree
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
from timing import median_seconds, worker_in

RESULTS = Path(__file__).resolve().parents[1] / "results"
HERE = Path(__file__).resolve().parents[2]
SIZES = ((16, 48), (32, 96))  # (texels per side, pixels per side)
PARAMS = (("texture",), ("texture", "ks"))


def worker(size: int, pixels: int, params: tuple, repeats: int) -> dict:
    """In this process (the tree on sys.path): the stats phase of the first and the warm solves."""
    from difflab import render
    from difflab.fit import Setup, solve
    from difflab.renderers.api import as_scene

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "truth.npy"
        np.save(path, np.random.default_rng(3).uniform(0.2, 0.8, (size, size, 3)).astype(np.float32))
        scene = as_scene({
            "camera": {"eye": [0, 0, 3], "target": [0, 0, 0], "fov_y": 40, "width": pixels, "height": pixels},
            "ambient": [0.1, 0.1, 0.1], "lights": [{"type": "point", "position": [1, 2, 4]}],
            "materials": {"m": {"ka": 0.2, "kd": 1, "ks": 0.3, "n": 20, "texture": str(path), "wrap": "clamp"}},
            "objects": [{"type": "mesh", "builtin": "quad", "material": "m",
                         "transform": {"rotate_deg": [90, 0, 0], "scale": 2.0}}],
            "render": {"shadows": False}})
        target = render(scene) + np.random.default_rng(4).normal(0, 0.02, (pixels, pixels, 3)).astype(np.float32)
        setup = Setup(scene, target, "m", params, init={"texture": 0.5, "ks": [0.2] * 3} if "ks" in params else
                      {"texture": 0.5})
        times = [solve(setup).timings["stats"] for _ in range(repeats + 1)]
        result = solve(setup)
    err = np.asarray(result.stderr["texture"], np.float64)
    return {"first_s": times[0], "warm_s": statistics.median(times[1:]), "finite": float(np.isfinite(err).mean()),
            "median_stderr": float(np.median(err)) if np.isfinite(err).any() else float("nan")}


def stencil(side: int) -> "scipy.sparse.csc_matrix":  # noqa: F821
    """A unit-diagonal SPD matrix coupling each texel of a side x side grid to its 8 neighbours."""
    import scipy.sparse as sp

    index = np.arange(side * side).reshape(side, side)
    rows, cols = [], []
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            a = index[max(0, -di):side - max(0, di), max(0, -dj):side - max(0, dj)]
            b = index[max(0, di):side + min(0, di), max(0, dj):side + min(0, dj)]
            rows.append(a.reshape(-1))
            cols.append(b.reshape(-1))
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    off = np.where(rows == cols, 0.0, np.random.default_rng(0).uniform(0.05, 0.1, rows.size))
    gram = sp.csc_matrix((off, (rows, cols)), shape=(side * side,) * 2)
    return (gram + gram.T + sp.eye(side * side)).tocsc()


def limits(repeats: int, small: bool) -> dict:
    """Median seconds of the dense and the sparse inverse diagonal by size."""
    from difflab.fit.inverse_diagonal import banded, factored
    from difflab.fit.stats import covariance_unscaled

    out = {"dense": {}, "banded": {}, "lu": {}}
    for p in (768, 1536, 2048) if small else (768, 1536, 2048, 3072):
        jac = np.random.default_rng(1).normal(size=(p + 16, p))
        out["dense"][p] = median_seconds(lambda: covariance_unscaled(jac.T @ jac), repeats)
    for side in (32, 45) if small else (32, 45, 64, 90, 128):
        block = stencil(side).tocsr()
        out["banded"][side * side] = median_seconds(lambda: banded(block)[1](), repeats)
        if side <= 90:
            out["lu"][side * side] = median_seconds(lambda: factored(block)[1](), repeats)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="the 16^2 texture only, 2 repeats")
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--old", type=Path, default=None, help="another checkout to compare with")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_fit_stderr.json")
    parser.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        size, pixels, params, repeats = args.worker
        print(json.dumps(worker(int(size), int(pixels), tuple(params.split(",")), int(repeats))))
        return
    repeats = args.repeats or (2 if args.small else 5)
    trees = {"new": HERE, **({"old": args.old.resolve()} if args.old else {})}
    report = {"load": os.getloadavg(), "repeats": repeats, "fits": []}
    print(f"load {os.getloadavg()[0]:.1f}; medians of {repeats}; first call without the compilation cache")
    for size, pixels in SIZES[:1] if args.small else SIZES:
        for params in PARAMS:
            row = {"texels": size, "pixels": pixels, "params": list(params)}
            for name, tree in trees.items():  # fresh processes, interleaved: a busy machine slows both alike
                row[name] = worker_in(tree, __file__, size, pixels, ",".join(params), repeats)
            report["fits"].append(row)
            new = row["new"]
            line = (f"{size:>3}^2 texels ({3 * size * size + 3 * (len(params) - 1)} entries) {'+'.join(params):<11} "
                    f"{pixels}^2 px: stats warm {new['warm_s']:.3f} s first {new['first_s']:.2f} s, "
                    f"{100 * new['finite']:.0f} % finite, median stderr {new['median_stderr']:.2g}")
            if "old" in row:
                old = row["old"]
                line += (f" | old warm {old['warm_s']:.3f} s first {old['first_s']:.2f} s "
                         f"({100 * old['finite']:.0f} % finite): new/old warm {new['warm_s'] / old['warm_s']:.1f}x")
            print(line, flush=True)
    report["limits"] = limits(repeats, args.small)
    print("dense eigh (covariance_unscaled): " + ", ".join(f"p {p}: {s:.2f} s" for p, s in report["limits"]["dense"].items()))
    for name in ("banded", "lu"):
        print(f"{name} block (inverse_diagonal): " + ", ".join(f"n {n}: {s:.2f} s"
                                                            for n, s in report["limits"][name].items()))
    from difflab.io import write_json_atomic

    write_json_atomic(args.out, report)


if __name__ == "__main__":
    main()

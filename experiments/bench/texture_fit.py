"""Benchmark of texel fits (`fit_texture`, the one engine's matrix-free box LM), every figure measured
in the same run.

1. One CG product pair (J v then J^T u) of the solver, float64, on the first view of each size: the
   texels in the image's affine form (`texels.texel_linearisation`: the points' gains times the
   filter taps; the derivative every solver gets from `Problem.residuals`) against the whole shading
   model linearised (`matfree.linearisation` of the residuals computed without that derivative)
   -- medians of the repeats, and their ratio.
2. Whole `fit_texture` calls ("lm"; `--solver gauss_newton` for optimistix's, whose CG products are
   the same) from a fresh process per tree: the first call (JIT compilation, the
   persistent cache switched off) and the warm calls after it; with `--old TREE` the same script
   runs on another checkout (e.g. a worktree of 02a8271, the dedicated texture solver before the
   engine) in processes interleaved with this tree's, and the table gives new / old ratios.

Problems (as issue 10's measurements): an H_t x H_t random RGB texture on a quad seen in two views
of W x W pixels (sizes 24/72, 64/128, 128/192), fitted from 0.5.

Writes experiments/results/bench_texture_fit.json and prints a table.

    python experiments/bench/texture_fit.py                 # all three sizes, 3 repeats
    python experiments/bench/texture_fit.py --small         # 24^2 texture only, 2 repeats
    python experiments/bench/texture_fit.py --old /tmp/oldtree
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from timing import worker_in

RESULTS = Path(__file__).resolve().parents[1] / "results"
HERE = Path(__file__).resolve().parents[2]
SIZES = ((24, 72), (64, 128), (128, 192))  # (texels per side, pixels per side)
EYES = ((0, 0, 3), (0.8, 0.4, 2.8))


def quad_views(size: int, pixels: int, folder: Path):
    """Two views of a quad carrying a random size x size kd texture: (texels, TextureViews)."""
    from difflab import render_frame
    from difflab.fit.texture_fit import texture_view
    from difflab.renderers.api import as_scene

    texels = np.random.default_rng(3).uniform(0.1, 0.9, (size, size, 3)).astype(np.float32)
    path = folder / f"truth{size}.npy"
    np.save(path, texels)
    views = []
    for eye in EYES:
        scene = as_scene({
            "camera": {"eye": list(eye), "target": [0, 0, 0], "fov_y": 40, "width": pixels, "height": pixels},
            "ambient": [0.1, 0.1, 0.1],
            "lights": [{"type": "point", "position": [1, 2, 4], "intensity": [1, 1, 1]},
                       {"type": "directional", "direction": [0, 0, -1], "intensity": [0.3, 0.3, 0.3]}],
            "materials": {"m": {"ka": 0.2, "kd": 1, "ks": 0.3, "n": 20, "texture": str(path), "wrap": "clamp"}},
            "objects": [{"type": "mesh", "builtin": "quad", "material": "m",
                         "transform": {"rotate_deg": [90, 0, 0], "scale": 2.0}}],
            "render": {"shadows": False}})
        frame = render_frame(scene)
        views.append(texture_view(frame.gbuffer, frame.image, scene, "m", (size, size)))
    return texels, views


def worker(size: int, pixels: int, repeats: int, solver: str) -> dict:
    """In this process (the tree on sys.path): the first and the warm fit_texture calls."""
    from difflab.fit.texture_fit import fit_texture

    with tempfile.TemporaryDirectory() as folder:
        texels, views = quad_views(size, pixels, Path(folder))
        times = []
        for _ in range(repeats + 1):
            start = time.perf_counter()
            result = fit_texture(views, (size, size), init=0.5, solver=solver)
            times.append(time.perf_counter() - start)
    return {"first_s": times[0], "warm_s": statistics.median(times[1:]), "steps": int(result.steps),
            "result": result.result, "max_error": float(np.abs(result.texture - texels)[result.visible].max())}


def products(size: int, pixels: int, repeats: int) -> dict:
    """Median seconds of one J v + J^T u pair, affine form against the linearised model."""
    import jax
    import jax.numpy as jnp

    from difflab import render
    from difflab.fit import Setup
    from difflab.fit.matfree import linearisation
    from difflab.fit.texels import texel_linearisation

    with tempfile.TemporaryDirectory() as folder, jax.enable_x64(True):
        _, views = quad_views(size, pixels, Path(folder))
        setup = Setup(views[0].scene, render(views[0].scene), "m", ("texture",), init={"texture": 0.5})
        x = jnp.asarray(setup.x0)
        v = jnp.asarray(np.random.default_rng(0).normal(size=x.shape))
        none = np.zeros(0, np.int64)

        def whole_model(y, q):  # the residuals without their custom derivative (`texels.affine_residuals`)
            return q.residuals(y, q.point_texels(q.layout.values(y)))

        forms = {"affine": texel_linearisation,
                 "linearised": lambda x, p: linearisation(whole_model, none, x, p)}
        out = {}
        for name, form in forms.items():
            def run(p, x, v, k, form=form):  # k normalised J^T J products after one linearisation
                _, jvp, vjp, _ = form(x, p)
                return jax.lax.fori_loop(0, k, lambda i, w: (lambda z: z / jnp.linalg.norm(z))(vjp(jvp(w))), v)

            run = jax.jit(run, static_argnums=3)
            seconds = {}
            for k in (1, 21):
                jax.block_until_ready(run(setup.problem, x, v, k))
                times = []
                for _ in range(repeats):
                    start = time.perf_counter()
                    jax.block_until_ready(run(setup.problem, x, v, k))
                    times.append(time.perf_counter() - start)
                seconds[k] = statistics.median(times)
            out[name + "_ms"] = 1e3 * (seconds[21] - seconds[1]) / 20
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="the 24^2 texture only, 2 repeats")
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--old", type=Path, default=None, help="another checkout to compare with")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_texture_fit.json")
    parser.add_argument("--solver", default="lm", choices=("lm", "gauss_newton"))
    parser.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        size, pixels, repeats, solver = args.worker
        print(json.dumps(worker(int(size), int(pixels), int(repeats), solver)))
        return
    repeats = args.repeats or (2 if args.small else 3)
    sizes = SIZES[:1] if args.small else SIZES
    trees = {"new": HERE, **({"old": args.old.resolve()} if args.old else {})}
    report = {"load": os.getloadavg(), "repeats": repeats, "solver": args.solver, "sizes": []}
    print(f"load {os.getloadavg()[0]:.1f}; medians of {repeats}; solver {args.solver}; first call without the "
          "compilation cache")
    for size, pixels in sizes:
        row = {"texels": size, "pixels": pixels, "unknowns": 3 * size * size, **products(size, pixels, repeats)}
        for name, tree in trees.items():  # fresh processes, interleaved: a busy machine slows both alike
            row[name] = worker_in(tree, __file__, size, pixels, repeats, args.solver)
        report["sizes"].append(row)
        line = (f"{size:>4}^2 texels, 2 x {pixels}^2 px: J v + J^T u {row['affine_ms']:.2f} ms affine vs "
                f"{row['linearised_ms']:.2f} ms linearised ({row['linearised_ms'] / row['affine_ms']:.1f}x); "
                f"fit warm {row['new']['warm_s']:.2f} s first {row['new']['first_s']:.2f} s, "
                f"{row['new']['steps']} steps, max error {row['new']['max_error']:.1e}")
        if "old" in row:
            line += (f" | old warm {row['old']['warm_s']:.2f} s first {row['old']['first_s']:.2f} s "
                     f"{row['old']['steps']} steps: new/old warm {row['new']['warm_s'] / row['old']['warm_s']:.2f}, "
                     f"first {row['new']['first_s'] / row['old']['first_s']:.2f}")
        print(line, flush=True)
    from difflab.io import write_json_atomic

    write_json_atomic(args.out, report)


if __name__ == "__main__":
    main()

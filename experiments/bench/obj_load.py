"""Benchmark: `load_mesh` of OBJ files as tools export them, each load in a fresh process (Python and
numpy started, `difflab.geometry` imported, then only the load timed), medians of interleaved repeats.

Files (an n x n grid of cells on a wavy sheet, n = 400: 160 801 `v` lines, 320 000 triangles):
  triangles      `f a b c`, two a cell (numpy read them before polygons were)
  quads          `f a/t b/t c/t d/t`, a `vt` a vertex (as Blender exports: the common case)
  quads_relative the same quads with negative (relative) indices (`absolute_indices`)
The ratios quads / triangles and quads_relative / triangles say what a polygon file costs over a
triangle file of the same surface. `--old TREE` times another checkout (e.g. a detached worktree of
main before a change) in processes interleaved with this one's, and prints old / new.

    python experiments/bench/obj_load.py            # n = 400, 3 repeats
    python experiments/bench/obj_load.py --small    # n = 100, 3 repeats
    python experiments/bench/obj_load.py --old /work/wt/exp

Writes experiments/results/bench_obj_load.json (atomically) and prints a table.
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
FILES = ("triangles", "quads", "quads_relative")


def grid_obj(n: int, name: str) -> str:
    """OBJ text of an n x n grid of cells over [0, 1]^2 at height sin(6x) cos(6y) / 10, uvs (x, y),
    as the file `name` of FILES."""
    x, y = (a.ravel() for a in np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij"))
    points = np.column_stack([x, y, np.sin(6 * x) * np.cos(6 * y) / 10])
    corner = np.arange(n + 1)[:, None] * (n + 1) + np.arange(n + 1)  # 0-based vertex of grid point (i, j)
    quads = np.stack([corner[:-1, :-1], corner[1:, :-1], corner[1:, 1:], corner[:-1, 1:]], -1).reshape(-1, 4)
    lines = ["# grid %d x %d" % (n, n)] + ["v %.6f %.6f %.6f" % tuple(p) for p in points]
    if name == "triangles":
        faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]) + 1
        return "\n".join(lines + ["f %d %d %d" % tuple(f) for f in faces]) + "\n"
    lines += ["vt %.6f %.6f" % (u, v) for u, v in points[:, :2]]
    index = quads + 1 if name == "quads" else quads - len(points)  # relative: -1 is the last `v` / `vt` line
    return "\n".join(lines + ["f %d/%d %d/%d %d/%d %d/%d" % tuple(np.repeat(f, 2)) for f in index]) + "\n"


def worker(path: str) -> dict:
    """One load in this (fresh) process: seconds, triangles, vertices."""
    from difflab.geometry import load_mesh

    start = time.perf_counter()
    mesh = load_mesh(path)
    return {"seconds": time.perf_counter() - start, "faces": mesh.n_faces, "vertices": mesh.n_vertices}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="a 100 x 100 grid")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--old", type=Path, default=None, help="another checkout to time beside this one")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_obj_load.json")
    parser.add_argument("--worker", nargs=1, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker[0])))
        return
    n = 100 if args.small else 400
    trees = {"new": HERE, **({"old": args.old.resolve()} if args.old else {})}
    seconds = {(tree, name): [] for tree in trees for name in FILES}
    shapes = {}
    with tempfile.TemporaryDirectory() as folder:
        paths = {name: Path(folder) / f"{name}.obj" for name in FILES}
        for name, path in paths.items():
            path.write_text(grid_obj(n, name))
        for _ in range(args.repeats):  # interleaved: a busy machine slows every file and tree alike
            for name, path in paths.items():
                for tree, root in trees.items():
                    result = worker_in(root, __file__, path)
                    seconds[tree, name].append(result["seconds"])
                    shapes[tree, name] = (result["faces"], result["vertices"])
        sizes = {name: path.stat().st_size for name, path in paths.items()}
    median = {key: statistics.median(times) for key, times in seconds.items()}
    print(f"load {os.getloadavg()[0]:.1f}; {n} x {n} grid; medians of {args.repeats} fresh-process loads "
          f"({sys.executable})")
    print(f"{'file':<16}{'MB':>6}{'triangles':>11}{'vertices':>10}" + "".join(f"{t + ' s':>10}" for t in trees)
          + (f"{'old/new':>9}" if "old" in trees else ""))
    for name in FILES:
        faces, vertices = shapes["new", name]
        line = f"{name:<16}{sizes[name] / 1e6:>6.1f}{faces:>11}{vertices:>10}" + "".join(
            f"{median[t, name]:>10.3f}" for t in trees)
        if "old" in trees:
            line += f"{median['old', name] / median['new', name]:>9.1f}"
        print(line)
    ratios = {tree: {name: median[tree, name] / median[tree, "triangles"] for name in FILES[1:]} for tree in trees}
    for tree, ratio in ratios.items():
        print(f"{tree}: " + ", ".join(f"{name} / triangles {r:.2f}" for name, r in ratio.items()))
    from difflab.io import write_json_atomic

    write_json_atomic(args.out, {"load": os.getloadavg(), "grid": n, "repeats": args.repeats, "file_bytes": sizes,
                                 "trees": {t: str(r) for t, r in trees.items()},
                                 "seconds": {f"{t}/{name}": s for (t, name), s in seconds.items()},
                                 "median_seconds": {f"{t}/{name}": s for (t, name), s in median.items()},
                                 "ratio_over_triangles": ratios})
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

"""Batch throughput: fits per minute at 1, 2, 4, 8 jobs in flight, locally and on a Dask LocalCluster.

A manifest of J small fits (a sphere's ka, kd, ks, n from one SxS target each, every target with its
own kd) runs through `difflab.fit_many` on local worker processes and on a `distributed.LocalCluster`
of as many single-threaded worker processes. For each it reports the wall time of the whole batch
(worker start-up and first compilation included) and the steady rate (fits finished after the first
one, over the time from the first result to the last), beside one warm fit: the median
time of a fit inside the lone worker of the 1-in-flight local run (each worker's first, compiling,
job left out), and, for reference, the same job function timed in this process. From those:

    ideal rate        = cores / warm fit time                  (fits/s: every core busy with warm fits)
    per-job overhead  = in-flight / steady rate - warm fit time  (s: what a job costs beyond its fit)
    core-seconds/job  = min(in-flight, cores) / steady rate    (the cluster's best run)
    projection(N)     = N x cores / core-seconds per job      -- a projection from the measured cost,
                        not a measurement: machines like this one, the scheduler's own limit (about
                        1 ms per task, 60,000 tasks/min) and the shared filesystem left out.

Writes experiments/results/bench_batch.json and prints a table.

    python experiments/bench/batch.py              # 64 fits of 24x24, 1/2/4/8 in flight
    python experiments/bench/batch.py --small      # 24 fits of 16x16, 1/2/4 in flight
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "results"
KD_STEPS = 10


def scene_dict(size: int, kd) -> dict:
    return {
        "camera": {"eye": [0, 1.2, 4], "target": [0, 0.6, 0], "fov_y": 40, "width": size, "height": size},
        "ambient": [0.2, 0.2, 0.2], "background": [0.05, 0.05, 0.1],
        "lights": [{"type": "point", "position": [3, 4, 3], "intensity": [1, 1, 1]}],
        "materials": {"red": {"ka": [0.1, 0.05, 0.02], "kd": kd, "ks": [0.5, 0.4, 0.3], "n": 24.0},
                      "floor": {"kd": [0.8, 0.8, 0.8]}},
        "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"},
                    {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
        "render": {"shading": "phong", "shadows": True},
    }


def write_batch(folder: Path, jobs: int, size: int) -> Path:
    """The start scene, one .npy target per job (kd varies) and the manifest; returns its path."""
    from difflab.io import save_image
    from difflab import render
    from difflab.scene import Scene, save_scene

    save_scene(Scene.from_dict(scene_dict(size, [0.5, 0.5, 0.5])), folder / "scene.json")
    lines = []
    for i in range(jobs):
        kd = [0.3 + 0.05 * (i % KD_STEPS), 0.2, 0.1]
        save_image(folder / f"t{i}.npy", render(Scene.from_dict(scene_dict(size, kd))))
        lines.append({"name": f"fit{i:04d}", "scene": "scene.json", "targets": [f"t{i}.npy"], "material": "red"})
    manifest = folder / "manifest.jsonl"
    manifest.write_text("".join(json.dumps(line) + "\n" for line in lines))
    return manifest


def warm_fit_seconds(manifest: Path, repeats: int) -> float:
    """Median wall time of one job in this process once its compiled solve exists (the first call
    compiles and is not counted)."""
    from difflab.batch.manifest import load_manifest
    from difflab.batch.worker import outcome_of

    jobs, _ = load_manifest(manifest)
    assert outcome_of(jobs[0].spec)["ok"]
    times = []
    for job in jobs[1:repeats + 1]:
        start = time.perf_counter()
        outcome_of(job.spec)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def run_batch(manifest: Path, out: Path, in_flight: int, **where) -> dict:
    """One `fit_many` run: its wall time, the steady rate from the reports' modification times, and
    the median time of one fit inside a worker (timing/, without each worker's first, compiling, job)."""
    from difflab import fit_many

    start = time.perf_counter()
    summary = fit_many(manifest, out, quiet=True, progress=False, **where)
    wall = time.perf_counter() - start
    finished = sorted(p.stat().st_mtime_ns for p in (out / "reports").glob("*.json"))
    steady = (len(finished) - 1) / ((finished[-1] - finished[0]) * 1e-9)
    fits = sorted(json.loads(p.read_text())["seconds"] for p in (out / "timing").glob("*.json"))[:-in_flight]
    return {"in_flight": in_flight, "wall_s": wall, "jobs_per_min": 60 * len(finished) / wall,
            "steady_jobs_per_min": 60 * steady, "fit_in_worker_median_s": statistics.median(fits),
            "converged": summary.counts["converged"], "jobs": summary.ran}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="24 fits of 16x16, 1/2/4 in flight")
    parser.add_argument("--jobs", type=int)
    parser.add_argument("--size", type=int)
    parser.add_argument("--in-flight", help="comma-separated (default 1,2,4,8)")
    parser.add_argument("--no-cluster", action="store_true", help="skip the Dask LocalCluster runs")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_batch.json")
    args = parser.parse_args(argv)
    jobs = args.jobs or (24 if args.small else 64)
    size = args.size or (16 if args.small else 24)
    in_flight = [int(x) for x in (args.in_flight or ("1,2,4" if args.small else "1,2,4,8")).split(",")]
    cores = os.cpu_count() or 1

    from difflab.io import write_json_atomic

    with tempfile.TemporaryDirectory(prefix="difflab-bench-batch-") as tmp:
        tmp = Path(tmp)
        os.environ.setdefault("DIFFLAB_CACHE_DIR", str(tmp / "cache"))  # an empty compilation cache to start
        manifest = write_batch(tmp, jobs, size)
        in_process = warm_fit_seconds(manifest, repeats=min(10, jobs - 1))
        rows = []
        for n in in_flight:
            rows.append({"backend": "local", **run_batch(manifest, tmp / f"local{n}", n, workers=n)})
            print(rows[-1], file=sys.stderr)
        if not args.no_cluster:
            from distributed import Client, LocalCluster

            for n in in_flight:
                with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
                        Client(cluster) as client:
                    rows.append({"backend": "dask", **run_batch(manifest, tmp / f"dask{n}", n, client=client)})
                print(rows[-1], file=sys.stderr)
    one = [r for r in rows if r["backend"] == "local" and r["in_flight"] == 1]
    warm = one[0]["fit_in_worker_median_s"] if one else in_process  # a warm fit in a worker, nothing beside it
    ideal = 60 * cores / warm
    for row in rows:
        row["per_job_overhead_s"] = row["in_flight"] * 60 / row["steady_jobs_per_min"] - warm
        row["steady_vs_ideal"] = row["steady_jobs_per_min"] / (60 * min(row["in_flight"], cores) / warm)
    best = {b: max((r for r in rows if r["backend"] == b), key=lambda r: r["steady_jobs_per_min"], default=None)
            for b in ("local", "dask")}
    core_seconds = (min(best["dask"]["in_flight"], cores) * 60 / best["dask"]["steady_jobs_per_min"]
                    if best["dask"] else None)
    projection = ({str(m): 60 * m * cores / core_seconds for m in (1, 2, 4, 8, 16, 32)} if core_seconds else {})

    print(f"batch of {jobs} fits ({size}x{size}, ka/kd/ks/n), {cores} cores; warm single fit {warm * 1e3:.1f} ms "
          f"in a lone worker ({in_process * 1e3:.1f} ms in this process) -> ideal {ideal:.0f} fits/min")
    print(f"{'backend':<8}{'in flight':>10}{'wall s':>9}{'fits/min':>10}{'steady/min':>12}{'vs ideal':>10}"
          f"{'overhead ms':>13}")
    for r in rows:
        print(f"{r['backend']:<8}{r['in_flight']:>10}{r['wall_s']:>9.2f}{r['jobs_per_min']:>10.0f}"
              f"{r['steady_jobs_per_min']:>12.0f}{r['steady_vs_ideal']:>10.2f}{r['per_job_overhead_s'] * 1e3:>13.1f}")
    if best["local"] and best["dask"]:
        print(f"dask / local (best steady): {best['dask']['steady_jobs_per_min'] / best['local']['steady_jobs_per_min']:.2f}")
    if projection:
        print("projection (not measured) for N machines of " + f"{cores} cores: "
              + ", ".join(f"N={m}: {rate:.0f}/min" for m, rate in projection.items()))
    import dask
    import jax
    import warp

    write_json_atomic(args.out, {
        "what": "fit_many throughput: local worker processes and a Dask LocalCluster vs one warm fit",
        "jobs": jobs, "size": size, "cores": cores, "warm_fit_s": warm, "warm_fit_in_process_s": in_process,
        "ideal_fits_per_min": ideal, "runs": rows,
        "projection_fits_per_min_by_machines": projection,
        "core_seconds_per_job": core_seconds,
        "projection_note": "N x cores / core-seconds per job of the best Dask run; not measured",
        "versions": {"python": platform.python_version(), "jax": jax.__version__, "warp": warp.__version__,
                     "dask": dask.__version__}})
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Batch throughput: fits per minute at 1, 2, 4, 8 jobs in flight, locally and on a Dask LocalCluster.

A manifest of J small fits (a sphere's ka, kd, ks, n from one SxS target each, every target with its
own kd; 200 by default, the issue's batch) runs through `difflab.fit_many` on local worker processes
and on a `distributed.LocalCluster` of as many single-threaded worker processes, the two back to back
at each number in flight, R times over (medians reported: the machine may be shared, and the load
average is printed beside them). For each it reports the wall time of the whole batch (worker
start-up and first compilation included) and the steady rate (fits finished after the first one,
over the time from the first result to the last), beside one warm fit: the median time of a fit
inside the lone worker of the 1-in-flight local runs (each worker's first, compiling, job left out),
and, for reference, the same job function timed in this process. From those:

    ideal rate        = cores / warm fit time                  (fits/s: every core busy with warm fits)
    per-job overhead  = in-flight / steady rate - warm fit time  (s: what a job costs beyond its fit)
    dask / local      = steady rates at the same number in flight, and best against best
    cpu ms/fit        = CPU time of all the run's processes (client, scheduler, workers) per fit, over
                        the steady part; cpu vs local = local's over Dask's: the rate ratio to expect
                        where the batch has the cores to itself (on a shared machine the rates follow
                        the load, the CPU times much less)
    core-seconds/job  = min(in-flight, cores) / steady rate    (the cluster's best run)
    projection(N)     = N x cores / core-seconds per job      -- a projection from the measured cost,
                        not a measurement: machines like this one, the scheduler's own limit (about
                        1 ms per task, 60,000 tasks/min; a task holds several fits, see
                        difflab.batch.runners.task_size) and the shared filesystem left out
    client cap        = 1 / CPU time of this process per fit  (fits/s: the one client receives and
                        writes every result, whatever the cluster; a LocalCluster's scheduler and
                        nannies run in it too, so this cap is low)

Writes experiments/results/bench_batch.json and prints a table.

    python experiments/bench/batch.py              # 200 fits of 24x24, 1/2/4/8 in flight, 3 repeats
    python experiments/bench/batch.py --small      # 24 fits of 16x16, 1/2/4 in flight, 3 repeats
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import threading
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


class TreeCpu:
    """CPU seconds of this process and all its descendants (pool workers; Dask nannies and workers),
    sampled every `interval` s on a thread while a batch runs (the process list refreshed each
    `refresh` s). `between(t0, t1)`: the CPU spent from the first sample at or after t0 to the last
    at or before t1 (all processes, and this one alone: the client, with a LocalCluster's scheduler),
    and that span. Needs psutil (a dependency of distributed)."""

    def __init__(self, interval: float = 0.05, refresh: float = 0.5):
        import psutil

        self.psutil, self.interval, self.refresh = psutil, interval, refresh
        self.samples, self.stop = [], threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        me, procs, listed = self.psutil.Process(), [], 0.0
        while not self.stop.wait(self.interval):
            now = time.time()
            if now - listed > self.refresh:
                procs, listed = [me] + me.children(recursive=True), now
            total = 0.0
            for proc in procs:
                try:
                    times = proc.cpu_times()
                    total += times.user + times.system + times.children_user + times.children_system
                except self.psutil.Error:
                    pass
            own = me.cpu_times()
            self.samples.append((now, total, own.user + own.system))

    def close(self) -> None:
        self.stop.set()
        self.thread.join()

    def between(self, t0: float, t1: float):
        inside = [s for s in self.samples if t0 <= s[0] <= t1]
        if len(inside) < 2:
            return None
        return inside[-1][1] - inside[0][1], inside[-1][2] - inside[0][2], inside[0][0], inside[-1][0]


def run_batch(manifest: Path, out: Path, in_flight: int, **where) -> dict:
    """One `fit_many` run: its wall time, the steady rate from the reports' modification times, the
    median time of one fit inside a worker (timing/, without each worker's first, compiling, job),
    and the CPU time of all the run's processes per fit in the steady part (when psutil is there):
    on a machine that other work shares, the rate follows the load, the CPU time much less."""
    from difflab import fit_many

    try:
        cpu = TreeCpu()
    except ImportError:
        cpu = None
    start = time.perf_counter()
    try:
        summary = fit_many(manifest, out, quiet=True, progress=False, **where)
    finally:
        if cpu is not None:
            cpu.close()
    wall = time.perf_counter() - start
    finished = sorted(p.stat().st_mtime_ns * 1e-9 for p in (out / "reports").glob("*.json"))
    steady = (len(finished) - 1) / (finished[-1] - finished[0])
    fits = sorted(json.loads(p.read_text())["seconds"] for p in (out / "timing").glob("*.json"))[:-in_flight]
    span = cpu.between(finished[0], finished[-1]) if cpu is not None else None
    done = sum(span[2] < t <= span[3] for t in finished) if span else 0
    return {"in_flight": in_flight, "wall_s": wall, "jobs_per_min": 60 * len(finished) / wall,
            "steady_jobs_per_min": 60 * steady, "fit_in_worker_median_s": statistics.median(fits),
            "cpu_per_job_s": span[0] / done if done else None, "client_cpu_per_job_s": span[1] / done if done else None,
            "converged": summary.counts["converged"], "jobs": summary.ran}


def dask_batch(manifest: Path, out: Path, in_flight: int) -> dict:
    """`run_batch` on a fresh LocalCluster of `in_flight` single-threaded worker processes."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=in_flight, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        return run_batch(manifest, out, in_flight, client=client)


def medians(runs: list[dict]) -> dict:
    """One row of the runs of a (backend, in flight): the median of each measured figure."""
    keys = ("wall_s", "jobs_per_min", "steady_jobs_per_min", "fit_in_worker_median_s", "cpu_per_job_s",
            "client_cpu_per_job_s")
    return {**runs[0], **{k: statistics.median(r[k] for r in runs) if None not in (r[k] for r in runs) else None
                          for k in keys},
            "steady_jobs_per_min_runs": [r["steady_jobs_per_min"] for r in runs],
            "converged": min(r["converged"] for r in runs)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="24 fits of 16x16, 1/2/4 in flight")
    parser.add_argument("--jobs", type=int)
    parser.add_argument("--size", type=int)
    parser.add_argument("--in-flight", help="comma-separated (default 1,2,4,8)")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each backend and number in flight")
    parser.add_argument("--no-cluster", action="store_true", help="skip the Dask LocalCluster runs")
    parser.add_argument("--out", type=Path, default=RESULTS / "bench_batch.json")
    args = parser.parse_args(argv)
    jobs = args.jobs or (24 if args.small else 200)
    size = args.size or (16 if args.small else 24)
    in_flight = [int(x) for x in (args.in_flight or ("1,2,4" if args.small else "1,2,4,8")).split(",")]
    backends = ("local",) if args.no_cluster else ("local", "dask")
    cores = os.cpu_count() or 1

    from difflab.io import write_json_atomic

    load_before = os.getloadavg()
    runs = {}
    with tempfile.TemporaryDirectory(prefix="difflab-bench-batch-") as tmp:
        tmp = Path(tmp)
        os.environ.setdefault("DIFFLAB_CACHE_DIR", str(tmp / "cache"))  # an empty compilation cache to start
        manifest = write_batch(tmp, jobs, size)
        in_process = warm_fit_seconds(manifest, repeats=min(10, jobs - 1))
        for rep in range(args.repeats):  # local and Dask back to back at each number in flight
            for n in in_flight:
                for backend in backends:
                    out = tmp / f"{backend}{n}-{rep}"
                    run = (dask_batch(manifest, out, n) if backend == "dask"
                           else run_batch(manifest, out, n, workers=n))
                    runs.setdefault((backend, n), []).append({"backend": backend, **run})
                    print(runs[backend, n][-1], file=sys.stderr)
    load_after = os.getloadavg()
    rows = [medians(r) for r in runs.values()]
    local = {r["in_flight"]: r for r in rows if r["backend"] == "local"}
    warm = local[1]["fit_in_worker_median_s"] if 1 in local else in_process  # a warm fit in a worker, nothing beside it
    ideal = 60 * cores / warm
    for row in rows:
        row["per_job_overhead_s"] = row["in_flight"] * 60 / row["steady_jobs_per_min"] - warm
        row["steady_vs_ideal"] = row["steady_jobs_per_min"] / (60 * min(row["in_flight"], cores) / warm)
        if row["backend"] == "dask" and row["in_flight"] in local:
            row["vs_local"] = row["steady_jobs_per_min"] / local[row["in_flight"]]["steady_jobs_per_min"]
            if row["cpu_per_job_s"] and local[row["in_flight"]]["cpu_per_job_s"]:
                row["cpu_vs_local"] = local[row["in_flight"]]["cpu_per_job_s"] / row["cpu_per_job_s"]
    best = {b: max((r for r in rows if r["backend"] == b), key=lambda r: r["steady_jobs_per_min"], default=None)
            for b in backends}
    dask_vs_local = (best["dask"]["steady_jobs_per_min"] / best["local"]["steady_jobs_per_min"]
                     if "dask" in best else None)
    core_seconds = (min(best["dask"]["in_flight"], cores) * 60 / best["dask"]["steady_jobs_per_min"]
                    if "dask" in best else None)
    projection = ({str(m): 60 * m * cores / core_seconds for m in (1, 2, 4, 8, 16, 32)} if core_seconds else {})
    client_cpu = best["dask"]["client_cpu_per_job_s"] if "dask" in best else None
    client_cap = 60 / client_cpu if client_cpu else None  # fits/min one client can receive and write

    print(f"batch of {jobs} fits ({size}x{size}, ka/kd/ks/n), {cores} cores, medians of {args.repeats} runs; "
          f"load average {load_before[0]:.1f} before, {load_after[0]:.1f} after")
    print(f"warm single fit {warm * 1e3:.1f} ms in a lone worker ({in_process * 1e3:.1f} ms in this process) "
          f"-> ideal {ideal:.0f} fits/min")
    print(f"{'backend':<8}{'in flight':>10}{'wall s':>9}{'fits/min':>10}{'steady/min':>12}{'vs ideal':>10}"
          f"{'overhead ms':>13}{'fit ms':>8}{'cpu ms/fit':>12}{'vs local':>10}{'cpu vs local':>14}")
    for r in sorted(rows, key=lambda r: (r["in_flight"], r["backend"])):
        print(f"{r['backend']:<8}{r['in_flight']:>10}{r['wall_s']:>9.2f}{r['jobs_per_min']:>10.0f}"
              f"{r['steady_jobs_per_min']:>12.0f}{r['steady_vs_ideal']:>10.2f}{r['per_job_overhead_s'] * 1e3:>13.1f}"
              f"{r['fit_in_worker_median_s'] * 1e3:>8.1f}{(r['cpu_per_job_s'] or float('nan')) * 1e3:>12.1f}"
              f"{r.get('vs_local', float('nan')):>10.2f}{r.get('cpu_vs_local', float('nan')):>14.2f}")
    if dask_vs_local is not None:
        print(f"dask / local (best steady against best steady): {dask_vs_local:.2f}")
    if projection:
        print("projection (not measured) for N machines of " + f"{cores} cores: "
              + ", ".join(f"N={m}: {rate:.0f}/min" for m, rate in projection.items()))
    if client_cap:
        print(f"but one client, which receives and writes every result, spent {client_cpu * 1e3:.1f} ms of CPU a fit "
              f"(the LocalCluster's scheduler in its process): at most ~{client_cap:.0f} fits/min whatever the cluster")
    import dask
    import jax
    import warp

    write_json_atomic(args.out, {
        "what": "fit_many throughput: local worker processes and a Dask LocalCluster vs one warm fit",
        "jobs": jobs, "size": size, "cores": cores, "repeats": args.repeats,
        "load_average_before_after": [load_before[0], load_after[0]],
        "warm_fit_s": warm, "warm_fit_in_process_s": in_process,
        "ideal_fits_per_min": ideal, "runs": rows, "dask_vs_local_best_steady": dask_vs_local,
        "projection_fits_per_min_by_machines": projection,
        "core_seconds_per_job": core_seconds,
        "projection_note": "N x cores / core-seconds per job of the best Dask run; not measured",
        "client_cpu_per_job_s": client_cpu, "client_cap_fits_per_min": client_cap,
        "versions": {"python": platform.python_version(), "jax": jax.__version__, "warp": warp.__version__,
                     "dask": dask.__version__}})
    print(f"wrote {args.out}")
    return 0

if __name__ == "__main__":
    sys.exit(main())

"""Where a batch's fits run: worker processes on this machine, or a Dask cluster.

Both are generators of (job, outcome) in the order the fits finish, outcomes as `worker.run_job`
returns them; the caller writes them (`store.Store.record`). Closing a generator early (Ctrl-C, an
error in the caller) stops its workers / cancels its tasks, so nothing runs on behind the caller.
"""

from __future__ import annotations

import os
import signal
import threading
import time

from .worker import pack, run_job


def _lost(error: str) -> dict:
    return {"ok": False, "error": error, "seconds": 0.0}


def _exit_with(parent: int) -> None:
    """Exit this process once `parent` is gone (a parent killed outright cannot stop its pool)."""
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(1)


def _init_worker(env: dict) -> None:
    """A pool process: its environment; Ctrl-C left to the parent, which stops the pool; and an exit
    when the parent dies."""
    os.environ.update(env)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_with, args=(os.getppid(),), daemon=True).start()


def local_jobs(jobs, workers: int):
    """Run `jobs` in `workers` spawned processes (a process pool). Each process keeps its compiled
    solves across the jobs it runs, and its Warp launches use cores / workers threads
    ($DIFFLAB_THREADS). A worker process that dies fails the jobs it had not finished (the pool breaks:
    the remaining jobs fail too, and a rerun retries them)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    threads = max(1, (os.cpu_count() or 1) // workers)
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=_init_worker,
                               initargs=({"DIFFLAB_THREADS": os.environ.get("DIFFLAB_THREADS", str(threads))},))
    futures = {pool.submit(run_job, job.spec): job for job in jobs}
    try:
        for future in as_completed(futures):
            try:
                outcome = future.result()
            except Exception as exc:  # the pool broke: a worker process died
                outcome = _lost(f"worker process lost: {type(exc).__name__}: {exc}")
            yield futures[future], outcome
    except BaseException:  # interrupted or closed early: stop the workers now, not after their jobs
        pool.shutdown(wait=False, cancel_futures=True)
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            process.terminate()  # Python 3.14 has pool.terminate_workers(); 3.11 only this
        raise
    pool.shutdown()


def cluster_jobs(jobs, client, inline: bool = False, retries: int = 2):
    """Run `jobs` as tasks on a Dask cluster through `client` (a `distributed.Client`).

    Workers read the inputs by path (a shared filesystem) or, with `inline`, receive the bytes of the
    scene file, targets and masks (files the scene refers to, meshes and textures, are still read by
    path). A task whose worker dies is rescheduled by Dask; `retries` re-runs a task that raised.
    Each job is one task with a deterministic key, so a result comes back once per job.
    """
    from dask.base import tokenize
    from distributed import as_completed

    futures = {}
    for job in jobs:
        files = pack(job.spec) if inline else None
        key = f"difflab-fit-{job.name}-{tokenize(job.spec, inline)}"
        futures[client.submit(run_job, job.spec, files, key=key, retries=retries, pure=False)] = job
    try:
        for future in as_completed(futures):
            try:
                outcome = future.result()
            except Exception as exc:  # lost beyond Dask's retries (KilledWorker, ...)
                outcome = _lost(f"cluster: {type(exc).__name__}: {exc}")
            yield futures[future], outcome
    except BaseException:
        client.cancel(list(futures))
        raise

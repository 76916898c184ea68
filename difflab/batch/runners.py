"""Where a batch's fits run: worker processes on this machine, or a Dask cluster.

Both are generators of (job, outcome) in the order the fits finish (a cluster task's fits together),
outcomes as `worker.run_job` returns them; the caller writes them (`store.Store.record`). Closing a
generator early (Ctrl-C, an error in the caller) stops its workers / cancels its tasks, so nothing
runs on behind the caller.
"""

from __future__ import annotations

import contextlib
import os
import signal
import statistics
import sys
import threading
import time

from ..errors import DifflabError
from ..limits import env_count
from .worker import pack, run_job, run_jobs

TASK_SECONDS = 0.5  # s of fitting a cluster task aims at: Dask's own cost per task (10-20 ms of CPU over
#                     client, scheduler and worker on 2 loaded cores, issue 13) then stays within a few %
TASKS_PER_THREAD = 2  # cluster tasks in flight per worker thread: one running, one ready behind it


UNGUARDED = 86  # the exit status of a pool worker whose import of the main script called fit_many


def leave_if_importing_main() -> None:
    """In a pool worker importing the parent's main script -- as a spawned process does before any job,
    running the script's top level --, exit with status UNGUARDED: a script that calls `fit_many`
    without `if __name__ == "__main__":` calls it again there, where no process can be started
    (multiprocessing raises while a process bootstraps); the parent then says what to do
    (`_refuse_unguarded`). Elsewhere, nothing. (`_inheriting` is multiprocessing's own mark of that
    phase, which its check of the same mistake reads.)"""
    import multiprocessing

    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise SystemExit(UNGUARDED)


def _refuse_unguarded(processes) -> None:
    """DifflabError naming the fix when a worker of `processes` left with status UNGUARDED."""
    deadline = time.monotonic() + 5.0  # a dead worker's status: the pool broke because one ended, but its exit
    codes = [p.exitcode for p in processes]  # status can lag the pool's noticing (join(1.0) returned None in 3 of 5)
    while UNGUARDED not in codes and None in codes and time.monotonic() < deadline:
        time.sleep(0.01)
        codes = [p.exitcode for p in processes]
    if UNGUARDED in codes:
        script = getattr(sys.modules["__main__"], "__file__", "the main script")
        raise DifflabError(f"fit_many: the worker processes start by importing {script}, and its top level calls "
                           "fit_many again; put the call under 'if __name__ == \"__main__\":' (docs/batch.md). "
                           "No fit was run") from None


def _lost(error: str) -> dict:
    return {"ok": False, "error": error, "seconds": 0.0}


def _exit_with(parent: int) -> None:
    """Exit this process once `parent` is gone (a parent killed outright cannot stop its pool)."""
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(1)


def _init_worker() -> None:
    """A pool process: an exit when the parent dies (Ctrl-C it ignores from its start: `_ctrl_c_held`)."""
    threading.Thread(target=_exit_with, args=(os.getppid(),), daemon=True).start()


@contextlib.contextmanager
def _ctrl_c_held():
    """Start worker processes here: they ignore Ctrl-C (SIGINT) from their first instruction -- the
    disposition SIG_IGN is inherited through fork and exec -- so that a Ctrl-C while they import
    (before any code of theirs runs) prints no traceback of theirs: the parent stops them. This
    thread's own Ctrl-C is held meanwhile (blocked: Linux keeps a blocked signal pending though
    ignored) and raised after the block; one landing in the microseconds between ignoring and
    blocking, or taken by another thread of the process that does not block it (threads started
    before this block; those started inside it inherit the block), is lost. Elsewhere
    than in the main thread, where signals are not handled, the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def render_threads(cores: int, tasks: int) -> int:
    """Threads for each fit's Warp render when `tasks` fits run at once on `cores` cores:
    $DIFFLAB_THREADS (of this process) if set, else cores // tasks (at least 1), so that the fits
    running side by side do not oversubscribe the cores. The rendered values do not depend on it."""
    return env_count("DIFFLAB_THREADS", max(1, cores // max(1, tasks)))


def _cores() -> int:
    return os.cpu_count() or 1


def cluster_render_threads(client) -> int:
    """`render_threads` for a Dask cluster: on each host, its cores over the task threads of all its
    workers; the smallest over the hosts (1 when no worker is up yet)."""
    cores = client.run(_cores)  # worker address -> its machine's cores
    hosts = {}
    for address, worker in client.scheduler_info()["workers"].items():
        if address in cores:
            held = hosts.setdefault(worker["host"], [cores[address], 0])
            held[1] += worker["nthreads"]
    return min((render_threads(n, tasks) for n, tasks in hosts.values()), default=render_threads(1, 1))


def local_jobs(jobs, workers: int):
    """Run `jobs` in `workers` spawned processes (a process pool): the (job, outcome) pairs as they
    finish. Each process keeps its compiled solves across the jobs it runs, and its Warp renders use
    `render_threads(cores, workers)` threads. A worker process that dies fails the jobs it had not
    finished (the pool breaks: the remaining jobs fail too, and a rerun retries them). Interrupted
    (Ctrl-C) or closed early at any point, even while the workers start, it kills them (`_kill`)
    before it lets the interruption on. The workers are started here, at the call, not at the first
    outcome asked for: before the caller's progress bar starts tqdm's monitor thread, which does not
    block SIGINT and so took a Ctrl-C landing while they started, and lost it (`_ctrl_c_held`):
    fit-batch then waited on endless jobs (3 runs in 40 of tests/test_batch_processes.py's
    Ctrl-C test at load ~2)."""
    outcomes = _local_outcomes(jobs, workers)
    next(outcomes)  # (its first yield: the workers started)
    return outcomes


def _local_outcomes(jobs, workers: int):
    """`local_jobs`' generator: yields once when the workers are started, then the outcomes."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    threads = render_threads(_cores(), workers)
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=_init_worker)
    try:
        with _ctrl_c_held():  # each submit starts a worker until there are `workers`
            futures = {pool.submit(run_job, job.spec, None, threads): job for job in jobs}
        processes = list(pool._processes.values())
        yield
        for future in _completed(futures):
            try:
                outcome = future.result()
            except Exception as exc:  # the pool broke: a worker process died
                _refuse_unguarded(processes)
                outcome = _lost(f"worker process lost: {type(exc).__name__}: {exc}")
            yield futures[future], outcome
    except BaseException:  # interrupted or closed early: stop the workers now, not after their jobs
        _kill(pool)
        raise
    pool.shutdown()


def _completed(futures, poll: float = 0.1):
    """The futures as they finish (`as_completed`), waiting at most `poll` seconds at a time: a
    Ctrl-C whose signal another thread of this process took (one that does not block SIGINT) only
    sets Python's flag, which the main thread reads between waits -- blocked in one endless wait it
    never would (fit-batch hung, Ctrl-C lost, ~1 run in 20 of a start-up interrupt at load 4)."""
    from concurrent.futures import FIRST_COMPLETED, wait

    pending = set(futures)
    while pending:
        done, pending = wait(pending, timeout=poll, return_when=FIRST_COMPLETED)
        yield from done


def _kill(pool) -> None:
    """Kill a process pool's workers (SIGKILL: a worker holds no output to clean up, the parent
    writes every file) and reap them, then shut the pool down, its jobs cancelled. (The pool's
    shutdown forgets its processes: terminating them after it, as this did, reached none, and
    Ctrl-C waited for the running jobs -- seconds while the workers imported JAX.) The shutdown
    waits for the pool's manager thread, which ends at once with its workers dead: left running,
    it closed its wake-up pipe while the interpreter's exit was writing to it ("Exception ignored
    ... Bad file descriptor" after "difflab: interrupted", 2 runs in 40 of
    tests/test_batch_processes.py's Ctrl-C test at load ~2)."""
    processes = list((pool._processes or {}).values())  # Python 3.14 has pool.kill_workers(); 3.11 only this
    for process in processes:
        process.kill()
    for process in processes:
        process.join()
    pool.shutdown(wait=True, cancel_futures=True)


def cluster_slots(client) -> int:
    """The task threads of all the cluster's workers (1 when no worker is up yet)."""
    return max(1, sum(worker["nthreads"] for worker in client.scheduler_info()["workers"].values()))


def task_size(seconds_per_job: float | None, remaining: int, slots: int) -> int:
    """Jobs in the next cluster task (guided self-scheduling): as many as fill TASK_SECONDS at the
    median seconds per job measured so far (1 while none is measured), and at most an equal share of
    the `remaining` jobs over the tasks in flight on `slots` threads, so that the last tasks shrink
    and the threads finish together."""
    if seconds_per_job is None:
        return 1
    share = -(-remaining // (slots * TASKS_PER_THREAD))
    return max(1, min(share, int(TASK_SECONDS / max(seconds_per_job, 1e-6))))


def cluster_jobs(jobs, client, inline: bool = False, retries: int = 2):
    """Run `jobs` as tasks on a Dask cluster through `client` (a `distributed.Client`).

    Workers read the inputs by path (a shared filesystem) or, with `inline`, receive the bytes of the
    scene file, targets and masks (files the scene refers to, meshes and textures, are still read by
    path). A task runs one or several jobs in turn (`worker.run_jobs`; `task_size`): a task costs Dask
    10-20 ms of CPU over client, scheduler and worker, as much as a small fit, so tasks are sized from
    the measured fit time to TASK_SECONDS, TASKS_PER_THREAD in flight per worker thread. A task whose
    worker dies is rescheduled by Dask; `retries` re-runs a task that raised. Each task has a
    deterministic key, so a job's result comes back once. Its Warp renders use
    `cluster_render_threads(client)` threads, as in the local pool: a Dask worker does not share the
    cores out by itself, and two workers on two cores each rendering on every core took 32-41 ms a
    fit against the local pool's 25 ms (issue 13).
    """
    from dask.base import tokenize
    from distributed import as_completed

    threads, slots = cluster_render_threads(client), cluster_slots(client)
    todo, seconds, futures = list(reversed(jobs)), [], {}
    running = as_completed()

    def submit():
        size = task_size(statistics.median(seconds) if seconds else None, len(todo), slots)
        chunk = [todo.pop() for _ in range(min(size, len(todo)))]
        specs = [job.spec for job in chunk]
        key = f"difflab-fits-{chunk[0].name}-{tokenize(specs, inline)}"
        files = [pack(spec) if inline else None for spec in specs]
        future = client.submit(run_jobs, specs, files, threads, key=key, retries=retries, pure=False)
        futures[future] = chunk
        running.add(future)

    try:
        for _ in range(min(len(todo), slots * TASKS_PER_THREAD)):
            submit()
        for future in running:
            chunk = futures.pop(future)
            try:
                outcomes = future.result()
                seconds.extend(outcome["seconds"] for outcome in outcomes)
            except Exception as exc:  # lost beyond Dask's retries (KilledWorker, ...)
                outcomes = [_lost(f"cluster: {type(exc).__name__}: {exc}")] * len(chunk)
            if todo:
                submit()
            yield from zip(chunk, outcomes)
    except BaseException:
        client.cancel(list(futures))
        raise

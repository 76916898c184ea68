"""The CPU thread pool and the band queue that banded launches run on (no Warp here): how many
threads (`cpu_threads`), the process's pools, and calling a function over bands of rows on the
calling thread and pool workers at once (`run_bands`, `run_phases`, `start_beside`).

Warp releases the GIL while a CPU launch runs, so bands launched from several threads use every
core; `launch` decides the bands and what each launches.
"""

from __future__ import annotations

import os
import queue
import threading

from ..limits import env_count

CORES = max(1, os.cpu_count() or 1)  # (asked once: ~4 us a call, several calls a frame)


def cpu_threads() -> int:
    """Worker threads for banded CPU launches: $DIFFLAB_THREADS, else the number of cores."""
    return env_count("DIFFLAB_THREADS", CORES)


class _Workers:
    """`count` threads that call what `submit` hands them, in turn: a ThreadPoolExecutor without the
    futures no caller reads (each call is a band queue's, which keeps its own errors). In a fit's
    cold frame its submit took ~40 us of the caller's before the z-buffer, and the worker, its
    bands done, settled the future while the caller, woken, waited for the GIL. Joined at exit, as
    the executor's threads are."""

    def __init__(self, count: int):
        self.calls = queue.SimpleQueue()
        self.threads = [threading.Thread(target=self._serve, name=f"difflab_{k}") for k in range(count)]
        for thread in self.threads:
            thread.start()

    def submit(self, fn, *args) -> None:
        self.calls.put((fn, args))

    def _serve(self) -> None:
        while (call := self.calls.get()) is not None:
            call[0](*call[1])  # (a band queue's `work`: it keeps its bands' errors for `join`)

    def stop(self) -> None:
        for unused in self.threads:
            self.calls.put(None)
        for thread in self.threads:
            thread.join()


_pools: dict[int, _Workers] = {}
_pools_lock = threading.Lock()
threading._register_atexit(lambda: [pool.stop() for pool in list(_pools.values())])  # (as concurrent.futures)


def _pool(workers: int) -> _Workers:
    """The process's pool of `workers` threads (made once, also when two threads first ask at once)."""
    with _pools_lock:
        if workers not in _pools:
            _pools[workers] = _Workers(workers)
        return _pools[workers]


class _BandQueue:
    """Bands handed out in order to whichever thread asks next; `join` takes bands on the calling
    thread until none is left, then returns once every band is done (or, after a band raised, once
    those started are), however many helpers never started."""

    beside = False  # whether `start` hands the queue to a pool worker (`start_beside`)

    def __init__(self, run_band, bands: list[tuple[int, int]]):
        self.run_band, self.todo = run_band, list(reversed(bands))  # popped from the end: first band first
        self.lock, self.finished = threading.Lock(), threading.Event()
        self.left, self.error = len(bands), None
        if not bands:
            self.finished.set()

    def work(self) -> None:
        while True:
            with self.lock:
                if not self.todo:
                    return
                band = self.todo.pop()
            try:
                self.run_band(*band)
            except BaseException as exc:  # noqa: BLE001 -- handed to the caller by `join`
                with self.lock:
                    self.error = self.error or exc
                self.drop()
            with self.lock:
                self.left -= 1
                if self.left == 0:
                    self.finished.set()

    def drop(self) -> None:
        """Leave the bands not started yet undone (they never will be)."""
        with self.lock:
            self.left -= len(self.todo)
            self.todo.clear()
            if self.left == 0:
                self.finished.set()

    def cancel(self) -> None:
        """Leave the bands not started undone and wait for those running, their errors dropped (for a
        caller that is passing on an error of its own); after `join`, nothing."""
        self.drop()
        self.finished.wait()
        self.run_band = None

    def start(self) -> None:
        """Hand the queue to a pool worker, once, where `start_beside` found a thread to spare."""
        if self.beside:
            self.beside = False
            _pool(1).submit(self.work)

    def join(self) -> None:
        try:
            self.work()
            self.finished.wait()
        except BaseException:  # interrupted waiting (Ctrl-C): no band starts now; those running end first
            self.drop()
            self.finished.wait()
            raise
        finally:
            self.run_band = None  # a pool worker may hold this queue a moment longer: not what the bands
            #                       captured (a frame's buffers, which the next frame reuses once unheld)
        if self.error is not None:
            raise self.error


_NOTHING = _BandQueue(None, [])  # `start_beside`'s handle of no task: done, shared (its calls change nothing)


def run_bands(run_band, bands: list[tuple[int, int]], threads: int | None = None) -> None:
    """Call `run_band(begin, end)` for every band, in order, on the calling thread and up to
    `threads` - 1 pool workers (kept between calls), each taking the next band when free: the caller
    never idles, and a worker the machine does not schedule in time leaves its share to the others
    instead of holding the frame up."""
    threads = cpu_threads() if threads is None else max(1, threads)
    if len(bands) <= 1 or threads == 1:  # (none: nothing to wait for)
        for begin, end in bands:
            run_band(begin, end)
        return
    queue, pool = _BandQueue(run_band, bands), _pool(threads - 1)  # (one pool per thread count, not per band count)
    for _ in range(min(threads, len(bands)) - 1):
        pool.submit(queue.work)
    queue.join()


def run_phases(phases: list[tuple], threads: int | None = None) -> None:
    """`run_bands(run_band, bands)` for each (run_band, bands) of `phases` in turn, on the calling
    thread and up to `threads` - 1 pool workers that go on from one phase to the next: each thread
    takes the next phase's bands once every band of this one is done, with no hand-off through the
    pool in between (a sleeping worker's wake-up: ~0.1 ms on the 2-core machine). A band that
    raises stops the later phases; the error is raised here.

    The workers are handed their part only once the caller's work before the first phase is done
    (the z-buffer's assembly): a worker handed a task while the caller runs Python gets the GIL only
    when the caller lets it go, which a frame's preparation does nowhere before the clip's launch
    (stages 1-2 handed over at the frame's start ran on the caller anyway); woken right before the
    assembly to wait for it, the worker took the GIL from the assembly's end (render +0.1 ms; the
    256^2 bench sphere's first fits, paired medians of 150-200)."""
    threads = cpu_threads() if threads is None else max(1, threads)
    queues = [_BandQueue(run_band, bands) for run_band, bands in phases]
    for _ in range(min(threads, max(len(bands) for unused, bands in phases)) - 1):
        _pool(threads - 1).submit(_follow_phases, queues)
    try:
        for queue in queues:
            queue.join()
    except BaseException:
        for queue in queues:
            queue.drop()
        raise


def _follow_phases(queues: list[_BandQueue]) -> None:
    """A pool worker's part of `run_phases`: the bands it can take of each phase in turn. It leaves
    once the last phase has no band left to take, without waiting for the others' bands: woken at
    their end, it took the GIL from the caller's code that follows (~10-15 us a frame)."""
    for queue in queues[:-1]:
        queue.work()
        queue.finished.wait()
        if queue.error is not None:
            return
    queues[-1].work()


def start_beside(task, device: str, threads: int | None = None, start: bool = True) -> _BandQueue:
    """Start `task()` on a pool worker, beside what the caller does next, when the CPU has a thread
    to spare (`threads`); `join()` the returned handle to have it done -- on the caller, if no worker
    has taken it yet (and on CUDA, or with one thread, it runs there); `cancel()` it to leave it
    undone. A `task` of None: nothing to do, no worker woken. `start` False: the handle's `start()`
    hands it to the worker later, when the caller is about to let go of the GIL for long (a kernel
    launch): the worker, woken, takes the GIL to start, and a caller that wants it back first waits
    (a G-buffer's clearing started at the frame's start held the 256^2 bench sphere's frame ~90 us
    in its next short call that lets the GIL go: a 50 us launch took 141 us of wall)."""
    if task is None:  # (a fit frame's G-buffer clearing: ~15 us of its cold frame to make a queue)
        return _NOTHING
    queue = _BandQueue(lambda begin, end: task(), [(0, 0)])
    queue.beside = device.startswith("cpu") and (cpu_threads() if threads is None else threads) > 1
    if start:
        queue.start()
    return queue

"""Warp start-up, device choice and the banded launches: how a launch is split into row bands
(`band_plan`, `launch_rows`, `launch_row_loops`, `launch_chunks`, `launch_parts`) and the recorded
launches a thread replays between frames (`launch_kept`).

Warp runs one CPU launch serially on one thread but releases the GIL while it runs, so a launch
split into bands of rows, launched from a thread pool (`bandpool`), uses every core. On CUDA a
launch is already parallel and is issued whole, with a thread per item: the row loops
(`launch_row_loops`), which on the CPU take a row per thread, take a sample per thread there
(`row_span`), as `launch_chunks` takes an item.
"""

from __future__ import annotations

import os
import sys
import tempfile
import threading

from .._warp import wp

from ..errors import RenderError
from .bandpool import cpu_threads, run_bands

CUDA_DRIVER_MISSING = "Could not find or load the NVIDIA CUDA driver"  # Warp's start-up line on CPU-only machines
COMPILE_NOTICE_SECONDS = 2.0  # a module load longer than this is Warp compiling, not reading its cache

_initialised = False
_loaded: set = set()
_noticed = False


def init() -> None:
    """Initialise Warp once. Its native start-up writes to the process's stderr; the line saying that
    no CUDA driver exists is dropped (noise on a CPU-only machine: asking for device="cuda" there
    raises a RenderError that says so), anything else is passed on."""
    global _initialised
    if _initialised:
        return
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as capture:
        os.dup2(capture.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        capture.seek(0)
        lines = capture.read().decode(errors="replace").splitlines(keepends=True)
    sys.stderr.write("".join(line for line in lines if CUDA_DRIVER_MISSING not in line))
    _initialised = True


def load_kernels(device: str, *kernels) -> None:
    """Load the Warp modules of `kernels` on `device` before their first launch in this process, on
    the calling thread: the band launchers below call it before handing bands to the pool, since
    two threads making a module's first launch at once load it twice, and a launch through the
    loser's unloaded code crashed the process (a segfault in ~1 of 60 fresh processes ray tracing
    with the item buffer, whose z-buffer was the first raster launch). Loading is compiling the
    first time (tens of seconds, then cached): when it takes longer than COMPILE_NOTICE_SECONDS a
    one-line notice goes to stderr, once per process."""
    modules = {kernel.module.name: kernel.module for kernel in kernels if (kernel.module.name, device) not in _loaded}
    if not modules:
        return
    timer = threading.Timer(COMPILE_NOTICE_SECONDS, compile_notice)
    timer.daemon = True
    timer.start()
    try:
        for name, module in modules.items():
            wp.load_module(module, device=device)
            _loaded.add((name, device))
    finally:
        timer.cancel()


def compile_notice() -> None:
    global _noticed
    if not _noticed:
        _noticed = True
        sys.stderr.write("difflab: compiling Warp kernels (first run only; they are cached for later runs)...\n")
        sys.stderr.flush()


def resolve_device(device: str = "cpu") -> str:
    """Check that `device` ("cpu", "cuda" or "cuda:N") exists and return Warp's name for it."""
    if device == "cpu" and _initialised:  # (asked 3 times a fit frame: Warp's lookup ~14 us of the first, cold)
        return device
    init()
    if not isinstance(device, str) or not (device == "cpu" or device.startswith("cuda")):
        raise RenderError(f"device: expected 'cpu' or 'cuda[:N]', got {device!r}")
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise RenderError(f"device: {device!r} requested but no CUDA device is available")
    try:
        return str(wp.get_device(device))
    except (ValueError, RuntimeError) as exc:
        raise RenderError(f"device: {device!r} is not available ({exc})") from None


# A rasterized frame of fewer samples than this runs on one thread: its bands' launches and the
# pool's hand-offs cost more than they save (2-core machine, medians of 7, one thread vs the pool:
# load 4: 64^2 2.5 vs 4.4 ms, 128^2 3.6 vs 10.9, 256^2 7.7 vs 14.3, 512^2 44.5 vs 45.2; load 1:
# 256^2 ~8 vs 11.4, 512^2 24.3 vs 19.9 -- the pool's win starts between the two).
RASTER_POOL_MIN_SAMPLES = 256 * 256 + 1
BANDS_PER_THREAD = 4


def raster_threads(threads: int | None, n_samples: int) -> int | None:
    """The CPU threads of a rasterized frame of `n_samples` samples: `threads` when given or
    $DIFFLAB_THREADS is set, else one below RASTER_POOL_MIN_SAMPLES, else None (all cores)."""
    if threads is not None or os.environ.get("DIFFLAB_THREADS", "").strip():
        return threads
    return 1 if n_samples < RASTER_POOL_MIN_SAMPLES else None


# The per-sample passes of a rasterized G-buffer (stages 4-7, `raster.driver.rasterize`) are one
# launch per band of rows with nothing to bin: from this many samples on they use every core, one
# band per thread, even where the z-buffer stays on one thread (below RASTER_POOL_MIN_SAMPLES). A
# band costs a launch (~16 us); the 256^2 bench sphere's Phong pass is ~2.3 ms of work (2-core
# machine at load 2-2.7, medians of 40, one thread vs two bands: 4.37 vs 4.52 ms a frame, minima
# 4.25 vs 3.89 ms -- even with the second core taken, and the saving of a free one).
PASS_POOL_MIN_SAMPLES = 128 * 128


def pass_threads(threads: int | None, n_samples: int) -> tuple[int | None, int]:
    """(threads, bands per thread) of a per-sample pass of a rasterized frame of `n_samples`
    samples: those of `raster_threads` with BANDS_PER_THREAD bands each, but all cores with one band each for a
    frame left to the default that `raster_threads` puts on one thread, from PASS_POOL_MIN_SAMPLES on."""
    chosen = raster_threads(threads, n_samples)
    if threads is None and chosen == 1 and n_samples >= PASS_POOL_MIN_SAMPLES:
        return None, 1
    return chosen, BANDS_PER_THREAD


def halved_zbuffer(chosen: int | None, row_pass: tuple, device: str) -> bool:
    """Whether a rasterized frame's z-buffer is drawn as two halves on two threads (`raster.driver.
    zbuffer`): where `raster_threads` leaves it on one thread (`chosen`: its choice; no binning into
    bands below RASTER_POOL_MIN_SAMPLES) while `pass_threads` (`row_pass`) gives the per-sample passes
    every core. (The two choices taken, not asked again: ~5 us of a fit's cold frame.)"""
    return device == "cpu" and chosen == 1 and row_pass[0] is None and cpu_threads() > 1


def row_bands(n_rows: int, n_bands: int) -> list[tuple[int, int]]:
    """Split rows [0, n_rows) into at most `n_bands` contiguous (begin, end) bands of near-equal size."""
    n_bands = max(1, min(n_bands, n_rows))
    edges = [round(k * n_rows / n_bands) for k in range(n_bands + 1)]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def band_plan(n_rows: int, device: str, threads: int | None = None,
              per_thread: int = BANDS_PER_THREAD) -> list[tuple[int, int]]:
    """The row bands a launch over n_rows is split into: one on CUDA or with one thread, else
    `per_thread` per thread (more bands than threads balances uneven rows)."""
    threads = cpu_threads() if threads is None else max(1, threads)
    if not device.startswith("cpu") or threads == 1 or n_rows < 2:
        return [(0, n_rows)]
    return row_bands(n_rows, per_thread * threads)


# Work of one band of `launch_rows` given its `row_work`: 2^25 inner-loop iterations, ~0.1 s of one
# core for the escape-time kernel (3e8 iterations/s where no point escapes) and for the Mandelbulb's
# (its rows' primary march bound, 640 x 10 x 256 a row at the defaults: 20 rows, 4.6 ms each; 2-core machine).
BAND_WORK = 2**25


def launch_rows(kernel, shape: tuple[int, int], inputs: list, device: str, threads: int | None = None, *,
                row_work: int | None = None, progress=None) -> None:
    """Launch a per-pixel `kernel` over `shape` = (rows, cols), in row bands.

    The kernel's first argument is `row0: int`; it runs with dim (band rows, cols) and reads its
    pixel as (row0 + i, j). It must write only its own pixels: bands never write the same element,
    so the result is bitwise identical to one launch, however the rows are banded.

    Arguments:
        row_work: at most how many inner-loop iterations the kernel runs over one row (the escape
            time's cols x (max_iter + 1)): on the CPU a band then holds at most BAND_WORK of them
            (one row at least; bands also on one thread), so that a long launch reports `progress`
            often and a Ctrl-C is taken within a band or two (Python runs its handler between the
            bands the calling thread launches). Default, and where that is coarser: `band_plan`.
        progress: None, or called as progress(rows_done, rows) as bands finish (rows_done
            increasing, the last call rows), on the thread that ran the band; on CUDA once, after
            the launch has completed.
    """
    rows, cols = shape
    done, lock = 0, threading.Lock()

    def run_band(begin: int, end: int) -> None:
        nonlocal done
        wp.launch(kernel, dim=(end - begin, cols), inputs=[begin, *inputs], device=device)
        if progress is not None:
            if not device.startswith("cpu"):
                wp.synchronize_device(device)
            with lock:  # (counts reported in order whichever thread finishes first)
                done += end - begin
                progress(done, rows)

    bands = band_plan(rows, device, threads)
    if row_work is not None and device.startswith("cpu"):
        most = max(1, BAND_WORK // max(1, row_work))  # rows a band may hold
        bands = row_bands(rows, max(len(bands), -(-rows // most)))  # (the plan itself where its bands are no larger)
    load_kernels(device, kernel)
    run_bands(run_band, bands, threads)


# Rows a band of `launch_row_loops` takes at a time: the 256^2 bench sphere's Phong G-buffer pass
# over two bands costs 2.44 ms of CPU in blocks of 8 rows, 2.6-2.8 ms dealt row by row (2-core
# machine, thread CPU time, medians of 200).
ROW_BLOCK = 8

# Whether a row-loop launch (`launch_row_loops`, `launch_dealt`) runs a thread per sample: None,
# by the device (CUDA yes, the CPU no); True / False force it (the tests run CUDA's mapping on the CPU).
PER_SAMPLE: bool | None = None


def row_span(cols: int, device: str) -> int:
    """The columns one thread of a row-loop launch over rows of `cols` samples covers: the whole row
    on the CPU (Warp runs a CPU launch serially: a thread per row reads the kernel's struct
    arguments once per row), one sample on CUDA (a thread per row gave a 512^2 frame 512 GPU
    threads: on an H200 the Whitted tracer's 512^2 sphere and floor took 15.2 ms beside its 16-core
    CPU's 10.2, the teapot demo 61.8 beside 10.4; a thread per sample: 2.8 and 3.1 ms, the
    rasterizer's 5.3 -> 2.7 and 11.9 -> 1.6 ms, medians of 5 frames after a warm-up)."""
    per_sample = not device.startswith("cpu") if PER_SAMPLE is None else PER_SAMPLE
    return 1 if per_sample else max(cols, 1)


def row_spans(cols: int, device: str) -> int:
    """How many threads share a row of `cols` samples (`row_span`): the entries per row of a per-thread
    count (a row-loop kernel's non-finite samples: `dealt_span`'s slot)."""
    return -(-cols // row_span(cols, device))


@wp.func
def dealt_row(row0: int, row_step: int, r: int):
    """The r-th row of a `launch_row_loops` band: blocks of ROW_BLOCK rows, the first from row0,
    then one every row_step rows."""
    return row0 + (r // ROW_BLOCK) * row_step + r % ROW_BLOCK


@wp.func
def dealt_span(row0: int, row_step: int, span: int, cols: int, tid: int):
    """What thread `tid` of a `launch_row_loops` band covers: (i, j0, j1, slot), row i's columns
    [j0, j1) -- `span` of them (`row_span`: the whole row, or one sample) -- and its slot in
    per-thread arrays of `row_spans` entries per row (i itself where a thread takes a whole row)."""
    spans = (cols + span - 1) // span
    r = tid // spans
    c = tid - r * spans
    i = dealt_row(row0, row_step, r)
    return i, c * span, wp.min(c * span + span, cols), i * spans + c


def dealt_bands(rows: int, device: str, threads: int | None = None,
                per_thread: int = BANDS_PER_THREAD) -> list[tuple[int, int]]:
    """The bands (k, n) `launch_row_loops` deals rows [0, rows) to: `per_thread` per CPU thread, as
    `band_plan` (one on CUDA), none without a block of rows."""
    n_bands = min(len(band_plan(rows, device, threads, per_thread)), -(-rows // ROW_BLOCK))
    return [(k, n_bands) for k in range(n_bands)]


def launch_dealt(kernel, k: int, n: int, shape: tuple[int, int], inputs: list, device: str,
                 kept: dict | None = None) -> None:
    """Launch `kernel` on band k of n of the rows of `shape` = (rows, cols) dealt in blocks
    (`launch_row_loops`); `kept`: see `launch_kept`."""
    rows, cols = shape
    span = row_span(cols, device)
    band_rows = sum(min(ROW_BLOCK, rows - block) for block in range(k * ROW_BLOCK, rows, n * ROW_BLOCK))
    launch_kept(kept, kernel, (n, rows), band_rows * row_spans(cols, device),
                [k * ROW_BLOCK, n * ROW_BLOCK, span, *inputs], device)


def launch_row_loops(kernel, shape: tuple[int, int], inputs: list, device: str, threads: int | None = None,
                     per_thread: int = BANDS_PER_THREAD) -> None:
    """Launch `kernel` over `shape` = (rows, cols), the rows dealt to bands in blocks of ROW_BLOCK
    (`dealt_bands`): band k of n takes blocks k, k + n, k + 2n, ..., so each band holds a share of
    every part of the frame and the bands' work is even where the frame's content is not (the 256^2
    bench sphere's top half holds 3x the covered samples of its bottom half: as two contiguous
    bands, 1.75 ms of CPU on one core beside 0.66 ms on the other; dealt, 1.25 and 1.19).

    The kernel's first arguments are (row0, row_step, span); its thread wp.tid() covers
    `dealt_span(row0, row_step, span, cols, tid)`: a row's columns [j0, j1), looping over them
    itself. `span` is `row_span`: on the CPU a whole row per thread (the kernel's struct arguments
    are read once per row), on CUDA one sample per thread. Each thread writes only its own samples
    (and its own slot of a per-thread count), so the results are bitwise the same under either
    mapping; a kernel keeping row state (a scan ahead of the per-sample loop) keeps it for its
    columns [j0, j1) only."""
    rows, cols = shape
    load_kernels(device, kernel)
    run_bands(lambda k, n: launch_dealt(kernel, k, n, shape, inputs, device),
              dealt_bands(rows, device, threads, per_thread), threads)


def launch_band(kernel, begin: int, end: int, cols: int, inputs: list, device: str) -> None:
    """Launch row-loop `kernel` (`launch_row_loops`) on the contiguous rows [begin, end) of rows of
    `cols` samples (a band of the z-buffer's `band_plan`): they are the dealt rows of a band whose
    row0 is `begin` and row_step ROW_BLOCK."""
    wp.launch(kernel, dim=(end - begin) * row_spans(cols, device),
              inputs=[begin, ROW_BLOCK, row_span(cols, device), *inputs], device=device)


def launch_kept(kept: dict | None, kernel, plan, dim: int, inputs: list, device: str) -> None:
    """`wp.launch`, or, given `kept` (a thread's dict kept between its frames), the launch recorded
    there for `kernel` and inputs[0] (its band) under the band plan `plan` (`kept_records`), replayed
    while the dim and inputs are the same (objects by identity, ints by value): Warp packs every
    argument anew at each launch (~15-35 us one of the z-buffer's). A recorded launch holds its
    inputs: only arrays kept anyway (scratch) or structs of a frame's outputs
    (`CompiledScene.reusable_structs`), never such arrays themselves, which `CompiledScene.reusable`
    must find unheld to reuse. The pool workers that run the owning thread's bands call this on its
    dict at once: each reads and sets only its own band's record (one dict operation each, atomic
    under the GIL), and the bands of one launch share its plan."""
    if kept is None:
        wp.launch(kernel, dim=dim, inputs=inputs, device=device)
        return
    records, band = kept_records(kept, kernel, plan), inputs[0]
    last = records.get(band)
    if last is None or last[0] != dim or len(last[1]) != len(inputs) or not all(
            a is b or (type(a) is int and type(b) is int and a == b) for a, b in zip(last[1], inputs)):
        last = records[band] = (dim, list(inputs), wp.launch(kernel, dim=dim, inputs=inputs, device=device,
                                                             record_cmd=True))
    last[2].launch()


_plans_lock = threading.Lock()


def kept_records(kept: dict, kernel, plan) -> dict:
    """`kernel`'s recorded launches in `kept` by band under band plan `plan` (equal for equal band
    lists): one entry per kernel, replaced whole when the plan changes, so a smaller frame frees a
    larger one's records and what they held. Replaced under a lock: two bands finding the old plan
    at once make one new dict, not two."""
    entry = kept.get(("launch", kernel))
    if entry is None or entry[0] != plan:
        with _plans_lock:
            entry = kept.get(("launch", kernel))
            if entry is None or entry[0] != plan:
                entry = kept[("launch", kernel)] = (plan, {})
    return entry[1]


def launch_chunks(kernel, n: int, inputs: list, device: str, threads: int | None = None,
                  kept: dict | None = None) -> None:
    """Launch `kernel` over items [0, n) in bands: its first arguments are (begin, end, chunk) and
    thread tid handles items begin + tid * chunk ... up to `chunk` of them (below end). On the CPU a
    band is one chunk (one thread reads the arguments once); on CUDA a chunk is one item. `kept`:
    see `launch_kept`."""
    bands = band_plan(n, device, threads)

    def run_band(begin: int, end: int) -> None:
        chunk = end - begin if device == "cpu" else 1
        launch_kept(kept, kernel, bands, (end - begin + chunk - 1) // chunk, [begin, end, chunk, *inputs], device)

    if n:
        load_kernels(device, kernel)
        run_bands(run_band, bands, threads)


def launch_parts(kernel, n: int, inputs: list, device: str, threads: int | None = None,
                 kept: dict | None = None) -> None:
    """`launch_chunks` with the band's index first: the kernel's first arguments are (part, begin,
    end, chunk), part p of `part_count(n, ...)` covering items [begin, end). A kernel may keep
    per-part results (counts, sums) there without two CPU threads sharing an element."""
    bands = band_plan(n, device, threads)
    part = {band: k for k, band in enumerate(bands)}

    def run_band(begin: int, end: int) -> None:
        chunk = end - begin if device == "cpu" else 1
        launch_kept(kept, kernel, bands, (end - begin + chunk - 1) // chunk,
                    [part[(begin, end)], begin, end, chunk, *inputs], device)

    if n:
        load_kernels(device, kernel)
        run_bands(run_band, bands, threads)


def part_count(n: int, device: str, threads: int | None = None) -> int:
    """How many parts `launch_parts` splits n items into."""
    return len(band_plan(n, device, threads))

"""Warp start-up, device choice and the banded CPU launch.

Warp runs one CPU launch serially on one thread but releases the GIL while it runs, so a launch
split into bands of rows, launched from a thread pool, uses every core. On CUDA a launch is
already parallel and is issued whole.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

from .._warp import wp

from ..errors import RenderError
from ..limits import env_count

_initialised = False


def init() -> None:
    """Initialise Warp once (quietly)."""
    global _initialised
    if not _initialised:
        wp.init()
        _initialised = True


def resolve_device(device: str = "cpu") -> str:
    """Check that `device` ("cpu", "cuda" or "cuda:N") exists and return Warp's name for it."""
    init()
    if not isinstance(device, str) or not (device == "cpu" or device.startswith("cuda")):
        raise RenderError(f"device: expected 'cpu' or 'cuda[:N]', got {device!r}")
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise RenderError(f"device: {device!r} requested but no CUDA device is available")
    try:
        return str(wp.get_device(device))
    except (ValueError, RuntimeError) as exc:
        raise RenderError(f"device: {device!r} is not available ({exc})") from None


def cpu_threads() -> int:
    """Worker threads for banded CPU launches: $DIFFLAB_THREADS, else the number of cores."""
    return env_count("DIFFLAB_THREADS", max(1, os.cpu_count() or 1))


def row_bands(n_rows: int, n_bands: int) -> list[tuple[int, int]]:
    """Split rows [0, n_rows) into at most `n_bands` contiguous (begin, end) bands of near-equal size."""
    n_bands = max(1, min(n_bands, n_rows))
    edges = [round(k * n_rows / n_bands) for k in range(n_bands + 1)]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def parallel_bands(run_band, n_rows: int, device: str, threads: int | None = None) -> None:
    """Call `run_band(begin, end)` over row bands: all cores on the CPU, a single band on CUDA.

    `run_band` must launch Warp kernels that touch only rows [begin, end) of their outputs, so that
    bands never write the same element and the result is bitwise identical to one launch.
    """
    threads = cpu_threads() if threads is None else max(1, threads)
    if not device.startswith("cpu") or threads == 1 or n_rows < 2:
        run_band(0, n_rows)
        return
    bands = row_bands(n_rows, 4 * threads)  # more bands than threads balances uneven rows
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for future in [pool.submit(run_band, a, b) for a, b in bands]:
            future.result()


def launch_rows(kernel, shape: tuple[int, int], inputs: list, device: str, threads: int | None = None) -> None:
    """Launch a per-pixel `kernel` over `shape` = (rows, cols), in row bands.

    The kernel's first argument is `row0: int`; it runs with dim (band rows, cols) and reads its
    pixel as (row0 + i, j).
    """
    rows, cols = shape

    def run_band(begin: int, end: int) -> None:
        wp.launch(kernel, dim=(end - begin, cols), inputs=[begin, *inputs], device=device)

    parallel_bands(run_band, rows, device, threads)

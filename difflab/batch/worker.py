"""One fit of a batch, as a worker process runs it (a local pool process or a Dask worker).

A worker only computes: it returns the fitted scene and the report as plain data, and the process
that owns the output folder writes them (`store.py`), so a worker that dies or is interrupted leaves
nothing behind. The compiled solves stay in the worker process (jobs of the same problem shape reuse
them), and JAX's persistent compilation cache on disk ($DIFFLAB_CACHE_DIR, `difflab.fit.cache`)
lets a new worker skip most compilation.
"""

from __future__ import annotations

import ctypes
import functools
import os
import tempfile
import time
from pathlib import Path

from ..errors import DifflabError, FitError

VOLATILE = ("seconds", "timings")  # report fields that change from run to run (kept apart from the report)
M_TRIM_THRESHOLD = -1  # glibc's mallopt parameter numbers
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20  # bytes: glibc's own ceiling for its adaptive mmap threshold (64-bit)


def fit_job(spec: dict, threads: int | None = None):
    """Run the fit a manifest line describes (`manifest.parse_line`'s spec) through the fitting
    engine, `difflab.fit.fit`, and return its FitResult. Its compiled solves stay in this process for
    the next job of the same problem shape, and its JAX compilation cache on disk serves every
    worker (`difflab.fit.cache`). `threads`: the Warp render's CPU threads (default $DIFFLAB_THREADS,
    else every core); the results do not depend on it."""
    from ..fit import fit
    from ..fit.edges import margin_masks

    targets = [(view["image"], {k: view[k] for k in ("camera", "lights") if k in view}) for view in spec["targets"]]
    masks = [view.get("mask") for view in spec["targets"]]
    masks = None if all(m is None for m in masks) else masks
    if spec.get("edge_margin"):  # the views' interior masks, inside their own (`fit.edges`)
        masks = margin_masks(spec["scene"], targets, masks, spec["edge_margin"], device=spec["solver"].get("device"),
                             method=spec.get("method"), spp=spec["solver"].get("spp"), materials=spec.get("material"),
                             params=spec.get("params"))
    options = {**spec["solver"], "init": spec["init"] or None, "history": False, "progress": False, "threads": threads,
               "masks": masks}
    if "params" in spec:
        options["params"] = tuple(spec["params"])
    return fit(spec["scene"], targets, spec.get("material"), method=spec.get("method"), **options)


def input_files(spec: dict) -> list[str]:
    """The files a job reads: its scene file, then each view's image and mask."""
    return [spec["scene"]] + [view[k] for view in spec["targets"] for k in ("image", "mask") if k in view]


def pack(spec: dict) -> dict:
    """The bytes of a job's input files, path -> bytes, to send to workers that cannot read them.
    A file that cannot be read is left out (the job then fails on the worker, naming it)."""
    files = {}
    for path in input_files(spec):
        try:
            files[path] = Path(path).read_bytes()
        except OSError:
            pass
    return files


def _unpacked(spec: dict, files: dict, folder: Path) -> dict:
    """`spec` with every packed input written into `folder` and its path pointing there."""
    local = {}
    for i, (path, data) in enumerate(files.items()):
        local[path] = folder / f"{i}-{Path(path).name}"  # keep the name: its suffix says how to decode
        local[path].write_bytes(data)

    def moved(path):
        return str(local.get(path, path))

    views = [{k: (moved(v) if k in ("image", "mask") else v) for k, v in view.items()} for view in spec["targets"]]
    return {**spec, "scene": moved(spec["scene"]), "targets": views}


def outcome_of(spec: dict, threads: int | None = None) -> dict:
    """Fit one job: {"ok": True, "scene": fitted scene dict, "textures": file name -> texels of each
    fitted texture (the scene names them: `FitResult.scene_dict` and `.texture_files`, the job's name
    as the stem), "report": FitResult.to_dict() without the VOLATILE fields} or {"ok": False,
    "error": message}. Never raises for a failed job: a bad input
    (DifflabError) gives its message, anything else "internal error: Type: message"."""
    try:
        result = fit_job(spec, threads)
        if result.no_fit() is not None:  # a failed job
            raise FitError(f"no fit made: {result.no_fit()}")
        report = result.to_dict(spec["name"], "scenes")  # a texture's file, in the batch folder
        for key in VOLATILE:
            report.pop(key, None)
        return {"ok": True, "scene": result.scene_dict(spec["name"]), "textures": result.texture_files(spec["name"]),
                "report": report}
    except DifflabError as exc:
        return {"ok": False, "error": str(exc)}
    except Exception as exc:  # one job's internal error must not stop the batch: record it
        return {"ok": False, "error": f"internal error: {type(exc).__name__}: {exc}"}


@functools.cache
def adaptive_allocator() -> bool:
    """Undo the fixed allocator thresholds of a process started with $MALLOC_TRIM_THRESHOLD_ set
    (Dask's nanny sets it to 64 KiB in every worker): glibc then stops adapting its thresholds, so
    each array over 128 KiB a fit makes is mapped and unmapped afresh, and each free leaving over
    64 KiB at the top of the heap hands it back to the system, to be faulted in again by the next
    array: ~400 page faults a fit against 6 in a plain process (24x24 fits of experiments/bench/
    batch.py; ~35 -> ~25 ms a fit, issue 13). Sets the mmap threshold to MMAP_THRESHOLD and the trim
    threshold to twice that (glibc's own adaptive ceilings), once per process; True when set.
    Results do not depend on it."""
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ or "MALLOC_MMAP_THRESHOLD_" in os.environ:
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # glibc only
    except (OSError, AttributeError):
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, 2 * MMAP_THRESHOLD))


def run_job(spec: dict, files: dict | None = None, threads: int | None = None) -> dict:
    """A worker's task: `outcome_of(spec, threads)` plus its wall time in "seconds". With `files` (from
    `pack`) the inputs are read from those bytes, written to a temporary folder, instead of from the paths."""
    adaptive_allocator()
    start = time.perf_counter()
    if files:
        with tempfile.TemporaryDirectory(prefix="difflab-job-") as folder:
            outcome = outcome_of(_unpacked(spec, files, Path(folder)), threads)
    else:
        outcome = outcome_of(spec, threads)
    return {**outcome, "seconds": time.perf_counter() - start}


def run_jobs(specs: list, files: list, threads: int | None = None) -> list:
    """A cluster task: `run_job` for each spec in turn, with its packed files (or None), in a list."""
    return [run_job(spec, packed, threads) for spec, packed in zip(specs, files)]

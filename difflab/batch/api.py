"""`fit_many`: every fit of a manifest, on this machine's cores or a Dask cluster, resumable."""

from __future__ import annotations

import dataclasses
import os
import sys
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

from ..errors import DifflabError
from ..fit.result import NOT_JUDGED
from .manifest import load_manifest
from .store import Store


@dataclass(frozen=True)
class BatchSummary:
    """What `fit_many` did. rows: one per manifest line, as in OUTDIR/summary.json (line, name,
    status, result, loss, psnr, steps, params, error); counts: status -> rows; ran: fits run by this
    call; skipped: fits found finished from an earlier run (resume)."""

    outdir: Path
    rows: list
    counts: dict
    ran: int
    skipped: int

    @property
    def all_converged(self) -> bool:
        """Every line gave a converged fit (model mismatches aside: see `mismatched`)."""
        return all(row["status"] == "converged" for row in self.rows)

    @property
    def mismatched(self) -> list:
        """Names of the fits flagged model_mismatch: their image model does not explain the targets."""
        return [row["name"] for row in self.rows if row["model_mismatch"]]

    @property
    def unjudged(self) -> list:
        """Names of the fits left unsettled (`FitResult.not_judged`: a flag of its NOT_JUDGED set
        in their row): their noise could not be estimated, a mismatch is suspected against an
        estimated noise, or they are underdetermined."""
        return [row["name"] for row in self.rows if any(row.get(flag) for flag in NOT_JUDGED)]


    def report(self) -> list[str]:
        """The lines `fit_many` ends with (on stderr): the counts, then a line per kind of fit that is
        not clean -- failed, invalid, not converged, not run, model mismatch, not judged -- naming
        the first SHOWN ("line N" for an invalid line without a usable name) and counting the rest."""
        line = (f"{len(self.rows)} line{'s' * (len(self.rows) != 1)}: " + ", ".join(f"{n} {status}" for status, n in self.counts.items() if n)
                + f" ({self.ran} run, {self.skipped} already done); summary in {self.outdir / 'summary.csv'}")
        kinds = [(status.replace("_", " "), [row["name"] or f"line {row['line']}" for row in self.rows
                                             if row["status"] == status])
                 for status in ("failed", "invalid", "not_converged", "not_run")]
        kinds += [("model mismatch", self.mismatched), ("not judged", self.unjudged)]
        return [line] + [f"  {kind} ({len(names)}): {', '.join(names[:SHOWN])}"
                         + (f" and {len(names) - SHOWN} more" if len(names) > SHOWN else "")
                         for kind, names in kinds if names]


SHOWN = 5  # names listed per kind of fit in `BatchSummary.report`
LOCAL_ONLY = {"inline": "local worker processes read the input files themselves",
              "retries": "local worker processes do not retry a job that raised (a failed job is recorded)"}


def _say(quiet: bool, text: str) -> None:
    if not quiet:
        print(text, file=sys.stderr)


def fit_many(manifest, outdir, *, workers: int | None = None, client=None, scheduler: str | None = None,
             inline: bool = False, retries: int | None = None, device: str | None = None, edge_margin: int = 0,
             progress: bool | None = None, quiet: bool = False, force: bool = False) -> BatchSummary:
    """Run every fit of a manifest and write each result as it finishes.

    The manifest is validated whole before any fit starts; each bad line is reported (on stderr,
    with its line number) and recorded as a failure, and the valid lines run. A fit already finished
    in `outdir` with the same line is skipped (resume), so an interrupted batch is completed by
    running it again; the folder then holds the same files as after an uninterrupted run (timing/
    apart). A failing fit is recorded with its error and the others go on. See `store.py` for the
    folder's layout and docs/batch.md for the manifest.

    Arguments:
        manifest: a JSON Lines file, or a list of line objects (dicts).
        outdir: the output folder (created if needed).
        workers: processes on this machine (default: the number of cores; not with a cluster, whose
            workers are its own).
        client: a `distributed.Client`: run the fits on its cluster instead; or
        scheduler: a Dask scheduler address ("tcp://host:8786") to connect a client to.
        inline: send the input files' bytes to the cluster workers instead of letting them read paths
            (a cluster only: local workers read the files).
        retries: Dask's retries of a task that raised (a cluster only; default 2; a task whose worker
            died is rescheduled anyway).
        device: where Warp renders each fit's G-buffers / ray trees, "cpu" or "cuda[:N]", for every
            line whose solver options name none (recorded in its report's job as solver.device, but
            no part of the job's identity: a rerun with another device fits nothing again); default:
            a line's own, else "cpu". Checked here for local workers (as `difflab fit --device`), by
            each job on a cluster's workers.
        edge_margin: pixels (an integer >= 0) for every line that gives no `edge_margin` of its own:
            its fit counts only pixels at least that far from every edge (`difflab.interior_mask`,
            inside the line's masks; part of the job's identity: a rerun with another margin fits
            those lines again); default 0: every pixel (the lines' specs left as they are).
        progress: show a progress bar with ETA (default: when stderr is a terminal).
        quiet: do not print the bad lines and the closing lines (`BatchSummary.report`) on stderr.
        force: write into `outdir` even when it holds other files than a batch's.
    Returns:
        a `BatchSummary`.
    Raises:
        ManifestError: the manifest cannot be read or lists nothing.
        OutputError: `outdir` holds files and is not a batch's folder (without `force`).
        DifflabError: bad `workers`, `retries`, `device`; `inline` or `retries` without a cluster,
            `workers` with one; or both `client` and `scheduler`; or a script calls fit_many
            outside `if __name__ == "__main__":`, which the local worker processes run again as they
            start (they import the main script), so that none could start: nothing is run.
    """
    from ..fit.edges import check_margin
    from .runners import leave_if_importing_main

    leave_if_importing_main()  # a script's unguarded call, run again in a worker: the parent says so
    jobs, invalid = load_manifest(manifest)
    if workers is not None and not (isinstance(workers, int) and not isinstance(workers, bool) and workers >= 1):
        raise DifflabError(f"workers: expected an integer >= 1, got {workers!r}")
    if client is not None and scheduler is not None:
        raise DifflabError("client, scheduler: give one or the other")
    cluster = client is not None or scheduler is not None
    if retries is not None and not (isinstance(retries, int) and not isinstance(retries, bool) and retries >= 0):
        raise DifflabError(f"retries: expected an integer >= 0, got {retries!r}")
    for name, given in (("inline", inline), ("retries", retries is not None)):
        if given and not cluster:
            raise DifflabError(f"{name}: applies only to a Dask cluster (client= or scheduler=): {LOCAL_ONLY[name]}")
    if workers is not None and cluster:
        raise DifflabError("workers: applies only to local worker processes; a Dask cluster's workers are its own")
    if device is not None and not cluster:  # (a cluster's workers may have the GPU this machine lacks: each job checks it there)
        from ..renderers.launch import resolve_device

        resolve_device(device)
    margin = check_margin(edge_margin, "edge_margin")
    margin = {"edge_margin": margin} if margin else {}
    jobs = [dataclasses.replace(job, spec={**margin, **job.spec, "solver": {"device": device or "cpu", **job.spec["solver"]}})
            for job in jobs]  # where each fit runs, in its report (not its identity: `store.same_job`)
    store = Store(outdir, force)
    for bad in invalid:
        _say(quiet, f"manifest line {bad.line}: {bad.error}")
    store.record_invalid(invalid)
    todo = [job for job in jobs if not store.done(job)]
    owned = _connect(scheduler) if scheduler is not None and todo else None
    try:
        _run(store, todo, owned or client, min(workers or os.cpu_count() or 1, len(todo)), inline,
             2 if retries is None else retries, progress)
    finally:
        if owned is not None:
            owned.close()
    table = store.summarise(jobs, invalid)
    summary = BatchSummary(Path(outdir), table["jobs"], table["counts"], len(todo), len(jobs) - len(todo))
    _say(quiet, "\n".join(summary.report()))
    return summary


def _connect(scheduler: str):
    """A `distributed.Client` of the scheduler at `scheduler`; DifflabError when Dask is missing or
    the scheduler does not answer."""
    try:
        from distributed import Client
    except ImportError:
        raise DifflabError("scheduler: running on a Dask cluster needs Dask: pip install -e \".[cluster]\"") from None
    try:
        return Client(scheduler)
    except (OSError, TimeoutError, ValueError) as exc:
        raise DifflabError(f"scheduler: cannot connect to {scheduler!r} ({exc})") from None


def _run(store: Store, todo, client, workers: int, inline: bool, retries: int, progress) -> None:
    """Run `todo` on the cluster of `client` (or local processes) and record each outcome as it comes."""
    from tqdm.auto import tqdm

    from .runners import cluster_jobs, local_jobs

    if not todo:
        return
    outcomes = cluster_jobs(todo, client, inline, retries) if client is not None else local_jobs(todo, workers)
    failed = 0
    with closing(outcomes), tqdm(total=len(todo), unit="fit", desc="fit-batch", dynamic_ncols=True,
                                 disable=None if progress is None else not progress) as bar:
        for job, outcome in outcomes:
            store.record(job, outcome)
            failed += not outcome["ok"]
            bar.set_postfix(failed=failed, refresh=False)
            bar.update()

"""`difflab fit-batch`: every fit of a manifest, resumable, locally or on a Dask cluster.

    difflab fit-batch MANIFEST.jsonl -o OUTDIR [--workers N | --scheduler tcp://host:8786 [--inline] [--retries R]]
                      [--device cpu|cuda] [--edge-margin N]

Bad manifest lines are listed (with their line numbers) before any fit starts and recorded as
failures; the other fits run. Rerun the same command to finish an interrupted batch: finished fits
are skipped. Exit code: 0 when every line gave a converged fit that its image model explains; 3 when
any line is invalid, failed or did not converge; else 4 when any fit is flagged model_mismatch, else
5 when any fit's model was not judged (noise unknown, underdetermined or a mismatch suspected, as `difflab fit`; everything
is still written: see OUTDIR/summary.csv); 2 when the manifest cannot be read. docs/batch.md describes the manifest and the output folder.
"""

from __future__ import annotations

import argparse

from ..errors import EXIT_MODEL_MISMATCH, EXIT_NOT_CONVERGED, EXIT_NOT_JUDGED, EXIT_OK


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `fit-batch` subcommand to an argparse subparsers object."""
    p = subparsers.add_parser("fit-batch", help="run the fits of a manifest (resumable; local or Dask)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("manifest", help="JSON Lines file: one fit per line")
    p.add_argument("-o", "--output", required=True, help="output folder (rerun into it to resume)")
    p.add_argument("--workers", type=int,
                   help="worker processes on this machine (default: one per core; not with --scheduler)")
    p.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786 (needs difflab[cluster])")
    p.add_argument("--inline", action="store_true",
                   help="with --scheduler: send input files to the Dask workers as bytes (default: workers read the "
                        "paths)")
    p.add_argument("--retries", type=int, help="with --scheduler: Dask retries of a task that raised (default 2)")
    p.add_argument("--device", help="where Warp renders each fit: cpu or cuda[:N], for every line whose solver "
                                    "options name no device (default: the line's, else cpu)")
    p.add_argument("--edge-margin", default="0", metavar="N",
                   help="for every line without its own edge_margin: count only pixels at least N pixels from every "
                        "silhouette, object, checker or shadow edge (as the option of difflab fit)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--force", action="store_true",
                   help="write into an output folder that holds other files (a batch's folder is resumed without it)")
    p.set_defaults(func=run, output_is_folder=True)
    return p


def run(args) -> int:
    from ..errors import DifflabError, OutputError
    from ..files import FORCE_ADVICE
    from ..fit.edges import margin_text
    from .api import LOCAL_ONLY, fit_many

    for name, given in (("inline", args.inline), ("retries", args.retries is not None)):
        if given and args.scheduler is None:
            raise DifflabError(f"--{name}: applies only with --scheduler (a Dask cluster): {LOCAL_ONLY[name]}")
    if args.workers is not None and args.scheduler is not None:
        raise DifflabError("--workers: applies only to local worker processes; a Dask cluster's workers are its own "
                           "(dask worker --nworkers N)")
    margin = margin_text(args.edge_margin, "--edge-margin")
    try:
        summary = fit_many(args.manifest, args.output, workers=args.workers, scheduler=args.scheduler,
                           inline=args.inline, retries=args.retries, device=args.device, edge_margin=margin,
                           progress=False if args.no_progress else None, force=args.force)
    except OutputError as exc:  # fit_many's advice (force=True) in this command's words (--force)
        raise OutputError(str(exc).replace(FORCE_ADVICE["python"], FORCE_ADVICE["cli"])) from None
    if not summary.all_converged:
        return EXIT_NOT_CONVERGED  # a line invalid, failed or not converged
    if summary.mismatched:
        return EXIT_MODEL_MISMATCH
    return EXIT_NOT_JUDGED if summary.unjudged else EXIT_OK

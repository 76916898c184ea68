"""A batch's output folder: each result written atomically as it arrives, resume, the summary table.

    OUTDIR/scenes/NAME.json         the fitted scene (scene file format)
    OUTDIR/scenes/NAME.MATERIAL.texture.npy   a fitted texture, which the fitted scene names
                                    (`fit.result.texture_file_name`); written with the scene
    OUTDIR/reports/NAME.json        the fit report: the job as run, then `FitResult.to_dict()` less
                                    its timings; written after the scene, so it marks the job done
    OUTDIR/failures/NAME.json       a job that failed: the job and the error
    OUTDIR/failures/line-N.json     an invalid manifest line: its number, name if any, and the error
    OUTDIR/timing/NAME.json         the job's wall time in its worker (the one thing that changes
                                    from run to run; everything else is the same for the same manifest)
    OUTDIR/summary.csv, .json       one row per manifest line, in manifest order, written at the end

Only the process that owns the folder writes to it, one file at a time, each through a temporary file
renamed into place: an interrupted run leaves complete files or none (a process killed mid-write can
leave a hidden temporary, which the next run removes: opening the folder sweeps it once, so that each
write need not list the folder again). One run per output folder at a time; a
non-empty folder that is not a batch's is not written into without `force`.
"""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

from ..files import (TMP_MARK, refuse_overwrite, uninterrupted, write_json, write_json_atomic, write_text_atomic,
                     write_together)
from ..fit.result import TEXTURE_FILE, drop_texture_files
from ..io import write_image
from .manifest import Invalid, Job

FOLDERS = ("scenes", "reports", "failures", "timing")
COLUMNS = ("line", "name", "status", "result", "model", "model_mismatch", "mismatch_suspected", "noise_unknown",
           "noise_not_white", "underdetermined", "too_few_values", "unreached", "loss", "psnr", "chi2", "steps", "params",
           "error")
REPORTED = ("result", "model", "model_mismatch", "mismatch_suspected", "noise_unknown", "noise_not_white",
            "underdetermined", "too_few_values", "unreached", "loss", "psnr", "chi2", "steps", "params")  # from a report
JSON_CELLS = ("unreached", "params")  # written to the CSV as JSON (a list, a dict)


def _read_json(path: Path):
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


class Store:
    """The output folder of one batch (see the module docstring for its layout)."""

    def __init__(self, outdir, force: bool = False):
        """Open (make) the folder. A batch's folder is reopened as it is (resume); any other folder
        with something in it is refused (OutputError) unless `force`, by the one overwrite rule."""
        self.root = Path(outdir)
        if not any((self.root / name).exists() for name in (*FOLDERS, "summary.json")):
            refuse_overwrite(self.root, force=force, caller="python")  # (fit_many's force=)
        for folder in FOLDERS:
            (self.root / folder).mkdir(parents=True, exist_ok=True)
        for folder in (self.root, *(self.root / f for f in FOLDERS)):  # temporaries of a killed writer
            for tmp in folder.glob(f".*{TMP_MARK}*"):
                tmp.unlink()

    def _file(self, folder: str, name: str) -> Path:
        return self.root / folder / f"{name}.json"

    def done(self, job: Job) -> bool:
        """Has `job`, as specified now (`same_job`), a result written -- its report, its scene, and
        every fitted-texture file the scene names? (A changed line, or a deleted file, is redone.)"""
        report = _read_json(self._file("reports", job.name))
        if not (isinstance(report, dict) and same_job(report.get("job"), job.spec)):
            return False
        scene = _read_json(self._file("scenes", job.name))
        if not isinstance(scene, dict):
            return False
        materials = scene.get("materials") if isinstance(scene.get("materials"), dict) else {}
        pattern = re.compile(re.escape(job.name) + TEXTURE_FILE)
        named = [m["texture"] for m in materials.values() if isinstance(m, dict) and isinstance(m.get("texture"), str)]
        return all((self.root / "scenes" / file).is_file() for file in named if pattern.fullmatch(file))

    def record(self, job: Job, outcome: dict) -> None:
        """Write a worker's outcome (`worker.run_job`): scene then report, or the failure; then the
        timing. A result replaces an earlier failure of the same name, and the other way round."""
        with uninterrupted():
            self._record(job, outcome)

    def _record(self, job: Job, outcome: dict) -> None:
        if outcome["ok"]:
            self._file("failures", job.name).unlink(missing_ok=True)
            drop_texture_files(self.root / "scenes", job.name, keep=outcome["textures"])
            scene = self._file("scenes", job.name)
            writers = {scene.with_name(file): lambda temporary, texels=texels: write_image(temporary, texels)
                       for file, texels in outcome["textures"].items()}
            writers[scene] = lambda temporary: write_json(temporary, outcome["scene"])
            write_together(writers, sweep=False)
            write_json_atomic(self._file("reports", job.name), {"name": job.name, "job": job.spec, **outcome["report"]},
                              sweep=False)
        else:
            self._file("reports", job.name).unlink(missing_ok=True)
            self._file("scenes", job.name).unlink(missing_ok=True)
            drop_texture_files(self.root / "scenes", job.name)
            write_json_atomic(self._file("failures", job.name),
                              {"name": job.name, "job": job.spec, "error": outcome["error"]}, sweep=False)
        write_json_atomic(self._file("timing", job.name), {"name": job.name, "seconds": outcome["seconds"]},
                          sweep=False)

    def record_invalid(self, invalid: list[Invalid]) -> None:
        """Write one failure per invalid line, and drop those of lines that are no longer invalid."""
        keep = {self._file("failures", f"line-{bad.line}") for bad in invalid}
        with uninterrupted():
            for old in (self.root / "failures").glob("line-*.json"):
                if old not in keep:
                    old.unlink()
            for bad in invalid:
                write_json_atomic(self._file("failures", f"line-{bad.line}"),
                                  {"line": bad.line, "name": bad.name, "error": bad.error})

    def row(self, job: Job) -> dict:
        """The summary row of a job, from what the folder holds for it now."""
        row = {**dict.fromkeys(COLUMNS), "line": job.line, "name": job.name, "status": "not_run"}
        report = _read_json(self._file("reports", job.name))
        failure = _read_json(self._file("failures", job.name))
        if isinstance(report, dict) and same_job(report.get("job"), job.spec):
            row.update({k: report.get(k) for k in REPORTED},
                       status="converged" if report.get("converged") else "not_converged")
        elif isinstance(failure, dict) and same_job(failure.get("job"), job.spec):
            row.update(status="failed", error=failure.get("error"))
        return row

    def summarise(self, jobs: list[Job], invalid: list[Invalid]) -> dict:
        """Write summary.csv and summary.json (one row per manifest line, in line order) and return the
        latter's content: {"lines", "counts": status -> rows, "jobs": rows}.
        Status: converged, not_converged (a result, flagged), failed (no result: the error says why),
        invalid (a bad manifest line), not_run; a converged fit may still carry model_mismatch."""
        rows = [self.row(job) for job in jobs]
        rows += [{**dict.fromkeys(COLUMNS), "line": bad.line, "name": bad.name, "status": "invalid", "error": bad.error}
                 for bad in invalid]
        rows.sort(key=lambda r: r["line"])
        counts = {status: sum(r["status"] == status for r in rows)
                  for status in ("converged", "not_converged", "failed", "invalid", "not_run")}
        summary = {"lines": len(rows), "counts": counts, "jobs": rows}
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
        writer.writeheader()
        for r in rows:
            writer.writerow({**r, **{k: None if r[k] is None else json.dumps(r[k]) for k in JSON_CELLS}})
        with uninterrupted():
            write_json_atomic(self.root / "summary.json", summary)
            write_text_atomic(self.root / "summary.csv", text.getvalue())
        return summary


def same_job(recorded, spec: dict) -> bool:
    """Whether a report's or failure's `recorded` job is the job `spec`: equal but for solver.device,
    which says where the fit's renders ran, not what is fitted, so that a rerun with another
    `--device` does not redo finished fits."""
    def identity(job):
        return {**job, "solver": {k: v for k, v in job.get("solver", {}).items() if k != "device"}}

    return isinstance(recorded, dict) and isinstance(recorded.get("solver", {}), dict) and identity(recorded) == identity(spec)

"""A batch with faults, interrupted and resumed: do we get every result, every failure, and the same files?

Builds a manifest of 200 small fits (experiments/bench/batch.py's sphere, each target with its own
kd) of which 5 lines are broken (bad JSON, unknown key, bad option type, bad name, repeated name) and
5 name targets that do not exist; runs it once uninterrupted with `difflab fit-batch`, then again in
a fresh folder, killing that run (SIGKILL) once half the results are written, and running it again.
Prints the counts, the largest kd error of the converged fits, and whether the two folders hold the
same files (timing/ apart). Writes experiments/results/batch_faults.json.

    python experiments/batch_faults.py [--fits 200] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / "bench"))
from batch import KD_STEPS, write_batch  # noqa: E402  (the benchmark's manifest)

RESULTS = Path(__file__).resolve().parent / "results"
BROKEN = ['{"name": "broken-json", "scene": "scene.json", "targets": ["t0.npy"]',
          '{"name": "broken-key", "scene": "scene.json", "targets": ["t0.npy"], "materal": "red"}',
          '{"name": "broken-option", "scene": "scene.json", "targets": ["t0.npy"], "solver": {"max_steps": "many"}}',
          '{"name": "../broken-name", "scene": "scene.json", "targets": ["t0.npy"]}',
          '{"name": "fit0000", "scene": "scene.json", "targets": ["t1.npy"]}']


def faulty_manifest(folder: Path, fits: int) -> Path:
    """fits - 10 good lines, 5 broken ones spread through them, 5 with missing targets."""
    manifest = write_batch(folder, fits - 10, 16)
    lines = manifest.read_text().splitlines()
    for i in range(5):
        lines.append(json.dumps({"name": f"unreachable{i}", "scene": "scene.json", "targets": [f"missing{i}.npy"],
                                 "material": "red"}))
    for i, bad in enumerate(BROKEN):
        lines.insert((i + 1) * len(lines) // 6, bad)
    manifest.write_text("\n".join(lines) + "\n")
    return manifest


def fit_batch(manifest: Path, out: Path, workers: int, kill_after: int | None = None) -> int:
    """Run `difflab fit-batch`; with kill_after, SIGKILL it once that many reports are written."""
    proc = subprocess.Popen([sys.executable, "-m", "difflab.cli", "fit-batch", str(manifest), "-o", str(out),
                             "--workers", str(workers), "--no-progress"], stderr=subprocess.DEVNULL)
    if kill_after is not None:
        while len(list((out / "reports").glob("*.json"))) < kill_after and proc.poll() is None:
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
    return proc.wait()


def snapshot(outdir: Path) -> dict:
    return {str(p.relative_to(outdir)): p.read_bytes() for p in sorted(outdir.rglob("*"))
            if p.is_file() and p.relative_to(outdir).parts[0] != "timing"}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fits", type=int, default=200)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--out", type=Path, default=RESULTS / "batch_faults.json")
    args = parser.parse_args(argv)
    from difflab.io import write_json_atomic

    with tempfile.TemporaryDirectory(prefix="difflab-batch-faults-") as tmp:
        tmp = Path(tmp)
        manifest = faulty_manifest(tmp, args.fits)
        start = time.perf_counter()
        code = fit_batch(manifest, tmp / "whole", args.workers)
        whole_s = time.perf_counter() - start
        summary = json.loads((tmp / "whole" / "summary.json").read_text())
        half = (args.fits - 10) // 2
        killed = fit_batch(manifest, tmp / "resumed", args.workers, kill_after=half)
        before = len(list((tmp / "resumed" / "reports").glob("*.json")))
        again = fit_batch(manifest, tmp / "resumed", args.workers)
        identical = snapshot(tmp / "whole") == snapshot(tmp / "resumed")
        errors = []
        for row in summary["jobs"]:
            if row["status"] == "converged" and row["name"].startswith("fit"):
                truth = 0.3 + 0.05 * (int(row["name"][3:]) % KD_STEPS)
                errors.append(abs(row["params"]["kd"][0] - truth) / truth)
    report = {"fits": args.fits, "workers": args.workers, "exit_code": code, "counts": summary["counts"],
              "wall_s": whole_s, "killed_exit": killed, "reports_when_killed": before, "rerun_exit": again,
              "identical_after_resume": identical, "max_kd_rel_error": max(errors)}
    write_json_atomic(args.out, report)
    print(f"{args.fits} lines on {args.workers} workers in {whole_s:.1f} s: {summary['counts']} (exit {code}); "
          f"killed with {before} results written, rerun exit {again}: "
          f"{'identical' if identical else 'DIFFERENT'} files; max kd error {max(errors):.1e}")
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())

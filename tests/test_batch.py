"""Batches of fits (`fit_many`, `difflab fit-batch`): the manifest's validation, results recovered and
written per job, failures recorded, resume, interruption, and the Dask backend with a worker killed.

One small batch (16x16 targets of a sphere with known kd) is run once, uninterrupted, on two local
worker processes; the other runs must leave the same files (timing/ apart)."""

import csv
import dataclasses
import io
import json
import os
import platform
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from test_fit_helpers import scene_dict

import difflab.files
from difflab import fit_many
from difflab.batch.api import BatchSummary
from difflab.batch.manifest import load_manifest, parse_line
from difflab.batch import runners
from difflab.batch.runners import TASK_SECONDS, cluster_render_threads, task_size
from difflab.batch.store import Store
from difflab.batch.worker import adaptive_allocator, outcome_of
from difflab.cli import main
from difflab.errors import DifflabError, ManifestError, OutputError
from difflab.io import load_image, save_image
from difflab import render_frame
from difflab.scene import Scene, load_scene, save_scene

KDS = [[0.3, 0.2, 0.1], [0.5, 0.2, 0.1], [0.7, 0.3, 0.1], [0.4, 0.4, 0.2], [0.6, 0.1, 0.3], [0.2, 0.5, 0.4],
       [0.35, 0.25, 0.15], [0.55, 0.45, 0.05], [0.65, 0.15, 0.25], [0.25, 0.35, 0.45]]
GOOD = [f"fit{i}" for i in range(len(KDS))]


def write_batch(folder: Path) -> Path:
    """A start scene, one .npy target per kd of KDS, and a manifest of 13 lines: the good fits, a bad
    line (line 3: an unknown key), a target that does not exist (line 12) and one that the model
    cannot explain (line 13: fit0's target with a bright 3x3 patch the scene has no reason for)."""
    start = scene_dict(size=16)
    start["materials"]["red"].update(kd=[0.5, 0.5, 0.5], ks=[0.3, 0.3, 0.3], n=18.0)
    save_scene(Scene.from_dict(start), folder / "scene.json")
    lines = []
    for i, kd in enumerate(KDS):
        truth = scene_dict(size=16)
        truth["materials"]["red"]["kd"] = kd
        save_image(folder / f"t{i}.npy", render_frame(Scene.from_dict(truth)).image)
        lines.append({"name": GOOD[i], "scene": "scene.json", "targets": [f"t{i}.npy"], "material": "red"})
    lines.insert(2, {"name": "typo", "scene": "scene.json", "targets": ["t0.npy"], "materal": "red"})
    lines.append({"name": "unreachable", "scene": "scene.json", "targets": ["nope.npy"], "material": "red"})
    patched = load_image(folder / "t0.npy")
    patched[6:9, 6:9] += 0.3
    save_image(folder / "patched.npy", patched)
    lines.append({"name": "patched", "scene": "scene.json", "targets": ["patched.npy"], "material": "red"})
    manifest = folder / "manifest.jsonl"
    manifest.write_text("".join(json.dumps(line) + "\n" for line in lines))
    return manifest


def snapshot(outdir: Path) -> dict:
    """Every file of an output folder (path -> bytes) but the run-dependent timing/."""
    return {str(p.relative_to(outdir)): p.read_bytes() for p in sorted(outdir.rglob("*"))
            if p.is_file() and p.relative_to(outdir).parts[0] != "timing"}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """(manifest, output folder, summary) of the uninterrupted run; JAX's compilation cache in a
    temporary folder, shared by this module's worker processes."""
    folder = tmp_path_factory.mktemp("batch")
    old = os.environ.get("DIFFLAB_CACHE_DIR")
    os.environ["DIFFLAB_CACHE_DIR"] = str(folder / "cache")
    try:
        manifest = write_batch(folder)
        summary = fit_many(manifest, folder / "out", workers=2, quiet=True)
        yield manifest, folder / "out", summary
    finally:
        if old is None:
            os.environ.pop("DIFFLAB_CACHE_DIR", None)
        else:
            os.environ["DIFFLAB_CACHE_DIR"] = old


# -- the manifest ------------------------------------------------------------------------------------

BASE = {"name": "a", "scene": "s.json", "targets": ["t.png"]}


@pytest.mark.parametrize("line, message", [
    ([1, 2], "expected a JSON object, got list"),
    ({"scene": "s.json", "targets": ["t.png"]}, "name: missing (required: name, scene, targets)"),
    ({**BASE, "material": "red", "solvr": {}}, "unknown key(s) ['solvr']; known: name, scene, targets, material, "
     "params, method, init, solver, edge_margin"),
    ({**BASE, "edge_margin": True}, "edge_margin: expected an integer number of pixels >= 0, got True"),
    ({**BASE, "edge_margin": 1.5}, "edge_margin: expected an integer number of pixels >= 0, got 1.5"),
    ({**BASE, "edge_margin": -1}, "edge_margin: expected an integer number of pixels >= 0, got -1"),
    ({**BASE, "name": "../x"}, "name: expected letters, digits, '.', '_', '-' (at most 100, starting with a letter "
     "or digit), got '../x'"),
    ({**BASE, "targets": []}, "targets: empty list"),
    ({**BASE, "targets": [{"image": "t.png", "camra": {}}]}, "targets[0]: unknown key(s) ['camra']; known: image, "
     "mask, camera, lights"),
    ({**BASE, "targets": [{"image": "t.png", "lights": {}}]},
     "targets[0].lights: expected a list of light objects (a scene file's lights)"),
    ({**BASE, "targets": [3]}, "targets[0]: expected an image path or a view object, got int"),
    ({**BASE, "method": "path"}, "method: expected one of raster, raytrace, got 'path'"),
    ({**BASE, "material": ["red", "red"]}, "material: names repeat: ['red', 'red']"),
    ({**BASE, "params": ""}, "params: expected a name or a non-empty list of names, got ['']"),
    ({**BASE, "init": {"kd": [0.1, "x"]}}, "init.kd: expected a number or a list of numbers, got [0.1, 'x']"),
    ({**BASE, "solver": {"max_steps": 2.5}}, "solver.max_steps: expected int, got 2.5"),
    ({**BASE, "solver": {"rtol": True}}, "solver.rtol: expected int or float, got True"),
    ({**BASE, "solver": {"ceiling": "1"}}, "solver.ceiling: expected int or float or bool, got '1'"),
    ({**BASE, "solver": {"tol": 1}}, "solver.tol: unknown option; known: solver, max_steps, rtol, atol, "
     "learning_rate, x64, rel_tol, abs_tol, per_channel, bounded, loss, loss_scale, sigma, ceiling, max_depth, spp, "
     "device"),
    ({**BASE, "solver": {"device": 0}}, "solver.device: expected str, got 0"),
    ({**BASE, "method": "raster", "solver": {"max_depth": 2}},  # (was accepted, and ignored by the fit)
     "solver.max_depth: does not apply to method 'raster' (the G-buffer has no secondary rays; use method 'raytrace')"),
])
def test_bad_line_names_its_problem(line, message):
    with pytest.raises(ManifestError) as info:
        parse_line(line, Path("/data"))
    assert str(info.value) == message


def test_manifest_reports_every_bad_line_with_its_number(tmp_path):
    text = ['{"name": "a", "scene": "s.json", "targets": "t.png"}', "", '{"name": "b", "scene": 1, "targets": ["t.png"]}',
            "{not json", '{"name": "a", "scene": "s.json", "targets": "u.png", "method": "raytrace"}']
    (tmp_path / "m.jsonl").write_text("\n".join(text) + "\n")
    jobs, invalid = load_manifest(tmp_path / "m.jsonl")
    assert [(j.line, j.name) for j in jobs] == [(1, "a")]
    assert jobs[0].spec == {"name": "a", "scene": str(tmp_path / "s.json"), "init": {}, "solver": {},
                            "targets": [{"image": str(tmp_path / "t.png")}]}
    assert [(bad.line, bad.name, bad.error) for bad in invalid] == [
        (3, "b", "scene: expected a file path, got 1"),
        (4, None, "not JSON: Expecting property name enclosed in double quotes: line 1 column 2 (char 1)"),
        (5, "a", "name: 'a' is already used on line 1")]


def test_manifest_that_cannot_run(tmp_path):
    with pytest.raises(ManifestError, match="manifest not found"):
        load_manifest(tmp_path / "none.jsonl")
    (tmp_path / "empty.jsonl").write_text("\n\n")
    with pytest.raises(ManifestError, match="no fits listed"):
        load_manifest(tmp_path / "empty.jsonl")
    with pytest.raises(DifflabError, match="workers: expected an integer >= 1, got 0"):
        fit_many([BASE], tmp_path / "out", workers=0, quiet=True)
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.png").write_bytes(b"")
    with pytest.raises(OutputError, match=r"photos: exists; pass force=True to overwrite$"):  # Python's words
        fit_many([BASE], tmp_path / "photos", quiet=True)
    assert sorted(p.name for p in (tmp_path / "photos").iterdir()) == ["a.png"]  # nothing written


def test_fit_batch_command_names_its_force_option(tmp_path, capsys):
    """The same refusal from the command line names --force (fit_many's Python error said --force too)."""
    from difflab.cli import main

    (tmp_path / "m.jsonl").write_text(json.dumps(BASE) + "\n")
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.png").write_bytes(b"")
    assert main(["fit-batch", str(tmp_path / "m.jsonl"), "-o", str(tmp_path / "photos"), "--no-progress"]) == 2
    assert capsys.readouterr().err == f"difflab: error: {tmp_path / 'photos'}: exists; use --force to overwrite\n"
    assert sorted(p.name for p in (tmp_path / "photos").iterdir()) == ["a.png"]


@pytest.mark.parametrize("flags, keywords, flag_message, keyword_message", [
    (["--inline"], {"inline": True}, "--inline: applies only with --scheduler (a Dask cluster): local worker "
     "processes read the input files themselves", "inline: applies only to a Dask cluster (client= or scheduler=): "
     "local worker processes read the input files themselves"),
    (["--retries", "3"], {"retries": 3}, "--retries: applies only with --scheduler (a Dask cluster): local worker "
     "processes do not retry a job that raised (a failed job is recorded)", "retries: applies only to a Dask cluster "
     "(client= or scheduler=): local worker processes do not retry a job that raised (a failed job is recorded)"),
    (["--scheduler", "tcp://127.0.0.1:9", "--workers", "2"], {"scheduler": "tcp://127.0.0.1:9", "workers": 2},
     "--workers: applies only to local worker processes; a Dask cluster's workers are its own (dask worker "
     "--nworkers N)", "workers: applies only to local worker processes; a Dask cluster's workers are its own"),
])
def test_options_of_the_other_backend_are_refused(tmp_path, capsys, flags, keywords, flag_message, keyword_message):
    """--inline and --retries without --scheduler (and --workers with it) did nothing, silently: now
    exit 2 naming the flag (fit_many: the keyword), before anything is written or connected."""
    (tmp_path / "m.jsonl").write_text(json.dumps(BASE) + "\n")
    assert main(["fit-batch", str(tmp_path / "m.jsonl"), "-o", str(tmp_path / "out"), *flags]) == 2
    assert capsys.readouterr().err == f"difflab: error: {flag_message}\n"
    with pytest.raises(DifflabError) as info:
        fit_many([BASE], tmp_path / "out", quiet=True, **keywords)
    assert str(info.value) == keyword_message
    assert not any((tmp_path / "out").iterdir())


def test_a_device_applies_to_every_line_without_its_own_and_is_checked_as_fit_does(tmp_path, capsys, monkeypatch):
    """--device (fit_many's device=) fills solver.device of each line that names none, recorded in
    its job; a device this machine lacks is refused before any fit, with `difflab fit --device`'s
    own message. (fit-batch had no --device, and a line's solver.device was an unknown option.)"""
    import difflab.batch.api as api

    lines = [BASE, {**BASE, "name": "b", "solver": {"device": "cuda:7", "max_steps": 5}}]
    ran = []
    monkeypatch.setattr(api, "_run", lambda store, todo, *args: ran.extend(job.spec["solver"] for job in todo))
    fit_many(lines, tmp_path / "out", device="cpu", quiet=True)
    assert ran == [{"device": "cpu"}, {"device": "cuda:7", "max_steps": 5}]
    scene = tmp_path / "s.json"
    scene.write_text(json.dumps(scene_dict(size=8)))
    save_image(tmp_path / "t.npy", np.zeros((8, 8, 3), np.float32))
    (tmp_path / "m.jsonl").write_text(json.dumps({"name": "a", "scene": "s.json", "targets": "t.npy"}) + "\n")
    for device in ("cuda:99", "gpu"):
        fit = main(["fit", str(scene), str(tmp_path / "t.npy"), "--material", "red", "--device", device,
                    "-o", str(tmp_path / "fitted.json")])
        fit_err = capsys.readouterr().err
        batch = main(["fit-batch", str(tmp_path / "m.jsonl"), "-o", str(tmp_path / device), "--device", device])
        assert (fit, batch) == (2, 2) and capsys.readouterr().err == fit_err and fit_err.startswith("difflab: error: device: ")
        assert not any((tmp_path / device).iterdir())


def test_a_rerun_with_another_device_fits_nothing_again_and_reports_keep_their_device(tmp_path, monkeypatch):
    """The device says where a fit's renders run, not what is fitted: a finished batch rerun with a
    --device added or changed fits nothing again (it is no part of the job's identity), and each
    report names the device its fit ran on (the default, cpu, too). Before, --device went into each
    job, so Store.done saw another job and every finished fit was redone."""
    import difflab.renderers.launch as launch

    save_scene(Scene.from_dict(scene_dict(size=8)), tmp_path / "s.json")
    save_image(tmp_path / "t.npy", np.full((8, 8, 3), 0.2, np.float32))
    line = {"name": "a", "scene": str(tmp_path / "s.json"), "targets": str(tmp_path / "t.npy"), "material": "red",
            "params": "kd", "solver": {"max_steps": 3}}
    first = fit_many([line], tmp_path / "out", workers=1, quiet=True)
    report = (tmp_path / "out" / "reports" / "a.json").read_bytes()
    assert (first.ran, json.loads(report)["job"]["solver"]) == (1, {"device": "cpu", "max_steps": 3})
    monkeypatch.setattr(launch, "resolve_device", lambda device: device)  # a GPU for this check (none runs)
    for device in ("cpu", "cuda:1"):
        again = fit_many([line], tmp_path / "out", device=device, workers=1, quiet=True)
        assert (again.ran, again.skipped, again.rows[0]["status"]) == (0, 1, first.rows[0]["status"])
        assert (tmp_path / "out" / "reports" / "a.json").read_bytes() == report
    assert fit_many([{**line, "solver": {"max_steps": 4}}], tmp_path / "out", workers=1, quiet=True).ran == 1


# -- a local run -------------------------------------------------------------------------------------


def test_batch_recovers_each_fit_and_records_failures(reference):
    manifest, out, summary = reference
    assert summary.counts == {"converged": 11, "not_converged": 0, "failed": 1, "invalid": 1, "not_run": 0}
    assert (summary.ran, summary.skipped, summary.all_converged, summary.mismatched) == (12, 0, False, ["patched"])
    assert summary.unjudged == []
    patched = json.loads((out / "reports" / "patched.json").read_text())
    assert patched["converged"] and patched["model_mismatch"] and patched["chi2"] > 100 and not patched["ok"]
    for name, kd in zip(GOOD, KDS):
        np.testing.assert_allclose(load_scene(out / "scenes" / f"{name}.json").materials["red"].kd, kd, rtol=1e-4)
        report = json.loads((out / "reports" / f"{name}.json").read_text())
        assert (report["result"], report["converged"], report["ok"], report["job"]["name"]) == ("successful", True, True,
                                                                                                   name)
        assert (report["model"], report["model_mismatch"]) == ("raster", False)
        assert "seconds" not in report and json.loads((out / "timing" / f"{name}.json").read_text())["seconds"] > 0
    failure = json.loads((out / "failures" / "unreachable.json").read_text())
    assert failure["error"] == f"targets[0]: {manifest.parent / 'nope.npy'}: image file not found"
    invalid = json.loads((out / "failures" / "line-3.json").read_text())  # the typo line
    assert invalid == {"line": 3, "name": "typo", "error": "unknown key(s) ['materal']; known: name, scene, targets, "
                       "material, params, method, init, solver, edge_margin"}
    rows = (out / "summary.csv").read_text().splitlines()
    assert rows[0] == ("line,name,status,result,model,model_mismatch,mismatch_suspected,noise_unknown,noise_not_white,"
                       "underdetermined,too_few_values,unreached,loss,psnr,chi2,steps,params,error")
    assert [r.split(",")[:3] for r in rows[1:]] == (
        [["1", "fit0", "converged"], ["2", "fit1", "converged"], ["3", "typo", "invalid"]]
        + [[str(i + 2), f"fit{i}", "converged"] for i in range(2, len(KDS))]
        + [["12", "unreachable", "failed"], ["13", "patched", "converged"]])


def test_the_closing_lines_name_the_fits_that_are_not_clean(reference, tmp_path, capsys):
    """fit-batch exited 4 after "13 lines: 11 converged, ..." without saying which fit was flagged."""
    _, out, summary = reference
    assert summary.report() == [
        f"13 lines: 11 converged, 1 failed, 1 invalid (12 run, 0 already done); summary in {out / 'summary.csv'}",
        "  failed (1): unreachable", "  invalid (1): typo", "  model mismatch (1): patched"]
    rows = ([{"line": i + 1, "name": f"f{i}", "status": "failed", "model_mismatch": None} for i in range(7)]
            + [{"line": 8, "name": None, "status": "invalid", "model_mismatch": None},
               {"line": 9, "name": "u", "status": "converged", "model_mismatch": False, "noise_unknown": True}])
    assert BatchSummary(tmp_path, rows, {}, 8, 0).report()[1:] == [
        "  failed (7): f0, f1, f2, f3, f4 and 2 more", "  invalid (1): line 8", "  not judged (1): u"]
    fit_many([{"name": "bad", "scene": "s.json"}], tmp_path / "out")  # nothing to run: no worker started
    assert capsys.readouterr().err == (
        "manifest line 1: targets: missing (required: name, scene, targets)\n"
        f"1 line: 1 invalid (0 run, 0 already done); summary in {tmp_path / 'out' / 'summary.csv'}\n"
        "  invalid (1): bad\n")


# `difflab fit-batch` in a process that stops itself (SIGSTOP) once it has written its `stop_at`-th
# scene -- inside `Store.record`, between that job's scene and its report -- so that a signal lands
# at a known point whatever the machine's load (polling the folder from here raced with fits that
# finish within a scheduling delay). Only this wrapper is test code: the batch runs unchanged.
STOPPING_CLI = """
import os, signal, sys
from difflab.batch import store
from difflab.cli import main

stop_at, write = int(sys.argv.pop(1)), store.write_together
scenes = []

def write_then_stop(writers, *args, **kwargs):
    write(writers, *args, **kwargs)
    if any(path.parent.name == "scenes" for path in writers):
        scenes.append(writers)
        if len(scenes) == stop_at:
            os.kill(os.getpid(), signal.SIGSTOP)

store.write_together = write_then_stop
sys.exit(main(sys.argv[1:]))
"""


def _run_until(manifest: Path, out: Path, log: Path, stop_at: int, sig) -> int:
    """Run `difflab fit-batch` on one worker process (this tree first on the path) until it has
    written the scene of its `stop_at`-th fit but not that fit's report, send it `sig` there, and
    return its exit status."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parents[1]), os.environ.get("PYTHONPATH", "")])}
    with log.open("w") as stderr:
        proc = subprocess.Popen([sys.executable, "-c", STOPPING_CLI, str(stop_at), "fit-batch", str(manifest), "-o",
                                 str(out), "--workers", "1", "--no-progress"], env=env, stderr=stderr)
        try:
            _, status = os.waitpid(proc.pid, os.WUNTRACED)  # until it stops itself (or ends: a failure)
            assert os.WIFSTOPPED(status), f"ended without stopping ({status}): {log.read_text()}"
            proc.send_signal(sig)
            os.kill(proc.pid, signal.SIGCONT)
            return proc.wait(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def test_interrupted_and_killed_runs_completed_by_a_rerun_are_identical(reference, tmp_path):
    """Ctrl-C (SIGINT) while a result is being written, then a second run killed outright (SIGKILL)
    between the scene and the report of its second fit: Ctrl-C lets the result being written finish,
    the kill leaves that scene without its report, each leaves complete files only, and a third run
    leaves the same files as the uninterrupted run -- redoing only what is missing (here also a
    report lost between its scene and itself, and a temporary file left by a killed writer)."""
    manifest, out, _ = reference
    reports, scenes, log = tmp_path / "out" / "reports", tmp_path / "out" / "scenes", tmp_path / "log.txt"
    names = lambda folder: {p.stem for p in folder.glob("*.json")}  # noqa: E731
    assert _run_until(manifest, tmp_path / "out", log, 1, signal.SIGINT) == 130, log.read_text()
    assert "difflab: interrupted" in log.read_text()
    assert not list((tmp_path / "out").rglob(".*.tmp*"))
    assert len(names(reports)) == 1 and names(scenes) == names(reports)  # the result being written: whole
    assert _run_until(manifest, tmp_path / "out", log, 2, signal.SIGKILL) == -signal.SIGKILL, log.read_text()
    done = sorted(reports.glob("*.json"))
    assert len(done) == 2 and len(names(scenes)) == 3 and names(reports) < names(scenes)  # a scene, no report
    for path in (tmp_path / "out").rglob("[!.]*.json"):  # a hidden temporary may be cut short: the next run removes it
        json.loads(path.read_text())  # complete files only
    done[0].unlink()  # as if killed between a scene and its report, too
    (scenes / ".fit4.json.x1.tmp.json").write_text("{")  # a killed writer's temporary
    summary = fit_many(manifest, tmp_path / "out", workers=2, quiet=True)
    assert (summary.ran, summary.skipped) == (len(GOOD) + 2 - 1, 1)  # 12 valid lines, one of them done
    assert snapshot(tmp_path / "out") == snapshot(out)


def test_failed_fits_are_values_not_exceptions(reference):
    manifest, _, _ = reference
    jobs, _ = load_manifest(manifest)
    spec = jobs[0].spec
    mask = manifest.parent / "nothing.png"
    save_image(mask, np.zeros((16, 16, 3), np.float32))
    empty = outcome_of({**spec, "targets": [{**spec["targets"][0], "mask": str(mask)}]})
    assert empty == {"ok": False, "error": f"no fit made: empty_mask: targets[0] ({spec['targets'][0]['image']}): the "
                     f"mask masks[0] ({mask}) selects no pixel (none is bright and opaque)"}
    unknown = outcome_of({**spec, "solver": {"solver": "newton"}})
    assert unknown == {"ok": False, "error": "solver: unknown solver 'newton'; known: lm, gauss_newton, dogleg, bfgs, "
                       "adam, varpro"}


def test_store_keeps_one_outcome_per_job(tmp_path, monkeypatch):
    """A result replaces an earlier failure of the same job and the other way round. The folder is
    swept of killed writers' temporaries once, on opening, not listed again at each write (which made
    a batch of N fits O(N^2): ~10 ms a fit at 5000)."""
    (job,), _ = load_manifest([{"name": "a", "scene": "s.json", "targets": "t.png"}])
    store = Store(tmp_path)
    monkeypatch.setattr(difflab.files, "remove_stale_temps", lambda path: pytest.fail(f"listed the folder of {path}"))
    store.record(job, {"ok": False, "error": "boom", "seconds": 1.0})
    assert store.row(job)["status"] == "failed" and not store.done(job)
    store.record(job, {"ok": True, "scene": {"x": 1}, "textures": {}, "report": {"converged": False, "result": "r"},
                       "seconds": 2.0})
    assert not (tmp_path / "failures" / "a.json").exists() and store.done(job)
    assert store.row(job)["status"] == "not_converged"
    changed = dataclasses.replace(job, spec={**job.spec, "params": ["kd"]})
    assert not store.done(changed) and store.row(changed)["status"] == "not_run"  # a changed line is redone
    store.record(job, {"ok": False, "error": "boom", "seconds": 1.0})
    assert sorted(p.name for p in tmp_path.rglob("*.json")) == ["a.json", "a.json"]  # failures/ and timing/


def test_summary_carries_the_reports_underdetermined_and_noise_flags(tmp_path):
    """summary.csv lacked unreached, too_few_values and noise_not_white, which every report holds."""
    jobs, _ = load_manifest([{"name": n, "scene": "s.json", "targets": "t.png"} for n in ("a", "b")])
    store = Store(tmp_path)
    flags = {"a": {"unreached": ["lights[1].intensity"], "too_few_values": False, "noise_not_white": True},
             "b": {"unreached": [], "too_few_values": True, "noise_not_white": False}}
    for job in jobs:
        store.record(job, {"ok": True, "scene": {}, "textures": {}, "seconds": 1.0,
                           "report": {"converged": True, "result": "successful", "underdetermined": True,
                                      **flags[job.name]}})
    summary = store.summarise(jobs, [])
    assert [{k: r[k] for k in flags["a"]} for r in summary["jobs"]] == [flags["a"], flags["b"]]
    rows = list(csv.DictReader(io.StringIO((tmp_path / "summary.csv").read_text())))
    assert [(r["unreached"], r["too_few_values"], r["noise_not_white"], r["underdetermined"]) for r in rows] == [
        ('["lights[1].intensity"]', "False", "True", "True"), ("[]", "True", "False", "True")]


# -- a Dask cluster ----------------------------------------------------------------------------------


class _Cluster:
    """What `cluster_render_threads` asks a client: each worker's cores and its host and threads."""

    def __init__(self, workers):  # address -> (host, cores, nthreads)
        self.workers = workers

    def run(self, function):
        return {address: cores for address, (_, cores, _) in self.workers.items()}

    def scheduler_info(self):
        return {"workers": {a: {"host": h, "nthreads": n} for a, (h, _, n) in self.workers.items()}}


def test_cluster_render_threads_share_each_hosts_cores(monkeypatch):
    """A host's cores over its workers' task threads, the smallest over the hosts; $DIFFLAB_THREADS
    instead when set; 1 with no worker."""
    monkeypatch.delenv("DIFFLAB_THREADS", raising=False)
    cluster = _Cluster({"a:1": ("a", 16, 2), "a:2": ("a", 16, 2), "b:1": ("b", 8, 1), "c:1": ("c", 2, 4)})
    assert cluster_render_threads(_Cluster(dict(list(cluster.workers.items())[:2]))) == 4  # 16 cores / 4 threads
    assert cluster_render_threads(_Cluster(dict(list(cluster.workers.items())[:3]))) == 4  # b: 8 / 1, a: 4
    assert cluster_render_threads(cluster) == 1  # c: 2 cores for 4 threads, at least 1
    assert cluster_render_threads(_Cluster({})) == 1
    monkeypatch.setenv("DIFFLAB_THREADS", "3")
    assert cluster_render_threads(cluster) == 3
    monkeypatch.setenv("DIFFLAB_THREADS", "many")
    with pytest.raises(DifflabError, match="DIFFLAB_THREADS"):
        cluster_render_threads(cluster)


@pytest.mark.parametrize("seconds_per_job, remaining, slots, size", [
    (None, 100, 2, 1),  # nothing measured yet: one job a task
    (0.025, 100, 2, 20),  # 0.5 s of 25 ms fits
    (0.025, 10, 2, 3),  # the tail: ceil(10 / (2 threads x 2 tasks))
    (0.025, 1, 8, 1),
    (2.0, 100, 2, 1),  # fits longer than a task's aim: one a task
    (0.0, 9, 1, 5),  # instant fits: the equal share of the remaining ones
])
def test_task_size_fills_task_seconds_and_shrinks_at_the_tail(seconds_per_job, remaining, slots, size):
    assert TASK_SECONDS == 0.5
    assert task_size(seconds_per_job, remaining, slots) == size


def _kill_a_busy_worker(client, killed: list) -> None:
    """Wait until a worker is running a task, then SIGKILL its process (the nanny starts a new one)."""
    pids = client.run(os.getpid)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        busy = [worker for worker, keys in client.processing().items() if keys]
        if busy:
            os.kill(pids[busy[0]], signal.SIGKILL)
            killed.append(pids[busy[0]])
            return
        time.sleep(0.01)


def test_dask_cluster_with_a_worker_killed_gives_the_same_files(reference, tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed")
    monkeypatch.delenv("DIFFLAB_THREADS", raising=False)
    manifest, out, _ = reference
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client:
        assert cluster_render_threads(client) == max(1, (os.cpu_count() or 1) // 2)  # as the local pool of 2
        killed = []
        killer = threading.Thread(target=_kill_a_busy_worker, args=(client, killed))
        killer.start()
        summary = fit_many(manifest, tmp_path / "paths", client=client, quiet=True)
        killer.join()
        assert killed and killed[0] not in client.run(os.getpid).values()
        assert summary.ran == 12 and snapshot(tmp_path / "paths") == snapshot(out)
        if platform.libc_ver()[0] == "glibc":  # the workers' mmap threshold was freed of Dask's fixed one
            assert all(client.run(adaptive_allocator).values())
        client.wait_for_workers(2)  # the killed worker's replacement
        monkeypatch.setattr(runners, "TASK_SECONDS", 60.0)  # so that the tasks' sizes depend on no timing
        with distributed.get_task_stream(client) as tasks:
            fit_many(manifest, tmp_path / "bytes", client=client, inline=True, quiet=True)
        assert snapshot(tmp_path / "bytes") == snapshot(out)
        assert len(tasks.data) == 10  # 12 jobs: 4 of one job (2 threads x 2), then 2, 2, 1, 1, 1, 1 (task_size)


@pytest.mark.parametrize("rows, code", [
    ([{"status": "converged", "model_mismatch": False, "noise_unknown": False}], 0),
    ([{"status": "converged", "model_mismatch": False, "noise_unknown": True}], 5),
    ([{"status": "converged", "model_mismatch": True, "noise_unknown": True}], 4),
    ([{"status": "converged", "model_mismatch": False, "noise_unknown": True}, {"status": "failed"}], 3),
])
def test_batch_exit_code_orders_the_outcomes(monkeypatch, tmp_path, rows, code):
    """fit-batch exits 3 for any line that gave no converged fit, else 4 for a mismatch, else 5 for a
    fit whose noise could not be estimated, else 0 (docs/cli.md)."""
    import difflab.batch.api as api
    from difflab.batch.api import BatchSummary
    from difflab.cli import main

    rows = [{"name": f"f{i}", "model_mismatch": None, "noise_unknown": None, **row} for i, row in enumerate(rows)]
    summary = BatchSummary(outdir=tmp_path, rows=rows, counts={}, ran=len(rows), skipped=0)
    monkeypatch.setattr(api, "fit_many", lambda *args, **kwargs: summary)
    assert main(["fit-batch", str(tmp_path / "m.jsonl"), "-o", str(tmp_path / "out")]) == code

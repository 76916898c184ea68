"""The local worker processes of a batch (docs/batch.md): Ctrl-C while they start stops them at once;
a script that calls fit_many without the main guard is told so.

Ctrl-C: the terminal's Ctrl-C goes to the whole process group, so the test sends SIGINT to the group of a
`difflab fit-batch` run in its own session, as soon as its workers exist and ignore SIGINT (the pool
stops them, not Ctrl-C) -- while they still import, before any fit -- and checks exit 130, one line
on stderr, no worker left and no file begun. Its fits would never end (adam, 10^9 steps, tolerances
0), so a batch that waited for its running jobs (as it did: 5-12 s at start-up, the workers importing
JAX) would not exit at all. Linux only: it reads the workers from /proc.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_fit_helpers import scene_dict

from difflab import render_frame
from difflab.io import save_image
from difflab.scene import Scene, save_scene

LINUX = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads processes from /proc (Linux)")

WORKERS = 2
CLI = "import sys; from difflab.cli import main; sys.exit(main(sys.argv[1:]))"
SIGINT_BIT = 1 << (signal.SIGINT - 1)  # in /proc/PID/status's SigIgn mask


def _status(pid: int) -> dict:
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return {}
    return dict(line.split(":\t", 1) for line in lines if ":\t" in line)


def _workers(parent: int) -> list[int]:
    """The spawned worker processes of `parent` (pool workers, not multiprocessing's resource tracker)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and _status(int(entry.name)).get("PPid", "").strip() == str(parent):
            try:
                if b"spawn_main" in (entry / "cmdline").read_bytes():
                    pids.append(int(entry.name))
            except OSError:
                pass
    return pids


def _running(pid: int) -> bool:
    state = _status(pid).get("State", "")
    return bool(state) and not state.startswith("Z")


def _inputs(folder: Path) -> None:
    """scene.json (kd 0.8) and the target t.npy (kd 0.3, 0.6, 0.2), 8x8."""
    save_scene(Scene.from_dict(scene_dict(size=8)), folder / "scene.json")
    truth = scene_dict(size=8)
    truth["materials"]["red"]["kd"] = [0.3, 0.6, 0.2]
    save_image(folder / "t.npy", render_frame(Scene.from_dict(truth)).image)


def _env() -> dict:
    """This environment with this tree first on the path."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parents[1]), os.environ.get("PYTHONPATH", "")])}


@LINUX
def test_ctrl_c_while_the_workers_start_stops_them_at_once(tmp_path):
    _inputs(tmp_path)
    endless = {"solver": "adam", "max_steps": 10**9, "rtol": 0.0, "atol": 0.0, "learning_rate": 1e-6}
    manifest = tmp_path / "m.jsonl"
    manifest.write_text("".join(json.dumps({"name": f"f{i}", "scene": "scene.json", "targets": "t.npy", "material": "red",
                                            "params": "kd", "solver": endless}) + "\n" for i in range(4)))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", CLI, "fit-batch", str(manifest), "-o", str(out), "--workers",
                             str(WORKERS), "--no-progress"], env=_env(), stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not (len(workers := _workers(proc.pid)) == WORKERS
                   and all(int(_status(pid).get("SigIgn", "0"), 16) & SIGINT_BIT for pid in workers)):
            assert proc.poll() is None and time.monotonic() < deadline, "the workers did not start"
            time.sleep(0.01)
        sent = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)  # the terminal's Ctrl-C: the whole group
        _, err = proc.communicate(timeout=30)
        waited = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert (proc.returncode, err) == (130, "difflab: interrupted\n")  # no worker's traceback
    assert waited < 5.0  # a generous bound for a shared machine: ~0.1 s measured
    assert not [pid for pid in workers if _running(pid)]
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        "failures", "reports", "scenes", "timing"]  # no temporary, no result begun


UNGUARDED_SCRIPT = """
import difflab
job = {"name": "kd", "scene": "scene.json", "targets": "t.npy", "material": "red", "params": "kd"}
try:
    difflab.fit_many([job], "out", workers=2, quiet=True)
except difflab.DifflabError as exc:
    print(exc)
"""


def test_a_script_calling_fit_many_without_the_main_guard_is_told_so(tmp_path):
    """The script's top level runs again in each worker (spawn imports the main script), which cannot
    start processes: every job, valid or not, was recorded "worker process lost: BrokenProcessPool".
    Now fit_many raises one DifflabError naming the fix in the script's process, and records nothing."""
    _inputs(tmp_path)
    script = tmp_path / "batch.py"
    script.write_text(UNGUARDED_SCRIPT)
    run = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=_env(), capture_output=True, text=True,
                         timeout=120)
    assert (run.returncode, run.stderr) == (0, "")
    assert run.stdout == (f"fit_many: the worker processes start by importing {script}, and its top level calls "
                          "fit_many again; put the call under 'if __name__ == \"__main__\":' (docs/batch.md). No fit "
                          "was run\n")
    assert [p.name for p in (tmp_path / "out").rglob("*") if p.is_file()] == []

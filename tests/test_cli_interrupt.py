"""Ctrl-C on the command line is never lost (docs/cli.md, exit 130): the `difflab` console command run
as a subprocess, a SIGINT sent at a few points -- during the package's imports, during the fit's
imports, inside a gc callback (where JAX's `_xla_gc_callback` swallowed the KeyboardInterrupt: the
fit then finished, wrote both files and exited 0), during the solve -- must each give exit 130, the
one line `difflab: interrupted` on stderr and no file written."""

import argparse
import functools
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from test_fit_helpers import TRUTH, make_scene, perturbed, target_of

from difflab import Scene, cli
from difflab.errors import EXIT_INTERRUPTED, DifflabError
from difflab.io import save_image
from difflab.scene import save_scene

ROOT = Path(__file__).resolve().parents[1]

#: The child: the console command's entry point (pyproject's [project.scripts]), with an import hook
#: that prints `at NAME` to stdout when module NAME (argv[1]) starts importing and then waits
#: (argv[2] seconds), so the parent can send SIGINT at that point; with argv[2] == "gc", the next
#: garbage collection after NAME is imported raises SIGINT inside its callback instead (a Python
#: handler runs at the callback's next call, so its KeyboardInterrupt is swallowed by the gc).
CHILD = r"""
import gc, signal, sys, time
import difflab_cli

name, how = sys.argv[1], sys.argv[2]
del sys.argv[1:3]

class Marker:
    def find_spec(self, fullname, path=None, target=None):
        if fullname == name:
            sys.meta_path.remove(self)
            if how == "gc":
                gc.callbacks.append(interrupt_in_gc)
            else:
                print("at", name, flush=True)
                time.sleep(float(how))
        return None

def interrupt_in_gc(phase, info):
    if phase == "start" and name in sys.modules:
        gc.callbacks.remove(interrupt_in_gc)
        signal.raise_signal(signal.SIGINT)
        len([])  # a call: the handler runs here, inside the callback

sys.meta_path.insert(0, Marker())
sys.exit(difflab_cli.main())
"""


@pytest.fixture(scope="module")
def fit_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("interrupt")
    truth = make_scene(size=24)
    save_image(folder / "target.npy", target_of(truth))
    start = {**truth.to_dict()}
    start["materials"]["red"] = {**start["materials"]["red"], **perturbed(TRUTH)}
    save_scene(Scene.from_dict(start), folder / "scene.json")
    return folder


def _run(folder, module, how):
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    argv = [sys.executable, "-c", CHILD, module, how, "fit", "scene.json", "target.npy", "--material", "red",
            "-o", "out.json", "--solver", "adam", "--max-steps", "100000"]
    proc = subprocess.Popen(argv, cwd=folder, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if how != "gc":
        assert proc.stdout.readline() == f"at {module}\n"
        proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=300)
    return proc.returncode, out, err


@pytest.mark.parametrize("module, how", [
    ("difflab.scene", "1"),  # the package's own imports, before difflab.cli's main runs
    ("jax", "1"),  # the fit's imports (JAX's gc callback is installed as it loads)
    ("optimistix", "gc"),  # swallowed inside a gc callback, as JAX's did
    ("optimistix", "0"),  # the fit under way: its solvers imported, tracing and compiling
])
def test_sigint_exits_130_with_one_line_and_writes_nothing(fit_files, module, how):
    rc, out, err = _run(fit_files, module, how)
    assert (rc, err) == (130, "difflab: interrupted\n"), (rc, err[-2000:], out[-500:])
    assert not (fit_files / "out.json").exists() and not (fit_files / "out.fit.json").exists()
    assert sorted(p.name for p in fit_files.iterdir()) == ["scene.json", "target.npy"]


def test_the_same_fit_uninterrupted_writes_both_files(fit_files, tmp_path):
    """The control: the child's hook alone changes nothing (the fit runs, 8 adam steps: not converged,
    exit 3, both files written)."""
    for name in ("scene.json", "target.npy"):
        (tmp_path / name).write_bytes((fit_files / name).read_bytes())
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    run = subprocess.run([sys.executable, "-c", CHILD, "optimistix", "0", "fit", "scene.json", "target.npy",
                          "--material", "red", "-o", "out.json", "--solver", "adam", "--max-steps", "8"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert run.stdout.startswith("at optimistix\n") and run.returncode == 3, run.stderr[-2000:]
    assert json.loads((tmp_path / "out.fit.json").read_text())["steps"] == 8 and (tmp_path / "out.json").exists()


def _main_running(monkeypatch, command):
    """`cli.main` running `command()` as its subcommand (a parser of its own in place of difflab's)."""
    parser = argparse.ArgumentParser()
    parser.set_defaults(func=lambda args: command())
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    return cli.main([])


def _sigint_main_thread(after_s=0.0):
    """A SIGINT to the main thread, as a Ctrl-C (now, or from a timer thread after `after_s`)."""
    send = functools.partial(signal.pthread_kill, threading.main_thread().ident, signal.SIGINT)
    if not after_s:
        send()
        return len([])  # a call: the handler runs here
    threading.Timer(after_s, send).start()


def test_a_second_ctrl_c_breaks_a_blocking_cleanup(monkeypatch, capsys):
    """The first Ctrl-C's KeyboardInterrupt runs a cleanup that blocks (closing a Dask client whose
    workers hang): the user's second Ctrl-C breaks it -- the repeats of the first are let go while it
    unwinds, a new one is not. Before, every SIGINT was ignored while the first was being handled:
    the cleanup ran its full 30 s and the command ended only then."""
    cleanup = []

    def command():
        try:
            _sigint_main_thread()
        finally:
            _sigint_main_thread(after_s=0.3)  # the second Ctrl-C, while the cleanup blocks
            cleanup.append("blocked")
            threading.Event().wait(30)
            cleanup.append("finished")

    assert _main_running(monkeypatch, command) == EXIT_INTERRUPTED
    assert cleanup == ["blocked"] and capsys.readouterr().err == "difflab: interrupted\n"


@pytest.mark.parametrize("error", [RuntimeError, DifflabError, MemoryError])
def test_a_ctrl_c_a_library_turned_into_another_error_exits_130(monkeypatch, capsys, error):
    """A library that catches the KeyboardInterrupt and raises its own error (an internal error, or
    one difflab reports as invalid input: a reader's failure turned into MeshError) -- the command was
    interrupted all the same: exit 130 and the one line, no traceback. Before: exit 1 with the
    traceback, or 2 with the error's line."""

    def command():
        try:
            _sigint_main_thread()
        except KeyboardInterrupt:
            raise error("cancelled") from None

    assert _main_running(monkeypatch, command) == EXIT_INTERRUPTED
    assert capsys.readouterr().err == "difflab: interrupted\n"

"""Start-up behaviour of the renderers: quiet on a CPU-only machine, a notice while Warp compiles."""

import subprocess
import sys
import time
from types import SimpleNamespace

from difflab.renderers import launch

SCENE = ('{"camera": {"eye": [0, 0, 4], "target": [0, 0, 0], "width": 16, "height": 12}, '
         '"lights": [{"type": "point", "position": [3, 3, 3]}], "materials": {"m": {}}, '
         '"objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "m"}]}')


def test_a_cpu_render_says_nothing_about_cuda(tmp_path):
    """Warp's "no CUDA driver" start-up line is noise when the CPU was asked for: it is dropped."""
    scene = tmp_path / "scene.json"
    scene.write_text(SCENE)
    done = subprocess.run([sys.executable, "-m", "difflab.cli", "render", str(scene), "-o", str(tmp_path / "out.png")],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert launch.CUDA_DRIVER_MISSING not in done.stderr
    assert (tmp_path / "out.png").stat().st_size > 0


def loaded_after(code):
    """The heavy packages (Warp, JAX, optimistix) that a fresh interpreter running `code` has imported."""
    probe = code + "\nimport sys; print(sorted(m for m in ('warp', 'jax', 'optimistix') if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()[-1]


def test_import_difflab_loads_neither_warp_nor_jax():
    """`import difflab` and the scene API stay light; the lazy names load their renderer on first use."""
    assert loaded_after("import difflab; difflab.Scene, difflab.load_scene, difflab.fit_many") == "[]"
    assert loaded_after("import difflab; difflab.render") == "['warp']"


def test_help_loads_neither_warp_nor_jax():
    """`difflab --help` (every subcommand's parser) builds without importing a renderer or the fitter."""
    code = ("import sys, contextlib, io\nfrom difflab import cli\nsys.argv = ['difflab', '--help']\n"
            "with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()): cli.main()")
    assert loaded_after(code) == "[]"


def fake_kernel(name):
    return SimpleNamespace(module=SimpleNamespace(name=name))


def test_a_slow_kernel_load_is_announced_once(monkeypatch, capsys):
    """A module load longer than COMPILE_NOTICE_SECONDS (Warp compiling) prints one line on stderr,
    once per process; a fast load (from Warp's cache) prints nothing."""
    delays = {"slow_a": 0.5, "slow_b": 0.5, "fast": 0.0}
    monkeypatch.setattr(launch.wp, "load_module", lambda module, device: time.sleep(delays[module.name]))
    monkeypatch.setattr(launch, "COMPILE_NOTICE_SECONDS", 0.1)
    monkeypatch.setattr(launch, "_noticed", False)
    monkeypatch.setattr(launch, "_loaded", set())
    launch.load_kernels("cpu", fake_kernel("fast"))
    assert capsys.readouterr().err == ""
    launch.load_kernels("cpu", fake_kernel("slow_a"))
    launch.load_kernels("cpu", fake_kernel("slow_b"), fake_kernel("slow_a"))  # slow_a is loaded already
    assert capsys.readouterr().err.count("difflab: compiling Warp kernels") == 1
    assert launch._loaded == {("fast", "cpu"), ("slow_a", "cpu"), ("slow_b", "cpu")}

"""Execute the tutorial notebooks and store their outputs, so a reader sees the figures on the repository.

    python experiments/notebooks/run_all.py          # every notebook, full size, outputs written back
    python experiments/notebooks/run_all.py 03 07    # only the notebooks whose names start with 03 or 07

Each notebook reads `DIFFLAB_NOTEBOOK_SCALE` (default 1) and multiplies its image sizes by it;
`tests/test_notebooks.py` executes them at a small scale and writes nothing back. Outputs are written
atomically, without timing metadata, so a re-run changes only what the code changed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

from difflab.io import write_text_atomic

HERE = Path(__file__).resolve().parent
#: Largest notebook we store (bytes): figures are PNGs at a modest dpi.
MAX_BYTES = 2_000_000


def execute(path: Path, scale: float | None = None, timeout: int = 900) -> nbformat.NotebookNode:
    """The notebook at `path`, executed top to bottom in a fresh kernel in its own folder.
    `scale` sets DIFFLAB_NOTEBOOK_SCALE for the kernel (None: the notebook's default, full size)."""
    notebook = nbformat.read(path, as_version=4)
    env = dict(os.environ)
    env.pop("MPLBACKEND", None)  # the inline backend, so that figures become outputs
    if scale is not None:
        env["DIFFLAB_NOTEBOOK_SCALE"] = str(scale)
    client = NotebookClient(notebook, timeout=timeout, kernel_name="python3", record_timing=False,
                            resources={"metadata": {"path": str(path.parent)}})
    client.execute(env=env)
    return notebook


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("prefixes", nargs="*", help="run only notebooks whose file name starts with one of these")
    args = parser.parse_args(argv)
    paths = [p for p in sorted(HERE.glob("*.ipynb")) if not args.prefixes or p.name.startswith(tuple(args.prefixes))]
    for path in paths:
        start = time.perf_counter()
        notebook = execute(path)
        text = nbformat.writes(notebook) + "\n"
        write_text_atomic(path, text)
        size = len(text.encode())
        noisy = [i for i, cell in enumerate(notebook.cells) if cell.cell_type == "code"
                 and any(o.output_type == "stream" and o.name == "stderr" for o in cell.outputs)]
        print(f"{path.name}: {time.perf_counter() - start:.0f} s, {size / 1e6:.2f} MB"
              + ("  (over the 2 MB budget)" if size > MAX_BYTES else "")
              + (f"  (stderr stored in cells {noisy}, e.g. a first-run compile notice: run it again)" if noisy else ""),
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

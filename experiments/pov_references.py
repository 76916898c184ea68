"""POV-Ray references the ray tracer's tests compare against (tests/data/pov): every NAME.pov there,
POV-Ray's reading of NAME.scene.json, is rendered at that scene camera's size (no anti-aliasing) to a
float EXR and saved as NAME.npy (linear RGB, POV-Ray's half floats), so that the tests need no POV-Ray.
Needs povray 3.7 and Mitsuba (to read the EXR).

    python experiments/pov_references.py
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from foreign_render import read_exr, render_pov

DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "pov"


def main() -> None:
    for pov in sorted(DATA.glob("*.pov")):
        camera = json.loads(pov.with_suffix(".scene.json").read_text())["camera"]
        with tempfile.TemporaryDirectory() as folder:
            exr = Path(folder) / f"{pov.stem}.exr"
            render_pov(pov.read_text(), exr, camera["width"], camera["height"], "exr")
            image = read_exr(exr)
        np.save(DATA / f"{pov.stem}.npy", image.astype(np.float32))
        print(f"{pov.stem}: {image.shape[1]} x {image.shape[0]}, mean {image.mean():.4f}")


if __name__ == "__main__":
    main()

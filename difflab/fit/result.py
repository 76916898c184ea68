"""`FitResult`: what a fit returns -- values in scene units, their uncertainty, and how it went."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np


def _json_number(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _json(value):
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_json(v) for v in np.asarray(value, np.float64).reshape(-1)]
    return _json_number(value)


@dataclass(frozen=True)
class FitResult:
    """The outcome of `fit_material`. Failure is a value: read `converged` and `result`.

    params: name -> fitted value in scene units (RGB lists for ka / kd / ks / light intensities,
        floats for n, m, f0); names are "kd", ..., or "<material>.kd" when several materials were
        fitted, and "lights[i].intensity".
    stderr: name -> standard error (same shapes; inf where the data do not determine it; nan when
        no fit was made).
    loss: the solvers' objective 0.5 sum r^2 at the solution, summed over the channels of the pixels
        used (for the l2 loss: half the weighted sum of squared errors).
    psnr: 10 log10(1 / MSE) of the fit over the pixels used (dB, peak 1): those in the masks that
        show a fitted material.
    steps: solver steps. seconds: wall time of the solve (compilation included on a first call).
    converged: the solver reported success and every value is finite.
    result: the result code as a string: optimistix's ("successful", "nonlinear_max_steps_reached",
        "nonlinear_divergence", "nonfinite", ...) or difflab's ("empty_mask": no pixel of the fitted
        material lies in the masks; "nonfinite_target": NaN / inf target pixels inside the masks).
    history: the loss at the point each solver step evaluated (rejected trial points included).
    poorly_determined: names whose value the images do not pin down (see `fit.stats`).
    initial: the starting values (same shapes as params). solver: the solver's name.
    timings: seconds per phase ("setup": G-buffers and arrays; "solve"; "stats").
    """

    params: dict
    stderr: dict
    loss: float
    psnr: float
    steps: int
    seconds: float
    converged: bool
    result: str
    history: list = field(default_factory=list)
    poorly_determined: list = field(default_factory=list)
    initial: dict = field(default_factory=dict)
    solver: str = "lm"
    timings: dict = field(default_factory=dict)
    scene: object = field(default=None, repr=False, compare=False)
    layout: tuple = field(default=(), repr=False, compare=False)

    def to_scene(self):
        """The scene with the fitted values written back (materials, and lights where fitted)."""
        if self.scene is None:
            raise ValueError("to_scene: this result carries no scene")
        scene = self.scene
        names = scene.material_names
        materials = dict(scene.materials)
        lights = list(scene.lights)
        for p in self.layout:
            value = self.params[p.key]
            if p.kind == "intensity":
                lights[p.index] = dataclasses.replace(lights[p.index], intensity=tuple(value))
            else:
                name = names[p.index]
                new = tuple(value) if isinstance(value, list) else float(value)
                materials[name] = dataclasses.replace(materials[name], **{p.kind: new})
        return dataclasses.replace(scene, materials=materials, lights=tuple(lights))

    def to_dict(self) -> dict:
        """A JSON-able summary (non-finite numbers become null)."""
        return {
            "params": {k: (_json(v) if isinstance(v, list) else _json_number(v)) for k, v in self.params.items()},
            "stderr": {k: (_json(v) if isinstance(v, list) else _json_number(v)) for k, v in self.stderr.items()},
            "initial": {k: (_json(v) if isinstance(v, list) else _json_number(v)) for k, v in self.initial.items()},
            "loss": _json_number(self.loss), "psnr": _json_number(self.psnr), "steps": self.steps,
            "seconds": self.seconds, "converged": self.converged, "result": self.result, "solver": self.solver,
            "poorly_determined": list(self.poorly_determined), "history": [_json_number(x) for x in self.history],
            "timings": dict(self.timings),
        }

    def table(self) -> str:
        """A plain-text table: name, value +- stderr (per channel), and a flag for poorly determined."""
        rows = [f"{'parameter':<22} {'value ± stderr':<60}"]
        for key, value in self.params.items():
            err = self.stderr.get(key)
            values = value if isinstance(value, list) else [value]
            errs = err if isinstance(err, list) else [err] * len(values)
            cells = ", ".join(f"{v:.6g} ± {e:.2g}" for v, e in zip(values, errs))
            flag = "  (poorly determined)" if key in self.poorly_determined else ""
            rows.append(f"{key:<22} {cells}{flag}")
        rows.append(f"result: {self.result}, converged: {self.converged}, steps: {self.steps}, "
                    f"loss: {self.loss:.4g}, PSNR: {self.psnr:.2f} dB, {self.seconds:.3f} s ({self.solver})")
        return "\n".join(rows)

"""Identifiability: which parameters the given views determine, before trusting a fit.

At parameter values theta (the scene's, or a fit's), with J the Jacobian of the weighted residuals
with respect to the values in scene units (one column per channel of each parameter),

    cov = sigma^2 (J^T J)^-1            standard errors = sqrt(diag cov)

for a pixel noise sigma (default: one 8-bit quantisation step, 1 / (255 sqrt 12)). Rank and
condition number are those of J^T J with its columns scaled to unit norm (so units do not count):
a rank below the number of columns means some combination of parameters leaves every pixel
unchanged -- no fit can separate them -- and a large condition number means a combination the
pixels barely see. The weakest directions (eigenvectors of the smallest eigenvalues) name the
parameters that trade off against each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import FitError
from .options import DENSE_MAX
from .params import SCENE_PARAMS
from .setup import Setup
from .stats import (QUANTISATION_SIGMA, covariance_unscaled, normal_matrix, poorly_determined, singular_rcond,
                    unit_spectrum)

CHANNELS = ("r", "g", "b")


@dataclass(frozen=True)
class Identifiability:
    """What the views determine at `values`.

    keys: parameter keys (as in `FitResult.params`); columns: one name per Jacobian column
        ("floor.kd[g]", "mirror.kr"); values, stderr: key -> (size,) arrays in scene units (stderr
        inf where a singular direction involves the parameter) at pixel noise `sigma`.
    rank, n_columns: numerical rank of the column-scaled J^T J and its size; condition: its
        condition number (inf when rank < n_columns); eigenvalues: ascending.
    weakest: the least determined directions, [(eigenvalue, [(column, component), ...])], largest
        components first.
    undetermined: keys whose standard error exceeds rel_tol |value| + abs_tol (ks and n of a
        material flagged together, as `FitResult.poorly_determined`).
    residuals: residual entries (pixel channels) used; views: number of views.
    """

    keys: tuple
    columns: tuple
    values: dict
    stderr: dict
    sigma: float
    rank: int
    n_columns: int
    condition: float
    eigenvalues: np.ndarray = field(repr=False)
    weakest: list = field(repr=False)
    undetermined: list
    residuals: int
    views: int

    @property
    def full_rank(self) -> bool:
        return self.rank == self.n_columns

    def table(self) -> str:
        """A plain-text report: a summary line, one row per parameter (value, standard error,
        relative error, verdict), and the weakest directions."""
        lines = [f"identifiability: {self.views} view(s), {self.residuals} pixel channels, pixel noise sigma "
                 f"{self.sigma:.3g}",
                 f"rank {self.rank} of {self.n_columns} columns, condition number of scaled J^T J "
                 f"{self.condition:.3g}" + ("" if self.full_rank else "  (RANK DEFICIENT: some parameters trade off "
                                                                      "exactly)"),
                 f"{'parameter':<22} {'value':>34} {'stderr':>30} {'rel. stderr':>11}  verdict"]
        for key in self.keys:
            value = np.asarray(self.values[key]).reshape(-1)
            err = np.asarray(self.stderr[key]).reshape(-1)
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = float(np.max(np.where(value != 0, err / np.abs(value), np.where(err == 0, 0.0, np.inf))))
            verdict = "UNDETERMINED" if key in self.undetermined else "ok"
            lines.append(f"{key:<22} {_cells(value, '.5g'):>34} {_cells(err, '.2g'):>30} {rel:>11.2g}  {verdict}")
        for eigenvalue, parts in self.weakest:
            combo = " ".join(f"{c:+.2f}*{name}" for name, c in parts)
            lines.append(f"weak direction (eigenvalue {eigenvalue:.2g}): {combo}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {"keys": list(self.keys), "columns": list(self.columns), "sigma": self.sigma, "rank": self.rank,
                "n_columns": self.n_columns, "condition": num(self.condition),
                "values": {k: [num(x) for x in np.asarray(v).reshape(-1)] for k, v in self.values.items()},
                "stderr": {k: [num(x) for x in np.asarray(v).reshape(-1)] for k, v in self.stderr.items()},
                "eigenvalues": [num(x) for x in self.eigenvalues],
                "weakest": [[num(e), [[n, num(c)] for n, c in parts]] for e, parts in self.weakest],
                "undetermined": list(self.undetermined), "residuals": self.residuals, "views": self.views}


def _cells(values, fmt) -> str:
    return ", ".join(format(float(x), fmt) for x in values)


def column_names(layout) -> tuple:
    names = []
    for p in layout:
        if p.shape is not None:  # texel (row, column) in texture orientation (row 0 = v 0), channel
            names.extend(f"{p.key}[{i},{j}].{c}" for i in range(p.shape[0]) for j in range(p.shape[1]) for c in CHANNELS)
            continue
        names.extend([f"{p.key}[{c}]" for c in CHANNELS] if p.size == 3 else [p.key])
    return tuple(names)


def identifiability(setup: Setup, values: dict | None = None, *, sigma=None, rel_tol=0.1, abs_tol=1e-3,
                    n_weakest=3) -> Identifiability:
    """The report for a prepared `Setup` at `values` (key -> value in scene units; default: its start)."""
    layout = setup.layout
    if layout.size > DENSE_MAX:
        raise FitError(f"params: identify forms the dense {layout.size} x {layout.size} Gram matrix; at most "
                       f"{DENSE_MAX} entries (a smaller texture, or fewer params)")
    values = {k: np.asarray(v, np.float64).reshape(-1) for k, v in (values or setup.initial).items()}
    sigma = QUANTISATION_SIGMA if sigma is None else float(sigma)
    with jax.enable_x64(setup.x64), setup.on_device():
        gram, r = normal_matrix(setup.problem, jnp.asarray(layout.flatten(values), setup.dtype))
    rcond = singular_rcond(setup.x64)
    eigval, eigvec, _, _, singular = unit_spectrum(gram, rcond=rcond)  # a zero column (a parameter no pixel sees) is singular
    top = max(float(eigval.max(initial=0.0)), 1e-300)
    rank = int(np.count_nonzero(~singular))
    n = gram.shape[0]
    condition = float(top / eigval.min()) if rank == n and n and eigval.min() > 0 else math.inf
    cov = covariance_unscaled(gram, rcond=rcond)
    diag = np.diag(cov)
    stderr, offset = {}, 0
    for p in layout:
        block = diag[offset:offset + p.size]
        stderr[p.key] = np.where(np.isfinite(block), np.sqrt(np.where(np.isfinite(block), block, 0.0)) * sigma, np.inf)
        offset += p.size
    names = column_names(layout)
    weakest = []
    for i in range(min(n_weakest, n)):
        vec = eigvec[:, i]
        order = np.argsort(-np.abs(vec))
        parts = [(names[j], float(vec[j])) for j in order[:4] if abs(vec[j]) > 0.05]
        weakest.append((float(eigval[i]), parts))
    flagged = poorly_determined(layout, layout.flatten(values), layout.flatten(stderr), rel_tol, abs_tol)
    return Identifiability(keys=tuple(p.key for p in layout), columns=names, values=values, stderr=stderr,
                           sigma=sigma, rank=rank, n_columns=n, condition=condition, eigenvalues=eigval,
                           weakest=weakest, undetermined=flagged, residuals=sum(part.size for part in r),
                           views=len(setup.views))


def identify(scene, targets, materials=None, params=SCENE_PARAMS, *, method="raytrace", values=None, sigma=None,
             rel_tol=0.1, abs_tol=1e-3, per_channel=True, masks=None, weights=None, max_depth=None, spp=None,
             x64=True, device="cpu", threads=None) -> Identifiability:
    """Which of `params` the views in `targets` determine, at the scene's values (or `values`).

    Only the targets' sizes and per-view overrides (and masks / weights) matter, not their pixels:
    the report is about the views, not the data. Read it before trusting a `fit_scene`.

    Arguments:
        scene, targets, materials, params, method, per_channel, masks, weights, max_depth, spp, x64,
            device, threads: as `fit_scene` (the ray trees are recorded at the scene's values).
        values: key -> value (scene units) to evaluate at, e.g. a `FitResult.params`; default the scene's.
        sigma: pixel noise standard deviation (linear units); default one 8-bit quantisation step.
        rel_tol, abs_tol: a parameter is undetermined when stderr > rel_tol |value| + abs_tol.
    Returns:
        an `Identifiability`; print its `table()`.
    """
    setup = Setup(scene, targets, materials, params, method=method, per_channel=per_channel, masks=masks,
                  weights=weights, x64=x64, max_depth=max_depth, spp=spp, device=device, threads=threads)
    given = None
    if values is not None:
        given = {p.key: np.broadcast_to(np.asarray(values[p.key], np.float64).reshape(-1), (p.size,))
                 if p.key in values else setup.initial[p.key] for p in setup.layout}
    return identifiability(setup, given, sigma=sigma, rel_tol=rel_tol, abs_tol=abs_tol)

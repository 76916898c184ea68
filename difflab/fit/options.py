"""How a fit is solved and reported: one value object, `FitOptions` (no JAX here: the command line
reads the solver names without importing it)."""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, fields

from ..errors import FitError

SOLVERS = ("lm", "gauss_newton", "dogleg", "bfgs", "adam", "varpro")
LINEAR_SOLVERS = ("auto", "dense", "cg")
DENSE_MAX = 256  # "auto": the most fitted entries solved with a dense Jacobian (more: matrix-free CG)
DEFAULT_TOL = {True: (1e-8, 1e-10), False: (1e-5, 1e-7)}  # (rtol, atol) by x64


@dataclass(frozen=True)
class FitOptions:
    """How a fit is solved and reported (every field has a default).

    solver: one of SOLVERS. max_steps: the most solver steps. rtol, atol: stopping tolerances
    (default by precision: 1e-8 / 1e-10 in float64, 1e-5 / 1e-7 in float32). learning_rate: Adam's.
    x64: compute in float64 (else float32). history: record the loss per step. progress: show a
    progress bar (None: only when stderr is a terminal). throw: raise FitError for a failed fit
    instead of returning it. rel_tol, abs_tol: a parameter is poorly determined when its standard
    error at the noise floor exceeds rel_tol |value| + abs_tol. linear_solver: how the
    least-squares solvers ("lm", "gauss_newton", "dogleg") solve each step's normal equations:
    "dense" (the Jacobian formed, a Cholesky solve), "cg" (matrix-free conjugate gradients on
    J^T J, J v and J^T v by autodiff: for a texture's many texels), "auto" ("cg" above DENSE_MAX
    fitted entries); cg_steps: the most CG iterations per step. visible_threshold: a fitted texel
    counts as seen when the pixels used change by more than this per unit texel, summed
    (`FitResult.seen`).
    """

    solver: str = "lm"
    max_steps: int = 256
    rtol: float | None = None
    atol: float | None = None
    learning_rate: float = 0.05
    x64: bool = True
    history: bool = True
    progress: bool | None = None
    throw: bool = False
    rel_tol: float = 0.1
    abs_tol: float = 1e-3
    linear_solver: str = "auto"
    cg_steps: int = 500
    visible_threshold: float = 1e-3

    def __post_init__(self):
        if self.solver not in SOLVERS:
            raise FitError(f"solver: unknown solver {self.solver!r}; known: {', '.join(SOLVERS)}")
        if self.linear_solver not in LINEAR_SOLVERS:
            raise FitError(f"linear_solver: expected one of {', '.join(LINEAR_SOLVERS)}, got {self.linear_solver!r}")
        for name in ("max_steps", "cg_steps"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
                raise FitError(f"{name}: must be an integer >= 1, got {value!r}")
        for name in ("rtol", "atol", "learning_rate", "rel_tol", "abs_tol", "visible_threshold"):
            value = getattr(self, name)
            if value is None and name in ("rtol", "atol"):
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise FitError(f"{name}: must be a finite number >= 0, got {value!r}")
        for name in ("x64", "history", "throw"):
            if not isinstance(getattr(self, name), bool):
                raise FitError(f"{name}: must be True or False, got {getattr(self, name)!r}")
        if self.progress is not None and not isinstance(self.progress, bool):
            raise FitError(f"progress: must be True, False or None, got {self.progress!r}")

    @classmethod
    def make(cls, options=None, **overrides) -> FitOptions:
        """`options` (a FitOptions or None) with keyword fields replaced; FitError for unknown names."""
        unknown = sorted(set(overrides) - FIELD_NAMES)
        if unknown:
            raise FitError(f"unknown argument(s) {unknown}; fit options are {sorted(FIELD_NAMES)}")
        if options is not None and not isinstance(options, FitOptions):
            raise FitError(f"options: expected a FitOptions, got {type(options).__name__}")
        return cls(**{**vars(options), **overrides}) if options is not None else cls(**overrides)

    def tolerances(self) -> tuple[float, float]:
        default_rtol, default_atol = DEFAULT_TOL[self.x64]
        return (default_rtol if self.rtol is None else float(self.rtol),
                default_atol if self.atol is None else float(self.atol))

    def matrix_free(self, size: int) -> bool:
        """Whether a fit of `size` entries solves its normal equations matrix-free (CG)."""
        return self.linear_solver == "cg" or (self.linear_solver == "auto" and size > DENSE_MAX)

    def show_progress(self) -> bool:
        return sys.stderr.isatty() if self.progress is None else self.progress


# `make`'s (fields() twice a call was ~9 us of a first fit)
FIELD_NAMES = frozenset(f.name for f in fields(FitOptions))

"""diag A^-1 of a sparse symmetric positive definite A -- a connected block of a matrix-free fit's
unit-diagonal J^T J (`stats.covariance_diagonal`) -- without forming A^-1.

Entries whose rows are wide (more than WIDE nonzeros: a scalar such as ks beside a texture couples
with every texel of its channel) are split off; the others are put in reverse Cuthill-McKee order,
which gives a texture's texels a band about one texel row wide. With B the band part, C its
coupling to the w wide entries and E theirs (w x w):

    S = E - C^T B^-1 C,    diag A^-1 = [diag B^-1 + rowsum((B^-1 C) S^-1 * (B^-1 C)),  diag S^-1]

and diag B^-1 by Takahashi's recurrence on the banded Cholesky factors B = L D L^T, which forms only
the band of B^-1 (O(n b^2) for n entries, band b):

    Z_Sj = -Z_SS L_Sj,   Z_jj = 1 / D_j - L_Sj . Z_Sj        (S = j+1 .. j+b; j from n-1 down)

A band wider than BAND_MAX, or more than WIDE_MAX wide entries (a texture seen in a mirror couples
far texels): sparse LU (SuperLU, a symmetric fill-reducing order, no pivoting), one solve per unit
vector, up to LU_MAX entries (beyond: nan). A is singular -- nan -- when its smallest eigenvalue
(inverse iteration with these solves, to 1e-3 relative) is at most `rcond` times `top`, or when a
factorisation fails.

Measured (2 shared cores, load 2-3): a bilinear texture channel's block of 4096 texels takes 0.45 s
banded, 8100 0.84 s, 16384 1.5 s; by SuperLU 1.75 s at 4096 and 7 s at 8100.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import LinAlgError, cho_solve_banded, cholesky_banded
from scipy.sparse.csgraph import reverse_cuthill_mckee
from scipy.sparse.linalg import ArpackNoConvergence, LinearOperator, eigsh, splu

WIDE = 64  # a row with more nonzeros is split off (Schur complement)
WIDE_MAX = 64  # the most entries split off
BAND_MAX = 256  # the widest band solved banded
LU_MAX = 4096  # the most entries solved by SuperLU


def inverse_diagonal(unit, top: float, rcond: float) -> np.ndarray:
    """diag A^-1 (n,) of the sparse SPD `unit` (unit diagonal), nan when A is singular (module
    docstring); top: the largest eigenvalue of the J^T J that A is a block of."""
    n = unit.shape[0]
    unit = unit.tocsr()
    try:
        factors = banded(unit) or (factored(unit) if n <= LU_MAX else None)
        if factors is None:
            return np.full(n, np.nan)
        solve, diagonal = factors
        low = eigsh(unit, k=1, sigma=0.0, OPinv=LinearOperator(unit.shape, matvec=solve, dtype=np.float64),
                    which="LM", tol=1e-3, return_eigenvectors=False)[0]
    except (RuntimeError, LinAlgError, ArpackNoConvergence):  # a factor exactly singular; no convergence
        return np.full(n, np.nan)
    return diagonal() if low > rcond * top else np.full(n, np.nan)


def banded(unit):
    """(solve y -> A^-1 y, diagonal () -> diag A^-1) by the band and Schur complement, or None when
    the band is too wide or too many rows are wide."""
    n = unit.shape[0]
    degree = np.diff(unit.indptr)
    wide = np.flatnonzero(degree > WIDE)
    if wide.size > WIDE_MAX or wide.size == n:
        return None
    narrow = np.flatnonzero(degree <= WIDE)
    order = reverse_cuthill_mckee(unit[narrow][:, narrow].tocsr(), symmetric_mode=True)
    band = narrow[order]
    part = unit[band][:, band].tocoo()
    lower = part.row >= part.col
    width = int((part.row - part.col)[lower].max(initial=0))
    if width > BAND_MAX:
        return None
    ab = np.zeros((width + 1, band.size))
    ab[(part.row - part.col)[lower], part.col[lower]] = part.data[lower]
    factor = (cholesky_banded(ab, lower=True), True)
    coupling = unit[band][:, wide].toarray()  # C (m, w)
    solved = cho_solve_banded(factor, coupling)  # B^-1 C
    schur_inv = np.linalg.inv(unit[wide][:, wide].toarray() - coupling.T @ solved)  # S^-1 (w, w)

    def solve(y):
        x = np.empty(n)
        x[wide] = schur_inv @ (y[wide] - solved.T @ y[band])
        x[band] = cho_solve_banded(factor, y[band] - coupling @ x[wide])
        return x

    def diagonal():
        out = np.empty(n)
        out[band] = takahashi(factor[0]) + np.einsum("ij,jk,ik->i", solved, schur_inv, solved)
        out[wide] = np.diagonal(schur_inv)
        return out

    return solve, diagonal


def takahashi(chol: np.ndarray) -> np.ndarray:
    """diag B^-1 (m,) from B's lower banded Cholesky factor (`scipy.linalg.cholesky_banded` storage:
    chol[k, j] = C[j + k, j]), by the recurrence of the module docstring on a (b, b) window of Z."""
    b, m = chol.shape[0] - 1, chol.shape[1]
    pivot = chol[0] ** 2  # D
    below = chol[1:] / chol[0]  # L_Sj, S = j+1 .. j+b
    below[np.arange(1, b + 1)[:, None] + np.arange(m) >= m] = 0.0  # (past the end: not referenced by LAPACK)
    window, out = np.zeros((b, b)), np.empty(m)
    for j in range(m - 1, -1, -1):
        l = below[:, j]
        z = -(window @ l)
        out[j] = 1.0 / pivot[j] - l @ z
        if b:
            nxt = np.empty((b, b))
            nxt[0, 0], nxt[0, 1:], nxt[1:, 0], nxt[1:, 1:] = out[j], z[:-1], z[:-1], window[:-1, :-1]
            window = nxt
    return out


def factored(unit):
    """(solve, diagonal) by SuperLU (module docstring)."""
    lu = splu(unit.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})

    def diagonal():
        out, unit_vector = np.empty(unit.shape[0]), np.zeros(unit.shape[0])
        for i in range(out.size):
            unit_vector[i] = 1.0
            out[i] = lu.solve(unit_vector)[i]
            unit_vector[i] = 0.0
        return out

    return lu.solve, diagonal

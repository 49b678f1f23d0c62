"""Step (b) of the smoother's data association, fast: Levenberg–Marquardt whose linear step eliminates the map first.

The smoother's normal equations :math:`(A + \\mu D)\\,\\delta = -g` over the keyframe poses :math:`p` and the
landmarks :math:`l` have a pose block :math:`A_{pp}` that is *block tridiagonal* (odometry ties each keyframe to the
next; the prior sits on the first) and a border :math:`A_{pl}` (sightings tie poses to landmarks). With the
landmarks' Schur complement

.. math::

    S = A_{ll} - A_{pl}^\\top A_{pp}^{-1} A_{pl}, \\qquad
    S\\,\\delta_l = -g_l + A_{pl}^\\top A_{pp}^{-1} g_p, \\qquad A_{pp}\\,\\delta_p = -g_p - A_{pl}\\,\\delta_l,

:math:`A_{pp} = U^\\top U` is factored once by a banded Cholesky (bandwidth 5: two 3 × 3 blocks), and one
triangular solve with :math:`U^\\top` on :math:`1 + 2L` right-hand sides gives all of it,

.. math::

    W = U^{-\\top} A_{pl}, \\quad y = U^{-\\top} g_p: \\qquad S = A_{ll} - W^\\top W, \\quad
    S\\,\\delta_l = -g_l + W^\\top y, \\quad \\delta_p = -U^{-1} (y + W \\delta_l),

since :math:`A_{pl}^\\top A_{pp}^{-1} A_{pl} = W^\\top W`. :math:`S` is a small dense (2L, 2L) matrix: linear in the
number of keyframes, where a general sparse LU of the whole matrix fills the landmarks' rows. The association solves
the problem many times (every round of every start), so this step sets its time. Same steps, same stopping rule
and same Huber weights as :func:`fastslam_edu.landmark.smoother.levenberg_marquardt` (its signature: usable as
``solve_with_gate``'s ``minimise``); a problem with calibration columns, or a pose block that is not banded, goes to
that function.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import scipy.sparse as sp
from scipy.linalg import LinAlgError, cholesky_banded
from scipy.linalg.lapack import dtbtrs

from fastslam_edu.landmark.smoother import levenberg_marquardt

#: Upper bandwidth of the pose block: keyframe k's 3 variables meet keyframe k+1's (one 3 × 3 block off the diagonal).
POSE_BANDWIDTH = 5


def banded_upper(A_pp: sp.spmatrix, u: int = POSE_BANDWIDTH) -> np.ndarray | None:
    """The upper band of the symmetric ``A_pp`` (P, P) in LAPACK's layout ``ab[u + i - j, j] = A[i, j]`` (u+1, P), or
    None when an entry lies outside the band."""
    C = A_pp.tocoo()
    off = C.col - C.row
    if np.any(np.abs(off) > u):
        return None
    up = off >= 0
    P = A_pp.shape[0]
    flat = np.bincount((u - off[up]) * P + C.col[up], weights=C.data[up], minlength=(u + 1) * P)
    return flat.reshape(u + 1, P)


def schur_step(A: sp.spmatrix, g: np.ndarray, n_pose_vars: int) -> np.ndarray | None:
    """:math:`\\delta = -A^{-1} g` by the landmarks' Schur complement (module docstring); ``A`` (V, V) symmetric
    positive definite, its first ``n_pose_vars`` variables the poses. None when the pose block is not banded or not
    positive definite (the caller then uses a general solver)."""
    A = A.tocsc()
    P = n_pose_vars
    ab = banded_upper(A[:P, :P])
    if ab is None:
        return None
    try:
        factor = cholesky_banded(ab)
    except LinAlgError:
        return None
    A_pl = A[:P, P:]  # sparse: a landmark meets only the poses that see it
    B = np.empty((P, 1 + A_pl.shape[1]), order="F")
    B[:, 0], B[:, 1:] = g[:P], A_pl.toarray()
    Y, _ = dtbtrs(factor, B, uplo="U", trans="T", overwrite_b=1)  # U^-T [g_p, A_pl]
    y, W = Y[:, 0], Y[:, 1:]
    S = A[P:, P:].toarray() - W.T @ W
    d_l = np.linalg.solve(S, -(g[P:] - W.T @ y)) if S.shape[0] else np.zeros(0)
    d_p, _ = dtbtrs(factor, y + W @ d_l, uplo="U")  # U^-1 (y + W d_l)
    return np.concatenate([-d_p, d_l])


def levenberg_marquardt_schur(problem, v, active, *, huber, max_iterations, tol):
    """:func:`fastslam_edu.landmark.smoother.levenberg_marquardt` with :func:`schur_step` for the damped step
    :math:`(A + \\mu\\,\\mathrm{diag} A)\\,\\delta = -g`; returns ``(v, iterations, cost)``."""
    if problem.n_extra:
        return levenberg_marquardt(problem, v, active, huber=huber, max_iterations=max_iterations, tol=tol)
    return levenberg_marquardt(problem, v, active, huber=huber, max_iterations=max_iterations, tol=tol,
                               damped_step=partial(schur_step, n_pose_vars=3 * problem.n_poses))


__all__ = ["POSE_BANDWIDTH", "banded_upper", "schur_step", "levenberg_marquardt_schur"]

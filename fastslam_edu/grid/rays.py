"""Casting a laser beam on a grid: the cells it crosses, from the sensor cell to its endpoint cell.

A beam from the sensor cell to its endpoint cell is the 8-connected digital line of :func:`bresenham` (the classic
integer algorithm, a readable loop); :func:`ray_cells` casts a whole scan at once with a closed form that gives
exactly the same cells (the test suite checks this on thousands of rays), and :func:`ray_cells_batch` casts the
scans of many particles at once. Cells are ``(row, col)`` of :class:`fastslam_edu.grid.occupancy.OccupancyGrid`:
the row comes from y, the column from x.
"""

from __future__ import annotations

import numpy as np

__all__ = ["bresenham", "ray_cells", "ray_cells_batch", "int_cells"]


def int_cells(name: str, cells, caller: str) -> np.ndarray:
    """Integer cell indices ``(..., 2)``; refuses non-integer or non-finite values."""
    a = np.asarray(cells)
    if a.ndim == 0 or a.shape[-1] != 2:
        raise ValueError(f"{caller}: {name} must have shape (..., 2) (row, col), got shape {a.shape}")
    if a.dtype.kind in "iu":
        return a.astype(np.int64)
    a = np.asarray(a, dtype=float)
    if not np.isfinite(a).all() or (a != np.round(a)).any():
        raise ValueError(f"{caller}: {name} must hold integer cell indices (row, col)")
    return a.astype(np.int64)


def bresenham(r0: int, c0: int, r1: int, c1: int) -> np.ndarray:
    """Cells of the digital line from cell ``(r0, c0)`` to ``(r1, c1)`` (both included).

    The classic integer algorithm (Bresenham 1965): walk one cell at a time
    along the *major* axis (the one with the larger difference ``n``), and
    step the *minor* axis when the error term says the true line is more than
    half a cell away. With ``m`` the minor difference, the decision variable
    ``D = 2m − n`` is updated by ``+2m`` every step and ``−2n`` when the minor
    coordinate steps; it steps when ``D > 0``, so the minor coordinate at step
    ``i`` is the true line's ``i m / n`` rounded to the nearest integer, ties
    (exactly half-way) rounded back towards the start.

    Parameters
    ----------
    r0, c0, r1, c1 : int
        Start and end cells.

    Returns
    -------
    ndarray of int64, shape (n + 1, 2)
        Rows ``(row, col)`` from start to end, ``n = max(|r1 − r0|, |c1 − c0|)``.
    """
    r0, c0, r1, c1 = (int(v) for v in (r0, c0, r1, c1))
    dr, dc = abs(r1 - r0), abs(c1 - c0)
    sr = 1 if r1 >= r0 else -1
    sc = 1 if c1 >= c0 else -1
    steep = dr > dc  # major axis: rows if steep, else columns
    n, m = (dr, dc) if steep else (dc, dr)
    r, c = r0, c0
    d = 2 * m - n
    cells = []
    for _ in range(n + 1):
        cells.append((r, c))
        if d > 0:  # the line is more than half a cell away: step the minor axis
            if steep:
                c += sc
            else:
                r += sr
            d -= 2 * n
        d += 2 * m
        if steep:  # always step the major axis
            r += sr
        else:
            c += sc
    return np.array(cells, dtype=np.int64).reshape(-1, 2)


def ray_cells(start, ends) -> tuple[np.ndarray, np.ndarray]:
    """Cells crossed by all beams of a scan, vectorised (no loop over beams).

    Beam ``k`` goes from cell ``start`` to cell ``ends[k]``; with
    ``n_k = max(|Δr|, |Δc|)`` its ``n_k + 1`` cells are, for ``i = 0 … n_k``,
    ``start + sign(Δ) · round_half_down(i |Δ| / n_k)`` per axis, computed in
    integers as ``⌊(2 i |Δ| + n_k − 1) / (2 n_k)⌋``. This is the closed form
    of :func:`bresenham`'s error loop: the same cells, in the same order.

    Parameters
    ----------
    start : array_like of int, shape (2,)
        Sensor cell ``(row, col)``.
    ends : array_like of int, shape (n, 2)
        Endpoint cells.

    Returns
    -------
    free_cells : ndarray of int64, shape (Σ n_k, 2)
        For every beam in order, its cells from the start up to but excluding
        its endpoint (empty for a zero-length beam). Cells crossed by several
        beams appear several times.
    hit_cells : ndarray of int64, shape (n, 2)
        The endpoint cells, ``ends`` itself.
    """
    s = int_cells("start", start, "ray_cells")
    e = int_cells("ends", ends, "ray_cells")
    if s.shape != (2,) or e.ndim != 2:
        raise ValueError(f"ray_cells: start must have shape (2,) and ends (n, 2), got {s.shape} and {e.shape}")
    free, hit = ray_cells_batch(s[None], e[None])  # one start: particle 0
    return free[:, 1:], hit[:, 1:]


def ray_cells_batch(starts, ends) -> tuple[np.ndarray, np.ndarray]:
    """Cells crossed by beams from several start cells at once (one start per particle).

    The closed form of :func:`bresenham` (Bresenham's digital
    line, ``start + sign(Δ)·⌊(2 i |Δ| + n − 1) / (2 n)⌋`` per axis for
    ``i = 0 … n − 1``, ``n = max |Δ|``) with a start per particle.

    Parameters
    ----------
    starts : ndarray of int, shape (M, 2)
        Sensor cell of each particle.
    ends : ndarray of int, shape (M, B, 2)
        Endpoint cells.

    Returns
    -------
    free : ndarray of int64, shape (F, 3)
        ``(particle, row, col)`` of every crossed cell (endpoint excluded).
    hit : ndarray of int64, shape (M·B, 3)
        ``(particle, row, col)`` of every endpoint.
    """
    s = np.asarray(starts, dtype=np.int64)
    e = np.asarray(ends, dtype=np.int64)
    if s.ndim != 2 or s.shape[1] != 2 or e.ndim != 3 or e.shape[0] != s.shape[0] or e.shape[2] != 2:
        raise ValueError(f"ray_cells_batch: starts must be (M, 2) and ends (M, B, 2), got {s.shape} and {e.shape}")
    m, b = e.shape[:2]
    particle = np.repeat(np.arange(m), b)
    start = np.repeat(s, b, axis=0)  # (M·B, 2)
    delta = e.reshape(-1, 2) - start
    n = np.abs(delta).max(axis=1)
    total = int(n.sum())
    i = np.arange(total) - np.repeat(np.cumsum(n) - n, n)
    nk = np.repeat(n, n)
    free = np.empty((total, 3), dtype=np.int64)
    free[:, 0] = np.repeat(particle, n)
    for axis in (0, 1):  # rows, then columns
        d = delta[:, axis]
        free[:, axis + 1] = np.repeat(start[:, axis], n) + np.repeat(np.sign(d), n) * (
            (i * np.repeat(2 * np.abs(d), n) + nk - 1) // (2 * nk)
        )
    hit = np.column_stack([particle, e.reshape(-1, 2)])
    return free, hit

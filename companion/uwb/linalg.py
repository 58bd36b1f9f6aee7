"""numpy.linalg's calls at less overhead, for the UWB solver's small arrays (the same floats).

These run a few dozen times per fix on arrays of 4-10 rows, where numpy's per-call overhead is
most of the cost. The arithmetic is kept as it was (the same reductions and LAPACK routines, so
the same floats) but called with less overhead: ``np.add.reduce`` is what ``np.sum`` calls, and
LAPACK's gesv / gelsd are called directly (scipy.linalg.lapack), as ``np.linalg.solve``, ``inv``
(gesv on the identity) and ``lstsq`` call them after their argument checks
(``tests/uwb/test_multilateration_fast.py`` holds them to numpy's results bit for bit).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dgelsd as _gelsd
from scipy.linalg.lapack import dgelsd_lwork as _gelsd_lwork
from scipy.linalg.lapack import dgesv as _gesv

_EPS = float(np.finfo(float).eps)
_GELSD_SIZES: dict[tuple[int, int], tuple[int, int]] = {}


def sum_rows(a: np.ndarray) -> np.ndarray:
    """Row sums, as ``np.sum(a, axis=1)`` (the same reduction without its Python wrapper)."""
    return np.add.reduce(a, axis=1)


def solve(M: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """``np.linalg.solve(M, b)`` (LAPACK gesv, the same floats); None where it raises (singular)."""
    _, _, x, info = _gesv(M, b)
    return x if info == 0 else None


def inv(M: np.ndarray) -> np.ndarray | None:
    """``np.linalg.inv(M)`` (numpy solves M X = I with gesv: the same floats); None when singular.

    C-ordered like numpy's result (LAPACK returns it in Fortran order): products such as the
    leverages' ``einsum`` sum in an order that follows the memory layout."""
    x = solve(M, np.eye(M.shape[0]))
    return None if x is None else np.ascontiguousarray(x)


def lstsq(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, int]:
    """(solution, rank) of ``np.linalg.lstsq(A, b, rcond=None)`` (LAPACK gelsd with numpy's default
    rcond = eps * max(m, n), the same floats)."""
    m, n = A.shape
    rcond = _EPS * max(m, n)
    sizes = _GELSD_SIZES.get((m, n))
    if sizes is None:  # LAPACK's workspace query (the same answer for every call of one shape)
        work, iwork, _ = _gelsd_lwork(m, n, 1, rcond)
        sizes = _GELSD_SIZES[m, n] = (int(work), int(iwork))
    bb = np.zeros(max(m, n))
    bb[:m] = b
    x, _, rank, info = _gelsd(A, bb, sizes[0], sizes[1], rcond)
    if info != 0:
        raise np.linalg.LinAlgError("SVD did not converge in linear least squares")
    return x[:n], int(rank)

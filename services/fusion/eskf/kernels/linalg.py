"""3x3 and thin products written out for the kernels: numba hands `@` to BLAS, whose calls cost
more than the arithmetic at 3x3 and at the update's m <= 4 columns."""

from __future__ import annotations

import numpy as np

from services.fusion.eskf.jit_cache import njit


@njit(cache=True)
def mv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A (3, 3) @ x (3,) written out: numba hands `@` to BLAS, whose call costs more than the
    product at this size."""
    out = np.empty(3)
    for i in range(3):
        out[i] = A[i, 0] * x[0] + A[i, 1] * x[1] + A[i, 2] * x[2]
    return out


@njit(cache=True)
def mtv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A.T (3, 3) @ x (3,) written out."""
    out = np.empty(3)
    for i in range(3):
        out[i] = A[0, i] * x[0] + A[1, i] * x[1] + A[2, i] * x[2]
    return out


@njit(cache=True)
def mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A (3, 3) @ B (3, 3) written out."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return out


@njit(cache=True)
def matmul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A (n, k) @ B (k, m) written out, for the update's thin products (m <= 4)."""
    n, k, m = A.shape[0], A.shape[1], B.shape[1]
    out = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            acc = 0.0
            for c in range(k):
                acc += A[i, c] * B[c, j]
            out[i, j] = acc
    return out

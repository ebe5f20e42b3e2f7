"""The pose maps' query (`eskf.maps`), compiled: it runs at every ToF range and every few
accelerometer samples over up to a window's worth of entries."""

from __future__ import annotations

import math

import numpy as np

from services.fusion.eskf.jit_cache import njit


@njit(cache=True)
def kernel_mean(
    K: np.ndarray, k2: np.ndarray, E: np.ndarray, T: np.ndarray, n: int, t_lo: int, R: np.ndarray, p: np.ndarray,
    wk: np.ndarray, out: np.ndarray,
) -> float:  # fmt: skip
    """The pose maps' query (`maps`): of the entries 0:n with keys K (., 12), their
    weighted square norms k2, values E (., d) and times T (ascending), those at or after t_lo,
    weighted w_i = exp(-|K_i - q|^2_W / 2) with q the pose (R, p) as a key and W = diag(wk);
    writes sum_i w_i E_i to out (d,) and returns sum_i w_i. Entries past 12 kernel widths (a
    weight under 1e-31) are skipped."""
    d = E.shape[1]
    for c in range(d):
        out[c] = 0.0
    lo, hi = 0, n  # the first entry at or after t_lo
    while lo < hi:
        mid = (lo + hi) // 2
        if T[mid] < t_lo:
            lo = mid + 1
        else:
            hi = mid
    qw = np.empty(12)
    qq = 0.0
    for i in range(3):
        for j in range(3):
            qw[3 * i + j] = wk[3 * i + j] * R[i, j]
            qq += qw[3 * i + j] * R[i, j]
        qw[9 + i] = wk[9 + i] * p[i]
        qq += qw[9 + i] * p[i]
    sw = 0.0
    for i in range(lo, n):
        dot = 0.0
        for c in range(12):
            dot += K[i, c] * qw[c]
        d2 = k2[i] - 2.0 * dot + qq
        if d2 < 144.0:
            w = math.exp(-0.5 * max(d2, 0.0))
            sw += w
            for c in range(d):
                out[c] += w * E[i, c]
    return sw

"""RCM registration: the point closest, in least squares, to the shaft lines of several poses.

Each static pose gives the shaft line {p + s u} (tip p, shaft direction u = R e_z, base frame,
from the robot reference). Lines through a fixed port meet there; the fit minimises the sum
of squared distances sum |(I - u u^T)(x - p)|^2. Poses whose directions are all parallel
cannot locate the point along the line and are refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tiplog.calibration.fits import require
from tiplog.calibration.fits.windows import kfold

FIT = "rcm"


@dataclass(frozen=True)
class RcmResult:
    rcm_base_m: np.ndarray  # (3,)
    residual_mm: float  # RMS distance of the fitting lines to the point
    heldout_mm: float  # RMS distance of held-out lines to the point fitted without them
    spread_deg: float  # angular spread of the directions (conditioning)
    poses: int


def direction_spread_deg(u: np.ndarray) -> float:
    """Angular spread of unit directions u (n, 3) [deg]: 0 when all are parallel (the smallest
    eigenvalue of the mean projector I - u u^T is the squared sine of the spread)."""
    lam = np.linalg.eigvalsh(np.eye(3) - (u.T @ u) / len(u))
    return float(np.degrees(np.arcsin(np.sqrt(np.clip(lam[0], 0.0, 1.0)))))


def _solve(p: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, float]:
    P = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    A = P.sum(0)
    b = np.einsum("nij,nj->i", P, p)
    return np.linalg.lstsq(A, b, rcond=None)[0], direction_spread_deg(u)


def line_distance(x: np.ndarray, p: np.ndarray, u: np.ndarray) -> np.ndarray:
    d = x - p
    return np.linalg.norm(d - (d * u).sum(-1, keepdims=True) * u, axis=-1)


def fit_rcm(p_tip_base_m: np.ndarray, R_base_tool: np.ndarray, min_spread_deg: float = 1.0) -> RcmResult:
    """RCM from k >= 3 static poses (tip positions (k, 3) [m], rotations (k, 3, 3))."""
    p = np.asarray(p_tip_base_m, dtype=float)
    require(p.ndim == 2 and p.shape[0] >= 3, FIT, f"needs at least 3 static poses (got {len(p)})")
    u = np.asarray(R_base_tool, dtype=float)[:, :, 2]
    x, spread = _solve(p, u)
    require(
        spread >= min_spread_deg,
        FIT,
        f"the shaft directions span only {spread:.2f} deg (need {min_spread_deg} deg): the lines do not cross",
    )
    res = line_distance(x, p, u)
    held = []
    for tr, te in kfold(len(p), len(p)):
        xi, _ = _solve(p[tr], u[tr])
        held.append(line_distance(xi, p[te], u[te]))
    held_a = np.concatenate(held)
    return RcmResult(
        x,
        float(np.sqrt(np.mean(res**2)) * 1e3),
        float(np.sqrt(np.mean(held_a**2)) * 1e3),
        spread,
        len(p),
    )

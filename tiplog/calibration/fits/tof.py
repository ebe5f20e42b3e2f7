"""The ToF ray-plane model's eight parameters from static poses against the robot reference.

rho = (h - m.(p + R o_s)) / (m.(R b_s)) with unit scale (paper, Time-of-Flight Range Model):
beam origin o_s (3, tool frame), beam direction b_s (2: a unit vector), plane normal m (2: a
unit vector, base frame) and offset h (1). Each static pose gives its mean status-valid raw
range; the fit is a maximum a posteriori least squares around the starting constants (a
design drawing or an earlier calibration) with the given prior SDs, because the VL53L0X's
pose-locked error (about 3 mm across poses) leaves some directions weakly determined by a few
poses. Each pose is weighted by the SD of its mean combined with `pose_sd_mm`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from tiplog.calibration.fits import require
from tiplog.calibration.fits.windows import kfold
from tiplog.geometry import so3_exp

FIT = "tof ray-plane"


@dataclass(frozen=True)
class TofModel:
    origin_tool_m: np.ndarray  # o_s (3,)
    beam_tool: np.ndarray  # b_s (3,) unit
    plane_normal_base: np.ndarray  # m (3,) unit
    plane_h_m: float

    def range_m(self, R_base_tool: np.ndarray, p_tip_base_m: np.ndarray) -> np.ndarray:
        """Range along the beam [m], (...,); NaN where the beam misses the plane."""
        m = self.plane_normal_base
        s = p_tip_base_m + np.einsum("...ij,j->...i", R_base_tool, self.origin_tool_m)
        den = np.einsum("...ij,j->...i", R_base_tool, self.beam_tool) @ m
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = (self.plane_h_m - s @ m) / den
        return np.where((den > 1e-6) & (rho > 0), rho, np.nan)


@dataclass(frozen=True)
class TofResult:
    model: TofModel
    residual_mm: float  # RMS on the fitting poses
    heldout_mm: float  # RMS on poses left out (k-fold)
    prior_heldout_mm: float  # the starting constants on the same poses
    sd: dict[str, float]  # posterior SDs: origin_mm (max), beam_deg, plane_deg, h_mm
    poses: int


def _tangent(v: np.ndarray) -> np.ndarray:
    """Two unit vectors normal to v (2, 3)."""
    a = np.array([1.0, 0.0, 0.0]) if abs(v[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(v, a)
    t1 /= np.linalg.norm(t1)
    return np.stack([t1, np.cross(v, t1)])


def _model(theta: np.ndarray, prior: TofModel) -> TofModel:
    tb, tm = _tangent(prior.beam_tool), _tangent(prior.plane_normal_base)
    b = so3_exp(tb.T @ theta[3:5]) @ prior.beam_tool
    m = so3_exp(tm.T @ theta[5:7]) @ prior.plane_normal_base
    return TofModel(prior.origin_tool_m + theta[:3], b, m, prior.plane_h_m + theta[7])


def _fit(
    rho_m: np.ndarray, sigma_m: np.ndarray, R: np.ndarray, p: np.ndarray, prior: TofModel, prior_sd: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    def resid(th: np.ndarray) -> np.ndarray:
        pred = _model(th, prior).range_m(R, p)
        r = np.where(np.isfinite(pred), (pred - rho_m) / sigma_m, 1e3)
        return np.concatenate([r, th / prior_sd])

    sol = least_squares(resid, np.zeros(8), method="lm", x_scale=prior_sd)
    J = sol.jac
    cov = np.linalg.pinv(J.T @ J)
    return sol.x, cov


def fit_tof(
    range_mean_mm: np.ndarray,
    range_sd_mm: np.ndarray,
    samples: np.ndarray,
    R_base_tool: np.ndarray,
    p_tip_base_m: np.ndarray,
    prior: TofModel,
    pose_sd_mm: float = 3.0,
    origin_prior_mm: float = 2.0,
    beam_prior_deg: float = 1.0,
    plane_prior_deg: float = 1.0,
    h_prior_mm: float = 2.0,
    folds: int = 5,
) -> TofResult:
    """Eight parameters from k >= 9 static poses: per pose the mean valid raw range [mm], its
    sample SD and count, and the robot's pose (R (k, 3, 3), tip (k, 3) [m])."""
    rho = np.asarray(range_mean_mm, float) * 1e-3
    require(len(rho) >= 9, FIT, f"needs at least 9 static poses with valid ranges for 8 parameters (got {len(rho)})")
    n = np.maximum(np.asarray(samples, float), 1.0)
    sigma = np.sqrt(np.asarray(range_sd_mm, float) ** 2 / n + pose_sd_mm**2) * 1e-3
    R = np.asarray(R_base_tool, float)
    p = np.asarray(p_tip_base_m, float)
    u = R[:, :, 2]
    spread = np.degrees(np.arcsin(np.sqrt(np.clip(np.linalg.eigvalsh(u.T @ u / len(u))[1], 0.0, 1.0))))
    require(spread > 1.0, FIT, f"the shaft directions span only {spread:.2f} deg: tilt the tool between poses")
    prior_sd = np.array(
        [origin_prior_mm * 1e-3] * 3
        + [np.radians(beam_prior_deg)] * 2
        + [np.radians(plane_prior_deg)] * 2
        + [h_prior_mm * 1e-3]
    )
    theta, cov = _fit(rho, sigma, R, p, prior, prior_sd)
    model = _model(theta, prior)
    held, held0 = [], []
    for tr, te in kfold(len(rho), folds):
        th, _ = _fit(rho[tr], sigma[tr], R[tr], p[tr], prior, prior_sd)
        held.append(_model(th, prior).range_m(R[te], p[te]) - rho[te])
        held0.append(prior.range_m(R[te], p[te]) - rho[te])
    rms = lambda r: float(np.sqrt(np.nanmean(np.concatenate(r) ** 2)) * 1e3)  # noqa: E731
    sd = np.sqrt(np.diag(cov))
    return TofResult(
        model=model,
        residual_mm=rms([model.range_m(R, p) - rho]),
        heldout_mm=rms(held),
        prior_heldout_mm=rms(held0),
        sd={
            "origin_mm": float(sd[:3].max() * 1e3),
            "beam_deg": float(np.degrees(sd[3:5].max())),
            "plane_deg": float(np.degrees(sd[5:7].max())),
            "h_mm": float(sd[7] * 1e3),
        },
        poses=len(rho),
    )

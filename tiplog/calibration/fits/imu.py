"""IMU-to-tool mounting and accelerometer calibration against the robot reference.

Mounting R_tool_imu (imu axes in tool axes): from the gyroscope during the moves between
poses, the rotation factor of the linear map that best takes the measured rate (bias removed)
onto the robot's body rate, omega_tool = R_tool_imu S omega_imu (S: the gyro's scale); it needs rotation about at least two
independent axes. Without motion it falls back to the accelerometer's gravity directions.

Accelerometer: at rest the specific force in the imu frame is f = R_tool_imu^T R_base_tool^T
(0, 0, g). The model a = (I + E) f + b has a symmetric E (three scale errors on its diagonal,
three misalignments off it; the antisymmetric part is the mounting) and a bias b [m/s^2],
solved as a linear least-squares problem over the static poses' mean samples with Gaussian
priors (a lab's tolerances) so that a parameter the poses do not excite stays at its prior;
the posterior SDs are reported. Held-out residual: the angle between the measured and the
modelled gravity direction on poses left out of the fit [deg].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tiplog.calibration.fits import require
from tiplog.calibration.fits.windows import kfold
from tiplog.geometry import so3_exp, so3_log

G_MPS2 = 9.80665
_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def polar_fit(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation factor of the least-squares linear map M with b_i ~ M a_i (n, 3): unlike the
    Kabsch rotation it is not biased by per-axis scale errors of the sensor (M = R S)."""
    M = np.linalg.lstsq(a, b, rcond=None)[0].T
    U, _, Vt = np.linalg.svd(M)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation R minimising sum |R a_i - b_i|^2 for (n, 3) arrays."""
    H = a.T @ b
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


@dataclass(frozen=True)
class MountResult:
    R_tool_imu: np.ndarray
    source: str  # "gyro" or "accel"
    residual_dps: float  # rate residual, fitting samples (gyro) [deg/s]
    heldout_dps: float  # on held-out blocks of motion
    samples: int
    jackknife_sd_deg: float = float("nan")  # spread of the leave-one-block/pose-out estimates


def fit_mount_gyro(
    omega_imu_radps: np.ndarray, omega_tool_radps: np.ndarray, bias_radps: np.ndarray | None = None, folds: int = 5
) -> MountResult:
    """R_tool_imu from paired rates (n, 3): gyro (imu frame) and robot body rate (tool frame)
    at the same instants; `bias_radps` ((3,) or (n, 3)) is subtracted from the gyro (e.g. its
    mean in the rests on either side of each move, since the bias moves during motion)."""
    fit = "imu mounting (gyro)"
    a = np.asarray(omega_imu_radps, float) - (0.0 if bias_radps is None else np.asarray(bias_radps, float))
    b = np.asarray(omega_tool_radps, float)
    require(len(a) >= 50, fit, f"needs at least 50 gyro samples in motion (got {len(a)})")
    s = np.linalg.svd(b, compute_uv=False)
    require(
        s[1] / s[0] > 0.05,
        fit,
        "the robot rotated about one axis only (second singular value "
        f"{s[1] / s[0]:.3f} of the first): a rotation about a second axis is needed",
    )
    R = polar_fit(a, b)
    res = b - a @ R.T
    held, Rs = [], []
    blocks = np.array_split(np.arange(len(a)), folds)
    for k, te in enumerate(blocks):
        tr = np.concatenate([x for j, x in enumerate(blocks) if j != k])
        Rk = polar_fit(a[tr], b[tr])
        Rs.append(Rk)
        held.append(b[te] - a[te] @ Rk.T)
    h = np.concatenate(held)
    rms = lambda r: float(np.degrees(np.sqrt(np.mean(np.sum(r**2, 1)))))  # noqa: E731
    return MountResult(R, "gyro", rms(res), rms(h), len(a), _jackknife_sd_deg(R, Rs))


def fit_mount_accel(accel_mean_mps2: np.ndarray, R_base_tool: np.ndarray) -> MountResult:
    """R_tool_imu from the gravity directions of k >= 2 static poses (not all parallel)."""
    fit = "imu mounting (accelerometer)"
    a = np.asarray(accel_mean_mps2, float)
    require(len(a) >= 2, fit, f"needs at least 2 static poses (got {len(a)})")
    g_tool = np.einsum("kji,j->ki", np.asarray(R_base_tool, float), np.array([0.0, 0.0, 1.0]))
    spread = np.degrees(np.arcsin(np.sqrt(np.clip(np.linalg.eigvalsh(g_tool.T @ g_tool / len(a))[1], 0.0, 1.0))))
    require(spread > 1.0, fit, f"gravity in tool axes varies by only {spread:.2f} deg over the poses")
    an = a / np.linalg.norm(a, axis=1, keepdims=True)
    R = kabsch(an, g_tool)
    ang = np.degrees(np.arccos(np.clip(np.sum((an @ R.T) * g_tool, 1), -1, 1)))
    Rs = [kabsch(an[tr], g_tool[tr]) for tr, _ in kfold(len(a), len(a))] if len(a) >= 3 else []
    held = [
        np.degrees(np.arccos(np.clip(np.sum((an[te] @ Rk.T) * g_tool[te], 1), -1, 1)))
        for Rk, (_, te) in zip(Rs, kfold(len(a), len(a)), strict=False)
    ]
    hd = float(np.sqrt(np.mean(np.concatenate(held) ** 2))) if held else float("nan")
    return MountResult(R, "accel", float(np.sqrt(np.mean(ang**2))), hd, len(a), _jackknife_sd_deg(R, Rs))


def _jackknife_sd_deg(R: np.ndarray, Rs: list[np.ndarray]) -> float:
    if len(Rs) < 2:
        return float("nan")
    d = so3_log(np.einsum("ji,njk->nik", R, np.asarray(Rs)))
    n = len(Rs)
    return float(np.degrees(np.sqrt((n - 1) / n * np.sum((d - d.mean(0)) ** 2) / 3.0)))


def combine_mounts(a: MountResult, b: MountResult) -> MountResult:
    """Inverse-variance weighted mean (on the rotation's tangent space) of two independent
    mounting estimates, each weighted by its jackknife SD."""
    wa, wb = 1.0 / a.jackknife_sd_deg**2, 1.0 / b.jackknife_sd_deg**2
    d = so3_log(a.R_tool_imu.T @ b.R_tool_imu)
    R = a.R_tool_imu @ so3_exp(d * wb / (wa + wb))
    return MountResult(
        R,
        f"{a.source}+{b.source}",
        a.residual_dps,
        a.heldout_dps,
        a.samples + b.samples,
        float(np.sqrt(1.0 / (wa + wb))),
    )


@dataclass(frozen=True)
class AccelResult:
    bias_mps2: np.ndarray  # (3,)
    scale: np.ndarray  # (3,) 1 + diagonal of E
    misalignment: np.ndarray  # (3,) E01, E02, E12 [rad-like, dimensionless]
    correction: np.ndarray  # (3, 3) C = (I + E)^-1: f = C (a - b)
    sd: dict[str, list[float]]  # posterior SDs: bias, scale, misalignment
    residual_deg: float  # gravity-direction residual on the fitting poses (RMS)
    heldout_deg: float  # on held-out poses (leave-one-out)
    norm_error_frac: float  # mean |corrected a| / g - 1 on all poses
    poses: int


def _design(f: np.ndarray) -> np.ndarray:
    k = len(f)
    J = np.zeros((k, 3, 9))
    for c, (i, j) in enumerate(_SYM):
        J[:, i, c] += f[:, j]
        if i != j:
            J[:, j, c] += f[:, i]
    J[:, :, 6:] = np.eye(3)
    return J


def _solve_accel(
    a: np.ndarray, f: np.ndarray, sigma: np.ndarray, prior_sd: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    J = _design(f).reshape(-1, 9)
    r = (a - f).reshape(-1)
    w = np.repeat(1.0 / sigma**2, 3)
    H = J.T @ (J * w[:, None]) + np.diag(1.0 / prior_sd**2)
    cov = np.linalg.inv(H)
    return cov @ (J.T @ (w * r)), cov


def _unpack(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    E = np.zeros((3, 3))
    for c, (i, j) in enumerate(_SYM):
        E[i, j] = E[j, i] = theta[c]
    return E, theta[6:]


def _angles(a: np.ndarray, f: np.ndarray, theta: np.ndarray) -> np.ndarray:
    E, b = _unpack(theta)
    pred = f @ (np.eye(3) + E).T + b
    c = np.sum(a * pred, 1) / np.linalg.norm(a, axis=1) / np.linalg.norm(pred, axis=1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def fit_accel(
    accel_mean_mps2: np.ndarray,
    R_base_tool: np.ndarray,
    R_tool_imu: np.ndarray,
    sample_sd_mps2: np.ndarray | None = None,
    pose_sd_deg: float = 0.21,
    bias_prior_mps2: float = 0.05,
    scale_prior: float = 0.01,
    misalignment_prior: float = 0.005,
) -> AccelResult:
    """Bias, scale and misalignment from k >= 4 static poses: mean samples (k, 3) [m/s^2] in
    the imu frame, the robot's rotations (k, 3, 3), the mounting. Each pose's weight is its
    sample SD of the mean combined with a pose-locked direction error of pose_sd_deg."""
    fit = "accelerometer"
    a = np.asarray(accel_mean_mps2, float)
    require(len(a) >= 4, fit, f"needs at least 4 static poses (got {len(a)})")
    g_tool = np.einsum("kji,j->ki", np.asarray(R_base_tool, float), np.array([0.0, 0.0, G_MPS2]))
    f = g_tool @ np.asarray(R_tool_imu, float)  # R_tool_imu^T g_tool per row
    fn = f / G_MPS2
    spread = np.degrees(np.arcsin(np.sqrt(np.clip(np.linalg.eigvalsh(fn.T @ fn / len(a))[1], 0.0, 1.0))))
    require(spread > 1.0, fit, f"gravity in imu axes varies by only {spread:.2f} deg over the poses")
    sd = np.zeros(len(a)) if sample_sd_mps2 is None else np.asarray(sample_sd_mps2, float)
    sigma = np.sqrt(sd**2 + (np.radians(pose_sd_deg) * G_MPS2) ** 2)
    prior = np.array([scale_prior] * 3 + [misalignment_prior] * 3 + [bias_prior_mps2] * 3)
    theta, cov = _solve_accel(a, f, sigma, prior)
    held = []
    for tr, te in kfold(len(a), len(a)):
        th, _ = _solve_accel(a[tr], f[tr], sigma[tr], prior)
        held.append(_angles(a[te], f[te], th))
    E, b = _unpack(theta)
    C = np.linalg.inv(np.eye(3) + E)
    corrected = (a - b) @ C.T
    psd = np.sqrt(np.diag(cov))
    res = _angles(a, f, theta)
    h = np.concatenate(held)
    return AccelResult(
        bias_mps2=b,
        scale=1.0 + np.diag(E),
        misalignment=theta[3:6].copy(),
        correction=C,
        sd={"bias_mps2": psd[6:].tolist(), "scale": psd[:3].tolist(), "misalignment": psd[3:6].tolist()},
        residual_deg=float(np.sqrt(np.mean(res**2))),
        heldout_deg=float(np.sqrt(np.mean(h**2))),
        norm_error_frac=float(np.mean(np.linalg.norm(corrected, axis=1)) / G_MPS2 - 1.0),
        poses=len(a),
    )


def rotation_error_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of R_a^T R_b [deg]."""
    return float(np.degrees(np.linalg.norm(so3_log(np.asarray(R_a).T @ np.asarray(R_b)))))

"""Pinhole camera with Brown-Conrady distortion (OpenCV's plumb_bob: k1, k2, p1, p2, k3).

Camera frame: x right, y down, z forward (optical axis), metres. Pixels: u right, v down,
origin at the top-left pixel's centre. "Undistorted" pixels are those of the ideal pinhole
with the same K. Shared by the bench's renderer and observation model, the vision service
and the estimator, so that all of them agree on one projection.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration


@dataclass(frozen=True)
class CameraModel:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    frame_id: str = field(default="camera", compare=False)

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera size must be positive (got {self.width}x{self.height})")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive (got fx={self.fx}, fy={self.fy})")
        if len(self.dist) != 5:
            raise ValueError(f"dist must hold k1, k2, p1, p2, k3 (got {len(self.dist)} values)")

    @classmethod
    def d405_colour(cls) -> CameraModel:
        """A D405-like colour stream at 1280x720 (about 87 deg horizontal field of view)."""
        return cls(1280, 720, 652.0, 651.0, 641.3, 358.7, (-0.0552, 0.0621, 0.00042, -0.00031, -0.0198))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    # normalised image coordinates ------------------------------------------------
    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Ideal normalised coordinates (..., 2) -> distorted normalised coordinates."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], -1)

    def undistort_normalized(self, xyd: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Inverse of `distort_normalized` by fixed-point iteration (accurate to ~1e-10 for
        the mild distortion of this lens class)."""
        xy = np.array(xyd, dtype=float, copy=True)
        for _ in range(iterations):
            err = self.distort_normalized(xy) - xyd
            xy = xy - err
        return xy

    # pixels --------------------------------------------------------------------------
    def project(self, p_cam: np.ndarray, distort: bool = True) -> np.ndarray:
        """Points (..., 3) in the camera frame [m] -> pixels (..., 2); NaN behind the camera."""
        p = np.asarray(p_cam, dtype=float)
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[..., :2] / z[..., None]
        xy = np.where((z > 1e-9)[..., None], xy, np.nan)
        if distort:
            xy = self.distort_normalized(xy)
        return np.stack([self.fx * xy[..., 0] + self.cx, self.fy * xy[..., 1] + self.cy], -1)

    def pixel_to_normalized(self, uv: np.ndarray, distorted: bool = True) -> np.ndarray:
        uv = np.asarray(uv, dtype=float)
        xy = np.stack([(uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy], -1)
        return self.undistort_normalized(xy) if distorted else xy

    def undistort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Distorted pixels -> undistorted pixels (same K)."""
        xy = self.pixel_to_normalized(uv, distorted=True)
        return np.stack([self.fx * xy[..., 0] + self.cx, self.fy * xy[..., 1] + self.cy], -1)

    def pixel_to_ray(self, uv: np.ndarray, distorted: bool = True) -> np.ndarray:
        """Pixels (..., 2) -> unit rays (..., 3) in the camera frame."""
        xy = self.pixel_to_normalized(uv, distorted)
        ray = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1)
        return ray / np.linalg.norm(ray, axis=-1, keepdims=True)

    # messages -----------------------------------------------------------------------
    def to_calibration(self, stamp_ns: int = 0) -> CameraCalibration:
        """As foxglove.CameraCalibration (plumb_bob), for camera/info."""
        m = CameraCalibration()
        m.timestamp.FromNanoseconds(int(stamp_ns))
        m.frame_id = self.frame_id
        m.width, m.height = self.width, self.height
        m.distortion_model = "plumb_bob"
        m.D.extend(self.dist)
        m.K.extend(self.K.ravel().tolist())
        m.R.extend(np.eye(3).ravel().tolist())
        P = np.zeros((3, 4))
        P[:, :3] = self.K
        m.P.extend(P.ravel().tolist())
        return m

    @classmethod
    def from_calibration(cls, m: CameraCalibration) -> CameraModel:
        if len(m.K) != 9:
            raise ValueError(f"camera calibration K must have 9 values (got {len(m.K)})")
        if m.distortion_model not in ("", "plumb_bob", "rational_polynomial") or len(m.D) not in (0, 5, 8):
            raise ValueError(f"unsupported distortion {m.distortion_model!r} with {len(m.D)} coefficients")
        d = tuple(m.D[:5]) if len(m.D) >= 5 else (0.0,) * 5
        return cls(m.width, m.height, m.K[0], m.K[4], m.K[2], m.K[5], d, m.frame_id or "camera")  # type: ignore[arg-type]

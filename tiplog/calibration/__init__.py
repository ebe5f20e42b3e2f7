"""The device's calibration constants, as estimators read them: one YAML file (what
`tiplog calibrate` writes and `tiplog fusion run --calibration` reads) or a bench session's
`calibration_as_calibrated` metadata. Never the bench's `calibration_truth`: `from_mcap_metadata`
refuses it by name.

Frames: base (z up; the robot's base on the bench, the cart's reference otherwise), tool (origin
at the tip, z distal along the shaft), imu, camera (x right, y down, z forward). Lengths in
metres, angles as rotation matrices, latencies in milliseconds from the event to its arrival
stamp on the host clock.
"""

from __future__ import annotations

import json
import numbers
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tiplog.userio import read_yaml, yaml_number

FORMAT = "tiplog-calibration"
VERSION = 1
# Metadata record names in a session file, in order of preference for estimators.
ESTIMATOR_METADATA = ("calibration", "calibration_as_calibrated")
FORBIDDEN_METADATA = ("calibration_truth",)

_SHAPES: dict[str, tuple[int, ...]] = {
    "rcm_base_m": (3,),
    "T_base_camera": (4, 4),
    "R_tool_imu": (3, 3),
    "p_imu_tool_m": (3,),
    "tof_origin_tool_m": (3,),
    "tof_beam_tool": (3,),
    "tof_plane_normal_base": (3,),
}
_SCALARS = ("shaft_radius_m", "junction_proximal_m", "tof_plane_h_m", "vision_tip_offset_m")
# Rotations are read as written: `yaml.safe_dump` keeps every digit, so a file from `tiplog
# calibrate` or the bench is orthonormal to ~1e-15; the tolerance admits one typed or rounded to
# four decimals (0.06 deg at most) and refuses anything that is not a rotation.
ROTATION_TOL = 1e-3
UNIT_TOL = 1e-3
_INTRINSICS = ("fx", "fy", "cx", "cy")
_INTRINSICS_OPTIONAL = ("dist", "width", "height")  # width/height: what `calibrate intrinsics` writes alone
_DIST_LENGTHS = (4, 5, 8, 12, 14)  # OpenCV's distortion models
# Keys of a record that are not fields: the bench marks its truth `evaluation_only` (refused).
_RECORD_KEYS = ("evaluation_only",)
_DOC_KEYS = ("format", "version", "calibration", "report")


class CalibrationError(ValueError):
    """A calibration file or record that cannot be used; the message names the field."""


def _fmt(v: Any) -> str:
    return " ".join(f"{x:g}" for x in np.ravel(v))


def _is_number(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


def _number(name: str, v: Any) -> float:
    """`v` as a finite float, or CalibrationError naming the field. A bool is not a number; a
    string that is one is (PyYAML reads `1e-5`, without a dot, as a string)."""
    x = yaml_number(v)
    if x is None:
        raise CalibrationError(f"calibration field {name}: expected a number (got {v!r})")
    if not np.isfinite(x):
        raise CalibrationError(f"calibration field {name}: must be a finite number (got {x})")
    return x


def _array(name: str, v: Any, shape: tuple[int, ...]) -> np.ndarray:
    """`v` (nested lists of numbers) as a finite float array of `shape`, or CalibrationError."""
    what = f"a {shape[0]}-vector" if len(shape) == 1 else f"a {shape[0]}x{shape[1]} matrix, a list of rows"
    if isinstance(v, np.ndarray) and v.dtype.kind in "iuf":
        a = v
    else:
        try:
            a = np.asarray(v, dtype=object)
        except ValueError:  # ragged nesting numpy cannot even hold
            raise CalibrationError(f"calibration field {name}: expected {what} of numbers") from None
    if a.shape != shape:
        raise CalibrationError(f"calibration field {name}: expected shape {shape} ({what}), got {a.shape}")
    if a.dtype == object:
        out = np.empty(shape)
        for idx, x in np.ndenumerate(a):
            if isinstance(x, str) or not _is_number(x):
                x = _number(f"{name}{list(idx)}", x)
            out[idx] = float(x)
        a = out
    a = a.astype(float)
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"calibration field {name}: not finite ({_fmt(a)})")
    return a


def _rotation(name: str, R: np.ndarray, part: str = "") -> None:
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    det = float(np.linalg.det(R))
    if err > ROTATION_TOL or det < 0:
        raise CalibrationError(
            f"calibration field {name}{part}: not a rotation matrix (R^T R differs from identity by {err:.3g}, "
            f"det {det:.6g}; needs orthonormal rows within {ROTATION_TOL:g} and det +1)"
        )


def _intrinsics(d: Any) -> dict[str, Any]:
    if not isinstance(d, dict):
        raise CalibrationError(f"calibration field intrinsics: expected a mapping with fx, fy, cx, cy (got {d!r})")
    for k in _INTRINSICS:
        if k not in d:
            raise CalibrationError(f"calibration field intrinsics: missing {k!r}")
    unknown = sorted(str(k) for k in d if k not in _INTRINSICS + _INTRINSICS_OPTIONAL)
    if unknown:
        raise CalibrationError(
            f"calibration field intrinsics: unknown key(s) {', '.join(unknown)} "
            f"(known: {', '.join(_INTRINSICS + _INTRINSICS_OPTIONAL)})"
        )
    out: dict[str, Any] = {k: _number(f"intrinsics.{k}", d[k]) for k in _INTRINSICS}
    for k in ("fx", "fy"):
        if not out[k] > 0:
            raise CalibrationError(f"calibration field intrinsics.{k}: focal length must be > 0 px (got {out[k]:g})")
    if "dist" in d:
        dist = d["dist"]
        if not isinstance(dist, list | tuple):
            raise CalibrationError(f"calibration field intrinsics.dist: expected a list of numbers (got {dist!r})")
        if len(dist) not in _DIST_LENGTHS:
            raise CalibrationError(
                f"calibration field intrinsics.dist: expected {', '.join(map(str, _DIST_LENGTHS))} "
                f"coefficients (OpenCV order k1 k2 p1 p2 [k3 ...]), got {len(dist)}"
            )
        out["dist"] = [_number(f"intrinsics.dist[{i}]", x) for i, x in enumerate(dist)]
    for k in ("width", "height"):
        if k in d:
            v = d[k]
            if not isinstance(v, numbers.Integral) or isinstance(v, bool) or v <= 0:
                raise CalibrationError(
                    f"calibration field intrinsics.{k}: expected a whole number of px > 0 (got {v!r})"
                )
            out[k] = int(v)
    return out


@dataclass(frozen=True)
class Calibration:
    rcm_base_m: np.ndarray  # (3,) registered remote centre of motion
    T_base_camera: np.ndarray  # (4, 4) camera pose in base (hand-eye result)
    intrinsics: dict[str, Any]  # fx, fy, cx, cy [px], dist (OpenCV order k1 k2 p1 p2 [k3])
    shaft_radius_m: float
    junction_proximal_m: float  # shaft junction to tip along the axis
    R_tool_imu: np.ndarray  # (3, 3) imu axes in tool axes
    p_imu_tool_m: np.ndarray  # (3,) imu origin in tool coordinates
    tof_origin_tool_m: np.ndarray  # (3,) ToF emitter in tool coordinates
    tof_beam_tool: np.ndarray  # (3,) unit beam direction in tool coordinates
    tof_plane_normal_base: np.ndarray  # (3,) unit normal m of the target plane, m.x = h
    tof_plane_h_m: float
    latency_ms: dict[str, float] = field(default_factory=dict)  # per stream: gyro, accel, tof, camera, ...
    vision_tip_offset_m: float = 0.0  # fitted junction-derived tip minus true tip, along u
    # how well R_tool_imu is known, SD per axis [deg], as `tiplog calibrate` fitted it; None: not
    # stated (the static-trial filter then learns the mounting in the rotation protocol)
    R_tool_imu_sd_deg: float | None = None

    def __post_init__(self) -> None:
        for name, shape in _SHAPES.items():
            object.__setattr__(self, name, _array(name, getattr(self, name), shape))
        for name in _SCALARS:
            object.__setattr__(self, name, _number(name, getattr(self, name)))
        if not self.shaft_radius_m > 0:
            raise CalibrationError(f"calibration field shaft_radius_m: must be > 0 (got {self.shaft_radius_m})")
        object.__setattr__(self, "intrinsics", _intrinsics(self.intrinsics))
        if self.R_tool_imu_sd_deg is not None:
            sd = _number("R_tool_imu_sd_deg", self.R_tool_imu_sd_deg)
            if not sd >= 0.0:
                raise CalibrationError(f"calibration field R_tool_imu_sd_deg: must be >= 0 deg (got {sd})")
            object.__setattr__(self, "R_tool_imu_sd_deg", sd)
        if not isinstance(self.latency_ms, dict):
            raise CalibrationError(
                f"calibration field latency_ms: expected a mapping of stream name to ms (got {self.latency_ms!r})"
            )
        lat = {}
        for k, v in self.latency_ms.items():
            lat[k] = _number(f"latency_ms.{k}", v)
            if not (0.0 <= lat[k] < 1000.0):
                raise CalibrationError(f"calibration field latency_ms.{k}: must be in [0, 1000) ms (got {v})")
        object.__setattr__(self, "latency_ms", lat)
        for name in ("tof_beam_tool", "tof_plane_normal_base"):
            n = np.linalg.norm(getattr(self, name))
            if abs(n - 1.0) > UNIT_TOL:
                raise CalibrationError(f"calibration field {name}: must be a unit vector (norm {n:.6f})")
        _rotation("R_tool_imu", self.R_tool_imu)
        _rotation("T_base_camera", self.T_base_camera[:3, :3], " (its upper-left 3x3)")
        if np.max(np.abs(self.T_base_camera[3] - (0.0, 0.0, 0.0, 1.0))) > 1e-9:
            raise CalibrationError(
                f"calibration field T_base_camera: last row must be 0 0 0 1 (got {_fmt(self.T_base_camera[3])})"
            )

    @property
    def R_base_camera(self) -> np.ndarray:
        return self.T_base_camera[:3, :3]

    @property
    def p_base_camera_m(self) -> np.ndarray:
        return self.T_base_camera[:3, 3]

    def latency_ns(self, stream: str) -> int:
        """Calibrated latency of `stream` in ns (0 when not calibrated)."""
        return int(round(float(self.latency_ms.get(stream, 0.0)) * 1e6))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = v.tolist() if isinstance(v, np.ndarray) else v
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "calibration") -> Calibration:
        """From a plain dict. Unknown keys are refused by name, as `tiplog fusion run --params`
        refuses unknown parameters (a misspelt field would otherwise silently keep its default);
        the bench's `evaluation_only` marker is the one extra key, and a record marked
        evaluation-only is refused."""
        if not isinstance(d, dict):
            raise CalibrationError(f"{where}: expected a mapping of calibration fields")
        if str(d.get("evaluation_only", False)).lower() == "true":
            raise CalibrationError(f"{where}: this is the bench's ground truth, never for estimators")
        names = {f.name for f in fields(cls)}
        unknown = sorted(str(k) for k in d if k not in names and k not in _RECORD_KEYS)
        if unknown:
            raise CalibrationError(
                f"{where}: unknown calibration field(s) {', '.join(unknown)} (known: {', '.join(sorted(names))})"
            )
        required = {f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING}
        missing = sorted(required - d.keys())
        if missing:
            raise CalibrationError(f"{where}: missing field(s) {', '.join(missing)}")
        try:
            return cls(**{k: v for k, v in d.items() if k in names})
        except CalibrationError as e:
            raise CalibrationError(f"{where}: {e}") from None

    def save_yaml(self, path: str | Path, extra: dict[str, Any] | None = None) -> None:
        """Write the YAML file `tiplog fusion run --calibration` reads; `extra` (residuals,
        provenance) goes under `report:` and is ignored when loading."""
        doc: dict[str, Any] = {"format": FORMAT, "version": VERSION, "calibration": self.to_dict()}
        if extra:
            doc["report"] = extra
        Path(path).write_text(yaml.safe_dump(doc, sort_keys=False))

    @classmethod
    def load_yaml(cls, path: str | Path) -> Calibration:
        p = Path(path)
        doc = read_yaml(p, CalibrationError, "not a tiplog calibration file (not text)")
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise CalibrationError(f"{p}: not a tiplog calibration file (no 'format: {FORMAT}')")
        version = doc.get("version", 0)
        if not isinstance(version, int) or isinstance(version, bool):
            raise CalibrationError(f"{p}: version: expected a whole number (got {version!r})")
        if version > VERSION:
            raise CalibrationError(f"{p}: calibration format version {version} is newer than {VERSION}")
        unknown = sorted(str(k) for k in doc if k not in _DOC_KEYS)
        if unknown:
            raise CalibrationError(
                f"{p}: unknown top-level key(s) {', '.join(unknown)} (known: {', '.join(_DOC_KEYS)})"
            )
        return cls.from_dict(doc.get("calibration"), where=str(p))

    @classmethod
    def from_mcap_metadata(cls, metadata: dict[str, dict[str, str]], where: str = "recording") -> Calibration:
        """From a recording's metadata records (name -> {key: value}): `calibration` (a file's
        contents recorded by the live system) or a bench session's `calibration_as_calibrated`."""
        for name in ESTIMATOR_METADATA:
            rec = metadata.get(name)
            if rec is None:
                continue
            try:
                d = json.loads(rec["json"]) if "json" in rec else yaml.safe_load(rec["yaml"])
            except (KeyError, ValueError, yaml.YAMLError):
                raise CalibrationError(f"{where}: metadata {name!r} is not a readable calibration record") from None
            return cls.from_dict(d, where=f"{where}: metadata {name!r}")
        raise CalibrationError(
            f"{where}: no calibration in the file (metadata {' or '.join(map(repr, ESTIMATOR_METADATA))}); "
            "give one with --calibration FILE"
        )

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
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

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


class CalibrationError(ValueError):
    """A calibration file or record that cannot be used; the message names the field."""


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

    def __post_init__(self) -> None:
        for name, shape in _SHAPES.items():
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != shape:
                raise CalibrationError(f"calibration field {name}: expected shape {shape}, got {v.shape}")
            if not np.all(np.isfinite(v)):
                raise CalibrationError(f"calibration field {name}: not finite")
            object.__setattr__(self, name, v)
        for k in ("fx", "fy", "cx", "cy"):
            if k not in self.intrinsics:
                raise CalibrationError(f"calibration field intrinsics: missing {k!r}")
        if not self.shaft_radius_m > 0:
            raise CalibrationError(f"calibration field shaft_radius_m: must be > 0 (got {self.shaft_radius_m})")
        for k, v in self.latency_ms.items():
            if not (0.0 <= float(v) < 1000.0):
                raise CalibrationError(f"calibration field latency_ms.{k}: must be in [0, 1000) ms (got {v})")
        for name in ("tof_beam_tool", "tof_plane_normal_base"):
            n = np.linalg.norm(getattr(self, name))
            if abs(n - 1.0) > 1e-3:
                raise CalibrationError(f"calibration field {name}: must be a unit vector (norm {n:.6f})")

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
        """From a plain dict; unknown keys (such as a bench's `evaluation_only`) are ignored
        except that a record marked evaluation-only is refused."""
        if not isinstance(d, dict):
            raise CalibrationError(f"{where}: expected a mapping of calibration fields")
        if str(d.get("evaluation_only", False)).lower() == "true":
            raise CalibrationError(f"{where}: this is the bench's ground truth, never for estimators")
        names = {f.name for f in fields(cls)}
        required = {f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING}
        missing = sorted(required - d.keys())
        if missing:
            raise CalibrationError(f"{where}: missing field(s) {', '.join(missing)}")
        try:
            return cls(**{k: v for k, v in d.items() if k in names})
        except CalibrationError as e:
            raise CalibrationError(f"{where}: {e}") from None
        except (TypeError, ValueError) as e:
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
        try:
            doc = yaml.safe_load(p.read_text())
        except OSError as e:
            raise CalibrationError(f"{p}: cannot read ({e.strerror or e})") from None
        except UnicodeDecodeError:
            raise CalibrationError(f"{p}: not a tiplog calibration file (not text)") from None
        except yaml.YAMLError as e:
            mark = getattr(e, "problem_mark", None)
            at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            raise CalibrationError(f"{p}: not valid YAML{at}") from None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise CalibrationError(f"{p}: not a tiplog calibration file (no 'format: {FORMAT}')")
        if int(doc.get("version", 0)) > VERSION:
            raise CalibrationError(f"{p}: calibration format version {doc.get('version')} is newer than {VERSION}")
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

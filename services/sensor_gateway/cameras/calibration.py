"""Camera intrinsics as foxglove.CameraCalibration: from the device or a YAML file.

File format (pixels):

    width: 1280
    height: 720
    K: [fx, 0, cx, 0, fy, cy, 0, 0, 1]   # or a 3x3 nested list
    D: [k1, k2, p1, p2, k3]
    distortion_model: plumb_bob          # or rational_polynomial, kannala_brandt
"""

from __future__ import annotations

from pathlib import Path

import yaml
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration

from .base import Intrinsics

MODELS = ("plumb_bob", "rational_polynomial", "kannala_brandt")


class CalibrationError(ValueError):
    """A calibration file is missing, malformed or inconsistent (message names the field)."""


def _flat(value: object, name: str, n: int | None) -> tuple[float, ...]:
    if isinstance(value, list) and value and all(isinstance(r, list) for r in value):
        value = [x for row in value for x in row]
    if not isinstance(value, list) or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in value):
        raise CalibrationError(f"calibration {name}: expected a list of numbers, got {value!r}")
    if n is not None and len(value) != n:
        raise CalibrationError(f"calibration {name}: expected {n} numbers, got {len(value)}")
    return tuple(float(x) for x in value)


def load_calibration(path: str | Path) -> Intrinsics:
    """Intrinsics from a YAML calibration file; CalibrationError naming the bad field."""
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except FileNotFoundError:
        raise CalibrationError(f"calibration file {p} does not exist") from None
    except yaml.YAMLError as e:
        raise CalibrationError(f"calibration file {p} is not valid YAML: {e}") from None
    if not isinstance(doc, dict):
        raise CalibrationError(f"calibration file {p} must hold a mapping")
    for key in ("width", "height", "K", "D"):
        if key not in doc:
            raise CalibrationError(f"calibration {key}: missing in {p}")
    width, height = doc["width"], doc["height"]
    for name, v in (("width", width), ("height", height)):
        if not isinstance(v, int) or v <= 0:
            raise CalibrationError(f"calibration {name}: expected a positive integer, got {v!r}")
    model = doc.get("distortion_model", "plumb_bob")
    if model not in MODELS:
        raise CalibrationError(f"calibration distortion_model: {model!r} is not one of {', '.join(MODELS)}")
    K = _flat(doc["K"], "K", 9)
    D = _flat(doc["D"], "D", None)
    if K[0] <= 0 or K[4] <= 0:
        raise CalibrationError(f"calibration K: focal lengths must be positive, got fx={K[0]}, fy={K[4]}")
    return Intrinsics(width, height, K, D, model)


def to_message(intr: Intrinsics, stamp_ns: int, frame_id: str = "camera") -> CameraCalibration:
    """foxglove.CameraCalibration for `intr` (R identity, P = [K | 0])."""
    m = CameraCalibration(
        frame_id=frame_id,
        width=intr.width,
        height=intr.height,
        distortion_model=intr.distortion_model,
    )
    m.timestamp.FromNanoseconds(stamp_ns)
    m.D.extend(intr.D)
    m.K.extend(intr.K)
    m.R.extend((1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
    K = intr.K
    m.P.extend((K[0], K[1], K[2], 0.0, K[3], K[4], K[5], 0.0, K[6], K[7], K[8], 0.0))
    return m

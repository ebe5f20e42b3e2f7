"""Vision service: shaft silhouette, consistency gate and tangent-plane geometry from each camera frame."""

from pathlib import Path

# The checkpoint shipped with the repository (trained by `tiplog vision train`, see docs/vision.md).
DEFAULT_WEIGHTS = Path(__file__).resolve().parents[2] / "models" / "shaft_unet.pt"

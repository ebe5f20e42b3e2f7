"""Camera sources behind one interface (`Camera`), one module per backend, and the one
factory that turns a backend config into a camera."""

from __future__ import annotations

from .base import (
    Camera,
    CameraConfig,
    CameraReadError,
    DeviceAlreadyConnectedError,
    DeviceNotConnectedError,
    EndOfStreamError,
    Frame,
    Intrinsics,
)
from .folder import FolderCamera, FolderCameraConfig
from .opencv import OpenCVCamera, OpenCVCameraConfig
from .realsense import RealSenseCamera, RealSenseCameraConfig


def make_camera(config: CameraConfig) -> Camera:
    """The camera for a backend config (RealSense imports its SDK only on connect)."""
    if isinstance(config, RealSenseCameraConfig):
        return RealSenseCamera(config)
    if isinstance(config, OpenCVCameraConfig):
        return OpenCVCamera(config)
    if isinstance(config, FolderCameraConfig):
        return FolderCamera(config)
    raise ValueError(f"no camera backend for {type(config).__name__}")


__all__ = [
    "Camera",
    "CameraConfig",
    "CameraReadError",
    "DeviceAlreadyConnectedError",
    "DeviceNotConnectedError",
    "EndOfStreamError",
    "FolderCamera",
    "FolderCameraConfig",
    "Frame",
    "Intrinsics",
    "OpenCVCamera",
    "OpenCVCameraConfig",
    "RealSenseCamera",
    "RealSenseCameraConfig",
    "make_camera",
]

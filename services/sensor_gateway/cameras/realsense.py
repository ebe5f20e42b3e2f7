"""Intel RealSense colour stream (D405: 1280x720 at 15 fps, exposure locked).

pyrealsense2 is an optional extra (`pip install tiplog[realsense]`), imported on connect:
the rest of the gateway runs without it. `playback_file` replays a .bag recording through
the same pipeline (the SDK's playback device), for tests and offline runs.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from .base import Camera, CameraConfig, CameraReadError, ColorOrder, Intrinsics


@dataclass
class RealSenseCameraConfig(CameraConfig):
    width: int = 1280
    height: int = 720
    fps: float = 15.0
    serial_number: str = ""  # "" = the first device found
    exposure_us: float = 8000.0  # locked (auto exposure off); 0 leaves auto exposure on
    gain: float = 0.0  # 0 leaves the sensor's gain as it is
    playback_file: str = ""  # a .bag file instead of a live device
    timeout_ms: int = 1000

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.width or not self.height or not self.fps:
            raise ValueError("RealSense needs width, height and fps (e.g. 1280, 720, 15)")
        if self.exposure_us < 0:
            raise ValueError(f"exposure_us must be >= 0, got {self.exposure_us}")


def import_sdk() -> ModuleType:
    """pyrealsense2, or a clear error naming the extra that provides it."""
    try:
        return importlib.import_module("pyrealsense2")
    except ImportError as e:
        raise CameraReadError("the RealSense source needs pyrealsense2: pip install 'tiplog[realsense]'") from e


class RealSenseCamera(Camera):
    config: RealSenseCameraConfig

    def __init__(self, config: RealSenseCameraConfig) -> None:
        super().__init__(config)
        self._rs: ModuleType | None = None
        self._pipeline: Any = None
        self._intrinsics: Intrinsics | None = None

    def __str__(self) -> str:
        return f"RealSenseCamera({self.config.serial_number or self.config.playback_file or 'first device'})"

    def _native_order(self) -> ColorOrder:
        return "rgb"

    def _connect(self) -> None:
        rs = self._rs = import_sdk()
        cfg = self.config
        rs_config = rs.config()
        if cfg.playback_file:
            rs_config.enable_device_from_file(cfg.playback_file, repeat_playback=False)
        elif cfg.serial_number:
            rs_config.enable_device(cfg.serial_number)
        rs_config.enable_stream(rs.stream.color, cfg.width, cfg.height, rs.format.rgb8, int(cfg.fps))
        pipeline = rs.pipeline()
        try:
            profile = pipeline.start(rs_config)
        except RuntimeError as e:
            raise CameraReadError(f"{self}: cannot start the colour stream: {e}") from e
        self._pipeline = pipeline
        if not cfg.playback_file:
            self._lock_exposure(profile)
        self._intrinsics = self._read_intrinsics(profile)

    def _lock_exposure(self, profile: Any) -> None:
        rs, cfg = self._rs, self.config
        if not cfg.exposure_us:
            return
        # On a D405 the colour stream comes from the stereo module: find the sensor that
        # owns a colour profile instead of asking for a separate RGB sensor.
        sensor = None
        for s in profile.get_device().query_sensors():
            if any(p.stream_type() == rs.stream.color for p in s.get_stream_profiles()):
                sensor = s
                break
        if sensor is None:
            raise CameraReadError(f"{self}: no sensor provides the colour stream")
        sensor.set_option(rs.option.enable_auto_exposure, 0)
        sensor.set_option(rs.option.exposure, float(cfg.exposure_us))
        if cfg.gain:
            sensor.set_option(rs.option.gain, float(cfg.gain))

    def _read_intrinsics(self, profile: Any) -> Intrinsics:
        rs = self._rs
        intr = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        name = str(intr.model).lower()
        model = "kannala_brandt" if ("kannala" in name or "ftheta" in name) else "plumb_bob"
        K = (intr.fx, 0.0, intr.ppx, 0.0, intr.fy, intr.ppy, 0.0, 0.0, 1.0)
        return Intrinsics(int(intr.width), int(intr.height), K, tuple(float(c) for c in intr.coeffs), model)

    def intrinsics(self) -> Intrinsics | None:
        return self._intrinsics

    def _grab(self) -> tuple[np.ndarray, int]:
        if self._pipeline is None:
            raise CameraReadError(f"{self} is not started")
        try:
            frames = self._pipeline.wait_for_frames(self.config.timeout_ms)
        except RuntimeError as e:  # the SDK's timeout and device-lost errors
            raise CameraReadError(f"{self}: {e}") from e
        stamp = self._now()
        color = frames.get_color_frame()
        if not color:
            raise CameraReadError(f"{self}: frameset without a colour frame")
        return np.asanyarray(color.get_data()), stamp

    def _disconnect(self) -> None:
        if self._pipeline is not None:
            try:
                self._pipeline.stop()
            except RuntimeError:
                pass
            self._pipeline = None

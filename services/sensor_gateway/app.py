"""`python -m services.sensor_gateway`: the clip-on device on serial and the camera, every
sample stamped on arrival on the host clock and published one message per sample.

Device: device/gyro, device/accel, device/tof, device/mag, and device/status at the status
period and on every state change. Camera (optional): camera/image (foxglove.RawImage) and
camera/info (foxglove.CameraCalibration, from the device or the calibration file).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from tiplog.config import ServiceConfig
from tiplog.priority import KernelWorkerPriority
from tiplog.service import ServiceContext, run_service

from .camera import CameraRunner
from .cameras import CameraConfig, FolderCameraConfig, OpenCVCameraConfig, RealSenseCameraConfig
from .cameras.calibration import CalibrationError, load_calibration
from .device import DeviceLinkConfig, DeviceReader
from .status import GatewayStatus

NAME = "sensor_gateway"


class CameraSettings(BaseModel):
    """Section `sensor_gateway.camera`: which source, and its options."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["none", "opencv", "folder", "realsense"] = "none"
    source: str = "0"  # opencv: device index, file or URL; folder: the folder
    width: int = Field(0, ge=0)  # 0: as delivered (realsense: 1280)
    height: int = Field(0, ge=0)  # 0: as delivered (realsense: 720)
    fps: float = Field(0.0, ge=0.0)  # 0: as delivered (realsense: 15)
    color: Literal["rgb", "bgr"] = "rgb"
    loop: bool = False  # files and folders: start again at the end
    pace: bool = True  # files: deliver at the file's frame rate
    serial_number: str = ""  # realsense
    exposure_us: float = Field(8000.0, ge=0.0)  # realsense: locked exposure (0: auto)
    gain: float = Field(0.0, ge=0.0)
    playback_file: str = ""  # realsense: a .bag recording instead of a device
    stall_timeout_s: float = Field(2.0, gt=0.0, le=60.0)
    reconnect_s: float = Field(0.5, gt=0.0, le=10.0)

    def backend_config(self) -> CameraConfig | None:
        """The backend's config dataclass (None for kind 'none')."""
        common = {"width": self.width, "height": self.height, "fps": self.fps, "color": self.color}
        if self.kind == "opencv":
            return OpenCVCameraConfig(**common, source=self.source, loop=self.loop, pace=self.pace)
        if self.kind == "folder":
            return FolderCameraConfig(**common, path=self.source, loop=self.loop)
        if self.kind == "realsense":
            rs = {k: v for k, v in common.items() if v}  # 0 keeps the D405 defaults
            return RealSenseCameraConfig(
                **rs,
                serial_number=self.serial_number,
                exposure_us=self.exposure_us,
                gain=self.gain,
                playback_file=self.playback_file,
            )
        return None

    @model_validator(mode="after")
    def _backend_valid(self) -> CameraSettings:
        self.backend_config()  # its ValueError names the field
        return self


class SensorGatewayConfig(ServiceConfig):
    """Configuration of the sensor_gateway service (section `sensor_gateway:` of the YAML file)."""

    port: str = "/tmp/tiplog-device"  # any pyserial name or URL; "" runs without a device
    baud: int = Field(921_600, gt=0)
    reconnect_initial_s: float = Field(0.05, gt=0.0, le=1.0)
    # Cap of the back-off: a port that comes back is reopened within this (plus open time).
    reconnect_max_s: float = Field(0.5, gt=0.0, le=0.9)
    stall_timeout_s: float = Field(0.5, gt=0.0, le=60.0)
    stall_reopen_s: float = Field(5.0, ge=0.0, le=600.0)  # 0: never reopen a silent port
    read_timeout_s: float = Field(0.05, gt=0.0, le=1.0)
    camera: CameraSettings = Field(default_factory=CameraSettings)
    calibration_file: str = ""  # YAML: width, height, K, D, distortion_model
    # The kernel's unbound workers carry a serial device's bytes to read() (tiplog/priority.py):
    # below 0 they are kept at this nice value, or with kernel_workers_fifo above 0 in the
    # real-time class SCHED_FIFO at that priority (root or CAP_SYS_NICE; in a container, the
    # host's process namespace), so that a loaded host cannot hold the device's samples back.
    # Both 0: left alone.
    kernel_workers_nice: int = Field(0, ge=-20, le=0)
    kernel_workers_fifo: int = Field(0, ge=0, le=99)

    @field_validator("calibration_file")
    @classmethod
    def _calibration_loads(cls, v: str) -> str:
        if v:
            try:
                load_calibration(v)
            except CalibrationError as e:
                raise ValueError(str(e)) from None
        return v

    def link(self) -> DeviceLinkConfig:
        return DeviceLinkConfig(
            port=self.port,
            baud=self.baud,
            reconnect_initial_s=self.reconnect_initial_s,
            reconnect_max_s=self.reconnect_max_s,
            stall_timeout_s=self.stall_timeout_s,
            stall_reopen_s=self.stall_reopen_s,
            read_timeout_s=self.read_timeout_s,
        )


def body(ctx: ServiceContext[SensorGatewayConfig]) -> None:
    cfg = ctx.config
    status_pub = ctx.bus.publisher("device/status")
    status = GatewayStatus(cfg.port, status_pub.put)
    reader = DeviceReader(cfg.link(), ctx.bus, status) if cfg.port else None
    camera = None
    cam_cfg = cfg.camera.backend_config()
    if cam_cfg is not None:
        calib = load_calibration(cfg.calibration_file) if cfg.calibration_file else None
        camera = CameraRunner(
            cam_cfg,
            ctx.bus,
            status,
            calib,
            stall_timeout_s=cfg.camera.stall_timeout_s,
            reconnect_s=cfg.camera.reconnect_s,
        )
    workers = None
    if reader and (cfg.kernel_workers_nice or cfg.kernel_workers_fifo):
        workers = KernelWorkerPriority(cfg.kernel_workers_nice, ctx.log, fifo=cfg.kernel_workers_fifo)
        workers.apply()
    for worker in (reader, camera):
        if worker is not None:
            worker.start()
    try:
        while not ctx.stop.wait(cfg.status_period_s):
            if workers is not None:
                workers.apply()
            status.publish_periodic()
    finally:
        for worker in (camera, reader):
            if worker is not None:
                worker.stop(timeout_s=1.0)
        if workers is not None:
            workers.restore()  # the host as it was


def main(argv: Sequence[str] | None = None) -> int:
    return run_service(NAME, SensorGatewayConfig, body, argv, description=__doc__)

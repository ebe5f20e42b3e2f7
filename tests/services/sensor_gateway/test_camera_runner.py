"""The gateway's camera runner on a real bus: RawImage and CameraCalibration as specified;
a wrong-size frame and a camera that stops delivering are counted and reconnected; the
gateway configuration validates camera and calibration settings."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest

from services.sensor_gateway.app import SensorGatewayConfig
from services.sensor_gateway.camera import CameraRunner
from services.sensor_gateway.cameras import Camera, CameraConfig, FolderCameraConfig, make_camera
from services.sensor_gateway.cameras.calibration import load_calibration
from services.sensor_gateway.status import GatewayStatus
from tiplog.bus import Bus
from tiplog.config import ConfigError, load_config

CAL = "width: 32\nheight: 24\nK: [30, 0, 16, 0, 30, 12, 0, 0, 1]\nD: [0, 0, 0, 0, 0]\n"


def wait_for(predicate, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    done = threading.Event()
    while not predicate():
        if time.monotonic() > deadline:
            return False
        done.wait(0.01)
    return True


class Collector:
    def __init__(self) -> None:
        self.images: list = []
        self.infos: list = []

    def on_image(self, msg, info) -> None:
        self.images.append(msg)

    def on_info(self, msg, info) -> None:
        self.infos.append(msg)


def _run(listen_cfg, connect_cfg, runner_factory):
    col = Collector()
    with Bus(listen_cfg) as sub_bus, Bus(connect_cfg) as pub_bus:
        sub_bus.subscribe("camera/image", col.on_image)
        sub_bus.subscribe("camera/info", col.on_info)
        statuses: list = []
        status = GatewayStatus("", statuses.append)
        runner = runner_factory(pub_bus, status)
        # The subscriber must be known to the publisher before the first frame goes out.
        assert wait_for(lambda: runner._image_pub._pub.matching_status.matching, 10)
        runner.start()
        yield col, runner, status
        runner.stop()


def test_images_published_bad_size_counted_and_reconnected(bus_pair_configs, tmp_path):
    listen_cfg, connect_cfg = bus_pair_configs
    folder = tmp_path / "imgs"
    folder.mkdir()
    for k in range(3):
        img = np.full((24, 32, 3), (10 * k, 100, 200), np.uint8)  # BGR
        cv2.imwrite(str(folder / f"{k}.png"), img)
    cv2.imwrite(str(folder / "9_wrong_size.png"), np.zeros((20, 32, 3), np.uint8))
    (tmp_path / "cal.yaml").write_text(CAL)
    calib = load_calibration(tmp_path / "cal.yaml")
    cfg = FolderCameraConfig(path=str(folder), color="rgb", fps=200, loop=True)

    def factory(bus, status):
        return CameraRunner(cfg, bus, status, calib, stall_timeout_s=1.0, reconnect_s=0.01)

    gen = _run(listen_cfg, connect_cfg, factory)
    col, runner, status = next(gen)
    try:
        assert wait_for(lambda: runner.faults["bad_frames"] >= 2 and len(col.images) >= 6), (
            runner.faults,
            len(col.images),
        )
        assert wait_for(lambda: len(col.infos) >= 1)
    finally:
        next(gen, None)
    assert runner.faults["reconnects"] >= 1
    assert status.faults["camera_bad_frames"] >= 2
    m = col.images[0]
    assert (m.width, m.height, m.encoding, m.step, m.frame_id) == (32, 24, "rgb8", 96, "camera")
    pixel = np.frombuffer(m.data, np.uint8).reshape(24, 32, 3)[0, 0]
    # RGB of one of the folder's images (BGR on disk); which one comes first depends on when
    # the subscriber was matched, and a loaded host can miss the first frame
    assert tuple(int(c) for c in pixel) in {(200, 100, 10 * k) for k in range(3)}, pixel
    stamps = [x.timestamp.ToNanoseconds() for x in col.images]
    assert all(s > 0 for s in stamps) and stamps == sorted(stamps)
    assert all((x.width, x.height) == (32, 24) for x in col.images)  # the bad frame never went out
    info = col.infos[0]
    assert (info.width, info.height, info.frame_id, list(info.K)[:3]) == (32, 24, "camera", [30, 0, 16])


class StallingCamera(Camera):
    """Delivers two frames, then blocks like a camera whose cable is pulled."""

    made = 0

    def __init__(self, config: CameraConfig) -> None:
        super().__init__(config)
        StallingCamera.made += 1
        self._n = 0
        self._release = threading.Event()

    def _native_order(self):
        return "bgr"

    def _connect(self) -> None:
        pass

    def _grab(self):
        self._n += 1
        if self._n > 2:
            self._release.wait(0.6)  # longer than the stall timeout
        return np.zeros((8, 8, 3), np.uint8), self._now()

    def _disconnect(self) -> None:
        self._release.set()


def test_camera_that_stops_is_reported_and_reconnected(bus_pair_configs):
    listen_cfg, connect_cfg = bus_pair_configs
    StallingCamera.made = 0

    def factory(bus, status):
        return CameraRunner(
            CameraConfig(), bus, status, None, stall_timeout_s=0.3, reconnect_s=0.01, camera_factory=StallingCamera
        )

    gen = _run(listen_cfg, connect_cfg, factory)
    col, runner, status = next(gen)
    try:
        assert wait_for(lambda: runner.faults["stalls"] >= 2 and len(col.images) >= 4), runner.faults
    finally:
        next(gen, None)
    assert StallingCamera.made >= 3 and status.faults["camera_stalls"] >= 2
    assert col.infos == []  # no calibration: no camera/info


def test_make_camera_rejects_an_unknown_config():
    with pytest.raises(ValueError, match="no camera backend"):
        make_camera(CameraConfig())


def test_gateway_config_camera_and_calibration(tmp_path):
    cal = tmp_path / "cal.yaml"
    cal.write_text(CAL)
    cfg = load_config(
        SensorGatewayConfig,
        "sensor_gateway",
        overrides=["camera.kind=folder", f"camera.source={tmp_path}", f"calibration_file={cal}"],
    )
    assert isinstance(cfg.camera.backend_config(), FolderCameraConfig)
    with pytest.raises(ConfigError, match="calibration_file"):
        load_config(SensorGatewayConfig, "sensor_gateway", overrides=[f"calibration_file={tmp_path / 'x.yaml'}"])
    with pytest.raises(ConfigError, match="camera.color"):
        load_config(SensorGatewayConfig, "sensor_gateway", overrides=["camera.color=yuv"])
    with pytest.raises(ConfigError, match="reconnect_max_s"):
        load_config(SensorGatewayConfig, "sensor_gateway", overrides=["reconnect_max_s=2"])

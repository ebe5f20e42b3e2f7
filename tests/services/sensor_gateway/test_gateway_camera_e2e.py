"""The gateway process with a folder camera and a calibration file and no device: camera/image
and camera/info arrive on the bus, device/status says DISCONNECTED with camera counters."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

import cv2
import numpy as np

from tests.conftest import ROOT
from tiplog.bus import Bus
from tiplog.v1 import device_pb2


def test_gateway_publishes_camera_frames_and_info(bus_pair_configs, tmp_path):
    listen_cfg, _ = bus_pair_configs
    folder = tmp_path / "imgs"
    folder.mkdir()
    for k in range(3):
        cv2.imwrite(str(folder / f"{k}.png"), np.full((24, 32, 3), 40 * k, np.uint8))
    cal = tmp_path / "cal.yaml"
    cal.write_text("width: 32\nheight: 24\nK: [30, 0, 16, 0, 30, 12, 0, 0, 1]\nD: [0, 0, 0, 0, 0]\n")
    images, infos, statuses = [], [], []
    got = threading.Event()

    def check() -> None:
        if len(images) >= 5 and infos and any(s.measured_rates_hz.get("camera", 0) > 0 for s in statuses):
            got.set()

    with Bus(listen_cfg) as bus:
        bus.subscribe("camera/image", lambda m, i: (images.append(m), check()))
        bus.subscribe("camera/info", lambda m, i: (infos.append(m), check()))
        bus.subscribe("device/status", lambda m, i: (statuses.append(m), check()))
        proc = subprocess.Popen(
            [sys.executable, "-m", "services.sensor_gateway", "--connect", listen_cfg.listen[0],
             "--prefix", listen_cfg.prefix, "--set", "port=", "--set", "camera.kind=folder",
             "--set", f"camera.source={folder}", "--set", "camera.loop=true", "--set", "camera.fps=30",
             "--set", f"calibration_file={cal}"],
            cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            ok = got.wait(30)
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                _, err = proc.communicate(timeout=10)
            finally:
                if proc.poll() is None:
                    proc.kill()
    assert ok, err[-2000:]
    assert proc.returncode == 0, err[-2000:]
    m = images[-1]
    assert (m.width, m.height, m.encoding, m.step, m.frame_id) == (32, 24, "rgb8", 96, "camera")
    assert infos[0].K[0] == 30 and infos[0].frame_id == "camera"
    assert statuses[-1].state == device_pb2.DEVICE_STATE_DISCONNECTED

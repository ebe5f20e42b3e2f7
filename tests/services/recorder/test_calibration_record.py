"""A recording made with a tiplog calibration file carries its constants as metadata, so fusion
can run offline on the recording alone (`Calibration.from_mcap_metadata`)."""

from __future__ import annotations

import numpy as np

from services.recorder.recorder import Recorder
from tests.services.recorder.test_core import A, S, cfg, cmd, gyro, info
from tiplog.calibration import Calibration
from tiplog.mcap_io import read_metadata


def test_recording_carries_the_calibration_it_was_made_with(tmp_path):
    cal_path = tmp_path / "calibration.yaml"
    T_base_camera = np.eye(4)
    T_base_camera[:3, 3] = [0.4, -0.1, 0.55]
    Calibration(
        rcm_base_m=np.array([0.5, 0.0, 0.3]),
        T_base_camera=T_base_camera,
        intrinsics={"fx": 640.0, "fy": 640.0, "cx": 640.0, "cy": 360.0, "dist": [0.0] * 5},
        shaft_radius_m=0.0025,
        junction_proximal_m=0.02,
        R_tool_imu=np.eye(3),
        p_imu_tool_m=np.array([0.0, 0.02, -0.3]),
        tof_origin_tool_m=np.array([0.0, 0.02, -0.29]),
        tof_beam_tool=np.array([0.0, 0.0, 1.0]),
        tof_plane_normal_base=np.array([0.0, 0.0, 1.0]),
        tof_plane_h_m=0.1,
        latency_ms={"gyro": 3.5, "tof": 21.0},
    ).save_yaml(cal_path)
    out = tmp_path / "rec"
    out.mkdir()
    rec = Recorder(cfg(out, calibration_file=str(cal_path)))
    rec.start_thread()
    try:
        r = rec.command(cmd(A.RECORDER_ACTION_START, "test", "case"))
        assert r.ok and r.status.state == S.RECORDER_STATE_RECORDING, r.message
        rec.on_sample(gyro(0), info(0))
        assert rec.command(cmd(A.RECORDER_ACTION_STOP)).ok
    finally:
        rec.close()
    (path,) = sorted(out.glob("case_*.mcap"))
    md = read_metadata(path)
    assert md["calibration"]["file"] == str(cal_path)
    got, want = Calibration.from_mcap_metadata(md, where=str(path)), Calibration.load_yaml(cal_path)
    np.testing.assert_array_equal(got.T_base_camera, want.T_base_camera)
    np.testing.assert_array_equal(got.rcm_base_m, want.rcm_base_m)
    assert got.latency_ms == want.latency_ms

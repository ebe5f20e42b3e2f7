"""The error-frame benchmark shows where a calibration error lands: an IMU mounting 1.5 deg off
(the bench's calibration error drawn large) leaves the tip offset across the shaft and along the
camera's line of sight, where vision does not see the tip, and the true mounting swapped in
takes that offset away."""

from __future__ import annotations

import numpy as np
import pytest

from tests.benchmarks.test_error_frame import _rows
from tiplog.cli import main as tiplog_main

pytestmark = pytest.mark.slow


def test_a_mounting_error_lands_along_the_line_of_sight_and_the_true_mounting_removes_it(tmp_path):
    session = tmp_path / "mount.mcap"
    args = ["sim", "generate", "--scenario", "sweeps", "--seed", "7", "--duration", "60", "--out", str(session)]
    assert tiplog_main([*args, "--quiet", "--set", "calibration.imu_mount_sd_deg=1.5"]) == 0
    off = _rows(tmp_path, session)
    across = float(np.hypot(*off["tool_mean_mm"][:2]))
    assert across > 1.0, off  # the mounting's tilt moves the tip by millimetres ...
    assert abs(off["sight_mean_mm"]) > 0.8 * across, off  # ... along the line of sight
    assert off["sight_sd_mm"] < 0.5 * abs(off["sight_mean_mm"]), off  # a steady offset, not noise
    true = _rows(tmp_path, session, "--swap", "R_tool_imu")
    assert abs(true["sight_mean_mm"]) < 0.5 * abs(off["sight_mean_mm"]), (off, true)
    assert true["tip_rmse_mm"] < off["tip_rmse_mm"]
    # along the shaft the error mostly changes within seconds: averaging over 2 s leaves less
    sm = true["along_sd_smoothed_mm"]
    assert sm["2"] < sm["0.5"] < true["tool_sd_mm"][2]

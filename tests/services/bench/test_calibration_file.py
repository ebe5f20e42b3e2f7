"""The live bench's calibration file: the as-calibrated constants fusion reads, the same record
an offline session of the same scenario and seed carries as `calibration_as_calibrated`."""

from __future__ import annotations

import numpy as np
import pytest

from services.bench.app import BenchConfig, write_calibration
from services.bench.scenario import load_scenario
from services.bench.simulation import simulate_session
from tiplog.calibration import Calibration
from tiplog.config import ConfigError


@pytest.mark.parametrize("seed", [1, 7])
def test_file_holds_the_sessions_as_calibrated_constants(tmp_path, seed):
    path = tmp_path / "calibration.yaml"
    cfg = BenchConfig(scenario="static", seed=seed, calibration_file=str(path))
    assert write_calibration(cfg) == path
    written = Calibration.load_yaml(path)
    sim = simulate_session(load_scenario("static"), seed, "measurement", duration_s=1.0)
    expected = Calibration.from_dict(sim.calib.to_dict())
    truth = Calibration.from_dict({**sim.truth.to_dict(), "evaluation_only": False})
    for name in ("rcm_base_m", "T_base_camera", "R_tool_imu", "tof_beam_tool"):
        np.testing.assert_allclose(getattr(written, name), getattr(expected, name), rtol=0, atol=1e-12)
    assert written.latency_ms == expected.latency_ms
    # what is written is the perturbed set, not the bench's truth
    assert np.linalg.norm(written.T_base_camera[:3, 3] - truth.T_base_camera[:3, 3]) > 1e-5
    assert [p.name for p in tmp_path.iterdir()] == ["calibration.yaml"]  # no temporary left behind


def test_unset_writes_nothing_and_missing_folder_is_named(tmp_path):
    assert write_calibration(BenchConfig(scenario="static")) is None
    cfg = BenchConfig(scenario="static", calibration_file=str(tmp_path / "nope" / "c.yaml"))
    with pytest.raises(ConfigError, match="calibration_file: folder .*nope does not exist"):
        write_calibration(cfg)

"""The paper's latency table on a bench latency-protocol session against the bench's true
latencies, and `tiplog calibrate latency` printing it."""

from __future__ import annotations

import json

import pytest

from tiplog.calibration import data as calibrate_data
from tiplog.calibration import latency as calibrate_latency
from tiplog.cli import main
from tiplog.mcap_io import read_metadata


@pytest.mark.slow
def test_latency_table_recovers_the_bench_latencies(tmp_path, capsys):
    path = tmp_path / "lat.mcap"
    assert main(["sim", "generate", "--scenario", "latency", "--out", str(path), "--seed", "6"]) == 0
    truth = json.loads(read_metadata(path)["calibration_truth"]["json"])["latency_ms"]
    data = calibrate_data.load(path)
    table = calibrate_latency.latency_table(data, data.prior)
    # the VL53L0X's pose-locked error (3 mm across poses) makes the ToF's phase noisy: its
    # standard error on this protocol is about 3 ms, the IMU's 0.05-0.15 ms, the camera's 1 ms
    tol = {"gyro": 0.5, "accel": 0.5, "tof": 6.0, "tof_smoothed": 6.0, "camera": 3.0}
    for stream, t in tol.items():
        assert abs(table[stream]["latency_ms"] - truth[stream]) < t, (stream, table[stream], truth[stream])
    assert set(table["gyro"]) >= {"tilt", "roll"} and "depth" in table["tof"]
    applied = calibrate_latency.apply(data.prior, table)
    assert applied.latency_ms["camera"] == table["camera"]["latency_ms"]
    assert applied.latency_ms["mag"] == data.prior.latency_ms["mag"]  # not fitted: kept
    assert main(["calibrate", "latency", str(path)]) == 0
    assert "| depth |" in capsys.readouterr().out

"""The attitude benchmark stays runnable: a short bench session through the CSV export, the
command and VQF, with inclination errors for both (figures come from the benchmark, not here)."""

from __future__ import annotations

import json

import pytest

from benchmarks import attitude_vqf


@pytest.mark.slow
def test_benchmark_runs(tmp_path, capsys):
    out = tmp_path / "att.json"
    argv = ["--scenarios", "sweeps", "--seeds", "1001", "--duration", "12", "--work", str(tmp_path), "--json", str(out)]
    assert attitude_vqf.main(argv) == 0
    (row,) = json.loads(out.read_text())
    assert row["rows"] > 2000  # 12 s of 200 Hz gyro
    for who in ("ours", "vqf"):
        assert 0.0 < row[who]["rms_deg"] < 10.0  # a wrong frame or sign would give tens of degrees
    assert "sweeps" in capsys.readouterr().out

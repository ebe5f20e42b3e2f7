"""`tiplog up` hands one calibration file to the services that read it: the bench's
as-calibrated constants by default, or the user's file with a real device."""

from __future__ import annotations

import pytest

from tiplog.up import _config_fields, calibration_sets
from tiplog.userio import UserError


def test_with_the_bench_its_file_goes_to_every_reader(tmp_path):
    names = ["bench", "sensor_gateway", "fusion", "recorder"]
    sets, path = calibration_sets(names, None, tmp_path)
    assert path == tmp_path / "calibration.yaml"
    assert sets["bench"] == [f"calibration_file={path}"]
    assert sets["recorder"] == [f"calibration_file={path}"]
    assert sets["sensor_gateway"] == []  # its calibration_file is the camera's, not this one
    # fusion gets it as soon as its configuration declares the field
    want = [f"calibration_file={path}"] if "calibration_file" in _config_fields("fusion") else []
    assert sets["fusion"] == want


def test_a_users_file_replaces_the_bench_one(tmp_path):
    mine = tmp_path / "mine.yaml"
    mine.write_text("format: tiplog-calibration\n")
    sets, path = calibration_sets(["bench", "recorder"], str(mine), tmp_path)
    assert path == mine.resolve() and sets["bench"] == []
    assert sets["recorder"] == [f"calibration_file={mine.resolve()}"]


def test_without_bench_or_file_nothing_is_passed(tmp_path):
    assert calibration_sets(["recorder"], None, tmp_path) == ({"recorder": []}, None)


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(UserError, match="nope.yaml: no such calibration file"):
        calibration_sets(["recorder"], str(tmp_path / "nope.yaml"), tmp_path)

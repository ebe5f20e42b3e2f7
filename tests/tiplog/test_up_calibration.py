"""`tiplog up` hands one calibration file to the services that read it: the bench's
as-calibrated constants by default, or the user's file with a real device."""

from __future__ import annotations

import pytest

from services.bench.app import BenchConfig, write_calibration
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


def test_a_reader_whose_model_did_not_import_here_still_gets_it(tmp_path, monkeypatch):
    import tiplog.up

    monkeypatch.setattr(tiplog.up, "config_model", lambda name: None)
    sets, path = calibration_sets(["bench", "sensor_gateway", "fusion"], None, tmp_path)
    assert sets["fusion"] == [f"calibration_file={path}"]
    assert sets["sensor_gateway"] == []  # not a reader


def test_a_users_file_replaces_the_bench_one(tmp_path):
    mine = tmp_path / "mine.yaml"
    write_calibration(BenchConfig(scenario="static", calibration_file=str(mine)))
    sets, path = calibration_sets(["bench", "recorder"], str(mine), tmp_path)
    assert path == mine.resolve() and sets["bench"] == []
    assert sets["recorder"] == [f"calibration_file={mine.resolve()}"]


def test_a_file_that_is_not_a_calibration_is_refused_by_name(tmp_path):
    notes = tmp_path / "notes.yaml"
    notes.write_text("format: tiplog-calibration\n")
    with pytest.raises(UserError, match="notes.yaml: expected a mapping of calibration fields"):
        calibration_sets(["recorder"], str(notes), tmp_path)


def test_without_bench_or_file_nothing_is_passed(tmp_path):
    assert calibration_sets(["recorder"], None, tmp_path) == ({"recorder": []}, None)


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(UserError, match="nope.yaml: no such calibration file"):
        calibration_sets(["recorder"], str(tmp_path / "nope.yaml"), tmp_path)


def test_the_demo_banner_says_where_to_look_where_recordings_go_and_how_to_stop():
    from tests.conftest import ROOT
    from tiplog.up import DEFAULT_SERVICES, banner

    text = banner(DEFAULT_SERVICES, str(ROOT / "config" / "demo.yaml"))
    lines = [ln for ln in text.splitlines() if ln.strip()]
    assert len(lines) == 6  # one short block
    assert "dashboard   http://127.0.0.1:8000" in text
    assert "foxglove    ws://127.0.0.1:8765" in text  # the live bridge is on in the demo
    assert "slicer      OpenIGTLink 127.0.0.1:18944" in text
    assert "recordings  ./recordings/" in text and "autostart: always" in text
    assert "stop        Ctrl-C" in text

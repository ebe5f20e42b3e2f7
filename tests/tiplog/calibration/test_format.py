"""The calibration file as a user meets it: every field is checked on reading (a NaN, a string
where a number belongs, a matrix that is not a rotation, a negative focal length, a misspelt
field) with one line naming the field; and what `tiplog calibrate` and the bench write reads
back unchanged."""

from __future__ import annotations

import copy
import dataclasses
import json

import cv2
import numpy as np
import pytest
import yaml

from services.bench.scenario import load_scenario
from services.bench.simulation import as_calibrated_constants
from tiplog.calibration import Calibration, CalibrationError
from tiplog.cli import main


@pytest.fixture(scope="module")
def bench_dict() -> dict:
    """A bench session's `calibration_as_calibrated` record, as JSON carries it."""
    return json.loads(json.dumps(as_calibrated_constants(load_scenario("sweeps"), 3).to_dict()))


def _doc(cal: dict) -> dict:
    return {"format": "tiplog-calibration", "version": 1, "calibration": cal}


def _write(tmp_path, cal: dict, name: str = "cal.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(_doc(cal), sort_keys=False))
    return p


def _set(d: dict, path: str, value) -> dict:
    d = copy.deepcopy(d)
    *head, last = path.split(".")
    node = d
    for k in head:
        node = node[k]
    node[last] = value
    return d


R_NOT_ROTATION = [[1, 0, 0], [0, 1, 0], [0, 0, 5]]
REFLECTION = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]


@pytest.mark.parametrize(
    ("path", "value", "needles"),
    [
        ("tof_plane_h_m", float("nan"), ("tof_plane_h_m", "finite")),
        ("shaft_radius_m", float("inf"), ("shaft_radius_m", "finite")),
        ("vision_tip_offset_m", float("-inf"), ("vision_tip_offset_m", "finite")),
        ("latency_ms.gyro", float("nan"), ("latency_ms.gyro", "finite")),
        ("intrinsics.cx", float("nan"), ("intrinsics.cx", "finite")),
        ("intrinsics.dist", [0.1, float("nan"), 0, 0, 0], ("intrinsics.dist[1]", "finite")),
        ("rcm_base_m", [0.6, float("inf"), 0.3], ("rcm_base_m", "not finite")),
        ("shaft_radius_m", "abc", ("shaft_radius_m", "expected a number", "'abc'")),
        ("junction_proximal_m", True, ("junction_proximal_m", "expected a number")),
        ("latency_ms.gyro", "fast", ("latency_ms.gyro", "expected a number", "'fast'")),
        ("latency_ms", [1, 2], ("latency_ms", "mapping")),
        ("intrinsics", "d405", ("intrinsics", "mapping")),
        ("p_imu_tool_m", ["0.01", "b", 0.3], ("p_imu_tool_m[1]", "expected a number", "'b'")),
        ("p_imu_tool_m", [[1, 2], [3]], ("p_imu_tool_m", "3-vector")),
        ("p_imu_tool_m", "abc", ("p_imu_tool_m", "3-vector")),
        ("intrinsics.dist", [0.1, "x", 0, 0, 0], ("intrinsics.dist[1]", "'x'")),
        ("R_tool_imu", R_NOT_ROTATION, ("R_tool_imu", "not a rotation matrix")),
        ("R_tool_imu", REFLECTION, ("R_tool_imu", "not a rotation matrix", "det -1")),
        ("intrinsics.fx", -5.0, ("intrinsics.fx", "> 0")),
        ("intrinsics.fy", 0, ("intrinsics.fy", "> 0")),
        ("intrinsics.dist", [0.1, 0.2, 0.3], ("intrinsics.dist", "got 3")),
        ("intrinsics.skew", 0.0, ("intrinsics", "unknown key", "skew")),
        ("bogus_key", 1.0, ("unknown calibration field", "bogus_key")),
        ("R_tool_imu_sd_deg", -0.1, ("R_tool_imu_sd_deg", ">= 0")),
        ("R_tool_imu_sd_deg", "tight", ("R_tool_imu_sd_deg", "expected a number")),
    ],
)
def test_a_bad_field_is_refused_by_name(tmp_path, bench_dict, path, value, needles):
    p = _write(tmp_path, _set(bench_dict, path, value))
    with pytest.raises(CalibrationError) as e:
        Calibration.load_yaml(p)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p))
    for n in needles:
        assert n in msg, msg


def test_numbers_pyyaml_reads_as_strings_are_numbers(tmp_path, bench_dict):
    """PyYAML (YAML 1.1) reads `2.6e3` and `65e-2` as strings: a hand-written file may hold them."""
    assert yaml.safe_load("a: 2.6e3\nb: 65e-2") == {"a": "2.6e3", "b": "65e-2"}
    d = _set(bench_dict, "rcm_base_m", ["65e-2", *bench_dict["rcm_base_m"][1:]])
    d = _set(d, "latency_ms.gyro", "6.5e0")
    cal = Calibration.load_yaml(_write(tmp_path, d))
    assert cal.rcm_base_m[0] == 0.65 and cal.latency_ms["gyro"] == 6.5


def test_the_camera_pose_must_be_a_rigid_transform(tmp_path, bench_dict):
    T = np.asarray(bench_dict["T_base_camera"])
    scaled = T.copy()
    scaled[:3, :3] *= 2
    with pytest.raises(CalibrationError, match=r"T_base_camera \(its upper-left 3x3\): not a rotation"):
        Calibration.load_yaml(_write(tmp_path, _set(bench_dict, "T_base_camera", scaled.tolist())))
    row = T.copy()
    row[3] = [0, 0, 1, 1]
    with pytest.raises(CalibrationError, match="T_base_camera: last row must be 0 0 0 1"):
        Calibration.load_yaml(_write(tmp_path, _set(bench_dict, "T_base_camera", row.tolist())))


def test_rotations_typed_with_rounding_are_accepted(tmp_path, bench_dict):
    for decimals in (4, 6):
        d = _set(bench_dict, "R_tool_imu", np.round(np.asarray(bench_dict["R_tool_imu"]), decimals).tolist())
        Calibration.load_yaml(_write(tmp_path, d))
    Calibration.load_yaml(_write(tmp_path, _set(bench_dict, "R_tool_imu", np.eye(3, dtype=int).tolist())))


def test_the_document_itself_is_checked(tmp_path, bench_dict):
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump({**_doc(bench_dict), "notes": "x"}))
    with pytest.raises(CalibrationError, match="unknown top-level key.*notes"):
        Calibration.load_yaml(p)
    p.write_text(yaml.safe_dump({**_doc(bench_dict), "version": "one"}))
    with pytest.raises(CalibrationError, match="version: expected a whole number"):
        Calibration.load_yaml(p)
    p.write_bytes(b"\x89MCAP0\r\n\x01\x02")
    with pytest.raises(CalibrationError, match="not text"):
        Calibration.load_yaml(p)


def test_what_the_bench_and_calibrate_write_reads_back(tmp_path, bench_dict):
    cal = Calibration.from_dict(bench_dict, where="bench")  # the record, with its evaluation_only: false
    assert bench_dict["evaluation_only"] is False
    with pytest.raises(CalibrationError, match="ground truth"):
        Calibration.from_dict({**bench_dict, "evaluation_only": True})
    # what `tiplog calibrate block|hand-eye|intrinsics` write: replace() on a loaded file, with a report
    T = cal.T_base_camera.copy()
    T[:3, 3] += 0.001
    for i, new in enumerate(
        (
            cal,
            dataclasses.replace(cal, T_base_camera=T),
            dataclasses.replace(
                cal, intrinsics={"fx": 650.0, "fy": 649.0, "cx": 640.5, "cy": 360.2, "dist": [0.0] * 5}
            ),
            dataclasses.replace(cal, latency_ms={**cal.latency_ms, "camera": 41.3}),
        )
    ):
        p = tmp_path / f"out{i}.yaml"
        new.save_yaml(p, extra={"hand_eye": {"poses": 30, "T_tool_marker": np.eye(4).tolist()}})
        assert Calibration.load_yaml(p).to_dict() == new.to_dict()  # every digit


def test_cli_names_the_field_in_one_line(tmp_path, capsys, bench_dict):
    # the inputs exist: they are checked before --base is read
    (tmp_path / "poses.csv").write_text("x\n")
    (tmp_path / "images").mkdir()
    cv2.imwrite(str(tmp_path / "images" / "v00.png"), np.zeros((8, 8), np.uint8))
    for path, value, field in (
        ("tof_plane_h_m", float("nan"), "tof_plane_h_m"),
        ("shaft_radius_m", "abc", "shaft_radius_m"),
        ("R_tool_imu", R_NOT_ROTATION, "R_tool_imu"),
        ("intrinsics.fx", -5.0, "intrinsics.fx"),
    ):
        base = _write(tmp_path, _set(bench_dict, path, value), "base.yaml")
        for argv in (
            ["calibrate", "hand-eye", str(tmp_path / "poses.csv"), "--base", str(base)],
            ["calibrate", "intrinsics", str(tmp_path / "images"), "--base", str(base)],
        ):
            assert main([*argv, "--out", str(tmp_path / "out.yaml")]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and str(base) in err[0] and field in err[0], err
    assert not (tmp_path / "out.yaml").exists()

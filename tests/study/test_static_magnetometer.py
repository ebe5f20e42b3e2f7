"""The magnetometer study: TRIAD, field-to-gravity angle and heading drift on exact vectors,
and the study's numbers on a short bench rotation session."""

from __future__ import annotations

import json

import numpy as np
import pytest

from study.static_magnetometer import main
from tiplog.calibration.fits.magnetometer import field_gravity_angle_deg, hold_drift_deg, triad_rotation_angle_deg
from tiplog.cli import main as tiplog_main
from tiplog.geometry import so3_exp

G = np.array([0.0, 0.0, 9.80665])  # specific force at rest, base frame (up)
B = 48.0 * np.array([np.cos(np.radians(64.0)), 0.0, -np.sin(np.radians(64.0))])  # inclination 64 deg


def _body(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("nji,j->ni", R, v)


def test_triad_angle_and_field_angle_exact_for_an_undisturbed_field():
    rng = np.random.default_rng(0)
    R0 = so3_exp(rng.normal(size=(20, 3)))
    rel = so3_exp(rng.normal(size=(20, 3)) * 0.5)
    R1 = rel @ R0
    ang = triad_rotation_angle_deg(_body(R0, G), _body(R0, B), _body(R1, G), _body(R1, B))
    true_deg = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert np.allclose(ang, true_deg, atol=1e-6)
    assert np.allclose(field_gravity_angle_deg(_body(R0, G), _body(R0, B)), 26.0, atol=1e-9)


def test_heading_drift_sees_a_field_change_that_tilt_does_not():
    R = so3_exp(np.array([[0.1, -0.2, 0.3]]))
    a, m = _body(R, G)[0], _body(R, B)[0]
    assert hold_drift_deg(a, m, a, m) == pytest.approx((0.0, 0.0), abs=1e-5)
    disturbed = m + _body(R, np.array([0.0, 3.0, 0.0]))[0]  # 3 uT horizontal disturbance
    h, tilt = hold_drift_deg(a, m, a, disturbed)
    assert h == pytest.approx(np.degrees(np.arctan2(3.0, 48.0 * np.cos(np.radians(64.0)))), abs=0.05)
    assert tilt == pytest.approx(0.0, abs=1e-5)


@pytest.mark.slow
def test_study_on_a_short_rotation_session(tmp_path, capsys):
    rot = tmp_path / "rot.mcap"
    assert (
        tiplog_main(["sim", "generate", "--scenario", "rotation", "--out", str(rot), "--seed", "5", "--duration", "90"])
        == 0
    )
    out = tmp_path / "mag.json"
    assert main([str(rot), "--json", str(out)]) == 0
    r = json.loads(out.read_text())["rotation"]
    assert r["trials"] >= 5
    assert 0.0 < r["triad_angle_rmse_deg"] < 20.0
    # bench field: inclination 64 deg, so 26 deg to gravity, moved by pose-dependent disturbance
    assert 20.0 < r["field_gravity_angle_deg"]["mean"] < 32.0
    assert r["field_gravity_change_in_trial_deg"]["max"] > 0.0
    capsys.readouterr()
    assert main([str(rot), "--json", str(out)]) == 2
    assert "--force" in capsys.readouterr().err

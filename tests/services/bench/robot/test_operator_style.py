"""The teleop operator's style: tremor, hesitation pauses and detours on the drawn motion."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from pydantic import ValidationError

from services.bench.robot.motion import MotionConfig, build_command
from services.bench.robot.operator_style import OperatorStyle, hesitation_clock


@lru_cache(maxsize=8)
def _teleop(**operator):
    """Block 1 of seed 5's teleop, as this operator moves it (built once per test run)."""
    return build_command(MotionConfig(**operator), "teleop1", 5)


def _speed_mps(cmd, rate_hz: float = 1000.0) -> np.ndarray:
    return np.linalg.norm(np.gradient(cmd.p_raw_m, axis=0), axis=1) * rate_hz


def test_default_operator_leaves_the_drawn_motion_unchanged():
    assert not OperatorStyle().active
    base = _teleop()
    same = _teleop(operator_tremor_hz=6.0, operator_pause_s=3.0)
    assert np.array_equal(base.p_raw_m, same.p_raw_m) and np.array_equal(base.roll_rad, same.roll_rad)


def test_hesitant_operator_shares_the_path_and_stops_on_it():
    base = _teleop()
    hes = _teleop(operator_pauses_per_min=3.0, operator_pause_s=1.0)
    assert base.trials[0]["draw"] == hes.trials[0]["draw"]  # the same intended motion
    assert len(hes.p_raw_m) == len(base.p_raw_m)
    assert np.allclose(hes.p_raw_m[-1], base.p_raw_m[-1])  # and the same end
    mv = slice(base.trials[0]["move_start"], base.trials[0]["move_end"])
    still = _speed_mps(hes)[mv] < 1e-4
    assert still.sum() >= 6 * 900 > (_speed_mps(base)[mv] < 1e-4).sum()  # six 1 s stops, ramps aside
    # every point the hesitant operator visits lies on the intended path
    step = 50
    d = np.linalg.norm(hes.p_raw_m[mv][::step, None] - base.p_raw_m[mv][None, ::5], axis=2).min(1)
    assert d.max() < 2e-4


def test_tremor_adds_motion_at_its_frequency():
    base = _teleop()
    shaky = _teleop(operator_tremor_mm=0.1, operator_tremor_hz=9.0)
    mv = slice(base.trials[0]["move_start"] + 10_000, base.trials[0]["move_end"] - 10_000)
    diff = (shaky.p_raw_m - base.p_raw_m)[mv]
    assert np.sqrt(np.mean(np.sum(diff**2, 1))) == pytest.approx(np.sqrt(2) * 1e-4, rel=0.2)
    spec = np.abs(np.fft.rfft(diff[:, 0] - diff[:, 0].mean()))
    f = np.fft.rfftfreq(len(diff), 1e-3)
    assert 7.0 < f[np.argmax(spec)] < 11.0


def test_hesitation_clock_is_monotone_and_spans_the_block():
    clock = hesitation_clock(np.random.default_rng(0), 10_000, 100.0, 3, 1.0, 600)
    assert clock[0] == 0.0 and clock[-1] == pytest.approx(9_999.0)
    assert np.all(np.diff(clock) >= 0.0)
    assert np.sum(np.diff(clock) == 0.0) >= 3 * 100 - 3


def test_operator_fields_are_range_checked():
    with pytest.raises(ValidationError, match="operator_tremor_mm"):
        MotionConfig(operator_tremor_mm=5.0)
    with pytest.raises(ValidationError, match="operator_pauses_per_min"):
        MotionConfig(operator_pauses_per_min=-1.0)


def test_the_hesitant_scenario_differs_from_teleop_only_in_the_operator():
    from pathlib import Path

    from services.bench.scenario import load_scenario, scenario_dict

    path = Path(__file__).parents[4] / "benchmarks" / "scenarios" / "teleop_hesitant.yaml"
    a, b = scenario_dict(load_scenario(path)), scenario_dict(load_scenario("teleop"))
    a.pop("name"), b.pop("name")
    ma, mb = a.pop("motion"), b.pop("motion")
    assert a == b
    changed = {k for k in ma if ma[k] != mb[k]}
    assert changed and all(k.startswith("operator_") for k in changed)

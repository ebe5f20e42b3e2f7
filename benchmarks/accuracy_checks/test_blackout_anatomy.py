"""The blackout benchmark recovers the bench's gyro walk from the recording and ties the heading
lost over a blackout to it: with the walk (and the scale error, which reads as a bias that moves
with the rate) switched off the recovered bias does not move and the held bias drifts by
nothing; with a walk ten times the bench's the heading lost over each blackout follows the drift
of the bias held from its start, a little less of it when the working depth is held as tightly
as vision saw it steady (the ToF then ties the heading). The filter's own heading sigma, which
expects the bench's walk, covers the first and not the second."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import blackout_anatomy
from tests.benchmarks.test_blackout_anatomy import _rows, _session

pytestmark = pytest.mark.slow


def test_the_heading_lost_in_a_blackout_follows_the_gyro_walk(tmp_path):
    still = _rows(
        tmp_path,
        _session(
            tmp_path / "still.mcap",
            "gyro.bias_rw_motion_dps_rts_per_radps=0",
            "gyro.bias_rw_static_dps_rts=0",
            "gyro.scale_sd=0",
        ),
    )
    for r in still:
        assert r["bias_walk_dps"] < 0.05, r  # the recovered bias stays put (white noise left)
        # what drifts is the bias error the blackout began with, held for its 10 s
        assert abs(r["gyro_drift_deg"]) <= 10.0 * r["bias_error_start_dps"] + 0.1, r
        assert abs(r["heading_change_deg"]) < 1.0, r
    # the filter expects the bench's walk, which is off here: it loses less than it fears
    assert np.sqrt(np.mean(blackout_anatomy.heading_z(still) ** 2)) < 1.0
    walking_session = _session(tmp_path / "walking.mcap", "gyro.bias_rw_motion_dps_rts_per_radps=3.5")
    loose = tmp_path / "loose_depth.yaml"
    loose.write_text("depth_anchor_learn_spread: false\n")
    walking_loose = _rows(tmp_path, walking_session, loose)
    walking = _rows(tmp_path, walking_session)
    assert max(r["bias_walk_dps"] for r in walking) > 0.3
    # each run's heading against the drift of the bias it held: the two runs start their
    # blackouts with different bias estimates, so their drifts differ
    d = np.array([r["gyro_drift_deg"] for r in walking])
    d_loose = np.array([r["gyro_drift_deg"] for r in walking_loose])
    assert np.max(np.abs(d)) > 5.0
    # with the working depth held loosely (5 mm) nothing else holds the heading for 10 s:
    # not gravity, not the RCM, hardly the ToF
    h_loose = np.array([r["heading_change_deg"] for r in walking_loose])
    assert np.corrcoef(h_loose, d_loose)[0, 1] > 0.9
    assert 0.7 < np.polyfit(d_loose, h_loose, 1)[0] < 1.3
    # held as tightly as the depth was steady with vision, the ToF's range to the plane ties
    # the heading a little: the same walk, less of it lost
    h = np.array([r["heading_change_deg"] for r in walking])
    assert np.corrcoef(h, d)[0, 1] > 0.9
    assert 0.4 < np.polyfit(d, h, 1)[0] < np.polyfit(d_loose, h_loose, 1)[0]
    # a walk ten times the one the filter expects: it loses far more than its sigma says
    assert np.sqrt(np.mean(blackout_anatomy.heading_z(walking) ** 2)) > 2.0
    for r in walking:
        assert 0.0 < r["heading_sigma_start_deg"] < r["heading_sigma_end_deg"], r

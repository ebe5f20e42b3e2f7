"""The fidelity report's gyro-wander row on two generated roll sweeps."""

from __future__ import annotations

import pytest

from services.bench.scenario import load_scenario
from services.bench.session import generate


@pytest.mark.slow
def test_gyro_wander_row_sees_the_bias_random_walk_not_one_draw(tmp_path):
    """The roll sweep's bias wander is graded from its 1 s block statistics: the bench's bias that
    moves in motion passes, the same sweep with a bias that only creeps at rest fails."""
    from services.bench.report.data import load
    from services.bench.report.fidelity import gyro_drift_row

    rows = {}
    for name, extra in (("moving", []), ("still", ["gyro.bias_rw_motion_dps_rts_per_radps=0"])):
        path = tmp_path / f"{name}.mcap"
        generate(load_scenario("sweeps", ["protocol=sweep_roll", *extra]), path, seed=3)
        rows[name] = gyro_drift_row(load(path))
    assert rows["moving"].status == "PASS", rows["moving"]
    assert rows["still"].status == "FAIL" and rows["still"].value < 0.5 * rows["moving"].value, rows["still"]
    assert "this draw" in rows["moving"].note

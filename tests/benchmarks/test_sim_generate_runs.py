"""The generation benchmark still runs against the current generator (its figures are
quoted in notes; a renamed timing key once broke it silently)."""

from __future__ import annotations

import json

import pytest

from benchmarks import sim_generate

pytestmark = pytest.mark.slow


def test_benchmark_reports_every_stage(capsys):
    assert sim_generate.main(["--scenario", "fit", "--duration", "5", "--json"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in ("robot_s", "models_s", "encode_s", "write_s", "total_s"):
        assert res[key] >= 0.0
    assert res["messages"] > 5 * 600  # five seconds of device streams at least

"""The blackout benchmark's command line: a recording without the bench's truth is refused in
one line. Its accuracy check (the heading lost in a blackout follows the gyro walk) is
benchmarks/accuracy_checks/test_blackout_anatomy.py, on the helpers here."""

from __future__ import annotations

import json

import pytest

from benchmarks import blackout_anatomy
from tiplog.cli import main as tiplog_main

pytestmark = pytest.mark.slow


def _session(path, *sets, duration_s: float = 120.0):
    args = ["sim", "generate", "--scenario", "sweeps", "--seed", "7", "--duration", f"{duration_s:g}"]
    args += ["--out", str(path), "--quiet"]
    for s in sets:
        args += ["--set", s]
    assert tiplog_main(args) == 0
    return path


def _rows(tmp_path, session, params=None):
    out = tmp_path / f"{session.stem}{'' if params is None else '_' + params.stem}.json"
    extra = [] if params is None else ["--params", str(params)]
    assert blackout_anatomy.main([str(session), "--length", "10", "--count", "6", "--json", str(out), *extra]) == 0
    rows = json.loads(out.read_text())
    assert len(rows) >= 3 and {r["session"] for r in rows} == {session.name}
    return rows


def test_a_recording_without_the_truth_is_one_line_and_status_2(tmp_path, capsys):
    src = _session(tmp_path / "s.mcap", duration_s=5.0)  # refused before any blackout is cut
    from tests.services.fusion.sessions import rewrite

    dst = tmp_path / "no_truth.mcap"
    rewrite(src, dst, lambda t: True, lambda name: name != "calibration_truth")
    assert blackout_anatomy.main([str(dst)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calibration_truth" in err[0]

"""The error-frame benchmark's command line: an unknown --swap field is one clear line. Its
accuracy check (a mounting error lands along the line of sight) is
benchmarks/accuracy_checks/test_error_frame.py, on the helper here."""

from __future__ import annotations

import json

import pytest

from benchmarks import error_frame

pytestmark = pytest.mark.slow


def _rows(tmp_path, session, *extra):
    out = tmp_path / f"rows{len(extra)}.json"
    assert error_frame.main([str(session), "--json", str(out), *extra]) == 0
    rows = json.loads(out.read_text())
    assert [r["block"] for r in rows] == ["sweep_pitch"]
    return rows[0]


def test_an_unknown_swap_field_is_one_clear_line(tmp_path, capsys):
    assert error_frame.main([str(tmp_path / "absent.mcap"), "--swap", "R_tool_imu,bogus"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error_frame: --swap: unknown field 'bogus'") and "\n" not in err

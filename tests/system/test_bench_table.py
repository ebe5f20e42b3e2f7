"""`python -m benchmarks` runs benchmark modules as their own processes and ends with one
table; a module's own `main` still runs alone; a wrong name is one line and exit 2."""

from __future__ import annotations

import subprocess
import sys

import pytest

from benchmarks.__main__ import Row, bus_latency, table
from tests.conftest import ROOT


@pytest.mark.slow
def test_quick_bus_latency_ends_with_one_table():
    p = subprocess.run(
        [sys.executable, "-m", "benchmarks", "--quick", "--only", "bus_latency"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    lines = p.stdout.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("benchmark"))
    assert lines[head].split() == ["benchmark", "figure", "value", "unit", "target", "pass"]
    rows = lines[head + 2 :]
    assert any("tiplog bus p99" in r for r in rows) and any("raw Zenoh p99" in r for r in rows), p.stdout
    tiplog_row = next(r for r in rows if "tiplog bus p99" in r)
    assert tiplog_row.split()[-1] in ("PASS", "FAIL")
    assert p.returncode == (1 if "FAIL" in tiplog_row else 0)


def test_unknown_benchmark_is_one_line_exit_2():
    p = subprocess.run(
        [sys.executable, "-m", "benchmarks", "--only", "nope"], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0 and "nope" in p.stderr and "bus_latency" in p.stderr


def test_bus_latency_rows_judge_the_tiplog_transport_only():
    out = (
        '{"rate_hz": 1000, "rows": [{"transport": "zenoh", "lost": 0, "p50_ms": 0.1, "p99_ms": 9.0}, '
        '{"transport": "tiplog", "lost": 3, "p50_ms": 0.1, "p99_ms": 1.0}]}'
    )
    rows = bus_latency(out, ROOT)
    judged = [r for r in rows if r.ok is not None]
    assert len(judged) == 1 and "tiplog" in judged[0].figure and judged[0].ok is False  # 3 lost
    text = table(rows + [Row("x", "y", None, "", "", None)])
    assert text.splitlines()[0].split() == ["benchmark", "figure", "value", "unit", "target", "pass"]
    assert "FAIL" in text

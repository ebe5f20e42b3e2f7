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
    assert lines[head].split() == ["benchmark", "figure", "value", "unit", "target", "pass", "load"]
    rows = lines[head + 2 :]
    assert any("tiplog bus p99" in r for r in rows) and any("raw Zenoh p99" in r for r in rows), p.stdout
    tiplog_row = next(r for r in rows if "tiplog bus p99" in r)
    assert tiplog_row.split()[-2] in ("PASS", "FAIL")  # then the load column
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
    assert text.splitlines()[0].split() == ["benchmark", "figure", "value", "unit", "target", "pass", "load"]
    assert "FAIL" in text


def _fake_benchmark(monkeypatch, tmp_path, script: str, parse) -> None:
    """`python -m benchmarks.<module>` replaced by a shell script (the seam: the interpreter)."""
    import benchmarks.__main__ as bm

    exe = tmp_path / "fake-python"
    exe.write_text("#!/bin/sh\n" + script)
    exe.chmod(0o755)
    monkeypatch.setattr(bm.sys, "executable", str(exe))
    monkeypatch.setitem(bm.BENCHMARKS, "vision_frame", ("vision_frame", [], [], parse))


def test_a_benchmark_that_hangs_is_a_row_and_leaves_nothing_running(monkeypatch, tmp_path):
    from benchmarks.__main__ import run_one

    pid_file = tmp_path / "child.pid"
    # the benchmark starts a child that holds the output pipe open, then hangs
    _fake_benchmark(monkeypatch, tmp_path, f"sleep 60 &\necho $! > {pid_file}\necho started\nsleep 60\n", None)
    rows, out = run_one("vision_frame", False, tmp_path, timeout_s=1.0)
    assert "started" in out
    (row,) = rows
    assert row.figure.startswith("timed out after 1 s") and row.ok is False
    assert row.unit and row.target  # still says what it measures and against what
    child = int(pid_file.read_text())
    assert _ends(child), "the benchmark's child outlived it"


def _ends(pid: int, within_s: float = 10.0) -> bool:
    """True once `pid` is gone or a zombie (killed; its new parent may reap it later)."""
    import time
    from pathlib import Path

    deadline = time.monotonic() + within_s
    while True:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (FileNotFoundError, ProcessLookupError):
            return True
        if state in ("Z", "X"):
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)


def test_a_crash_or_unreadable_output_is_a_row(monkeypatch, tmp_path):
    from benchmarks.__main__ import run_one

    def broken(out, tmp):
        return [Row("vision_frame", "x", 1.0 / int(out.strip() == "nope"), "ms", "", None)]  # ZeroDivisionError

    _fake_benchmark(monkeypatch, tmp_path, "echo fine\n", broken)
    (row,) = run_one("vision_frame", False, tmp_path, 60.0)[0]
    assert "unreadable output: ZeroDivisionError" in row.figure and row.ok is False and row.target
    _fake_benchmark(monkeypatch, tmp_path, "echo torch missing >&2\nexit 3\n", broken)
    (row,) = run_one("vision_frame", False, tmp_path, 60.0)[0]
    assert row.figure == "failed (exit 3): torch missing" and row.ok is False


def test_vision_rows_say_unit_and_target(tmp_path):
    import json

    from benchmarks.__main__ import vision_frame

    pct = {"p50": 30.0, "p95": 40.0, "mean": 31.0}
    report = {
        "torch_threads": 1,
        "per_frame": {f"{s}{k}": pct for s in ("labeler", "network", "total") for k in ("_ms", "_cpu_ms")},
        "vision_run": [{"workers": 1, "fps": 14.0}, {"workers": 2, "fps": 25.0}],
    }
    (tmp_path / "vision_frame.json").write_text(json.dumps(report))
    rows = vision_frame("", tmp_path)
    assert all(r.unit for r in rows)
    fps = [r for r in rows if r.unit == "frames/s"]
    assert [(r.target, r.ok) for r in fps] == [(">= 15", False), (">= 15", True)]
    (total,) = [r for r in rows if r.figure.startswith("total CPU p50")]
    assert total.target == "<= 66.7 (15 fps)" and total.ok is True
    assert "none" in table(rows)  # figures without a target say so

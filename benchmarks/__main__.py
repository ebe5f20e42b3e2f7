"""`make bench` (`python -m benchmarks`): the system's benchmarks, each run as its own process
(`python -m benchmarks.<name> ...`, every module keeps its own `main`), then ONE table:
benchmark, figure, value, unit, target ("none": a figure for comparison), pass, and the host's
load average when the benchmark ended. A benchmark that times out, fails or prints nothing
readable is one row saying why (with its unit and target), never the end of the table.

    python -m benchmarks            # full runs (tens of minutes on a small machine)
    python -m benchmarks --quick    # short runs of each (a few minutes)
    python -m benchmarks --only bus_latency,fusion_offline

Every other module in this folder still runs alone (`python -m benchmarks.<name> --help`).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class Row:
    benchmark: str
    figure: str
    value: float | None
    unit: str
    target: str  # "" for a figure given for comparison (printed as "none")
    ok: bool | None  # None: no target (a figure for comparison)
    load: float | None = None  # the host's 1-min load average when the benchmark ended


def _json_line(out: str) -> dict:
    for line in reversed(out.splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise ValueError("no JSON line in the output")


def _num(pattern: str, out: str) -> float:
    m = re.search(pattern, out)
    if not m:
        raise ValueError(f"not found in the output: {pattern}")
    return float(m.group(1))


def fusion_offline(out: str, _tmp: Path) -> list[Row]:
    r = _json_line(out)
    v = r["filter_s_per_120s"]
    return [Row("fusion_offline", "filter CPU per 120 s block", v, "s", "<= 2.4", v <= 2.4)]


def vision_frame(_out: str, tmp: Path) -> list[Row]:
    r = json.loads((tmp / "vision_frame.json").read_text())
    pf = r["per_frame"]
    threads = r.get("torch_threads", 1)
    rows = []
    for stage in ("labeler", "network", "total"):
        cpu = pf[f"{stage}_cpu_ms"]
        target, ok = ("<= 66.7 (15 fps)", cpu["p50"] <= 66.7) if stage == "total" else ("", None)
        rows.append(Row("vision_frame", f"{stage} CPU p50 ({threads} thread)", cpu["p50"], "ms", target, ok))
        rows.append(Row("vision_frame", f"{stage} CPU p95", cpu["p95"], "ms", "", None))
    wall = pf["total_ms"]
    rows.append(Row("vision_frame", "total wall p50 (load-dependent)", wall["p50"], "ms", "", None))
    for run in r.get("vision_run", []):
        fps = run["fps"]
        figure = f"tiplog vision run --workers {run['workers']}, sustained"
        rows.append(Row("vision_frame", figure, fps, "frames/s", ">= 15", fps >= 15))
    return rows


def recorder(out: str, _tmp: Path) -> list[Row]:
    v = _num(r"lz4: sustained x([\d.]+) of the live rate", out)
    return [Row("recorder_throughput", "sustained, zero drops (lz4)", v, "x live rate", ">= 1", v >= 1)]


def bus_latency(out: str, _tmp: Path) -> list[Row]:
    r = _json_line(out)
    rows = []
    for t in r["rows"]:
        name = "tiplog bus" if t["transport"] == "tiplog" else "raw Zenoh"
        ok = t["lost"] == 0 and t["p99_ms"] < 5.0 if t["transport"] == "tiplog" else None
        rows.append(Row("bus_latency 1 kHz", f"{name} p50", t["p50_ms"], "ms", "", None))
        rows.append(Row("bus_latency 1 kHz", f"{name} p99 ({t['lost']} lost)", t["p99_ms"], "ms", "< 5, 0 lost", ok))
    return rows


def display_lag(out: str, _tmp: Path) -> list[Row]:
    p95 = _num(r"websocket message leaves: p50 [\d.]+ ms, p95 ([\d.]+) ms", out)
    p50 = _num(r"websocket message leaves: p50 ([\d.]+) ms", out)
    return [
        Row("display_lag (whole system)", "state time -> websocket, p50", p50, "ms", "<= 33 (paper)", p50 <= 33),
        Row("display_lag (whole system)", "state time -> websocket, p95", p95, "ms", "", None),
    ]


def igtlink_lag(out: str, _tmp: Path) -> list[Row]:
    r = _json_line(out)
    ok = r["rate_hz"] >= 0.95 * r["configured_hz"]
    return [
        Row("igtlink (3D Slicer)", "transforms", r["rate_hz"], "Hz", f">= {0.95 * r['configured_hz']:g}", ok),
        Row("igtlink (3D Slicer)", "state stamp -> client, p50", r["lag_p50_ms"], "ms", "", None),
        Row("igtlink (3D Slicer)", "state stamp -> client, p95", r["lag_p95_ms"], "ms", "", None),
    ]


def cpu_share(out: str, _tmp: Path) -> list[Row]:
    r = _json_line(out)
    rows = []
    for n, s in r["services"].items():
        rows.append(Row(f"demo CPU ({r['tier']} tier)", n, s["cpu_percent"], "% of a core", "", None))
    total = sum(s["cpu_percent"] for s in r["services"].values())
    cap = 100 * (r["cpu_count"] or 1)
    rows.append(Row(f"demo CPU ({r['tier']} tier)", "all services", total, "% of a core", f"< {cap}", total < cap))
    rates = r.get("rates_hz", {})
    if "fusion/state" in rates:  # the demo stays live: one state per gyro sample
        hz = rates["fusion/state"]
        rows.append(Row(f"demo rates ({r['tier']} tier)", "fusion/state", hz, "Hz", ">= 190 (gyro 200)", hz >= 190))
    if "vision/observation" in rates:
        rows.append(
            Row(
                f"demo rates ({r['tier']} tier)",
                "vision/observation",
                rates["vision/observation"],
                "Hz",
                "15 (camera)",
                None,
            )
        )
    return rows


# name -> (module, full args, quick args, parser)
BENCHMARKS: dict[str, tuple[str, list[str], list[str], Callable[[str, Path], list[Row]]]] = {
    "fusion_offline": ("fusion_offline", ["--json"], ["--json", "--seconds", "30", "--repeat", "1"], fusion_offline),
    "vision_frame": (
        "vision_frame",
        ["--json", "{tmp}/vision_frame.json"],
        ["--json", "{tmp}/vision_frame.json", "--duration", "3", "--frames", "15", "--workers", "2"],
        vision_frame,
    ),
    "recorder": (
        "recorder_throughput",
        [],
        ["--compression", "lz4", "--multiples", "1", "2", "--seconds", "3"],
        recorder,
    ),
    "bus_latency": ("system_bus_latency", ["--json"], ["--json", "--seconds", "3"], bus_latency),
    "display_lag": ("dashboard_e2e", [], ["--seconds", "8"], display_lag),
    "igtlink_lag": ("igtlink_lag", ["--json"], ["--json", "--seconds", "8"], igtlink_lag),
    "cpu_share": (
        "system_soak",
        ["--json", "--tier", "pixel", "--seconds", "120"],
        ["--json", "--tier", "pixel", "--seconds", "30"],
        cpu_share,
    ),
}


# What a benchmark's main figure is measured in and against: a row that says why a benchmark
# gave no figure (timed out, failed, unreadable output) still names both.
HEADLINE: dict[str, tuple[str, str]] = {
    "fusion_offline": ("s", "<= 2.4"),
    "vision_frame": ("ms, frames/s", "<= 66.7 ms a frame, >= 15 frames/s"),
    "recorder": ("x live rate", ">= 1"),
    "bus_latency": ("ms", "p99 < 5, 0 lost"),
    "display_lag": ("ms", "p50 <= 33 (paper)"),
    "igtlink_lag": ("Hz", ">= 95 % of rate_hz"),
    "cpu_share": ("% of a core", "below the machine's cores"),
}


def _no_figure(name: str, why: str) -> list[Row]:
    unit, target = HEADLINE.get(name, ("", ""))
    return [Row(name, why[:90], None, unit, target, False)]


def _kill_group(p: subprocess.Popen) -> None:
    """The benchmark and whatever it started (the vision benchmark runs `tiplog vision run`,
    the system ones a whole `tiplog up`): left alive, they would hold the output pipes open."""
    try:
        os.killpg(p.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        p.kill()


def run_one(name: str, quick: bool, tmp: Path, timeout_s: float) -> tuple[list[Row], str]:
    """The benchmark's rows; a timeout, a crash or output that cannot be read gives one row
    saying so (never an exception: the table is printed whatever happens)."""
    module, full, short, parse = BENCHMARKS[name]
    args = [a.replace("{tmp}", str(tmp)) for a in (short if quick else full)]
    cmd = [sys.executable, "-m", f"benchmarks.{module}", *args]
    print(f"== {' '.join(['python', *cmd[1:]])}", flush=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    try:
        p = subprocess.Popen(
            cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
        )
    except OSError as e:
        return _no_figure(name, f"could not start: {e}"), ""
    try:
        out, err = p.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        _kill_group(p)
        out, _ = p.communicate()
        sys.stdout.write(out or "")
        return _no_figure(name, f"timed out after {timeout_s:g} s (load {os.getloadavg()[0]:.1f})"), out or ""
    except BaseException:  # Ctrl-C: nothing of the benchmark outlives the table
        _kill_group(p)
        raise
    sys.stdout.write(out)
    if p.returncode != 0:
        tail = err.strip().splitlines()[-1:] or ["?"]
        return _no_figure(name, f"failed (exit {p.returncode}): {tail[0][:70]}"), out
    try:
        rows = parse(out, tmp)
    except Exception as e:  # any parse error is a row, never the end of the table
        return _no_figure(name, f"unreadable output: {e.__class__.__name__}: {e}"), out
    return rows or _no_figure(name, "no figure in the output"), out


def table(rows: list[Row]) -> str:
    head = ("benchmark", "figure", "value", "unit", "target", "pass", "load")
    body = [
        (
            r.benchmark,
            r.figure,
            "-" if r.value is None else f"{r.value:.3g}" if abs(r.value) < 100 else f"{r.value:.0f}",
            r.unit or "-",
            r.target or "none",
            "-" if r.ok is None else "PASS" if r.ok else "FAIL",
            "-" if r.load is None else f"{r.load:.1f}",
        )
        for r in rows
    ]
    w = [max(len(x[i]) for x in [head, *body]) for i in range(len(head))]
    lines = ["  ".join(c.ljust(w[i]) for i, c in enumerate(x)).rstrip() for x in [head, *body]]
    lines.insert(1, "  ".join("-" * n for n in w))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short runs of each benchmark")
    ap.add_argument("--only", help=f"comma list of {', '.join(BENCHMARKS)}")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds each benchmark may take")
    ap.add_argument("--json", help="also write the table here (JSON)")
    a = ap.parse_args(argv)
    names = a.only.split(",") if a.only else list(BENCHMARKS)
    unknown = [n for n in names if n not in BENCHMARKS]
    if unknown:
        print(f"--only: unknown benchmark(s) {', '.join(unknown)}; known: {', '.join(BENCHMARKS)}", file=sys.stderr)
        return 2
    rows: list[Row] = []
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="tiplog-bench-") as d:
        for name in names:
            got, _ = run_one(name, a.quick, Path(d), a.timeout)
            load = os.getloadavg()[0]
            for r in got:
                r.load = load
            rows += got
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"\n{'quick' if a.quick else 'full'} run, {time.monotonic() - t0:.0f} s; host load {load:.1f} on {os.cpu_count()} CPUs"
    )
    print(table(rows))
    if a.json:
        Path(a.json).write_text(json.dumps([r.__dict__ for r in rows], indent=1))
    return 1 if any(r.ok is False for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())

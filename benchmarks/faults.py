"""kill -9 of each service of `tiplog up`, then of `tiplog up` itself, on the whole simulated
system (measurement tier, real processes, the device through a pseudo-terminal). Per fault:
the time until the killed service's data flows again, what each topic lost (the longest hole
in the recordings around the fault), what the files hold and what `tiplog info` says.

    nice -n 10 python -m benchmarks.faults [--settle 8] [--faults fusion,bench] [--json out.json]

Data flowing again: bench -> bench/robot, sensor_gateway -> device/gyro, fusion ->
fusion/state, vision -> its liveliness token (the measurement tier sends it no frames),
recorder -> the first message its new file holds (log time after the kill), dashboard ->
GET /api/state answering, `tiplog up` -> a new `tiplog up` with device/gyro flowing again.
Times are host monotonic seconds from the kill.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

from services.recorder.info import inspect
from tests.system.harness import R, UpRun, system_config
from tiplog.clock import now_ns
from tiplog.mcap_io import raw_messages, read_summary, topic_spans
from tiplog.userio import UserError

ROOT = Path(__file__).resolve().parents[1]
SERVICES = ["bench", "sensor_gateway", "vision", "fusion", "recorder", "dashboard"]
FLOW_TOPIC = {"bench": "bench/robot", "sensor_gateway": "device/gyro", "fusion": "fusion/state"}
WATCHED = ("bench/robot", "device/gyro", "device/accel", "device/tof", "fusion/state", "recorder/status")
TARGET_S = {"recorder": 1.0, "fusion": 1.0, "bench": 2.0}


class Arrivals:
    """Receive times (now_ns) per topic on the benchmark's own bus session."""

    def __init__(self) -> None:
        self.times: dict[str, list[int]] = defaultdict(list)
        self.lock = threading.Lock()
        self.alive: dict[str, bool] = {}

    def on(self, topic: str):
        def cb(_msg, info) -> None:
            with self.lock:
                self.times[topic].append(info.receive_ns)

        return cb

    def first_after(self, topic: str, t_ns: int) -> int | None:
        with self.lock:
            return next((t for t in self.times[topic] if t > t_ns), None)


def _wait(pred, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        time.sleep(0.02)


def _recovered(paths: list[Path]) -> list[Path]:
    """Each recording readable: a file cut short by SIGKILL through `tiplog record recover`."""
    out = []
    for p in paths:
        if p.name.endswith(".recovered.mcap"):
            continue
        try:
            intact = read_summary(p) is not None
        except UserError:  # cut short: no footer, a truncated record
            intact = False
        if intact:
            out.append(p)
            continue
        fixed = p.with_suffix(".recovered.mcap")
        subprocess.run(
            [sys.executable, "-m", "tiplog.cli", "record", "recover", str(p), "--out", str(fixed), "--force"],
            cwd=ROOT,
            check=True,
            capture_output=True,
            timeout=300,
        )
        out.append(fixed)
    return out


def _holes(paths: list[Path], windows: dict[str, tuple[int, int]]) -> dict[str, dict[str, float]]:
    """Per fault, per topic: the longest interval between consecutive log times (across every
    file) that begins in the fault's window (or up to 2 s before its kill: a cut file's
    unflushed tail) and ends after the kill, in seconds."""
    times: dict[str, list[int]] = defaultdict(list)
    for p in paths:
        for _schema, channel, message in raw_messages(p, WATCHED):
            times[channel.topic].append(message.log_time)
    out: dict[str, dict[str, float]] = {}
    for fault, (t0, t1) in windows.items():
        per: dict[str, float] = {}
        for topic, ts in times.items():
            ts.sort()
            worst = 0
            for a, b in zip(ts, ts[1:], strict=False):
                if b >= t0 and t0 - int(2e9) <= a <= t1:
                    worst = max(worst, b - a)
            per[topic] = round(worst / 1e9, 3)
        out[fault] = per
    return out


def run(settle_s: float, faults: Sequence[str] = (*SERVICES, "tiplog up")) -> dict:
    """Kill each of `faults` (services, then `tiplog up`) in turn; the figures of `analyse`."""
    tmp = Path(tempfile.mkdtemp(prefix="tiplog-faults-"))
    config = system_config(tmp)
    arrivals = Arrivals()
    results: dict[str, dict] = {}
    windows: dict[str, tuple[int, int]] = {}
    with UpRun(tmp, SERVICES, config=config) as up:
        up.wait_status(up.all_running, timeout_s=240)
        for topic in WATCHED:
            up.bus.subscribe(topic, arrivals.on(topic))
        up.poll_api("/api/state", lambda a: a["received"] > 400, 240)
        time.sleep(settle_s)
        for name in [n for n in SERVICES if n in faults]:
            pid = up.run_of(up.latest_status(), name).pid
            t_kill = now_ns()
            os.kill(pid, signal.SIGKILL)
            up.wait_status(lambda s, n=name: f"{n} killed by SIGKILL" in s.event, 60)
            back = up.wait_status(
                lambda s, n=name, p=pid: (
                    up.run_of(s, n).state == R.SERVICE_RUN_STATE_RUNNING and up.run_of(s, n).pid not in (0, p)
                ),
                120,
            )
            t_restart = back.header.stamp_ns
            r: dict = {"restart_s": round((t_restart - t_kill) / 1e9, 3)}
            if name in FLOW_TOPIC:
                topic = FLOW_TOPIC[name]
                _wait(
                    lambda t=topic, t0=t_restart: arrivals.first_after(t, t0) is not None, 120, f"{topic} after {name}"
                )
                r["flowing_s"] = round((arrivals.first_after(topic, t_restart) - t_kill) / 1e9, 3)
            elif name == "dashboard":
                up.poll_api("/api/state", lambda a: True, 120)
                r["flowing_s"] = round((now_ns() - t_kill) / 1e9, 3)
            elif name == "vision":
                up.poll_api("/api/health", lambda a: a["services"]["vision"]["state"] == "up", 120)
                r["flowing_s"] = round((now_ns() - t_kill) / 1e9, 3)
            else:  # recorder: measured on its new file below
                _wait(lambda: len(up.recordings()) >= 2, 60, "the recorder's new file")
            r["target_s"] = TARGET_S.get(name)
            r["t_kill_ns"] = t_kill
            results[name] = r
            windows[name] = (t_kill, t_kill + int(10e9))
            time.sleep(settle_s)
        if "tiplog up" not in faults:
            up.stop()
            (tmp / "faults.json").write_text(json.dumps({"results": results}))
            return analyse(tmp)
        t_kill = now_ns()
        pids = [run.pid for run in up.latest_status().services]
        os.kill(up.proc.pid, signal.SIGKILL)
        up.proc.wait(10)
        _wait(lambda: all(_gone(p) for p in pids), 60, "the services after tiplog up died")
        results["tiplog up"] = {"services_stopped_s": round((now_ns() - t_kill) / 1e9, 3), "t_kill_ns": t_kill}
    again = UpRun(tmp, SERVICES, config=config)
    again.endpoint = up.endpoint
    with again:
        t_start = now_ns()
        again.wait_status(again.all_running, timeout_s=240)
        flowing = threading.Event()
        again.bus.subscribe("device/gyro", lambda _m, _i: flowing.set())
        flowing.wait(240)
        results["tiplog up"]["new_up_gyro_s"] = round((now_ns() - t_start) / 1e9, 3)
        time.sleep(settle_s)
        assert again.stop() == 0
    windows["tiplog up"] = (results["tiplog up"]["t_kill_ns"], results["tiplog up"]["t_kill_ns"] + int(10e9))
    (tmp / "faults.json").write_text(json.dumps({"results": results, "windows": windows}))
    return analyse(tmp)


def analyse(tmp: Path) -> dict:
    """The figures from a run's folder (its faults.json and recordings)."""
    saved = json.loads((tmp / "faults.json").read_text())
    results = saved["results"]
    # each fault's window: from its kill for 10 s, ending 1 s before the next fault's
    kills = sorted((r["t_kill_ns"], name) for name, r in results.items())
    windows = {
        name: (t, min(t + int(10e9), kills[i + 1][0] - int(1e9) if i + 1 < len(kills) else t + int(10e9)))
        for i, (t, name) in enumerate(kills)
    }
    files = sorted((tmp / "rec").glob("*.mcap"))
    readable = _recovered(files)
    # the recorder's new file: its first message after the kill
    t_rec = results["recorder"]["t_kill_ns"] if "recorder" in results else None
    firsts = []
    for p in readable if t_rec is not None else []:
        spans = topic_spans(p, ["device/gyro"])
        if "device/gyro" in spans and spans["device/gyro"][0] > t_rec:
            firsts.append(spans["device/gyro"][0])
    if firsts:
        results["recorder"]["flowing_s"] = round((min(firsts) - t_rec) / 1e9, 3)
    holes = _holes(readable, windows)
    for fault, per in holes.items():
        results[fault]["longest_hole_s"] = per
    infos = []
    for p in readable:
        info = inspect(p)
        infos.append(
            {
                "file": p.name,
                "closed_validly": p in files,
                "duration_s": round(info["duration_s"], 2),
                "messages": info["messages"],
                "sequence_gaps": info["gaps"],
                "time_gaps": info["time_gaps"],
                "time_gaps_per_topic": {
                    t: (ti["time_gaps"], ti["time_gap_s"]) for t, ti in info["topics"].items() if ti["time_gaps"]
                },
                "replayed_supervisor_events": _replayed(p),
            }
        )
    return {"faults": results, "files": infos, "folder": str(tmp)}


def _replayed(path: Path) -> list[str]:
    from tiplog.mcap_io import read_messages

    return [r.message.event for r in read_messages(path, ["system/supervisor"]) if r.message.replayed]


def _gone(pid: int) -> bool:
    try:
        return "\nState:\tZ" in Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return True


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--settle", type=float, default=8.0, help="seconds of normal running between faults")
    ap.add_argument("--json", help="write the figures here as JSON")
    ap.add_argument(
        "--faults",
        default=",".join([*SERVICES, "tiplog up"]),
        help="which to kill, in this order (default: every service, then tiplog up)",
    )
    ap.add_argument("--analyse", metavar="FOLDER", help=argparse.SUPPRESS)  # figures of a finished run again
    a = ap.parse_args(argv)
    faults = [f.strip() for f in a.faults.split(",") if f.strip()]
    unknown = sorted(set(faults) - {*SERVICES, "tiplog up"})
    if unknown:
        ap.error(f"--faults: unknown {', '.join(unknown)} (any of {', '.join(SERVICES)}, tiplog up)")
    r = analyse(Path(a.analyse)) if a.analyse else run(a.settle, faults)
    if a.json:
        Path(a.json).write_text(json.dumps(r, indent=1))
    print(f"{'fault':<16}{'restart s':>10}{'flowing s':>10}{'target s':>9}  longest hole per topic (s)")
    ok = True
    for fault, f in r["faults"].items():
        flowing = f.get("flowing_s", f.get("new_up_gyro_s"))
        target = f.get("target_s")
        ok &= target is None or (flowing is not None and flowing <= target)
        holes = ", ".join(f"{t} {v:.2f}" for t, v in sorted(f.get("longest_hole_s", {}).items()))
        restart = f.get("restart_s", f.get("services_stopped_s"))
        print(
            f"{fault:<16}{restart if restart is not None else '-':>10}{flowing if flowing is not None else '-':>10}"
            f"{target if target is not None else '-':>9}  {holes}"
        )
    print("\nfiles:")
    for info in r["files"]:
        print(
            f"  {info['file']}: {'closed validly' if info['closed_validly'] else 'recovered after SIGKILL'}, "
            f"{info['duration_s']} s, {info['messages']} messages; tiplog info: sequence gaps {info['sequence_gaps']}, "
            f"time gaps {info['time_gaps']} {info['time_gaps_per_topic']}; replayed supervisor events "
            f"{len(info['replayed_supervisor_events'])}: {info['replayed_supervisor_events'][:4]}"
        )
    print(f"(tiplog up killed: {r['faults'].get('tiplog up', 'not this run')}; folder {r['folder']})")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())

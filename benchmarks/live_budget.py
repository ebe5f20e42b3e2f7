"""The demo under `tiplog up` on this machine, second by second, against the real-time targets:
fusion never behind the gyro, the display fresh, vision useful, nothing reset by load.

    python -m benchmarks.live_budget [--seconds 300] [--load] [--json OUT] [--set vision.workers=1]
    python -m benchmarks.live_budget --startup-only [--fresh]      # time to the first estimate

The configuration is `config/demo.yaml` (pixel tier, every service) with its ports, device link
and recording folder moved to free ones, and the calibration `make demo` makes and uses (a bench
fit block through `tiplog calibrate block`) where it exists. `--load` adds a process that keeps
one core busy (a spinning loop at normal priority, standing for what else a cart runs). Per
second after the first state, each figure on the clock of the process that made it (one host
clock), so that this process's own delays never read as the system's: device/gyro samples
arriving at the gateway, and how long they waited on the way from the device (`dev95`: the
gateway's publish stamp against the device's clock, above the quickest sample of the 20 s
around); fusion/state published (stamp + lag_ms) and fusion's own lag (lag_ms,
p95); display lag (a state's stamp to the dashboard's websocket message carrying it leaving,
`sent_ns`, p95, as the page gets it); vision observations finished per second and their latency
(capture stamp to vision's processed stamp, p95); camera frames dropped as stale by vision
(vision/status); frames the pixel tier skipped late and its rate (bench/status); fusion's
re-acquisitions, resets and vision-axis NIS (fusion/diagnostics); each service's CPU share. At
the end the targets are checked.

Start-up: seconds from `tiplog up` starting to the first fusion/state on the bus and to the
first state in a websocket batch (what the page draws). `--fresh` starts with empty caches (an
empty numba cache folder and bench pass cache): a fresh install; without it, the caches as they
are (after `make install`: compiled kernels, and the pass from an earlier start).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import yaml

from benchmarks.system_soak import proc_sample
from tests.conftest import ROOT, free_port
from tests.system.harness import VIEWER_TOKEN, R, UpRun
from tiplog.clock import now_ns

SERVICES = ["bench", "sensor_gateway", "vision", "fusion", "recorder", "dashboard", "igtlink"]
TARGETS = {
    "fusion_hz_min": 195.0,  # in every second after the first state
    "display_lag_p95_ms": 50.0,
    "vision_hz_min": 10.0,  # mean over the run
    "vision_latency_p95_ms": 250.0,
    "nis_factor": 2.0,  # vision-axis NIS mean within this factor of its nominal
}
DEMO_CALIBRATION = ROOT / "build" / "demo" / "calibration.yaml"  # `make demo`'s (Makefile: DEMO_CAL)
NIS_NOMINAL = 4.0  # the vision axis is a 4-row update (two planes' directions and offsets): chi-square(4)
SPIN = "while True:\n    pass\n"


def demo_config(tmp: Path, fresh: bool) -> dict:
    """config/demo.yaml with this run's device link, recordings, ports (and, fresh, caches)."""
    cfg = yaml.safe_load((ROOT / "config" / "demo.yaml").read_text())
    device = str(tmp / "device")
    cfg["bench"]["device_link"] = device
    cfg["sensor_gateway"]["port"] = device
    cfg["recorder"]["out_dir"] = str(tmp / "rec")
    cfg["recorder"]["min_free_bytes"] = 0
    cfg["dashboard"].update(port=free_port(), foxglove_port=free_port())
    cfg["igtlink"]["port"] = free_port()
    if fresh:
        cfg["bench"]["pass_cache_dir"] = str(tmp / "pass-cache")
    return cfg


class Seconds:
    """Per-second buckets (seconds since t0 on the host clock) of counts and samples."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.counts: dict[str, dict[int, int]] = defaultdict(lambda: defaultdict(int))
        self.samples: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
        self.t0_ns: int | None = None
        self.first: dict[str, int] = {}

    def sec(self, t_ns: int) -> int:
        return int((t_ns - self.t0_ns) // 1_000_000_000) if self.t0_ns is not None else -1

    def add(self, name: str, t_ns: int, value: float | None = None) -> None:
        with self.lock:
            self.first.setdefault(name, t_ns)
            if self.t0_ns is None:
                return
            k = self.sec(t_ns)
            self.counts[name][k] += 1
            if value is not None:
                self.samples[name][k].append(value)


def _websocket(url: str, acc: Seconds, stop: threading.Event) -> None:
    """The page's websocket: per state row, sent_ns minus the state's stamp (the display lag)."""
    from websockets.sync.client import connect

    while not stop.is_set():
        try:
            with connect(url, additional_headers={"Authorization": f"Bearer {VIEWER_TOKEN}"}) as ws:
                t0 = json.loads(ws.recv(timeout=30))["t0_ns"]
                while not stop.is_set():
                    try:
                        msg = json.loads(ws.recv(timeout=0.5))
                    except TimeoutError:
                        continue
                    if msg.get("type") != "batch" or not msg.get("state"):
                        continue
                    sent = msg["sent_ns"]
                    for r in msg["state"]:
                        acc.add("display_lag", sent, (sent - (t0 + r[0] * 1e6)) / 1e6)
        except (OSError, TimeoutError, ValueError, KeyError):
            time.sleep(0.2)  # the dashboard is not up yet
        except Exception as e:  # websockets' own errors (a closed connection): reconnect
            if stop.wait(0.2):
                return
            _ = e


def run(
    seconds: float,
    load: bool,
    fresh: bool,
    startup_only: bool,
    keep: str | None = None,
    sets: list[str] = (),
    calibration: str | None = None,
) -> dict:
    spin = subprocess.Popen([sys.executable, "-c", SPIN]) if load else None
    try:
        with tempfile.TemporaryDirectory(prefix="tiplog-budget-") as d:
            tmp = Path(d)
            cfg = demo_config(tmp, fresh)
            for item in sets:  # SECTION.FIELD=VALUE, the value as YAML
                key, _, value = item.partition("=")
                section, _, field = key.partition(".")
                cfg.setdefault(section, {})[field] = yaml.safe_load(value)
            env = {}
            if fresh:
                env["NUMBA_CACHE_DIR"] = str(tmp / "numba-cache")
            args = ["--calibration", calibration] if calibration else []
            r = _measure(tmp, cfg, env, seconds, startup_only, args) | {
                "load": load,
                "fresh": fresh,
                "calibration": calibration or "the bench's as-calibrated constants",
            }
            if keep:
                Path(keep).mkdir(parents=True, exist_ok=True)
                recordings = sorted((tmp / "rec").glob("*.mcap"))
                for f in recordings:
                    shutil.move(str(f), Path(keep) / f.name)
                if recordings and (tmp / "up.err").exists():  # named after the run's first recording
                    shutil.copy(tmp / "up.err", Path(keep) / f"{recordings[0].stem}.log")
            return r
    finally:
        if spin is not None:
            spin.kill()
            spin.wait(10)


def _measure(tmp: Path, cfg: dict, env: dict, seconds: float, startup_only: bool, args: list[str]) -> dict:
    acc = Seconds()
    last: dict[str, object] = {}
    t_up = now_ns()
    stop = threading.Event()
    with UpRun(tmp, SERVICES, cfg, extra_env=env, extra_args=args) as up:
        bus = up.bus
        assert bus is not None

        # Every figure on the clock of the process that made it (one host clock), bucketed by when
        # that process acted, so that this process's own delays (a Python subscriber on a busy
        # machine) never read as the system's: a state at its publish time (stamp + its lag_ms,
        # fusion's own figure), a gyro sample at its arrival at the gateway (its stamp), an
        # observation when vision finished it, a status at its stamp.
        def on_state(m, _i) -> None:
            acc.add("state", m.header.stamp_ns + int(m.lag_ms * 1e6), m.lag_ms)

        def on_obs(m, _i) -> None:
            if m.processed_stamp_ns:
                acc.add("vision", m.processed_stamp_ns, (m.processed_stamp_ns - m.header.stamp_ns) / 1e6)

        def keep(topic: str):
            def cb(m, _i) -> None:
                last[topic] = m
                acc.add(topic, m.header.stamp_ns)
                with acc.lock:
                    if acc.t0_ns is not None:
                        acc.samples[topic + ":msg"][acc.sec(m.header.stamp_ns)].append(m)

            return cb

        bus.subscribe("fusion/state", on_state)

        def on_gyro(m, i) -> None:
            acc.add("gyro", m.header.stamp_ns)
            if m.header.device_stamp_ns:  # when the gateway published it, against the device's clock
                acc.add("device_wait", i.publish_ns, (i.publish_ns - m.header.device_stamp_ns) / 1e6)

        bus.subscribe("device/gyro", on_gyro)
        bus.subscribe("vision/observation", on_obs)
        for topic in ("fusion/diagnostics", "vision/status", "bench/status"):
            bus.subscribe(topic, keep(topic))
        ws = threading.Thread(target=_websocket, args=(f"ws://127.0.0.1:{cfg['dashboard']['port']}/ws", acc, stop))
        ws.start()
        try:
            deadline = time.monotonic() + 600
            while "display_lag" not in acc.first or "state" not in acc.first:
                up.check_alive()
                _given_up(up)
                if time.monotonic() > deadline:
                    raise TimeoutError(f"no state in 600 s:\n{up.log_tail()}")
                time.sleep(0.1)  # polling the collector, not synchronising the system
            startup = {
                "first_state_s": (acc.first["state"] - t_up) / 1e9,
                "first_page_state_s": (acc.first["display_lag"] - t_up) / 1e9,
            }
            log = (tmp / "up.err").read_text(errors="replace")
            if _LOG:
                Path(_LOG[0]).write_text(log)
            startup["kernel_lines"] = [
                ln.split("tiplog.fusion")[-1].lstrip(": ").strip() for ln in log.splitlines() if "kernels" in ln
            ]
            if startup_only:
                return {"startup": startup}
            with acc.lock:
                acc.t0_ns = now_ns()
            pids = {r.service: r.pid for r in up.latest_status().services if r.pid}
            cpu0 = {n: proc_sample(p) for n, p in pids.items()}
            t0 = time.monotonic()
            end = t0 + seconds
            while time.monotonic() < end:
                up.check_alive()
                _given_up(up)
                time.sleep(0.5)
            time.sleep(3.0)  # what the last second published, still on its way here
            cpu = {}
            for n, p in pids.items():
                a, b = cpu0[n], proc_sample(p)
                if a is not None and b is not None:
                    cpu[n] = round(100 * (b[0] - a[0]) / (time.monotonic() - t0), 1)
            status = up.latest_status()
            restarts = {r.service: r.restarts for r in status.services if r.restarts} if status else {}
        finally:
            stop.set()
            ws.join(5)
        up.stop()
    return {
        "startup": startup,
        "restarts": restarts,
        "cpu_percent": cpu,
        "load_average_1min": os.getloadavg()[0],
        **_per_second(acc, int(seconds)),
        "seconds": seconds,
    }


def _given_up(up: UpRun) -> None:
    """A service `tiplog up` gave up on (it kept failing at start): the run cannot measure the
    demo, so it stops here with that service's last error line instead of waiting for states."""
    st = up.latest_status()
    failed = [r for r in st.services if r.state == R.SERVICE_RUN_STATE_FAILED] if st else []
    if failed:
        raise RuntimeError("; ".join(f"{r.service} given up on: {r.last_error}" for r in failed))


_LOG: list[str] = []  # where to copy tiplog up's log at the first state (--log)


def _p95(x: list[float]) -> float:
    return float(np.percentile(x, 95)) if x else float("nan")


def _device_waits(waits: dict[int, list[float]], k: int, window: int = 10) -> list[float]:
    """How much later than the quickest of the seconds around it (within `window`, so that the
    device clock's drift cancels) each gyro sample of second k was published by the gateway [ms]:
    the time its bytes waited on the way from the device (the tty layer, the reader)."""
    here = waits.get(k, [])
    if not here:
        return []
    base = min(v for j in range(k - window, k + window + 1) for v in waits.get(j, []))
    return [v - base for v in here]


def _per_second(acc: Seconds, n: int) -> dict:
    rows = []
    prev: dict[str, float] = {}

    def delta(key: str, value: float) -> float:
        d = value - prev.get(key, value)
        prev[key] = value
        return d

    waits = [_device_waits(acc.samples["device_wait"], k) for k in range(n)]
    for k in range(n):
        diag = acc.samples["fusion/diagnostics:msg"].get(k, [])
        vst = acc.samples["vision/status:msg"].get(k, [])
        bst = acc.samples["bench/status:msg"].get(k, [])
        row = {
            "t": k,
            "gyro_hz": acc.counts["gyro"].get(k, 0),
            "state_hz": acc.counts["state"].get(k, 0),
            "state_lag_p95_ms": _p95(acc.samples["state"].get(k, [])),
            "display_lag_p95_ms": _p95(acc.samples["display_lag"].get(k, [])),
            "vision_hz": acc.counts["vision"].get(k, 0),
            "vision_latency_p95_ms": _p95(acc.samples["vision"].get(k, [])),
            "device_wait_p95_ms": _p95(waits[k]),
        }
        if diag:
            d = diag[-1]
            row["reacquisitions"] = delta("reacq", d.updates.get("reacquire", 0))
            row["resets"] = delta("resets", d.resets)
            row["queue_drops"] = delta("queue_drops", d.queue_drops)
            row["nis_vision_axis"] = d.innovation_nis.get("vision_axis", float("nan"))
            row["noise_scale_vision_axis"] = d.noise_scale.get("vision_axis", float("nan"))
            row["vision_axis_updates"] = d.updates.get("vision_axis", 0)
            row["vision_axis_rejected"] = sum(v for k, v in d.rejected.items() if k.startswith("vision_axis:"))
        if vst:
            row["vision_dropped_stale"] = delta("stale", vst[-1].counts.get("frames_dropped_stale", 0))
            row["vision_own_p95_ms"] = vst[-1].latency_p95_ms  # arrival at vision to observation out
        if bst:
            row["camera_hz"] = round(bst[-1].achieved_hz, 1)
            row["camera_skipped_late"] = delta("late", bst[-1].counts.get("frames_skipped_late", 0))
            row["camera_behind"] = bst[-1].behind
        rows.append(row)
    return {"per_second": rows, "summary": _summary(acc, rows, [v for w in waits for v in w])}


def _summary(acc: Seconds, rows: list[dict], device_waits: list[float]) -> dict:
    lags = [v for r in acc.samples["display_lag"].values() for v in r]
    vlat = [v for r in acc.samples["vision"].values() for v in r]
    state_hz = [r["state_hz"] for r in rows]
    nis = [r["nis_vision_axis"] for r in rows if np.isfinite(r.get("nis_vision_axis", float("nan")))]
    s = {
        "state_hz_min": min(state_hz) if state_hz else 0,
        "state_hz_median": float(np.median(state_hz)) if state_hz else 0,
        "seconds_under_195": sum(h < TARGETS["fusion_hz_min"] for h in state_hz),
        "display_lag_p50_ms": float(np.percentile(lags, 50)) if lags else float("nan"),
        "display_lag_p95_ms": _p95(lags),
        "device_wait_p95_ms": _p95(device_waits),
        "vision_hz_mean": float(np.mean([r["vision_hz"] for r in rows])) if rows else 0.0,
        "vision_latency_p50_ms": float(np.percentile(vlat, 50)) if vlat else float("nan"),
        "vision_latency_p95_ms": _p95(vlat),
        "vision_dropped_stale": sum(r.get("vision_dropped_stale", 0) for r in rows),
        "camera_hz_mean": float(np.mean([r["camera_hz"] for r in rows if "camera_hz" in r] or [0.0])),
        "camera_skipped_late": sum(r.get("camera_skipped_late", 0) for r in rows),
        "camera_seconds_behind": sum(bool(r.get("camera_behind")) for r in rows),
        "reacquisitions": sum(r.get("reacquisitions", 0) for r in rows),
        "resets": sum(r.get("resets", 0) for r in rows),
        "fusion_queue_drops": sum(r.get("queue_drops", 0) for r in rows),
        "nis_vision_axis_last": nis[-1] if nis else float("nan"),
        # fusion's noise matching: the factor it applies to the vision axis' assumed variance, and
        # its updates applied and rejected since fusion started
        "noise_scale_vision_axis_last": next(
            (r["noise_scale_vision_axis"] for r in reversed(rows) if "noise_scale_vision_axis" in r), float("nan")
        ),
        "vision_axis_updates": next(
            (r["vision_axis_updates"] for r in reversed(rows) if "vision_axis_updates" in r), 0
        ),
        "vision_axis_rejected": next(
            (r["vision_axis_rejected"] for r in reversed(rows) if "vision_axis_rejected" in r), 0
        ),
    }
    t = TARGETS
    nis_last = s["nis_vision_axis_last"]
    s["targets"] = {
        "fusion >= 195 Hz every second": s["seconds_under_195"] == 0,
        "display lag p95 <= 50 ms": s["display_lag_p95_ms"] <= t["display_lag_p95_ms"],
        "no re-acquisition or reset": s["reacquisitions"] == 0 and s["resets"] == 0,
        "vision >= 10 obs/s": s["vision_hz_mean"] >= t["vision_hz_min"],
        "vision latency p95 <= 250 ms": s["vision_latency_p95_ms"] <= t["vision_latency_p95_ms"],
        f"vision-axis NIS within x2 of {NIS_NOMINAL:g}": NIS_NOMINAL / t["nis_factor"]
        <= nis_last
        <= NIS_NOMINAL * t["nis_factor"],
    }
    return s


def _print(r: dict) -> None:
    st = r["startup"]
    print(
        f"start-up ({'fresh caches' if r['fresh'] else 'caches as they are'}{', one core kept busy' if r['load'] else ''}): "
        f"first fusion/state {st['first_state_s']:.1f} s, first state on the page's websocket "
        f"{st['first_page_state_s']:.1f} s after tiplog up started"
    )
    for ln in st["kernel_lines"]:
        print(f"  fusion: {ln}")
    if "per_second" not in r:
        return
    print(
        f"\n{'t':>4} {'gyro':>5} {'state':>6} {'flag95':>6} {'lag95':>6} {'vis/s':>5} {'vlat95':>7} {'vown95':>6} {'stale':>5} {'cam/s':>5} {'late':>4} {'reacq':>5} {'reset':>5} {'NIS':>5} {'dev95':>6}"
    )
    for row in r["per_second"]:
        print(
            f"{row['t']:4d} {row['gyro_hz']:5d} {row['state_hz']:6d} {row['state_lag_p95_ms']:6.1f} {row['display_lag_p95_ms']:6.1f} {row['vision_hz']:5d} "
            f"{row['vision_latency_p95_ms']:7.0f} {row.get('vision_own_p95_ms', float('nan')):6.0f} {row.get('vision_dropped_stale', 0):5.0f} "
            f"{row.get('camera_hz', float('nan')):5.1f} {row.get('camera_skipped_late', 0):4.0f} "
            f"{row.get('reacquisitions', 0):5.0f} {row.get('resets', 0):5.0f} {row.get('nis_vision_axis', float('nan')):5.1f} "
            f"{row['device_wait_p95_ms']:6.1f}"
        )
    s = r["summary"]
    print(
        f"\n{r['seconds']:g} s{' with one core kept busy' if r['load'] else ''}; restarts {r['restarts']}; "
        f"host load {r['load_average_1min']:.1f}; CPU % of a core: "
        + ", ".join(f"{n} {c:g}" for n, c in r["cpu_percent"].items())
        + "\n"
        f"  fusion/state: min {s['state_hz_min']} Hz, median {s['state_hz_median']:g} Hz, "
        f"{s['seconds_under_195']} s under 195 Hz; fusion input queue drops {s['fusion_queue_drops']}\n"
        f"  display lag: p50 {s['display_lag_p50_ms']:.1f} ms, p95 {s['display_lag_p95_ms']:.1f} ms; "
        f"device samples' wait before the gateway published them: p95 {s['device_wait_p95_ms']:.1f} ms\n"
        f"  vision: {s['vision_hz_mean']:.1f} obs/s, latency p50 {s['vision_latency_p50_ms']:.0f} ms, "
        f"p95 {s['vision_latency_p95_ms']:.0f} ms; {s['vision_dropped_stale']} frames dropped as stale\n"
        f"  camera (pixel tier): {s['camera_hz_mean']:.1f} frames/s, {s['camera_skipped_late']} skipped late, "
        f"behind in {s['camera_seconds_behind']} s\n"
        f"  re-acquisitions {s['reacquisitions']}, resets {s['resets']}; vision-axis NIS {s['nis_vision_axis_last']:.1f} "
        f"(noise factor {s['noise_scale_vision_axis_last']:.1f}; {s['vision_axis_updates']} updates, "
        f"{s['vision_axis_rejected']} rejected since fusion started)"
    )
    for name, ok in s["targets"].items():
        print(f"  {'met ' if ok else 'MISSED'}  {name}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=300.0, help="how long to measure after the first state [s]")
    ap.add_argument("--load", action="store_true", help="one more process keeps one core busy")
    ap.add_argument("--fresh", action="store_true", help="start with empty kernel and bench pass caches")
    ap.add_argument("--startup-only", action="store_true", help="stop at the first state on the page")
    ap.add_argument("--json", metavar="OUT", help="write the figures (per second and summary) to this file")
    ap.add_argument("--log", metavar="FILE", help="copy tiplog up's log up to the first state to this file")
    ap.add_argument(
        "--keep", metavar="DIR", help="move the run's recording into this folder, with tiplog up's log (RECORDING.log)"
    )
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="configuration override")
    ap.add_argument(
        "--calibration",
        metavar="FILE",
        default=str(DEMO_CALIBRATION) if DEMO_CALIBRATION.exists() else None,
        help=f"tiplog up's calibration file (default: {DEMO_CALIBRATION.relative_to(ROOT)}, `make demo`'s, where it "
        "exists; else the bench's as-calibrated constants)",
    )
    a = ap.parse_args(argv)
    if not a.seconds > 0:
        ap.exit(2, f"live_budget: --seconds must be above 0 (got {a.seconds:g})\n")
    for item in a.set:
        key, eq, _ = item.partition("=")
        if not eq or "." not in key or not all(key.partition(".")[::2]):
            ap.exit(2, f"live_budget: --set wants SECTION.FIELD=VALUE (got {item!r})\n")
    # A kill (SIGTERM) stops tiplog up and the load process as Ctrl-C does, instead of leaving them.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    if a.log:
        _LOG.append(a.log)
    try:
        r = run(a.seconds, a.load, a.fresh, a.startup_only, a.keep, a.set, a.calibration)
    except (RuntimeError, TimeoutError) as e:  # the system did not come up or stopped: no figures
        print(f"live_budget: {e}", file=sys.stderr)
        return 1
    _print(r)
    if a.json:
        Path(a.json).write_text(json.dumps(r, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

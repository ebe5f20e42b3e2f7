"""The whole system under `tiplog up` for a while: CPU share and memory (RSS) of each service,
sampled from /proc every few seconds, and what the recording says about drops.

    python -m benchmarks.system_soak --seconds 600              # the soak (10 min)
    python -m benchmarks.system_soak --seconds 60 --tier pixel  # the demo's CPU share

Services are found by the pids `tiplog up` publishes on `system/supervisor`. CPU share is
each process's user+system time over the sampled stretch divided by its wall time (100 % = one
core). Memory: median RSS over the first and over the last `--window` seconds (after
`--warmup`), and the change between them (target: within 10 %). Drops: sequence gaps per
topic in the recording, restarts, and the recorder's own drop count.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from tests.system.analysis import topic_rates
from tests.system.harness import UpRun, system_config
from tiplog.mcap_io import read_messages

CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def proc_sample(pid: int) -> tuple[float, float] | None:
    """(cpu_s, rss_mib) of one process, None once it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        statm = Path(f"/proc/{pid}/statm").read_text().split()
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return None
    return (int(stat[11]) + int(stat[12])) / CLK_TCK, int(statm[1]) * PAGE / 2**20


def soak(
    seconds: float,
    tier: str,
    services: list[str],
    warmup_s: float,
    window_s: float,
    period_s: float,
    camera_archive: str = "jpeg",
) -> dict:
    with tempfile.TemporaryDirectory(prefix="tiplog-soak-") as d:
        tmp = Path(d)
        config = system_config(tmp, tier=tier)
        config["recorder"]["camera_archive"] = camera_archive  # the demo's: jpeg, the default
        with UpRun(tmp, services, config) as up:
            st = up.wait_status(up.all_running, timeout_s=300)
            pids = {n: up.run_of(st, n).pid for n in services}
            t_start = time.monotonic()
            samples: dict[str, list[tuple[float, float, float]]] = {n: [] for n in services}
            while (now := time.monotonic()) - t_start < seconds:
                up.check_alive()
                for n, pid in pids.items():
                    s = proc_sample(pid)
                    if s is not None:
                        samples[n].append((now - t_start, *s))
                time.sleep(period_s)  # a sampling period, not a synchronisation
            last = up.latest_status()
            recorded_s = time.monotonic() - t_start
            restarts = {r.service: r.restarts for r in last.services} if last else {}
            assert up.stop() == 0, up.log_tail()
        recording_bytes = sum(p.stat().st_size for p in up.recordings())
        rates: dict[str, dict] = {}
        recorder_dropped = recorder_rejected = 0  # counts of the session, from its status messages
        for rec in up.recordings():
            for t, r in topic_rates(rec).items():
                prev = rates.get(t, {"count": 0, "seq_gaps": 0, "rate_hz": 0.0})
                rates[t] = {
                    "count": prev["count"] + r.count,
                    "seq_gaps": prev["seq_gaps"] + r.seq_gaps,
                    "rate_hz": max(prev["rate_hz"], round(float(r.rate_hz), 2)),
                }
            for m in read_messages(rec, ["recorder/status"]):
                counts = m.message.topics
                recorder_dropped = max(recorder_dropped, sum(c.dropped for c in counts.values()))
                recorder_rejected = max(
                    recorder_rejected, sum(c.received for t, c in counts.items() if t.startswith("_rejected/"))
                )
    rows = {}
    for n, s in samples.items():
        a = np.asarray(s)
        if len(a) < 3:
            continue
        t, cpu, rss = a[:, 0], a[:, 1], a[:, 2]
        busy = t >= min(warmup_s, t[-1] / 2)
        cpu_share = (cpu[-1] - cpu[busy][0]) / max(t[-1] - t[busy][0], 1e-9)
        first = rss[(t >= warmup_s) & (t < warmup_s + window_s)]
        final = rss[t >= t[-1] - window_s]
        first = first if len(first) else rss[: max(1, len(rss) // 4)]
        rss0, rss1 = float(np.median(first)), float(np.median(final))
        rows[n] = {
            "cpu_percent": round(100 * cpu_share, 1),
            "rss_first_mib": round(rss0, 1),
            "rss_last_mib": round(rss1, 1),
            "rss_change_percent": round(100 * (rss1 - rss0) / rss0, 1),
            "rss_max_mib": round(float(rss.max()), 1),
        }
    return {
        "seconds": seconds,
        "tier": tier,
        "services": rows,
        "restarts": restarts,
        "camera_archive": camera_archive,
        "recording_bytes": recording_bytes,
        "archive_gb_per_hour": round(recording_bytes / recorded_s * 3600 / 1e9, 2),
        "recorder_dropped": recorder_dropped,
        "recorder_rejected": recorder_rejected,
        "seq_gaps": {t: r["seq_gaps"] for t, r in rates.items() if r["seq_gaps"]},
        "messages": sum(r["count"] for r in rates.values()),
        "rates_hz": {t: r["rate_hz"] for t, r in sorted(rates.items())},
        "load_average_1min": os.getloadavg()[0],
        "cpu_count": os.cpu_count(),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0, help="how long the system runs once started [s]")
    ap.add_argument("--tier", choices=["measurement", "pixel"], default="measurement", help="bench camera tier")
    ap.add_argument("--services", default="bench,sensor_gateway,vision,fusion,recorder,dashboard")
    ap.add_argument("--warmup", type=float, help="seconds left out at the start (default: 10 %% of the run)")
    ap.add_argument("--window", type=float, help="seconds of the first and last RSS windows (default: 20 %%)")
    ap.add_argument("--period", type=float, default=2.0, help="sampling period [s]")
    ap.add_argument("--camera-archive", choices=["jpeg", "raw"], default="jpeg", help="the recorder's camera_archive")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON line at the end")
    a = ap.parse_args(argv)
    warmup = a.warmup if a.warmup is not None else 0.1 * a.seconds
    window = a.window if a.window is not None else 0.2 * a.seconds
    r = soak(a.seconds, a.tier, a.services.split(","), warmup, window, a.period, a.camera_archive)
    print(
        f"whole system, {r['tier']} tier, {r['seconds']:g} s; host load {r['load_average_1min']:.1f} on "
        f"{r['cpu_count']} CPUs; {r['messages']} messages recorded"
    )
    print(f"{'service':15s} {'CPU %':>6s} {'RSS first':>10s} {'RSS last':>9s} {'change':>7s} {'RSS max':>8s} restarts")
    for n, s in r["services"].items():
        print(
            f"{n:15s} {s['cpu_percent']:6.1f} {s['rss_first_mib']:8.1f} M {s['rss_last_mib']:7.1f} M "
            f"{s['rss_change_percent']:6.1f}% {s['rss_max_mib']:6.1f} M {r['restarts'].get(n, 0):8d}"
        )
    print(
        f"archive (camera_archive {r['camera_archive']}): {r['recording_bytes'] / 1e6:.1f} MB, "
        f"{r['archive_gb_per_hour']:.2f} GB per hour at this run's rates"
    )
    print("achieved rates [Hz]: " + ", ".join(f"{t} {hz:g}" for t, hz in r["rates_hz"].items()))
    print(
        f"drops: recorder {r['recorder_dropped']}, rejected by its admission check {r['recorder_rejected']}, "
        f"sequence gaps {r['seq_gaps'] or 'none'}"
    )
    if a.json:
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

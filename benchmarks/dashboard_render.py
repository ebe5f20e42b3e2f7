"""Page smoothness with a full 2-minute trail at 200 Hz, in headless Chromium (Debian's).

A publisher process fills the dashboard's trail with 24,000 states (2 min at 200 Hz) and then
publishes at 200 Hz; the page draws path, inset and envelope once per animation frame. Reported
from the page itself: time spent drawing a frame (p50/p95/max) and the interval between drawn
frames (p50/p95), over `--seconds` with the full trail, and how many states the page holds.

    python -m benchmarks.dashboard_render [--seconds 10]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.dashboard_lag import ROOT, dashboard_on_bus

CHROMIUM = "/usr/bin/chromium"
TRAIL = 24_000


def run(seconds: float) -> dict[str, float]:
    from playwright.sync_api import sync_playwright

    with dashboard_on_bus("render") as (endpoint, prefix, port, _dash, env):
        pub = None
        try:
            pub = subprocess.Popen(
                [sys.executable, "-m", "benchmarks.dashboard_lag", "--publisher", endpoint, prefix]
                + ["--seconds", str(seconds + 90), "--prefill", str(TRAIL)],
                cwd=ROOT,
                env=env,
            )
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1440, "height": 1000})
                page.goto(f"http://127.0.0.1:{port}/")
                page.wait_for_function(f"() => window.tiplog.est && window.tiplog.est.n >= {TRAIL}", timeout=120_000)
                page.evaluate("() => { window.tiplog.frames.length = 0; }")
                time.sleep(seconds)  # benchmark only: let the page draw
                frames = np.array(page.evaluate("() => window.tiplog.frames"))
                held = page.evaluate("() => window.tiplog.est.n")
                browser.close()
        finally:
            if pub is not None and pub.poll() is None:
                pub.terminate()
                pub.wait(10)
    if len(frames) < 2:
        raise RuntimeError("the page drew no frames")
    interval, draw = frames[1:, 0], frames[:, 1]
    return {
        "frames": float(len(frames)),
        "fps": float(1000.0 / np.median(interval)),
        "draw_p50_ms": float(np.percentile(draw, 50)),
        "draw_p95_ms": float(np.percentile(draw, 95)),
        "draw_max_ms": float(draw.max()),
        "interval_p50_ms": float(np.percentile(interval, 50)),
        "interval_p95_ms": float(np.percentile(interval, 95)),
        "trail_states": float(held),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0)
    a = ap.parse_args(argv)
    if not Path(CHROMIUM).exists():
        print(f"dashboard_render: {CHROMIUM} missing (make browser); skipped")
        return 0
    r = run(a.seconds)
    print(
        f"dashboard page, {r['trail_states']:.0f}-state trail, 200 Hz live, {a.seconds:g} s, headless Chromium:\n"
        f"  drawing a frame: p50 {r['draw_p50_ms']:.2f} ms, p95 {r['draw_p95_ms']:.2f} ms, max {r['draw_max_ms']:.2f} ms\n"
        f"  between frames:  p50 {r['interval_p50_ms']:.1f} ms, p95 {r['interval_p95_ms']:.1f} ms "
        f"({r['fps']:.0f} frames/s, {r['frames']:.0f} frames)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

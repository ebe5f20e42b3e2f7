"""The page never misleads, in real headless Chromium (Debian's, driven by Playwright) against a
dashboard on a loopback bus: the trail breaks at a reset instead of drawing a line the tip never
travelled, the vision badge holds its lock through a short gap, the device's smoothed ToF range
is shown, stale numbers are dimmed and said to be stale where they stand, only services are
listed, and the icon is served."""

from __future__ import annotations

import pytest

from tests.services.dashboard.conftest import OPERATOR, make_state
from tiplog.bus import Bus
from tiplog.clock import now_ns
from tiplog.v1 import device_pb2, fusion_pb2

pytestmark = [pytest.mark.browser, pytest.mark.slow]

MS = 1_000_000


def _signed_in(browser, url: str):
    ctx = browser.new_context(viewport={"width": 1440, "height": 1000}, bypass_csp=True)
    page = ctx.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    assert page.goto(url).status == 401
    page.fill("#token", OPERATOR)
    page.click("#sign-in")
    page.wait_for_function("window.tiplog && window.tiplog.est && window.tiplog.est.n > 0", timeout=30_000)
    page.errors = errors
    return ctx, page


def test_the_page_breaks_holds_shows_the_tof_and_marks_stale(browser, served, bus_pair_configs, artifacts):
    ctx, page = _signed_in(browser, served.url)
    try:
        page.click("#clear-trail")
        pub = served.pub_bus.publisher("fusion/state")
        t0 = now_ns()
        # 300 states at 200 Hz moving at 0.1 m/s along x, a reset 50 mm away, 300 more.
        for k in range(600):
            x = 0.1 + 0.0005 * k + (0.05 if k >= 300 else 0.0)
            st = make_state(t0 + k * 5 * MS, tip_m=(x, 0.2, 0.3))
            st.vision_locked = k < 500
            # unlocked for the last 100 states (0.5 s), the last frame 0.6 s before the last one
            st.last_vision_stamp_ns = t0 + min(k, 499) * 5 * MS - (100 * MS if k >= 500 else 0)
            pub.put(st)
        page.wait_for_function("window.tiplog.est.n >= 600", timeout=15_000)
        assert page.evaluate("window.TiplogDraw.segments(window.tiplog.est, 1)") == [[0, 299], [300, 599]]
        # Locked until 0.6 s ago: the badge holds "locked" (the filter's own flag is off).
        page.wait_for_function(f"window.tiplog.current.state.header.stamp_ns === {t0 + 599 * 5 * MS}")
        assert page.text_content("#lock") == "vision: locked"

        tof = device_pb2.Tof(range_raw_mm=118.0, range_smoothed_mm=123.4, smoothed_valid=True)
        tof.header.stamp_ns = now_ns()
        served.pub_bus.publisher("device/tof").put(tof)
        page.wait_for_function("document.getElementById('v-tof-smoothed').textContent === '123.4'", timeout=10_000)
        api = served.client(OPERATOR).get("/api/state").json()
        assert "depth_smoothed_mm" not in api["state"] and api["tof"]["range_smoothed_mm"] == 123.4

        # samples a stalled host held up, and a device clock taken anew, are listed by stream
        diag = fusion_pb2.FusionDiagnostics(mode="full", initialised=True)
        diag.header.stamp_ns = now_ns()
        diag.held_up["gyro"], diag.clock_restarts["tof"] = 120, 1
        served.pub_bus.publisher("fusion/diagnostics").put(diag)
        page.wait_for_function(
            "document.getElementById('diagnostics').textContent.includes('held up gyro (host stalled)120')",
            timeout=10_000,
        )
        assert "device clock restarts tof1" in page.text_content("#diagnostics")

        # Nothing more comes: the numbers stay, dimmed and said to be stale.
        page.wait_for_function(
            "document.getElementById('state-stale').textContent.startsWith('stale: no new state for')",
            timeout=10_000,
        )
        assert "stale" in page.get_attribute("#state-panel", "class") and "stale" in page.get_attribute(
            "#lock", "class"
        )
        page.wait_for_function("document.getElementById('tof-row').classList.contains('stale')", timeout=10_000)
        page.screenshot(path=str(artifacts / "dashboard-stale-after-reset.png"), full_page=True)
        assert page.is_visible("#stale") and page.text_content("#v-depth") == "140.00"
        # A state again: no longer stale; its last frame 1.5 s old: no lock, said so.
        st = make_state(t0 + 800 * 5 * MS, tip_m=(0.25, 0.2, 0.3))
        st.last_vision_stamp_ns = t0 + 800 * 5 * MS - 1500 * MS
        pub.put(st)
        page.wait_for_function("document.getElementById('state-stale').textContent === ''", timeout=10_000)
        assert "stale" not in (page.get_attribute("#state-panel", "class") or "")
        assert page.text_content("#lock") == "vision: no lock for 1.5 s"

        # `tiplog up`'s own session is not a service.
        with Bus(bus_pair_configs[1], service="up"):
            assert served.running.feed.health.wait_token("up", True, 10.0)
            seen_ms = (now_ns() - served.running.feed.t0_ns) / 1e6
            page.wait_for_function(f"window.tiplog.status && window.tiplog.status.t_ms > {seen_ms}", timeout=10_000)
            names = page.eval_on_selector_all("#health tbody tr", "rows => rows.map(r => r.cells[0].textContent)")
            assert "dashboard" in names and "up" not in names, names

        icon = page.request.get(served.url + "/favicon.ico")
        assert icon.status == 200 and icon.headers["content-type"].startswith("image/svg+xml")
        assert page.errors == []
    finally:
        ctx.close()

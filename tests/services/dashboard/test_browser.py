"""The dashboard in real headless Chromium (Debian's, driven by Playwright) against a running
system on the simulated bench: sign-in, the numbers against the published state, the trail
growing with no state dropped, recorder controls by role, a screenshot, reconnection."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest

from tests.conftest import ROOT
from tests.services.dashboard.live_system import (
    OPERATOR_TOKEN,
    SHOT_TIMEOUT_MS,
    VIEWER_TOKEN,
    LiveSystem,
    lock_text,
    signed_in,
    start_system,
)
from tiplog.mcap_io import read_metadata
from tiplog.v1 import recorder_pb2

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def system(tmp_path_factory) -> LiveSystem:
    s = start_system(tmp_path_factory.mktemp("system"))
    yield s
    s.stop()


def test_numbers_match_the_published_state_and_screenshot(browser, system, artifacts):
    ctx, page = signed_in(browser, system, OPERATOR_TOKEN)
    try:
        assert page.text_content("#role") == "operator"
        last = system.fusion.pause()
        try:
            page.wait_for_function(
                "s => window.tiplog.current && window.tiplog.current.state.header.stamp_ns === s",
                arg=last.header.stamp_ns,
                timeout=15_000,
            )
            page.wait_for_function(
                "d => document.getElementById('v-depth').textContent === d", arg=f"{last.depth_mm:.2f}", timeout=30_000
            )
            shown = {
                k: page.text_content(f"#{k}")
                for k in ("v-depth", "v-tilt", "v-roll", "v-tof-offset", "v-tip", "v-fusion-lag")
            }
            tip_mm = [last.tip_m.x * 1e3, last.tip_m.y * 1e3, last.tip_m.z * 1e3]
            assert shown == {
                "v-depth": f"{last.depth_mm:.2f}",
                "v-tilt": f"{last.tilt_deg:.2f}",
                "v-roll": "12.50",
                "v-tof-offset": "1.25",
                "v-tip": " / ".join(f"{v:.2f}" for v in tip_mm),
                "v-fusion-lag": f"{last.lag_ms:.1f}",
            }
            assert page.text_content("#lock") == lock_text(last)
            # The error panel against the robot: the stand-in's wobble is at most ~1.5 mm. (The
            # newest state may still lack its bracketing robot samples: the RMS is checked.)
            page.wait_for_function("document.getElementById('e-count').textContent !== '0'", timeout=30_000)
            assert 0.0 < float(page.text_content("#e-rms")) < 1.6
            # None dropped: every state published since the first one the page holds reached it
            # (the dashboard may have joined the bus after the stand-in's first states).
            first_ns = page.evaluate("window.tiplog.hello.t0_ns + window.tiplog.est.get(0, 0) * 1e6")
            expected = sum(1 for m in system.fusion.published if m.header.stamp_ns >= first_ns - 1_000)
            assert page.evaluate("[window.tiplog.received, window.tiplog.est.n, window.tiplog.skipped]") == [
                expected,
                expected,
                0,
            ]
        finally:
            system.fusion.resume()
        page.wait_for_function("() => document.querySelector('#health tbody tr') !== null", timeout=30_000)
        health = dict(
            zip(
                page.locator("#health tbody td:nth-child(1)").all_text_contents(),
                page.locator("#health tbody td:nth-child(2)").all_text_contents(),
                strict=True,
            )
        )
        assert health["bench"] == "up" and health["sensor_gateway"] == "up" and health["recorder"] == "up"
        assert health["vision"] == "down"  # not started in this system
        page.screenshot(path=str(artifacts / "dashboard.png"), full_page=True, timeout=SHOT_TIMEOUT_MS)
        assert (artifacts / "dashboard.png").stat().st_size > 20_000
        assert page.errors == []
    finally:
        ctx.close()


@pytest.mark.parametrize("viewport", [(1280, 720), (1920, 1080), (800, 1000)], ids=["laptop", "cart", "narrow"])
def test_trail_grows_and_the_page_fits_the_screen(browser, system, viewport):
    ctx, page = signed_in(browser, system, VIEWER_TOKEN, viewport)
    try:
        n0 = page.evaluate("window.tiplog.est.n")
        page.wait_for_function("n => window.tiplog.est.n >= n + 200", arg=n0, timeout=15_000)
        span_s = float(page.text_content("#trail-span"))
        assert span_s > 0.5
        # No sideways scrolling; the path view and the depth are on the first screen.
        assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth")
        box = page.locator("#path").bounding_box()
        assert box["width"] >= 0.45 * viewport[0] and box["y"] < viewport[1]
        assert page.locator("#v-depth").bounding_box()["y"] < 2 * viewport[1]
    finally:
        ctx.close()


def test_recorder_controls_with_operator_token(browser, system):
    ctx, page = signed_in(browser, system, OPERATOR_TOKEN)
    try:
        page.click("#rec-start")
        page.wait_for_function("document.getElementById('rec-state').textContent === 'recording'", timeout=15_000)
        page.fill("#mark-label", "first incision")
        page.click("#rec-mark")
        page.wait_for_function(
            "document.getElementById('rec-result').textContent.startsWith('mark: ok')", timeout=10_000
        )
        path = page.text_content("#rec-file")
        page.click("#rec-stop")
        page.wait_for_function("document.getElementById('rec-state').textContent === 'idle'", timeout=15_000)
    finally:
        ctx.close()
        # Left recording by a failure above, the module's system would fail the next test too.
        with system.client(OPERATOR_TOKEN) as c:
            if c.get("/api/recorder").json()["status"]["state"] == "RECORDER_STATE_RECORDING":
                c.post("/api/recorder/stop", json={"reason": "test cleanup"})
    labels = {m.get("label", "") for name, m in read_metadata(path).items() if name.startswith("event_")}
    assert "first incision" in labels
    assert any(lb.startswith("dashboard: start by operator") for lb in labels)
    assert any(lb.startswith("dashboard: stop by operator") for lb in labels)
    assert "operator action: start recording" in system.log_tail("dashboard", 200)


def test_viewer_token_cannot_start_a_recording(browser, system):
    ctx, page = signed_in(browser, system, VIEWER_TOKEN)
    try:
        assert page.text_content("#role") == "viewer"
        assert page.is_disabled("#rec-start") and page.is_disabled("#rec-stop")
        status = page.evaluate(
            """async () => (await fetch('/api/recorder/start', {method: 'POST',
                headers: {'Content-Type': 'application/json'}, body: '{}'})).status"""
        )
        assert status == 403
    finally:
        ctx.close()
    with system.client(VIEWER_TOKEN) as c:
        assert c.get("/api/recorder").json()["status"]["state"] != "RECORDER_STATE_RECORDING"


def test_without_a_token_everything_is_refused(browser, system):
    ctx = browser.new_context(bypass_csp=True)
    try:
        page = ctx.new_page()
        resp = page.goto(system.url)
        assert resp.status == 401
        assert "script-src 'self'" in resp.headers["content-security-policy"]
        assert page.locator("#token").count() == 1
        got = page.evaluate(
            """async () => {
                const api = (await fetch('/api/state')).status;
                const rec = (await fetch('/api/recorder/start', {method: 'POST', body: '{}',
                    headers: {'Content-Type': 'application/json'}})).status;
                const ws = await new Promise((done) => {
                    const s = new WebSocket(`ws://${location.host}/ws`);
                    s.onopen = () => done('opened');
                    s.onclose = () => done('closed');
                });
                return [api, rec, ws];
            }"""
        )
        assert got == [401, 401, "closed"]
        page.fill("#token", "not-a-valid-token-at-all")
        page.click("#sign-in")
        assert "not valid" in page.text_content("body")
    finally:
        ctx.close()


def test_bus_text_is_shown_as_text_never_as_markup(browser, system):
    alarm = '<img src=x onerror="window.pwned=1">disk <b>full</b>'
    pub = system.bus.publisher("recorder/status")
    stop = threading.Event()

    def flood() -> None:  # outnumber the real recorder's 2 Hz status
        st = recorder_pb2.RecorderStatus(state=recorder_pb2.RECORDER_STATE_ERROR, alarm=alarm)
        while not stop.wait(0.02):
            pub.put(st)

    ctx, page = signed_in(browser, system, VIEWER_TOKEN)
    t = threading.Thread(target=flood, daemon=True)
    t.start()
    try:
        page.wait_for_function("a => document.getElementById('rec-alarm').textContent === a", arg=alarm, timeout=15_000)
        assert page.evaluate("[document.querySelectorAll('#rec-alarm *').length, typeof window.pwned]") == [
            0,
            "undefined",
        ]
    finally:
        stop.set()
        t.join()
        pub.close()
        ctx.close()


def test_page_reconnects_after_the_dashboard_restarts(browser, system):
    ctx, page = signed_in(browser, system, VIEWER_TOKEN)
    try:
        old = system.procs["dashboard"]
        old.terminate()
        assert old.wait(10) == 0
        page.wait_for_function("document.getElementById('conn').textContent === 'reconnecting'", timeout=10_000)
        system.procs["dashboard"] = subprocess.Popen(
            old.args, cwd=ROOT, env={**os.environ, **_dashboard_env()}, stderr=subprocess.DEVNULL
        )
        page.wait_for_function("document.getElementById('conn').textContent === 'connected'", timeout=60_000)
        page.wait_for_function("window.tiplog.est.n > 50", timeout=30_000)
    finally:
        ctx.close()


def _dashboard_env() -> dict[str, str]:
    return {
        "PYTHONPATH": str(ROOT),
        "TIPLOG_DASHBOARD_VIEWER_TOKEN": VIEWER_TOKEN,
        "TIPLOG_DASHBOARD_OPERATOR_TOKEN": OPERATOR_TOKEN,
    }


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))

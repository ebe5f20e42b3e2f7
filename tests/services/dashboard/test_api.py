"""The JSON API and the websocket of a dashboard on a real Zenoh session: tokens, the state and
its error split against the reference, every state delivered in order, the OpenAPI schema."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from tests.services.dashboard.conftest import OPERATOR, VIEWER, make_robot, make_state
from tiplog.bus import Bus
from tiplog.clock import now_ns
from tiplog.v1 import vision_pb2


@pytest.mark.parametrize(
    "path", ["/", "/api/state", "/api/health", "/api/status", "/static/dashboard.js", "/openapi.json"]
)
def test_no_token_is_401(served, path):
    with served.client() as c:
        assert c.get(path).status_code == 401
    with served.client("wrong-token-but-long-enough") as c:
        assert c.get(path).status_code == 401


def test_viewer_reads_but_cannot_act(served):
    with served.client(VIEWER) as c:
        assert c.get("/api/state").status_code == 200
        assert c.get("/").status_code == 200
        for action, body in (("start", {}), ("stop", {}), ("mark", {"label": "x"})):
            assert c.post(f"/api/recorder/{action}", json=body).status_code == 403


def test_operator_without_a_recorder_gets_503_not_a_traceback(served):
    with served.client(OPERATOR) as c:
        r = c.post("/api/recorder/start", json={"reason": "test"})
        assert r.status_code == 503 and r.json()["detail"] == "no recorder answered on the bus"
        assert c.post("/api/recorder/mark", json={"label": "bad\x00label"}).status_code == 422
        assert c.post("/api/recorder/start", json={"session": "../etc"}).status_code == 422


def test_state_and_error_split_against_the_reference(served):
    robot = served.pub_bus.publisher("bench/robot")
    fusion = served.pub_bus.publisher("fusion/state")
    rcm = np.array([0.5, 0.0, 0.3])
    u = np.array([0.0, 0.6, -0.8])  # reference shaft direction
    t0 = now_ns()
    refs_before = served.running.feed.reference.total
    for k in range(5):  # tip moving along x at 10 mm/s, 5 ms apart
        tip = rcm + 0.14 * u + np.array([1e-2 * 0.005 * k, 0.0, 0.0])
        robot.put(make_robot(t0 + k * 5_000_000, tip.tolist(), rcm.tolist()))
    served.wait_states(refs_before + 5, ring="reference")
    # state at t0 + 7.5 ms: reference tip interpolated there, plus 2 mm along u and 1 mm across.
    ref = rcm + 0.14 * u + np.array([1e-2 * 0.0075, 0.0, 0.0])
    across = np.cross(u, [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    est = ref + 2e-3 * u + 1e-3 * across
    before = served.running.feed.state.total
    fusion.put(make_state(t0 + 7_500_000, tip_m=est.tolist(), depth_mm=142.0, tilt_deg=5.5))
    served.wait_states(before + 1)
    with served.client(VIEWER) as c:
        body = c.get("/api/state").json()
    assert body["state"]["depth_mm"] == 142.0 and body["state"]["tilt_deg"] == 5.5
    d = body["derived"]
    assert d["x_mm"] == pytest.approx(est[0] * 1e3, abs=1e-3)
    assert d["err_radial_mm"] == pytest.approx(2.0, abs=1e-3)
    assert d["err_tangential_mm"] == pytest.approx(1.0, abs=1e-3)
    assert d["err_mm"] == pytest.approx(np.sqrt(5.0), abs=1e-3)
    with served.client(VIEWER) as c:
        rms = c.get("/api/status").json()["error"]
    # The probe states (stamped near 0) are far outside the 30 s window and had no reference.
    assert rms["samples"] == 1 and rms["rms_mm"] == pytest.approx(np.sqrt(5.0), abs=1e-3)
    assert rms["radial_rms_mm"] == pytest.approx(2.0, abs=1e-3)


def test_health_counts_streams_and_gaps(served):
    pub = served.pub_bus.publisher("fusion/state")
    before = served.running.feed.state.total
    for k in range(20):
        pub.put(make_state(10_000 + k))
    pub._seq += 5  # five states lost upstream: the dashboard counts them from the sequence numbers
    pub.put(make_state(20_000))
    served.wait_states(before + 21)
    with served.client(VIEWER) as c:
        h = c.get("/api/health").json()
    assert h["streams"]["fusion/state"]["dropped"] == 5
    assert h["services"]["dashboard"]["state"] == "up"
    assert h["services"]["recorder"]["state"] == "down"


def test_a_service_with_a_token_but_no_data_is_stale(served, bus_pair_configs):
    health = served.running.feed.health
    with Bus(bus_pair_configs[1], service="vision") as vision_bus:
        assert health.wait_token("vision", True, 10)
        with served.client(VIEWER) as c:
            assert c.get("/api/health").json()["services"]["vision"]["state"] == "stale"
            pub = vision_bus.publisher("vision/observation")
            pub.put(vision_pb2.VisionObservation(accepted=False))
            assert served.running.feed.streams.wait_count("vision/observation", 1, 10)
            assert c.get("/api/health").json()["services"]["vision"]["state"] == "up"
    assert health.wait_token("vision", False, 10)
    with served.client(VIEWER) as c:
        assert c.get("/api/health").json()["services"]["vision"]["state"] == "down"


def test_websocket_delivers_every_state_in_order(served):
    pub = served.pub_bus.publisher("fusion/state")
    url = served.url.replace("http://", "ws://") + "/ws"
    with pytest.raises(InvalidStatus):
        connect(url, additional_headers={"Authorization": "Bearer nope-nope-nope-nope"}).close()
    with connect(url, additional_headers={"Authorization": f"Bearer {VIEWER}"}) as ws:
        hello = json.loads(ws.recv(timeout=10))
        assert hello["type"] == "hello" and hello["role"] == "viewer"
        cols = hello["columns"]["state"]
        base = served.running.feed.state.total
        stamps = [hello["t0_ns"] + 1_000_000 * (k + 1) for k in range(300)]
        for k, t in enumerate(stamps):
            pub.put(make_state(t, depth_mm=100.0 + k))
        rows: list[list[float]] = []
        while len(rows) < base + 300:
            msg = json.loads(ws.recv(timeout=10))
            if msg["type"] == "batch":
                assert msg["skipped"] == 0
                rows += msg["state"]
        mine = rows[base:]
        assert [r[cols.index("depth_mm")] for r in mine] == [100.0 + k for k in range(300)]
        assert [round(r[0] * 1e6) + hello["t0_ns"] for r in mine] == stamps


def test_openapi_documents_the_api(served):
    with served.client(VIEWER) as c:
        schema = c.get("/openapi.json").json()
    paths = schema["paths"]
    for p in ("/api/state", "/api/health", "/api/recorder/start", "/api/recorder/stop", "/api/recorder/mark"):
        assert p in paths, p
    start = paths["/api/recorder/start"]["post"]
    assert {"401", "403", "503"} <= set(start["responses"])
    assert "HTTPBearer" in schema["components"]["securitySchemes"]


def test_page_scripts_never_write_markup():
    # Bus data reaches the page only through textContent and canvas: no HTML sinks, no eval.
    from services.dashboard.server import STATIC

    for js in STATIC.glob("*.js"):
        text = js.read_text()
        for sink in ("innerHTML", "outerHTML", "insertAdjacentHTML", "document.write", "eval(", "new Function"):
            assert sink not in text, f"{js.name} uses {sink}"
    html = (STATIC / "index.html").read_text()
    assert "<script>" not in html  # no inline script (CSP forbids it)
    # Works with no internet: nothing is loaded from elsewhere (no CDN, no web font).
    for f in STATIC.iterdir():
        text = f.read_text().replace('xmlns="http://www.w3.org/2000/svg"', "")  # a name, never fetched
        assert "http://" not in text and "https://" not in text and "//cdn" not in text, f.name
    assert set(re.findall(r'(?:src|href)="([^"]+)"', html)) == {
        "/static/dashboard.css",
        "/static/draw.js",
        "/static/dashboard.js",
        "/api/metrics?download=1",  # the skill metrics of the current recording, same origin
        "/favicon.ico",  # the icon, served without a token (the sign-in page asks for it too)
    }


def test_preview_served_as_published_and_only_raster_formats(served):
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    pub = served.pub_bus.publisher("vision/preview")
    with served.client(VIEWER) as c:
        assert c.get("/api/preview").status_code == 404
        pub.put(CompressedImage(format="svg+xml", data=b"<svg onload='alert(1)'/>"))  # never served
        jpeg = b"\xff\xd8\xff\xe0fake-jpeg-bytes"
        pub.put(CompressedImage(format="jpeg", data=jpeg))
        assert served.running.feed.wait_preview(10)
        r = c.get("/api/preview")
        assert r.status_code == 200 and r.content == jpeg and r.headers["content-type"] == "image/jpeg"
        assert r.headers["x-content-type-options"] == "nosniff"


def test_cross_site_posts_are_refused_and_sign_out_clears_the_cookie(served):
    with served.client(OPERATOR) as c:
        r = c.post("/api/recorder/mark", json={"label": "x"}, headers={"Origin": "http://evil.example"})
        assert r.status_code == 403 and r.text == "cross-site request refused"
        host = served.url.split("://", 1)[1]
        same = c.post("/api/recorder/mark", json={"label": "x"}, headers={"Origin": f"http://{host}"})
        assert same.status_code == 503  # past the check: no recorder on this bus
        out = c.post("/logout")
        assert out.status_code == 303 and 'tiplog_token=""' in out.headers["set-cookie"]


def test_every_answer_carries_the_security_headers_once(served):
    with served.client(VIEWER) as c:
        answers = [
            c.get("/api/state"),
            c.get("/static/missing.js"),  # 404
            served.client().get("/api/state"),  # 401
            c.post("/api/recorder/mark", json={"label": "x"}, headers={"Origin": "http://evil.example"}),  # 403
        ]
    assert [r.status_code for r in answers] == [200, 404, 401, 403]
    for r in answers:
        for name in ("content-security-policy", "x-content-type-options", "referrer-policy", "cache-control"):
            assert len(r.headers.get_list(name)) == 1, (r.status_code, name)
        assert r.headers["cache-control"] == "no-store" and "default-src 'none'" in r.headers["content-security-policy"]


def test_pages_referrer_policy_lets_the_browser_send_its_origin(served):
    # With no-referrer, Chromium sends "Origin: null" on the page's own form posts (sign-in),
    # which the cross-site check refuses.
    with served.client(VIEWER) as c:
        assert c.get("/").headers["referrer-policy"] == "same-origin"


def test_supervisor_run_state_and_restarts_join_health(served):
    from tiplog.v1 import system_pb2

    R = system_pb2.ServiceRunState
    sup = system_pb2.SupervisorStatus(event="fusion exited with -9; restarting in 1.0 s")
    sup.services.add(service="fusion", state=R.SERVICE_RUN_STATE_RESTARTING, restarts=2)
    sup.services.add(service="recorder", state=R.SERVICE_RUN_STATE_RUNNING, restarts=0)
    served.pub_bus.publisher("system/supervisor").put(sup)
    assert served.running.feed.wait_latest("system/supervisor", 10)
    with served.client(VIEWER) as c:
        body = c.get("/api/status").json()
    assert body["supervisor_event"] == "fusion exited with -9; restarting in 1.0 s"
    assert body["health"]["fusion"]["run_state"] == "restarting" and body["health"]["fusion"]["restarts"] == 2
    assert body["health"]["recorder"]["run_state"] == "running"


def test_vision_and_camera_load_join_the_status(served):
    """vision/status and bench/status as published (the page shows rate, drops and 'behind')."""
    from tiplog.loadstatus import LoadMeter

    bench = LoadMeter("bench", 15.0)
    bench.status(1_000_000_000)
    for _ in range(9):
        bench.done(80.0)
    bench.count("frames_skipped_late", 6)
    msg = bench.status(2_000_000_000)
    msg.note = "cannot keep 15 frames/s: 9.0 of 15 frames/s rendered"
    served.pub_bus.publisher("bench/status").put(msg)
    assert served.running.feed.wait_latest("bench/status", 10)
    with served.client(VIEWER) as c:
        load = c.get("/api/status").json()["load"]
    b = load["bench"]
    assert b["behind"] and b["achieved_hz"] == 9.0 and b["counts"]["frames_skipped_late"] == 6
    assert b["note"].startswith("cannot keep 15") and b["age_s"] >= 0
    assert "vision" not in load  # none published

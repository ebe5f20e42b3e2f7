"""A rogue process on the bus: garbage, wrongly typed and oversized payloads on every tiplog
key while `tiplog up` runs the whole system. Nothing crashes (no service restarted), states
keep reaching the page, the decode errors are counted (fusion's diagnostics) and logged by
the services that subscribe, and the recording stays valid: the recorder keeps the forged
payloads out of their topics' channels and counts them."""

from __future__ import annotations

import collections
import json
import subprocess
import sys

import pytest

from tests.conftest import ROOT
from tests.system.harness import UpRun
from tiplog.mcap_io import read_messages, read_metadata, read_summary
from tiplog.topics import TOPICS

pytestmark = pytest.mark.slow

SERVICES = ["bench", "sensor_gateway", "fusion", "recorder", "dashboard"]

ROGUE = """
import sys, zenoh, numpy as np
from tiplog.bus import encode_attachment
endpoint, topics = sys.argv[1], sys.argv[2].split(",")
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", '["%s"]' % endpoint)
conf.insert_json5("scouting/multicast/enabled", "false")
rng = np.random.default_rng(7)
with zenoh.open(conf) as s:
    # The junk is sent blocking, so that none of it is lost at the rogue's own send queue
    # (which the 16 MiB puts fill) and every service sees all of it. The 16 MiB puts may drop,
    # but for those on the first topic, which are sure to reach the services.
    block = zenoh.CongestionControl.BLOCK
    pubs = {t: s.declare_publisher("tiplog/" + t, congestion_control=block) for t in topics}
    bigs = [pubs[topics[0]]] + [s.declare_publisher("tiplog/" + t) for t in topics[1:]]
    big = rng.integers(0, 256, 16 * 2**20, dtype=np.uint8).tobytes()
    for rnd in range(20):
        for t, p in pubs.items():
            junk = rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes()
            p.put(junk)                                                   # no attachment
            p.put(junk, attachment=encode_attachment(rnd, 0, 99, "tiplog.v1.RecorderStatus"))  # wrong type
            p.put(junk, attachment=encode_attachment(rnd, 0, 99, "no.such.Type"))
            p.put(junk, attachment=b"\\x01\\x02")                         # attachment cut short
            for name in ("tiplog.v1.Gyro", "tiplog.v1.FusionState", "tiplog.v1.Tof"):   # right name, bad bytes
                p.put(b"\\xff" * 64, attachment=encode_attachment(rnd, 0, 99, name))
        if rnd % 5 == 0:
            for p in bigs:
                p.put(big)                                                # oversized: 16 MiB
print("rogue done", flush=True)
"""


def test_rogue_publisher_on_every_key(tmp_path):
    with UpRun(tmp_path, SERVICES) as up:
        up.wait_status(up.all_running, timeout_s=120)
        up.poll_api("/api/state", lambda a: a["received"] > 200, 120)
        before = up.latest_status()
        out = subprocess.run(
            [sys.executable, "-c", ROGUE, up.endpoint, ",".join(TOPICS)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=180,
        )
        assert out.returncode == 0 and "rogue done" in out.stdout, out.stderr[-2000:]
        # States keep reaching the page after the storm.
        n0 = up.api("/api/state")["received"]
        up.poll_api("/api/state", lambda a: a["received"] > n0 + 200, 60)
        # fusion counts what it could not decode, per topic, in its diagnostics: all of it.
        # Per round and topic the rogue sends 7 payloads fusion cannot take (no attachment, a cut
        # attachment, an unknown type, a wrong type, three right-or-wrong names on 0xff bytes:
        # none is this topic's message) and nothing of them is lost on the way (blocking puts).
        keys = [f"{t}:undecodable" for t in ("device/gyro", "device/accel", "device/tof", "vision/observation")]
        up.poll_api(
            "/api/status",
            lambda a: all(int((a["diagnostics"] or {}).get("rejected", {}).get(k, 0)) >= 7 * 20 for k in keys),
            30,
        )
        after = up.latest_status()
        for run in after.services:  # nothing crashed: no restart, the same processes
            assert run.restarts == 0, run
            assert run.pid == up.run_of(before, run.service).pid, run
        assert up.stop() == 0, up.log_tail()
    log = up.stderr_path.read_text(errors="replace")
    assert "Traceback" not in log, log[-3000:]
    assert "undecodable payload on" in log
    (rec,) = up.recordings()
    assert read_summary(rec) is not None
    # The recorder kept every forged payload out of its topic's channel: the file reads back
    # whole, holds what the recorder says it wrote, and counts the rejects per topic and reason
    # (kept on `_rejected/<topic>:<reason>`, the 16 MiB ones counted but not kept).
    in_file = collections.Counter(r.topic for r in read_messages(rec))
    counts = {t: json.loads(v) for t, v in read_metadata(rec)["recorder_counts"].items()}
    assert {t: n for t, n in in_file.items()} == {t: c["written"] for t, c in counts.items() if c["written"]}
    # Per round and topic: two with no usable attachment, four naming another type, one naming
    # this topic's type on 0xff bytes; none lost on the way.
    for topic in ("device/gyro", "device/tof", "fusion/state"):
        assert counts[f"_rejected/{topic}:no_type"]["received"] >= 2 * 20, counts
        assert counts[f"_rejected/{topic}:wrong_type"]["received"] >= 4 * 20, counts
        assert counts[f"_rejected/{topic}:undecodable"]["received"] >= 20, counts
    assert sum(c["dropped"] for t, c in counts.items() if t.endswith(":no_type")) >= 1, counts  # 16 MiB ones
    assert in_file["device/gyro"] > 200
    # The offline filter reads it and tracks.
    out = tmp_path / "offline.mcap"
    p = subprocess.run(
        [sys.executable, "-m", "tiplog.cli", "fusion", "run", str(rec), "--out", str(out), "--quiet"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert p.returncode == 0, p.stderr[-2000:]
    assert sum(1 for _ in read_messages(out, ["fusion/state"])) > 200

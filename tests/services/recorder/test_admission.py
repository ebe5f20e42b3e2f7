"""The recorder's admission check: a payload that is not a well-formed message of its topic's
type never enters the topic's channel; it is counted per topic and reason and kept on
`_rejected/<topic>:<reason>` as google.protobuf.Any, so the file reads back whole."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
from foxglove_schemas_protobuf import RawImage_pb2
from google.protobuf import any_pb2
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from services.bench.scenario import load_scenario
from services.bench.session import generate
from services.recorder.admission import Admission, quarantine_record
from tests.conftest import ROOT
from tests.services.recorder.conftest import StatusWatch
from tiplog.bus import Bus
from tiplog.mcap_io import read_messages, read_metadata
from tiplog.v1 import device_pb2, fusion_pb2, recorder_pb2

S = recorder_pb2.RecorderState
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _status_bytes() -> bytes:
    st = recorder_pb2.RecorderStatus(path="/x.mcap", bytes_written=123, alarm="rogue")
    st.header.stamp_ns = 77
    st.topics["a"].received = 3
    return st.SerializeToString()


def _gyro(k: int) -> bytes:
    m = device_pb2.Gyro()
    m.header.stamp_ns, m.header.seq = 1_000 + k, k
    m.rate_radps.z = 0.01 * k
    return m.SerializeToString()


def test_each_reason():
    a = Admission()
    img = RawImage_pb2.RawImage(width=2, height=1, encoding="rgb8", step=6, data=bytes(6))
    img.timestamp.FromNanoseconds(5)
    assert a.check("camera/image", "foxglove.RawImage", img.SerializeToString()) is None
    assert a.check("device/gyro", "tiplog.v1.Gyro", _gyro(3)) is None
    # A RecorderStatus said to be a RawImage parses (protobuf is lenient) but its fields do not fit.
    assert a.check("camera/image", "foxglove.RawImage", _status_bytes()) == "unknown_fields"
    assert a.check("camera/image", "tiplog.v1.RecorderStatus", _status_bytes()) == "wrong_type"
    assert a.check("camera/image", "", img.SerializeToString()) == "no_type"
    assert a.check("device/gyro", "tiplog.v1.Gyro", b"\xff" * 64) == "undecodable"
    assert a.check("device/gyro", "tiplog.v1.Gyro", b"\x08\x01") == "unknown_fields"  # varint where a message is
    assert a.check("device/gyro", "tiplog.v1.Gyro", b"") == "no_stamp"
    assert a.check("device/gyro", "tiplog.v1.Gyro", b"\x12\x00") == "no_stamp"  # an empty rate, no header
    # Topics the system does not know: checked against the type they claim.
    assert a.check("lab/extra", "tiplog.v1.Gyro", _gyro(1)) is None
    assert a.check("lab/extra", "tiplog.v1.Gyro", b"\xff" * 8) == "undecodable"
    assert a.check("lab/extra", "no.such.Type", b"") == "unknown_type"


def test_quarantine_record_is_an_any_holding_the_payload():
    payload = bytes(range(256)) * 700  # a multi-byte length
    rec = any_pb2.Any.FromString(quarantine_record("tiplog.v1.Gyro", payload))
    assert rec.type_url == "type.googleapis.com/tiplog.v1.Gyro" and rec.value == payload
    assert any_pb2.Any.FromString(quarantine_record("", b"")).type_url == "type.googleapis.com/"


def test_every_message_of_bench_sessions_is_admitted(tmp_path):
    """The check never rejects what the system itself publishes (bench sessions, both tiers)."""
    a = Admission()
    for tier in ("measurement", "pixel"):
        path = tmp_path / f"{tier}.mcap"
        generate(load_scenario("teleop"), path, seed=1003, tier=tier, duration_s=1.0)
        n = 0
        with open(path, "rb") as f:
            for schema, channel, message in make_reader(f).iter_messages():
                assert a.check(channel.topic, schema.name, message.data) is None, (tier, channel.topic)
                n += 1
        assert n > 500


ROGUE = """
import sys, threading, time, zenoh
from tiplog.bus import encode_attachment
from tiplog.v1 import recorder_pb2
endpoint, prefix, payload_file = sys.argv[1:4]
cases = [tuple(c) for c in __import__("json").load(open(payload_file))]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", '["%s"]' % endpoint)
conf.insert_json5("scouting/multicast/enabled", "false")
heard = threading.Event()

def on_status(sample):  # stay until the recorder has received every put (closing drops the rest)
    st = recorder_pb2.RecorderStatus.FromString(sample.payload.to_bytes())
    if sum(c.received for t, c in st.topics.items() if not t.startswith(("_", "recorder/"))) >= len(cases):
        heard.set()

with zenoh.open(conf) as s:
    s.declare_subscriber(prefix + "recorder/status", on_status)
    block = zenoh.CongestionControl.BLOCK
    pubs = {t: s.declare_publisher(prefix + t, congestion_control=block) for t, _, _ in cases}
    while not all(p.matching_status.matching for p in pubs.values()):  # the recorder is seen
        time.sleep(0.01)
    for k, (topic, type_name, hex_payload) in enumerate(cases):
        att = encode_attachment(k, 1, 99, type_name) if type_name is not None else None
        pubs[topic].put(bytes.fromhex(hex_payload), attachment=att)
    if not heard.wait(30):
        sys.exit("the recorder did not receive every put")
print("rogue done", flush=True)
"""


def _cases() -> tuple[list[tuple[str, str | None, bytes]], dict[str, int], dict[str, int]]:
    """(topic, attachment type or None, payload) in publishing order; good counts per topic;
    rejected counts per quarantine channel."""
    rng = np.random.default_rng(11)
    img = RawImage_pb2.RawImage(width=64, height=48, encoding="rgb8", step=192)
    img.data = rng.integers(0, 256, 64 * 48 * 3, dtype=np.uint8).tobytes()
    img.timestamp.FromNanoseconds(9)
    state = fusion_pb2.FusionState(depth_mm=80.0)
    state.header.stamp_ns = 4
    # topic: (type, a good payload, what a RecorderStatus's bytes sent as that type are taken for)
    good = {
        "camera/image": ("foxglove.RawImage", img.SerializeToString(), "unknown_fields"),
        "device/gyro": ("tiplog.v1.Gyro", _gyro(1), "unknown_fields"),
        # FusionState's field 3 is a message: the status's path string (field 3) does not parse as one
        "fusion/state": ("tiplog.v1.FusionState", state.SerializeToString(), "undecodable"),
    }
    big = rng.integers(0, 256, 300_000, dtype=np.uint8).tobytes()  # over the quarantine's size limit
    cases: list[tuple[str, str | None, bytes]] = []
    n_good: dict[str, int] = {}
    rejected: dict[str, int] = {}
    for rnd in range(3):
        for topic, (type_name, payload, foreign) in good.items():
            bad = [
                ("wrong_type", "tiplog.v1.RecorderStatus", _status_bytes()),
                (foreign, type_name, _status_bytes()),
                ("undecodable", type_name, b"\xff" * 64),
                ("no_type", None, payload),
                ("no_stamp", type_name, b""),
            ]
            if rnd == 0:
                bad.append(("undecodable", type_name, b"\xff" + big))
            for reason, t, p in bad:
                cases.append((topic, type_name, payload))
                cases.append((topic, t, p))
                n_good[topic] = n_good.get(topic, 0) + 1
                key = f"_rejected/{topic}:{reason}"
                rejected[key] = rejected.get(key, 0) + 1
    return cases, n_good, rejected


def test_rogue_process_on_known_topics_against_a_recorder_process(bus_pair_configs, tmp_path):
    listen_cfg, _ = bus_pair_configs
    cases, n_good, rejected = _cases()
    payload_file = tmp_path / "cases.json"
    payload_file.write_text(json.dumps([(t, n, p.hex()) for t, n, p in cases]))
    with Bus(listen_cfg) as bus:
        watch = StatusWatch()
        bus.subscribe("recorder/status", watch)
        proc = subprocess.Popen(
            [sys.executable, "-m", "services.recorder", "--connect", listen_cfg.listen[0], "--prefix"]
            + [listen_cfg.prefix, "--set", "autostart=always", "--set", f"out_dir={tmp_path / 'rec'}"]
            + ["--set", "min_free_bytes=0", "--set", "quarantine_max_payload_bytes=100000"]
            + ["--set", "status_period_s=0.2", "--set", "camera_archive=raw"],
            cwd=ROOT,
            env=ENV,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            st = watch.wait(lambda s: s.state == S.RECORDER_STATE_RECORDING, timeout=30)
            out = subprocess.run(
                [sys.executable, "-c", ROGUE, listen_cfg.listen[0], listen_cfg.prefix, str(payload_file)],
                cwd=ROOT,
                env=ENV,
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert out.returncode == 0 and "rogue done" in out.stdout, out.stderr[-2000:]
            total = len(cases)

            def all_in(s: recorder_pb2.RecorderStatus) -> bool:
                return sum(c.received for t, c in s.topics.items() if not t.startswith(("_", "recorder/"))) >= total

            live = watch.wait(all_in, timeout=30)
            live = watch.wait(
                lambda s: (
                    sum(c.written + c.dropped for t, c in s.topics.items() if t.startswith("_rejected/"))
                    >= sum(rejected.values())
                ),
                timeout=30,
            )
            proc.send_signal(signal.SIGINT)
            assert proc.wait(20) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
        err = proc.stderr.read()
    assert "Traceback" not in err, err[-3000:]
    assert "rejected a payload on camera/image (unknown_fields" in err
    # Counts on recorder/status: per topic, and per topic and reason.
    for topic, n in n_good.items():
        c = live.topics[topic]
        assert (c.received, c.written, c.dropped) == (2 * n, n, 0), (topic, c)
    got_rejected = {t: c for t, c in live.topics.items() if t.startswith("_rejected/")}
    assert {t: c.received for t, c in got_rejected.items()} == rejected
    for t, c in got_rejected.items():  # the 300 kB payloads are counted, not kept
        assert c.dropped == (1 if t.endswith(":undecodable") else 0) and c.written == c.received - c.dropped, t
    assert len(got_rejected) == 3 * 5 - 1
    # The file reads back whole with the mcap reader, every message decoded by its channel's schema.
    path = st.path
    by_topic: dict[str, list] = {}
    with open(path, "rb") as f:
        for _s, ch, _m, msg in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            by_topic.setdefault(ch.topic, []).append(msg)
    for topic, n in n_good.items():
        assert len(by_topic[topic]) == n
    kept = {t: c.written for t, c in got_rejected.items()}
    assert {t: len(v) for t, v in by_topic.items() if t.startswith("_rejected/")} == kept
    (wrong,) = {m.type_url for m in by_topic["_rejected/camera/image:wrong_type"]}
    assert wrong == "type.googleapis.com/tiplog.v1.RecorderStatus"
    assert by_topic["_rejected/device/gyro:undecodable"][0].value == b"\xff" * 64
    assert recorder_pb2.RecorderStatus.FromString(by_topic["_rejected/camera/image:unknown_fields"][0].value).alarm == (
        "rogue"
    )
    # tiplog's own reader and `tiplog info` too.
    assert sum(1 for _ in read_messages(path)) == sum(len(v) for v in by_topic.values())
    r = subprocess.run(
        [sys.executable, "-m", "tiplog.cli", "info", path, "--json"],
        cwd=ROOT,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    info = json.loads(r.stdout)
    assert {t: info["topics"][t]["count"] for t in kept} == kept
    assert info["topics"]["camera/image"]["count"] == n_good["camera/image"]
    # The file's own account at its end says the same.
    at_end = {t: json.loads(v) for t, v in read_metadata(path)["recorder_counts"].items()}
    assert {t: c["received"] for t, c in at_end.items() if t.startswith("_rejected/")} == rejected

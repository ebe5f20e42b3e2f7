"""`tiplog info`'s sequence gaps agree with the recorder's own per-publisher counts on a live
recording (the bench's device through the gateway, the gateway killed and restarted midway, so
each device topic holds two publishers' sequences), and its table's columns stay apart."""

from __future__ import annotations

import json
import os
import signal
import threading
from collections import Counter

import pytest

from services.recorder.info import format_info, inspect
from tests.system.harness import UpRun, system_config

pytestmark = pytest.mark.slow

SERVICES = ["bench", "sensor_gateway", "recorder"]
DEVICE = ("device/gyro", "device/accel", "device/tof", "device/mag")


def test_info_gaps_equal_the_recorder_counts_across_a_gateway_restart(tmp_path):
    config = system_config(tmp_path)
    del config["dashboard"]
    gyro_by_publisher: Counter[int] = Counter()
    recorded = [0]  # device/gyro samples the recorder has received, by its latest status
    cv = threading.Condition()

    def on_gyro(_msg, info) -> None:
        with cv:
            gyro_by_publisher[info.publisher_id] += 1
            cv.notify_all()

    def on_recorder(msg, _info) -> None:
        with cv:
            recorded[0] = msg.topics["device/gyro"].received if "device/gyro" in msg.topics else 0
            cv.notify_all()

    def wait_for(what: str, pred) -> None:
        with cv:
            assert cv.wait_for(pred, 120), (what, dict(gyro_by_publisher), recorded[0], up.log_tail())

    def publishers(n: int) -> bool:  # n gateways have each published 1000 gyro samples
        return sum(c >= 1000 for c in gyro_by_publisher.values()) >= n

    with UpRun(tmp_path, SERVICES, config) as up:
        up.bus.subscribe("device/gyro", on_gyro)
        up.bus.subscribe("recorder/status", on_recorder)
        # the recorder starts on its own: on a loaded machine the first gateway's samples may all
        # be sent before it subscribes, so the kill waits until it has recorded some of them
        wait_for("first gateway recorded", lambda: publishers(1) and recorded[0] >= 500)
        at_kill = recorded[0]
        st = up.latest_status()
        os.kill(up.run_of(st, "sensor_gateway").pid, signal.SIGKILL)
        wait_for("second gateway recorded", lambda: publishers(2) and recorded[0] >= at_kill + 500)
        assert up.stop() == 0
    (path,) = up.recordings()
    info = inspect(path)
    counts = {t: json.loads(v) for t, v in info["metadata"]["recorder_counts"].items()}
    for topic in DEVICE:
        ti = info["topics"][topic]
        assert ti["sequences"] >= 2, (topic, ti)  # both gateways' sequences are in the file
        assert ti["count"] == counts[topic]["written"]
        assert ti["gaps"] == counts[topic]["upstream_gaps"], (topic, ti, counts[topic])
    assert info["gaps"] == sum(c["upstream_gaps"] for c in counts.values())
    table = format_info(info).splitlines()
    head = next(ln for ln in table if ln.startswith("topic "))
    for topic in DEVICE:
        row = next(ln for ln in table if ln.startswith(topic + " "))
        assert len(row.split()) == len(head.split()) - 5  # "rate Hz", "seq gaps", ... are two words each

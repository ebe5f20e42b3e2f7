"""The one adapter from messages to measurements: latency taken off each stamp, unused sensors
and invalid samples left out and counted, a corrupt message an error the runner counts."""

from __future__ import annotations

import numpy as np
import pytest

from services.fusion.eskf.measurement import VisionObservation
from services.fusion.eskf.params import Params
from services.fusion.timing.measurements import MessageAdapter
from tests.services.fusion.eskf.test_filter import _calib
from tiplog.v1 import device_pb2, vision_pb2


def _adapter(sensors=frozenset({"imu", "tof", "vision"})) -> tuple[MessageAdapter, dict]:
    dropped: dict[str, int] = {}
    return MessageAdapter(_calib(), Params(), sensors, dropped), dropped


def test_each_stream_gets_its_latency_off_and_its_type():
    a, dropped = _adapter()
    g = device_pb2.Gyro()
    g.header.stamp_ns = 5_000_000_000
    g.rate_radps.x, g.rate_radps.y, g.rate_radps.z = 0.1, -0.2, 0.3
    m = a.measurement("device/gyro", g)
    assert m.kind == "gyro" and m.t_ns == 5_000_000_000 - a.lat["gyro"]
    np.testing.assert_array_equal(m.value, [0.1, -0.2, 0.3])
    v = vision_pb2.VisionObservation()
    v.header.stamp_ns = 5_000_000_000
    v.accepted, v.junction_visible = True, True
    v.n_left.x, v.n_right.y, v.junction_ray.z = 1.0, 1.0, 1.0
    m = a.measurement("vision/observation", v)
    assert m.kind == "vision" and m.t_ns == 5_000_000_000 - a.lat["camera"]
    assert isinstance(m.value, VisionObservation) and m.value.junction_visible
    np.testing.assert_array_equal(m.value.ray, [0.0, 0.0, 1.0])
    assert dropped == {}


def test_left_out_and_counted():
    a, dropped = _adapter(frozenset({"imu", "vision"}))
    t = device_pb2.Tof()
    t.range_raw_mm, t.status = 150.0, 1
    assert a.measurement("device/tof", t) is None  # ToF not in use: not even counted
    a2, dropped2 = _adapter()
    t.status = 4
    assert a2.measurement("device/tof", t) is None and dropped2 == {"tof:invalid": 1}
    v = vision_pb2.VisionObservation()
    v.accepted = False
    assert a.measurement("vision/observation", v) is None and dropped == {"vision:not_accepted": 1}
    assert a.measurement("device/status", device_pb2.Gyro()) is None


def test_a_non_finite_vector_is_an_error():
    a, _ = _adapter()
    g = device_pb2.Gyro()
    g.rate_radps.x = float("nan")
    with pytest.raises(ValueError):
        a.measurement("device/gyro", g)

"""`exclude_topics`: what the demo leaves out of its recording (raw frames), by topic or by a
prefix ending in '/'."""

from __future__ import annotations

from tiplog.mcap_io import read_messages
from tiplog.v1 import device_pb2, recorder_pb2

S = recorder_pb2.RecorderState


def test_excluded_topics_are_not_recorded(served_recorder):
    srv = served_recorder(autostart="always", exclude_topics=["device/gyro", "bench/"])
    st = srv.status.wait(lambda s: s.state == S.RECORDER_STATE_RECORDING)
    gyro, tof, status = (srv.bus.publisher(t) for t in ("device/gyro", "device/tof", "device/status"))
    robot = srv.bus.publisher("bench/robot")
    header = {"header": {"stamp_ns": 1}}
    for k in range(20):
        gyro.put(device_pb2.Gyro(**header))
        robot.put(robot.msg_type(**header))
        tof.put(device_pb2.Tof(range_raw_mm=float(k), **header))
    status.put(device_pb2.DeviceStatus(**header))
    srv.status.wait(lambda s: "device/status" in s.topics and s.topics["device/status"].written == 1)
    final = srv.status.wait(lambda s: "device/tof" in s.topics and s.topics["device/tof"].written == 20)
    assert "device/gyro" not in final.topics and "bench/robot" not in final.topics
    srv.stop.set()
    srv.thread.join(10)
    topics = {r.topic for r in read_messages(st.path)}
    assert "device/tof" in topics and "device/status" in topics
    assert not topics & {"device/gyro", "bench/robot"}

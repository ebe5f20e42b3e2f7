"""DeviceReader on a pyserial URL (socket://): messages as specified, the HELLO in the status,
a dropped connection reported and reopened, an unknown ToF status counted."""

from __future__ import annotations

import socket
import threading
import time

from services.sensor_gateway.device import MAX_LATE_NS, DeviceLinkConfig, DeviceReader
from services.sensor_gateway.status import GatewayStatus
from tiplog.bus import Bus
from tiplog.devproto.packets import HelloPacket, PacketType, TofPacket, Vec3Packet, encode_packet_frame
from tiplog.v1 import device_pb2


def wait_for(predicate, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    tick = threading.Event()
    while not predicate():
        if time.monotonic() > deadline:
            return False
        tick.wait(0.01)
    return True


def wait_matched(reader: DeviceReader) -> bool:
    """Both tested streams' publishers see the subscriber: nothing sent before is lost."""
    return all(
        wait_for(lambda kind=kind: reader._pubs[kind]._pub.matching_status.matching, 30)
        for kind in (PacketType.GYRO, PacketType.TOF)
    )


def test_reader_over_a_socket_url(bus_pair_configs):
    listen_cfg, connect_cfg = bus_pair_configs
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    gyros, tofs = [], []
    statuses: list[device_pb2.DeviceStatus] = []
    with Bus(listen_cfg) as sub_bus, Bus(connect_cfg) as pub_bus:
        sub_bus.subscribe("device/gyro", lambda m, i: gyros.append(m))
        sub_bus.subscribe("device/tof", lambda m, i: tofs.append(m))
        status = GatewayStatus(f"socket://127.0.0.1:{port}", statuses.append)
        cfg = DeviceLinkConfig(port=f"socket://127.0.0.1:{port}", reconnect_initial_s=0.02, reconnect_max_s=0.1)
        reader = DeviceReader(cfg, pub_bus, status)
        assert wait_matched(reader)
        reader.start()
        try:
            conn, _ = server.accept()
            # pyserial flushes its input on open: send once the port is open (the DTR gate).
            assert wait_for(lambda: len(reader.connect_times_ns) == 1)
            hello = HelloPacket(0, 1, "fw 9.9", "DEV-7", {"gyro": 200.0, "accel": 240.0, "tof": 100.0, "mag": 0.0})
            data = encode_packet_frame(hello)
            for k in range(50):
                data += encode_packet_frame(Vec3Packet(PacketType.GYRO, k, 1000 + 5000 * k, 0.1 * k, 0.0, -1.0))
            data += encode_packet_frame(TofPacket(0, 2000, 120.0, 9, 0.0, False))  # status 9: unknown
            conn.sendall(data)
            assert wait_for(lambda: len(gyros) == 50 and len(tofs) == 1), (len(gyros), len(tofs))
            conn.close()  # the "device" goes away
            assert wait_for(lambda: reader.faults["disconnects"] == 1)
            conn, _ = server.accept()  # reopened
            assert wait_for(lambda: len(reader.connect_times_ns) == 2)
            conn.sendall(b"".join(
                encode_packet_frame(Vec3Packet(PacketType.GYRO, k, 1000 + 5000 * k, 0.0, 0.0, 0.0))
                for k in range(60, 70)
            ))  # fmt: skip
            assert wait_for(lambda: len(gyros) == 60)
            conn.close()
        finally:
            reader.stop()
            server.close()
    g = gyros[3]
    assert g.header.device_stamp_ns == (1000 + 5000 * 3) * 1000 and g.header.frame_id == "imu"
    assert abs(g.rate_radps.x - 0.3) < 1e-6 and g.rate_radps.z == -1.0
    assert [m.header.seq for m in gyros] == list(range(50)) + list(range(60, 70))
    stamps = [m.header.stamp_ns for m in gyros]
    assert stamps[0] > 0 and all(b > a for a, b in zip(stamps, stamps[1:], strict=False))  # distinct, ordered
    assert tofs[0].status == device_pb2.TOF_STATUS_UNSPECIFIED and tofs[0].range_raw_mm == 120.0
    assert reader.faults["tof_status_unknown"] == 1 and reader.faults["reconnects"] == 1
    assert reader.parser.faults["seq_gap_samples"] == 10  # 50..59 never came
    assert status.firmware == "fw 9.9" and status.device_id == "DEV-7"
    assert status.nominal_rates_hz == {"gyro": 200.0, "accel": 240.0, "tof": 100.0}
    states = [s for _, s in status.state_changes]
    assert states[:2] == [device_pb2.DEVICE_STATE_CONNECTING, device_pb2.DEVICE_STATE_STREAMING]
    assert device_pb2.DEVICE_STATE_DISCONNECTED in states[2:]
    msg = status.publish_periodic()
    assert msg.faults["disconnects"] >= 1 and msg.frames_ok == 62 and msg.firmware == "fw 9.9"


def test_a_burst_read_at_once_keeps_the_device_spacing(bus_pair_configs):
    """A loaded host reads several samples in one read: the newest of each stream gets the
    read's arrival stamp, older ones are back-dated by the device clock (5 ms gyro spacing
    here), never to or before the stream's previous stamp."""
    listen_cfg, connect_cfg = bus_pair_configs
    gyros, tofs = [], []
    with Bus(listen_cfg) as sub_bus, Bus(connect_cfg) as pub_bus:
        sub_bus.subscribe("device/gyro", lambda m, i: gyros.append(m))
        sub_bus.subscribe("device/tof", lambda m, i: tofs.append(m))
        reader = DeviceReader(DeviceLinkConfig(port="loop://"), pub_bus, GatewayStatus("loop://", lambda m: None))
        assert wait_matched(reader)

        def burst(first: int, n: int) -> bytes:
            frames = [
                encode_packet_frame(Vec3Packet(PacketType.GYRO, k, 5000 * k, 0.0, 0.0, 0.0))
                for k in range(first, first + n)
            ]
            frames.insert(2, encode_packet_frame(TofPacket(first, 5000 * first + 100, 120.0, 0, 0.0, False)))
            return b"".join(frames)

        T = 10_000_000_000
        assert reader._handle(burst(0, 4), T) == 5
        assert reader._handle(burst(4, 3), T + 1_000_000) == 4  # next read only 1 ms later
        assert wait_for(lambda: len(gyros) == 7 and len(tofs) == 2, 30), (len(gyros), len(tofs))
    stamps = [m.header.stamp_ns for m in gyros]
    assert stamps[:4] == [T - 15_000_000, T - 10_000_000, T - 5_000_000, T]
    # the second read cannot go back before the first one's newest: 1 ns steps up to its arrival
    assert stamps[4:] == [T + 1, T + 2, T + 1_000_000]
    assert [m.header.stamp_ns for m in tofs] == [T, T + 1_000_000]  # alone in its stream in each read


def test_after_a_stall_samples_keep_their_device_times(bus_pair_configs):
    """The device's writer (or this reader) starved for 0.6 s: the overdue samples come in two
    reads. They are stamped at most MAX_LATE_NS after their device time plus the quickest
    arrival seen, not the first read on arrival (0.3 s late) and the second squeezed into 1 ns
    steps after it; the ordinary reads (jitter under MAX_LATE_NS) keep their arrival time."""
    listen_cfg, connect_cfg = bus_pair_configs
    gyros = []
    with Bus(listen_cfg) as sub_bus, Bus(connect_cfg) as pub_bus:
        sub_bus.subscribe("device/gyro", lambda m, i: gyros.append(m))
        sub_bus.subscribe("device/tof", lambda m, i: None)  # wait_matched waits for both streams
        reader = DeviceReader(DeviceLinkConfig(port="loop://"), pub_bus, GatewayStatus("loop://", lambda m: None))
        assert wait_matched(reader)

        def gyro(k: int) -> bytes:
            return encode_packet_frame(Vec3Packet(PacketType.GYRO, k, 5000 * k, 0.0, 0.0, 0.0))

        T = 10_000_000_000  # host time of device time 0, plus a 0.5 ms quickest delay
        for k in range(100):  # one sample a read, 0.5-2.5 ms after its time
            assert reader._handle(gyro(k), T + 5_000_000 * k + 500_000 + (k % 5) * 500_000) == 1
        # 0.6 s with nothing, then samples 100-219 (due meanwhile) in two reads 1 ms apart
        assert reader._handle(b"".join(gyro(k) for k in range(100, 160)), T + 5_000_000 * 219 + 700_000) == 60
        assert reader._handle(b"".join(gyro(k) for k in range(160, 220)), T + 5_000_000 * 219 + 1_700_000) == 60
        assert wait_for(lambda: len(gyros) == 220, 30), len(gyros)
    stamps = [m.header.stamp_ns for m in gyros]
    ordinary = [T + 5_000_000 * k + 500_000 + (k % 5) * 500_000 for k in range(100)]
    assert stamps[:100] == ordinary  # arrival, as before
    late = [s - (T + 5_000_000 * k + 500_000) for k, s in enumerate(stamps)]
    assert max(late[100:]) <= MAX_LATE_NS  # the stall's samples at their device times (first read was 300 ms late)
    assert min(b - a for a, b in zip(stamps[99:], stamps[100:], strict=False)) > 1_000_000  # no 1 ns steps

"""Serial reader thread: open the port, read, parse, stamp on arrival, publish; reconnect.

One thread owns the port (never a Zenoh callback thread). Every read is stamped on the host
clock the moment it returns, before parsing. The newest sample of each stream in a read
carries that arrival stamp; older samples of the same stream in the same read (a loaded host
reads bursts) are back-dated by their spacing on the device clock, never to or before the
stream's previous stamp, so every sample keeps a distinct, ordered host time. Each also
carries its device clock. No sample is stamped more than `MAX_LATE_NS` after the time the device
clock gives it (its device time plus the smallest arrival delay of its stream over the last
`DELAY_WINDOW_NS`): after a stall (the device's writer or this reader starved for a while) the
first read holds samples from the start of the stall, and stamping its newest on arrival put the
whole read late and squeezed the next read's samples into 1 ns steps after it, a gap and a pile
of equal times that fusion turned into jumps of the tip. In the ordinary case (arrival within
`MAX_LATE_NS` of the quickest) the stamp is the arrival, as before. Faults are counted (parser counters plus `disconnects`, `reconnects`,
`stalls`, `open_failures`) and never end the thread: a lost port is retried with capped
exponential back-off, a silent port goes STALLED (and is reopened after `stall_reopen_s`).
"""

from __future__ import annotations

import logging
import threading
from collections import Counter, deque
from dataclasses import dataclass

import serial

from tiplog.bus import Bus
from tiplog.clock import NS_PER_S, now_ns
from tiplog.devproto.packets import PROTOCOL_VERSION, STREAM_NAMES, HelloPacket, PacketType, TofPacket, Vec3Packet
from tiplog.devproto.parser import StreamParser
from tiplog.v1 import device_pb2

from .status import GatewayStatus

log = logging.getLogger("tiplog.sensor_gateway.device")

_TOF_STATUSES = set(device_pb2.TofStatus.values())


@dataclass(frozen=True)
class DeviceLinkConfig:
    """Port and timing of the serial link (seconds)."""

    port: str  # any name or URL pyserial's serial_for_url accepts
    baud: int = 921_600
    reconnect_initial_s: float = 0.05
    reconnect_max_s: float = 0.5  # cap: the port is retried at least this often
    stall_timeout_s: float = 0.5
    stall_reopen_s: float = 5.0  # 0: never reopen a stalled port
    read_timeout_s: float = 0.05


# A burst older than this on the device clock is not back-dated (a device restart, a clock jump).
MAX_BACKDATE_NS = NS_PER_S
# A sample is stamped at most this long after its device time plus its stream's smallest arrival
# delay of the last DELAY_WINDOW_NS: the ordinary jitter of the reads stays arrival time, and it
# is under the spacing of the fastest stream (4.2 ms at 240 Hz), so the samples of a stall never
# pile onto those read before or after it.
MAX_LATE_NS = 4_000_000
DELAY_WINDOW_NS = 10 * NS_PER_S


class DeviceReader:
    """Runs the serial loop on its own thread; publishes device/* through `bus`."""

    def __init__(self, config: DeviceLinkConfig, bus: Bus, status: GatewayStatus) -> None:
        self.config = config
        self.status = status
        self.parser = StreamParser()
        self.faults: Counter[str] = Counter()
        self._pubs = {
            PacketType.GYRO: bus.publisher("device/gyro"),
            PacketType.ACCEL: bus.publisher("device/accel"),
            PacketType.MAG: bus.publisher("device/mag"),
            PacketType.TOF: bus.publisher("device/tof"),
        }
        self._last_stamp_ns: dict[PacketType, int] = {}
        # per stream, (read stamp, arrival minus device time of the read's newest sample) for the
        # last DELAY_WINDOW_NS, the smallest delay first: a monotonic deque (see _quickest)
        self._delays: dict[PacketType, deque[tuple[int, int]]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="serial-reader", daemon=True)
        self.connect_times_ns: list[int] = []

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        self._thread.join(timeout_s)

    # the loop -----------------------------------------------------------------
    def _run(self) -> None:
        cfg = self.config
        backoff = cfg.reconnect_initial_s
        ever_connected = False
        while not self._stop.is_set():
            try:
                port = serial.serial_for_url(cfg.port, baudrate=cfg.baud, timeout=cfg.read_timeout_s)
            except (serial.SerialException, OSError, ValueError) as e:
                self.faults["open_failures"] += 1
                self._sync_faults()
                self.status.set_state(device_pb2.DEVICE_STATE_DISCONNECTED, f"cannot open {cfg.port}: {e}")
                self._stop.wait(backoff)
                backoff = min(backoff * 2, cfg.reconnect_max_s)
                continue
            backoff = cfg.reconnect_initial_s
            t_open = now_ns()
            self.connect_times_ns.append(t_open)
            if ever_connected:
                self.faults["reconnects"] += 1
            ever_connected = True
            self.parser.reset()
            self._sync_faults()
            self.status.set_state(device_pb2.DEVICE_STATE_CONNECTING, f"opened {cfg.port}", t_open)
            log.info("opened %s", cfg.port)
            try:
                self._read_until_lost(port, t_open)
            except Exception:  # a bug here must cost a reconnect, never the gateway
                log.exception("serial reader failed on %s; reopening", cfg.port)
                self.faults["internal_errors"] += 1
                self._sync_faults()
                self.status.set_state(device_pb2.DEVICE_STATE_DISCONNECTED, "internal error; reopening")
                self._stop.wait(backoff)
            finally:
                try:
                    port.close()
                except (serial.SerialException, OSError):
                    pass
        self.status.set_state(device_pb2.DEVICE_STATE_DISCONNECTED, "stopped")

    def _read_until_lost(self, port: serial.SerialBase, t_open: int) -> None:
        cfg = self.config
        stall_ns = int(cfg.stall_timeout_s * NS_PER_S)
        reopen_ns = int(cfg.stall_reopen_s * NS_PER_S)
        last_valid = t_open
        stalled = False
        while not self._stop.is_set():
            try:
                data = port.read(port.in_waiting or 1)
                if data and port.in_waiting:
                    data += port.read(port.in_waiting)
            except (serial.SerialException, OSError) as e:
                stamp = now_ns()
                self.faults["disconnects"] += 1
                self._sync_faults()
                self.status.set_state(device_pb2.DEVICE_STATE_DISCONNECTED, f"lost {cfg.port}: {e}", stamp)
                log.warning("lost %s: %s", cfg.port, e)
                return
            stamp = now_ns()  # arrival, before any parsing
            if data:
                n = self._handle(data, stamp)
                if n:
                    last_valid = stamp
                    if stalled or self.status.state != device_pb2.DEVICE_STATE_STREAMING:
                        stalled = False
                        self.status.set_state(device_pb2.DEVICE_STATE_STREAMING, "streaming", stamp)
                    continue
            quiet = stamp - last_valid
            if not stalled and quiet > stall_ns:
                stalled = True
                self.faults["stalls"] += 1
                self._sync_faults()
                self.status.set_state(device_pb2.DEVICE_STATE_STALLED, f"no valid frame for {quiet / NS_PER_S:.2f} s")
            if stalled and reopen_ns and quiet > reopen_ns:
                log.warning("%s silent for %.1f s: reopening", cfg.port, quiet / NS_PER_S)
                return

    def _handle(self, data: bytes, stamp_ns: int) -> int:
        """Publish the samples completed by `data`; returns how many were valid."""
        pkts = self.parser.feed(data)
        if not pkts:
            self._sync_faults()
            return 0
        counts: Counter[str] = Counter()
        newest_us = {p.type: p.device_us for p in pkts if isinstance(p, (Vec3Packet, TofPacket))}
        offset = {typ: self._quickest(typ, stamp_ns, us) for typ, us in newest_us.items()}
        for pkt in pkts:
            if isinstance(pkt, Vec3Packet):
                self._publish_vec3(pkt, self._sample_stamp(pkt, stamp_ns, newest_us[pkt.type], offset[pkt.type]))
            elif isinstance(pkt, TofPacket):
                self._publish_tof(pkt, self._sample_stamp(pkt, stamp_ns, newest_us[pkt.type], offset[pkt.type]))
            elif isinstance(pkt, HelloPacket):
                self.status.on_hello(pkt, PROTOCOL_VERSION)
            counts[STREAM_NAMES[pkt.type]] += 1
        self.status.on_samples(counts, stamp_ns)
        self._sync_faults()
        return len(pkts)

    def _quickest(self, typ: PacketType, read_ns: int, newest_us: int) -> int | None:
        """Host minus device time [ns] of the stream's quickest arrival of the last
        DELAY_WINDOW_NS, this read's newest sample included; None when this read says the device
        clock jumped (its newest sample would be over MAX_BACKDATE_NS old): the window starts
        again from it."""
        delay = read_ns - newest_us * 1000
        q = self._delays.setdefault(typ, deque())
        if q and delay - q[0][1] > MAX_BACKDATE_NS:
            q.clear()
            q.append((read_ns, delay))
            return None
        while q and q[-1][1] >= delay:
            q.pop()
        q.append((read_ns, delay))
        while q[0][0] < read_ns - DELAY_WINDOW_NS:
            q.popleft()
        return q[0][1]

    def _sample_stamp(
        self, pkt: Vec3Packet | TofPacket, read_ns: int, newest_us: int, offset: int | None = None
    ) -> int:
        """Host time of one sample of a read stamped `read_ns` [ns] (see the module docstring);
        `offset` from _quickest."""
        back_ns = (newest_us - pkt.device_us) * 1000
        t = read_ns - back_ns if 0 <= back_ns < MAX_BACKDATE_NS else read_ns
        if offset is not None:
            t = min(t, pkt.device_us * 1000 + offset + MAX_LATE_NS)
        prev = self._last_stamp_ns.get(pkt.type, 0)
        if t <= prev:
            t = min(prev + 1, read_ns)
        self._last_stamp_ns[pkt.type] = t
        return t

    def _publish_vec3(self, pkt: Vec3Packet, stamp_ns: int) -> None:
        t = pkt.type
        if t is PacketType.GYRO:
            m = device_pb2.Gyro()
            v = m.rate_radps
        elif t is PacketType.ACCEL:
            m = device_pb2.Accel()
            v = m.specific_force_mps2
        else:
            m = device_pb2.Mag()
            v = m.field_ut
        h = m.header
        h.stamp_ns = stamp_ns
        h.device_stamp_ns = pkt.device_us * 1000
        h.seq = pkt.seq_ext
        h.frame_id = "imu"
        v.x, v.y, v.z = pkt.x, pkt.y, pkt.z
        self._pubs[t].put(m)

    def _publish_tof(self, pkt: TofPacket, stamp_ns: int) -> None:
        m = device_pb2.Tof(
            range_raw_mm=pkt.range_raw_mm,
            range_smoothed_mm=pkt.range_smoothed_mm,
            smoothed_valid=pkt.smoothed_valid,
        )
        if pkt.status in _TOF_STATUSES:
            m.status = pkt.status
        else:  # a status this host does not know: kept out of the filter, counted
            self.faults["tof_status_unknown"] += 1
        h = m.header
        h.stamp_ns = stamp_ns
        h.device_stamp_ns = pkt.device_us * 1000
        h.seq = pkt.seq_ext
        h.frame_id = "tof"
        self._pubs[PacketType.TOF].put(m)

    def _sync_faults(self) -> None:
        merged = Counter(self.parser.faults)
        merged.update(self.faults)
        self.status.set_faults(merged)

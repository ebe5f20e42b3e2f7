"""A device emulator: writes the protocol into a pseudo-terminal, with fault injection.

The port's stable path is a symlink to the pty's slave (`/dev/pts/N`): unplug closes the pty
and removes the link, replug opens a new pty and relinks it. Like the firmware, which sends
only while the host holds DTR, the emulator holds its frames until a host has opened the
port (pyserial flushes the input queue on open; the pty master sees that flush in packet
mode), so what the host reads starts at a frame boundary and nothing is lost to the flush.

Callers feed samples (`send_gyro(device_us, xyz)` ...: the bench) or run the built-in
synthetic generator (`tiplog.devproto.synthetic.run_synthetic`, `python -m tiplog.devproto`).
"""

from __future__ import annotations

import fcntl
import logging
import os
import random
import select
import struct
import termios
import threading
import time
import tty
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from tiplog.clock import now_ns
from tiplog.devproto.packets import (
    SEQ_MODULO,
    STREAM_NAMES,
    HelloPacket,
    Packet,
    PacketType,
    TofPacket,
    Vec3Packet,
    encode_packet_frame,
)

log = logging.getLogger(__name__)

DEFAULT_RATES_HZ = {"gyro": 200.0, "accel": 240.0, "tof": 100.0, "mag": 100.0}
_TIOCPKT_FLUSHREAD = 0x01


@dataclass
class FaultConfig:
    """Probabilities per frame of each injected fault (seeded)."""

    garbage_prob: float = 0.0  # random bytes (0x00 included) written before the frame
    garbage_max_bytes: int = 64
    truncate_prob: float = 0.0  # the frame loses its tail, trailing delimiter included
    bitflip_prob: float = 0.0  # one bit flipped inside the frame
    drop_prob: float = 0.0  # the frame is never written (a sequence gap on the host)
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("garbage_prob", "truncate_prob", "bitflip_prob", "drop_prob"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name} must be within [0, 1], got {p}")
        if self.garbage_max_bytes < 1:
            raise ValueError(f"garbage_max_bytes must be >= 1, got {self.garbage_max_bytes}")


@dataclass(slots=True)
class WrittenFrame:
    """Ledger entry of one sample the emulator produced (record=True)."""

    stream: str
    seq: int
    device_us: int
    fate: str  # "intact", "truncated", "bitflip", "dropped", "unplugged", "no_host"
    connection: int  # plug count when written (0: never plugged)
    end_offset: int  # bytes written on this connection once the frame was out
    reached: bool = False  # intact and read by the host before the port went away


class DeviceEmulator:
    """Pseudo-terminal device at `link` (a symlink path) speaking protocol version 1.

    `wait_for_host`: send only once a host has opened the port (the firmware's DTR gate);
    until then `send` blocks, or with `drop_without_host` discards the packet (fate
    "no_host": a live source that must not fall behind). `record` keeps a ledger of every
    packet's fate, for tests that compare what reached the port with what was published.
    """

    def __init__(
        self,
        link: str | Path,
        faults: FaultConfig | None = None,
        *,
        firmware: str = "tiplog-emulator 1.0.0",
        device_id: str = "EMU-0001",
        rates_hz: dict[str, float] | None = None,
        wait_for_host: bool = True,
        drop_without_host: bool = False,
        record: bool = False,
    ) -> None:
        self.link = Path(link)
        self.faults = faults or FaultConfig()
        self.firmware = firmware
        self.device_id = device_id
        self.rates_hz = dict(rates_hz or DEFAULT_RATES_HZ)
        self.wait_for_host = wait_for_host
        self.drop_without_host = drop_without_host
        self.record = record
        self.ledger: list[WrittenFrame] = []
        self.stats: Counter[str] = Counter()
        self.plug_times_ns: list[int] = []
        self._rng = random.Random(self.faults.seed)
        self._seq: dict[PacketType, int] = {t: 0 for t in PacketType}
        self._lock = threading.RLock()
        self._master: int | None = None
        self._slave: int | None = None
        self._connection = 0
        self._conn_bytes = 0
        self._host_open = threading.Event()
        self._closed = threading.Event()
        self._hello_due = False

    # plug / unplug ----------------------------------------------------------
    @property
    def is_plugged(self) -> bool:
        return self._master is not None

    @property
    def host_open(self) -> bool:
        return self._host_open.is_set()

    def plug(self) -> None:
        """Open a new pty and point the link at it."""
        with self._lock:
            if self._master is not None:
                return
            master, slave = os.openpty()
            tty.setraw(slave, termios.TCSANOW)  # no echo, no newline translation
            fcntl.ioctl(master, termios.TIOCPKT, struct.pack("i", 1))
            os.set_blocking(master, False)
            tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")
            tmp.unlink(missing_ok=True)
            os.symlink(os.ttyname(slave), tmp)
            os.replace(tmp, self.link)  # atomic: a reader never sees a half-made link
            self._master, self._slave = master, slave
            self._connection += 1
            self._conn_bytes = 0
            self._host_open.clear()
            self._hello_due = True
            self.plug_times_ns.append(now_ns())
            log.info("plugged %s -> %s", self.link, os.ttyname(slave))

    def unplug(self, drain_timeout_s: float = 2.0) -> int:
        """Remove the link and close the pty. First waits (up to `drain_timeout_s`) until
        the host has read what was written. Returns the bytes the host never read."""
        with self._lock:
            if self._master is None:
                return 0
            pending = self._drain(drain_timeout_s)
            self.link.unlink(missing_ok=True)
            os.close(self._master)
            os.close(self._slave)
            self._master = self._slave = None
            self._host_open.clear()
            if self.record and pending:
                cut = self._conn_bytes - pending
                for w in reversed(self.ledger):
                    if w.connection != self._connection or w.end_offset <= cut:
                        break
                    w.reached = False
            self.stats["unplugs"] += 1
            self.stats["undrained_bytes"] += pending
            log.info("unplugged %s (%d bytes unread)", self.link, pending)
            return pending

    def _pending(self) -> int:
        return struct.unpack("i", fcntl.ioctl(self._slave, termios.FIONREAD, b"\0" * 4))[0]

    def _drain(self, timeout_s: float, quiet_s: float = 0.05) -> int:
        # FIONREAD sees only the line discipline's 4 KiB; up to ~60 KiB more can wait in the
        # pty's flip buffers, pushed by a kernel worker. So "drained" means the queue stayed
        # empty for `quiet_s`, long enough for that worker on a loaded machine.
        deadline = time.monotonic() + timeout_s
        quiet_since = None
        while time.monotonic() < deadline:
            now = time.monotonic()
            if self._pending() == 0:
                quiet_since = quiet_since or now
                if now - quiet_since >= quiet_s:
                    return 0
            else:
                quiet_since = None
            time.sleep(0.002)
        return self._pending()

    def wait_host(self, timeout_s: float | None = None) -> bool:
        """Wait until a host has opened the port (True) or the timeout passed."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not self._closed.is_set():
            with self._lock:
                if self._master is None:
                    return False
                self._poll_master(0.0)
                if self._host_open.is_set():
                    return True
            if deadline is not None and time.monotonic() >= deadline:
                return False
            time.sleep(0.002)
        return False

    def _poll_master(self, timeout_s: float) -> None:
        r, _, _ = select.select([self._master], [], [], timeout_s)
        if r:
            try:
                data = os.read(self._master, 4096)
            except OSError:  # EIO: no slave open at this instant
                return
            if data and data[0] & _TIOCPKT_FLUSHREAD:
                self._host_open.set()

    def close(self) -> None:
        self._closed.set()
        self.unplug(drain_timeout_s=0.0)

    def __enter__(self) -> DeviceEmulator:
        self.plug()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # sending ------------------------------------------------------------------
    def send_gyro(self, device_us: int, rate_radps: Sequence[float]) -> None:
        self.send(Vec3Packet(PacketType.GYRO, 0, device_us, *rate_radps))

    def send_accel(self, device_us: int, specific_force_mps2: Sequence[float]) -> None:
        self.send(Vec3Packet(PacketType.ACCEL, 0, device_us, *specific_force_mps2))

    def send_mag(self, device_us: int, field_ut: Sequence[float]) -> None:
        self.send(Vec3Packet(PacketType.MAG, 0, device_us, *field_ut))

    def send_tof(
        self,
        device_us: int,
        range_raw_mm: float,
        status: int = 1,
        range_smoothed_mm: float = 0.0,
        smoothed_valid: bool = False,
    ) -> None:
        self.send(TofPacket(0, device_us, range_raw_mm, status, range_smoothed_mm, smoothed_valid))

    def send_hello(self, device_us: int, tx_dropped: int = 0) -> None:
        self.send(HelloPacket(0, device_us, self.firmware, self.device_id, self.rates_hz, tx_dropped=tx_dropped))

    def send(self, pkt: Packet) -> None:
        """Number `pkt` on its stream, inject faults, write it (or not, if unplugged).
        The first packet after a host opened the port is preceded by a HELLO."""
        if self._hello_due and pkt.type != PacketType.HELLO and self._master is not None:
            with self._lock:
                present = not self.wait_for_host or self._host_present()
            if present:
                self._hello_due = False
                self.send_hello(pkt.device_us)
        pkt.seq = self._seq[pkt.type]
        self._seq[pkt.type] = (pkt.seq + 1) % SEQ_MODULO
        frame = encode_packet_frame(pkt)
        f, rng = self.faults, self._rng
        with self._lock:
            fate = "intact"
            if self._master is None:
                fate = "unplugged"
            elif f.drop_prob and rng.random() < f.drop_prob:
                fate = "dropped"
            elif self.wait_for_host and not self._host_present():
                fate = "unplugged" if self._master is None else "no_host"
            if fate == "intact":
                if f.garbage_prob and rng.random() < f.garbage_prob:
                    junk = rng.randbytes(rng.randint(1, f.garbage_max_bytes))
                    self._write(junk)
                    self.stats["garbage_bytes"] += len(junk)
                if f.truncate_prob and rng.random() < f.truncate_prob:
                    frame = frame[: rng.randint(1, len(frame) - 2)]
                    fate = "truncated"
                elif f.bitflip_prob and rng.random() < f.bitflip_prob:
                    buf = bytearray(frame)
                    buf[rng.randint(1, len(frame) - 2)] ^= 1 << rng.randrange(8)
                    frame = bytes(buf)
                    fate = "bitflip"
                self._write(frame)
            self.stats[fate] += 1
            if self.record:
                self.ledger.append(
                    WrittenFrame(
                        STREAM_NAMES[pkt.type], pkt.seq, pkt.device_us, fate, self._connection,
                        self._conn_bytes, fate == "intact",
                    )
                )  # fmt: skip

    def _host_present(self) -> bool:
        """Whether a host holds the port open; blocks for one unless `drop_without_host`."""
        if self._host_open.is_set():
            return True
        if self.drop_without_host:
            with self._lock:
                if self._master is not None:
                    self._poll_master(0.0)
            return self._host_open.is_set()
        self._lock.release()  # let unplug() in while we wait (send holds the lock once)
        try:
            return self.wait_host()
        finally:
            self._lock.acquire()

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view and self._master is not None and not self._closed.is_set():
            self._poll_master(0.0)
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                select.select([self._master], [self._master], [], 0.05)
                continue
            view = view[n:]
            self._conn_bytes += n
        self.stats["bytes"] += len(data) - len(view)

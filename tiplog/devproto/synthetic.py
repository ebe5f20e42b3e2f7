"""Synthetic sample streams for the emulator: gyro, accel, ToF, mag and hello packets in
device-clock order at the nominal rates, seeded (no physics: the bench has that)."""

from __future__ import annotations

import heapq
import logging
import math
import random
import threading
import time
from collections.abc import Iterator
from typing import Protocol

from tiplog.devproto.packets import HelloPacket, Packet, PacketType, TofPacket, Vec3Packet

log = logging.getLogger(__name__)

G_MPS2 = 9.80665


class PacketSink(Protocol):
    """What `run_synthetic` drives: a `tiplog.devproto.emulator.DeviceEmulator` (or a fake)."""

    rates_hz: dict[str, float]
    firmware: str
    device_id: str

    def send(self, pkt: Packet) -> None: ...
    def plug(self) -> None: ...
    def unplug(self) -> object: ...


def synthetic_packets(
    rates_hz: dict[str, float],
    *,
    seed: int = 0,
    start_us: int = 1_000_000,
    firmware: str = "tiplog-emulator 1.0.0",
    device_id: str = "EMU-0001",
) -> Iterator[Packet]:
    """Endless packets, sequence numbers left 0 (the emulator numbers them)."""
    rng = random.Random(seed)
    period_us = {"hello": 1e6}
    for name in ("gyro", "accel", "tof", "mag"):
        if rates_hz.get(name, 0.0) > 0.0:
            period_us[name] = 1e6 / rates_hz[name]
    # (next time, tie-break order, name, sample index)
    heap = [(start_us, i, name, 0) for i, name in enumerate(sorted(period_us))]
    heapq.heapify(heap)
    window: list[float] = []
    while True:
        t_us, order, name, k = heapq.heappop(heap)
        heapq.heappush(heap, (start_us + round((k + 1) * period_us[name]), order, name, k + 1))
        t_s = t_us * 1e-6
        if name == "gyro":
            w = 0.3 * math.sin(2 * math.pi * 0.5 * t_s)
            yield Vec3Packet(PacketType.GYRO, 0, t_us, w + rng.gauss(0, 0.002), rng.gauss(0, 0.002), -w)
        elif name == "accel":
            yield Vec3Packet(PacketType.ACCEL, 0, t_us, rng.gauss(0, 0.05), rng.gauss(0, 0.05), G_MPS2)
        elif name == "mag":
            yield Vec3Packet(PacketType.MAG, 0, t_us, 22.0 + rng.gauss(0, 0.3), -3.0, 41.0)
        elif name == "tof":
            raw = 120.0 + 5.0 * math.sin(2 * math.pi * 0.2 * t_s) + rng.gauss(0, 3.0)
            window = (window + [raw])[-5:]
            yield TofPacket(0, t_us, raw, 1, sum(window) / len(window), len(window) == 5)
        else:
            yield HelloPacket(0, t_us, firmware, device_id, dict(rates_hz))


def run_synthetic(
    emu: PacketSink,
    *,
    speed: float = 1.0,
    duration_s: float | None = None,
    seed: int = 0,
    stop: threading.Event | None = None,
    unplug_every_s: float = 0.0,
    unplug_for_s: float = 1.0,
    stall_every_s: float = 0.0,
    stall_for_s: float = 2.0,
) -> None:
    """Stream synthetic samples; `speed` 1.0 is real time, 0 as fast as the host reads.
    Unplug and stall schedules are in device seconds (0 disables them)."""
    stop = stop or threading.Event()
    start_us = 1_000_000
    wall0 = time.monotonic()
    next_unplug = unplug_every_s or math.inf
    next_stall = stall_every_s or math.inf
    offset_s = 0.0  # wall time the device spent stalled (its clock stops: firmware hung)
    replug_at: float | None = None
    for pkt in synthetic_packets(emu.rates_hz, seed=seed, start_us=start_us, firmware=emu.firmware,
                                 device_id=emu.device_id):  # fmt: skip
        t_s = (pkt.device_us - start_us) * 1e-6
        if stop.is_set() or (duration_s is not None and t_s >= duration_s):
            return
        # The device keeps sampling while unplugged: those packets consume their sequence
        # numbers and are never written, so the host sees the gap.
        if replug_at is not None and t_s >= replug_at:
            emu.plug()
            replug_at = None
        if t_s >= next_unplug:
            emu.unplug()
            replug_at = t_s + unplug_for_s
            next_unplug += unplug_every_s
        if t_s >= next_stall:
            log.info("stalling for %.1f s", stall_for_s)
            if stop.wait(stall_for_s / (speed or 1.0)):
                return
            offset_s += stall_for_s
            next_stall += stall_every_s
        if speed > 0:
            lag = wall0 + (t_s + offset_s) / speed - time.monotonic()
            if lag > 0:
                time.sleep(lag)
        emu.send(pkt)

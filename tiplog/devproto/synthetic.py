"""Synthetic sample streams for the emulator: gyro, accel, ToF, mag and hello packets in
device-clock order at the nominal rates, seeded (no physics: the bench has that)."""

from __future__ import annotations

import heapq
import math
import random
from collections.abc import Iterator

from tiplog.devproto.packets import HelloPacket, Packet, PacketType, TofPacket, Vec3Packet

G_MPS2 = 9.80665


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

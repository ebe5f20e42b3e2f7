"""A device sample's time on the host clock, from the device's own clock.

The gateway stamps every sample on arrival (`header.stamp_ns`) and passes the module's own stamp
on (`header.device_stamp_ns`). Arrival is the sample's time plus the link's latency, as long as
the host keeps up. When it does not (a busy cart: the gateway or the bus held up for a second),
the samples of the whole stall arrive together: by arrival they are one gap and then a burst
at one instant, and a filter timed by arrival integrates the stall's motion as none. The device
clock keeps their spacing. So a sample's host time is its device stamp plus the typical
(arrival - device) offset, followed by a slow average over the samples that were not held up;
a held-up sample keeps the offset it finds. The latency calibrated for the stream is then taken
off as before (the offset includes the link's mean latency, as arrival does).

One `DeviceClock` per stream, fed in the stream's own order, so that the live service and an
offline run over the recording (which interleave streams differently) map every sample alike."""

from __future__ import annotations


class DeviceClock:
    """Host time [ns] of a stream's samples from (arrival, device stamp) pairs in stream order.

    - `tau_s`: time constant of the offset's average, in device time (it follows the two clocks'
      drift: tens of ppm, a tenth of a millisecond behind at most).
    - `held_ns`: a sample whose arrival is more than this after the offset predicts was held up
      on the way; it does not move the offset.
    - `lost_ns`: a sample that arrives more than this before the offset predicts, or more than
      `stalled_ns` after it, or whose device stamp does not advance, means the device's clock
      started again (a replug, a reset): the offset is taken anew from that sample.
    A device stamp of 0 is a device without a clock: its arrival is its time."""

    def __init__(
        self,
        tau_s: float = 2.0,
        held_ns: int = 3_000_000,
        lost_ns: int = 5_000_000,
        stalled_ns: int = 10_000_000_000,
    ):
        self.tau_ns = tau_s * 1e9
        self.held_ns = held_ns
        self.lost_ns = lost_ns
        self.stalled_ns = stalled_ns
        self.offset_ns: float | None = None
        self.last_device_ns = 0
        self.last_ns = -(1 << 62)
        self.held = 0  # samples timed by the device clock that arrived held up
        self.restarts = 0  # times the offset was taken anew after the first

    def host_ns(self, arrival_ns: int, device_ns: int) -> int:
        if device_ns <= 0:
            return arrival_ns
        r = arrival_ns - device_ns
        off = self.offset_ns
        if off is None or device_ns <= self.last_device_ns or not (-self.lost_ns <= r - off <= self.stalled_ns):
            self.restarts += off is not None
            off = float(r)
        elif r - off <= self.held_ns:
            off += (r - off) * min(1.0, (device_ns - self.last_device_ns) / self.tau_ns)
        else:
            self.held += 1
        self.offset_ns = off
        self.last_device_ns = device_ns
        # never before the stream's previous sample (only where the offset was taken anew)
        t = max(device_ns + int(round(off)), self.last_ns)
        self.last_ns = t
        return t

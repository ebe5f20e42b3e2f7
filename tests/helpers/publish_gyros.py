"""Child process for the two-process bus test: waits for the subscriber's liveliness token,
publishes N gyro messages, and stays until the subscriber says it has them all."""

from __future__ import annotations

import argparse
import sys
import threading

from tiplog.bus import Bus, BusConfig
from tiplog.v1 import device_pb2


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--prefix", required=True)
    ap.add_argument("-n", type=int, default=1000)
    a = ap.parse_args()
    ready, done = threading.Event(), threading.Event()

    def on_alive(service: str, alive: bool) -> None:
        if alive and service == "test-subscriber":
            ready.set()
        if alive and service == "test-done":
            done.set()

    with Bus(BusConfig(connect=[a.connect], prefix=a.prefix), service="test-publisher") as bus:
        bus.watch_alive(on_alive)
        pub = bus.publisher("device/gyro")
        if not ready.wait(20):
            print("subscriber never appeared", file=sys.stderr)
            return 3
        for k in range(a.n):
            m = device_pb2.Gyro()
            m.header.seq = k
            m.header.stamp_ns = 1_000_000 * k
            m.rate_radps.x = k * 1e-3
            pub.put(m)
        if not done.wait(20):
            print("subscriber never finished", file=sys.stderr)
            return 4
    return 0


if __name__ == "__main__":
    sys.exit(main())

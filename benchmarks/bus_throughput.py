"""Messages per second through the bus between two sessions on loopback, by payload size."""

from __future__ import annotations

import argparse
import threading
import time

from tiplog.bus import Bus, BusConfig
from tiplog.v1 import device_pb2


def run(n: int, port: int) -> float:
    ep = f"tcp/127.0.0.1:{port}"
    done = threading.Event()
    count = [0]

    def on(m, i):
        count[0] += 1
        if count[0] == n:
            done.set()

    with (
        Bus(BusConfig(listen=[ep], connect=[], prefix="bench/")) as a,
        Bus(BusConfig(connect=[ep], prefix="bench/")) as b,
    ):
        a.subscribe("device/gyro", on)
        pub = b.publisher("device/gyro")
        m = device_pb2.Gyro()
        m.rate_radps.x = 0.1
        time.sleep(0.5)  # benchmark only: let the declarations propagate
        t0 = time.perf_counter()
        for k in range(n):
            m.header.seq = k
            pub.put(m)
        done.wait(60)
        return count[0] / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("-n", type=int, default=50_000)
    ap.add_argument("--port", type=int, default=17499)
    a = ap.parse_args(argv)
    rate = run(a.n, a.port)
    print(f"gyro messages/s through the bus: {rate:,.0f} (device total ~640/s: x{rate / 640:,.0f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""`python -m tiplog.devproto`: a device emulator streaming synthetic samples into a
pseudo-terminal, with fault injection (what the gateway's tests and a bench without physics use)."""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from collections.abc import Sequence

from tiplog.devproto.emulator import DeviceEmulator, FaultConfig
from tiplog.devproto.synthetic import run_synthetic

log = logging.getLogger("tiplog.devproto")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tiplog.devproto", description=__doc__.split("\n")[0])
    ap.add_argument("--link", default="/tmp/tiplog-device", help="symlink path the host opens")
    ap.add_argument("--speed", type=float, default=1.0, help="1 = real time, 0 = as fast as read")
    ap.add_argument("--duration", type=float, default=None, help="device seconds to stream (default: forever)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--garbage", type=float, default=0.0, help="probability per frame")
    ap.add_argument("--truncate", type=float, default=0.0, help="probability per frame")
    ap.add_argument("--bitflip", type=float, default=0.0, help="probability per frame")
    ap.add_argument("--drop", type=float, default=0.0, help="probability per frame")
    ap.add_argument("--unplug-every", type=float, default=0.0, help="seconds between unplugs (0: never)")
    ap.add_argument("--unplug-for", type=float, default=1.0)
    ap.add_argument("--stall-every", type=float, default=0.0, help="seconds between stalls (0: never)")
    ap.add_argument("--stall-for", type=float, default=2.0)
    ap.add_argument(
        "--no-host",
        choices=["drop", "block"],
        default="drop",
        help="while no host has the port open: drop samples (default) or wait",
    )
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        faults = FaultConfig(a.garbage, 64, a.truncate, a.bitflip, a.drop, a.seed)
    except ValueError as e:
        ap.error(str(e))
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with DeviceEmulator(a.link, faults, drop_without_host=a.no_host == "drop") as emu:
        try:
            run_synthetic(
                emu, speed=a.speed, duration_s=a.duration, seed=a.seed, stop=stop,
                unplug_every_s=a.unplug_every, unplug_for_s=a.unplug_for,
                stall_every_s=a.stall_every, stall_for_s=a.stall_for,
            )  # fmt: skip
        except KeyboardInterrupt:
            pass
        log.info("done: %s", dict(emu.stats))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

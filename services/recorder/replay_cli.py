"""`tiplog replay`: a recording back onto the bus, with its original timing or as fast as
possible, so fusion, vision and the dashboard can run on it live."""

from __future__ import annotations

import argparse
import sys
import threading

from tiplog.bus import BusConfig
from tiplog.config import load_config
from tiplog.service import add_bus_arguments, overrides_from_args


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="FILE", help="MCAP file")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--speed", type=float, default=1.0, help="playback speed factor")
    speed.add_argument("--max", action="store_true", help="as fast as possible")
    p.add_argument("--topics", nargs="*", help="only these topics (default: all but recorder/*)")
    p.add_argument("--wait", type=float, default=5.0, help="seconds to wait for a subscriber before starting")
    p.add_argument("-c", "--config", metavar="FILE", help="YAML configuration file (its bus section)")
    add_bus_arguments(p)
    p.set_defaults(func=_run, set=[])


def _run(args: argparse.Namespace) -> int:
    import signal

    from pydantic import BaseModel, Field

    from services.recorder.replay import replay
    from tiplog.bus import Bus

    class _Cfg(BaseModel):
        bus: BusConfig = Field(default_factory=BusConfig)
        log_level: str = "INFO"

    from tiplog import mcap_salvage
    from tiplog.userio import UserError, input_mcap, truncation_note

    path = input_mcap(args.recording, allow_truncated=True)
    if not mcap_salvage.ends_in_order(path):
        state, n = mcap_salvage.scan(path)
        if not state.complete and n == 0:  # nothing to replay: say so before joining the bus
            raise UserError(truncation_note(path, state, n))
    if args.speed is not None and not args.max and args.speed <= 0:
        raise UserError(f"--speed must be > 0 (got {args.speed})")
    # Standalone: with no router on this machine, the first tiplog process holds the endpoint
    # and the others (`tiplog record run` in another terminal) join it.
    config = load_config(_Cfg, "replay", args.config, [("bus.standalone", True), *overrides_from_args(args)])
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set, daemon=True).start())
    with Bus(config.bus, service="replay") as bus:
        rep = replay(
            bus,
            path,
            speed=args.speed,
            as_fast_as_possible=args.max,
            topics_=args.topics,
            stop=stop,
            wait_s=args.wait,
        )
    print(f"replayed {rep.messages} messages in {rep.duration_s:.2f} s (worst lateness {rep.max_late_ns / 1e6:.2f} ms)")
    for topic, n in sorted(rep.messages_by_topic.items()):
        print(f"  {topic:<24}{n:>10}")
    if rep.skipped_topics:
        print(f"skipped (unknown schema): {', '.join(sorted(rep.skipped_topics))}")
    if rep.salvage is not None and not rep.salvage.complete:
        sys.stdout.flush()
        print(f"tiplog replay: {truncation_note(path, rep.salvage, rep.messages, 'replayed')}", file=sys.stderr)
        return 2
    return 0

"""`tiplog replay`: a recording back onto the bus, with its original timing or as fast as
possible, so fusion, vision and the dashboard can run on it live."""

from __future__ import annotations

import argparse
import sys
import threading

from services.recorder.replay import LATE_NS, MAX_SPEED, MIN_SPEED
from tiplog.bus import BusConfig
from tiplog.cliargs import finite
from tiplog.config import load_config
from tiplog.service import add_bus_arguments, overrides_from_args


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="FILE", help="MCAP file")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument(
        "--speed",
        type=finite(MIN_SPEED, MAX_SPEED),
        default=1.0,
        help=f"playback speed factor, {MIN_SPEED:g} to {MAX_SPEED:g} (default 1)",
    )
    speed.add_argument("--max", action="store_true", help="as fast as possible")
    p.add_argument("--topics", nargs="*", help="only these topics (default: all but recorder/*)")
    p.add_argument(
        "--wait",
        type=finite(0, 3600),
        default=5.0,
        help="seconds to wait for a subscriber before starting, 0 to 3600 (default 5)",
    )
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
    from tiplog.userio import UserError, input_mcap, trailer_note, truncation_note

    path = input_mcap(args.recording, allow_truncated=True)
    problem = mcap_salvage.trailer_problem(path)
    if problem:
        state, n = mcap_salvage.scan(path)
        if state.complete:
            # The data is whole and only what follows it is wrong (bytes appended, the footer
            # cut off, a summary failing its CRC): refused before joining the bus, in the line
            # every other reader gives; `record recover` rebuilds the file losing nothing.
            raise UserError(trailer_note(path, problem))
        if n == 0:  # nothing to replay: say so before joining the bus
            raise UserError(truncation_note(path, state, n))
    # Standalone: with no router on this machine, the first tiplog process holds the endpoint
    # and the others (`tiplog record run` in another terminal) join it.
    config = load_config(_Cfg, "replay", args.config, [("bus.standalone", True), *overrides_from_args(args)])
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set, daemon=True).start())
    try:
        bus = Bus(config.bus, service="replay", stop=stop)  # SIGTERM ends the wait for a router too
    except ConnectionError:
        if stop.is_set():
            return 143  # 128 + SIGTERM, as had it not been caught
        raise
    with bus:
        rep = replay(
            bus,
            path,
            speed=args.speed,
            as_fast_as_possible=args.max,
            topics_=args.topics,
            stop=stop,
            wait_s=args.wait,
        )
    print(
        f"replayed {rep.messages} messages in {rep.duration_s:.2f} s "
        f"(worst lateness {rep.max_late_ns / 1e6:.2f} ms, {rep.late_puts} late by over {LATE_NS / 1e6:g} ms)"
    )
    for topic, n in sorted(rep.messages_by_topic.items()):
        print(f"  {topic:<24}{n:>10}")
    if rep.skipped_topics:
        print(f"skipped (unknown schema): {', '.join(sorted(rep.skipped_topics))}")
    if rep.salvage is not None and not rep.salvage.complete:
        sys.stdout.flush()
        print(f"tiplog replay: {truncation_note(path, rep.salvage, rep.messages, 'replayed')}", file=sys.stderr)
        return 2
    return 0

"""`tiplog info`: what a recording holds (duration, topics, types, rates, counts, gaps,
metadata). A file cut short or damaged is shown as far as it can be read, and said so (exit
status 2)."""

from __future__ import annotations

import argparse
import json
import sys


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="FILE", help="MCAP file")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from services.recorder.info import format_info, inspect
    from tiplog import mcap_salvage
    from tiplog.userio import damage_note, input_mcap, records_note, trailer_note, truncation_note

    path = input_mcap(args.recording, allow_truncated=True, check_records=False)  # shown as it is
    info = inspect(path)
    print(json.dumps(info, indent=1) if args.json else format_info(info))
    if info["indexed"]:
        error = info["metadata"].get("_read_error")
        problem = mcap_salvage.trailer_problem(path)  # the summary it was read through, by its CRC
        if error is None and not problem:
            note = records_note(path)  # metadata changed where no CRC of its own would tell
            if note is None:
                return 0
        elif error is None:
            note = trailer_note(path, problem)
        else:
            note = error.get("note") or damage_note(path) or f"{path}: not all of it could be read ({error['error']})"
    else:
        state, n = mcap_salvage.scan(path)
        if state.complete:  # a finished data section: nothing lost, but its end may be damaged
            problem = mcap_salvage.trailer_problem(path)
            if not problem:
                return 0
            note = trailer_note(path, problem)
        else:
            note = truncation_note(path, state, n, "shown")
    sys.stdout.flush()
    print(f"tiplog info: {note}", file=sys.stderr)
    return 2

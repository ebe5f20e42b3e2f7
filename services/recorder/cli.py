"""`tiplog record`: run a recorder, control a running one, or recover a truncated file.

tiplog record run [--out-dir DIR] [--start]     a recorder in the foreground
tiplog record start|stop|split|mark|status      talk to the running recorder over the bus
tiplog record recover FILE [--out FILE]         rebuild a valid indexed file
"""

from __future__ import annotations

import argparse
import json
import sys

from tiplog.cliargs import finite
from tiplog.config import load_config
from tiplog.service import add_bus_arguments, overrides_from_args

ACTIONS = {"start": 1, "stop": 2, "split": 3, "mark": 4, "status": 5}  # RecorderAction values


def register(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="record_command", metavar="ACTION", required=True)
    r = sub.add_parser("run", help="run a recorder in the foreground until interrupted")
    r.add_argument("-c", "--config", metavar="FILE", help="YAML configuration file")
    r.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="override a recorder field")
    add_bus_arguments(r)
    r.add_argument("--out-dir", help="folder for the recordings (default: recorder.out_dir)")
    r.add_argument("--start", action="store_true", help="start a session at once (autostart=always)")
    r.set_defaults(func=_run)
    for action in ACTIONS:
        a = sub.add_parser(action, help=f"{action} on the running recorder, over the bus")
        add_bus_arguments(a)
        a.add_argument("-c", "--config", metavar="FILE", help="YAML configuration file (its bus section)")
        if action == "start":
            a.add_argument("--session", default="", help="session name (default: prefix + UTC time)")
        if action in ("start", "stop", "split", "mark"):
            a.add_argument(
                "reason",
                nargs="?" if action != "mark" else None,
                default="",
                help="event label" if action == "mark" else "reason, recorded in the file",
            )
        a.add_argument("--json", action="store_true", help="print the reply as JSON")
        a.add_argument(
            "--timeout",
            type=finite(0, 3600, lo_open=True),
            default=10.0,
            help="seconds to wait for the reply, up to 3600 (default 10)",
        )
        a.set_defaults(func=_control, action=action, set=[])
    rc = sub.add_parser("recover", help="rebuild a valid indexed file from a truncated one")
    rc.add_argument("file", metavar="FILE", help="MCAP file cut short (a crash, a full disk)")
    rc.add_argument("--out", metavar="FILE", help="output file (default: FILE with .recovered.mcap)")
    rc.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    rc.add_argument("--json", action="store_true")
    rc.set_defaults(func=_recover)


def _run(args: argparse.Namespace) -> int:
    from services.recorder.app import main

    # Standalone: with no router on this machine the recorder holds the endpoint itself, so a
    # `tiplog replay` started alone in another terminal reaches it.
    argv: list[str] = ["--set", "bus.standalone=true"]
    for flag in ("config", "mode", "prefix"):
        v = getattr(args, flag, None)
        if v:
            argv += [f"--{flag.replace('_', '-')}", v]
    for flag in ("connect", "listen"):
        for v in getattr(args, flag, None) or []:
            argv += [f"--{flag}", v]
    for s in args.set or []:
        argv += ["--set", s]
    if args.out_dir:
        argv += ["--set", f"out_dir={args.out_dir}"]
    if args.start:
        argv += ["--set", "autostart=always"]
    return main(argv)


def _control(args: argparse.Namespace) -> int:
    from google.protobuf.json_format import MessageToDict

    from services.recorder.config import RecorderConfig
    from tiplog import topics
    from tiplog.bus import Bus
    from tiplog.v1 import recorder_pb2

    config = load_config(RecorderConfig, "recorder", args.config, overrides_from_args(args))
    cmd = recorder_pb2.RecorderCommand(
        action=ACTIONS[args.action], reason=getattr(args, "reason", "") or "", session=getattr(args, "session", "")
    )
    with Bus(config.bus) as bus:
        replies = bus.request(topics.RECORDER_COMMAND, cmd.SerializeToString(), timeout_s=args.timeout)
    if not replies:
        print("tiplog: no recorder answered on the bus (is one running? same --prefix/--connect?)", file=sys.stderr)
        return 1
    rc = 0
    for raw in replies:
        reply = recorder_pb2.RecorderReply.FromString(raw)
        if args.json:
            print(json.dumps(MessageToDict(reply, preserving_proto_field_name=True), indent=1))
        else:
            print(format_status(reply.status, f"{'ok' if reply.ok else 'FAILED'}: {reply.message}"))
        rc = rc or (0 if reply.ok else 1)
    return rc


def format_status(st, headline: str = "") -> str:  # type: ignore[no-untyped-def]
    """A RecorderStatus as a few lines of text with a per-topic table."""
    from tiplog.v1 import recorder_pb2

    state = recorder_pb2.RecorderState.Name(st.state).removeprefix("RECORDER_STATE_")
    lines = [headline] if headline else []
    lines.append(f"state {state}  session {st.session or '-'}  file #{st.file_index}  {st.path or ''}")
    lines.append(
        f"written {st.bytes_written / 2**20:.1f} MiB  free {st.free_bytes / 2**30:.1f} GiB  duration {st.duration_s:.1f} s"
    )
    if st.alarm:
        lines.append(f"ALARM: {st.alarm}")
    if st.topics:
        lines.append(
            f"{'topic':<24} {'received':>10} {'written':>10} {'dropped':>10} {'seq gaps':>10} {'time gaps':>10} {'gap s':>8}"
        )
        for t, c in sorted(st.topics.items()):
            lines.append(
                f"{t:<24} {c.received:>10} {c.written:>10} {c.dropped:>10} {c.upstream_gaps:>10} {c.time_gaps:>10} "
                f"{c.time_gap_s:>8.2f}"
            )
    return "\n".join(lines)


def _recover(args: argparse.Namespace) -> int:
    from pathlib import Path

    from services.recorder.recover import recover
    from tiplog.userio import UserError, atomic_output, input_mcap, records_note

    src = input_mcap(args.file, allow_truncated=True, check_records=False)  # copied as it is
    changed = records_note(src)
    out = Path(args.out) if args.out else src.with_suffix(".recovered.mcap")
    if out.exists() and out.resolve() == src.resolve():
        raise UserError(f"{out}: --out must differ from the file being recovered")
    with atomic_output(out, args.force) as tmp:
        rep = recover(src, tmp)
    rep.output = str(out)
    if args.json:
        print(json.dumps(rep.as_dict(), indent=1))
        return 0
    print(f"{out}: kept {rep.messages} messages, {rep.metadata} metadata, {rep.attachments} attachments")
    for topic, n in sorted(rep.messages_by_topic.items()):
        print(f"  {topic:<24}{n:>10}")
    if changed:
        print(
            f"{changed.split('; ', 1)[0]}; its records were copied as they were read: check its metadata",
            file=sys.stderr,
        )
    if rep.complete:
        print("the source was complete: nothing lost")
    else:
        last = "-" if rep.last_good_log_ns is None else f"{rep.last_good_log_ns} ns"
        span = (
            ""
            if rep.first_log_ns is None or rep.last_good_log_ns is None
            else f" ({(rep.last_good_log_ns - rep.first_log_ns) / 1e9:.3f} s kept)"
        )
        print(f"lost: {rep.lost_bytes} truncated bytes after offset {rep.good_bytes}; last good log time {last}{span}")
        if rep.error:
            print(f"stopped at: {rep.error}")
    return 0

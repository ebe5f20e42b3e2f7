"""A real OpenIGTLink client in its own process (pyigtl's OpenIGTLinkClient), for the tests.

    python -m tests.helpers.igtl_client HOST PORT OUT.jsonl

Writes one JSON line per message received (when, on the host clock; type, device, header
timestamp, metadata, matrix or string), flushed as it comes, until SIGTERM. pyigtl keeps only the newest message per device;
the client's dict of incoming messages is replaced by one that also writes each message down,
so none is missed between polls. It sends a STRING every 0.2 s, as Slicer's client sends
queries: a send to a closed server fails, and pyigtl's client then reconnects.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time

import pyigtl


class _Logged(dict):
    def __init__(self, out):
        super().__init__()
        self.out = out

    def __setitem__(self, key, msg):
        row = {
            "received_ns": time.monotonic_ns(),  # the host clock every tiplog stamp is on
            "type": msg.message_type,
            "device": msg.device_name,
            "timestamp": msg.timestamp,
            "header_version": msg.header_version,
            "metadata": dict(msg.metadata),
        }
        if msg.message_type == "TRANSFORM":
            row["matrix"] = [[float(v) for v in r] for r in msg.matrix]
        elif msg.message_type == "STRING":
            row["string"] = msg.string
        self.out.write(json.dumps(row) + "\n")
        self.out.flush()
        super().__setitem__(key, msg)


def main(host: str, port: int, path: str) -> int:
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with open(path, "a") as out:
        client = pyigtl.OpenIGTLinkClient(host=host, port=port, start_now=False)
        client.incoming_messages = _Logged(out)
        client.start()
        while not stop.wait(0.2):
            client.send_message(pyigtl.StringMessage("ping", device_name="TestClient"), wait=False)
        client.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], int(sys.argv[2]), sys.argv[3]))

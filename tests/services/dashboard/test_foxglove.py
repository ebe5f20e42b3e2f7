"""Foxglove live: a plain websocket client speaking the Foxglove protocol subscribes to
fusion/state on the bridge and receives the published messages with their schema."""

from __future__ import annotations

import base64
import json
import struct
import threading
import time

import pytest
from google.protobuf import descriptor_pb2
from websockets.sync.client import connect

from services.dashboard.app import start
from services.dashboard.auth import Tokens
from services.dashboard.config import DashboardConfig
from tests.services.dashboard.conftest import make_state
from tiplog.bus import Bus
from tiplog.userio import UserError
from tiplog.v1 import fusion_pb2

pytest.importorskip("foxglove")
SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk's server speaks (the app's current protocol)


def _recv_json(ws, op: str) -> dict:
    while True:
        msg = ws.recv(timeout=10)
        if isinstance(msg, str):
            obj = json.loads(msg)
            if obj.get("op") == op:
                return obj


def test_client_subscribes_to_fusion_state_and_receives_it(bus_pair_configs):
    listen_cfg, connect_cfg = bus_pair_configs
    with Bus(listen_cfg, service="dashboard") as dash_bus, Bus(connect_cfg) as pub_bus:
        cfg = DashboardConfig(bus=listen_cfg, port=0, foxglove_bridge=True, foxglove_port=0)
        running = start(dash_bus, cfg, Tokens())
        try:
            bridge = running.bridge
            pub = pub_bus.publisher("fusion/state")
            advertised = threading.Event()
            k = 0
            while not advertised.wait(0.05):  # until the bridge has the topic (first message)
                pub.put(make_state(1 + k))
                k += 1
                if bridge.relayed:
                    advertised.set()
                assert k < 400, "the bridge never received fusion/state"
            # no client subscribed: the payloads are not even copied out of the bus
            relayed = bridge.relayed
            for i in range(5):
                pub.put(make_state(5_000 + i))
            deadline = time.monotonic() + 10
            while bridge.skipped < 5:
                assert time.monotonic() < deadline, bridge.skipped
                time.sleep(0.02)  # the bus's callbacks run on its threads: nothing to wait on
            assert bridge.relayed == relayed
            with connect(f"ws://127.0.0.1:{bridge.port}", subprotocols=[SUBPROTOCOL]) as ws:
                assert _recv_json(ws, "serverInfo")["name"] == "tiplog"
                channels = _recv_json(ws, "advertise")["channels"]
                (ch,) = [c for c in channels if c["topic"] == "fusion/state"]
                assert ch["encoding"] == "protobuf" and ch["schemaName"] == "tiplog.v1.FusionState"
                fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(ch["schema"]))
                assert "tiplog/v1/fusion.proto" in {f.name for f in fds.file}
                ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": ch["id"]}]}))
                got: list[fusion_pb2.FusionState] = []
                sent = 0
                while len(got) < 20:
                    pub.put(make_state(10_000 + sent, depth_mm=1000.0 + sent))
                    sent += 1
                    assert sent < 2000, f"only {len(got)} messages reached the Foxglove client"
                    while True:  # take what has arrived without waiting for more
                        try:
                            msg = ws.recv(timeout=0.02)
                        except TimeoutError:
                            break
                        if isinstance(msg, bytes) and msg[0] == 0x01:  # MessageData
                            sub_id, _log_time = struct.unpack_from("<IQ", msg, 1)
                            assert sub_id == 7
                            st = fusion_pb2.FusionState.FromString(msg[13:])
                            if st.depth_mm >= 1000.0:
                                got.append(st)
            depths = [s.depth_mm for s in got]
            assert depths == sorted(depths) and all(
                d == 1000.0 + (s.header.stamp_ns - 10_000) for d, s in zip(depths, got, strict=True)
            )
        finally:
            running.stop()


def test_remote_bridge_needs_explicit_consent(bus_pair_configs):
    listen_cfg, _ = bus_pair_configs
    with Bus(listen_cfg, service="dashboard") as bus:
        cfg = DashboardConfig(bus=listen_cfg, port=0, foxglove_bridge=True, foxglove_port=0, foxglove_host="0.0.0.0")
        with pytest.raises(UserError, match="foxglove_allow_remote"):
            start(bus, cfg, Tokens())

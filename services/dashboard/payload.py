"""What goes to the page and to the JSON API: plain dicts and lists, no NaN (JSON has none).

Trail rows go as `[t_ms, *columns]` with `t_ms` relative to the feed's origin `t0_ns` (the
host clock, int64 ns), so that JSON numbers stay exact enough and small.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from google.protobuf import json_format
from google.protobuf.message import Message

from services.dashboard.feed import REF_COLUMNS, STATE_COLUMNS, VISION_COLUMNS, BusFeed
from services.dashboard.ring import Slice
from tiplog.clock import now_ns
from tiplog.v1 import system_pb2


def message_dict(msg: Message | None) -> dict[str, Any] | None:
    """A protobuf message as a JSON-ready dict (field names as in the .proto, enums by name)."""
    if msg is None:
        return None
    return _finite(
        json_format.MessageToDict(
            msg,
            always_print_fields_with_no_presence=True,
            preserving_proto_field_name=True,
            unquote_int64_if_possible=True,
        )
    )


def _finite(obj: Any) -> Any:
    """Replace NaN and infinities by None, recursively (protobuf JSON writes them as strings)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, str) and obj in ("NaN", "Infinity", "-Infinity"):
        return None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    return obj


def rows(s: Slice, t0_ns: int, decimals: int = 4) -> list[list[float | None]]:
    """[[t_ms, *row], ...] with NaN as None."""
    if s.end == s.start:
        return []
    t_ms = (s.stamps_ns - t0_ns) / 1e6
    table = np.round(np.column_stack([t_ms, s.rows]), decimals)
    out = table.tolist()
    if np.isnan(table).any():
        out = [[None if v != v else v for v in r] for r in out]
    return out


def columns() -> dict[str, list[str]]:
    return {
        "state": ["t_ms", *STATE_COLUMNS],
        "reference": ["t_ms", *REF_COLUMNS],
        "vision": ["t_ms", *VISION_COLUMNS],
    }


def _age_s(feed: BusFeed, topic: str, t: int) -> float | None:
    r = feed.latest_receive_ns.get(topic)
    return round((t - r) / 1e9, 3) if r else None


def tof(feed: BusFeed, t: int) -> dict[str, Any] | None:
    """The device's newest ToF sample: its raw and firmware-smoothed ranges (mm, along the
    sensor's ray, not the insertion depth), whether the smoothed one is valid, and its age."""
    msg = feed.latest.get("device/tof")
    if msg is None:
        return None
    return {
        "range_raw_mm": msg.range_raw_mm,
        "range_smoothed_mm": msg.range_smoothed_mm if msg.smoothed_valid else None,
        "smoothed_valid": msg.smoothed_valid,
        "age_s": _age_s(feed, "device/tof", t),
    }


def status(feed: BusFeed, t0_ns: int) -> dict[str, Any]:
    """Everything but the trails: health, streams, recorder, diagnostics, device, vision,
    error statistics, envelope."""
    t = now_ns()
    latest = feed.latest
    accepted = latest.get("vision/accepted")
    health = feed.health.snapshot()
    sup = latest.get("system/supervisor")
    if sup is not None:  # `tiplog up` runs the system: its view of each process joins the tokens'
        for run in sup.services:
            entry = health.setdefault(run.service, {"state": "down", "token": False})
            entry["run_state"] = system_pb2.ServiceRunState.Name(run.state).removeprefix("SERVICE_RUN_STATE_").lower()
            entry["restarts"] = run.restarts
            if run.last_error:
                entry["last_error"] = run.last_error
    return {
        "t_ms": round((t - t0_ns) / 1e6, 3),
        "health": health,
        "supervisor_event": sup.event if sup is not None else None,
        "streams": feed.streams.snapshot(),
        "recorder": message_dict(latest.get("recorder/status")),
        "recorder_age_s": _age_s(feed, "recorder/status", t),
        "diagnostics": message_dict(latest.get("fusion/diagnostics")),
        "device": message_dict(latest.get("device/status")),
        # what vision and the bench's renderer shed to keep real time (LoadStatus), with their age
        "load": {
            n: dict(message_dict(m), age_s=_age_s(feed, f"{n}/status", t))
            for n in ("vision", "bench")
            if (m := latest.get(f"{n}/status")) is not None
        },
        "tof": tof(feed, t),
        "robot": message_dict(latest.get("bench/robot")),
        "vision": {
            "last": message_dict(latest.get("vision/observation")),
            "last_accepted_age_s": _age_s(feed, "vision/accepted", t) if accepted is not None else None,
            "calibrated": feed.calibration is not None,
        },
        "preview_seq": feed.preview[0] if feed.preview else 0,
        "error": feed.error_rms_mm(),
        "envelope": feed.envelope.snapshot(),
        "websocket": {"clients": feed.ws_clients, "dropped_slow": feed.ws_dropped},
    }


def state_now(feed: BusFeed, t0_ns: int) -> dict[str, Any]:
    """The newest state as the page and `GET /api/state` show it."""
    msg = feed.latest.get("fusion/state")
    state = message_dict(msg)
    if state is not None:  # never filled by fusion (a 0.0 that read as a range): the device's is under "tof"
        state.pop("depth_smoothed_mm", None)
    last = feed.state.last()
    derived = None
    if last is not None:
        stamp, row = last
        derived = {k: (None if v != v else round(float(v), 4)) for k, v in zip(STATE_COLUMNS, row, strict=True)}
        derived["t_ms"] = round((stamp - t0_ns) / 1e6, 3)
    t = now_ns()
    return {
        "state": state,
        "derived": derived,
        "received": feed.state.total,
        "age_s": _age_s(feed, "fusion/state", t),
        "tof": tof(feed, t),
    }

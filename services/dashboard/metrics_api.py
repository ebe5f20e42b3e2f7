"""Skill-assessment metrics of the current recording, from the tip trail the dashboard holds.

`GET /api/metrics` (viewers): `tiplog metrics`' figures (docs/metrics.md) over the fusion states
since the running recording started (the recorder's `duration_s`), or over the whole trail when
nothing is recording (in either case from the last gap of over a second in the stream), and on the bench the robot reference's beside them. The trail holds the
display stream without sigmas, and only its last `trail_samples`: the figures carry no
interval; `tiplog metrics FILE` gives them with intervals and per segment once the file is
closed. `?download=1` serves the same JSON as a file.
"""

import json
import math
from collections.abc import Callable
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Response

from services.dashboard.auth import Role
from services.dashboard.feed import REF_COLUMNS, STATE_COLUMNS, BusFeed
from tiplog.clock import now_ns
from tiplog.v1 import recorder_pb2

_X = STATE_COLUMNS.index("x_mm")
_ROLL = STATE_COLUMNS.index("roll_deg")
_RX = REF_COLUMNS.index("x_mm")
MAX_GAP_NS = 1_000_000_000


def _rows(ring, since_ns: int) -> tuple[np.ndarray, np.ndarray]:
    s = ring.read(max(ring.total - len(ring), 0), len(ring))
    keep = s.stamps_ns >= since_ns
    t, rows = s.stamps_ns[keep], s.rows[keep]
    order = np.argsort(t, kind="stable")
    t, rows = t[order], rows[order]
    uniq = np.concatenate([[True], np.diff(t) > 0]) if len(t) else np.zeros(0, bool)
    t, rows = t[uniq], rows[uniq]
    gaps = np.flatnonzero(np.diff(t) > MAX_GAP_NS)  # a stream that stopped and started again:
    start = int(gaps[-1]) + 1 if len(gaps) else 0  # assess only what came since
    return t[start:], rows[start:]


def _clean(d: dict[str, float]) -> dict[str, float | None]:
    return {k: (v if math.isfinite(v) else None) for k, v in d.items()}


def current_metrics(feed: BusFeed) -> dict[str, Any]:
    """The metrics of the running recording's trail (see the module docstring)."""
    # Imported at the first request: the metrics' scipy is 1 s of the dashboard's 1.6 s import.
    from services.fusion.skill.assess import METRICS, MetricsParams, resample, segment_metrics

    params = MetricsParams(draws=0)  # the trail carries no sigmas: no intervals
    if feed.calibration is None:
        raise HTTPException(409, "no calibration: the dashboard needs the RCM (configure calibration_file)")
    status = feed.latest.get("recorder/status")
    recording = bool(
        status is not None and status.state == recorder_pb2.RECORDER_STATE_RECORDING and status.duration_s > 0
    )
    since = now_ns() - int(status.duration_s * 1e9) if recording else 0
    t, rows = _rows(feed.state, since)
    if len(t) < 2 or (t[-1] - t[0]) * 1e-9 < params.min_segment_s:
        raise HTTPException(409, f"under {params.min_segment_s:g} s of fusion states held: nothing to assess yet")
    rcm = feed.calibration.rcm_base_m
    est = resample(t, rows[:, _X : _X + 3] * 1e-3, np.unwrap(np.deg2rad(rows[:, _ROLL])), rcm, params.rate_hz)
    out: dict[str, Any] = {
        "recording": status.path if recording else None,
        "stream": "fusion/state",
        "start_s": (int(t[0]) - feed.t0_ns) * 1e-9,
        "end_s": (int(t[-1]) - feed.t0_ns) * 1e-9,
        "definitions": {k: {"unit": u, "what": w} for k, (u, w) in METRICS.items()},
        "metrics": _clean(segment_metrics(est, params)),
        "truth": None,
    }
    tr, ref = _rows(feed.reference, int(t[0]))
    if len(tr) > 1 and (tr[-1] - tr[0]) * 1e-9 >= params.min_segment_s:
        truth = resample(tr, ref[:, _RX : _RX + 3] * 1e-3, np.zeros(len(tr)), rcm, params.rate_hz, t0_ns=int(t[0]))
        out["truth"] = _clean(segment_metrics(truth, params))  # the reference carries no roll: ignore roll_path
        out["truth"]["roll_path_deg"] = None
    return out


def router(feed: BusFeed, require: Callable[[Role], Any]) -> APIRouter:
    """The /api/metrics route; `require(role)` is the authentication dependency."""
    api = APIRouter(tags=["metrics"])
    Viewer = Annotated[Role, Depends(require(Role.VIEWER))]

    @api.get("/api/metrics", responses={409: {"description": "no calibration, or too little trail yet"}})
    def metrics(_role: Viewer, download: bool = False) -> Response:
        """Skill-assessment metrics of the current recording's trail (no intervals: see docs/metrics.md)."""
        body = json.dumps(current_metrics(feed), indent=2)
        headers = {"Content-Disposition": 'attachment; filename="metrics.json"'} if download else {}
        return Response(body, media_type="application/json", headers=headers)

    return api

"""The estimate of a recording as arrays, cut into segments and sampled on a frame grid.

Every format reads the same `Frames`: one row per grid time `t0 + k / fps` of a segment, each
the fusion state nearest that time (never interpolated, so a row is a state exactly as fusion
published it; its own stamp is kept beside the grid time). A grid time with no state within
half a frame period is not valid: Slicer marks it INVALID, the CSV says so, LeRobot starts a new
episode after it (its frames must be evenly spaced).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tiplog.geometry import quat_to_rot, so3_log
from tiplog.mcap_io import read_messages, read_metadata, read_summary
from tiplog.userio import UserError

# Preferred first: the settled stream is what a live recording archives (every late vision
# frame applied); `tiplog fusion run` writes its states as fusion/state.
ESTIMATE_TOPICS = ("fusion/state_settled", "fusion/state")
SEGMENTS = ("whole", "events")


@dataclass(frozen=True)
class Track:
    """Fusion states in stamp order (host clock, base frame)."""

    topic: str
    source: Path
    t_ns: np.ndarray  # (n,) int64, the state's own stamp
    p_tip_base_m: np.ndarray  # (n, 3)
    q_base_tool_xyzw: np.ndarray  # (n, 4), R_base_tool
    u_base: np.ndarray  # (n, 3) shaft direction, distal
    v_tip_base_mps: np.ndarray  # (n, 3)
    w_base_radps: np.ndarray  # (n, 3) angular velocity of the tool, base frame (from the orientations)
    depth_mm: np.ndarray
    tilt_deg: np.ndarray
    roll_deg: np.ndarray
    tip_sigma_mm: np.ndarray  # (n, 3)
    vision_locked: np.ndarray  # (n,) bool

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def R_base_tool(self) -> np.ndarray:
        return quat_to_rot(self.q_base_tool_xyzw)


@dataclass(frozen=True)
class Frames:
    """One segment on its frame grid: `index[k]` is the track row of grid time `time_s[k]`."""

    segment: int
    time_s: np.ndarray  # (m,) seconds since the segment's first grid time, exactly k / fps
    index: np.ndarray  # (m,) rows of the track (valid rows only are meaningful)
    valid: np.ndarray  # (m,) bool: a state within half a frame period of the grid time


def estimate_topic_of(path: Path) -> str | None:
    summary = read_summary(path)
    have = {c.topic for c in summary.channels.values()} if summary is not None else set()
    return next((t for t in ESTIMATE_TOPICS if t in have), None)


def load_track(recording: Path, estimate: Path | None = None) -> Track:
    """The states of `estimate` (a `tiplog fusion run` file) or else of `recording`; UserError
    naming the file when it holds none."""
    source = estimate or recording
    topic = estimate_topic_of(source)
    if topic is None:
        hint = "" if estimate else f"; run `tiplog fusion run {recording} --out EST.mcap` and pass --estimate EST.mcap"
        raise UserError(f"{source}: no fusion state ({' or '.join(ESTIMATE_TOPICS)}){hint}")
    rows = []
    for rec in read_messages(source, [topic]):
        m = rec.message
        rows.append(
            (
                m.header.stamp_ns,
                (m.tip_m.x, m.tip_m.y, m.tip_m.z),
                (m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w),
                (m.shaft_direction.x, m.shaft_direction.y, m.shaft_direction.z),
                (m.tip_velocity_mps.x, m.tip_velocity_mps.y, m.tip_velocity_mps.z),
                m.depth_mm, m.tilt_deg, m.roll_deg,
                (m.tip_sigma_mm.x, m.tip_sigma_mm.y, m.tip_sigma_mm.z),
                m.vision_locked,
            )
        )  # fmt: skip
    if len(rows) < 2:
        raise UserError(f"{source}: {len(rows)} fusion state(s) on {topic}; at least 2 are needed")
    rows.sort(key=lambda r: r[0])
    cols = list(zip(*rows, strict=True))
    t = np.asarray(cols[0], np.int64)
    keep = np.concatenate([[True], np.diff(t) > 0])  # one state per stamp
    arr = [np.asarray(c)[keep] for c in cols]
    q = arr[2] / np.linalg.norm(arr[2], axis=1, keepdims=True)
    return Track(
        topic, source, arr[0], arr[1].astype(float), q, arr[3].astype(float), arr[4].astype(float),
        angular_velocity(arr[0], quat_to_rot(q)), arr[5].astype(float), arr[6].astype(float),
        arr[7].astype(float), arr[8].astype(float), arr[9].astype(bool),
    )  # fmt: skip


def angular_velocity(t_ns: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(n, 3) [rad/s] in the base frame: central differences log(R_{k+1} R_{k-1}^T) / dt
    (one-sided at the ends)."""
    n = len(t_ns)
    lo = np.clip(np.arange(n) - 1, 0, n - 1)
    hi = np.clip(np.arange(n) + 1, 0, n - 1)
    dR = R[hi] @ np.swapaxes(R[lo], 1, 2)
    dt = (t_ns[hi] - t_ns[lo]) * 1e-9
    return so3_log(dR) / dt[:, None]


def event_stamps(recording: Path) -> list[int]:
    """The recorder's event marks (`tiplog record mark`), host-clock ns in order."""
    md = read_metadata(recording)
    out = []
    for name, rec in md.items():
        if name.startswith("event_") and "log_time_ns" in rec:
            out.append(int(rec["log_time_ns"]))
    return sorted(out)


def segment_bounds(track: Track, recording: Path, segments: str) -> list[tuple[int, int]]:
    """[(first_ns, end_ns)] of each segment: the whole track, or cut at the recorder's events."""
    first, last = int(track.t_ns[0]), int(track.t_ns[-1]) + 1
    if segments == "whole":
        return [(first, last)]
    cuts = [t for t in event_stamps(recording) if first < t < last]
    if not event_stamps(recording):
        raise UserError(f"{recording}: --segments events: the recording has no event marks (`tiplog record mark`)")
    edges = [first, *cuts, last]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def frames(track: Track, bounds: list[tuple[int, int]], fps: float) -> list[Frames]:
    """Each segment on its grid (`fps` <= 0: every state, its own time)."""
    out = []
    for seg, (a, b) in enumerate(bounds):
        rows = np.flatnonzero((track.t_ns >= a) & (track.t_ns < b))
        if len(rows) < 2:
            continue
        t_seg = track.t_ns[rows]
        if fps <= 0:
            out.append(Frames(seg, (t_seg - t_seg[0]) * 1e-9, rows, np.ones(len(rows), bool)))
            continue
        period_ns = 1e9 / fps
        m = int(np.floor((t_seg[-1] - t_seg[0]) / period_ns)) + 1
        grid = t_seg[0] + np.round(np.arange(m) * period_ns).astype(np.int64)
        j = np.clip(np.searchsorted(t_seg, grid), 1, len(t_seg) - 1)
        nearer = np.where(np.abs(t_seg[j - 1] - grid) <= np.abs(t_seg[j] - grid), j - 1, j)
        valid = np.abs(t_seg[nearer] - grid) <= period_ns / 2
        out.append(Frames(seg, np.arange(m) / fps, rows[nearer], valid))
    return out


def provenance(track: Track, recording: Path) -> dict[str, str]:
    """What every export records of where its rows came from."""
    return {
        "recording": recording.name,
        "estimate_file": track.source.name,
        "estimate_topic": track.topic,
        "first_stamp_ns": str(int(track.t_ns[0])),
        "states": str(len(track)),
    }

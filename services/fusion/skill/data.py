"""What `tiplog metrics` reads from a recording and its estimate: the estimated trajectory with its
sigmas, the segments (event marks, bench trials or the whole), and on the bench the robot's
reference beside it (evaluation only: never part of an estimate).

The estimate is, in a live recording, its settled stream `fusion/state_settled`; in a `tiplog
fusion run` file, `fusion/state_smoothed` where the run had `--smooth`, else `fusion/state`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from services.fusion.offline.inputs import source_fingerprint
from services.fusion.skill.assess import Motion, resample
from services.fusion.skill.kinematics import roll_angle
from tiplog.calibration import Calibration, CalibrationError
from tiplog.mcap_io import read_messages, read_metadata, read_summary
from tiplog.userio import UserError

SETTLED, SMOOTHED, STATE = "fusion/state_settled", "fusion/state_smoothed", "fusion/state"
CONTINUOUS_KINDS = ("sweep", "teleop", "demo")


@dataclass
class Segment:
    name: str
    t0_ns: int
    t1_ns: int


@dataclass
class Inputs:
    recording: Path
    estimate_file: Path
    topic: str
    estimate: Motion
    truth: Motion | None
    segments: list[Segment] = field(default_factory=list)
    t0_ns: int = 0  # the grid's origin (stamp of t_s = 0)


def _topics(path: Path) -> set[str]:
    s = read_summary(path)
    return {c.topic for c in s.channels.values()} if s is not None else set()


def _metadata(path: Path) -> dict[str, dict[str, str]]:
    try:
        return read_metadata(path)
    except Exception as e:  # noqa: BLE001 - any reader failure is a bad file for the user
        raise UserError(f"{path}: cannot read the MCAP metadata ({type(e).__name__})") from None


def estimate_source(recording: Path, estimate: Path | None) -> tuple[Path, str]:
    """(file, topic) of the estimate; UserError when there is none or it is of another recording."""
    if estimate is None:
        have = _topics(recording)
        for topic in (SETTLED, SMOOTHED, STATE):
            if topic in have:
                return recording, topic
        raise UserError(
            f"{recording}: no fusion state (fusion/state_settled or fusion/state): estimate it first with "
            f"`tiplog fusion run {recording} --smooth --out EST.mcap` and give --estimate EST.mcap"
        )
    have = _topics(estimate)
    topic = SMOOTHED if SMOOTHED in have else STATE if STATE in have else ""
    if not topic:
        raise UserError(f"{estimate}: no fusion/state or fusion/state_smoothed (not a `tiplog fusion run` output)")
    made = _metadata(estimate).get("fusion", {})
    want = made.get("source_fingerprint")
    if want:
        if want != source_fingerprint(recording):
            raise UserError(
                f"{estimate}: an estimate of another recording ({made.get('source', '?')}), not of {recording.name}"
            )
    elif made.get("source") and made["source"] != recording.name:
        raise UserError(f"{estimate}: an estimate of {made['source']}, not of {recording.name}")
    return estimate, topic


def _rcm(estimate: Path, recording: Path) -> np.ndarray:
    """The registered RCM the estimate used: its run's calibration, else the recording's."""
    md = _metadata(estimate)
    try:
        if "fusion_calibration" in md:
            return Calibration.from_dict(json.loads(md["fusion_calibration"]["json"])).rcm_base_m
        return Calibration.from_mcap_metadata(_metadata(recording), where=str(recording)).rcm_base_m
    except (CalibrationError, ValueError, KeyError) as e:
        raise UserError(f"{estimate}: no usable calibration to take the RCM from ({e})") from None


def _states(path: Path, topic: str) -> dict[str, np.ndarray]:
    t, tip, sig, q, att = [], [], [], [], []
    for rec in read_messages(path, [topic]):
        m = rec.message
        t.append(m.header.stamp_ns)
        tip.append((m.tip_m.x, m.tip_m.y, m.tip_m.z))
        sig.append((m.tip_sigma_mm.x, m.tip_sigma_mm.y, m.tip_sigma_mm.z))
        q.append((m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w))
        att.append(m.attitude_sigma_deg)
    if len(t) < 2:
        raise UserError(f"{path}: fewer than two states on {topic}")
    order = np.argsort(np.asarray(t), kind="stable")
    t_ns = np.asarray(t, np.int64)[order]
    keep = np.concatenate([[True], np.diff(t_ns) > 0])  # a repeated stamp adds nothing to a path
    pick = order[keep]
    return {
        "t_ns": t_ns[keep],
        "tip_m": np.asarray(tip)[pick],
        "sigma_m": np.asarray(sig)[pick] * 1e-3,
        "q": np.asarray(q)[pick],
        "att_rad": np.deg2rad(np.asarray(att)[pick]),
    }


def _truth(recording: Path) -> dict[str, np.ndarray] | None:
    if "bench/robot" not in _topics(recording):
        return None
    t, tip, q, rcm = [], [], [], None
    for rec in read_messages(recording, ["bench/robot"]):
        m = rec.message
        t.append(m.header.stamp_ns)
        tip.append((m.tip_m.x, m.tip_m.y, m.tip_m.z))
        o = m.tool_pose.orientation
        q.append((o.x, o.y, o.z, o.w))
        rcm = (m.rcm_m.x, m.rcm_m.y, m.rcm_m.z)
    if len(t) < 2:
        return None
    return {"t_ns": np.asarray(t, np.int64), "tip_m": np.asarray(tip), "q": np.asarray(q), "rcm": np.asarray(rcm)}


def event_marks(md: dict[str, dict[str, str]]) -> list[tuple[int, str]]:
    """(log_time_ns, label) of the recording's event marks (`event_NNNN` metadata), in time order."""
    out = []
    for name, rec in md.items():
        if name.startswith("event_") and "log_time_ns" in rec:
            try:
                out.append((int(rec["log_time_ns"]), str(rec.get("label", name))))
            except ValueError:
                continue
    return sorted(out)


def segments_of(mode: str, md: dict[str, dict[str, str]], t0_ns: int, t1_ns: int) -> list[Segment]:
    """The segments to assess in [t0_ns, t1_ns]: `events` between consecutive event marks (from the
    start to the first mark, named `start`, then each from its mark, named by its label; the whole
    recording without marks), `trials` each continuous bench trial's move window, `none` the whole."""
    if mode == "none":
        return [Segment("all", t0_ns, t1_ns)]
    if mode == "trials":
        trials = json.loads(md.get("trials", {}).get("json", "[]") or "[]")
        segs = [
            Segment(str(tr["kind"]), int(tr["move_start"]) * 1_000_000, int(tr["move_end"]) * 1_000_000)
            for tr in trials
            if isinstance(tr, dict) and str(tr.get("kind", "")).startswith(CONTINUOUS_KINDS)
        ]
        if not segs:
            raise UserError("--segments trials: the recording has no continuous bench trials (sweeps, teleop, demo)")
        return segs
    marks = [(t, label) for t, label in event_marks(md) if t0_ns < t < t1_ns]
    if not marks:
        return [Segment("all", t0_ns, t1_ns)]
    edges = [t0_ns] + [t for t, _ in marks] + [t1_ns]
    names = ["start"] + [label for _, label in marks]
    return [Segment(names[i], edges[i], edges[i + 1]) for i in range(len(names))]


def load(recording: Path, estimate: Path | None, segments: str, rate_hz: float) -> Inputs:
    """Everything one `tiplog metrics` run needs, on one grid; UserError names what is missing."""
    est_file, topic = estimate_source(recording, estimate)
    rcm = _rcm(est_file, recording)
    s = _states(est_file, topic)
    t0 = int(s["t_ns"][0])
    est = resample(
        s["t_ns"], s["tip_m"], roll_angle(s["q"]), rcm, rate_hz,
        tip_sigma_m=s["sigma_m"], roll_sigma_rad=s["att_rad"], t0_ns=t0,
    )  # fmt: skip
    tr = _truth(recording)
    truth = None
    if tr is not None:
        truth = resample(tr["t_ns"], tr["tip_m"], roll_angle(tr["q"]), tr["rcm"], rate_hz, t0_ns=t0)
    segs = segments_of(segments, _metadata(recording), t0, int(s["t_ns"][-1]))
    return Inputs(recording, est_file, topic, est, truth, segs, t0)


def describe(inputs: Inputs) -> dict[str, Any]:
    """The JSON's `source` block: which files and stream the figures are of."""
    return {
        "recording": inputs.recording.name,
        "estimate_file": inputs.estimate_file.name,
        "estimate_topic": inputs.topic,
        "truth": "bench/robot" if inputs.truth is not None else None,
    }

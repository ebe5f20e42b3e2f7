"""The paper's latency table from a latency-protocol recording (sinusoids in insertion depth,
shaft tilt and roll at several frequencies, each a trial of kind "latency" with freq_hz).

Per trial and stream, the measured signal and the same quantity predicted from the robot
reference through the calibration (`cal`) are reduced to one scalar each: the projection on
the direction along which the prediction varies most during the trial. Streams: gyro (body
rate), accel (specific force, lever arm included), tof and tof_smoothed (range through the
ray-plane model), camera (the junction's ray, for depth and tilt: a pixel position is well
conditioned where the closest axis point P0 is not; roll is invisible to the silhouette). Robot stamps are event times; sensor stamps are arrivals.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from tiplog.calibration import Calibration
from tiplog.calibration.block import robot_body_rate
from tiplog.calibration.data import CalibrationData
from tiplog.calibration.fits import DegenerateDataError, require
from tiplog.calibration.fits.latency import fit_transfer, lockin_se
from tiplog.calibration.fits.tof import TofModel
from tiplog.geometry import vision as vg

G_BASE = np.array([0.0, 0.0, -9.80665])
STREAMS = ("tof", "tof_smoothed", "gyro", "accel", "camera")
CHANNEL_STREAMS = {
    "depth": ("tof", "tof_smoothed", "camera"),
    "tilt": ("gyro", "accel", "camera"),  # ToF under tilt is dominated by its pose-locked error
    "roll": ("gyro", "accel"),
}
# a segment counts for a stream only if the robot-predicted signal moves at least this much
MIN_AMPLITUDE = {"tof": 1.0, "tof_smoothed": 1.0, "gyro": 0.01, "accel": 0.05, "camera": 0.002}


def _principal(ref: np.ndarray) -> np.ndarray:
    d = ref - ref.mean(0)
    return np.linalg.svd(d, full_matrices=False)[2][0]


def _segments(data: CalibrationData) -> list[tuple[str, float, int, int]]:
    """(axis, freq_hz, t0_ns, t1_ns) of each latency trial's oscillation, from the robot's
    trial/phase labels."""
    out = []
    for tr in data.trials:
        if tr.get("kind") != "latency" or "freq_hz" not in tr:
            continue
        sel = (data.robot_trial == int(tr["index"])) & (data.robot_phase == "move")
        if np.sum(sel) < 10:
            continue
        t = data.robot_t_ns[sel]
        out.append((str(tr["axis"]), float(tr["freq_hz"]), int(t[0]), int(t[-1])))
    return out


class _Predictor:
    """Robot-predicted signals at robot sample times for each stream."""

    def __init__(self, data: CalibrationData, cal: Calibration):
        self.d, self.cal = data, cal
        t, R, p = data.robot_t_ns, data.R_base_tool, data.p_tip_base_m
        self.tm, w = robot_body_rate(t, R)
        self.w_tool = w
        p_imu = p + np.einsum("nij,j->ni", R, cal.p_imu_tool_m)
        ts = t * 1e-9
        acc = np.gradient(np.gradient(p_imu, ts, axis=0), ts, axis=0)
        R_imu = R @ cal.R_tool_imu
        self.f_imu = np.einsum("nji,nj->ni", R_imu, acc - G_BASE)
        tof = TofModel(cal.tof_origin_tool_m, cal.tof_beam_tool, cal.tof_plane_normal_base, cal.tof_plane_h_m)
        self.rho_mm = tof.range_m(R, p) * 1e3
        A, c = cal.R_base_camera, cal.p_base_camera_m
        u = R[:, :, 2]
        self.u_cam = u @ A
        self.junction_cam = (p - cal.junction_proximal_m * u - c) @ A
        self.p0_cam = vg.closest_axis_point(self.junction_cam, self.u_cam)

    def pair(self, stream: str, axis: str, t0: int, t1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(t_ref, ref (n, k), t_meas, meas (m, k)) for one stream over [t0, t1]."""
        d, cal = self.d, self.cal
        if stream == "gyro":
            return self.tm, self.w_tool, d.gyro_t_ns, d.gyro_radps @ cal.R_tool_imu.T
        if stream == "accel":
            return d.robot_t_ns, self.f_imu, d.accel_t_ns, d.accel_mps2
        if stream == "tof":
            m = np.where(d.tof_valid, d.tof_raw_mm, np.nan)
            return d.robot_t_ns, self.rho_mm[:, None], d.tof_t_ns, m[:, None]
        if stream == "tof_smoothed":
            m = np.where(d.tof_smoothed_valid, d.tof_smoothed_mm, np.nan)
            return d.robot_t_ns, self.rho_mm[:, None], d.tof_t_ns, m[:, None]
        v = d.vision
        sel = (v["capture_ns"] >= t0) & (v["capture_ns"] < t1) & v["accepted"]
        sel &= v["junction_visible"]  # the junction's ray: a pixel, well conditioned
        return d.robot_t_ns, _unit(self.junction_cam), v["capture_ns"][sel], _unit(v["junction_ray"][sel])


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def latency_table(data: CalibrationData, cal: Calibration) -> dict[str, Any]:
    """{stream: {channel: {delay_ms, gain, dead_time_ms, time_constant_ms, ...}}, plus each
    stream's latency_ms (inverse-variance mean over its channels) and latency_se_ms}."""
    require(data.has_robot, "latency", f"{data.source}: no robot reference (topic bench/robot)")
    segs = _segments(data)
    require(len(segs) > 0, "latency", f"{data.source}: no latency trials (record the latency protocol)")
    pred = _Predictor(data, cal)
    table: dict[str, Any] = {}
    for axis in sorted({s[0] for s in segs}):
        for stream in CHANNEL_STREAMS.get(axis, ()):
            freqs, gains, ses = [], [], []
            for ax, f, t0, t1 in segs:
                if ax != axis:
                    continue
                tr, ref, tm, meas = pred.pair(stream, axis, t0, t1)
                rs = (tr >= t0) & (tr < t1)
                if np.sum(rs) < 10 or len(tm) < 8:
                    continue
                e = _principal(ref[rs])
                try:
                    zr, sr = lockin_se(tr, ref @ e, f, t0, t1)
                    zm, sm = lockin_se(tm, meas @ e, f, t0, t1)
                except DegenerateDataError:
                    continue
                if abs(zr) < MIN_AMPLITUDE[stream]:
                    continue
                freqs.append(f)
                gains.append(zm / zr)
                ses.append(float(np.hypot(sm / max(abs(zm), 1e-12), sr / abs(zr))))
            try:
                fit = fit_transfer(np.array(freqs), np.array(gains), f"{stream}, {axis}", np.array(ses))
            except DegenerateDataError:
                continue
            table.setdefault(stream, {})[axis] = {
                "delay_ms": float(round(fit.group_delay_ms, 2)),
                "delay_se_ms": float(round(fit.delay_se_ms, 2)),
                "gain": float(round(fit.gain, 3)),
                "dead_time_ms": float(round(fit.dead_time_ms, 2)),
                "time_constant_ms": float(round(fit.time_constant_ms, 2)),
                "fit_residual": float(round(fit.residual, 4)),
                "segments": len(freqs),
            }
    require(len(table) > 0, "latency", "no stream could be fitted (need 3+ frequencies per channel)")
    for rows in table.values():  # inverse-variance weighted over the channels
        d = np.array([r["delay_ms"] for r in rows.values()])
        w = 1.0 / np.array([max(r["delay_se_ms"], 0.05) for r in rows.values()]) ** 2
        rows["latency_ms"] = round(float(np.sum(w * d) / np.sum(w)), 2)
        rows["latency_se_ms"] = round(float(1.0 / np.sqrt(np.sum(w))), 2)
    return table


def apply(cal: Calibration, table: dict[str, Any]) -> Calibration:
    """`cal` with latency_ms replaced by the table's per-stream latencies (others kept)."""
    lat = dict(cal.latency_ms)
    for stream, rows in table.items():
        lat[stream] = max(0.0, float(rows["latency_ms"]))
    return dataclasses.replace(cal, latency_ms=lat)


def markdown(table: dict[str, Any]) -> str:
    """The paper's latency table: channels as rows, streams as columns, 'delay ms (gain)'."""
    cols = [s for s in STREAMS if s in table]
    lines = ["| Channel | " + " | ".join(cols) + " |", "| --- |" + " --- |" * len(cols)]
    for ch in ("depth", "tilt", "roll"):
        cells = []
        for s in cols:
            r = table[s].get(ch)
            cells.append(f"{r['delay_ms']:.1f} ({r['gain']:.2f})" if isinstance(r, dict) else "-")
        lines.append(f"| {ch} | " + " | ".join(cells) + " |")
    lines.append("| latency_ms | " + " | ".join(f"{table[s]['latency_ms']:.1f}" for s in cols) + " |")
    return "\n".join(lines)

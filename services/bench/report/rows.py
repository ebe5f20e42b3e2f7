"""The report's row type and what the statistic and motion rows share: a graded row, and the
true tip speed that tells frames at rest from frames in motion."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.bench.report.data import Session

REST_MMPS = 2.0  # tip speed under which a frame counts as at rest


@dataclass
class Row:
    name: str
    unit: str
    paper: str
    lo: float
    hi: float
    value: float | None
    status: str
    note: str = ""


def _row(name: str, unit: str, paper: str, lo: float, hi: float, value: float | None, note: str = "") -> Row:
    if value is None or not np.isfinite(value):
        return Row(name, unit, paper, lo, hi, None, "n/a", note)
    return Row(name, unit, paper, lo, hi, float(value), "PASS" if lo <= value <= hi else "FAIL", note)


def tip_speed_mmps(s: Session, t_ns: np.ndarray) -> np.ndarray:
    """True tip speed [mm/s] at times t_ns, from the recorded ground truth."""
    if len(s.robot_t) < 2:
        return np.zeros(len(t_ns))
    dt = np.diff(s.robot_t).mean() * 1e-9
    v_tip = np.linalg.norm(np.gradient(s.robot_p, dt, axis=0), axis=1) * 1e3
    return np.interp(t_ns, s.robot_t, v_tip)

"""Warm-up: the filter run once over a short synthetic session before the live service
subscribes, so that numba's compiled kernels are loaded (or, on a machine that has no cache yet,
compiled) before the first real sample arrives.

Without it the first gyro sample and the first vision frame pay that cost inside the worker:
0.75 s idle on a 2-core development machine with the cache present, over 30 s with none. The
inputs queue meanwhile, so the live display starts seconds behind real time and then publishes
that backlog at once. A process-wide cost: the compiled code stays loaded for every later
runner in the process.

The session is a tool held still under the calibration's trocar at the working depth
(`start_depth_mm`), the shaft pointing along the camera's optical axis where it can: gyro and
accelerometer at their rates, ToF ranges through the calibration's ray-plane model, and
vision frames that agree with the pose, each arriving after later gyro samples (so the rewind
path runs too) and every third with the junction hidden. It is built from the calibration
alone and never touches the bus.

`python -m services.fusion.live.warmup [CALIBRATION.yaml]` fills the cache ahead of time (`make
install`, and so `make demo` and `make test`, and the container image do so); without a file it
uses the bench's nominal calibration: compiled code depends on types, not on the geometry. numba
keys each kernel module's cache on that module's own file, and `eskf/jit_cache.py` drops every
module's cache when any file of eskf/kernels/, eskf/models/ or eskf/layout.py changes, so a fresh
clone or an edit of one of those files starts cold again: `kernel_cache` tells, so that the
service can say why its first start waits.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from services.fusion.eskf.init import initial_rotation
from services.fusion.eskf.measurement import VisionObservation
from services.fusion.eskf.params import SENSORS, Params
from services.fusion.timing.runner import FusionRunner
from tiplog.calibration import Calibration, CalibrationError
from tiplog.v1 import device_pb2, vision_pb2

G = 9.80665
DURATION_S = 1.0
RATES_HZ = {"device/gyro": 200.0, "device/accel": 240.0, "device/tof": 100.0, "vision/observation": 15.0}
VISION_DELAY_NS = 80_000_000  # capture to arrival: later than the display's output delay (a rewind)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def tangent_normals(axis_point_cam: np.ndarray, u_cam: np.ndarray, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals n of the two planes through the camera centre tangent to the shaft (a
    cylinder of `radius_m` about the line through `axis_point_cam` along unit `u_cam`), with
    n.x = radius_m for every point x on the axis (the vision service's convention)."""
    w = axis_point_cam - (axis_point_cam @ u_cam) * u_cam  # the axis' closest point to the centre
    dist = float(np.linalg.norm(w))
    if dist <= radius_m:
        raise ValueError("the camera centre is inside the shaft")
    w_hat = w / dist
    v_hat = np.cross(u_cam, w_hat)
    a = radius_m / dist
    b = np.sqrt(1.0 - a * a)
    return a * w_hat + b * v_hat, a * w_hat - b * v_hat


def _candidates(calib: Calibration) -> list[np.ndarray]:
    """Shaft directions to try, best first: towards points on the camera's optical axis (the
    field it views), then along the ToF target plane's inward normal and straight down."""
    c_cam, z_cam = calib.p_base_camera_m, calib.R_base_camera[:, 2]
    dist = float(np.linalg.norm(calib.rcm_base_m - c_cam))
    out = []
    for k in (1.0, 0.75, 1.25, 0.5, 1.5):
        d = c_cam + k * dist * z_cam - calib.rcm_base_m
        if np.linalg.norm(d) > 1e-3:
            out.append(_unit(d))
    out += [-calib.tof_plane_normal_base, np.array([0.0, 0.0, -1.0])]
    return out


def _pose(calib: Calibration, params: Params) -> tuple[np.ndarray, float, dict[str, Any]]:
    """(R_base_tool, depth [m], vision frame of it) of the first candidate pose whose frame the
    filter would start from (in front of the camera, junction ray well conditioned)."""
    runner = FusionRunner(calib, params, SENSORS)  # only for its filter's geometry
    f = runner.filt
    depth = params.start_depth_mm * 1e-3
    for u in _candidates(calib):
        R = initial_rotation(u, None, calib.R_tool_imu)
        tip = calib.rcm_base_m + depth * u
        junction_cam = f.A @ (tip - f.jp * u - f.c_cam)
        u_cam = f.A @ u
        if junction_cam[2] <= 0.0:
            continue  # behind the camera
        try:
            n_l, n_r = tangent_normals(f.rcm_cam, u_cam, calib.shaft_radius_m)
        except ValueError:
            continue
        obs = VisionObservation(n_l, n_r, True, _unit(junction_cam))
        s = f.init_from_vision(0, obs, None)
        if s is not None and abs(s.p - tip).max() < 1e-3:
            return R, depth, obs
    raise ValueError("no pose of the shaft that this calibration's camera can see")


def _tof_range_m(calib: Calibration, R: np.ndarray, tip: np.ndarray) -> float:
    """The raw range of the ray-plane model, rho = (h - m.(p + R o)) / (m.(R b)), no offset."""
    m = calib.tof_plane_normal_base
    return float((calib.tof_plane_h_m - m @ (tip + R @ calib.tof_origin_tool_m)) / (m @ (R @ calib.tof_beam_tool)))


def synthetic_inputs(
    calib: Calibration, params: Params | None = None, duration_s: float = DURATION_S
) -> list[tuple[str, Any, int]]:
    """(topic, message, arrival [ns]) of a still tool under the trocar, in arrival order; every
    stamp is its stream's capture time plus its calibrated latency, on a clock starting at 1 s."""
    params = params or Params()
    R, depth, obs = _pose(calib, params)
    tip = calib.rcm_base_m + depth * R[:, 2]
    f_imu = calib.R_tool_imu.T @ R.T @ np.array([0.0, 0.0, G])  # at rest: minus gravity
    rng_mm = 1e3 * _tof_range_m(calib, R, tip)
    t0 = 1_000_000_000
    lat = {"device/gyro": "gyro", "device/accel": "accel", "device/tof": "tof", "vision/observation": "camera"}
    out: list[tuple[str, Any, int]] = []
    for topic, hz in RATES_HZ.items():
        for k in range(int(duration_s * hz)):
            t = t0 + int(k * 1e9 / hz)
            stamp = t + calib.latency_ns(lat[topic])
            if topic == "device/gyro":
                m = device_pb2.Gyro()
                m.rate_radps.x, m.rate_radps.y, m.rate_radps.z = 1e-4 * np.sin(k), 0.0, 0.0
            elif topic == "device/accel":
                m = device_pb2.Accel()
                m.specific_force_mps2.x, m.specific_force_mps2.y, m.specific_force_mps2.z = f_imu.tolist()
            elif topic == "device/tof":
                m = device_pb2.Tof()
                m.range_raw_mm = rng_mm
                m.status = 1
            else:
                m = vision_pb2.VisionObservation()
                m.accepted = True
                m.junction_visible = k % 3 != 2
                for name, key in (("n_left", "n_left"), ("n_right", "n_right"), ("junction_ray", "ray")):
                    v = getattr(m, name)
                    v.x, v.y, v.z = getattr(obs, key).tolist()
            m.header.stamp_ns = stamp
            m.header.seq = k
            arrival = stamp + (VISION_DELAY_NS if topic == "vision/observation" else 0)
            out.append((topic, m, arrival))
    out.sort(key=lambda e: e[2])
    return out


def kernel_cache() -> tuple[bool | None, str]:
    """(whether numba's cache holds compiled code of this version of the filter's kernels, the
    cache folder); (None, "") when numba is absent or its cache cannot be read. Judged by
    `gyro_step`, which every live sample goes through: the warm-up compiles it with the rest,
    and an edit of any file the kernels compile in drops every module's cache at once
    (`eskf/jit_cache.py`)."""
    try:
        from services.fusion.eskf.kernels.steps import gyro_step

        cache = gyro_step._cache
        # numba's index is empty when missing or written for another version of the source
        return bool(cache._cache_file._load_index()), str(cache._cache_path)
    except Exception:  # numba absent, or its private cache layout changed: nothing to say
        return None, ""


def cold_start_line() -> str | None:
    """The line to show before a warm-up that will compile (None when the cache is warm or
    cannot be read)."""
    cached, where = kernel_cache()
    if cached is not False:
        return None
    return (
        f"compiling the filter's kernels: none cached in {where} for this version (first start after an "
        "install or an update); 40-90 s on two busy cores, once, and no estimate until then "
        "(`python -m services.fusion.live.warmup` does it ahead, as `make install` does)"
    )


def warm_up(calib: Calibration, params: Params | None = None, sensors: frozenset[str] = SENSORS) -> dict:
    """Run a throwaway runner (both outputs, as live) over `synthetic_inputs`; returns its
    diagnostics with `warm_up_s`, the time it took."""
    start = time.perf_counter()
    runner = FusionRunner(calib, params, sensors, output="both")
    for topic, msg, arrival in synthetic_inputs(calib, params):
        runner.feed(topic, msg, arrival)
        runner.advance(arrival)
        runner.take_settled()
        runner.predict(arrival)
    runner.finish()
    runner.take_settled()
    diag = runner.diagnostics()
    diag["warm_up_s"] = time.perf_counter() - start
    return diag


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m services.fusion.live.warmup", description=__doc__.split("\n\n")[0])
    ap.add_argument("calibration", nargs="?", help="calibration file (default: the bench's nominal calibration)")
    ap.add_argument(
        "--only",
        choices=("fusion", "attitude"),
        help="only the tracking filter's kernels (the live service and the offline run with its smoother) "
        "or only `tiplog fusion attitude`'s; default both (two processes can fill the cache side by side)",
    )
    args = ap.parse_args(argv)
    if args.only != "attitude":
        try:
            if args.calibration:
                calib = Calibration.load_yaml(args.calibration)
            else:
                from services.bench.scenario import load_scenario
                from services.bench.simulation import as_calibrated_constants

                calib = Calibration.from_dict(as_calibrated_constants(load_scenario("teleop"), 0).to_dict(), "bench")
            line = cold_start_line()
            if line:
                print(line, flush=True)
            diag = warm_up(calib)
            smoother_s = warm_up_smoother(calib)
        except (CalibrationError, ValueError) as e:
            print(f"warmup: {e}", file=sys.stderr)
            return 2
        print(
            f"fusion kernels {'compiled' if line else 'ready'} in {diag['warm_up_s']:.1f} s, the smoother's in {smoother_s:.1f} s"
        )
    if args.only != "fusion":
        print(f"attitude kernels ready in {warm_up_attitude():.1f} s")
    return 0


def warm_up_smoother(calib: Calibration) -> float:
    """The offline run's smoother (`tiplog fusion run --smooth`) over `synthetic_inputs`: its
    transition kernel is the only one the live filter does not use; seconds taken."""
    from services.fusion.offline.smoother import smooth

    t0 = time.perf_counter()
    smooth(calib, Params(), synthetic_inputs(calib))
    return time.perf_counter() - t0


def warm_up_attitude() -> float:
    """`tiplog fusion attitude`'s compiled kernels (the online filter's and the offline smoother's)
    into numba's cache too (they are not the live service's, but cold ones compile for tens of
    seconds inside a user's first run); seconds taken."""
    from services.fusion.attitude.filter import estimate
    from services.fusion.attitude.offline import smooth

    t0 = time.perf_counter()
    t = np.arange(200) / 200.0
    gyr, acc = np.zeros((200, 3)), np.tile([0.0, 0.0, G], (200, 1))
    estimate(t, gyr, acc)
    smooth(t, gyr, acc)
    return time.perf_counter() - t0


if __name__ == "__main__":
    sys.exit(main())

"""The tracking filter's maths on synthetic data (no bench): propagation across a stalled host,
the compiled steps against the same maths apart, gyro bias and tip estimated at rest from
gravity, RCM and vision, the innovation gate, and the ToF offset held while vision is absent.
The kernels and measurement models alone: tests/services/fusion/eskf/kernels/, models/."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from services.fusion.eskf.filter import N, TrackingFilter
from services.fusion.eskf.init import E_Z
from services.fusion.eskf.kernels.propagate import propagate, propagate_held
from services.fusion.eskf.kernels.rest import rest_init, rest_sample
from services.fusion.eskf.layout import REST_RATE
from services.fusion.eskf.measurement import VisionObservation
from services.fusion.eskf.models.gravity import gravity_jacobian
from services.fusion.eskf.models.rcm import port_lever, rcm_jacobian
from services.fusion.eskf.models.tof import tof_jacobian
from services.fusion.eskf.params import Params
from tiplog.calibration import Calibration
from tiplog.geometry import rot_between, so3_exp
from tiplog.geometry import vision as vg

G = np.array([0.0, 0.0, -9.80665])
RCM = np.array([0.65, 0.0, 0.30])


def _calib() -> Calibration:
    _, tip = _pose()
    cam = tip + np.array([0.0, 0.06, 0.06])  # beside and above the tip, about 85 mm away
    z = (tip - cam) / np.linalg.norm(tip - cam)
    x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    T[:3, 3] = cam
    beam = np.array([0.0, math.sin(math.radians(55.8)), math.cos(math.radians(55.8))])
    m = np.array([0.2, -0.1, -0.97])
    m /= np.linalg.norm(m)
    return Calibration(
        rcm_base_m=RCM, T_base_camera=T, intrinsics={"fx": 650.0, "fy": 650.0, "cx": 640.0, "cy": 360.0},
        shaft_radius_m=0.00259, junction_proximal_m=0.004, R_tool_imu=so3_exp(np.array([0.0, 0.0, 1.57])),
        p_imu_tool_m=np.array([0.018, 0.0, -0.304]), tof_origin_tool_m=np.array([0.0, 0.015, -0.284]),
        tof_beam_tool=beam, tof_plane_normal_base=m, tof_plane_h_m=float(m @ (RCM + 0.02 * m)),
    )  # fmt: skip


def _pose():
    u = np.array([math.sin(math.radians(28.6)), 0.0, -math.cos(math.radians(28.6))])
    R = rot_between(np.array([0.0, 0.0, 1.0]), u)
    return R, RCM + 0.14 * u


def _obs(c: Calibration, R: np.ndarray, p: np.ndarray, tilt_rad: float = 0.0) -> VisionObservation:
    A = c.R_base_camera.T
    u_c = A @ R[:, 2]
    J_c = A @ (p - c.junction_proximal_m * R[:, 2] - c.p_base_camera_m)
    n_l, n_r = vg.tangent_plane_normals(vg.closest_axis_point(J_c, u_c), u_c, c.shaft_radius_m)
    if tilt_rad:
        n_l = vg.tilt_normal(n_l, tilt_rad, 0.0, u_c)
    return VisionObservation(n_l, n_r, True, J_c / np.linalg.norm(J_c))


def test_a_stall_past_the_imu_gap_holds_the_velocity_and_gives_it_its_no_imu_uncertainty():
    """`propagate_held` (every propagation of the filter): within the IMU gap, or without an IMU,
    it is `propagate` exactly. Past the gap the held samples drive only the gap itself; the rest
    of the stall is propagated as without an IMU (velocity held, no rotation), and the velocity's
    variance grows by the no-IMU noise for each further second. Integrating the held specific
    force over a whole stall ran an accelerating tool off by tens of centimetres."""
    f = TrackingFilter(_calib(), Params())
    k = f._gyro_k
    rng = np.random.default_rng(2)
    X = rng.normal(size=(N, N))
    P0 = X @ X.T * 1e-4 + np.eye(N) * 1e-6
    R0 = so3_exp(rng.normal(size=3))
    args = [rng.normal(size=3) for _ in range(5)]  # bg, ba, w, f, alpha

    def run(kernel, dt, imu, then=None):
        P, R = P0.copy(), R0.copy()
        p, v = np.zeros(3), np.zeros(3)
        bg, ba, w, fi, alpha = (a.copy() for a in args)
        if kernel is propagate:
            kernel(p, v, R, P, bg, ba, w, fi, alpha, f.R_ti, f.r_imu_tip_tool, f._Q, k[0], k[1], dt, imu, k[8])
            if then is not None:
                kernel(p, v, R, P, bg, ba, w, fi, alpha, f.R_ti, f.r_imu_tip_tool, f._Q, k[0], k[1], then, False, k[8])
        else:
            kernel(p, v, R, P, bg, ba, w, fi, alpha, f.R_ti, f.r_imu_tip_tool, f._Q, k, dt, imu)
        return P, p, v, R

    gap = Params().imu_gap_ms * 1e-3
    assert k[2] == pytest.approx(gap) and k[3] > 0
    dt = gap + 0.3
    P_h, p_h, v_h, R_h = run(propagate_held, dt, True)
    P_r, p_r, v_r, R_r = run(propagate, gap, True, then=0.3)
    added = P_h - P_r
    np.testing.assert_allclose(np.diag(added)[3:6], k[3] * 0.3, rtol=1e-9)
    added[3:6, 3:6] -= np.eye(3) * k[3] * 0.3
    np.testing.assert_allclose(added, 0.0, atol=1e-15)
    np.testing.assert_array_equal(R_h, R_r)
    np.testing.assert_array_equal(v_h, run(propagate, gap, True)[2])  # no acceleration past the gap
    np.testing.assert_allclose(p_h, p_r, atol=1e-15)
    # the whole stall under the held samples would move it much further
    p_all = run(propagate, dt, True)[1]
    assert np.linalg.norm(p_all) > 3 * np.linalg.norm(p_h)  # 0.5 a dt^2 against a gap (gap / 2 + 0.3 s)
    for step, imu in ((gap * 0.9, True), (dt, False)):
        np.testing.assert_array_equal(run(propagate_held, step, imu)[0], run(propagate, step, imu)[0])


def test_the_tof_offset_walks_as_the_tool_turns_only_while_it_is_free():
    """b_rho stands for the ToF's error at the present pose, which is pose-locked: while vision
    gives tips it walks by `tof_offset_rw_mm2_per_deg` for every degree the tool turns, on top
    of its walk at rest; held (no tip within the window) it does not move at all."""
    prm = Params()
    f = TrackingFilter(_calib(), prm)
    k = f._gyro_k
    assert k[8] == pytest.approx(prm.tof_offset_rw_mm2_per_deg * 1e-6 / math.radians(1.0)) and k[8] > 0
    dt = 0.005
    w_turn = np.array([0.3, -0.2, 0.4])  # rad/s in IMU coordinates

    def var_brho(Q, w):
        P = np.eye(N) * 1e-8
        z = np.zeros(3)
        propagate_held(
            np.zeros(3), z.copy(), np.eye(3), P, z.copy(), z.copy(), w, np.array([0, 0, 9.8]), z.copy(),
            f.R_ti, f.r_imu_tip_tool, Q, k, dt, True,
        )  # fmt: skip
        return P[N - 1, N - 1] - 1e-8

    rest, turning = var_brho(f._Q, np.zeros(3)), var_brho(f._Q, w_turn)
    assert rest == pytest.approx(f._Q[N - 1] * dt, rel=1e-9)
    assert turning - rest == pytest.approx(k[8] * np.linalg.norm(w_turn) * dt, rel=1e-9)
    # one degree of turning adds the parameter's variance [m^2]
    assert (turning - rest) / math.degrees(np.linalg.norm(w_turn) * dt) == pytest.approx(
        prm.tof_offset_rw_mm2_per_deg * 1e-6, rel=1e-9
    )
    assert var_brho(f._Q_held, w_turn) == 0.0


def test_the_gravity_update_takes_the_shafts_point_at_the_port_at_rest():
    """A tool pivoting about the port (rate and angular acceleration, no sliding): the specific
    force at the IMU is gravity plus the centripetal and tangential terms about the port, so
    the gravity update must see no innovation and leave the attitude as it was. Taking the tip
    at rest instead misses the tip's own swing, L alpha."""
    c = _calib()
    R, p = _pose()
    depth = float(np.linalg.norm(p - RCM))
    w_tool, alpha = np.array([1.0, -0.5, 0.3]), np.array([4.0, -3.0, 1.0])
    r = c.p_imu_tool_m + depth * E_Z  # port to IMU, tool coordinates (the tip is the origin)
    a_imu = np.cross(alpha, r) + np.cross(w_tool, np.cross(w_tool, r))
    f_imu = c.R_tool_imu.T @ (a_imu - R.T @ G)
    w_imu = c.R_tool_imu.T @ w_tool
    lever = port_lever(R, p, RCM, -c.p_imu_tool_m)
    np.testing.assert_allclose(lever, -r, atol=1e-12)
    _, y = gravity_jacobian(R, c.R_tool_imu, lever, w_imu, np.zeros(3), np.zeros(3), alpha, f_imu)
    np.testing.assert_allclose(y, 0.0, atol=1e-12)
    _, y_tip = gravity_jacobian(R, c.R_tool_imu, -c.p_imu_tool_m, w_imu, np.zeros(3), np.zeros(3), alpha, f_imu)
    assert np.linalg.norm(y_tip) > 0.5  # m/s^2: 3 deg of gravity
    f = TrackingFilter(c, Params())
    s = f.new_state(0, R, depth, f_imu)
    s.w_imu, s.alpha_tool = w_imu, alpha.copy()
    R0, p0 = s.R.copy(), s.p.copy()
    assert f.update_gravity(s)
    np.testing.assert_allclose(s.R, R0, atol=1e-12)
    np.testing.assert_allclose(s.p, p0, atol=1e-12)


def test_the_compiled_gyro_and_gravity_steps_equal_propagate_then_the_update():
    """`kernels.steps.gyro_step` (propagation, angular acceleration and the RCM update in one call)
    and `kernels.steps.gravity_step` (propagation and the gravity update) against the same samples
    propagated apart first (`propagate`, as the smoother runs the filter), with a stall longer
    than the IMU gap, stamps bunched closer than the angular-acceleration span, and both b_rho
    modes (free after the junction, held once the offset window has passed)."""
    c = _calib()
    R, p = _pose()
    f_true = c.R_tool_imu.T @ R.T @ (-G)
    states = []
    for apart in (False, True):
        f = TrackingFilter(c, Params())
        f.propagate_apart = apart
        s = f.init_from_vision(0, _obs(c, R, p), f_true)
        rng = np.random.default_rng(3)
        t = 0
        for k in range(1, 900):
            t += 200_000 if k % 97 == 0 else 120_000_000 if k == 400 else 5_000_000
            f.on_gyro(s, t, rng.normal(size=3) * 0.02)
            if k % 5 == 0:
                f.on_accel(s, t + 1000, f_true + rng.normal(size=3) * 0.05)
        states.append(s)
    a, b = states
    assert a.counts == b.counts and a.counts["updates:rcm"] > 800 and a.counts["updates:gravity"] > 100
    assert a.nis["rcm"] == pytest.approx(b.nis["rcm"], rel=1e-9)
    assert a.nis["gravity"] == pytest.approx(b.nis["gravity"], rel=1e-9)
    for name in ("p", "v", "R", "bg", "ba", "alpha_tool", "w_imu"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-9, atol=1e-18)
    assert a.brho == pytest.approx(b.brho, abs=1e-12)


def _heading_information(s, rcm: np.ndarray) -> float:
    """Information along the turn of the whole state about the vertical through the RCM."""
    n = np.zeros(N)
    n[0:3] = np.cross(E_Z, s.p - rcm)
    n[3:6] = np.cross(E_Z, s.v)
    n[6:9] = s.R.T @ E_Z
    return float(n @ np.linalg.solve(s.P, n))


def test_the_rcm_and_gravity_updates_tell_nothing_about_the_heading():
    """Turning the whole state about the vertical through the RCM changes neither prediction, so
    their updates must leave the information along that turn as it was, however far they move
    the estimate. (With the covariance kept as it was across each change of estimate, every
    update fed it a little: without vision the heading sigma settled at 1 deg while the heading
    walked off by tens of degrees.)"""
    c = _calib()
    R, p = _pose()
    f = TrackingFilter(c, Params(), frozenset({"imu"}))
    f_true = c.R_tool_imu.T @ R.T @ (-G)
    s = f.new_state(0, R, 0.14, f_true)
    s.p = s.p + np.array([0.003, -0.002, 0.001])  # an estimate the updates have to move
    s.v = np.array([0.01, 0.0, -0.02])
    s.R = s.R @ so3_exp(np.array([0.01, -0.02, 0.005]))
    s.f_imu, s.w_imu = f_true, np.zeros(3)
    p0, R0 = s.p.copy(), s.R.copy()
    for _ in range(20):
        before = _heading_information(s, f.rcm)
        H, y = rcm_jacobian(s.R, s.p, f.rcm)
        assert f._update(s, H, y, np.full(2, 1e-8), 1e9, "rcm")
        assert _heading_information(s, f.rcm) == pytest.approx(before, rel=1e-8)
        before = _heading_information(s, f.rcm)
        assert f.update_gravity(s)
        assert _heading_information(s, f.rcm) == pytest.approx(before, rel=1e-8)
    assert np.linalg.norm(s.p - p0) > 1e-3 and np.linalg.norm(so3_exp(np.zeros(3)) - R0.T @ s.R) > 1e-3


def _run_static(seconds: float, bias_imu: np.ndarray, seed: int = 1, params: Params | None = None):
    c = _calib()
    R, p = _pose()
    f = TrackingFilter(c, params or Params())
    rng = np.random.default_rng(seed)
    f_true = c.R_tool_imu.T @ R.T @ (-G)
    s = f.init_from_vision(0, _obs(c, R, p), f_true)
    assert s is not None
    for k in range(1, int(seconds * 200)):
        t = k * 5_000_000
        f.on_gyro(s, t, bias_imu + rng.normal(size=3) * 0.003)
        if k % 5 == 0:
            f.on_accel(s, t + 1000, f_true + rng.normal(size=3) * 0.05)
        if k % 13 == 0:
            f.propagate(s, t + 2000)
            f.update_vision(s, _obs(c, R, p))
    return f, s, R, p


@pytest.mark.parametrize("every", [0, 1, 3])
def test_gravity_updates_come_at_every_nth_accelerometer_sample(every):
    """`gravity_every`: a gravity update at every n-th accelerometer sample, none at 0."""
    c = _calib()
    R, p = _pose()
    f = TrackingFilter(c, Params(gravity_every=every), frozenset({"imu"}))
    f_true = c.R_tool_imu.T @ R.T @ (-G)
    s = f.new_state(0, R, 0.14, f_true)
    for k in range(1, 601):
        f.on_gyro(s, k * 5_000_000, np.zeros(3))
        f.on_accel(s, k * 5_000_000 + 1000, f_true)
    assert s.counts.get("updates:gravity", 0) == (600 // every if every else 0)
    assert ("gravity" in s.nis) == bool(every)


def _range(c: Calibration, R: np.ndarray, p: np.ndarray) -> float:
    """The raw range [m] of the ray-plane model at the tool pose (R, p), written out here so the
    tests do not lean on the filter's own kernel."""
    m = c.tof_plane_normal_base
    return float((c.tof_plane_h_m - m @ (p + R @ c.tof_origin_tool_m)) / (m @ (R @ c.tof_beam_tool)))


def test_a_state_copy_carries_every_slot_and_no_array_the_filter_changes():
    """Rewinds restore snapshots: a slot copy() forgot would come back from the wrong time, and
    an array it shared would come back as the filter later changed it. The arrays it does share
    (`State.SHARED`, to keep the snapshot at every gyro sample cheap) must come through more
    filtering of the original unchanged."""
    from services.fusion.eskf.filter import State

    f, s, R, p = _run_static(0.5, np.zeros(3), params=Params(accel_map_every_ms=1.0))
    c = s.copy()
    shared = {}
    for name in State.__slots__:
        a, b = getattr(s, name), getattr(c, name)
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b, equal_nan=True), name
            if name in State.SHARED:
                shared[name] = a.copy()
            else:
                assert a is not b, name
        else:
            assert a == b, name
            assert not isinstance(a, (list, dict)) or a is not b, name
    assert set(shared) == set(State.SHARED)
    rng = np.random.default_rng(5)
    for k in range(1, 41):  # the original goes on: gyro, accelerometer, vision
        t = s.t_ns + 5_000_000
        f.on_gyro(s, t, rng.normal(size=3) * 0.01)
        f.on_accel(s, t + 1000, c.f_imu + rng.normal(size=3) * 0.05)
        if k % 13 == 0:
            f.update_vision(s, _obs(f.c, R, p))
    for name, before in shared.items():
        assert not np.array_equal(getattr(s, name), before) or name == "f_corr", name  # it moved on
        assert np.array_equal(getattr(c, name), before), name  # the snapshot did not


def test_gyro_bias_and_tip_at_rest():
    bias = np.radians([0.08, -0.06, 0.05])  # about the 0.05 deg/s instability of the prior
    f, s, R, p = _run_static(20.0, bias)
    sigma = np.sqrt(np.trace(s.P[0:3, 0:3]))
    assert np.linalg.norm(s.p - p) < min(0.4e-3, 3 * sigma)
    assert np.degrees(np.abs(s.bg - bias)).max() < 0.015, np.degrees(s.bg)
    assert s.counts["updates:vision_axis"] > 300 and s.counts["updates:rcm"] >= 3999


def test_trocar_and_innovation_gates_reject_wrong_lines():
    f, s, R, p = _run_static(5.0, np.zeros(3))
    before = s.p.copy()
    # 4 deg off: the line misses the RCM by far more than 3.5 mm
    f.update_vision(s, _obs(f.c, R, p, tilt_rad=math.radians(4.0)))
    assert s.counts.get("rejected:vision_axis:trocar_gate", 0) == 1
    # 1.2 deg off: passes the trocar gate, fails the chi-square gate
    f.update_vision(s, _obs(f.c, R, p, tilt_rad=math.radians(1.2)))
    assert s.counts.get("rejected:vision_axis:innovation", 0) == 1
    assert s.counts.get("rejected:vision_axis:trocar_gate", 0) == 1
    # only the (true) tips were applied: the estimate did not move away from the truth
    assert np.linalg.norm(s.p - p) <= np.linalg.norm(before - p) + 0.02e-3


def _axis_frames(params: Params, poses: list[tuple[np.ndarray, np.ndarray]], dt_ns: int = 66_000_000):
    """A filter without the IMU or the junction fed one axis frame per (R, p), dt_ns apart, its
    state set to each pose first: the axis' variance factor before each frame, and the state."""
    c = _calib()
    f = TrackingFilter(c, params, frozenset({"vision"}))
    R0, p0 = poses[0]
    s = f.init_from_vision(0, _obs(c, R0, p0), None)
    factors = []
    for k, (R, p) in enumerate(poses, start=1):
        s.t_ns, s.R, s.p = k * dt_ns, R.copy(), p.copy()
        factors.append(f._revisit(s))
        obs = _obs(c, R, p)
        f.update_vision(s, VisionObservation(obs.n_left, obs.n_right, False, obs.ray))
    return factors, s


def test_axis_frames_at_a_held_pose_weigh_less_as_they_accumulate():
    """`vision_axis_revisit_weight`: the planes' error is mostly pose-locked, so each axis frame's
    variance grows with the applied frames near its pose (1 + w per frame at the same pose); frames
    at poses a few kernel widths away, or older than the window, do not count, and 0 turns it off."""
    R, p = _pose()
    held = [(R, p)] * 12
    factors, s = _axis_frames(Params(), held)
    assert s.counts["updates:vision_axis"] == 12
    assert factors[0] == 1.0
    assert np.allclose(factors, 1.0 + 0.05 * np.arange(12), rtol=1e-6)  # the state sits on the pose
    # the same frames with the weighting off claim more: the shaft direction's variance ends
    # smaller (the attitude error's first two components; the third, the roll, vision never sees)
    off, s_off = _axis_frames(Params(vision_axis_revisit_weight=0.0), held)
    assert off == [1.0] * 12
    assert np.trace(s_off.P[6:8, 6:8]) < 0.92 * np.trace(s.P[6:8, 6:8])
    assert s_off.P[8, 8] == pytest.approx(s.P[8, 8])
    # a path that moves on, 4 deg (10 mm of tip) per frame: only the last frame counts, in part
    path = []
    for k in range(12):
        Rk = so3_exp(np.array([math.radians(4.0 * k), 0.0, 0.0])) @ R
        path.append((Rk, RCM + 0.14 * Rk[:, 2]))
    moving, _ = _axis_frames(Params(), path)
    assert 1.0 < max(moving) < 1.0 + 0.05 * 0.7  # against 1.55 for the twelfth frame held
    # frames older than the window are forgotten: one frame per 4 s at one pose, window 10 s
    sparse, _ = _axis_frames(Params(), held[:6], dt_ns=4_000_000_000)
    assert sparse[-1] == pytest.approx(1.0 + 0.05 * 2, rel=1e-6)


def test_tof_offset_moves_only_after_an_independent_tip():
    f, s, R, p = _run_static(3.0, np.zeros(3))
    rho = _range(f.c, R, p)
    stale = s.copy()
    stale.last_tip_ns = stale.t_ns - 3_000_000_000  # last vision tip 3 s ago
    for _ in range(50):
        f.update_tof(stale, rho + 0.004)  # the range reads 4 mm long
        f.update_tof(s, rho + 0.004)
    assert stale.brho == pytest.approx(0.0, abs=1e-12)
    assert s.brho > 0.5e-3


def test_tof_weighs_more_while_it_is_the_only_depth():
    f, s, R, p = _run_static(3.0, np.zeros(3))
    rho = _range(f.c, R, p)
    held = s.copy()
    held.last_tip_ns = held.t_ns - 3_000_000_000
    assert f.prm.tof_sigma_held_mm < f.prm.tof_sigma_mm
    depth = {}
    for name, st in (("free", s), ("held", held)):
        L0 = float(st.R[:, 2] @ (st.p - f.rcm))
        assert f.update_tof(st, rho + 0.004)
        depth[name] = float(st.R[:, 2] @ (st.p - f.rcm)) - L0
    assert abs(depth["held"]) > 1.5 * abs(depth["free"]) > 0.0


def test_a_junction_far_from_the_tof_depth_is_refused_while_the_offset_is_current():
    """A gross junction error (the labeler on a wrong end of the shaft) is refused when the
    latest ToF range puts the tip elsewhere; once b_rho is held (after a blackout) a junction
    may move the depth whatever the ToF says."""
    f, s, R, p = _run_static(3.0, np.zeros(3))
    rho = _range(f.c, R, p)
    u = R[:, 2]
    s.P[0:3, 0:3] += 1e-4 * np.outer(u, u)  # 10 mm of depth uncertainty: the chi-square gate alone lets it in
    held = s.copy()
    held.last_tip_ns = held.t_ns - 3_000_000_000
    for st in (s, held):
        assert f.update_tof(st, rho + st.brho)
        f.update_vision(st, _obs(f.c, R, p + 0.02 * u))  # the junction 20 mm deeper than it is
    assert s.counts.get("rejected:vision_tip:tof_disagrees", 0) == 1
    assert abs(float(u @ (s.p - p))) < 1e-3
    assert held.counts.get("rejected:vision_tip:tof_disagrees", 0) == 0
    assert held.counts["deferred:vision_tip"] == 1  # a surprise: it waits for the next frame
    _frames(f, held, [_obs(f.c, R, p + 0.02 * u)])
    assert float(u @ (held.p - p)) > 5e-3  # confirmed and applied: the ToF vetoed nothing
    tips = s.counts["updates:vision_tip"]
    f.update_vision(s, _obs(f.c, R, p + 0.004 * u))  # 4 mm: within what the ToF can tell
    assert s.counts["updates:vision_tip"] == tips + 1
    assert s.counts.get("rejected:vision_tip:tof_disagrees", 0) == 1


def test_a_start_the_tof_puts_elsewhere_waits_for_a_frame_it_agrees_with():
    """A first state from one frame whose junction the latest range puts 20 mm away (a gross
    junction error, or a shaft line degrees off) is refused; a frame the range agrees with
    starts. Without a fresh range, or after `reset_after_vision_rejections` refusals in a row
    (a ToF that is itself off), the frame starts whatever the ToF says."""
    c = _calib()
    R, p = _pose()
    u = R[:, 2]
    f = TrackingFilter(c, Params())
    f_true = c.R_tool_imu.T @ R.T @ (-G)
    tof = (0, _range(c, R, p))
    far = _obs(c, R, p + 0.02 * u)
    t = 1_000_000
    s, refused = f.start_from_vision(t, far, f_true, tof, 0)
    assert s is None and refused == 1
    s, refused = f.start_from_vision(t, _obs(c, R, p), f_true, tof, refused)
    assert s is not None and refused == 0
    assert np.linalg.norm(s.p - p) < 1e-4
    assert s.tof_last[0] < 0  # the range was only looked at: the state has applied none
    for start in (f.start_from_vision(200_000_000, far, f_true, tof, 0), f.start_from_vision(t, far, f_true, None, 0)):
        assert start[0] is not None and float(u @ (start[0].p - p)) > 0.019
    k = f.prm.reset_after_vision_rejections
    assert f.start_from_vision(t, far, f_true, tof, k - 1)[1] == k
    s, refused = f.start_from_vision(t, far, f_true, tof, k)
    assert s is not None and refused == 0 and float(u @ (s.p - p)) > 0.019
    off = TrackingFilter(c, Params(vision_tip_tof_gate_mm=0.0))
    assert off.start_from_vision(t, far, f_true, tof, 0)[0] is not None


def _depth_uncertain(f: TrackingFilter, s, mm: float):
    """The state with `mm` of depth uncertainty added (IMU only for a while, no ToF range)."""
    u = s.R[:, 2]
    s.P[0:3, 0:3] += (mm * 1e-3) ** 2 * np.outer(u, u)
    return u


def test_a_surprising_tip_waits_for_the_next_frame_and_a_gross_one_is_dropped():
    """A junction 15 mm too deep (the labeler's gross error) after the depth has grown 6 mm
    uncertain passes the chi-square gate; held for confirmation, it is dropped when the next
    frame's tip is where the state says. Without the confirmation it throws the depth."""
    f, s, R, p = _run_static(3.0, np.zeros(3))
    u = _depth_uncertain(f, s, 6.0)
    off = TrackingFilter(f.c, replace(f.prm, tip_confirm_chi2=0.0))
    plain = s.copy()
    off.update_vision(plain, _obs(f.c, R, p + 0.015 * u))
    assert plain.counts.get("rejected:vision_tip:innovation", 0) == 0
    assert float(u @ (plain.p - p)) > 5e-3  # the chi-square gate alone let it in
    f.update_vision(s, _obs(f.c, R, p + 0.015 * u))
    assert s.counts["deferred:vision_tip"] == 1
    assert abs(float(u @ (s.p - p))) < 0.5e-3
    tips = s.counts["updates:vision_tip"]
    _frames(f, s, [_obs(f.c, R, p)])
    assert s.counts["updates:vision_tip"] == tips + 1
    assert s.counts["rejected:vision_tip:unconfirmed"] == 1
    assert s.tip_held is None
    assert abs(float(u @ (s.p - p))) < 0.5e-3


def test_a_depth_that_drifted_is_corrected_once_two_frames_agree():
    """The state 12 mm too shallow and unsure of it: the first frame's tip is held, the second,
    off the same way, confirms it and is applied."""
    f, s, R, p = _run_static(3.0, np.zeros(3))
    u = _depth_uncertain(f, s, 6.0)
    s.p = s.p - 0.012 * u
    f.update_vision(s, _obs(f.c, R, p))
    assert s.counts["deferred:vision_tip"] == 1
    assert float(u @ (p - s.p)) > 11.5e-3
    _frames(f, s, [_obs(f.c, R, p)])
    assert s.counts.get("rejected:vision_tip:unconfirmed", 0) == 0
    assert abs(float(u @ (s.p - p))) < 2e-3
    # a tip that disagrees with the held one by more than the tolerance does not confirm it
    s2 = s.copy()
    s2.P[0:3, 0:3] += (6e-3) ** 2 * np.outer(u, u)
    s2.p = s2.p - 0.012 * u
    f.update_vision(s2, _obs(f.c, R, p))
    _frames(f, s2, [_obs(f.c, R, p + 0.006 * u)])
    assert s2.counts["rejected:vision_tip:unconfirmed"] == 1
    assert s2.counts["deferred:vision_tip"] == 3  # the second is held in its turn
    # no more than two wait in a row: a third that disagrees again is applied
    tips = s2.counts["updates:vision_tip"]
    _frames(f, s2, [_obs(f.c, R, p - 0.006 * u)])
    assert s2.counts["rejected:vision_tip:unconfirmed"] == 2
    assert s2.counts["updates:vision_tip"] == tips + 1
    assert s2.tip_held is None


def test_held_tof_uses_the_error_learnt_at_this_pose_while_vision_saw_the_tip():
    """At this pose the range reads 4 mm long, learnt while b_rho was free; b_rho was then held
    at 0 (set where the ToF read true). Without vision, the ToF at this pose then leaves the
    depth where it is; without the map it pulls the tip off along the shaft, towards 4 mm."""
    moved = {}
    for use_map in (True, False):
        # the accelerometer's map off: what it learns from a still tool's noise is not the point
        f, s, R, p = _run_static(3.0, np.zeros(3), params=Params(accel_map=False))
        f = TrackingFilter(f.c, Params(tof_map=use_map, accel_map=False))
        rho = _range(f.c, R, p)
        learn = s.copy()
        for k in range(100):
            learn.t_ns = learn.last_tip_ns = s.t_ns + k * 10_000_000  # vision sees the tip throughout
            f.update_tof(learn, rho + 0.004)
        assert (f.tof_map is not None and len(f.tof_map) > 0) == use_map
        held = s.copy()
        held.t_ns = learn.t_ns + 10_000_000
        held.last_tip_ns = held.t_ns - 3_000_000_000
        held.brho = 0.0
        L0 = float(held.R[:, 2] @ (held.p - f.rcm))
        for _ in range(200):
            f.update_tof(held, rho + 0.004)
        moved[use_map] = abs(float(held.R[:, 2] @ (held.p - f.rcm)) - L0)
        assert held.counts.get("updates:tof_mapped", 0) == (200 if use_map else 0)
    assert moved[True] < 0.25 * moved[False] and moved[False] > 0.15e-3, moved


def _held_tof_matches(f: TrackingFilter, s, r_var: float, far: bool = True) -> bool:
    """Whether a held ToF range with no innovation (the state stays, P shrinks) used the
    measurement variance r_var: P against the Joseph form with b_rho given no gain. The range
    is the one the map predicts, shrunk towards its far prior (`far`) or towards b_rho."""
    c = f.c
    H, rho, _ = tof_jacobian(
        s.R, s.p, s.brho, c.tof_plane_normal_base, c.tof_plane_h_m, c.tof_origin_tool_m, c.tof_beam_tool
    )
    if f.tof_map is not None:
        prior = f.tof_map.far_prior(s.t_ns, s.R, s.p, s.brho) if far else s.brho
        rho += f.tof_map.predict(s.t_ns, s.R, s.p, prior)[0] - s.brho
    h, P = H[0], s.P.copy()
    assert f.update_tof(s, rho)
    K = P @ h / (h @ P @ h + r_var)
    K[-1] = 0.0
    A = np.eye(N) - np.outer(K, h)
    return np.allclose(s.P, A @ P @ A.T + r_var * np.outer(K, K), rtol=1e-9, atol=1e-15)


def test_held_tof_weighs_less_where_the_map_learnt_nothing():
    """While b_rho is held the range's pose-locked error is known only where the map learnt it:
    at such a pose the held variance, elsewhere (or with no map at all, as without vision)
    `tof_unmapped_var_factor` + 1 times it."""
    f, s, R, p = _run_static(3.0, np.zeros(3))
    held_var = (f.prm.tof_sigma_held_mm * 1e-3) ** 2
    k = f.prm.tof_unmapped_var_factor
    assert k > 0
    rho = _range(f.c, R, p)
    learn = s.copy()
    for i in range(300):
        learn.t_ns = learn.last_tip_ns = s.t_ns + i * 10_000_000
        f.update_tof(learn, rho)
    here = s.copy()
    here.t_ns = learn.t_ns + 10_000_000
    here.last_tip_ns = here.t_ns - 3_000_000_000
    weight = f.tof_map.predict(here.t_ns, here.R, here.p, 0.0)[1]
    w0 = f.prm.tof_map_prior_weight
    assert weight > 10 * w0
    expected_here = held_var * (1 + k * w0 / (weight + w0))
    assert _held_tof_matches(f, here.copy(), expected_here)
    assert not _held_tof_matches(f, here.copy(), held_var * (1 + k))
    elsewhere = here.copy()
    elsewhere.R = elsewhere.R @ so3_exp(np.array([0.0, 0.0, math.radians(20.0)]))  # rolled: unseen
    assert f.tof_map.predict(elsewhere.t_ns, elsewhere.R, elsewhere.p, 0.0)[1] < 1e-6
    # there the range is expected off by the map's far prior (the recorded errors' mean, shrunk
    # towards b_rho), not by the held b_rho, learnt 20 deg away and here 4 mm off them
    elsewhere.brho += 0.004
    assert abs(f.tof_map.far_prior(elsewhere.t_ns, elsewhere.R, elsewhere.p, elsewhere.brho) - elsewhere.brho) > 5e-4
    assert not _held_tof_matches(f, elsewhere.copy(), held_var * (1 + k), far=False)
    assert _held_tof_matches(f, elsewhere, held_var * (1 + k))
    no_vision = TrackingFilter(f.c, f.prm, frozenset({"imu", "tof"}))
    assert no_vision.tof_map is None
    assert _held_tof_matches(no_vision, here.copy(), held_var * (1 + k))


def test_held_tof_offset_moves_through_no_other_update():
    """With the junction hidden (no independent tip), b_rho is correlated with the tip by the
    ToF updates, but neither the RCM, the vision axis, gravity nor time moves it or its variance:
    before, a vision axis update carried the ToF's error into b_rho and the depth walked away."""
    f, s, R, p = _run_static(3.0, np.zeros(3))
    rho = _range(f.c, R, p)
    s.last_tip_ns = s.t_ns - 3_000_000_000
    b0, var0 = s.brho, s.P[15, 15]
    hidden = _obs(f.c, R, p)._replace(junction_visible=False)
    f_true = f.c.R_tool_imu.T @ R.T @ (-G)
    for k in range(200):
        t = s.t_ns + 5_000_000
        f.on_gyro(s, t, np.zeros(3))
        f.on_accel(s, t, f_true)
        f.update_tof(s, rho + 0.004)
        if k % 7 == 0:
            assert f.update_vision(s, hidden)
    assert s.counts["updates:vision_axis"] > 20 and s.counts["updates:tof"] == 200
    assert abs(float(np.linalg.norm(s.P[0:3, 15]))) > 0.0  # correlated with the tip
    assert s.brho == b0
    assert s.P[15, 15] == pytest.approx(var0, rel=1e-9)


def _off_heading(f: TrackingFilter, s, angle_deg: float):
    """The state turned about the vertical through the RCM (a heading error after a blackout),
    its covariance left as confident as before."""
    bad = s.copy()
    Rz = so3_exp(np.array([0.0, 0.0, math.radians(angle_deg)]))
    bad.R = Rz @ s.R
    bad.p = f.rcm + Rz @ (s.p - f.rcm)
    return bad


def _frames(f: TrackingFilter, s, obs_list) -> None:
    for obs in obs_list:
        f.propagate(s, s.t_ns + 33_000_000)
        f.update_vision(s, obs)


def test_consistent_frames_failing_the_innovation_gate_reacquire_heading():
    f, s, R, p = _run_static(5.0, np.zeros(3))
    bad = _off_heading(f, s, 6.0)
    assert np.linalg.norm(bad.p - p) > 6e-3
    k = f.prm.reacquire_frames
    _frames(f, bad, [_obs(f.c, R, p)] * (k - 1))
    assert bad.counts.get("updates:reacquire", 0) == 0  # not before k frames agree
    assert bad.counts["rejected:vision_axis:innovation"] >= k - 1
    # the tip of the first rejected frame still pulls the state, so its correction may differ
    _frames(f, bad, [_obs(f.c, R, p)] * 2)
    assert bad.counts["updates:reacquire"] == 1
    assert np.linalg.norm(bad.p - p) < 1e-3
    assert math.degrees(math.acos(min(1.0, float(bad.R[:, 2] @ R[:, 2])))) < 0.2
    assert f.diverged(bad) is None
    # afterwards the frames pass the gate again
    n0 = bad.counts.get("updates:vision_axis", 0)
    _frames(f, bad, [_obs(f.c, R, p)] * 3)
    assert bad.counts["updates:vision_axis"] == n0 + 3


def test_frames_whose_junction_the_tof_puts_elsewhere_do_not_reacquire():
    """Frames that agree with each other but put the tip 20 mm deeper than the latest range (a
    gross junction error that lasts) are no lost state: they do not move the state onto them."""
    f, s, R, p = _run_static(5.0, np.zeros(3))
    bad = _off_heading(f, s, 6.0)
    u = R[:, 2]
    for _ in range(2 * f.prm.reacquire_frames):
        f.propagate(bad, bad.t_ns + 33_000_000)
        f.update_tof(bad, _range(f.c, R, p) + s.brho)  # the true range
        f.update_vision(bad, _obs(f.c, R, p + 0.02 * u))
    assert bad.counts.get("updates:reacquire", 0) == 0
    assert bad.counts["rejected:reacquire:tof_disagrees"] >= f.prm.reacquire_frames
    assert np.linalg.norm(bad.p - p) > 5e-3  # still where it was, 7 mm off


def test_disagreeing_frames_do_not_reacquire():
    f, s, R, p = _run_static(5.0, np.zeros(3))
    bad = _off_heading(f, s, 6.0)
    tilts = [0.0, 1.5] * 4  # each passes the trocar gate, but they ask for different lines
    _frames(f, bad, [_obs(f.c, R, p, tilt_rad=math.radians(t)) for t in tilts])
    assert bad.counts.get("updates:reacquire", 0) == 0
    assert bad.counts.get("rejected:vision_axis:trocar_gate", 0) == 0
    # not moved onto vision (a re-acquisition leaves it within 1 mm, as above); the frames' tips
    # still pull it a little from its 7 mm off
    assert np.linalg.norm(bad.p - p) > 5e-3


def test_without_vision_the_tip_stays_at_a_physical_depth():
    c = _calib()
    R, _ = _pose()
    f = TrackingFilter(c, Params(), frozenset({"imu", "tof"}))
    f_true = c.R_tool_imu.T @ R.T @ (-G)
    for depth in (0.9, -0.05):
        s = f.new_state(0, R, depth, f_true)
        f.on_gyro(s, 5_000_000, np.zeros(3))
        L = float(R[:, 2] @ (s.p - f.rcm))
        assert f.prm.depth_min_m - 1e-4 <= L <= f.prm.depth_max_m + 1e-4, L
        assert s.counts["clamped:depth"] == 1
    # with vision the clamp is not applied: vision itself bounds the depth
    fv = TrackingFilter(c, Params())
    s = fv.new_state(0, R, 0.9, f_true)
    fv.on_gyro(s, 5_000_000, np.zeros(3))
    assert "clamped:depth" not in s.counts


def _still_imu(seconds: float, bias: np.ndarray, f_true: np.ndarray, seed: int = 2):
    """(t_s, kind, sample) of a still IMU at 200 Hz gyro and 240 Hz accelerometer, with the
    bench's white noise (0.2 deg/s and 0.07 m/s^2 per sample)."""
    rng = np.random.default_rng(seed)
    ev = [(k / 200.0, 0, bias + rng.normal(size=3) * math.radians(0.2)) for k in range(int(seconds * 200))]
    ev += [(k / 240.0 + 1e-4, 1, f_true + rng.normal(size=3) * 0.07) for k in range(int(seconds * 240))]
    return sorted(ev, key=lambda e: e[0])


def _rest_k(prm: Params) -> np.ndarray:
    return TrackingFilter(_calib(), prm)._rest_k


def test_rest_releases_the_mean_rate_of_a_still_tool_chunk_by_chunk():
    prm = Params()
    k = _rest_k(prm)
    bias = np.radians([0.4, -0.7, 1.3])
    rest = rest_init()
    released = []
    for t, kind, x in _still_imu(6.0, bias, np.array([0.0, 0.0, 9.8])):
        if rest_sample(rest, x, t, kind, k):
            released.append((t, rest[REST_RATE : REST_RATE + 3].copy()))
    # at rest after rest_min_ms; a chunk is released when the next one has agreed with it
    first = (prm.rest_min_ms + 2 * prm.rest_chunk_ms) * 1e-3
    assert first <= released[0][0] < first + 0.1, released[0][0]
    gaps = np.diff([t for t, _ in released])
    assert len(released) >= 6 and np.all((gaps >= 0.5) & (gaps <= 0.51)), gaps  # one per chunk
    sd_mean = math.radians(0.2) / math.sqrt(100)
    for _, m in released:
        assert np.abs(m - bias).max() < 4 * sd_mean, np.degrees(m - bias)


def test_rest_uses_no_chunk_from_a_motions_onset_nor_a_slow_smooth_motion():
    """A turn that starts slowly stays within 2 deg/s of its low-pass for a while: the chunk it
    started in must not be used; nor must a slow sway that never leaves its low-pass."""
    k = _rest_k(Params())
    g = np.array([0.0, 0.0, 9.8])
    rest = rest_init()
    onset = 3.2  # the pending chunk then holds [2.5, 3.0) s and the next one is open
    released = []
    for t, kind, x in _still_imu(8.0, np.zeros(3), g):
        rate = math.radians(4.0) * max(t - onset, 0.0)  # about x, ramping 4 deg/s per s
        if kind == 0:
            x = x + np.array([rate, 0.0, 0.0])
        else:  # gravity turns with it
            ang = math.radians(2.0) * max(t - onset, 0.0) ** 2
            x = x + 9.8 * np.array([0.0, math.sin(ang), math.cos(ang) - 1.0])
        if rest_sample(rest, x, t, kind, k):
            released.append(t)
    assert released and max(released) < onset, released
    # a sway at 0.1 Hz, 5 deg/s: near its low-pass throughout (VQF's test alone calls it rest)
    rest = rest_init()
    n = 0
    for t, kind, x in _still_imu(12.0, np.zeros(3), g):
        w = 2 * math.pi * 0.1
        if kind == 0:
            x = x + np.array([math.radians(5.0) * math.sin(w * t), 0.0, 0.0])
        else:
            ang = math.radians(5.0) * (1 - math.cos(w * t)) / w
            x = x + 9.8 * np.array([0.0, math.sin(ang), math.cos(ang) - 1.0])
        n += rest_sample(rest, x, t, kind, k)
    assert n == 0


def test_at_rest_the_vertical_gyro_bias_is_learnt_without_vision():
    """Without vision nothing else observes the bias about the vertical: with the rest update
    the filter learns it, and the heading stops drifting."""
    c = _calib()
    R, _ = _pose()
    f_true = c.R_tool_imu.T @ R.T @ (-G)
    bias_v = c.R_tool_imu.T @ R.T @ np.array([0.0, 0.0, math.radians(1.0)])  # 1 deg/s about the vertical
    heading = {}
    for on in (True, False):
        f = TrackingFilter(c, replace(Params(), rest_bias=on, init_gyro_bias_dps=2.0), frozenset({"imu"}))
        s = f.new_state(0, R, 0.14, f_true)
        for t, kind, x in _still_imu(20.0, bias_v, f_true):
            if kind == 0:
                f.on_gyro(s, int(t * 1e9), x)
            else:
                f.on_accel(s, int(t * 1e9), x)
        dR = s.R @ R.T
        heading[on] = math.degrees(math.atan2(dR[1, 0], dR[0, 0]))
        if on:
            assert s.counts["updates:rest"] >= 30
            assert np.degrees(np.abs(s.bg - bias_v)).max() < 0.02, np.degrees(s.bg - bias_v)
        else:
            assert "updates:rest" not in s.counts
    assert abs(heading[True]) < 4.0 and abs(heading[False]) > 15.0, heading


def test_without_vision_a_rest_moves_the_bias_alone():
    """A rest measures the gyro bias. While b_rho is held (no vision tip within the offset
    window) it moves the bias only and takes no variance from the attitude through its
    correlation with the bias; with a fresh vision tip it is the full Kalman update."""
    c = _calib()
    R, _ = _pose()
    f_imu = c.R_tool_imu.T @ R.T @ (-G)
    rng = np.random.default_rng(3)
    M = rng.normal(size=(N, N))
    P0 = M @ M.T * 1e-6 + np.eye(N) * 1e-8  # every state correlated with the bias
    measured = np.radians([0.3, -0.2, 0.5])
    out = {}
    for fresh_tip in (False, True):
        f = TrackingFilter(c, Params(), frozenset({"imu", "tof", "vision"}))
        s = f.new_state(0, R, 0.14, f_imu)
        s.P[:] = P0
        s.last_tip_ns = 0 if fresh_tip else -(1 << 62)
        assert f.brho_free(s) == fresh_tip
        s.rest[25:28] = measured
        R0, p0 = s.R.copy(), s.p.copy()
        assert f.update_rest(s)
        out[fresh_tip] = (s.P.copy(), s.bg.copy(), np.abs(s.R - R0).max(), np.abs(s.p - p0).max())
    P_held, bg_held, dR_held, dp_held = out[False]
    P_free, _, dR_free, _ = out[True]
    others = np.r_[0:9, 12:N]
    # held: the bias moved towards the measurement and its variance shrank; nothing else moved
    assert np.all(np.abs(bg_held - measured) < np.abs(measured))
    assert np.trace(P_held[9:12, 9:12]) < np.trace(P0[9:12, 9:12])
    assert dR_held == 0.0 and dp_held == 0.0
    np.testing.assert_array_equal(P_held[np.ix_(others, others)], P0[np.ix_(others, others)])
    assert np.allclose(P_held, P_held.T) and np.linalg.eigvalsh(P_held).min() > 0
    # a fresh tip: the full update turns the attitude too and takes variance from it
    assert dR_free > 0.0
    assert np.trace(P_free[6:9, 6:9]) < np.trace(P0[6:9, 6:9])


def _depth(f: TrackingFilter, s) -> float:
    return float(s.R[:, 2] @ (s.p - f.rcm))


def test_without_vision_the_depth_is_drawn_to_the_working_depth_and_with_vision_follows():
    """`depth_anchor_sigma_mm`: with vision recent the working depth follows the depth (running
    mean); once vision has been away past the offset window each range draws the depth to it
    (`updates:depth_anchor`), more the smaller the sigma; 0 switches it off."""
    moved = {}
    for sigma in (0.0, 5.0, 1.0):
        f, s, R, p = _run_static(3.0, np.zeros(3), params=Params(depth_anchor_sigma_mm=sigma))
        with_vision = s.copy()
        ref0 = with_vision.depth_ref
        with_vision.p = with_vision.p + 0.010 * with_vision.R[:, 2]  # 10 mm deeper, vision recent
        for k in (1, 2):  # the first range starts the clock, the second is 10 ms after it
            with_vision.t_ns = with_vision.last_vision_ns = s.t_ns + k * 10_000_000
            f.update_tof(with_vision, _range(f.c, R, with_vision.p))
        assert with_vision.counts.get("updates:depth_anchor", 0) == 0
        if sigma > 0:  # 10 ms of a 20 s running mean: 1/2000 of the way to the depth
            step = (with_vision.depth_ref - ref0) / (_depth(f, with_vision) - ref0)
            assert step == pytest.approx(0.01 / f.prm.depth_ref_tau_s, rel=0.05)
        else:
            assert with_vision.depth_ref == ref0
        away = s.copy()
        away.last_vision_ns = away.last_tip_ns = away.t_ns - 3_000_000_000
        away.p = away.p + 0.010 * away.R[:, 2]
        L0 = _depth(f, away)
        for k in range(1, 101):  # one second of ranges that agree with the deeper tip
            away.t_ns = s.t_ns + k * 10_000_000
            f.update_tof(away, _range(f.c, R, away.p))
        moved[sigma] = L0 - _depth(f, away)
        assert away.counts.get("updates:depth_anchor", 0) == (99 if sigma > 0 else 0)  # the first starts the clock
    assert abs(moved[0.0]) < 1e-4
    assert 2e-5 < moved[5.0] < moved[1.0], moved


def test_the_pull_to_the_working_depth_is_as_tight_as_the_depth_was_steady_with_vision():
    """`depth_anchor_learn_spread`: while vision comes the pull's sigma follows the depth's
    spread about the working depth (floored at `depth_anchor_sigma_min_mm`), so a depth held
    still is then held hard, a depth that wandered only loosely; unlearnt, the sigma stays
    `depth_anchor_sigma_mm`."""
    moved, spread = {}, {}
    for learn, wobble in ((False, 0.0), (True, 0.0), (True, 0.010)):
        prm = Params(depth_anchor_learn_spread=learn, depth_ref_tau_s=2.0)
        f, s, R, p = _run_static(3.0, np.zeros(3), params=prm)
        w = s.copy()
        u, L0 = w.R[:, 2], _depth(f, w)
        for k in range(1, 2001):  # 20 s of ranges (ten running-mean times) with vision recent
            w.t_ns = w.last_vision_ns = s.t_ns + k * 10_000_000
            w.p = f.rcm + (L0 + wobble * math.sin(2 * math.pi * k / 50)) * u
            f.update_tof(w, _range(f.c, R, w.p))
        spread[learn, wobble] = math.sqrt(w.depth_var) * 1e3
        away = w.copy()
        away.last_vision_ns = away.last_tip_ns = away.t_ns - 3_000_000_000
        away.p = f.rcm + (away.depth_ref + 0.010) * u
        La = _depth(f, away)
        for k in range(1, 101):  # one second of ranges that agree with a tip 10 mm deeper
            away.t_ns = w.t_ns + k * 10_000_000
            f.update_tof(away, _range(f.c, R, away.p))
        moved[learn, wobble] = La - _depth(f, away)
    assert spread[False, 0.0] == pytest.approx(5.0)  # the parameter's, untouched
    assert spread[True, 0.0] < 0.5  # the depth held still: the spread decayed
    assert spread[True, 0.010] == pytest.approx(10 / math.sqrt(2), rel=0.3)  # a sine's RMS
    assert moved[True, 0.0] > 1.5 * moved[False, 0.0] > 1.5 * moved[True, 0.010] > 0, moved

"""The tracking error-state Kalman filter under the trocar's remote centre of motion: pure
numpy, no bus, no files.

Nominal state (`State`): tip position p and velocity v in the base frame [m, m/s], tool
orientation R_base_tool, gyro bias b_g and accelerometer bias b_a in the IMU frame [rad/s,
m/s^2], ToF range offset b_rho [m]. Error state [dp, dv, dtheta, db_g, db_a, db_rho] (16),
dtheta in tool coordinates (R = R_nom Exp(dtheta)). Propagation by the gyroscope and the raw
accelerometer, the specific force moved from the IMU to the tip (a_tip = a_I + alpha x r_I +
w x (w x r_I)); updates: gravity (down-weighted as |a| departs from g), the RCM as a 2-D
pseudo-measurement, ToF through the ray-plane model plus b_rho, vision tangent planes (shaft
direction and the axis' offset) and the junction ray (the tip, unconstrained along the line of
sight). Every update passes an innovation (chi-square) gate; counts go to `State.counts`.
Frames that pass the trocar gate but consistently fail the axis' innovation gate re-acquire
the pose from vision (`_reacquire`); without vision the tip is held at a physical depth.
Measurement times are already latency-corrected by the caller (the runner).
"""

from __future__ import annotations

import math

import numpy as np

from services.fusion.eskf.init import closest_params, initial_rotation
from services.fusion.eskf.kernels.propagate import propagate_held
from services.fusion.eskf.kernels.rest import rest_init, rest_sample
from services.fusion.eskf.kernels.so3 import cross, exp_so3
from services.fusion.eskf.kernels.steps import gravity_step, gyro_step
from services.fusion.eskf.kernels.update import finite, health, inject, update
from services.fusion.eskf.layout import (
    GK_BG_RW,
    GK_BG_RW_PER_RADPS,
    GK_BRHO_PER_RAD,
    GK_IMU_GAP_S,
    GK_MAX_POS_VAR,
    GK_MAX_SPEED2,
    GK_NO_IMU_Q,
    GK_RCM_CHI2,
    GK_RCM_VAR,
    GK_SIZE,
    GR_CHI2,
    GR_SIGMA,
    GR_SIGMA_PER_EXCESS,
    GR_SIZE,
    IBA,
    IBG,
    IBR,
    IP,
    ITH,
    IV,
    REST_RATE,
    N,
    rest_constants,
)
from services.fusion.eskf.maps import AccelMap, TofMap
from services.fusion.eskf.measurement import VisionObservation
from services.fusion.eskf.models.depth import anchor, shaft_depth
from services.fusion.eskf.models.tof import tof_jacobian
from services.fusion.eskf.models.vision import junction_ray, tangent_planes
from services.fusion.eskf.params import SENSORS, Params
from tiplog.calibration import Calibration

DEG = math.pi / 180.0


class State:
    """Nominal state, covariance and the bookkeeping a rewind must restore (copy() is exact)."""

    __slots__ = (
        "t_ns", "p", "v", "R", "bg", "ba", "brho", "P", "w_imu", "f_imu", "w_prev", "alpha_tool",
        "gyro_n", "accel_n", "last_tip_ns", "last_vision_ns", "vis_reject_run", "counts", "nis", "reacq",
        "t_init_ns", "tof_last", "depth_ref", "depth_var", "rest", "tip_held", "f_corr", "f_corr_ns", "acc", "acc_bin", "acc_t",
        "noise", "axis_seen",
    )  # fmt: skip
    # arrays a copy shares with its original: the filter replaces them, never changes them in place
    SHARED = ("w_imu", "f_imu", "f_corr", "axis_seen")

    def copy(self) -> State:
        # written out, not looped over the slots: a snapshot is taken at every gyro sample
        s = State.__new__(State)
        s.t_ns, s.brho, s.gyro_n, s.t_init_ns = self.t_ns, self.brho, self.gyro_n, self.t_init_ns
        s.accel_n, s.last_tip_ns, s.last_vision_ns = self.accel_n, self.last_tip_ns, self.last_vision_ns
        s.vis_reject_run, s.reacq, s.tof_last = self.vis_reject_run, self.reacq, self.tof_last
        s.depth_ref, s.depth_var = self.depth_ref, self.depth_var
        s.tip_held, s.w_imu, s.f_imu = self.tip_held, self.w_imu, self.f_imu
        s.f_corr, s.f_corr_ns = self.f_corr, self.f_corr_ns
        s.acc, s.acc_bin, s.acc_t = self.acc.copy(), self.acc_bin, self.acc_t
        s.noise = self.noise.copy()
        s.axis_seen = self.axis_seen
        s.p, s.v, s.R, s.P = self.p.copy(), self.v.copy(), self.R.copy(), self.P.copy()
        s.bg, s.ba, s.alpha_tool = self.bg.copy(), self.ba.copy(), self.alpha_tool.copy()
        s.rest = self.rest.copy()
        s.w_prev = list(self.w_prev)
        s.counts = dict(self.counts)
        s.nis = dict(self.nis)
        return s

    def finite(self) -> bool:
        return finite(self.p, self.R, self.P)


def _bump(d: dict, key: str, by: float = 1.0) -> None:
    d[key] = d.get(key, 0) + by


# The streams whose measurement variance follows their innovations (`TrackingFilter._adapt`):
# row of `State.noise` (variance factor, time of the stream's last innovation [ns], set aside).
ADAPTIVE = {"vision_axis": 0, "vision_tip": 1, "tof": 2}


def noise_init() -> np.ndarray:
    """`State.noise` of a filter that has seen no innovation: every factor 1, nothing set aside."""
    out = np.zeros((len(ADAPTIVE), 3))
    out[:, 0] = 1.0
    out[:, 1] = np.nan
    return out


class TrackingFilter:
    """Maths over a `State`: every method takes the state and returns/mutates it, so the runner
    can snapshot and rewind. The things kept here are the pose maps (`tof_map`, `accel_map`),
    which only grow in time; the runner cuts their tails when it rewinds. `sensors` switches
    streams off (ablation)."""

    def __init__(self, calib: Calibration, params: Params, sensors: frozenset[str] = SENSORS):
        self.c = calib
        self.prm = params
        self.imu = "imu" in sensors
        self.tof = "tof" in sensors
        self.vision = "vision" in sensors
        self.R_ti = calib.R_tool_imu
        self.r_imu_tip_tool = -calib.p_imu_tool_m  # lever arm from the IMU to the tip, tool coordinates
        self.A = calib.R_base_camera.T  # base -> camera
        self.c_cam = calib.p_base_camera_m
        self.rcm = calib.rcm_base_m
        self.rcm_cam = self.A @ (self.rcm - self.c_cam)
        self.jp = calib.junction_proximal_m - calib.vision_tip_offset_m  # offset: vision tip minus true tip, along u
        p = params
        self.q_gyro = (p.gyro_noise_dps_rthz * DEG) ** 2
        self.q_acc = p.accel_noise_mps2_rthz**2
        self.q_ba = p.accel_bias_rw_mps2_rts**2
        self.q_brho = (p.tof_offset_rw_mm_rts * 1e-3) ** 2
        self.rcm_var = (p.rcm_sigma_mm * 1e-3) ** 2
        self._tof_r = np.array([(p.tof_sigma_mm * 1e-3) ** 2])
        self._tof_r_held = np.array([(p.tof_sigma_held_mm * 1e-3) ** 2])
        self.plane_var = (p.vision_plane_sigma_deg * DEG) ** 2
        self.offset_var = (p.vision_offset_sigma_mm * 1e-3) ** 2
        self._revisit_ns = p.vision_axis_revisit_window_s * 1e9
        self._revisit_k = 0.5 / np.array(
            [(p.vision_axis_revisit_sigma_deg * DEG) ** 2, (p.vision_axis_revisit_sigma_mm * 1e-3) ** 2]
        )
        self.ray_var = (p.vision_ray_sigma_mm * 1e-3) ** 2
        self._adapt_tau_s = p.noise_adapt_tau_s
        self._adapt_max = p.noise_adapt_max
        self._adapt_dt_max_s = p.noise_adapt_step_max_ms * 1e-3
        self._tip_power = p.noise_adapt_tip_power
        self._grav_k = np.empty(GR_SIZE)
        self._grav_k[GR_SIGMA] = p.gravity_sigma_deg * DEG
        self._grav_k[GR_SIGMA_PER_EXCESS] = p.gravity_sigma_per_excess * DEG
        self._grav_k[GR_CHI2] = p.gate_chi2_3
        Q = np.zeros(N)
        if self.imu:
            Q[IV] = self.q_acc
            Q[ITH] = self.q_gyro
            Q[IBA] = self.q_ba
        else:
            Q[IV] = p.no_imu_accel_rw_mps2_rts**2
            Q[ITH] = (p.no_imu_rate_rw_dps_rts * DEG) ** 2
        Q[IBR] = self.q_brho
        self._Q = Q  # per second; the gyro-bias entries are set per step (they grow with |w|)
        self._Q_held = Q.copy()  # while b_rho is held its uncertainty is too: the ToF stays informative
        self._Q_held[IBR] = 0.0
        self._brho_window_ns = p.tof_offset_window_ms * 1e6
        self._map_settle_ns = p.tof_map_settle_ms * 1e6
        self._tof_fresh_ns = 100e6  # the ToF range a junction is checked against: at most this old
        k = self._gyro_k = np.empty(GK_SIZE)
        k[GK_BG_RW] = p.gyro_bias_rw_dps_rts * DEG
        k[GK_BG_RW_PER_RADPS] = p.gyro_bias_rw_dps_rts_per_radps * DEG
        k[GK_IMU_GAP_S] = p.imu_gap_ms * 1e-3
        k[GK_NO_IMU_Q] = p.no_imu_accel_rw_mps2_rts**2
        k[GK_RCM_VAR] = self.rcm_var
        k[GK_RCM_CHI2] = p.gate_chi2_2
        k[GK_MAX_POS_VAR] = (p.max_position_sigma_mm * 1e-3) ** 2
        k[GK_MAX_SPEED2] = p.max_speed_mps**2
        k[GK_BRHO_PER_RAD] = p.tof_offset_rw_mm2_per_deg * 1e-6 / DEG
        self._alpha_min_span_ns = p.alpha_min_span_ms * 1e6
        self.rest_on = self.imu and p.rest_bias
        self._rest_k = rest_constants(
            p.rest_tau_ms * 1e-3, p.rest_th_gyro_dps * DEG, p.rest_th_accel_mps2, p.rest_min_ms * 1e-3,
            p.rest_chunk_ms * 1e-3, p.imu_gap_ms * 1e-3, p.rest_agree_gyro_dps * DEG, p.rest_agree_accel_mps2,
        )  # fmt: skip
        # what the compiled steps take: the detector's constants, or none (empty) when it is off
        self._no_rest_k = np.zeros(0)
        self._rest_k_on = self._rest_k if self.rest_on else self._no_rest_k
        # the chunk mean's variance: white rate noise over the chunk, plus the slack
        self._rest_var = np.full(3, self.q_gyro / (p.rest_chunk_ms * 1e-3) + (p.rest_sigma_dps * DEG) ** 2)
        self._rest_H = np.zeros((3, N))  # the chunk's mean rate measures b_g
        self._rest_H[:, IBG] = np.eye(3)
        # a gyro sample's propagation through `propagate` (the smoother records every step
        # there), not inside the compiled gyro step: the same result, slower
        self.propagate_apart = False
        self.tof_map = (
            TofMap(
                p.tof_map_sigma_deg,
                p.tof_map_sigma_mm,
                p.tof_map_bin_ms,
                p.tof_map_window_s,
                p.tof_map_prior_weight,
                rewind_ms=p.history_ms,
                far_sigma_deg=p.tof_map_far_sigma_deg,
                far_sigma_mm=p.tof_map_far_sigma_mm,
                far_weight=p.tof_map_far_weight,
                mean_weight=p.tof_map_mean_weight,
                gp_bins=p.tof_map_gp_bins,
                gp_sigma_mm=p.tof_map_gp_sigma_mm,
                gp_noise_mm=p.tof_map_gp_noise_mm,
            )
            if p.tof_map and self.tof and self.vision
            else None
        )
        self.accel_map = (
            AccelMap(
                p.accel_map_sigma_deg, p.accel_map_sigma_mm, p.accel_map_bin_ms, p.accel_map_window_s,
                p.accel_map_prior_weight,
            )
            if p.accel_map and self.imu and self.vision
            else None
        )  # fmt: skip
        # the pose maps kept here, those switched on: the runner cuts their tails when it
        # rewinds and forgets what a diverging state taught them
        self.maps = tuple(m for m in (self.tof_map, self.accel_map) if m is not None)
        self._accel_map_every_ns = int(p.accel_map_every_ms * 1e6)
        self._accel_bin_ns = int(p.accel_map_bin_ms * 1e6)

    # ------------------------------------------------------------------ initialisation
    def new_state(self, t_ns: int, R: np.ndarray, depth_m: float, f_imu: np.ndarray | None) -> State:
        p = self.prm
        s = State()
        s.t_ns = s.t_init_ns = int(t_ns)
        s.R = R.copy()
        s.p = self.rcm + depth_m * R[:, 2]
        s.v = np.zeros(3)
        s.bg = np.zeros(3)
        s.ba = np.zeros(3)
        s.brho = 0.0
        s.depth_ref = float(depth_m)
        s.depth_var = (p.depth_anchor_sigma_mm * 1e-3) ** 2  # the spread before vision showed one
        d = np.empty(N)
        d[IP] = (p.init_position_mm * 1e-3) ** 2
        d[IV] = p.init_velocity_mps**2
        d[ITH] = (p.init_attitude_deg * DEG) ** 2
        d[IBG] = (p.init_gyro_bias_dps * DEG) ** 2
        d[IBA] = p.init_accel_bias_mps2**2
        d[IBR] = (p.init_tof_offset_mm * 1e-3) ** 2
        s.P = np.diag(d)
        s.w_imu = np.zeros(3)
        s.f_imu = np.zeros(3) if f_imu is None else np.asarray(f_imu, float).copy()
        s.w_prev = []
        s.alpha_tool = np.zeros(3)
        s.rest = rest_init()
        s.gyro_n = 0
        s.accel_n = 0
        s.last_tip_ns = -(1 << 62)
        s.last_vision_ns = -(1 << 62)
        s.vis_reject_run = 0
        s.counts = {}
        s.nis = {}
        s.tof_last = (-(1 << 62), 0.0)  # (t_ns, range_m) of the last ToF range applied
        s.reacq = ()  # (t_ns, phi_base (3,), dp_base_m (3,)) of frames gated out on innovation
        s.tip_held = None  # (t_ns, residual_cam_m (3,), replaced a dropped one) of a tip awaiting confirmation
        s.f_corr = np.zeros(3)  # the accelerometer map's correction taken off each sample (IMU frame)
        s.f_corr_ns = -(1 << 62)
        s.acc = np.zeros(16)  # the accelerometer map's open bin (`kernels.steps.gravity_step`)
        s.acc_bin = -(1 << 62)  # which bin (time // bin length) it is
        s.acc_t = 0  # its last sample's time
        s.noise = noise_init()
        s.axis_seen = np.zeros((0, 7))  # (t_ns, shaft direction (3,), tip (3,)) of the axis frames applied
        return s

    def init_from_vision(self, t_ns: int, obs: VisionObservation, f_imu: np.ndarray | None) -> State | None:
        """A state from one vision frame with a visible junction (shaft direction from the mean
        tangent plane and the plane through the RCM and the junction ray, depth from the ray),
        roll from the accelerometer's gravity; None when the frame cannot serve."""
        if not obs.junction_visible:
            return None
        n_l, n_r, d = obs.n_left, obs.n_right, obs.ray
        rho = self.c.shaft_radius_m
        if max(abs(n_l @ self.rcm_cam - rho), abs(n_r @ self.rcm_cam - rho)) > self.prm.trocar_gate_mm * 1e-3:
            return None
        m = n_l + n_r
        q = cross(self.rcm_cam, d)
        u_c = cross(m, q)
        nu = np.linalg.norm(u_c)
        if nu < 1e-9:
            return None
        u_c /= nu
        s_axis, t_ray = closest_params(self.rcm_cam, u_c, d)
        if s_axis < 0:
            u_c, s_axis = -u_c, -s_axis
        depth = s_axis + self.jp
        if not (0.02 < depth < 0.4):
            return None
        u = self.A.T @ u_c
        R = initial_rotation(u, f_imu, self.R_ti)
        s = self.new_state(t_ns, R, depth, f_imu)
        s.last_tip_ns = s.last_vision_ns = int(t_ns)
        return s

    def start_from_vision(
        self, t_ns: int, obs: VisionObservation, f_imu: np.ndarray | None, tof: tuple[int, float] | None, refused: int
    ) -> tuple[State | None, int]:
        """`init_from_vision`, but a start whose junction depth the latest ToF range (b_rho taken
        as zero) puts further than `vision_tip_tof_gate_mm` away is refused, as a tip would be:
        one frame's shaft can be degrees off where its junction ray nearly meets the trocar in the
        image, and a start that far off diverges before vision can correct it. After
        `reset_after_vision_rejections` refusals in a row the ToF is not believed and the frame
        starts. Returns (the state or None, the refusals in a row so far)."""
        cand = self.init_from_vision(t_ns, obs, f_imu)
        if cand is None:
            return None, refused
        fresh = tof is not None and t_ns - tof[0] <= self._tof_fresh_ns
        if fresh and refused < self.prm.reset_after_vision_rejections:
            if self._junction_off_range(cand.R, 0.0, tof[1], self.A @ cand.R[:, 2], obs.ray):
                return None, refused + 1
        return cand, 0

    # ------------------------------------------------------------------ propagation
    def propagate(self, s: State, t_ns: int) -> None:
        """Nominal state and covariance forward to t_ns with the latest gyro/accel samples held."""
        dt = (t_ns - s.t_ns) * 1e-9
        if dt <= 0.0:
            return
        s.t_ns = int(t_ns)
        propagate_held(
            s.p, s.v, s.R, s.P, s.bg, s.ba, s.w_imu, s.f_imu, s.alpha_tool, self.R_ti, self.r_imu_tip_tool,
            self._Q if self.brho_free(s) else self._Q_held, self._gyro_k, dt, self.imu,
        )  # fmt: skip

    def _advance(self, s: State, t_ns: int) -> float:
        """The state's clock to t_ns for a compiled step (`kernels.steps`: `gyro_step`, `gravity_step`):
        returns the dt [s] that step is to propagate over, or 0 after propagating here when
        each step's propagation must come apart (`propagate_apart`)."""
        if self.propagate_apart:
            self.propagate(s, t_ns)
            return 0.0
        dt = (t_ns - s.t_ns) * 1e-9
        if dt > 0.0:
            s.t_ns = int(t_ns)
        return dt

    def on_gyro(self, s: State, t_ns: int, w_imu: np.ndarray) -> str | None:
        """Propagate to t_ns with the held samples, take the new rate (and the angular
        acceleration over the last `alpha_window` samples), and every `rcm_every`-th sample the
        RCM update (the shaft line through the registered RCM, (R^T (r - p))_xy = 0, 2-D): one
        compiled call (`kernels.steps.gyro_step`), the same maths as `propagate` and `_update`.
        Returns why the state must be reset (`diverged`), or None."""
        dt = self._advance(s, t_ns)
        free = self.brho_free(s)
        w = w_old = s.w_imu
        dt_alpha = -1.0  # alpha unchanged until the window is full
        if self.imu:
            w = np.asarray(w_imu, float)
            s.w_prev.append((int(t_ns), w))
            if len(s.w_prev) > self.prm.alpha_window:
                t0, w_old = s.w_prev.pop(0)
                span = t_ns - t0
                # stamps bunched by a stalled host: no angular acceleration from them
                dt_alpha = span * 1e-9 if span >= self._alpha_min_span_ns else 0.0
        s.gyro_n += 1
        do_rcm = s.gyro_n % self.prm.rcm_every == 0
        status, nis, dbrho, hl, rest = gyro_step(
            s.p, s.v, s.R, s.P, s.bg, s.ba, s.w_imu, s.f_imu, s.alpha_tool, self.R_ti, self.r_imu_tip_tool,
            self._Q if free else self._Q_held, self._gyro_k, dt, self.imu, w, w_old, dt_alpha, self.rcm, do_rcm,
            not free, s.rest, t_ns * 1e-9, self._rest_k_on,
        )  # fmt: skip
        s.w_imu = w
        if status == 0:
            s.counts["updates:rcm"] = s.counts.get("updates:rcm", 0) + 1
            s.nis["rcm"] = s.nis.get("rcm", 0) + nis
            s.brho += dbrho
        elif status == 1:
            s.counts["rejected:rcm:innovation"] = s.counts.get("rejected:rcm:innovation", 0) + 1
        if rest:
            self.update_rest(s)
        if not self.vision:
            self._clamp_depth(s)
        return self._why(hl, s)

    def on_accel(self, s: State, t_ns: int, f_imu: np.ndarray) -> None:
        """Hold the sample for propagation; every `gravity_every`-th sample, the gravity update
        at the state's time (at most one gyro period earlier: far below its noise)."""
        if not self.imu:
            return
        s.f_imu = np.asarray(f_imu, float)
        amap = self.accel_map
        if amap is not None:
            if t_ns - s.f_corr_ns >= self._accel_map_every_ns:
                s.f_corr_ns = int(t_ns)
                s.f_corr = amap.predict(t_ns, s.R, s.p)
            s.f_imu = s.f_imu - s.f_corr
        s.accel_n += 1
        every = self.prm.gravity_every
        if not every or s.accel_n % every:
            if self.rest_on:
                rest_sample(s.rest, s.f_imu, t_ns * 1e-9, 1, self._rest_k)
            return
        self.update_gravity(s, self._advance(s, t_ns), t_ns * 1e-9)

    # ------------------------------------------------------------------ updates
    def brho_free(self, s: State) -> bool:
        """Whether b_rho may move: only while vision gave an independent tip within the offset
        window. Otherwise no update moves it, not even through its correlation with the tip (a
        vision axis or RCM update would otherwise carry the ToF's depth error into b_rho and
        the depth would walk away without a junction in view)."""
        return self.vision and (s.t_ns - s.last_tip_ns) <= self._brho_window_ns

    def _gain(self, s: State) -> tuple[int, int]:
        """The error states an update gives gain by default (`kernels.update.update`'s lo, hi): all but
        a held b_rho."""
        return 0, N if self.brho_free(s) else N - 1  # `kernels.update.gain_hi`, without a compiled call

    def _update(
        self, s: State, H: np.ndarray, y: np.ndarray, r_var: np.ndarray, chi2: float, name: str,
        gain: tuple[int, int] | None = None, scaled: bool = False, adapt: bool = True, weigh: float = 1.0,
    ) -> bool:  # fmt: skip
        """`kernels.update.update`, the error states given gain (lo, hi) by default `_gain(s)`. An
        `ADAPTIVE` stream's variance is scaled by its factor, which its innovation then updates;
        while the stream is set aside its innovation is only watched. `scaled`: r_var is
        already scaled and this innovation already counted (a held tip applied); `adapt`
        False: scaled, but the innovation does not move the factor; `weigh`: the update applied
        with its variance times this, gated and noise-matched on its own (`_update_weighed`)."""
        lo, hi = gain if gain is not None else self._gain(s)
        i = None if scaled else ADAPTIVE.get(name)
        aside = False
        if i is not None:
            r_var = r_var * s.noise[i, 0]
            aside = s.noise[i, 2] != 0.0
        if weigh != 1.0 and not aside:
            return self._update_weighed(s, H, y, r_var, chi2, name, lo, hi, weigh, i is not None and adapt)
        status, nis, dx = update(s.P, H, y, r_var, -1.0 if aside else chi2, lo, hi)
        if i is not None and adapt:
            self._adapt(s, name, nis, len(y), chi2)
        if status:
            _bump(s.counts, f"rejected:{name}:{'set_aside' if aside else 'innovation'}")
            return False
        self._apply(s, name, nis, dx)
        return True

    def _update_weighed(
        self, s: State, H: np.ndarray, y: np.ndarray, r_var: np.ndarray, chi2: float, name: str, lo: int, hi: int,
        weigh: float, adapt: bool,
    ) -> bool:  # fmt: skip
        """An update whose gain is that of r_var * weigh while its gate and its noise matching see
        the innovation against r_var: the weight says how much a frame adds to frames already
        taken (`_revisit`), not that the frame is noisier, so it must not widen the gate nor
        teach the stream's factor a smaller noise."""
        nis = update(s.P, H, y, r_var, -1.0, lo, hi)[1]  # measured only
        if adapt:
            self._adapt(s, name, nis, len(y), chi2)
        status, _, dx = update(s.P, H, y, r_var * weigh, math.inf, lo, hi) if nis <= chi2 else (1, nis, None)
        if status:
            _bump(s.counts, f"rejected:{name}:innovation")
            return False
        self._apply(s, name, nis, dx)
        return True

    def _adapt(self, s: State, name: str, nis: float, m: int, gate: float) -> None:
        """Innovation-based noise matching of one `ADAPTIVE` stream: its variance factor
        lambda follows the stream's NIS per degree of freedom z (computed with lambda R, capped
        at the gate's gate/m so that one gross outlier moves it little): lambda <- lambda (1 +
        a (z - 1)), a = dt / noise_adapt_tau_s (dt since the stream's previous innovation, at
        most noise_adapt_step_max_ms), kept within [1, noise_adapt_max]. A stream as noisy as
        assumed stays at 1 (its NIS averages at most m); one k times noisier in variance settles
        near k, so that it is weighed less instead of being gated out frame after frame. At the
        ceiling the stream is set aside (its updates not applied, its innovations still
        watched), and it returns once lambda has fallen to half the ceiling."""
        tau = self._adapt_tau_s
        if not tau > 0.0:
            return
        row = s.noise[ADAPTIVE[name]]
        last, row[1] = row[1], float(s.t_ns)
        if last != last:
            return
        a = min(1.0, min(max(s.t_ns - last, 0.0) * 1e-9, self._adapt_dt_max_s) / tau)
        z = min(nis / m, gate / m) if nis == nis else gate / m
        lam = min(max(row[0] * (1.0 + a * (z - 1.0)), 1.0), self._adapt_max)
        row[0] = lam
        if row[2] == 0.0 and lam >= self._adapt_max:
            row[2] = 1.0
            _bump(s.counts, f"set_aside:{name}")
        elif row[2] != 0.0 and lam <= 0.5 * self._adapt_max:
            row[2] = 0.0
            _bump(s.counts, f"returned:{name}")

    def _apply(self, s: State, name: str, nis: float, dx: np.ndarray) -> None:
        _bump(s.counts, f"updates:{name}")
        _bump(s.nis, name, nis)
        s.brho += inject(s.p, s.v, s.R, s.bg, s.ba, dx, s.P)

    def _update_tip(self, s: State, H: np.ndarray, y: np.ndarray, resid_cam: np.ndarray) -> bool:
        """The junction ray's update, a surprising one only once confirmed. A tip whose NIS
        passes the gate but exceeds `tip_confirm_chi2` is held; it is applied when the next
        tip (within `tip_confirm_ms`) is as surprising in the same way (the two residuals,
        tip to ray in camera coordinates, within `tip_confirm_mm`), and dropped otherwise
        (`rejected:vision_tip:unconfirmed`). Why: the labeler's rare gross junction errors (millimetres
        to centimetres along the shaft) pass the gate once the depth has grown uncertain between
        frames, and, without the ToF, the velocity they leave carries the tip away while the
        true junctions that follow are gated out.
        At most two tips in a row wait: a surprising tip that disagrees with a held one that
        had itself replaced a dropped one is applied, so a state moving fast against vision
        (without the IMU, or after a gross error got in) is never left to vision's gate alone."""
        prm = self.prm
        row = s.noise[ADAPTIVE["vision_tip"]]
        lam = row[0]
        weigh = lam**self._tip_power if lam > 1.0 else lam
        r_var = np.full(2, self.ray_var * weigh)
        # the factor follows the NIS under lambda R, whatever the tip is weighed with (the
        # kernel at a negative gate only measures it, as for a stream set aside)
        nis_lam = update(s.P, H, y, np.full(2, self.ray_var * lam), -1.0, 0, N)[1] if weigh != lam else None
        held, s.tip_held = s.tip_held, None
        gate = prm.gate_chi2_2
        if row[2] != 0.0:  # set aside: watched only
            status, nis, _ = update(s.P, H, y, r_var, -1.0, *self._gain(s))
            self._adapt(s, "vision_tip", nis if nis_lam is None else nis_lam, 2, gate)
            _bump(s.counts, "rejected:vision_tip:set_aside")
            return False
        # switched off (0) or at the gate, nothing passes the gate and fails the confirmation
        confirm = prm.tip_confirm_chi2 if 0.0 < prm.tip_confirm_chi2 < gate else gate
        status, nis, dx = update(s.P, H, y, r_var, confirm, *self._gain(s))
        self._adapt(s, "vision_tip", nis if nis_lam is None else nis_lam, 2, gate)
        if status == 0:
            if held is not None:
                _bump(s.counts, "rejected:vision_tip:unconfirmed")
            self._apply(s, "vision_tip", nis, dx)
            return True
        if not nis <= gate:
            s.tip_held = held  # an outlier of its own: the held tip still waits for the next
            _bump(s.counts, "rejected:vision_tip:innovation")
            return False
        if held is not None and s.t_ns - held[0] > prm.tip_confirm_ms * 1e6:
            _bump(s.counts, "rejected:vision_tip:unconfirmed")
            held = None
        if held is not None:
            agree = float(np.linalg.norm(resid_cam - held[1])) <= prm.tip_confirm_mm * 1e-3
            if not agree:
                _bump(s.counts, "rejected:vision_tip:unconfirmed")
            if agree or held[2]:
                return self._update(s, H, y, r_var, gate, "vision_tip", scaled=True)
        s.tip_held = (s.t_ns, resid_cam, held is not None)
        _bump(s.counts, "deferred:vision_tip")
        return False

    def update_gravity(self, s: State, dt: float = 0.0, rest_t_s: float | None = None) -> bool:
        """Specific force at the IMU against gravity plus the lever arm's centripetal and
        tangential terms (the shaft's point at the port taken at rest: `models.rcm.port_lever`),
        down-weighted as |f| leaves g, after
        propagating over dt [s] (the state's time already set): one compiled call
        (`kernels.steps.gravity_step`). With rest_t_s [s], the sample also goes through the rest
        detector first (`on_accel`: one call for both)."""
        free = self.brho_free(s)
        amap = self.accel_map
        max_excess = -1.0  # recorded for the accelerometer's map: only while b_rho is free
        if amap is not None:
            b = s.t_ns // self._accel_bin_ns
            if b != s.acc_bin:  # a new bin: the last one goes to the map
                if s.acc[15] > 0.0:
                    amap.add_bin(s.acc_t, s.acc)
                    s.acc = np.zeros(16)
                s.acc_bin = b
            if free and s.t_ns - s.t_init_ns >= self._map_settle_ns:  # not from a state still converging
                max_excess = self.prm.accel_map_max_excess
        status, nis, dbrho, recorded = gravity_step(
            s.p, s.v, s.R, s.P, s.bg, s.ba, s.w_imu, s.f_imu, s.alpha_tool, self.R_ti, self.r_imu_tip_tool,
            self._Q if free else self._Q_held, self._gyro_k, dt, self._grav_k, not free, self.rcm,
            s.acc, s.f_corr, max_excess, s.rest, -1.0 if rest_t_s is None else rest_t_s,
            self._rest_k_on if rest_t_s is not None else self._no_rest_k,
        )  # fmt: skip
        if recorded:
            s.acc_t = s.t_ns
        if status:
            s.counts["rejected:gravity:innovation"] = s.counts.get("rejected:gravity:innovation", 0) + 1
            return False
        s.counts["updates:gravity"] = s.counts.get("updates:gravity", 0) + 1
        s.nis["gravity"] = s.nis.get("gravity", 0) + nis
        s.brho += dbrho
        return True

    def update_rest(self, s: State) -> bool:
        """The tool at rest: the mean gyro rate over a chunk of rest (`kernels.rest.rest_sample`)
        is the bias, w = b_g. The gate turns away a slow steady turn taken for rest once the
        bias is known better than that turn's rate. While b_rho is held (no vision tip within
        the offset window) it moves the gyro bias alone (`rest_bias_only`): a Schmidt update,
        no gain on any other state, so that no other state's variance shrinks through its
        correlation with the bias. Without vision the heading's error is mostly not the bias's
        doing (the ToF's and the accelerometer's pose-locked errors turn it too), and a rest
        between blocks would shrink the heading's sigma several times while the heading itself
        stayed tens of degrees off, and a heading that sure of itself cannot be pulled back."""
        gain = (IBG.start, IBG.stop) if self.prm.rest_bias_only and not self.brho_free(s) else None
        return self._update(
            s,
            self._rest_H,
            s.rest[REST_RATE : REST_RATE + 3] - s.bg,
            self._rest_var,
            self.prm.gate_chi2_3,
            "rest",
            gain,
        )

    def update_tof(self, s: State, range_m: float) -> bool:
        """Raw range through the ray-plane model rho = (h - m.(p + R o)) / (m.(R b)) + b_rho;
        b_rho moves only while vision gave an independent tip within the offset window."""
        if not self.tof:
            return False
        c = self.c
        H, rho, den = tof_jacobian(
            s.R, s.p, s.brho, c.tof_plane_normal_base, c.tof_plane_h_m, c.tof_origin_tool_m, c.tof_beam_tool
        )
        if den < 0.05:
            _bump(s.counts, "rejected:tof:grazing")
            return False
        free = self.brho_free(s)
        tmap = self.tof_map
        record = None
        r_var = self._tof_r
        if not free:
            # the pose-locked error is unmodelled where the map learnt nothing (or there is no
            # map), so the held variance grows by up to `tof_unmapped_var_factor` there
            unmapped = 1.0
            if tmap is not None:
                prior = tmap.far_prior(s.t_ns, s.R, s.p, s.brho) if self.prm.tof_map_far else s.brho
                c, weight = tmap.predict(s.t_ns, s.R, s.p, prior)
                rho += c - s.brho
                w0 = tmap.prior_weight
                unmapped = w0 / (weight + w0) if weight + w0 > 0 else 1.0
            r_var = self._tof_r_held * (1.0 + self.prm.tof_unmapped_var_factor * unmapped)
        elif tmap is not None and s.t_ns - s.t_init_ns >= self._map_settle_ns:  # not from a state still converging
            record = s.t_ns, tmap.key(s.R, s.p), range_m - (rho - s.brho)
        y = np.array([range_m - rho])
        dt_tof = (s.t_ns - s.tof_last[0]) * 1e-9  # since the last range applied
        # the range's innovations tell of its noise only while vision tips tie the depth: held,
        # they carry the state's own drift (a heading lost in a blackout), and a factor grown
        # from that would loosen the one sensor left holding the depth
        ok = self._update(s, H, y, r_var, self.prm.gate_chi2_1, "tof", adapt=free)
        self._anchor_depth(s, dt_tof)
        if ok:
            s.tof_last = (s.t_ns, range_m)
            if record is not None:
                tmap.add(*record)
            elif tmap is not None and not free and weight >= tmap.prior_weight:  # mostly the map's
                _bump(s.counts, "updates:tof_mapped")
        return ok

    def _anchor_depth(self, s: State, dt_s: float) -> None:
        """The working depth, at each ToF range (dt_s since the last one applied): while vision
        was applied within the offset window the reference follows the depth (a running mean
        over `depth_ref_tau_s`); without vision the depth is drawn to it, `depth_anchor_sigma_mm`
        per `depth_anchor_tau_s` (the pseudo-measurement's variance scaled by tau / dt, so that
        its information per second does not depend on the ToF's rate).

        Without vision the range sees the heading only mixed with the depth (about 2.2 mm of
        depth per degree on the paper's layout), and the accelerometer holds the depth for well
        under a second, so the range's changes went into the depth while the gyro's bias walked
        the heading away. The operator keeps a working depth (the paper: 130-150 mm, 85-99 % of
        the time); with the depth drawn to it, a slow change of the range turns the heading back
        and only the depth's faster excursions are left to the ToF."""
        prm = self.prm
        if prm.depth_anchor_sigma_mm <= 0.0 or not 0.0 < dt_s < 1.0:
            return
        L = shaft_depth(s.R, s.p, self.rcm)
        if self.vision and s.t_ns - s.last_vision_ns <= self._brho_window_ns:
            a = min(1.0, dt_s / prm.depth_ref_tau_s)
            dev = L - s.depth_ref
            s.depth_ref += a * dev
            if prm.depth_anchor_learn_spread:
                s.depth_var += a * (dev * dev - s.depth_var)
            return
        H, y = anchor(s.R, L, s.depth_ref)
        var = max(s.depth_var, (prm.depth_anchor_sigma_min_mm * 1e-3) ** 2)
        r_var = np.array([var * prm.depth_anchor_tau_s / dt_s])
        self._update(s, H, y, r_var, math.inf, "depth_anchor")

    def _tip_disagrees_with_tof(self, s: State, u_c: np.ndarray, d: np.ndarray, R: np.ndarray | None = None) -> bool:
        """Whether the junction ray puts the tip on the present shaft line (or on the shaft at
        attitude R: a candidate pose) further than `vision_tip_tof_gate_mm` from the latest ToF
        range's depth (`_junction_off_range`; only while b_rho is free, so current). The
        labeler's gross junction errors (a wrong end of the shaft, 5-25 mm) pass the chi-square
        gate when the depth has grown uncertain between frames; the ToF is the independent depth
        that tells them apart."""
        if not self.brho_free(s) or s.t_ns - s.tof_last[0] > self._tof_fresh_ns:
            return False
        return self._junction_off_range(s.R if R is None else R, s.brho, s.tof_last[1], u_c, d)

    def _junction_off_range(self, R: np.ndarray, brho: float, range_m: float, u_c: np.ndarray, d: np.ndarray) -> bool:
        """Whether the depth the junction ray d implies on the shaft at attitude R (direction u_c,
        camera coordinates) is further than `vision_tip_tof_gate_mm` from the depth of the range
        range_m less the offset brho; never where the gate is 0, without the ToF, or where the
        beam or the shaft grazes the ToF's plane."""
        gate = self.prm.vision_tip_tof_gate_mm * 1e-3
        if gate <= 0 or not self.tof:
            return False
        c = self.c
        m = c.tof_plane_normal_base
        mu, mb = float(m @ R[:, 2]), float(m @ (R @ c.tof_beam_tool))
        if abs(mu) < 0.2 or abs(mb) < 0.05:
            return False
        L_tof = (c.tof_plane_h_m - float(m @ (self.rcm + R @ c.tof_origin_tool_m)) - (range_m - brho) * mb) / mu
        L_vis = closest_params(self.rcm_cam, u_c, d)[0] + self.jp
        return abs(L_vis - L_tof) > gate

    def _clamp_depth(self, s: State) -> None:
        """The tip back to the physical insertion range along the shaft (depth_min/max_m)."""
        L = shaft_depth(s.R, s.p, self.rcm)
        Lc = min(max(L, self.prm.depth_min_m), self.prm.depth_max_m)
        if Lc != L:
            s.p = s.p + (Lc - L) * s.R[:, 2]
            _bump(s.counts, "clamped:depth")

    def update_vision(self, s: State, obs: VisionObservation) -> bool:
        """One accepted frame (camera frame: normals n_left/n_right, junction ray): tangent
        planes (direction and offset of the axis) if the frame passes the trocar gate, the
        junction ray (tip) if visible and well conditioned."""
        if not self.vision:
            return False
        prm = self.prm
        A = self.A
        n = np.stack([obs.n_left, obs.n_right])
        rho = self.c.shaft_radius_m
        cam = self.c_cam
        gate = np.abs(n @ self.rcm_cam - rho).max()
        passed = gate <= prm.trocar_gate_mm * 1e-3
        applied = False
        if passed:
            H, y = tangent_planes(s.R, s.p, n, A, cam, rho)
            r = np.array([self.plane_var, self.plane_var, self.offset_var, self.offset_var])
            if self._update(s, H, y, r, prm.gate_chi2_4, "vision_axis", weigh=self._revisit(s)):
                applied = True
                if prm.vision_axis_revisit_weight > 0:
                    s.axis_seen = np.vstack([s.axis_seen, np.concatenate([[s.t_ns], s.R[:, 2], s.p])])
                s.reacq = ()
            elif self._reacquire(s, obs):
                return True
        else:
            _bump(s.counts, "rejected:vision_axis:trocar_gate")
        if obs.junction_visible and (passed or prm.gated_out_tip):
            d = obs.ray
            u_c = A @ s.R[:, 2]
            if 1.0 - float(d @ u_c) ** 2 < prm.junction_min_sin2:
                _bump(s.counts, "rejected:vision_tip:ill_conditioned")
            elif self._tip_disagrees_with_tof(s, u_c, d):
                _bump(s.counts, "rejected:vision_tip:tof_disagrees")
            else:
                H, y, resid_cam = junction_ray(s.R, s.p, d, A, cam, self.jp)
                if self._update_tip(s, H, y, resid_cam):
                    s.last_tip_ns = s.t_ns
                    applied = True
        s.vis_reject_run = 0 if applied else s.vis_reject_run + 1
        if applied:
            s.last_vision_ns = s.t_ns
        return applied

    def _revisit(self, s: State) -> float:
        """The axis frame's variance factor, 1 + `vision_axis_revisit_weight` times the summed
        Gaussian kernel weight, in shaft direction and tip position, of the axis frames applied
        within `vision_axis_revisit_window_s` (older ones are dropped here). Why: the planes'
        error is mostly pose-locked, so frames at one pose share it. The fixed inflation of
        `vision_plane_sigma_deg` suits a path that moves on; at a held attitude (a depth sweep,
        a hold, an oscillation of a few degrees) the state would settle on that pose's error."""
        w = self.prm.vision_axis_revisit_weight
        if not w > 0:
            return 1.0
        seen = s.axis_seen
        if len(seen) and seen[0, 0] <= s.t_ns - self._revisit_ns:
            seen = s.axis_seen = seen[seen[:, 0] > s.t_ns - self._revisit_ns]
        if not len(seen):
            return 1.0
        du = seen[:, 1:4] - s.R[:, 2]
        dp = seen[:, 4:7] - s.p
        d2 = self._revisit_k[0] * np.einsum("ij,ij->i", du, du) + self._revisit_k[1] * np.einsum("ij,ij->i", dp, dp)
        return 1.0 + w * float(np.exp(-d2).sum())

    def _reacquire(self, s: State, obs: VisionObservation) -> bool:
        """A frame that passes the trocar gate but fails the axis' innovation gate: the
        correction vision asks for (rotation phi [rad] taking the shaft onto the frame's, tip
        shift dp [m], base frame) is kept; once `reacquire_frames` such frames within the window
        ask for the same correction, it is applied with the position/velocity/attitude
        covariance reset to its initial values (biases kept): vision re-acquires the heading
        after a blackout instead of waiting for the divergence reset. True when applied."""
        prm = self.prm
        if prm.reacquire_frames < 1 or not obs.junction_visible:
            return False
        cand = self.init_from_vision(s.t_ns, obs, None)
        if cand is None:
            return False
        if self._tip_disagrees_with_tof(s, self.A @ cand.R[:, 2], obs.ray, cand.R):
            _bump(s.counts, "rejected:reacquire:tof_disagrees")  # a gross junction error, not a lost state
            return False
        u, u_c = s.R[:, 2], cand.R[:, 2]
        ax = cross(u, u_c)
        sn = float(np.linalg.norm(ax))
        phi = ax * (math.atan2(sn, float(u @ u_c)) / sn) if sn > 1e-12 else np.zeros(3)
        keep = [e for e in s.reacq if s.t_ns - e[0] <= prm.reacquire_window_ms * 1e6]
        keep.append((s.t_ns, phi, cand.p - s.p))
        s.reacq = tuple(keep[-int(prm.reacquire_frames) :])
        if len(s.reacq) < prm.reacquire_frames:
            return False
        phis = np.array([e[1] for e in s.reacq])
        dps = np.array([e[2] for e in s.reacq])
        if (np.abs(phis - phis.mean(0)).max() > prm.reacquire_agree_deg * DEG
                or np.abs(dps - dps.mean(0)).max() > prm.reacquire_agree_mm * 1e-3):  # fmt: skip
            return False
        s.R = exp_so3(phi) @ s.R  # the latest frame's correction, roll carried along
        s.p = s.p + dps[-1]
        s.v = np.zeros(3)
        init = self.new_state(s.t_ns, s.R, 0.1, None).P
        for blk in (IP, IV, ITH):
            s.P[blk, :] = 0.0
            s.P[:, blk] = 0.0
            s.P[blk, blk] = init[blk, blk]
        s.reacq = ()
        s.tip_held = None
        s.vis_reject_run = 0
        s.last_vision_ns = s.last_tip_ns = s.t_ns
        _bump(s.counts, "updates:reacquire")
        return True

    def diverged(self, s: State) -> str | None:
        """Why the state must be reset, or None."""
        return self._why(health(s.p, s.v, s.R, s.P, self._gyro_k[GK_MAX_POS_VAR], self._gyro_k[GK_MAX_SPEED2]), s)

    def _why(self, health: int, s: State) -> str | None:
        if health == 1:
            return "not_finite"
        if health == 2:
            return "covariance"
        if self.vision and s.vis_reject_run >= self.prm.reset_after_vision_rejections:
            return "innovation"
        if health == 3:
            return "speed"
        return None

"""Bench motion: configuration, ground truth and `simulate` (FR3 + RCM servo + protocol).

`simulate(cfg, protocol, seed)` places the instrument at the neutral pose through the port,
builds the named protocol's tip targets, runs the 1 kHz RCM servo on the kinematic FR3 and
returns the robot's forward kinematics as `GroundTruth`. Base frame W = robot base; metres,
radians and nanoseconds unless a name says otherwise. Deterministic for a given seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from services.bench.robot import protocols
from services.bench.robot.fr3 import FR3_Q_MAX_RAD, FR3_Q_MIN_RAD, Fr3Kinematics, InstrumentMount, rpy_to_matrix
from services.bench.robot.operator_style import OperatorStyle
from services.bench.robot.protocols import FREE, HOLD, MOVE, POST, PRE  # noqa: F401  (re-exported)
from services.bench.robot.servo import RcmServo, ServoParams, project_onto_port

Vec3 = tuple[float, float, float]
Vec7 = tuple[float, float, float, float, float, float, float]


class MotionConfig(BaseModel):
    """Where the port, the neutral shaft and the camera are, and how the servo drives the FR3."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    rcm_base_m: Vec3 = Field((0.65, 0.0, 0.30), description="RCM (port centre) in the robot base [m]")
    neutral_tilt_deg: float = Field(28.6, ge=1.0, le=60.0, description="neutral shaft angle from vertical")
    neutral_azimuth_deg: float = Field(0.0, ge=-180.0, le=180.0, description="azimuth of the shaft's distal lean")
    neutral_roll_deg: float = Field(0.0, ge=-180.0, le=180.0, description="tool x axis about the shaft")
    depth_mm: float = Field(140.0, ge=100.0, le=180.0, description="neutral insertion depth")
    L_min_mm: float = Field(105.0, ge=50.0, le=200.0, description="servo depth clip, lower (admits translation -z)")
    L_max_mm: float = Field(175.0, ge=50.0, le=250.0, description="servo depth clip, upper")
    working_depth_mm: tuple[float, float] = Field((130.0, 150.0), description="depth range the operator keeps")
    tilt_envelope_deg: float = Field(10.0, ge=1.0, le=45.0, description="tilt range the operator keeps")
    camera_rpy_deg: Vec3 = Field((180.0, 0.0, -90.0), description="R_base_camera as roll, pitch, yaw")
    command_camera_error_deg: Vec3 = Field(
        (0.0, 0.0, 0.0), description="hand-eye rotation error (rpy) in the R_base_camera used to command trials"
    )
    camera_distance_m: float = Field(0.25, ge=0.05, le=1.0, description="camera centre to neutral tip, along its z")
    tip_speed_limit_mmps: float = Field(50.0, gt=0.0, le=200.0)
    speed_fraction: float = Field(0.8, gt=0.0, le=1.0, description="fraction of the limit programmed moves use")
    roll_rate_limit_dps: float = Field(60.0, gt=0.0, le=360.0)
    min_move_s: float = Field(1.5, ge=0.2, le=10.0)
    k_p_per_s: float = Field(30.0, gt=0.0, le=200.0)
    k_f: float = Field(1.0, ge=0.0, le=1.5)
    k_rcm_per_s: float = Field(30.0, ge=0.0, le=200.0)
    k_roll_per_s: float = Field(20.0, ge=0.0, le=200.0)
    damping: float = Field(0.005, ge=0.0, le=0.5, description="DLS damping")
    posture_gain_per_s: float = Field(2.0, ge=0.0, le=50.0)
    posture_weights: Vec7 = Field((1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0))
    posture_seed_rad: Vec7 = Field((0.0, -0.25, 0.0, -2.2, 0.0, 2.2, 0.0), description="IK seed / null-space target")
    joint_margin_rad: float = Field(0.01, ge=0.0, le=0.3, description="hard clamp inside the joint limits")
    rate_hz: float = Field(1000.0, ge=250.0, le=4000.0)
    operator_tremor_mm: float = Field(0.0, ge=0.0, le=2.0, description="teleop: tremor, RMS tip travel per tilt axis")
    operator_tremor_hz: float = Field(9.0, ge=3.0, le=15.0, description="teleop: tremor frequency")
    operator_pauses_per_min: float = Field(0.0, ge=0.0, le=10.0, description="teleop: hesitation pauses per minute")
    operator_pause_s: float = Field(1.5, ge=0.2, le=5.0, description="teleop: length of each hesitation pause")
    operator_detour: float = Field(
        0.0, ge=0.0, le=1.0, description="teleop: path economy, extra wandering as a fraction of the tilt's RMS"
    )
    correction: Literal["tip", "target"] = "tip"
    shaft_length_m: float = Field(0.34, ge=0.05, le=0.6)
    p_flange_handle_m: Vec3 = Field((0.0, 0.0, 0.05))
    rpy_flange_tool_deg: Vec3 = Field((0.0, 0.0, 0.0))

    @model_validator(mode="after")
    def _check(self) -> MotionConfig:
        if any(abs(v) > 1.5 for v in self.rcm_base_m):
            raise ValueError("rcm_base_m: each coordinate must be within 1.5 m of the base")
        if not self.L_min_mm < self.depth_mm < self.L_max_mm:
            raise ValueError("depth_mm must lie strictly between L_min_mm and L_max_mm")
        lo, hi = self.working_depth_mm
        if not self.L_min_mm <= lo < hi <= self.L_max_mm:
            raise ValueError("working_depth_mm must be an increasing pair inside [L_min_mm, L_max_mm]")
        if any(not 0.0 <= w <= 100.0 for w in self.posture_weights):
            raise ValueError("posture_weights must each be in [0, 100]")
        for name in ("camera_rpy_deg", "command_camera_error_deg", "rpy_flange_tool_deg"):
            if any(abs(v) > 360.0 for v in getattr(self, name)):
                raise ValueError(f"{name}: each angle must be within +-360 deg")
        if any(abs(v) > 5.0 for v in self.command_camera_error_deg):
            raise ValueError("command_camera_error_deg: a hand-eye error beyond 5 deg is not a calibration")
        if any(abs(v) > 0.3 for v in self.p_flange_handle_m):
            raise ValueError("p_flange_handle_m: each coordinate must be within 0.3 m of the flange")
        q = np.asarray(self.posture_seed_rad)
        if np.any(q < FR3_Q_MIN_RAD) or np.any(q > FR3_Q_MAX_RAD):
            raise ValueError("posture_seed_rad must lie inside the FR3 joint limits")
        return self

    def mount(self) -> InstrumentMount:
        return InstrumentMount(self.shaft_length_m, self.p_flange_handle_m, self.rpy_flange_tool_deg)

    def R_base_camera(self) -> np.ndarray:
        return rpy_to_matrix(np.deg2rad(self.camera_rpy_deg))

    def R_neutral(self) -> np.ndarray:
        """Neutral R_base_tool: z = shaft (distal), x = up-shaft in the vertical plane turned by the roll."""
        t, a = np.deg2rad(self.neutral_tilt_deg), np.deg2rad(self.neutral_azimuth_deg)
        u0 = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), -np.cos(t)])
        h = np.array([np.cos(a), np.sin(a), 0.0])
        x = h - (h @ u0) * u0
        x /= np.linalg.norm(x)
        y = np.cross(u0, x)
        c, s = np.cos(np.deg2rad(self.neutral_roll_deg)), np.sin(np.deg2rad(self.neutral_roll_deg))
        x, y = c * x + s * y, -s * x + c * y
        return np.stack([x, y, u0], axis=1)

    def p_base_camera_m(self) -> np.ndarray:
        """Camera centre: camera_distance_m back along its optical axis from the neutral tip."""
        tip = np.asarray(self.rcm_base_m) + self.depth_mm * 1e-3 * self.R_neutral()[:, 2]
        return tip - self.camera_distance_m * self.R_base_camera()[:, 2]


@dataclass
class GroundTruth:
    """Robot ground truth at the servo rate (N samples) and the trial bookkeeping.

    t_ns (N,) int64 from 0; q_rad, dq_radps (N, 7); R_base_tool (N, 3, 3); p_tip_base_m (N, 3);
    rcm_base_m (3,); trial (N,) int32 (-1 outside trials); phase (N,) uint8 (FREE, PRE, MOVE, POST,
    HOLD); p_target_base_m (N, 3) the projected tip command; roll_cmd_rad (N,).
    """

    t_ns: np.ndarray
    q_rad: np.ndarray
    dq_radps: np.ndarray
    R_base_tool: np.ndarray
    p_tip_base_m: np.ndarray
    rcm_base_m: np.ndarray
    trial: np.ndarray
    phase: np.ndarray
    trials: list[dict] = field(default_factory=list)
    meta: dict = field(default_factory=dict)
    p_target_base_m: np.ndarray | None = None
    roll_cmd_rad: np.ndarray | None = None

    FREE = FREE
    PRE = PRE
    MOVE = MOVE
    POST = POST
    HOLD = HOLD

    @property
    def u_base(self) -> np.ndarray:
        """Shaft directions (N, 3), u = R_base_tool @ e_z."""
        return self.R_base_tool[:, :, 2]

    def depth_m(self) -> np.ndarray:
        """Insertion depth L = (p - r).u per sample [m]."""
        return np.einsum("ij,ij->i", self.p_tip_base_m - self.rcm_base_m, self.u_base)

    def rcm_error_m(self) -> np.ndarray:
        """Distance of the shaft line from the RCM per sample [m]."""
        d = self.rcm_base_m - self.p_tip_base_m
        u = self.u_base
        perp = d - np.einsum("ij,ij->i", d, u)[:, None] * u
        return np.linalg.norm(perp, axis=1)


def _context(cfg: MotionConfig) -> protocols.ProtocolContext:
    return protocols.ProtocolContext(
        r_m=np.asarray(cfg.rcm_base_m, float),
        R_neutral=cfg.R_neutral(),
        R_base_camera=cfg.R_base_camera() @ rpy_to_matrix(np.deg2rad(cfg.command_camera_error_deg)),
        depth_m=cfg.depth_mm * 1e-3,
        rate_hz=cfg.rate_hz,
        tip_speed_max_mps=cfg.tip_speed_limit_mmps * 1e-3,
        speed_fraction=cfg.speed_fraction,
        roll_rate_max_radps=np.deg2rad(cfg.roll_rate_limit_dps),
        min_move_s=cfg.min_move_s,
        working_depth_m=(cfg.working_depth_mm[0] * 1e-3, cfg.working_depth_mm[1] * 1e-3),
        tilt_envelope_rad=np.deg2rad(cfg.tilt_envelope_deg),
        operator=OperatorStyle(
            cfg.operator_tremor_mm,
            cfg.operator_tremor_hz,
            cfg.operator_pauses_per_min,
            cfg.operator_pause_s,
            cfg.operator_detour,
        ),
    )


def neutral_posture(cfg: MotionConfig, kin: Fr3Kinematics | None = None) -> np.ndarray:
    """Joint angles [rad] with the tip at depth_mm through the port along the neutral shaft."""
    kin = kin or Fr3Kinematics(cfg.mount())
    p0 = np.asarray(cfg.rcm_base_m) + cfg.depth_mm * 1e-3 * cfg.R_neutral()[:, 2]
    return kin.solve_ik(cfg.R_neutral(), p0, np.asarray(cfg.posture_seed_rad))


def build_command(cfg: MotionConfig, protocol: str, seed: int, duration_s: float | None = None) -> protocols.Command:
    """The protocol's commanded targets (no simulation), truncated to duration_s."""
    if duration_s is not None and duration_s <= 0:
        raise ValueError(f"duration_s must be positive, got {duration_s}")
    cmd = protocols.build(protocol, _context(cfg), seed, duration_s)
    if duration_s is not None:
        cmd = cmd.truncate(int(round(duration_s * cfg.rate_hz)))
    return cmd


def simulate(cfg: MotionConfig, protocol: str, seed: int, duration_s: float | None = None) -> GroundTruth:
    """Run the named protocol on the simulated FR3; ground truth at cfg.rate_hz (1 kHz default)."""
    cmd = build_command(cfg, protocol, seed, duration_s)
    kin = Fr3Kinematics(cfg.mount())
    q0 = neutral_posture(cfg, kin)
    r = np.asarray(cfg.rcm_base_m, float)
    params = ServoParams(
        k_p_per_s=cfg.k_p_per_s,
        k_f=cfg.k_f,
        k_rcm_per_s=cfg.k_rcm_per_s,
        k_roll_per_s=cfg.k_roll_per_s,
        damping=cfg.damping,
        posture_gain_per_s=cfg.posture_gain_per_s,
        posture_weights=tuple(cfg.posture_weights),
        tip_speed_max_mps=cfg.tip_speed_limit_mmps * 1e-3,
        L_min_m=cfg.L_min_mm * 1e-3,
        L_max_m=cfg.L_max_mm * 1e-3,
        joint_margin_rad=cfg.joint_margin_rad,
        rate_hz=cfg.rate_hz,
        correction=cfg.correction,
    )
    servo = RcmServo(kin, r, cfg.R_neutral(), q0, params)
    dp = np.gradient(cmd.p_raw_m, axis=0) * cfg.rate_hz if len(cmd.p_raw_m) > 1 else np.zeros_like(cmd.p_raw_m)
    droll = np.gradient(cmd.roll_rad) * cfg.rate_hz if len(cmd.roll_rad) > 1 else np.zeros_like(cmd.roll_rad)
    log = servo.run(q0, cmd.p_raw_m, dp, cmd.roll_rad, droll)
    p_target, _, _ = project_onto_port(cmd.p_raw_m, dp, r, params.L_min_m, params.L_max_m)
    n = len(cmd.p_raw_m)
    step_ns = int(round(1e9 / cfg.rate_hz))
    meta = dict(
        protocol=protocol,
        seed=int(seed),
        rate_hz=cfg.rate_hz,
        config=cfg.model_dump(),
        q_neutral_rad=q0.tolist(),
        R_neutral=cfg.R_neutral().tolist(),
        R_base_camera=cfg.R_base_camera().tolist(),
        p_base_camera_m=cfg.p_base_camera_m().tolist(),
        phase_names=dict(protocols.PHASE_NAMES),
    )
    return GroundTruth(
        t_ns=np.arange(n, dtype=np.int64) * step_ns,
        q_rad=log.q_rad,
        dq_radps=log.dq_radps,
        R_base_tool=log.R_base_tool,
        p_tip_base_m=log.p_tip_base_m,
        rcm_base_m=r,
        trial=cmd.trial.astype(np.int32),
        phase=cmd.phase.astype(np.uint8),
        trials=cmd.trials,
        meta=meta,
        p_target_base_m=p_target,
        roll_cmd_rad=cmd.roll_rad.copy(),
    )

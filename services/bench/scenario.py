"""The scenario file: every number of the simulated bench, validated with a range.

Defaults reproduce the paper's bench (its Methods and Experiments); a YAML file
or `--set section.field=value` overrides any field. Units are in the field names (_m, _mm,
_deg, _ms, _hz, ...). Frames: base (z up), tool (origin at the tip, z along the shaft,
distal), imu, camera (x right, y down, z forward).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, FiniteFloat, ValidationError, field_validator

from services.bench.profiles import DEFAULT_PROFILE, PROFILES, profile_overrides
from tiplog.config import ConfigError, format_validation_error, parse_override, read_yaml_file, set_path
from tiplog.geometry.camera import CameraModel

try:  # the robot helper's motion configuration (services/bench/motion.py)
    from services.bench.robot.motion import MotionConfig
except ImportError:  # pragma: no cover - until motion.py lands

    class MotionConfig(BaseModel):  # type: ignore[no-redef]
        model_config = ConfigDict(extra="allow")


try:  # the render helper's pixel-tier parameters (services/bench/render.py)
    from services.bench.render.renderer import RenderParams
except ImportError:  # pragma: no cover - without OpenCV or before render.py lands

    class RenderParams(BaseModel):  # type: ignore[no-redef]
        model_config = ConfigDict(extra="allow")


def _increasing(v: tuple[float, float]) -> tuple[float, float]:
    if not v[0] <= v[1]:
        raise ValueError("a range is [min, max] with min <= max")
    return v


F = Field
Vec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]
Vec2 = tuple[FiniteFloat, FiniteFloat]
Range2 = Annotated[Vec2, AfterValidator(_increasing)]  # (min, max)


# The bench's camera, as far as the scenario changes the robot helper's defaults: above the
# field, optical axis about 75 deg from the neutral shaft (a junction ray nearly along the axis
# would fail 1-(d.u)^2 >= 0.45), about 82 mm from the axis so that the tangent planes are
# ~3.6 deg apart as in the paper.
MOTION_DEFAULTS: dict[str, Any] = {"camera_rpy_deg": (180.0, 46.4, 0.0), "camera_distance_m": 0.085}


class _M(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class InstrumentConfig(_M):
    shaft_radius_m: float = F(0.00259, gt=0.0005, lt=0.01)
    imu_proximal_m: float = F(0.304, gt=0.05, lt=0.6, description="IMU distance proximal of the tip along the shaft")
    imu_lateral_m: Vec2 = F((0.018, 0.0), description="IMU offset from the shaft axis, tool x/y")
    imu_mount_rpy_deg: Vec3 = F((1.5, -2.0, 91.0), description="rotation IMU-to-tool R_tool_imu, roll/pitch/yaw")
    tof_proximal_m: float = F(0.284, gt=0.05, lt=0.6)
    tof_lateral_m: Vec2 = F((0.0, 0.015), description="beam origin o_s offset from the axis, tool x/y")
    tof_beam_off_axis_deg: float = F(55.8, ge=0.0, le=80.0, description="angle of b_s to the shaft axis")
    tof_beam_azimuth_deg: float = F(
        90.0, ge=-180.0, le=180.0, description="azimuth of b_s about the shaft, from tool x"
    )
    tof_plane_off_neutral_deg: float = F(13.4, ge=0.0, le=60.0, description="plane normal m to the neutral shaft axis")
    tof_plane_azimuth_deg: float = F(30.0, ge=-180.0, le=180.0)
    tof_plane_offset_m: float = F(0.0, ge=-0.1, le=0.1, description="plane distance from the RCM along m")
    junction_proximal_m: float = F(0.004, ge=0.0, le=0.03, description="shaft junction proximal of the true tip")


class ClockConfig(_M):
    """Device clock (nRF52840) against the host clock."""

    offset_s_max: float = F(5.0, ge=0.0, le=1e4, description="device clock offset drawn in [0, max]")
    drift_ppm_sd: float = F(20.0, ge=0.0, le=500.0)
    sample_jitter_us: float = F(30.0, ge=0.0, le=2000.0, description="sample-time jitter SD")


class GyroConfig(_M):
    rate_hz: float = F(200.0, gt=1.0, le=2000.0)
    noise_density_dps_rthz: float = F(0.014, ge=0.0, le=1.0)
    bias_instability_dps: float = F(0.05, ge=0.0, le=5.0, description="initial bias SD per axis")
    bias_rw_static_dps_rts: float = F(0.002, ge=0.0, le=1.0, description="bias random walk at rest")
    bias_rw_motion_dps_rts_per_radps: float = F(
        0.35, ge=0.0, le=10.0, description="extra bias random walk per rad/s of angular rate (bias moves in motion)"
    )
    scale_sd: float = F(0.002, ge=0.0, le=0.1)
    latency_ms: float = F(6.75, ge=0.0, le=500.0)
    latency_jitter_ms: float = F(0.4, ge=0.0, le=50.0)


class AccelConfig(_M):
    rate_hz: float = F(240.0, gt=1.0, le=2000.0)
    noise_sd_mps2: float = F(0.072, ge=0.0, le=2.0, description="per axis per sample: 0.30-0.55 deg tilt SD")
    noise_pose_spread: float = F(0.15, ge=0.0, le=1.0, description="relative spread of the noise SD across poses")
    noise_factor_range: Range2 = F((0.73, 1.29), description="clip of that factor: 0.30-0.55 deg across holds")
    bias_sd_mps2: float = F(0.002, ge=0.0, le=1.0, description="keeps the norm within 0.06 % of g")
    scale_sd: float = F(0.0002, ge=0.0, le=0.1, description="norm within 0.06 % of g")
    pose_tilt_sd_deg: float = F(0.21, ge=0.0, le=10.0, description="pose-locked direction error (held out 0.21)")
    pose_corr_deg: float = F(6.0, gt=0.0, le=180.0)
    pose_corr_m: float = F(0.01, gt=0.0, le=1.0)
    vibration_mps2_per_mps: float = F(
        0.0, ge=0.0, le=100.0, description="RMS vibration of the specific force per m/s of tip speed (robot and hand)"
    )
    vibration_hz: float = F(15.0, gt=0.5, le=100.0, description="centre of the vibration band (about an octave wide)")
    compliance_deg_per_mps2: float = F(
        0.0, ge=0.0, le=5.0, description="mount compliance: IMU tilt against the tool per m/s^2 of acceleration"
    )
    self_recal: bool = F(False, description="BNO085 runtime self-recalibration (off in the paper's firmware)")
    self_recal_jump_frac: float = F(0.063, ge=0.0, le=0.5)
    self_recal_jump_time_s: float = F(600.0, ge=0.0, le=1e5, description="jump completes within 13 min")
    self_recal_settle_frac: float = F(0.055, ge=0.0, le=0.5)
    self_recal_settle_tau_s: float = F(120.0, gt=0.0, le=1e5)
    latency_ms: float = F(6.75, ge=0.0, le=500.0)
    latency_jitter_ms: float = F(0.4, ge=0.0, le=50.0)


class TofConfig(_M):
    rate_hz: float = F(100.0, gt=1.0, le=1000.0)
    noise_sd_mm: float = F(3.2, ge=0.0, le=50.0, description="per sample, 2.95-3.43 mm")
    noise_pose_spread: float = F(0.05, ge=0.0, le=1.0)
    noise_factor_range: Range2 = F((0.92, 1.07), description="clip of that factor: 2.95-3.43 mm across holds")
    pose_sd_mm: float = F(3.04, ge=0.0, le=50.0, description="pose-locked systematic error across poses")
    pose_corr_deg: float = F(4.0, gt=0.0, le=180.0)
    pose_corr_m: float = F(0.008, gt=0.0, le=1.0)
    pose_corr_spread: float = F(
        1.0, ge=1.0, le=10.0, description="each session draws its correlation lengths log-uniform within this factor"
    )
    integration_ms: float = F(0.0, ge=0.0, le=100.0, description="ranging time, centred on the sample instant")
    beam_fov_deg: float = F(25.0, gt=0.0, le=60.0, description="full cone of the emitter/receiver field of view")
    surface_relief_mm: float = F(0.0, ge=0.0, le=20.0, description="SD of the target surface about its plane")
    surface_corr_mm: float = F(15.0, gt=0.1, le=1000.0, description="correlation length of that relief")
    repeat_sd_mm: float = F(0.39, ge=0.0, le=20.0, description="slow drift: 0.43 mm over repeats with the white part")
    repeat_tau_s: float = F(20.0, gt=0.0, le=1e4)
    dropout_prob: float = F(0.01, ge=0.0, le=1.0, description="sigma/signal/phase failures per sample")
    max_range_mm: float = F(1200.0, gt=10.0, le=8190.0)
    out_of_range_value_mm: float = F(8190.0, ge=0.0, le=65535.0)
    smoothed_window: int = F(5, ge=1, le=50)
    latency_ms: float = F(9.0, ge=0.0, le=500.0)
    latency_jitter_ms: float = F(0.5, ge=0.0, le=50.0)
    smoothed_latency_ms: float = F(58.7, ge=0.0, le=1000.0, description="total, raw latency + average + hold")


class MagConfig(_M):
    rate_hz: float = F(100.0, gt=1.0, le=1000.0)
    earth_field_ut: float = F(48.0, gt=1.0, le=200.0)
    inclination_deg: float = F(64.0, ge=-90.0, le=90.0)
    declination_deg: float = F(2.0, ge=-180.0, le=180.0)
    noise_sd_ut: float = F(0.4, ge=0.0, le=20.0)
    hard_iron_sd_ut: float = F(
        2.0, ge=0.0, le=100.0, description="residual hard iron per axis: the paper's 4.8 deg is a median draw"
    )
    pose_disturbance_sd_ut: float = F(1.0, ge=0.0, le=100.0, description="field-to-gravity angle up to ~4.8 deg")
    pose_corr_deg: float = F(8.0, gt=0.0, le=180.0)
    pose_corr_m: float = F(0.02, gt=0.0, le=1.0)
    session_scale_min: float = F(0.79, gt=0.0, le=2.0, description="mean field falls up to 21 % between sessions")
    session_scale_max: float = F(1.0, gt=0.0, le=2.0)
    latency_ms: float = F(6.75, ge=0.0, le=500.0)
    latency_jitter_ms: float = F(0.4, ge=0.0, le=50.0)


_D405 = CameraModel.d405_colour()


class CameraConfig(_M):
    width: int = F(_D405.width, ge=16, le=8192)
    height: int = F(_D405.height, ge=16, le=8192)
    fx: float = F(_D405.fx, gt=10.0, le=1e5)
    fy: float = F(_D405.fy, gt=10.0, le=1e5)
    cx: float = F(_D405.cx, ge=0.0, le=8192.0)
    cy: float = F(_D405.cy, ge=0.0, le=8192.0)
    dist: tuple[float, float, float, float, float] = F(_D405.dist)
    fps: float = F(15.0, gt=0.1, le=240.0)
    latency_ms: float = F(16.4, ge=0.0, le=1000.0, description="15.5-17.3 ms capture to host arrival")
    latency_jitter_ms: float = F(0.5, ge=0.0, le=50.0)
    frame_jitter_us: float = F(100.0, ge=0.0, le=10000.0)

    def model(self) -> CameraModel:
        return CameraModel(self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.dist)


class VisionConfig(_M):
    plane_white_deg: float = F(0.06, ge=0.0, le=10.0, description="per-frame tangent-plane noise")
    plane_pose_deg: float = F(0.09, ge=0.0, le=10.0, description="pose-locked part; total held out 0.11 deg")
    pose_corr_deg: float = F(5.0, gt=0.0, le=180.0)
    pose_corr_m: float = F(0.01, gt=0.0, le=1.0)
    junction_depth_white_mm: float = F(0.30, ge=0.0, le=50.0)
    junction_depth_pose_mm: float = F(0.36, ge=0.0, le=50.0, description="with white: 0.47 mm held out")
    junction_lateral_px: float = F(0.5, ge=0.0, le=50.0)
    junction_hidden_prob: float = F(0.05, ge=0.0, le=1.0)
    # Gross junction errors that pass the consistency gate: the pixel tier's labeler and network
    # agreeing on a wrong end of the shaft (benchmarks/vision_accuracy.py, teleop seeds 1-3: 1
    # frame in 522 with a junction, 22 mm off). The paper's error sizes have no such tail.
    junction_outlier_prob: float = F(0.002, ge=0.0, le=1.0, description="per frame with a junction")
    junction_outlier_mm: Range2 = F((5.0, 25.0), description="range of a gross junction depth error")
    junction_min_sin2: float = F(0.45, ge=0.0, le=1.0, description="reject when 1-(d.u)^2 is below")
    gate_iou_min: float = F(0.75, ge=0.0, le=1.0)
    gate_line_angle_deg: float = F(0.5, gt=0.0, le=10.0)
    gate_lateral_px: float = F(1.5, gt=0.0, le=50.0)
    gate_junction_px: float = F(4.0, gt=0.0, le=100.0)
    metric_scale_rest: float = F(0.52, gt=0.0, le=10.0, description="gate metrics' spread, in gate thresholds")
    metric_scale_per_px: float = F(0.04, ge=0.0, le=1.0, description="growth per px/frame of image motion")
    wrong_seg_prob: float = F(0.04, ge=0.0, le=1.0)
    wrong_seg_deg: Range2 = F((2.0, 6.0), description="range of a wrong line's error")
    # Motion (all zero in the clean profile): exposure blur, errors growing with image speed and
    # away from the validated range, quality-following gate, correlated dropouts.
    exposure_ms: float = F(0.0, ge=0.0, le=66.0, description="locked exposure of the global-shutter colour sensor")
    edge_width_px: float = F(2.0, gt=0.1, le=50.0, description="edge width at rest; blur across it adds noise")
    junction_blur_bias: float = F(0.0, ge=0.0, le=1.0, description="junction shift distally, per px of axial blur")
    junction_blur_sd: float = F(0.0, ge=0.0, le=2.0, description="junction noise SD per px of axial blur")
    junction_speed_px_per_px: float = F(
        0.0, ge=0.0, le=5.0, description="junction noise SD [px] per px/frame of image motion"
    )
    plane_speed_deg_per_px: float = F(
        0.0, ge=0.0, le=1.0, description="tangent-plane noise SD [deg] per px/frame of image motion"
    )
    range_growth_per_10mm: float = F(
        0.0, ge=0.0, le=10.0, description="relative error growth per 10 mm beyond 140 +- 10 mm insertion"
    )
    range_growth_per_10deg: float = F(
        0.0, ge=0.0, le=10.0, description="relative error growth per 10 deg beyond 10 deg tilt"
    )
    validated_depth_mm: Range2 = F((130.0, 150.0), description="insertion depth range of validated reconstruction")
    validated_tilt_deg: float = F(10.0, gt=0.0, le=90.0, description="tilt from neutral of validated reconstruction")
    gate_quality_weight: float = F(
        0.0, ge=0.0, le=4.0, description="weight of the frame's own motion error in the gate measures (quadrature)"
    )
    dropout_rate_per_min: float = F(0.0, ge=0.0, le=60.0, description="correlated vision dropouts (occlusion, smoke)")
    dropout_s: Range2 = F((0.5, 10.0), description="dropout durations, log-uniform")
    dropout_junction_only_frac: float = F(0.0, ge=0.0, le=1.0, description="dropouts that hide only the junction")
    junction_across_mm: float = F(0.0, ge=0.0, le=5.0, description="junction point off the axis, across the shaft")
    junction_across_azimuth_deg: float = F(90.0, ge=-180.0, le=180.0, description="its direction, from tool x")
    min_visible_px: float = F(60.0, ge=0.0, le=4000.0, description="visible shaft length in the image")
    processing_ms: float = F(113.0, ge=0.0, le=5000.0)
    processing_jitter_ms: float = F(12.0, ge=0.0, le=1000.0)


class CalibrationErrorConfig(_M):
    """Sizes of the errors of the "as calibrated" constants."""

    hand_eye_mean_mm: float = F(2.35, ge=0.0, le=100.0, description="held-out residual per marker pose (mean)")
    hand_eye_mean_deg: float = F(0.74, ge=0.0, le=30.0, description="held-out residual per marker pose (mean)")
    hand_eye_poses: int = F(30, ge=1, le=10000, description="poses the AX=XB refinement averages over")
    hand_eye_conditioning: float = F(2.0, ge=1.0, le=100.0, description="error growth of X over residual/sqrt(poses)")
    rcm_sd_mm: float = F(0.03, ge=0.0, le=20.0)
    imu_mount_sd_deg: float = F(0.2, ge=0.0, le=20.0)
    imu_position_sd_mm: float = F(1.0, ge=0.0, le=50.0)
    tof_origin_sd_mm: float = F(1.0, ge=0.0, le=50.0)
    tof_beam_sd_deg: float = F(0.3, ge=0.0, le=20.0)
    tof_plane_sd_deg: float = F(0.3, ge=0.0, le=20.0)
    tof_plane_offset_sd_mm: float = F(0.6, ge=0.0, le=50.0)
    latency_sd_ms: float = F(0.3, ge=0.0, le=50.0)
    junction_offset_sd_mm: float = F(0.2, ge=0.0, le=20.0)
    shaft_radius_sd_mm: float = F(0.01, ge=0.0, le=1.0)
    intrinsics_sd_frac: float = F(0.002, ge=0.0, le=0.2)


class OutputConfig(_M):
    robot_rate_hz: float = F(200.0, gt=0.0, le=1000.0, description="bench/robot ground truth rate")
    chunk_mb: float = F(4.0, gt=0.1, le=256.0)


class Scenario(_M):
    name: str = F("custom", pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    # The models' own defaults are the clean profile; load_scenario applies DEFAULT_PROFILE
    # (paper) to every built-in scenario and scenario file that names none.
    profile: str = F("clean", description="error profile applied under the scenario's own fields (clean, paper, harsh)")
    protocol: str = F("static", pattern=r"^[a-z0-9_]{1,32}$")
    duration_s: float | None = F(None, gt=0.0, le=1e5, description="cut the protocol (default: all of it)")
    motion: MotionConfig = F(default_factory=lambda: MotionConfig(**MOTION_DEFAULTS))
    instrument: InstrumentConfig = F(default_factory=InstrumentConfig)
    clock: ClockConfig = F(default_factory=ClockConfig)
    gyro: GyroConfig = F(default_factory=GyroConfig)
    accel: AccelConfig = F(default_factory=AccelConfig)
    tof: TofConfig = F(default_factory=TofConfig)
    mag: MagConfig = F(default_factory=MagConfig)
    camera: CameraConfig = F(default_factory=CameraConfig)
    vision: VisionConfig = F(default_factory=VisionConfig)
    calibration: CalibrationErrorConfig = F(default_factory=CalibrationErrorConfig)
    output: OutputConfig = F(default_factory=OutputConfig)
    render: RenderParams = F(default_factory=RenderParams, description="pixel tier only")

    @field_validator("profile")
    @classmethod
    def _known_profile(cls, v: str) -> str:
        if v not in PROFILES:
            raise ValueError(f"unknown profile; choose from {', '.join(PROFILES)}")
        return v

    @field_validator("protocol")
    @classmethod
    def _known_protocol(cls, v: str) -> str:
        from services.bench.robot.protocols import PROTOCOLS

        if v not in PROTOCOLS:
            raise ValueError(f"unknown protocol; choose from {', '.join(PROTOCOLS)}")
        return v


# name -> overrides of the defaults
BUILTIN: dict[str, dict[str, Any]] = {
    "static": {"protocol": "static"},
    "latency": {"protocol": "latency"},
    "fit": {"protocol": "fit"},
    "translation": {"protocol": "translation"},
    "rotation": {"protocol": "rotation", "motion": {"neutral_tilt_deg": 30.4}},
    "sweeps": {"protocol": "sweeps"},
    "teleop": {"protocol": "teleop"},
    "demo": {"protocol": "demo", "duration_s": 120.0},
}


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _profile_of(doc: dict[str, Any], pairs: list[tuple[str, Any]]) -> str:
    """The profile a scenario asks for: the last `profile=` override, else the file's, else the default."""
    name = doc.get("profile", DEFAULT_PROFILE)
    for k, v in pairs:
        if k == "profile":
            name = v
    if not isinstance(name, str) or name not in PROFILES:
        raise ConfigError(f"scenario error: profile: {name!r} is not a profile ({', '.join(PROFILES)})")
    return name


def load_scenario(name_or_path: str | Path, overrides: list[str] | dict[str, Any] | None = None) -> Scenario:
    """A built-in scenario by name, or a YAML file (optionally `base: <builtin>`), then
    overrides ('section.field=value' strings or a {dotted: value} dict). Precedence: built-in
    defaults < the profile (`profile`, default paper) < the file's explicit fields < overrides.
    Raises ConfigError naming the field path of every unknown or out-of-range field."""
    key = str(name_or_path)
    doc: dict[str, Any] = {}
    if key in BUILTIN:
        data: dict[str, Any] = _merge({"name": key, "motion": dict(MOTION_DEFAULTS)}, BUILTIN[key])
    else:
        p = Path(key)
        if not p.exists():
            raise ConfigError(f"scenario error: {key!r} is neither a built-in ({', '.join(BUILTIN)}) nor a file")
        doc = read_yaml_file(p, "scenario")
        if not isinstance(doc, dict):
            raise ConfigError(f"scenario error: {p} must hold a mapping")
        base = doc.pop("base", None)
        if base is not None and base not in BUILTIN:
            raise ConfigError(f"scenario error: base: {base!r} is not a built-in ({', '.join(BUILTIN)})")
        data = _merge({"name": p.stem, "motion": dict(MOTION_DEFAULTS)}, BUILTIN[base] if base else {})
    pairs = list(overrides.items()) if isinstance(overrides, dict) else [parse_override(o) for o in overrides or []]
    profile = _profile_of(doc, pairs)
    data = _merge(_merge(data, profile_overrides(profile)), doc)
    data["profile"] = profile
    for k, v in pairs:
        set_path(data, k, v)
    try:
        return Scenario.model_validate(data)
    except ValidationError as e:
        raise ConfigError(format_validation_error(e).replace("config error:", "scenario error:")) from None


def scenario_dict(s: Scenario) -> dict[str, Any]:
    """The resolved scenario as plain JSON-able data (for the session's metadata)."""
    return s.model_dump(mode="json")

"""The tracking filter's parameters: one set, fixed before any evaluation block, used by the
live service and by `tiplog fusion run` alike.

Units are in the field names. Noise densities are continuous-time (per sqrt(Hz) or
per sqrt(s)); measurement sigmas are per update, already inflated for correlated samples as
the paper's noise model prescribes (held-out residual times sqrt(N_c)). The values were tuned
on bench sessions kept apart from every evaluation.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from tiplog.userio import read_yaml, yaml_number

SENSORS = frozenset({"imu", "tof", "vision"})
_GATES = ("gate_chi2_1", "gate_chi2_2", "gate_chi2_3", "gate_chi2_4")
_POSITIVE = (
    "tof_map_sigma_deg", "tof_map_sigma_mm", "tof_map_far_sigma_deg", "tof_map_far_sigma_mm", "tof_map_bin_ms",
    "tof_map_gp_sigma_mm", "tof_map_gp_noise_mm", "rest_tau_ms", "rest_chunk_ms", "tip_confirm_ms", "tip_confirm_mm", "accel_map_sigma_deg", "accel_map_sigma_mm",
    "accel_map_bin_ms", "accel_map_every_ms", *_GATES,
    "depth_anchor_tau_s", "depth_ref_tau_s", "depth_anchor_sigma_min_mm", "start_depth_mm",
)  # fmt: skip
MAX_HISTORY_MS = 120_000.0  # the rewind history lives in memory: a snapshot per gyro sample


class ParamsError(ValueError):
    """A parameter file or value that cannot be used; the message names the field."""


@dataclass(frozen=True)
class Params:
    # --- timing -------------------------------------------------------------------------
    output_delay_ms: float = 30.0  # published state held this far behind real time
    history_ms: float = 1500.0  # snapshots kept for out-of-sequence rewinds
    max_age_ms: float = 1000.0  # a measurement older than this on arrival is dropped
    # --- process noise ------------------------------------------------------------------
    gyro_noise_dps_rthz: float = 0.02
    gyro_bias_rw_dps_rts: float = 0.003  # at rest
    gyro_bias_rw_dps_rts_per_radps: float = 0.35  # extra, per rad/s of angular rate
    accel_noise_mps2_rthz: float = 0.03  # includes the lever arm's angular-acceleration noise
    # The accelerometer bias is small and stable (|a| within 0.06 % of g, self-recalibration off):
    # estimated loosely it trades against tilt through the lever arm's unmodelled acceleration.
    accel_bias_rw_mps2_rts: float = 0.00001
    tof_offset_rw_mm_rts: float = 1.5
    # ... and, while it is estimated, by this much variance for every degree the tool turns: b_rho
    # stands for the ToF's error at the present pose, and that error is pose-locked (3 mm across
    # poses, 0.4 mm over repeats of one), so it changes as the beam moves over the target and not
    # with time. Without it a fast pitch sweep leaks the changing error into the depth; 20 mm^2
    # per degree lets b_rho follow the error over the field's few-degree correlation
    tof_offset_rw_mm2_per_deg: float = 20.0
    alpha_window: int = 4  # gyro samples spanned by the angular-acceleration difference
    # ... over at least this long: a loaded host's gateway can stamp a backlog of samples 1 ns
    # apart, and a difference over nanoseconds is no angular acceleration (it threw the tip
    # kilometres); over a shorter span the lever-arm term is left out for that sample
    alpha_min_span_ms: float = 10.0
    imu_gap_ms: float = 50.0  # propagating further than this without an IMU sample: see filter.propagate
    # without IMU (ablation, and across IMU gaps for the velocity): random walks standing in
    # for the gyro and accelerometer
    no_imu_rate_rw_dps_rts: float = 40.0
    no_imu_accel_rw_mps2_rts: float = 0.3
    # rest: the gyro bias straight from the gyroscope while the tool is still (VQF's rest
    # detection and thresholds, as `fusion attitude`). Without it only vision sees the bias's
    # vertical component, and the bias walks in motion: without vision the heading drifts on
    # with whatever bias the last motion left, even when the tool has come to rest
    rest_bias: bool = True
    rest_th_gyro_dps: float = 2.0  # every gyro sample within this of its low-pass ...
    rest_th_accel_mps2: float = 0.5  # ... and every accelerometer sample within this of its own
    rest_tau_ms: float = 500.0  # (their low-pass time constant)
    rest_min_ms: float = 1500.0  # ... for this long: at rest
    rest_chunk_ms: float = 500.0  # the mean rate over each chunk of rest measures the bias,
    rest_agree_gyro_dps: float = 0.1  # once the next chunk's mean rate is within this of it
    rest_agree_accel_mps2: float = 0.05  # and its mean specific force within this
    # ... and while b_rho is held (no vision tip within the offset window) the rest moves the
    # bias alone, taking no variance from the heading through its correlation with the bias
    # (filter.update_rest): without vision nothing else observes the heading, and a rest must
    # not move it; with vision it changes nothing
    rest_bias_only: bool = True
    rest_sigma_dps: float = 0.01  # added to the chunk mean's noise: motion below the thresholds
    # --- initial uncertainty ------------------------------------------------------------
    init_gyro_bias_dps: float = 0.05
    init_accel_bias_mps2: float = 0.002
    init_tof_offset_mm: float = 5.0
    init_position_mm: float = 2.0
    init_velocity_mps: float = 0.02
    init_attitude_deg: float = 1.0
    # --- measurements -------------------------------------------------------------------
    rcm_sigma_mm: float = 0.3
    rcm_every: int = 1  # RCM pseudo-measurement every n-th gyro sample
    gravity_sigma_deg: float = 1.0
    gravity_sigma_per_excess: float = 20.0  # sigma grows by this many deg per unit | |a|/g - 1 |
    # every n-th accelerometer sample (0: none). Each sample's tilt noise is white (0.3-0.55 deg),
    # so every sample at the same standard deviation beats fewer samples each trusted more
    gravity_every: int = 1
    # ToF per sample: 3.2 mm white + 3 mm pose-locked at 100 Hz, inflated for the correlation;
    # weighed less while vision tips also give the depth (the pose-locked part then only adds
    # error), more while b_rho is held and the ToF is the only depth (blackouts, junction hidden)
    tof_sigma_mm: float = 45.0
    tof_sigma_held_mm: float = 14.0
    tof_min_mm: float = 20.0
    tof_max_mm: float = 400.0
    # b_rho estimated only within this of an independent vision tip (the paper: 2 s). Past it
    # the ToF is the depth: held weight, the pose map. 250 ms is 4 frames at 15 frames/s: with
    # 2 s the first 2 s of every gap in the tips ran on the weak ToF weight and the
    # accelerometer alone
    tof_offset_window_ms: float = 250.0
    # the ToF's pose-locked error learnt while b_rho is free, used while it is held (tof_map.py)
    tof_map: bool = True
    tof_map_sigma_deg: float = 1.0
    tof_map_sigma_mm: float = 6.0
    tof_map_bin_ms: float = 50.0
    # the whole of a procedure's last 10 min, not 120 s: the error stays where it was (0.4 mm over
    # repeats of a pose), and a teleoperated block comes back to poses it left minutes before
    tof_map_window_s: float = 600.0
    tof_map_prior_weight: float = 2.0
    # where the map recorded little, its prediction is shrunk towards `TofMap.far_prior`, not
    # the held b_rho: b_rho only within the error's correlation over the pose of where it was
    # last learnt (these widths: the bench's ToF field, 4 deg and 8 mm, not tuned), the errors
    # recorded within that correlation of the present pose further off (shrunk towards the
    # mean as if it were tof_map_far_weight bins of 50 ms), their mean over the window further
    # still (shrunk towards b_rho as if it were tof_map_mean_weight bins): a held b_rho is the
    # error of one pose, and the further the tool has moved from it the less it says
    tof_map_far: bool = True
    tof_map_far_sigma_deg: float = 4.0
    tof_map_far_sigma_mm: float = 8.0
    tof_map_far_weight: float = 10.0
    tof_map_mean_weight: float = 200.0
    # ... and where the newest tof_map_gp_bins bins (2 s) lie, far_prior is their regression at
    # the pose, a Gaussian process with the field's correlation (the far widths), its 3 mm and
    # a bin's noise (3.2 mm white over 5 ranges), about the errors recorded near: b_rho is a
    # slow average that lags a changing error, and was held where the error went on changing.
    # Held for a gap, the regression carries on the trend of the path into it. With fewer bins
    # (the junction seen only briefly) b_rho as above. 0: off
    tof_map_gp_bins: int = 40
    tof_map_gp_sigma_mm: float = 3.0
    tof_map_gp_noise_mm: float = 1.5
    # while b_rho is held the ToF's variance is tof_sigma_held^2 (1 + k w0 / (w + w0)), w the
    # map's kernel weight at the pose and w0 its prior weight: where the map learnt nothing (and
    # with no map, as without vision) the pose-locked error is unmodelled. k = 3 gives 28 mm
    # per sample there: the 3 mm pose-locked error inflated for its correlation over 100 Hz
    tof_unmapped_var_factor: float = 3.0
    # it records only from a state tracked this long since its (re)initialisation, not one
    # still converging from a single frame (a runner's reset also forgets what the map took
    # from the diverging state after its last vision tip)
    tof_map_settle_ms: float = 1000.0
    # Without vision the depth is drawn to the working depth (its running mean over
    # depth_ref_tau_s while vision came), depth_anchor_sigma_mm per depth_anchor_tau_s, so that
    # the ToF's slow changes turn the heading back instead of moving the depth
    # (`TrackingFilter._anchor_depth`); 0: off. 5 mm per 5 s is the teleoperated blocks' depth
    # spread (SD 4-6 mm around the working depth) and a stroke's length
    depth_anchor_sigma_mm: float = 5.0
    depth_anchor_tau_s: float = 5.0
    depth_ref_tau_s: float = 20.0
    # with vision the pull's sigma is learnt: the depth's spread about the working depth (RMS
    # over depth_ref_tau_s), not below depth_anchor_sigma_min_mm; depth_anchor_sigma_mm is the
    # spread assumed until vision has shown one (and throughout without vision)
    depth_anchor_learn_spread: bool = True
    depth_anchor_sigma_min_mm: float = 1.0
    # The accelerometer's pose-locked error (its reading turned by a fraction of a degree that
    # depends on the pose, the same on every pass) learnt as the ToF's is (tof_map.py): the
    # gravity update's residual, recorded while b_rho is free (vision tips) and |f| is within
    # accel_map_max_excess of g, in 50 ms bins over the last 120 s; the kernel-weighted mean at
    # the present pose (2 deg, 8 mm: narrower than the error's 6 deg, 10 mm), looked up every
    # accel_map_every_ms (the pose moves little in 40 ms), is taken off every sample, with
    # vision or not
    accel_map: bool = True
    accel_map_sigma_deg: float = 2.0
    accel_map_sigma_mm: float = 8.0
    accel_map_bin_ms: float = 50.0
    accel_map_window_s: float = 120.0
    accel_map_prior_weight: float = 2.0
    accel_map_every_ms: float = 40.0
    accel_map_max_excess: float = 0.03
    vision_plane_sigma_deg: float = 0.15
    vision_offset_sigma_mm: float = 0.4
    vision_ray_sigma_mm: float = 1.0
    # a junction whose depth is this far from the latest ToF range's (b_rho free) is refused:
    # the labeler's gross errors (a wrong end of the shaft, 5-25 mm) otherwise pass the
    # chi-square gate once the depth has grown uncertain between frames
    vision_tip_tof_gate_mm: float = 12.0
    # a tip this surprising (NIS) is applied only once the next tip, within the window, is off
    # the same way (residuals within the tolerance): a gross junction error is one frame, a
    # drifted state shows in every frame. The tips' NIS runs far below its nominal mean of 2
    # (the ray's 1 mm sigma covers the junction's pose-locked error), so 2 is already a
    # surprise; 0 is off
    tip_confirm_chi2: float = 2.0
    tip_confirm_ms: float = 300.0
    tip_confirm_mm: float = 3.0
    trocar_gate_mm: float = 3.5
    gated_out_tip: bool = True  # use the tip (not the axis) of frames that fail the trocar gate
    junction_min_sin2: float = 0.45
    vision_lock_ms: float = 500.0
    # --- innovation gating and divergence ----------------------------------------------
    # innovation-based noise matching of the vision axis, the vision tip and the ToF
    # (`TrackingFilter._adapt`): each stream's variance factor follows its NIS with this time
    # constant, within [1, noise_adapt_max]; at the ceiling the stream is set aside until the
    # factor halves. 0 switches it off
    noise_adapt_tau_s: float = 3.0
    noise_adapt_max: float = 100.0
    noise_adapt_step_max_ms: float = 200.0
    gate_chi2_1: float = 10.83  # 99.9 % of chi2 with 1 degree of freedom
    gate_chi2_2: float = 13.82
    gate_chi2_4: float = 18.47
    gate_chi2_3: float = 16.27
    # without vision the tip is held within the physical insertion range along the shaft
    depth_min_m: float = 0.02
    depth_max_m: float = 0.40
    reset_after_vision_rejections: int = 15  # consecutive rejected vision frames -> divergence
    # after a reset, restart from the IMU and ToF (as without vision) if no vision frame could
    # restart the filter within this long: depth and inclination stay on display through a long
    # loss of view; 0 waits for vision
    restart_without_vision_ms: float = 1000.0
    # the depth a start without vision assumes, and then holds as the working depth (the paper's
    # operators kept 130-150 mm): the range alone cannot tell it from the heading
    start_depth_mm: float = 140.0
    # re-acquisition: this many frames in a row that pass the trocar gate but fail the axis'
    # innovation gate, and agree with each other (the same heading/position correction within
    # the tolerances below, over at most the window), move the state onto vision directly
    reacquire_frames: int = 4
    reacquire_window_ms: float = 1000.0
    reacquire_agree_deg: float = 2.0
    reacquire_agree_mm: float = 6.0
    max_position_sigma_mm: float = 200.0
    max_speed_mps: float = 2.0  # a faster tip is a diverged state (hand-held: well under 1 m/s)

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            default = f.default
            if isinstance(default, bool):
                if not isinstance(v, bool | np.bool_):
                    raise ParamsError(f"fusion parameter {f.name}: expected true or false (got {v!r})")
                continue
            if isinstance(default, int):
                if not isinstance(v, numbers.Integral) or isinstance(v, bool | np.bool_):
                    raise ParamsError(f"fusion parameter {f.name}: expected a whole number (got {v!r})")
            elif not isinstance(v, numbers.Real) or isinstance(v, bool | np.bool_) or not math.isfinite(v):
                raise ParamsError(f"fusion parameter {f.name}: must be a finite number (got {v!r})")
            if v < 0:
                raise ParamsError(f"fusion parameter {f.name}: must be >= 0 (got {v})")
        if self.noise_adapt_max < 1.0:
            raise ParamsError(f"fusion parameter noise_adapt_max: must be >= 1 (got {self.noise_adapt_max})")
        for name in ("rcm_every", "alpha_window"):  # gravity_every may be 0: no gravity updates
            if getattr(self, name) < 1:
                raise ParamsError(f"fusion parameter {name}: must be >= 1 (got {getattr(self, name)})")
        for name in _POSITIVE:
            if not getattr(self, name) > 0:
                raise ParamsError(f"fusion parameter {name}: must be > 0 (got {getattr(self, name)})")
        if not self.depth_min_m * 1e3 <= self.start_depth_mm <= self.depth_max_m * 1e3:
            raise ParamsError(
                f"fusion parameter start_depth_mm: must lie within depth_min_m and depth_max_m "
                f"({self.depth_min_m * 1e3:g}-{self.depth_max_m * 1e3:g} mm, got {self.start_depth_mm:g})"
            )
        if self.history_ms > MAX_HISTORY_MS:  # a snapshot per gyro sample is kept for that long
            raise ParamsError(f"fusion parameter history_ms: at most {MAX_HISTORY_MS:g} (got {self.history_ms:g})")
        if self.max_age_ms > self.history_ms:
            raise ParamsError("fusion parameter max_age_ms: must not exceed history_ms")
        for lo, hi in (("tof_min_mm", "tof_max_mm"), ("depth_min_m", "depth_max_m")):
            if not getattr(self, lo) < getattr(self, hi):
                raise ParamsError(
                    f"fusion parameters {lo} ({getattr(self, lo)}) and {hi} ({getattr(self, hi)}): "
                    f"{lo} must be less than {hi}"
                )

    @property
    def output_delay_ns(self) -> int:
        return int(round(self.output_delay_ms * 1e6))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def with_(self, **changes: Any) -> Params:
        return replace(self, **changes)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "parameters") -> Params:
        if not isinstance(d, dict):
            raise ParamsError(f"{where}: expected a mapping of parameter names to values")
        names = {f.name: f for f in fields(cls)}
        unknown = sorted(str(k) for k in d if k not in names)
        if unknown:
            raise ParamsError(f"{where}: unknown parameter(s) {', '.join(unknown)}")
        out: dict[str, Any] = {}
        for k, v in d.items():
            default = names[k].default
            if isinstance(default, bool):
                if not isinstance(v, bool):  # YAML true/false; "false", "maybe" and 5 are not
                    raise ParamsError(f"{where}: parameter {k}: expected true or false (got {v!r})")
                out[k] = v
            else:
                x = yaml_number(v)
                if x is None:
                    raise ParamsError(f"{where}: parameter {k}: expected a number (got {v!r})")
                if isinstance(default, int):
                    if not x.is_integer():
                        raise ParamsError(f"{where}: parameter {k}: expected a whole number (got {v!r})")
                    out[k] = int(x)
                else:
                    out[k] = x
        try:
            return cls(**out)
        except ParamsError as e:
            raise ParamsError(f"{where}: {e}") from None

    @classmethod
    def load_yaml(cls, path: str | Path) -> Params:
        """A YAML mapping of parameter names (optionally under `fusion_params:`)."""
        p = Path(path)
        doc = read_yaml(p, ParamsError, "not a text/YAML file (a parameter file is YAML)")
        if isinstance(doc, dict) and "fusion_params" in doc:
            doc = doc["fusion_params"]
        return cls.from_dict(doc or {}, where=str(p))


def parse_sensors(text: str | None) -> frozenset[str]:
    """'imu,tof,vision' (or 'all'; None: all) -> frozenset; ParamsError naming an unknown
    sensor or an empty list ("" and "," alike)."""
    if text is None or text.strip() == "all":
        return SENSORS
    out = frozenset(s.strip() for s in text.split(",") if s.strip())
    bad = sorted(out - SENSORS)
    if bad:
        raise ParamsError(f"--sensors: unknown sensor(s) {', '.join(bad)} (choose from imu, tof, vision)")
    if not out:
        raise ParamsError(f"--sensors: empty ({text!r}); give a comma list of imu, tof, vision, or all")
    return out


def mode_name(sensors: frozenset[str]) -> str:
    if sensors == SENSORS:
        return "full"
    return "_".join(s for s in ("imu", "tof", "vision") if s in sensors) + "_only" * (len(sensors) == 1)

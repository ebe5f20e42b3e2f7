"""The tracking filter's parameters: one set, fixed before any evaluation block, used by the
live service and by `tiplog fusion run` alike.

Units are in the field names. Noise densities are continuous-time (per sqrt(Hz) or
per sqrt(s)); measurement sigmas are per update, already inflated for correlated samples as
the paper's noise model prescribes (held-out residual times sqrt(N_c)). The values were set
on bench sessions kept apart from every evaluation.

Each field's docstring (the string under it) is its one-line description, which
`services.fusion.params_file` turns into the table of docs/fusion.md and `tiplog fusion params`.
Reading a parameter file is also there: the filter core reads no files.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from tiplog.userio import yaml_number

SENSORS = frozenset({"imu", "tof", "vision"})
_GATES = ("gate_chi2_1", "gate_chi2_2", "gate_chi2_3", "gate_chi2_4")
_POSITIVE = (
    "tof_map_sigma_deg", "tof_map_sigma_mm", "tof_map_far_sigma_deg", "tof_map_far_sigma_mm", "tof_map_bin_ms",
    "tof_map_gp_sigma_mm", "tof_map_gp_noise_mm", "rest_tau_ms", "rest_chunk_ms", "tip_confirm_ms", "tip_confirm_mm", "accel_map_sigma_deg", "accel_map_sigma_mm",
    "accel_map_bin_ms", "accel_map_every_ms", *_GATES,
    "depth_anchor_tau_s", "depth_ref_tau_s", "depth_anchor_sigma_min_mm", "start_depth_mm",
    "vision_axis_revisit_sigma_deg", "vision_axis_revisit_sigma_mm",
)  # fmt: skip
MAX_HISTORY_MS = 120_000.0  # the rewind history lives in memory: a snapshot per gyro sample


class ParamsError(ValueError):
    """A parameter file or value that cannot be used; the message names the field."""


@dataclass(frozen=True)
class Params:
    # --- timing -------------------------------------------------------------------------
    output_delay_ms: float = 30.0
    """The display stream (live fusion/state) is held this far behind real time, so that IMU and ToF samples in flight
    are in it."""
    history_ms: float = 1500.0
    """Snapshots kept for out-of-sequence rewinds; at least max_age_ms."""
    max_age_ms: float = 1000.0
    """A measurement older than this on arrival is dropped; also how far the settled stream lags."""
    # --- process noise ------------------------------------------------------------------
    gyro_noise_dps_rthz: float = 0.02
    """Gyroscope white noise density."""
    gyro_bias_rw_dps_rts: float = 0.003
    """Gyro-bias random walk at rest."""
    gyro_bias_rw_dps_rts_per_radps: float = 0.35
    """Extra gyro-bias random walk per rad/s of angular rate: the BNO085's bias moves in motion."""
    accel_noise_mps2_rthz: float = 0.03
    """Accelerometer noise density, including the lever arm's angular-acceleration noise."""
    accel_bias_rw_mps2_rts: float = 0.00001
    """Accelerometer-bias random walk, tight: the bias is small and stable, and loose it trades against tilt through the
    lever arm's unmodelled acceleration."""
    tof_offset_rw_mm_rts: float = 1.5
    """Random walk of the ToF range offset b_rho while it is estimated."""
    tof_offset_rw_mm2_per_deg: float = 20.0
    """Extra b_rho variance per degree the tool turns: the range's error is pose-locked, so it changes as the beam
    moves, not with time."""
    alpha_window: int = 4
    """Gyro samples spanned by the angular-acceleration difference of the lever-arm term."""
    alpha_min_span_ms: float = 10.0
    """Least time that difference may span; over less (a backlog stamped 1 ns apart) the lever-arm term is left out for
    that sample."""
    imu_gap_ms: float = 50.0
    """Propagating further than this without an IMU sample uses the no-IMU random walks below."""
    no_imu_rate_rw_dps_rts: float = 40.0
    """Without IMU (ablation, IMU gaps): the random walk standing in for the gyro."""
    no_imu_accel_rw_mps2_rts: float = 0.3
    """Without IMU: the random walk standing in for the accelerometer."""
    rest_bias: bool = True
    """At rest, measure the gyro bias from the gyro itself: without it only vision sees the bias's vertical part, and
    the heading drifts at rest."""
    rest_th_gyro_dps: float = 2.0
    """Rest: every gyro sample within this of its low-pass (VQF's threshold)."""
    rest_th_accel_mps2: float = 0.5
    """Rest: every accelerometer sample within this of its low-pass (VQF's threshold)."""
    rest_tau_ms: float = 500.0
    """Time constant of the rest detector's low-passes."""
    rest_min_ms: float = 1500.0
    """Rest: the thresholds held this long."""
    rest_chunk_ms: float = 500.0
    """The mean rate over each chunk of rest is one bias measurement."""
    rest_agree_gyro_dps: float = 0.1
    """A chunk is used once the next chunk's mean rate is within this of it (a slow sway is not rest); about 3.5 sigma
    of the device's noise."""
    rest_agree_accel_mps2: float = 0.05
    """... and its mean specific force within this; about 5 sigma of the device's noise."""
    rest_bias_only: bool = True
    """While b_rho is held, a rest moves the bias alone (Schmidt update), so that it does not shrink the heading's
    variance through their correlation."""
    rest_sigma_dps: float = 0.01
    """Added to the chunk mean's noise: motion below the rest thresholds."""
    # --- initial uncertainty ------------------------------------------------------------
    init_gyro_bias_dps: float = 0.05
    """Initial gyro-bias sigma."""
    init_accel_bias_mps2: float = 0.002
    """Initial accelerometer-bias sigma (the device's bias is small)."""
    init_tof_offset_mm: float = 5.0
    """Initial b_rho sigma."""
    init_position_mm: float = 2.0
    """Initial tip-position sigma, from the first vision frame."""
    init_velocity_mps: float = 0.02
    """Initial velocity sigma."""
    init_attitude_deg: float = 1.0
    """Initial attitude sigma, from the first vision frame."""
    # --- measurements -------------------------------------------------------------------
    rcm_sigma_mm: float = 0.3
    """The RCM pseudo-measurement (the shaft passes the registered port): the trocar's held-out residual, inflated for
    correlation."""
    rcm_every: int = 1
    """RCM update every n-th gyro sample."""
    gravity_sigma_deg: float = 1.0
    """Gravity direction per accelerometer sample: each sample's tilt noise is white, so all samples at one sigma beat
    fewer trusted more."""
    gravity_sigma_per_excess: float = 20.0
    """Gravity sigma grows by this many degrees per unit of | |a|/g - 1 | (down-weighted, never gated on the norm)."""
    gravity_every: int = 1
    """Gravity update every n-th accelerometer sample (0: none)."""
    tof_sigma_mm: float = 45.0
    """ToF range sigma while vision tips also give the depth: its pose-locked error would only add error."""
    tof_sigma_held_mm: float = 14.0
    """ToF range sigma while b_rho is held and the range is the depth: 3.2 mm white plus 3 mm pose-locked at 100 Hz,
    inflated for correlation."""
    tof_min_mm: float = 20.0
    """Ranges below this are not used."""
    tof_max_mm: float = 400.0
    """Ranges above this are not used."""
    tof_offset_window_ms: float = 250.0
    """b_rho is estimated only within this of an independent vision tip (four frames at 15 frames/s); past it, it is
    held."""
    tof_map: bool = True
    """Record the ToF's pose-locked error while b_rho is free and predict ranges with it while b_rho is held."""
    tof_map_sigma_deg: float = 1.0
    """The ToF map's kernel width in attitude."""
    tof_map_sigma_mm: float = 6.0
    """The ToF map's kernel width in tip position."""
    tof_map_bin_ms: float = 50.0
    """The ToF map records the mean residual and pose per bin of this length."""
    tof_map_window_s: float = 600.0
    """The ToF map keeps this much of the past: the error stays where it was, and a procedure returns to poses minutes
    later."""
    tof_map_prior_weight: float = 2.0
    """Kernel weight at which the map's value counts as much as its prior."""
    tof_map_far: bool = True
    """Where the map recorded little, shrink towards what the field's correlation says there (`TofMap.far_prior`), not
    towards the held b_rho."""
    tof_map_far_sigma_deg: float = 4.0
    """The ToF error field's correlation width in attitude (the bench's field)."""
    tof_map_far_sigma_mm: float = 8.0
    """The ToF error field's correlation width in tip position."""
    tof_map_far_weight: float = 10.0
    """Weight, in bins, of the errors recorded within the field's correlation of the present pose."""
    tof_map_mean_weight: float = 200.0
    """Weight, in bins, of the mean of every recorded error against the held b_rho."""
    tof_map_gp_bins: int = 40
    """The newest this many bins are regressed at the present pose (a Gaussian process), following an error still
    changing along the path; 0: off."""
    tof_map_gp_sigma_mm: float = 3.0
    """That regression's prior sigma: the field's pose-locked error."""
    tof_map_gp_noise_mm: float = 1.5
    """That regression's noise per bin: 3.2 mm white over a bin's five ranges."""
    tof_unmapped_var_factor: float = 3.0
    """While b_rho is held the range's variance grows by up to 1 + this where the map learnt nothing: the pose-locked
    error is unmodelled there."""
    tof_map_settle_ms: float = 1000.0
    """The map learns only from a state tracked this long since its (re)initialisation, not one still converging."""
    depth_anchor_sigma_mm: float = 5.0
    """Without vision the depth is drawn to the working depth with this sigma per depth_anchor_tau_s, so that slow range
    changes turn the heading; 0: off."""
    depth_anchor_tau_s: float = 5.0
    """The depth anchor's sigma holds per this much time, whatever the ToF's rate."""
    depth_ref_tau_s: float = 20.0
    """The working depth is the depth's running mean over this long while vision came."""
    depth_anchor_learn_spread: bool = True
    """With vision, the anchor's sigma is the depth's own spread about the working depth (depth_anchor_sigma_mm until
    vision has shown one)."""
    depth_anchor_sigma_min_mm: float = 1.0
    """The learnt anchor sigma is not below this: tighter drags the depth along when a blackout runs into a depth sweep."""
    accel_map: bool = True
    """Learn the accelerometer's pose-locked tilt from gravity residuals while vision ties the pose, and take it off
    every sample."""
    accel_map_sigma_deg: float = 2.0
    """The accelerometer map's kernel width in attitude (narrower than the error's 6 deg correlation)."""
    accel_map_sigma_mm: float = 8.0
    """The accelerometer map's kernel width in tip position."""
    accel_map_bin_ms: float = 50.0
    """The accelerometer map records per bin of this length."""
    accel_map_window_s: float = 120.0
    """The accelerometer map keeps this much of the past."""
    accel_map_prior_weight: float = 2.0
    """Kernel weight at which the accelerometer map's value counts as much as its prior (zero)."""
    accel_map_every_ms: float = 40.0
    """The correction is looked up this often: the pose moves little in between."""
    accel_map_max_excess: float = 0.03
    """Gravity residuals are recorded only while |a| is within this fraction of g."""
    vision_plane_sigma_deg: float = 0.15
    """Each tangent plane's normal: vision's held-out residual, inflated for its correlation between frames."""
    vision_offset_sigma_mm: float = 0.4
    """The shaft axis' offset from each tangent plane."""
    vision_axis_revisit_weight: float = 0.05
    """Each axis frame's variance is multiplied by 1 + this times the summed kernel weight (widths below) of the axis
    frames applied within the window at poses near the present one: frames at one pose share its pose-locked error, so
    at a held attitude (a depth sweep, a hold, a small fast oscillation) each new frame tells less than the first did,
    while frames along a path that moves on count nearly in full; 0: off."""
    vision_axis_revisit_window_s: float = 10.0
    """How far back applied axis frames are counted."""
    vision_axis_revisit_sigma_deg: float = 5.0
    """The kernel's width in shaft direction: about the pose-locked error's correlation."""
    vision_axis_revisit_sigma_mm: float = 10.0
    """The kernel's width in tip position."""
    vision_ray_sigma_mm: float = 1.0
    """The tip normal to the junction's line of sight."""
    vision_tip_tof_gate_mm: float = 12.0
    """While b_rho is free, a junction whose depth is this far from the latest range's is refused: the labeler's gross
    errors (5-25 mm); so is a start or a re-acquisition from such a frame (0: off)."""
    tip_confirm_chi2: float = 2.0
    """A tip more surprising than this (NIS) waits for the next frame to agree; the tips' NIS runs far below 2, so 2 is
    a surprise; 0: off."""
    tip_confirm_ms: float = 300.0
    """The next tip must come within this to confirm a held one."""
    tip_confirm_mm: float = 3.0
    """... and be off the same way, its residual within this of the held one's."""
    trocar_gate_mm: float = 3.5
    """A frame whose tangent planes miss the RCM by more than this gives its tip but not its axis."""
    gated_out_tip: bool = True
    """Use the tip of frames that fail the trocar gate."""
    junction_min_sin2: float = 0.45
    """The junction ray is used only where it crosses the shaft at an angle whose sine squared is at least this (a
    grazing ray gives no depth)."""
    vision_lock_ms: float = 500.0
    """Vision counts as locked while a frame was accepted within this."""
    # --- innovation gating and divergence ----------------------------------------------
    noise_adapt_tau_s: float = 3.0
    """Noise matching: each adaptive stream's variance factor follows its NIS with this time constant; 0: off."""
    noise_adapt_max: float = 100.0
    """The factor's ceiling; at it the stream is set aside until the factor halves."""
    noise_adapt_step_max_ms: float = 200.0
    """One innovation moves the factor by at most this much time's worth."""
    noise_adapt_tip_power: float = 3.0
    """The vision tip is weighed with its factor to this power: its innovations show the junction's white excess,
    not the pose-locked part the state follows, which grows with it (blur, smoke, distance)."""
    gate_chi2_1: float = 10.83
    """Innovation gate, 1 degree of freedom (99.9 %)."""
    gate_chi2_2: float = 13.82
    """Innovation gate, 2 degrees of freedom (99.9 %)."""
    gate_chi2_4: float = 18.47
    """Innovation gate, 4 degrees of freedom (99.9 %)."""
    gate_chi2_3: float = 16.27
    """Innovation gate, 3 degrees of freedom (99.9 %)."""
    depth_min_m: float = 0.02
    """Without vision the tip is held at least this deep along the shaft (the physical insertion range)."""
    depth_max_m: float = 0.40
    """... and at most this deep."""
    reset_after_vision_rejections: int = 15
    """This many vision frames rejected in a row is a divergence."""
    restart_without_vision_ms: float = 1000.0
    """After a reset, restart from IMU and ToF if no vision frame restarted the filter within this; 0 waits for vision."""
    start_depth_mm: float = 140.0
    """The depth a start without vision assumes and holds as the working depth: the range alone cannot tell depth from
    heading."""
    reacquire_frames: int = 4
    """Re-acquisition: this many frames that pass the trocar gate, fail the axis gate and agree move the state onto
    vision."""
    reacquire_window_ms: float = 1000.0
    """... within this long."""
    reacquire_agree_deg: float = 2.0
    """... agreeing on the heading correction within this."""
    reacquire_agree_mm: float = 6.0
    """... and on the tip shift within this."""
    max_position_sigma_mm: float = 200.0
    """A position sigma above this is a divergence."""
    max_speed_mps: float = 2.0
    """A faster tip is a divergence (hand-held: well under 1 m/s)."""

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
        if self.noise_adapt_tip_power < 1.0:
            raise ParamsError(
                f"fusion parameter noise_adapt_tip_power: must be >= 1 (got {self.noise_adapt_tip_power})"
            )
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

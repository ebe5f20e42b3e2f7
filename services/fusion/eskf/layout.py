"""Where each value sits in the flat arrays the numba kernels take: the error state, the
constants derived from `Params` once per filter, and the rest detector's state. numba reads a
module-level integer as a compile-time constant, so `k[GK_RCM_VAR]` costs what `k[4]` did.

Error state (16): tip position p [m] and velocity v [m/s] in the base frame, attitude error
theta [rad] (right-multiplied: R = R_hat exp(theta)), gyroscope bias b_g [rad/s], accelerometer
bias b_a [m/s^2], ToF range offset b_rho [m]."""

from __future__ import annotations

import math

import numpy as np

N = 16
IP, IV, ITH, IBG, IBA, IBR = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15), 15

_DEG = math.pi / 180.0

# ---------------------------------------------------------------- gyro-step constants
GK_BG_RW = 0  # gyroscope-bias random walk at rest [rad/s/sqrt(s)]
GK_BG_RW_PER_RADPS = 1  # ... and its growth per rad/s of rate
GK_IMU_GAP_S = 2  # past this long without an IMU sample the held specific force says little
GK_NO_IMU_Q = 3  # velocity noise then [m^2/s^3]
GK_RCM_VAR = 4  # RCM pseudo-measurement variance per axis [m^2]
GK_RCM_CHI2 = 5  # its chi-square gate
GK_MAX_POS_VAR = 6  # `health`: position variance beyond which the state is reset [m^2]
GK_MAX_SPEED2 = 7  # ... and squared speed [m^2/s^2]
GK_BRHO_PER_RAD = 8  # ToF-offset random walk per radian turned [m^2/rad]
GK_SIZE = 9

# ---------------------------------------------------------------- gravity-update constants
GR_SIGMA = 0  # direction standard deviation per axis [rad] ...
GR_SIGMA_PER_EXCESS = 1  # ... plus this per unit of | |f|/g - 1 |
GR_CHI2 = 2  # chi-square gate
GR_SIZE = 3

# ---------------------------------------------------------------- rest-detector constants
RK_TAU_S = 0  # low-pass time constant [s]
RK_TH_GYRO2 = 1  # squared distance of a gyro sample from its low-pass [(rad/s)^2] ...
RK_TH_ACCEL2 = 2  # ... and of an accelerometer sample [(m/s^2)^2], within which it is still
RK_MIN_S = 3  # still this long before chunks are summed
RK_CHUNK_S = 4  # chunk length [s]
RK_GAP_S = 5  # a longer gap between samples restarts the channel
RK_AGREE_GYRO2 = 6  # consecutive chunks' gyro means agree within this [(rad/s)^2] ...
RK_AGREE_ACCEL2 = 7  # ... and their accel means within this [(m/s^2)^2]
RK_SIZE = 8

# ---------------------------------------------------------------- rest-detector state
# The gyro channel at offset +0, the accelerometer channel at +3 (vectors) or +1 (scalars).
REST_LP = 0  # (3, 3) low-passed gyro, low-passed accel
REST_T_LAST = 6  # (1, 1) each channel's last sample time [s]
REST_SINCE = 8  # since when every sample was near its low-pass [s] (NaN: moving)
REST_SUM = 9  # (3, 3) the current chunk's gyro and accel sums
REST_COUNT = 15  # (1, 1) ... their counts
REST_CHUNK_T0 = 17  # ... and its start [s]
REST_PREV_GYRO = 18  # (3) the completed chunk's gyro mean ...
REST_PREV_ACCEL = 21  # (3) ... and accel mean
REST_HAVE_PREV = 24  # 1.0 when there is a completed chunk
REST_RATE = 25  # (3) the mean rate ready to apply [rad/s]
REST_SIZE = 28


def rest_constants(
    tau_s: float, th_gyro_radps: float, th_accel_mps2: float, min_s: float, chunk_s: float, gap_s: float,
    agree_gyro_radps: float, agree_accel_mps2: float,
) -> np.ndarray:  # fmt: skip
    """The rest detector's constants (`kernels.rest.rest_sample`), thresholds given as distances."""
    k = np.empty(RK_SIZE)
    k[RK_TAU_S] = tau_s
    k[RK_TH_GYRO2] = th_gyro_radps**2
    k[RK_TH_ACCEL2] = th_accel_mps2**2
    k[RK_MIN_S] = min_s
    k[RK_CHUNK_S] = chunk_s
    k[RK_GAP_S] = gap_s
    k[RK_AGREE_GYRO2] = agree_gyro_radps**2
    k[RK_AGREE_ACCEL2] = agree_accel_mps2**2
    return k

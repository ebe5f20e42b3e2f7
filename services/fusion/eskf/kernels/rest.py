"""The rest detector, shared by the tracking filter and the attitude filter
(`services.fusion.attitude`): VQF's still test, then chunks of samples taken for rest only
once the next chunk agrees. Its state and constants are flat arrays (`layout.REST_*`,
`layout.RK_*`) so that the compiled steps carry them."""

from __future__ import annotations

import math

import numpy as np

from services.fusion.eskf.jit_cache import njit
from services.fusion.eskf.layout import (
    REST_CHUNK_T0,
    REST_COUNT,
    REST_HAVE_PREV,
    REST_LP,
    REST_PREV_ACCEL,
    REST_PREV_GYRO,
    REST_RATE,
    REST_SINCE,
    REST_SIZE,
    REST_SUM,
    REST_T_LAST,
    RK_AGREE_ACCEL2,
    RK_AGREE_GYRO2,
    RK_CHUNK_S,
    RK_GAP_S,
    RK_MIN_S,
    RK_TAU_S,
    RK_TH_GYRO2,
)


def rest_init() -> np.ndarray:
    """A rest detector's state (`State.rest`, slots `layout.REST_*`): no sample yet."""
    r = np.zeros(REST_SIZE)
    r[REST_T_LAST : REST_T_LAST + 2] = np.nan
    r[REST_SINCE] = np.nan
    return r


@njit(cache=True)
def _rest_break(rest: np.ndarray) -> None:
    rest[REST_SINCE] = np.nan
    rest[REST_COUNT] = rest[REST_COUNT + 1] = 0.0
    rest[REST_HAVE_PREV] = 0.0


@njit(cache=True)
def rest_sample(rest: np.ndarray, x: np.ndarray, t_s: float, accel: int, k: np.ndarray) -> bool:
    """One gyro (accel=0, x in rad/s) or accelerometer (accel=1, m/s^2) sample through the rest
    detector (state `rest`, constants k: `layout.REST_*`, `layout.RK_*`). First VQF's test: every
    sample of both near its channel's low-pass for k[RK_MIN_S]; a gap over k[RK_GAP_S] restarts
    the channel. Then the samples are averaged in chunks of k[RK_CHUNK_S], and a chunk is taken
    for rest only when the next one agrees with it: a slow smooth motion stays near its
    low-pass, but its mean rate or its gravity moves from chunk to chunk. A chunk's mean rate is
    then released into rest[REST_RATE:] (True returned); any sample off its low-pass drops the
    chunks not yet released, so none from a motion's onset is used."""
    lp, it = REST_LP + 3 * accel, REST_T_LAST + accel
    t_last = rest[it]
    rest[it] = t_s
    if not t_s - t_last <= k[RK_GAP_S]:  # the channel's first sample (NaN), or after a gap
        for i in range(3):
            rest[lp + i] = x[i]
        _rest_break(rest)
        return False
    a = 1.0 - math.exp(-(t_s - t_last) / k[RK_TAU_S])
    d2 = 0.0
    for i in range(3):
        rest[lp + i] += a * (x[i] - rest[lp + i])
        e = x[i] - rest[lp + i]
        d2 += e * e
    if d2 >= k[RK_TH_GYRO2 + accel]:  # RK_TH_ACCEL2 follows RK_TH_GYRO2
        _rest_break(rest)
        return False
    if math.isnan(rest[REST_SINCE]):
        rest[REST_SINCE] = t_s
        return False
    if t_s - rest[REST_SINCE] < k[RK_MIN_S]:
        return False
    if rest[REST_COUNT] + rest[REST_COUNT + 1] == 0.0:
        rest[REST_CHUNK_T0] = t_s
        for i in range(REST_SUM, REST_SUM + 6):
            rest[i] = 0.0
    for i in range(3):
        rest[REST_SUM + 3 * accel + i] += x[i]
    rest[REST_COUNT + accel] += 1.0
    if accel or t_s - rest[REST_CHUNK_T0] < k[RK_CHUNK_S] or rest[REST_COUNT + 1] == 0.0:
        return False
    g = np.empty(3)
    f = np.empty(3)
    dg = df = 0.0
    for i in range(3):
        g[i] = rest[REST_SUM + i] / rest[REST_COUNT]
        f[i] = rest[REST_SUM + 3 + i] / rest[REST_COUNT + 1]
        dg += (g[i] - rest[REST_PREV_GYRO + i]) ** 2
        df += (f[i] - rest[REST_PREV_ACCEL + i]) ** 2
    ready = rest[REST_HAVE_PREV] > 0.0 and dg < k[RK_AGREE_GYRO2] and df < k[RK_AGREE_ACCEL2]
    for i in range(3):
        rest[REST_RATE + i] = rest[REST_PREV_GYRO + i]
        rest[REST_PREV_GYRO + i] = g[i]
        rest[REST_PREV_ACCEL + i] = f[i]
    # a disagreeing pair: neither is rest
    rest[REST_HAVE_PREV] = 1.0 if rest[REST_HAVE_PREV] == 0.0 or ready else 0.0
    rest[REST_COUNT] = rest[REST_COUNT + 1] = 0.0
    return ready

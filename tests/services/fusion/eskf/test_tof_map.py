"""The ToF's pose-locked error map: what it predicts near and far from recorded poses, the
prior it shrinks to, its window, and that a rewind leaves it as if the discarded samples had
never come."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.fusion.eskf.maps import AccelMap, TofMap
from tiplog.geometry import so3_exp

P0 = np.array([0.7, 0.0, 0.18])


def _map(**kw) -> TofMap:
    args = dict(sigma_deg=1.0, sigma_mm=6.0, bin_ms=50.0, window_s=120.0, prior_weight=2.0) | kw
    return TofMap(**args)


def _roll(deg: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, math.radians(deg)]))


def _fill(m: TofMap, t0_ns: int, seconds: float, roll_deg: float, err_m: float) -> int:
    """ToF samples at 100 Hz at one pose, each err_m off; returns the next time."""
    t = t0_ns
    for _ in range(int(seconds * 100)):
        m.add(t, m.key(_roll(roll_deg), P0), err_m)
        t += 10_000_000
    return t


def test_near_a_recorded_pose_it_gives_that_pose_error_and_far_from_it_the_prior():
    m = _map()
    assert m.predict(0, _roll(0.0), P0, prior=0.001) == (0.001, 0.0)  # nothing recorded yet
    t = _fill(m, 0, 2.0, 0.0, 0.004)
    t = _fill(m, t, 2.0, 5.0, -0.002)
    assert len(m) >= 70  # 50 ms bins over 4 s
    assert m.predict(t, _roll(0.0), P0, prior=0.0)[0] == pytest.approx(0.004, rel=0.1)
    assert m.predict(t, _roll(5.0), P0, prior=0.0)[0] == pytest.approx(-0.002, rel=0.1)
    assert m.predict(t, _roll(20.0), P0, prior=0.001)[0] == pytest.approx(0.001, abs=1e-6)
    assert m.predict(t, _roll(20.0), P0, prior=0.001)[1] < 1e-6 < 30.0 < m.predict(t, _roll(0.0), P0, 0.0)[1]
    far = P0 + np.array([0.0, 0.0, 0.05])  # 50 mm deeper: another part of the target
    assert m.predict(t, _roll(0.0), far, prior=0.001)[0] == pytest.approx(0.001, abs=1e-6)
    # between the two: a blend, shrunk towards the prior where few samples are near
    mid = m.predict(t, _roll(2.5), P0, prior=0.0)[0]
    assert -0.002 < mid < 0.004


def test_where_little_is_recorded_it_expects_b_rho_near_its_pose_the_errors_near_here_or_their_mean():
    """`far_prior`, the prior `predict` is shrunk to while b_rho is held: b_rho near the pose of
    the newest bin (where b_rho was last learnt), the errors recorded within the field's
    correlation (4 deg, 8 mm) of the pose further off (shrunk towards the mean by `far_weight`
    bins), and their mean over the window where nothing recorded is near (shrunk towards b_rho
    by `mean_weight` bins). Here without the newest bins' trend (`gp_bins` 0), which the next
    test covers."""
    m = _map(far_weight=10.0, mean_weight=0.0, gp_bins=0)
    assert m.far_prior(0, _roll(0.0), P0, brho=0.006) == 0.006  # nothing recorded
    t = _fill(m, 0, 2.0, 20.0, 0.004)
    t = _fill(m, t, 2.0, -20.0, -0.002)
    t = _fill(m, t, 1.0, 0.0, 0.001)  # the newest bins: where b_rho was last learnt
    mean = float(m.entries()[2].mean())
    assert 0.0009 < mean < 0.0011  # 40 bins at 4 mm, 40 at -2 mm, 19 at 1 mm (the 20th still open)
    assert m.far_prior(t, _roll(0.0), P0, brho=0.006) == pytest.approx(0.006, abs=1e-9)
    # 40 bins at each of the older poses, shrunk towards the mean as if it were 10 bins
    assert m.far_prior(t, _roll(20.0), P0, brho=0.006) == pytest.approx((40 * 0.004 + 10 * mean) / 50, rel=1e-4)
    assert m.far_prior(t, _roll(-20.0), P0, brho=0.006) == pytest.approx((40 * -0.002 + 10 * mean) / 50, rel=1e-4)
    assert m.far_prior(t, _roll(70.0), P0, brho=0.006) == pytest.approx(mean, rel=1e-9)
    # within the correlation of b_rho's pose, a blend of b_rho and what is recorded near
    assert 0.001 < m.far_prior(t, _roll(4.0), P0, brho=0.006) < 0.006
    # few bins: the mean is shrunk towards b_rho, by as many bins as mean_weight
    w = _map(mean_weight=99.0, gp_bins=0)
    _fill(w, 0, 2.0, 20.0, 0.004)
    _fill(w, 2_000_000_000, 2.0, -20.0, -0.002)
    t = _fill(w, 4_000_000_000, 1.0, 0.0, 0.001)
    n = len(w)
    assert w.far_prior(t, _roll(70.0), P0, brho=0.006) == pytest.approx((mean * n + 99 * 0.006) / (n + 99), rel=1e-9)


def _path(m: TofMap, seconds: float, deg_per_s: float, mm_per_deg: float) -> int:
    """ToF samples at 100 Hz along a turn from roll 0 at deg_per_s, their error growing by
    mm_per_deg along it; returns the next time."""
    t = 0
    for k in range(int(seconds * 100)):
        roll = deg_per_s * k / 100
        m.add(t, m.key(_roll(roll), P0), roll * mm_per_deg * 1e-3)
        t += 10_000_000
    return t


def test_along_a_path_the_held_prior_follows_the_newest_bins_and_their_trend():
    """With `gp_bins` bins in the window, `far_prior` regresses the error on the newest of them:
    a turn that took the error from 0 to 3 mm over 3 deg, with b_rho a lagging 1.5 mm, expects
    the error recorded along the path, and past its end more than the newest bin's; the prior
    without the trend stays at b_rho. Far from the path, what is recorded near, both."""
    kw = dict(far_weight=10.0, mean_weight=0.0)
    m, old = _map(gp_bins=40, **kw), _map(gp_bins=0, **kw)
    for x in (m, old):
        t = _path(x, 3.0, 1.0, 1.0)
    newest = float(m.entries()[2][-1])
    assert len(m) >= 50 and 0.0028 < newest < 0.003
    assert m.far_prior(t, _roll(2.0), P0, brho=0.0015) == pytest.approx(0.002, abs=1.5e-4)
    ahead = m.far_prior(t, _roll(3.5), P0, brho=0.0015)
    assert newest < ahead < 0.0035
    for roll in (2.0, 3.5):
        assert old.far_prior(t, _roll(roll), P0, brho=0.0015) == pytest.approx(0.0015, abs=2e-5)
    mean = float(m.entries()[2].mean())
    assert m.far_prior(t, _roll(60.0), P0, brho=0.0015) == pytest.approx(mean, rel=1e-6)
    assert old.far_prior(t, _roll(60.0), P0, brho=0.0015) == pytest.approx(mean, rel=1e-6)
    # the regression is solved again whenever the bins change, a rewind too
    mark = m.mark()
    for k in range(100):
        m.add(t + k * 10_000_000, m.key(_roll(3.0), P0), 0.02)
    assert m.far_prior(t + 10**9, _roll(3.5), P0, brho=0.0015) > 0.005
    m.rewind(mark)
    assert m.far_prior(t, _roll(3.5), P0, brho=0.0015) == ahead
    # fewer bins than gp_bins: the prior without the trend
    few = _map(gp_bins=100, **kw)
    t = _path(few, 3.0, 1.0, 1.0)
    assert few.far_prior(t, _roll(3.5), P0, 0.0015) == old.far_prior(t, _roll(3.5), P0, 0.0015)


def test_entries_older_than_the_window_are_not_used():
    m = _map(window_s=5.0)
    t = _fill(m, 0, 2.0, 0.0, 0.004)
    assert m.predict(t, _roll(0.0), P0, prior=0.0)[0] == pytest.approx(0.004, rel=0.1)
    t = _fill(m, t + 10_000_000_000, 1.0, 30.0, 0.0)  # 10 s later, elsewhere
    assert m.predict(t, _roll(0.0), P0, prior=0.0)[0] == 0.0


@pytest.mark.parametrize("cut", [250, 252, 254, 399])  # a bin's last sample, inside one, the open bin
def test_a_rewind_forgets_exactly_what_came_after_its_mark(cut):
    """The rewound map equals one that never saw what came after the mark, also when the mark
    falls inside a bin (samples share the state's time with the snapshot, so it is the count)."""
    rng = np.random.default_rng(3)
    poses = [(rng.uniform(-3, 3), rng.normal(size=3) * 0.003, rng.normal() * 0.003) for _ in range(400)]
    once = _map()
    for k, (roll, dp, e) in enumerate(poses):
        once.add(k * 10_000_000, once.key(_roll(roll), P0 + dp), e)
    # the rewound map takes other samples after the mark, then rewinds and takes the same ones
    other = _map()
    for k, (roll, dp, e) in enumerate(poses[: cut + 1]):
        other.add(k * 10_000_000, other.key(_roll(roll), P0 + dp), e)
    mark = other.mark()
    for k in range(cut + 1, cut + 50):  # at the poses that will come again, 50 mm off
        roll, dp, _ = poses[k % 400]
        other.add(k * 10_000_000, other.key(_roll(roll), P0 + dp), 0.05)
    other.far_prior((cut + 50) * 10_000_000, _roll(0.0), P0, 0.002)  # solved with what is then cut
    other.rewind(mark)
    for k in range(cut + 1, 400):
        roll, dp, e = poses[k]
        other.add(k * 10_000_000, other.key(_roll(roll), P0 + dp), e)
    for x, y in zip(once.entries(), other.entries(), strict=True):
        np.testing.assert_array_equal(x, y)
    q = [(_roll(r), P0 + d) for r, d, _ in poses[::37]]
    a = [once.predict(400 * 10_000_000, R, p, 0.0)[0] for R, p in q]
    b = [other.predict(400 * 10_000_000, R, p, 0.0)[0] for R, p in q]
    assert a == b and not np.allclose(a, 0.0)
    a = [once.far_prior(400 * 10_000_000, R, p + [0.0, 0.0, 0.01], 0.002) for R, p in q]
    b = [other.far_prior(400 * 10_000_000, R, p + [0.0, 0.0, 0.01], 0.002) for R, p in q]
    assert a == b and len(set(a)) == len(a)


@pytest.mark.parametrize(("last", "kept"), [(283, 284), (123, 120)])
def test_a_reset_forgets_the_samples_after_a_time(last, kept):
    """Within a rewind's reach (1.5 s) exactly; further back, the bin that straddles the time
    (50 ms) goes whole."""
    m, ref = _map(), _map()
    for k in range(300):
        for mm in (m, ref) if k < kept else (m,):
            mm.add(k * 10_000_000, mm.key(_roll(k * 0.01), P0), 0.001 * k)
    m.forget_after(last * 10_000_000)
    assert m.mark() == ref.mark() == kept
    for mm in (m, ref):
        mm.add(400 * 10_000_000, mm.key(_roll(0.0), P0), 0.0)
    for x, y in zip(m.entries(), ref.entries(), strict=True):
        np.testing.assert_array_equal(x, y)


def test_a_full_map_keeps_what_its_window_needs():
    """Many windows' worth of samples (the map compacts itself many times): a prediction is
    still the kernel mean over exactly the bins within the window."""
    m = _map(window_s=0.5, prior_weight=0.0, mean_weight=0.0)
    rng = np.random.default_rng(5)
    rolls = np.cumsum(rng.normal(size=2000) * 0.2)
    for k, roll in enumerate(rolls):
        m.add(k * 10_000_000, m.key(_roll(roll), P0), 0.001 * math.sin(math.radians(roll) * 20))
    assert len(m) < 200  # bounded, though 400 bins were recorded
    t = 1999 * 10_000_000
    # the bins within the window, recomputed from what was added: 50 ms bins of 5 samples, the
    # last one still open (it is entered when the next bin starts)
    bins = [(b, range(b * 5, b * 5 + 5)) for b in range(399)]
    keep = [rolls[list(idx)] for b, idx in bins if (b * 5 + 4) * 10_000_000 >= t - 500_000_000]
    q = _roll(rolls[-1])
    num = den = 0.0
    for rs in keep:
        R = np.mean([_roll(r) for r in rs], axis=0)
        e = np.mean([0.001 * math.sin(math.radians(r) * 20) for r in rs])
        d2 = np.sum((R - q) ** 2) / (2 * math.radians(1.0) ** 2)
        w = math.exp(-0.5 * d2)
        num, den = num + w * e, den + w
    assert len(keep) < len(m)  # older bins are kept but not used
    assert m.predict(t, q, P0, 0.0)[0] == pytest.approx(num / den, rel=1e-9)
    # far from every pose, the far prior is the mean of those bins, from the running sum
    mean = np.mean([np.mean([0.001 * math.sin(math.radians(r) * 20) for r in rs]) for rs in keep])
    assert m.far_prior(t, q, P0 + [0.0, 0.0, 0.5], 0.003) == pytest.approx(mean, rel=1e-9, abs=1e-15)


def _bin(R: np.ndarray, p: np.ndarray, e, n: int = 4) -> np.ndarray:
    """A bin as `kernels.steps.gravity_step` sums it: n samples at (R, p), each e off."""
    acc = np.zeros(16)
    acc[:9], acc[9:12], acc[12:15], acc[15] = n * R.ravel(), n * p, n * np.asarray(e), n
    return acc


def test_the_accelerometer_map_keeps_vectors_and_rewinds_whole_bins():
    """Per-component means near a recorded pose, shrunk towards zero by the prior weight; zero
    far from it; a rewind or a reset drops exactly the bins taken after it."""
    m = AccelMap(sigma_deg=2.0, sigma_mm=8.0, bin_ms=50.0, window_s=120.0, prior_weight=2.0)
    assert np.array_equal(m.predict(0, _roll(0.0), P0), np.zeros(3))
    here, there = np.array([0.03, -0.01, 0.002]), np.array([-0.05, 0.0, 0.04])
    t = 0
    for _ in range(40):
        t += 50_000_000
        m.add_bin(t, _bin(_roll(0.0), P0, here))
    mark, t_mark = m.mark(), t
    for _ in range(20):
        t += 50_000_000
        m.add_bin(t, _bin(_roll(12.0), P0, there))
    assert len(m) == 60 and m.entries()[2].shape == (60, 3)
    np.testing.assert_allclose(m.predict(t, _roll(0.0), P0), 40 / 42 * here, atol=1e-6)
    np.testing.assert_allclose(m.predict(t, _roll(12.0), P0), 20 / 22 * there, atol=1e-6)
    np.testing.assert_allclose(m.predict(t, _roll(40.0), P0), np.zeros(3), atol=1e-12)
    m.rewind(mark)
    assert len(m) == 40 and m.mark() == mark
    np.testing.assert_allclose(m.predict(t, _roll(12.0), P0), np.zeros(3), atol=1e-6)
    for _ in range(5):
        t += 50_000_000
        m.add_bin(t, _bin(_roll(12.0), P0, there))
    m.forget_after(t_mark + 1)
    assert len(m) == 40 and m.mark() == mark
    np.testing.assert_allclose(m.predict(t, _roll(0.0), P0), 40 / 42 * here, atol=1e-6)

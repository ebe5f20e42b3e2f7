"""The ToF's pose-locked error, learnt online while vision gives an independent tip.

The time-of-flight range is off by a few millimetres that depend on where the beam lands and
how (3 mm across poses, 0.4 mm over repeats of one pose): a single offset b_rho follows it
while the junction is in view, but once vision is lost b_rho is held at the value of the last
pose and the depth takes the difference between poses. `TofMap` keeps, for the poses visited
with vision, the range error against the filter's geometric prediction (grouped into short
bins), and gives for a pose the kernel-weighted mean of the errors recorded near it, shrunk
towards a prior where few were recorded (`far_prior`: near the path the newest bins took, their
trend, or the held b_rho while there are few; the errors recorded within the error's
correlation further off, their mean over the whole window further still). It is append-only
in time so that a rewind only has to cut its tail.

The accelerometer's reading is turned by a pose-locked error too (0.21 deg across poses, the
same on every pass): `AccelMap` keeps, for the poses visited with vision, the gravity update's
residual (3 components), and the filter takes the kernel-weighted mean at the present pose off
every sample. Its bins are summed in the filter's state (`kernels.steps.gravity_step`), which a
rewind restores, so the map takes them whole.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from services.fusion.eskf.kernels.pose_map import kernel_mean


class _PoseEntries:
    """Errors (`dim` components) at poses (R (3, 3), p (3,)), one entry per bin of `bin_ns`,
    the newest kept and those within `window_ns` used; `predict` gives their kernel-weighted
    mean at a pose."""

    def __init__(
        self, sigma_deg: float, sigma_mm: float, bin_ms: float, window_s: float, prior_weight: float, dim: int
    ):
        self._wk = self._weights(sigma_deg, sigma_mm)
        self.bin_ns = int(bin_ms * 1e6)
        self.window_ns = int(window_s * 1e9)
        self.prior_weight = float(prior_weight)
        self.dim = int(dim)
        # bins are distinct, so the newest `keep` entries span at least twice the window: a
        # query a rewind's length in the past still finds all it needs after a compaction
        self._keep = 2 * (self.window_ns // max(self.bin_ns, 1)) + 4
        self._K = np.empty((2 * self._keep, 12))
        self._k2 = np.empty(2 * self._keep)  # each key's weighted square norm
        self._e = np.empty((2 * self._keep, self.dim))
        self._t = np.empty(2 * self._keep, np.int64)  # last sample time of each bin
        self._c = np.empty(2 * self._keep, np.int64)  # samples added up to the end of each bin
        self._n = 0
        self._added = 0
        self._sum = np.empty(self.dim)
        self._columns = [self._K, self._k2, self._e, self._t, self._c]  # what a compaction moves
        self._version = 0  # changes whenever the bins do

    def __len__(self) -> int:
        return self._n

    @staticmethod
    def _weights(sigma_deg: float, sigma_mm: float) -> np.ndarray:
        """A kernel's weight per key component: |R_i - R|_F^2 ~ 2 theta^2, so the orientation
        part of the distance is theta^2 / sigma^2."""
        wr = 1.0 / (2.0 * math.radians(sigma_deg) ** 2)
        wp = 1.0 / (sigma_mm * 1e-3) ** 2
        return np.concatenate((np.full(9, wr), np.full(3, wp)))

    @staticmethod
    def key(R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """A pose as the map stores it (a copy: take it before an update moves the state)."""
        return np.concatenate((R.ravel(), p))

    def _append(self, t_ns: int, key: np.ndarray, e) -> None:
        if self._n == len(self._t):  # full: keep the newest half (nothing grows)
            k = self._keep
            for a in self._columns:
                a[:k] = a[-k:]
            self._n = k
        self._version += 1
        i = self._n
        self._K[i] = key
        self._k2[i] = self._wk @ (key * key)
        self._e[i] = e
        self._t[i] = t_ns
        self._c[i] = self._added
        self._n += 1

    def entries(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(bin times (n,), pose keys (n, 12), errors (n,) at dim 1, else (n, dim)) held now,
        oldest first: copies."""
        n = self._n
        e = self._e[:n, 0] if self.dim == 1 else self._e[:n]
        return self._t[:n].copy(), self._K[:n].copy(), e.copy()

    def _kernel_sum(self, t_ns: int, R: np.ndarray, p: np.ndarray) -> float:
        """The kernel weight of the entries within the window at (R, p); their weighted sum of
        errors is left in self._sum."""
        return kernel_mean(
            self._K, self._k2, self._e, self._t, self._n, int(t_ns - self.window_ns), R, p, self._wk, self._sum
        )


class TofMap(_PoseEntries):
    """Range errors e [m] at poses, binned every `bin_ns` as they are added, kept `window_ns`."""

    def __init__(
        self,
        sigma_deg: float,
        sigma_mm: float,
        bin_ms: float,
        window_s: float,
        prior_weight: float,
        rewind_ms: float = 1500.0,
        far_sigma_deg: float = 4.0,
        far_sigma_mm: float = 8.0,
        far_weight: float = 10.0,
        mean_weight: float = 200.0,
        gp_bins: int = 40,
        gp_sigma_mm: float = 3.0,
        gp_noise_mm: float = 1.5,
    ):
        super().__init__(sigma_deg, sigma_mm, bin_ms, window_s, prior_weight, 1)
        # `far_prior`'s kernel (the error's correlation over the pose), each entry's weighted
        # square norm under it, and the running sum of the errors (a window's sum in O(1))
        self._wk_far = self._weights(far_sigma_deg, far_sigma_mm)
        self._k2_far = np.empty(len(self._t))
        self._cum = np.empty(len(self._t))
        self._columns += [self._k2_far, self._cum]
        self.far_weight = float(far_weight)
        self.mean_weight = float(mean_weight)
        self._sum_far = np.empty(1)
        self.gp_bins = int(gp_bins)
        self.gp_var = (gp_sigma_mm * 1e-3) ** 2
        self.gp_noise = (gp_noise_mm * 1e-3) ** 2
        self._gp_cache: tuple | None = None  # (the map's version, the bins' keys, norms, solve)
        self._pending: list[tuple[int, np.ndarray, float]] = []
        # the samples of the newest bins, as far back as a rewind may go: a rewind into a bin
        # keeps that bin's earlier samples (they are not replayed)
        self._members: deque[list[tuple[int, np.ndarray, float]]] = deque(
            maxlen=int(rewind_ms * 1e6 // max(self.bin_ns, 1)) + 2
        )

    def add(self, t_ns: int, key: np.ndarray, e: float) -> None:
        """The range error e [m] at the pose `key` (from `key()`), at time t_ns."""
        if self._pending and t_ns // self.bin_ns != self._pending[0][0] // self.bin_ns:
            self._flush()
        self._pending.append((int(t_ns), key, float(e)))
        self._added += 1

    def mark(self) -> int:
        """Where the map stands now, for `rewind` (the number of samples added)."""
        return self._added

    def _append(self, t_ns: int, key: np.ndarray, e) -> None:
        super()._append(t_ns, key, e)
        i = self._n - 1
        self._k2_far[i] = self._wk_far @ (key * key)
        self._cum[i] = (self._cum[i - 1] if i else 0.0) + float(e)

    def _flush(self) -> None:
        pend = self._pending
        self._pending = []
        k = pend[0][1].copy()
        for _, k1, _ in pend[1:]:
            k += k1
        self._append(pend[-1][0], k / len(pend), sum(e for _, _, e in pend) / len(pend))
        self._members.append(pend)

    def rewind(self, mark: int) -> None:
        """Back to where `mark()` said it stood: a rewind replays what came after, so a rewound
        run equals one that had every measurement in order. (Samples are stamped with the
        state's time, which a replayed ToF range shares with the snapshot: time cannot tell.)"""
        if mark >= self._added:
            return
        self._version += 1
        flushed = self._added - len(self._pending)
        self._added = mark
        if mark > flushed or flushed == 0:
            del self._pending[mark - flushed :]
            return
        # a bin is entered when the next one starts: at the mark, the bin ending there was open
        n = int(np.searchsorted(self._c[: self._n], mark, side="left"))
        cut, end = self._n - n, int(self._c[n])
        self._pending = []
        if len(self._members) < cut:  # further back than a rewind goes: whole bins
            self._n = int(np.searchsorted(self._c[: self._n], mark, side="right"))
            self._members.clear()
            return
        self._n = n
        for _ in range(cut):
            straddling = self._members.pop()
        self._pending = straddling[: max(0, mark - (end - len(straddling)))]

    def forget_after(self, t_ns: int) -> None:
        """Forget the samples added after t_ns (a reset: they came from a state going wrong)."""
        n = int(np.searchsorted(self._t[: self._n], t_ns, side="right"))  # bins ending by t_ns
        if n == self._n:
            later = [i for i, x in enumerate(self._pending) if x[0] > t_ns]
            if later:
                self.rewind(self._added - len(self._pending) + later[0])
            return
        j = len(self._members) - (self._n - n)  # bin n's samples, if still kept
        first = self._members[j] if j >= 0 else []
        start = int(self._c[n]) - len(first) if first else (int(self._c[n - 1]) if n else 0)
        self.rewind(start + sum(1 for x in first if x[0] <= t_ns))

    def far_prior(self, t_ns: int, R: np.ndarray, p: np.ndarray, brho: float) -> float:
        """The range error to expect at (R, p) where the map recorded little: what `predict`
        shrinks its near errors towards while b_rho is held.

        The error is a smooth field over the pose, so b_rho, learnt at the pose of the newest
        bin, tells it only within the field's correlation of that pose (the far kernel's
        widths). Beyond, the errors recorded within that correlation of (R, p) tell it, and
        beyond those, their mean over the window: the field's mean is the best guess at a pose
        that nothing recorded is near. The errors near (R, p) are shrunk towards that mean as
        if it were `far_weight` bins, and the mean towards b_rho as if b_rho were `mean_weight`
        bins, so that a few bins recorded long ago do not outweigh b_rho, learnt over many
        ranges. b_rho where nothing is recorded.

        Once the window holds `gp_bins` bins, the newest of them stand for b_rho: b_rho is a
        slow average that lags an error changing along the path, so the error is regressed on
        those bins instead (`_trend`), about what is recorded near (R, p)."""
        n = self._n
        t_lo = int(t_ns - self.window_ns)
        lo = int(np.searchsorted(self._t[:n], t_lo, side="left"))
        if lo >= n:
            return brho
        wm = self.mean_weight
        mean = (float(self._cum[n - 1] - self._cum[lo] + self._e[lo, 0]) + wm * brho) / (n - lo + wm)
        sw = kernel_mean(self._K, self._k2_far, self._e, self._t, n, t_lo, R, p, self._wk_far, self._sum_far)
        wf = self.far_weight
        near = (float(self._sum_far[0]) + wf * mean) / (sw + wf) if sw + wf > 0.0 else mean
        if self.gp_bins > 0 and n - lo >= self.gp_bins:
            return self._trend(n, R, p, near)
        d = self._K[n - 1] - self.key(R, p)
        corr = math.exp(-0.5 * float(self._wk_far @ (d * d)))  # the field's correlation with b_rho's pose
        return corr * brho + (1.0 - corr) * near

    def _trend(self, n: int, R: np.ndarray, p: np.ndarray, mean: float) -> float:
        """The error at (R, p) regressed on the newest `gp_bins` bins: a Gaussian process with
        the field's correlation (the far kernel), standard deviation `gp_sigma` and a bin's
        noise `gp_noise` about `mean`. Near the path those bins took it follows their trend;
        far from it, `mean`. The bins' solve is kept until the map changes (while b_rho is
        held nothing is added, so a gap solves once)."""
        if self._gp_cache is None or self._gp_cache[0] != self._version:
            a = n - self.gp_bins
            K, k2, e = self._K[a:n].copy(), self._k2_far[a:n].copy(), self._e[a:n, 0]
            A = self._gp_cov(K, k2, K, k2) + self.gp_noise * np.eye(len(k2))
            cf = np.linalg.cholesky(A)
            sol = np.linalg.solve(cf.T, np.linalg.solve(cf, np.stack((e, np.ones(len(k2))), 1)))
            self._gp_cache = (self._version, K, k2, sol)
        _, K, k2, sol = self._gp_cache
        q = self.key(R, p)[None, :]
        ks = self._gp_cov(K, k2, q, (q * q) @ self._wk_far)[:, 0]
        return mean + float(ks @ sol[:, 0]) - mean * float(ks @ sol[:, 1])

    def _gp_cov(self, K: np.ndarray, k2: np.ndarray, Q: np.ndarray, q2: np.ndarray) -> np.ndarray:
        """The regression's covariance (len(K), len(Q)) between keys K and keys Q (k2, q2: their
        square norms under the far kernel W): gp_var exp(-|K_i - Q_j|^2_W / 2)."""
        d2 = k2[:, None] + q2[None, :] - 2.0 * (K * self._wk_far) @ Q.T
        return self.gp_var * np.exp(-0.5 * np.maximum(d2, 0.0))

    def predict(self, t_ns: int, R: np.ndarray, p: np.ndarray, prior: float) -> tuple[float, float]:
        """(the range error expected at (R, p): the errors recorded near it, shrunk to `prior`;
        the kernel weight of those errors, in bins at the pose itself)."""
        sw = self._kernel_sum(t_ns, R, p)
        if sw == 0.0:
            return prior, 0.0
        return (float(self._sum[0]) + self.prior_weight * prior) / (sw + self.prior_weight), sw


class AccelMap(_PoseEntries):
    """The accelerometer's residuals [m/s^2, IMU frame] at poses, taken in whole bins (the
    filter sums each bin in its state), kept `window_ns`."""

    def __init__(self, sigma_deg: float, sigma_mm: float, bin_ms: float, window_s: float, prior_weight: float):
        super().__init__(sigma_deg, sigma_mm, bin_ms, window_s, prior_weight, 3)

    def add_bin(self, t_ns: int, acc: np.ndarray) -> None:
        """A bin summed as `kernels.steps.gravity_step` sums it (acc (16,): the poses' R and p, the
        residuals, the count), stamped t_ns (its last sample's time)."""
        n = acc[15]
        self._added += 1
        self._append(int(t_ns), acc[:12] / n, acc[12:15] / n)

    def mark(self) -> int:
        """Where the map stands now, for `rewind` (the number of bins taken)."""
        return self._added

    def rewind(self, mark: int) -> None:
        """Back to where `mark()` said it stood (the bins taken since are dropped)."""
        if mark < self._added:
            self._n = max(0, self._n - (self._added - mark))
            self._added = mark

    def forget_after(self, t_ns: int) -> None:
        """Forget the bins that ended after t_ns (a reset: they came from a state going wrong)."""
        self.rewind(self._added - (self._n - int(np.searchsorted(self._t[: self._n], t_ns, side="right"))))

    def predict(self, t_ns: int, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The residual expected at (R, p): the mean of those recorded near it, shrunk towards
        zero where few were (a new array)."""
        sw = self._kernel_sum(t_ns, R, p)
        if sw == 0.0:
            return np.zeros(3)
        return self._sum / (sw + self.prior_weight)

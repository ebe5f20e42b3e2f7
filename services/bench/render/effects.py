"""What a real bench camera adds to the pixel renderer's exact frames, drawn once per session:
the lens as built (its calibration residual), how the visible shaft lies on the tool axis, and
episodes of seconds (a second instrument crossing the view, smoke, glare). Exposure blur is the
renderer's own (sub-frame renders over the locked exposure).

A `RenderSession` holds these per-session draws; `render_frame` takes it with the frame's time.
Without one (or with every field at its default) the renderer draws what it drew before these
effects existed, draw for draw of the caller's generator.

`RENDER_PROFILE_OVERRIDES` are the RenderParams values of the bench's profiles (their `render`
sections, which every pixel-tier session of that profile renders with); `clean` is the defaults.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from services.bench.profiles import PROFILES
from services.bench.render.geometry import InstrumentGeometry, silhouette_lines
from tiplog.geometry.camera import CameraModel

# RenderParams values per bench profile (`clean` = the defaults): each profile's `render` section.
RENDER_PROFILE_OVERRIDES: dict[str, dict[str, object]] = {
    name: dict(prof.get("render", {})) for name, prof in PROFILES.items()
}

EPISODE_KINDS = ("occluder", "smoke", "glare")
GLARE_DN = 420.0  # a specular image of the lamp: well past saturation (255 DN) at its core


@dataclass(frozen=True)
class Episode:
    """One episode of `kind` over [t0_s, t1_s) of session time; `seed` fixes its look."""

    kind: str
    t0_s: float
    t1_s: float
    seed: int

    def phase(self, t_s: float) -> float:
        """0 at the start, 1 at the end."""
        return (t_s - self.t0_s) / max(self.t1_s - self.t0_s, 1e-9)


@dataclass(frozen=True)
class RenderSession:
    """Per-session draws of the pixel tier: `lens` (the camera the frames are drawn through; the
    pipeline is told the stated one), `T_tool_shaft` (4x4, the drawn shaft in the tool frame) and
    the `episodes`, sorted by start."""

    lens: CameraModel
    T_tool_shaft: np.ndarray
    episodes: tuple[Episode, ...] = field(default_factory=tuple)

    @classmethod
    def create(
        cls, camera: CameraModel, params, duration_s: float, junction_m: float, rng: np.random.Generator
    ) -> RenderSession:
        """Draw the session's lens residual, shaft tilt and episodes for a session of duration_s [s]
        (junction_m: the junction's distance from the tip, the tilt's pivot)."""
        return cls(
            lens_as_built(camera, params, rng),
            shaft_tilt(params, junction_m, rng),
            draw_episodes(params, duration_s, rng),
        )

    def active(self, t_s: float | None) -> list[Episode]:
        """Episodes under way at t_s (none without a time)."""
        if t_s is None:
            return []
        return [e for e in self.episodes if e.t0_s <= t_s < e.t1_s]


def lens_as_built(camera: CameraModel, params, rng: np.random.Generator) -> CameraModel:
    """The stated camera with a calibration residual: fx, fy scaled and cx, cy shifted by
    N(0, lens_error_sd_frac) (the shift in units of fx, fy), k1 offset by N(0, lens_k1_error_sd)."""
    e = rng.normal(size=5)
    if params.lens_error_sd_frac <= 0 and params.lens_k1_error_sd <= 0:
        return camera
    s = params.lens_error_sd_frac
    dist = list(camera.dist)
    dist[0] = dist[0] + params.lens_k1_error_sd * e[4]
    return CameraModel(
        camera.width,
        camera.height,
        camera.fx * (1.0 + s * e[0]),
        camera.fy * (1.0 + s * e[1]),
        camera.cx + camera.fx * s * e[2],
        camera.cy + camera.fy * s * e[3],
        tuple(dist),
    )


def shaft_tilt(params, junction_m: float, rng: np.random.Generator) -> np.ndarray:
    """T_tool_shaft (4x4): the drawn shaft turned by |N(0, shaft_tilt_sd_deg)| about an axis across
    it (a direction fixed in the tool) through the junction, so the junction stays where it is."""
    e = rng.normal(size=2)
    T = np.eye(4)
    if params.shaft_tilt_sd_deg <= 0:
        return T
    ang = np.radians(params.shaft_tilt_sd_deg * e[0])
    axis = np.array([np.cos(np.pi * e[1]), np.sin(np.pi * e[1]), 0.0])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K
    pivot = np.array([0.0, 0.0, -junction_m])
    T[:3, :3] = R
    T[:3, 3] = pivot - R @ pivot
    return T


def draw_episodes(params, duration_s: float, rng: np.random.Generator) -> tuple[Episode, ...]:
    """Poisson arrivals of each episode kind at its rate [1/min] over [0, duration_s), each lasting a
    uniform draw from its duration range [s]; kinds are drawn in EPISODE_KINDS order."""
    out: list[Episode] = []
    for kind in EPISODE_KINDS:
        child = rng.spawn(1)[0]  # every kind its own stream: one rate's change leaves the others
        rate = getattr(params, f"{kind}_rate_per_min")
        if rate <= 0:
            continue
        lo, hi = getattr(params, f"{kind}_duration_s")
        t = child.exponential(60.0 / rate)
        while t < duration_s:
            d = child.uniform(lo, hi)
            out.append(Episode(kind, float(t), float(t + d), int(child.integers(2**31))))
            t += d + child.exponential(60.0 / rate)
    return tuple(sorted(out, key=lambda e: e.t0_s))


def crossing_instrument(scene, geom: InstrumentGeometry, ep: Episode, t_s: float):
    """The second instrument of an occluder episode at t_s: (geometry, (line_left, line_right)) or
    None. It lies on the line of sight of a point of this shaft, nearer the camera, and its tip
    advances across this shaft and withdraws again over the episode, drifting sideways slowly."""
    g = np.random.default_rng(ep.seed)
    s = g.uniform(geom.s_junction - 0.04, geom.s_junction)
    frac = g.uniform(0.55, 0.8)
    angle = g.uniform(0, 2 * np.pi)
    radius = g.uniform(0.0025, 0.005)
    drift = g.uniform(-0.01, 0.01)
    p = geom.point(s)
    if p[2] < 0.03:
        return None
    q = p * frac
    view = q / np.linalg.norm(q)
    ref = np.cross(view, [0.0, 1.0, 0.0] if abs(view[1]) < 0.9 else [1.0, 0.0, 0.0])
    ref /= np.linalg.norm(ref)
    a = np.cos(angle) * ref + np.sin(angle) * np.cross(view, ref)
    side = np.cross(view, a)
    ph = ep.phase(t_s)
    reach = 0.03 * np.sin(np.pi * ph) - 0.01  # tip 10 mm short of the line of sight at both ends
    tip = q + a * reach + side * drift * (ph - 0.5)
    g2 = InstrumentGeometry(tip, a, float(radius), 0.001, 0.0, 0.5)
    try:
        lines = silhouette_lines(g2, scene.camera)
    except ValueError:
        return None
    return g2, lines[:2]


def smoke_alpha(shape: tuple[int, int], ep: Episode, t_s: float, density: float) -> np.ndarray:
    """Opacity (H, W) float32 of a smoke episode at t_s: a low-frequency haze that thickens, drifts
    across the view and clears again (peak opacity `density`)."""
    h, w = shape
    g = np.random.default_rng(ep.seed)
    coarse = g.random((7, 13), dtype=np.float32)
    v = g.normal(size=2) * 0.25  # drift, in coarse cells per second
    ph = ep.phase(t_s)
    sh, sw = max(2, h // 8), max(2, w // 8)
    fine = cv2.resize(coarse, (sw * 2, sh * 2), interpolation=cv2.INTER_CUBIC)
    shift = v * (t_s - ep.t0_s) * (2 * sw / coarse.shape[1])  # px of the (sw, sh) grid
    M = np.float32([[1, 0, sw / 2 + shift[0]], [0, 1, sh / 2 + shift[1]]])
    field = cv2.warpAffine(fine, M, (sw, sh), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                           borderMode=cv2.BORDER_REFLECT)  # fmt: skip
    ramp = np.sin(np.pi * np.clip(ph, 0.0, 1.0)) ** 0.5
    alpha = density * ramp * np.clip(0.35 + 1.2 * (field - 0.5), 0.0, 1.0)
    return cv2.resize(alpha.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)


def draw_glare(canvas: np.ndarray, scene, geom: InstrumentGeometry, ep: Episode, t_s: float) -> None:
    """Add a glare episode at t_s to the canvas (DN) in place: one or two specular images of the lamp
    (wet tissue or a drop beside the shaft), soft Gaussian spots whose core saturates, near the
    shaft's distal part and wandering slowly."""
    g = np.random.default_rng(ep.seed)
    n = 1 + int(g.random() < 0.5)
    h, w = canvas.shape[:2]
    ph = ep.phase(t_s)
    ramp = np.sin(np.pi * np.clip(ph, 0.0, 1.0)) ** 0.3
    for _ in range(n):
        s = g.uniform(geom.s_junction - 0.05, 0.0)
        off = g.normal(0.0, 12.0, 2)
        wander = g.normal(0.0, 8.0, 2)
        sigma = g.uniform(4.0, 14.0)
        p = geom.point(s)
        if p[2] < 0.01:
            continue
        c = scene.camera
        centre = np.array([c.fx * p[0] / p[2] + c.cx, c.fy * p[1] / p[2] + c.cy]) + off + wander * (ph - 0.5)
        r = int(np.ceil(3.5 * sigma))
        x0, y0 = max(0, int(centre[0]) - r), max(0, int(centre[1]) - r)
        x1, y1 = min(w, int(centre[0]) + r + 1), min(h, int(centre[1]) + r + 1)
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
        spot = np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / (2 * sigma**2))
        canvas[y0:y1, x0:x1] += (GLARE_DN * ramp * spot)[..., None]

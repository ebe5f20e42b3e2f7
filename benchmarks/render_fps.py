"""Frames per second of the bench's pixel renderer (1280x720 D405 colour, one core by default)
for typical poses: the shaft about 0.14 m inserted, the camera 0.2-0.3 m from the tip looking
down, the shaft within 10 deg of its 28.6 deg neutral tilt; without and with smoke; and with the
`paper` profile's camera (services/bench/render/effects.py): at rest, in motion (the exposure's
sub-frame renders), and with every episode kind under way."""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from services.bench.render.effects import RENDER_PROFILE_OVERRIDES, Episode, RenderSession
from services.bench.render.renderer import RenderParams, get_scene, render_frame
from tiplog.geometry.camera import CameraModel

NEUTRAL_FROM_VERTICAL_DEG = 28.6
INSERTION_M = 0.14


def typical_poses(n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """T_camera_tool for a camera looking straight down (+z): the tip 0.2-0.3 m deep near the image
    centre, the shaft (tool z, distal) tilted within 10 deg of neutral, any azimuth and roll."""
    poses = []
    while len(poses) < n:
        depth = rng.uniform(0.2, 0.3)
        tip = np.array([rng.uniform(-0.25, 0.25) * depth, rng.uniform(-0.15, 0.15) * depth, depth])
        th = np.radians(NEUTRAL_FROM_VERTICAL_DEG + rng.uniform(-10.0, 10.0))
        az = rng.uniform(0, 2 * np.pi)
        z = np.array([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), np.cos(th)])
        rcm = tip - INSERTION_M * z  # the port; the shaft runs on past it, out of the image
        if rcm[2] < 0.02:
            continue
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        roll = rng.uniform(0, 2 * np.pi)
        x, y = np.cos(roll) * x + np.sin(roll) * y, -np.sin(roll) * x + np.cos(roll) * y
        T = np.eye(4)
        T[:3, :3] = np.stack([x, y, z], 1)
        T[:3, 3] = tip
        poses.append(T)
    return poses


def example_pose() -> np.ndarray:
    """The tip right of centre, 0.25 m deep, the shaft at the neutral tilt leaning in from the right."""
    th = np.radians(NEUTRAL_FROM_VERTICAL_DEG)
    z = np.array([-np.sin(th), -0.15, np.cos(th)])
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    T[:3, 3] = [0.03, 0.015, 0.25]
    return T


def swept(poses: list[np.ndarray], speed_m_s: float, exposure_ms: float, m: int = 9) -> list[np.ndarray]:
    """Each pose as (m, 4, 4) over the exposure, the tip moving at speed_m_s across the view (camera x)."""
    out = []
    for T in poses:
        P = np.repeat(T[None], m, axis=0)
        P[:, 0, 3] += np.linspace(-0.5, 0.5, m) * speed_m_s * exposure_ms * 1e-3
        out.append(P)
    return out


def measure(
    camera: CameraModel,
    params: RenderParams,
    poses: list[np.ndarray],
    seconds: float,
    truth: bool = False,
    session: RenderSession | None = None,
) -> tuple[float, float, float]:
    """Frames per second (overall, from the median frame time, from the 10th-percentile frame time):
    on a machine that others load, the last approaches the figure for an idle core."""
    rng = np.random.default_rng(1)
    render_frame(camera, poses[0], params, rng, t_s=1.0, session=session)  # warm (scene already built)
    times = []
    t_start = time.perf_counter()
    while time.perf_counter() - t_start < seconds or len(times) < 5:
        t0 = time.perf_counter()
        t_s = 1.0 + 0.067 * len(times)
        render_frame(camera, poses[len(times) % len(poses)], params, rng, {} if truth else None, t_s=t_s,
                     session=session)  # fmt: skip
        times.append(time.perf_counter() - t0)
    t = np.array(times)
    return len(t) / t.sum(), 1.0 / np.median(t), 1.0 / np.percentile(t, 10)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=4.0, help="time per case")
    ap.add_argument("--threads", type=int, default=1, help="OpenCV threads (1: one core)")
    ap.add_argument("--png", default="", help="also write one example frame here (cv2.imwrite)")
    args = ap.parse_args(argv)
    cv2.setNumThreads(args.threads)
    camera = CameraModel.d405_colour()
    poses = typical_poses(16, np.random.default_rng(0))
    base = RenderParams(smoke_probability=0.0, occlusion_probability=0.0)
    t0 = time.perf_counter()
    get_scene(camera, base)
    print(
        f"scene precompute (floor texture, rays, gain): {time.perf_counter() - t0:.2f} s, once per scene; "
        f"{args.threads} OpenCV thread(s)"
    )
    cases = {
        "no smoke, no occlusion": base,
        "smoke every frame": base.model_copy(update={"smoke_probability": 1.0}),
        "occlusion every frame": base.model_copy(update={"occlusion_probability": 1.0}),
        "defaults (5 % smoke, 5 % occlusion)": RenderParams(),
    }
    cases["no smoke, no occlusion, with truth"] = base
    paper = RenderParams(**RENDER_PROFILE_OVERRIDES["paper"])
    still = RenderSession.create(camera, paper, 0.0, paper.junction_from_tip_mm * 1e-3, np.random.default_rng(0))
    busy = RenderSession(still.lens, still.T_tool_shaft, tuple(Episode(k, 0.0, 1e6, 3) for k in ("occluder", "smoke",
                                                                                                   "glare")))  # fmt: skip
    m = paper.exposure_subframes_max
    runs = {name: (params, poses, None) for name, params in cases.items()}
    runs["paper, at rest"] = (paper, [np.repeat(T[None], m, axis=0) for T in poses], still)
    runs["paper, tip 20 mm/s across the view"] = (paper, swept(poses, 0.02, paper.exposure_ms, m), still)
    runs["paper, tip 60 mm/s across the view"] = (paper, swept(poses, 0.06, paper.exposure_ms, m), still)
    runs["paper, at rest, 3 episodes under way"] = (paper, [np.repeat(T[None], m, axis=0) for T in poses], busy)
    for name, (params, ps, session) in runs.items():
        fps, fps_med, fps_p10 = measure(camera, params, ps, args.seconds, truth="truth" in name, session=session)
        print(
            f"{name:40s} {fps:5.1f} frames/s overall, {fps_med:5.1f} by median frame ({1e3 / fps_med:5.1f} ms), "
            f"{fps_p10:5.1f} by 10th-percentile frame ({1e3 / fps_p10:5.1f} ms)"
        )
    if args.png:
        truth: dict = {}
        img = render_frame(camera, example_pose(), RenderParams(), np.random.default_rng(2), truth)
        cv2.imwrite(args.png, cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        print(f"example frame: {args.png} (junction at {np.round(truth['junction_px_distorted'], 1)} px)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

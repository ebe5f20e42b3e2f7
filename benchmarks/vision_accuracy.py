"""Accuracy of the vision pipeline on pixel-tier bench frames against the bench's truth, set
beside the measurement tier's error model (services.bench vision_model) on the same motion.

For each seed the scenario is simulated twice with the same seed, so the robot's motion and the
camera's frame instants are the same: once at the pixel tier (frames rendered and run through
services.vision.pipeline with the shipped checkpoint) and once at the measurement tier (the
error model's observations). Both are scored the same way, on what the estimator would use:
  plane residual  asin(n . u_true) of both tangent-plane normals of accepted frames [deg]
  junction depth  the observation's junction ray intersected with the true axis, minus the true
                  junction, along the axis [mm] (accepted frames with a junction)
  acceptance      frames accepted by the consistency gate / all frames
  trocar gate     accepted frames whose shaft line (from the two normals) passes within 3.5 mm of
                  the as-calibrated RCM / all frames
  outliers        accepted frames with a plane residual above 1 deg / accepted frames; junction
                  outliers: junction depth errors beyond 2 mm / frames with a junction
Each is also given by image speed: how far the true junction moves in the image in one frame
period [px/frame] (the first bin is the tool at rest). Truth is read here, by the evaluation,
never by the pipeline. The pipeline is told the stated camera (camera/info), whatever lens the
renderer draws through. With `--jpeg Q` the same rendered frames are also scored as the
recorder's camera archive holds them (JPEG of quality Q, decoded): the rows `jpeg ...`.

    python -m benchmarks.vision_accuracy --scenario teleop --seeds 1 2 3 --duration 40
    python -m benchmarks.vision_accuracy --scenario teleop --seeds 1 2 3 --duration 30 --render-profile paper
    python -m benchmarks.vision_accuracy --scenario static --seeds 1 --duration 20 --set render.exposure_ms=16
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter

import numpy as np

from services.bench.render.effects import RENDER_PROFILE_OVERRIDES
from services.bench.scenario import load_scenario
from services.bench.simulation import simulate_session
from tiplog.config import ConfigError, parse_override
from tiplog.geometry import vision as vg


def _truth(sim, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(true axis direction u, true junction J) in the camera frame at frame k."""
    T = sim.frame_pose_cam(k)
    u = T[:3, 2]
    return u, T[:3, 3] - sim.truth.junction_proximal_m * u


SPEED_BINS_PX = (0.0, 0.3, 1.0, 3.0, 8.0, np.inf)  # junction image speed [px/frame]; the first: at rest


def image_speed_px(sim, k: int) -> float:
    """How far the true junction moves in the (undistorted) image over one frame period around frame k
    [px/frame]."""
    cam = sim.scenario.camera.model()
    half = 0.5e9 / sim.scenario.camera.fps
    t = int(sim.camera_frames.t_true_ns[k])
    ts = np.clip(np.array([t - half, t + half]), 0, sim.kin.t_ns[-1]).astype(np.int64)
    pts = []
    for tq in ts:
        T = sim.pose_cam(np.array([tq]))
        pts.append(T[:3, 3] - sim.truth.junction_proximal_m * T[:3, 2])
    uv = cam.project(np.array(pts), distort=False)
    return float(np.linalg.norm(uv[1] - uv[0]))


def _rcm_cam(sim) -> np.ndarray:
    T = sim.calib.T_base_camera
    return T[:3, :3].T @ (np.asarray(sim.calib.rcm_base_m) - T[:3, 3])


def score(rows: list[dict]) -> dict:
    """Summary of per-frame rows {accepted, n_l, n_r, u, J, ray|None, reason, trocar}."""
    n = len(rows)
    acc = [r for r in rows if r["accepted"]]
    res = np.degrees(np.arcsin(np.clip([[r["n_l"] @ r["u"], r["n_r"] @ r["u"]] for r in acc], -1, 1))).ravel()
    dep = []
    for r in acc:
        if r["ray"] is not None:
            _, p, _ = vg.ray_axis_intersection(r["ray"], vg.closest_axis_point(r["J"], r["u"]), r["u"])
            dep.append(float((p - r["J"]) @ r["u"]) * 1e3)
    dep = np.asarray(dep)
    out_mask = np.abs(res.reshape(-1, 2)).max(1) > 1.0 if len(acc) else np.zeros(0, bool)
    inl = res.reshape(-1, 2)[~out_mask].ravel() if len(acc) else res
    q = lambda a, p: float(np.percentile(a, p)) if len(a) else float("nan")  # noqa: E731
    return {
        "frames": n,
        "acceptance": len(acc) / n if n else float("nan"),
        "trocar_pass": sum(r["trocar"] for r in acc) / n if n else float("nan"),
        "outlier_fraction": float(out_mask.mean()) if len(acc) else float("nan"),
        "plane_residual_rms_deg": float(np.sqrt(np.mean(inl**2))) if len(inl) else float("nan"),
        "plane_residual_median_abs_deg": q(np.abs(inl), 50),
        "plane_residual_p95_abs_deg": q(np.abs(inl), 95),
        "junction_frames": int(len(dep)),
        "junction_depth_mean_mm": float(dep.mean()) if len(dep) else float("nan"),
        "junction_depth_rms_mm": float(np.sqrt(np.mean(dep**2))) if len(dep) else float("nan"),
        "junction_depth_sd_mm": float(dep.std()) if len(dep) else float("nan"),
        "junction_depth_median_abs_mm": q(np.abs(dep), 50),
        "junction_outlier_fraction": float((np.abs(dep) > 2.0).mean()) if len(dep) else float("nan"),
        "junction_outliers_mm": sorted(round(float(x), 2) for x in dep[np.abs(dep) > 2.0]),
        "junction_depth_inlier_sd_mm": float(dep[np.abs(dep) <= 2.0].std()) if len(dep) else float("nan"),
        "reasons": dict(Counter(r["reason"] for r in rows if not r["accepted"]).most_common(8)),
    }


def archived(img, quality: int):
    """The frame as the recorder's JPEG archive holds it and vision reads it back."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    from services.recorder.camera_archive import CameraArchive
    from services.vision.frames import decode_frame
    from tiplog.images import decompress, raw_image

    _, _, payload = CameraArchive(["camera/image"], quality).encode(
        "camera/image", raw_image(img, 0).SerializeToString()
    )
    return decode_frame(decompress(CompressedImage.FromString(payload)), None)


def pixel_rows(
    sim, weights: str, every: int, timings: list, jpeg: int = 0, archived_rows: list | None = None
) -> list[dict]:
    """Rows of the rendered frames; with `jpeg`, the same frames as archived (JPEG of that
    quality, decoded) are scored into `archived_rows` too."""
    from services.vision.network import load_checkpoint
    from services.vision.pipeline import Pipeline

    seg, _ = load_checkpoint(weights, "cpu")
    pipe = Pipeline(seg, sim.calib.shaft_radius_m)
    cam = sim.scenario.camera.model()
    rcm, rho = _rcm_cam(sim), sim.calib.shaft_radius_m
    rows = []
    for k in range(len(sim.camera_frames.t_true_ns)):
        if k % every:
            continue
        # only scored frames are rendered: the renderer's chance events (smoke, occluders, noise)
        # then come from other draws of its generator than in a full recording, same statistics
        img = sim.render_frame(k)
        u, J = _truth(sim, k)
        for frame, out in [(img, rows)] + ([(archived(img, jpeg), archived_rows)] if jpeg else []):
            res = pipe.process(frame, cam, int(sim.camera_frames.capture_ns[k]), k)
            if out is rows:
                timings.append(res.timings_ms)
            o = res.obs
            n_l = np.array([o.n_left.x, o.n_left.y, o.n_left.z])
            n_r = np.array([o.n_right.x, o.n_right.y, o.n_right.z])
            ray = np.array([o.junction_ray.x, o.junction_ray.y, o.junction_ray.z]) if o.junction_visible else None
            trocar = bool(o.accepted and vg.trocar_gate(n_l, n_r, rho, rcm)[1])
            out.append(dict(accepted=o.accepted, n_l=n_l, n_r=n_r, u=u, J=J, ray=ray, reason=o.reject_reason,
                            trocar=trocar, speed=image_speed_px(sim, k)))  # fmt: skip
    return rows


def model_rows(sim, every: int) -> list[dict]:
    v = sim.vision
    rcm, rho = _rcm_cam(sim), sim.calib.shaft_radius_m
    rows = []
    for k in range(0, len(v), every):
        u, J = _truth(sim, k)
        ray = v.junction_ray[k] if v.junction_visible[k] else None
        ok = bool(v.accepted[k])
        trocar = bool(ok and vg.trocar_gate(v.n_left[k], v.n_right[k], rho, rcm)[1])
        rows.append(dict(accepted=ok, n_l=v.n_left[k], n_r=v.n_right[k], u=u, J=J, ray=ray,
                         reason=v.reject_reason[k], trocar=trocar, speed=image_speed_px(sim, k)))  # fmt: skip
    return rows


def by_speed(pix: list[dict], mod: list[dict]) -> list[dict]:
    """score() of both tiers' rows in each SPEED_BINS_PX bin, with the inlier RMS of junction depth."""
    out = []
    for lo, hi in zip(SPEED_BINS_PX[:-1], SPEED_BINS_PX[1:], strict=True):
        row = {"bin": f"{lo:g}-{hi:g}"}
        for tier, rows in (("pixel", pix), ("model", mod)):
            sel = [r for r in rows if lo <= r["speed"] < hi]
            sc = score(sel) if sel else score([])
            dep = _depths(sel)
            inl = dep[np.abs(dep) <= 2.0]
            sc["junction_depth_inlier_rms_mm"] = float(np.sqrt(np.mean(inl**2))) if len(inl) else float("nan")
            sc["junction_outlier_count"] = int((np.abs(dep) > 2.0).sum())
            row[tier] = {k: v for k, v in sc.items() if k != "junction_outliers_mm"}
        out.append(row)
    return out


def _depths(rows: list[dict]) -> np.ndarray:
    """Junction depth errors [mm] of the accepted rows with a junction."""
    dep = []
    for r in rows:
        if r["accepted"] and r["ray"] is not None:
            _, p, _ = vg.ray_axis_intersection(r["ray"], vg.closest_axis_point(r["J"], r["u"]), r["u"])
            dep.append(float((p - r["J"]) @ r["u"]) * 1e3)
    return np.asarray(dep)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.vision_accuracy", description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="teleop")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--duration", type=float, default=40.0)
    ap.add_argument("--every", type=int, default=1, help="score every N-th frame")
    ap.add_argument("--weights", default=None)
    ap.add_argument("--json", help="write the figures here")
    ap.add_argument("--jpeg", type=int, default=0, metavar="Q",
                    help="also score the same frames as the recorder archives them (JPEG quality Q, decoded)")  # fmt: skip
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                    help="scenario override (both tiers), repeatable")  # fmt: skip
    ap.add_argument("--render-profile", choices=sorted(RENDER_PROFILE_OVERRIDES), default=None,
                    help="the pixel tier's RenderParams of this bench profile (before --set)")  # fmt: skip
    a = ap.parse_args(argv)
    ov: dict = {}
    if a.render_profile:
        ov = {f"render.{k}": v for k, v in RENDER_PROFILE_OVERRIDES[a.render_profile].items()}
    try:
        ov.update(dict(parse_override(o) for o in a.overrides))
        sc = load_scenario(a.scenario, ov)
    except (ConfigError, ValueError) as e:
        print(f"vision_accuracy: {e}", file=sys.stderr)
        return 2
    import torch

    from services.vision import DEFAULT_WEIGHTS

    torch.set_num_threads(1)
    pix_all, mod_all, jpg_all, report = [], [], [], {}
    tiers = ("pixel", "model") + (("jpeg",) if a.jpeg else ())
    for seed in a.seeds:
        t0 = time.perf_counter()
        timings: list = []
        jpg: list = []
        pix = pixel_rows(simulate_session(sc, seed, "pixel", a.duration), a.weights or str(DEFAULT_WEIGHTS), a.every,
                         timings, a.jpeg, jpg)  # fmt: skip
        mod = model_rows(simulate_session(sc, seed, "measurement", a.duration), a.every)
        pix_all += pix
        mod_all += mod
        jpg_all += jpg
        report[f"seed{seed}"] = {"pixel": score(pix), "model": score(mod)} | ({"jpeg": score(jpg)} if a.jpeg else {})
        print(f"seed {seed}: {len(pix)} frames in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    report["pooled"] = {"pixel": score(pix_all), "model": score(mod_all)} | ({"jpeg": score(jpg_all)} if a.jpeg else {})
    keys = ["acceptance", "trocar_pass", "outlier_fraction", "plane_residual_rms_deg", "plane_residual_median_abs_deg",
            "plane_residual_p95_abs_deg", "junction_depth_mean_mm", "junction_depth_sd_mm",
            "junction_depth_median_abs_mm", "junction_depth_inlier_sd_mm", "junction_outlier_fraction",
            "junction_frames"]  # fmt: skip
    print(f"{a.scenario}, seeds {a.seeds}, {a.duration:g} s each, every {a.every} frame(s)")
    print(f"{'':32s}" + "".join(f"{k:>18s}" for k in report))
    for tier in tiers:
        for k in keys:
            vals = "".join(f"{report[s][tier][k]:18.4f}" for s in report)
            print(f"{tier + ' ' + k:32s}{vals}")
    report["by_speed"] = by_speed(pix_all, mod_all)
    print("\nby junction image speed [px/frame] (pooled): frames, acceptance, plane RMS [deg], junction depth"
          " RMS / median abs [mm] (|error| <= 2 mm; outliers counted apart)")  # fmt: skip
    for b in report["by_speed"]:
        cells = []
        for tier in ("pixel", "model"):
            r = b[tier]
            cells.append(f"{tier} {r['frames']:4d} {r['acceptance']:6.3f} {r['plane_residual_rms_deg']:7.4f} "
                         f"{r['junction_depth_inlier_rms_mm']:7.3f} / {r['junction_depth_median_abs_mm']:6.3f}"
                         f" ({r['junction_outlier_count']} out)")  # fmt: skip
        print(f"  {b['bin']:>10s}  " + "   ".join(cells))
    for tier in tiers:
        print(f"{tier} reject reasons (pooled): {report['pooled'][tier]['reasons']}")
        print(f"{tier} junction outliers [mm] (pooled): {report['pooled'][tier]['junction_outliers_mm']}")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`tiplog evaluate --paper [--out DIR] [--seed N] [--quick] [--jobs J] [--force]`: the whole
study on the bench, one command, one report.

1. Generates the sessions (static, latency, fit, translation, rotation, sweeps, teleop;
   measurement tier) by running `tiplog sim generate` as subprocesses, `--jobs` at a time
   (`--quick` cuts them with `--duration` to a smoke test, not the paper's conditions).
2. Runs every analysis in a process pool of `--jobs` workers (default: the cores), each
   worker reading its MCAP itself: `tiplog calibrate block FIT --latency LAT` (subprocess),
   the latency table, the translation and rotation protocols (static-trial filter), the
   magnetometer study, static stability, full fusion on sweeps and teleop with the
   sessions' as-calibrated metadata, and, once calibrate has written its file, every sensor
   subset and degraded vision on both with that file (`study.ablation`).
3. Writes DIR/report.md (tables with the paper's figures beside ours, wall time at the top),
   DIR/report.json and DIR/*.png. A step that fails is reported (one line) and the rest go on.

The estimators read only device/vision topics and the calibration (as-calibrated metadata or
the calibrate output); the ground truth is read by the scoring only.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import time
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Any

from study.evaluation import public
from tiplog.procpool import process_pool
from tiplog.userio import UserError

log = logging.getLogger("tiplog.evaluate")

SCENARIOS = ("static", "latency", "fit", "fit_rotation", "translation", "rotation", "sweeps", "teleop")
# the rotation session holds the shaft at another neutral pose (bench facts: 30.4 deg from
# vertical, against 28.6): its constants are fitted on a fit-only block recorded there, as the
# paper fitted the rotation session's constants under its own conditions
ROTATION_NEUTRAL_TILT_DEG = 30.4
GENERATE_AS = {"fit_rotation": ("fit", ["--set", f"motion.neutral_tilt_deg={ROTATION_NEUTRAL_TILT_DEG}"])}
# --quick: seconds per session. The fit block stays whole (ten poses are what it needs), the
# latency protocol keeps its first three depth frequencies (three per channel are needed).
QUICK_DURATION_S = {
    "static": 40,
    "latency": 150,
    "fit": None,
    "fit_rotation": None,
    "translation": 40,
    "rotation": 40,
    "sweeps": 40,
    "teleop": 40,
}
CONTINUOUS = ("sweeps", "teleop")


def _tiplog(*args: str) -> list[str]:
    return [sys.executable, "-m", "tiplog.cli", *args]


def _generate(scen: str, out: Path, seed: int, duration: float | None) -> tuple[str, float]:
    name, extra = GENERATE_AS.get(scen, (scen, []))
    cmd = _tiplog("sim", "generate", "--scenario", name, "--out", str(out), "--seed", str(seed), "--quiet", "--force")
    cmd += extra
    if duration is not None:
        cmd += ["--duration", str(duration)]
    t0 = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if r.returncode != 0:
        raise RuntimeError(f"sim generate {scen}: {(r.stderr or r.stdout).strip().splitlines()[-1:]}")
    return scen, time.monotonic() - t0


# ---- analysis tasks (run in worker processes; each reads its files itself) ----


def _task_calibrate(d: Path, fit: str = "fit", out: str = "calibration.yaml") -> dict[str, Any]:
    s = d / "sessions"
    base = ["calibrate", "block", str(s / f"{fit}.mcap"), "--out", str(d / out), "--json", "--force"]
    r = subprocess.run(_tiplog(*base, "--latency", str(s / "latency.mcap")), capture_output=True, text=True)
    note = None
    if r.returncode != 0:  # the latency fit can refuse a short latency session: calibrate without it
        note = f"latency not fitted: {r.stderr.strip()}"
        r = subprocess.run(_tiplog(*base), capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(r.stderr.strip() or "calibrate block failed")
    text = r.stdout.strip()
    report = json.loads(text[: text.rfind("}") + 1])
    return {"file": out, "report": report, "note": note}


def _task_latency(d: Path) -> dict[str, Any]:
    from tiplog.calibration import data as calibrate_data
    from tiplog.calibration import latency as calibrate_latency

    data = calibrate_data.load(d / "sessions" / "latency.mcap")
    return calibrate_latency.latency_table(data, data.prior)


def _task_protocol(d: Path, scen: str, calibration: str | None = None) -> dict[str, Any]:
    from study.static import evaluate_static
    from tiplog.calibration import Calibration

    cal = Calibration.load_yaml(d / calibration) if calibration else None
    return evaluate_static(d / "sessions" / f"{scen}.mcap", cal)


def _task_magnetometer(d: Path) -> dict[str, Any]:
    from study.static_magnetometer import rotation_study, static_study
    from tiplog.calibration.data import load

    s = d / "sessions"
    out: dict[str, Any] = {"rotation": rotation_study(load(s / "rotation.mcap"))}
    try:
        out["static"] = static_study(load(s / "static.mcap"))
    except UserError as e:  # a quick static session may hold too little
        out["static_error"] = str(e)
    return out


def _task_stability(d: Path) -> dict[str, Any]:
    from study.holds import evaluate_holds

    return evaluate_holds(d / "sessions" / "static.mcap")


def _task_variant(d: Path, scen: str, variant: str, calibrated: bool = False) -> dict[str, Any]:
    """One subset or degradation. Blackouts as the paper placed them: its sixteen shared over
    both continuous sessions in proportion to their blocks (`blackout10`), or, the harsher
    reading, sixteen in each session (`blackout10_per_session`)."""
    from study.ablation import BLACKOUT_COUNT, PER_SESSION, SUBSETS, evaluate_variant, sessions_blackouts

    cal = d / "calibration.yaml" if calibrated else None
    base, per_session = variant.removesuffix(PER_SESSION), variant.endswith(PER_SESSION)
    n = BLACKOUT_COUNT
    if base.startswith("blackout") and not per_session:
        n = sessions_blackouts([d / "sessions" / f"{s}.mcap" for s in CONTINUOUS])[CONTINUOUS.index(scen)]
    r = evaluate_variant(
        d / "sessions" / f"{scen}.mcap", base, cal, series=base == "full", blackouts=n, block_errors=base in SUBSETS
    )
    r["variant"] = variant
    return r


def _run_task(name: str, fn_name: str, args: tuple) -> tuple[str, Any, str | None, float]:
    """Worker entry: (name, result or None, error line or None, seconds)."""
    t0 = time.monotonic()
    try:
        return name, globals()[fn_name](*args), None, time.monotonic() - t0
    except Exception as e:  # noqa: BLE001 - one failed step is reported, the study goes on
        msg = str(e).strip().splitlines()
        return name, None, f"{type(e).__name__}: {msg[-1] if msg else ''}", time.monotonic() - t0


def _short(name: str, r: Any) -> str:
    if not isinstance(r, dict):
        return ""
    if "tip_rmse_mm" in r:
        return f"tip RMSE {r['tip_rmse_mm']:.2f} mm"
    if "translation" in r:
        return f"RMSE {r['translation']['rmse_mm']:.2f} mm, scale {r['translation']['scale']:.3f}"
    if "rotation" in r and "relrot_rmse_deg" in r["rotation"]:
        return f"rel. rot. {r['rotation']['relrot_rmse_deg']:.3f} deg"
    return ""


def _tasks(d: Path) -> list[tuple[str, str, tuple]]:
    """Longest first, so the pool ends together."""
    out = [
        ("translation", "_task_protocol", (d, "translation")),
        ("rotation", "_task_protocol", (d, "rotation")),
        ("stability", "_task_stability", (d,)),
        ("calibrate", "_task_calibrate", (d,)),
        ("calibrate_rotation", "_task_calibrate", (d, "fit_rotation", "calibration_rotation.yaml")),
    ]
    out += [(f"as_calibrated:{s}", "_task_variant", (d, s, "full")) for s in CONTINUOUS]
    out += [("magnetometer", "_task_magnetometer", (d,)), ("latency", "_task_latency", (d,))]
    return out


def _ablations(calibrated: bool) -> list[tuple[str, str, tuple]]:
    """Every subset and degradation on both continuous sessions (arguments after the folder)."""
    from study.ablation import PER_SESSION, variants

    names = [*variants(), *(v + PER_SESSION for v in variants() if v.startswith("blackout"))]
    return [(f"ablation:{s}:{v}", "_task_variant", (s, v, calibrated)) for s in ("teleop", "sweeps") for v in names]


# Run once the calibration they read is written. The subsets and degraded vision run with the
# calibrate output, as a lab would run them (if calibrate fails, with the as-calibrated metadata).
AFTER_CALIBRATE = {
    "calibrate": [("translation_calibrated", "_task_protocol", ("translation", "calibration.yaml")), *_ablations(True)],
    "calibrate_rotation": [("rotation_calibrated", "_task_protocol", ("rotation", "calibration_rotation.yaml"))],
}
# task name -> its arguments without the calibrate file, run instead when calibrate fails
IF_CALIBRATE_FAILS = {nm: a for nm, _, a in _ablations(False)}


def check_out(out: Path, force: bool) -> None:
    if out.exists() and not force:
        raise UserError(f"{out}: exists, use --force to write the report into it")
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a folder")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise UserError(f"{out}: cannot create the folder here ({parent} missing or not writable)")


def run(args: argparse.Namespace) -> int:
    out = Path(args.out or "paper_report")
    check_out(out, args.force)
    if args.jobs is not None and args.jobs < 1:
        raise UserError(f"--jobs: must be 1 or more, got {args.jobs}")
    jobs = args.jobs or os.cpu_count() or 1
    seed = 1 if args.seed is None else args.seed
    wall0 = time.monotonic()

    def say(msg: str) -> None:
        print(f"[{time.monotonic() - wall0:7.1f} s] {msg}", flush=True)

    (out / "sessions").mkdir(parents=True, exist_ok=True)
    durations = {s: (QUICK_DURATION_S[s] if args.quick else None) for s in SCENARIOS}
    say(f"generating {len(SCENARIOS)} bench sessions (seed {seed}{', quick' if args.quick else ''}), {jobs} at a time")
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futs = [
            pool.submit(_generate, s, out / "sessions" / f"{s}.mcap", seed, durations[s])
            for s in sorted(SCENARIOS, key=lambda s: s in ("fit", "latency"))
        ]
        for f in futs:
            scen, sec = f.result()
            say(f"generated {scen} in {sec:.1f} s")
    res = analyse(out, jobs, say)
    res.update(seed=seed, quick=bool(args.quick), jobs=jobs, sessions=_session_info(out))
    res["plots"] = _plots(res, out, say)
    res["wall_time_s"] = time.monotonic() - wall0
    from study.paper_report import markdown

    (out / "report.json").write_text(json.dumps(public(res), indent=1) + "\n")
    (out / "report.md").write_text(markdown(res))
    say(f"wrote {out / 'report.md'}, {out / 'report.json'} and {len(res['plots'])} plots")
    return 0


def analyse(out: Path, jobs: int, say) -> dict[str, Any]:
    """Every analysis task in a process pool; results gathered into the report's dict."""
    results: dict[str, Any] = {}
    errors: dict[str, str] = {}
    ablations_on = "calibrate"  # or "as_calibrated" if calibrate fails
    tasks = _tasks(out)
    total = len(tasks) + sum(len(v) for v in AFTER_CALIBRATE.values())
    with process_pool(jobs) as pool:
        pending: set[Future] = {pool.submit(_run_task, *t) for t in tasks}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                name, r, err, sec = f.result()
                if err:
                    errors[name] = err
                else:
                    results[name] = r
                n = len(results) + len(errors)
                say(f"{n}/{total} {name} ({sec:.1f} s): {err or _short(name, r)}")
                for nm, fn, a in AFTER_CALIBRATE.get(name, []):
                    if not err:
                        pending.add(pool.submit(_run_task, nm, fn, (out, *a)))
                    elif nm in IF_CALIBRATE_FAILS:  # the same task on the as-calibrated metadata
                        pending.add(pool.submit(_run_task, nm, fn, (out, *IF_CALIBRATE_FAILS[nm])))
                        ablations_on = "as_calibrated"
                    else:
                        errors[nm] = f"no calibration file ({name} failed)"
    return gather(results, errors, ablations_on)


def gather(results: dict[str, Any], errors: dict[str, str], ablations_on: str = "calibrate") -> dict[str, Any]:
    """The report's dict from the tasks' results (keys documented in docs/evaluation.md)."""
    res: dict[str, Any] = {"errors": errors}
    for k in ("translation", "rotation"):
        if k in results:
            res[k] = results[k][k]
            res[f"_{k}_errors"] = results[k]  # with private per-trial errors, for the boxplots
    for k in ("translation", "rotation"):
        if f"{k}_calibrated" in results:
            res[f"{k}_calibrated"] = results[f"{k}_calibrated"][k]
    for k in ("stability", "latency", "magnetometer"):
        if k in results:
            res[k] = results[k]
    for k, task in (("calibration", "calibrate"), ("calibration_rotation", "calibrate_rotation")):
        if task in results:
            res[k] = results[task]
    res["dynamic"] = {}
    res["subsets"], res["degraded"] = {}, {}
    res["ablations_calibration"] = ablations_on
    for name, r in results.items():
        if name.startswith("ablation:"):
            _, scen, variant = name.split(":")
            key = "subsets" if r["kind"] == "subset" else "degraded"
            row = res[key].setdefault(
                variant, {"tip_rmse_mm": {}, "tip_p95_mm": {}, "block_mean_mm": {}, "coverage": {}, "resets": {}}
            )
            for m in ("tip_rmse_mm", "tip_p95_mm", "block_mean_mm", "coverage", "resets", "blackouts"):
                if m in r:
                    row.setdefault(m, {})[scen] = r[m]
            if key == "subsets" and r.get("blocks"):  # block names are unique over the sessions
                row.setdefault("block_rmse_mm", {}).update({b["name"]: b["tip_rmse_mm"] for b in r["blocks"]})
            if variant == "full" and res["ablations_calibration"] == "calibrate":
                res["dynamic"].setdefault(scen, {})["calibrated"] = r
        elif name.startswith("as_calibrated:"):
            res["dynamic"].setdefault(name.split(":")[1], {})["as_calibrated"] = r
    _full_against_best(res, results)
    return res


def _full_against_best(res: dict[str, Any], results: dict[str, Any]) -> None:
    """Per block, full fusion against the best other subset there (`subsets.full.block_vs_best`):
    the difference of their tip RMSE with its block-bootstrap interval
    (`evaluation.paired_rmse_difference`), from the subsets' private `_block_errors`; nothing
    where those were not kept (an older report's results)."""
    from study.evaluation import paired_rmse_difference

    errors: dict[str, dict[str, tuple]] = {}
    for name, r in results.items():
        if name.startswith("ablation:") and "_block_errors" in r:
            errors.setdefault(name.split(":")[2], {}).update(r["_block_errors"])
    sub = res["subsets"]
    if "full" not in errors or "block_rmse_mm" not in sub.get("full", {}):
        return
    for block in sub["full"]["block_rmse_mm"]:
        others = {
            v: r["block_rmse_mm"][block]
            for v, r in sub.items()
            if v != "full" and block in r.get("block_rmse_mm", {}) and block in errors.get(v, {})
        }
        if not others or block not in errors["full"]:
            continue
        best = min(others, key=others.__getitem__)
        (t_f, e_f), (t_b, e_b) = errors["full"][block], errors[best][block]
        d = paired_rmse_difference(t_f, e_f, t_b, e_b)
        sub["full"].setdefault("block_vs_best", {})[block] = {"against": best, **d}


def _session_info(out: Path) -> dict[str, Any]:
    from tiplog.mcap_io import read_metadata

    info = {}
    for s in SCENARIOS:
        p = out / "sessions" / f"{s}.mcap"
        md = read_metadata(p).get("session", {})
        info[s] = {"path": str(p.relative_to(out)), "duration_s": float(md.get("duration_s", "nan"))}
    return info


def _plots(res: dict[str, Any], out: Path, say) -> list[str]:
    try:
        from study.evaluation import plot
        from study.plots import ablation_bars, protocol_boxplots
    except ImportError as e:
        say(f"no plots ({e})")
        return []
    files: list[Path] = []
    for k in ("translation", "rotation"):
        if f"_{k}_errors" in res:
            files += protocol_boxplots(res[f"_{k}_errors"], out)
    for d in res["dynamic"].values():
        a = d.get("calibrated") or d.get("as_calibrated")
        if a and "_series" in a:
            files += plot(a, out)
    tables = {
        s: {
            "subsets": {v: {"tip_rmse_mm": r["tip_rmse_mm"].get(s)} for v, r in res["subsets"].items()},
            "degraded": {v: {"tip_rmse_mm": r["tip_rmse_mm"].get(s)} for v, r in res["degraded"].items()},
        }
        for s in CONTINUOUS
    }
    if res["subsets"]:
        files.append(ablation_bars(tables, out))
    return [f.name for f in files]

r'''CPU time of the jpl calibrator's fits on rendered paper-campaign jobs

SYNOPSIS

    uv run --frozen python benchmarks/bench_jpl.py [--jobs 5/CAHVORE,3/CAHVOR,...]
        [--repeats 3] [--obs /tmp/camval_bench_jpl_obs.pkl]
        [--out benchmarks/results/jpl.json]

For each job (camera/family of campaigns/paper.toml: 6 poses of the dot
target, ray-cast at spp=16, adaptive) the images are rendered and the dots
detected once; the observations are kept in the --obs pickle (reused by later
runs: the rendering of a 5120x3840 camera takes minutes). Then
harness.runner.calibrate_stage("jpl", ...) runs --repeats times after one
warm-up fit (which loads or compiles the numba kernels); the table gives the
median CPU (time.process_time) and wall seconds per fit (with more CPU than wall
seconds, BLAS threads spin: set OPENBLAS_NUM_THREADS=1), the solver's
function evaluations, the final RMS residual, and a fingerprint of the fitted
model (its projection of the surveyed points) so that two versions of the
calibrator can be compared: --compare old.json prints the largest projection
difference between the two runs' models, per job.
'''

import argparse
import json
import os
import pickle
import platform
import statistics
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.records import git_commit  # noqa: E402

DEFAULT_JOBS = "5/CAHV,5/CAHVOR,5/CAHVORE,3/CAHV,3/CAHVOR,3/CAHVORE"


def _paper_job(jobs, spec):
    camera, family = spec.split("/")
    for j in jobs:
        if j.camera_key == camera and j.family == family:
            return j
    raise SystemExit(f"no job {spec} in campaigns/paper.toml")


def observations(specs, cache):
    r'''{spec: (obs, truth, job)}: rendered and detected once, kept in the pickle `cache`'''
    from harness.campaign import load_campaign
    from harness.runner import (
        _target,
        camera_stage,
        detect_stage,
        expand_jobs,
        observations_from,
        poses_stage,
        render_stage,
    )
    stored = {}
    if cache.exists():
        with open(cache, "rb") as f:
            stored = pickle.load(f)
    jobs = expand_jobs(load_campaign(ROOT / "campaigns" / "paper.toml"))
    out = {}
    for spec in specs:
        job = _paper_job(jobs, spec)
        _, truth = camera_stage(job)
        target = _target(job.target)
        if spec not in stored:
            t0 = time.perf_counter()
            poses = poses_stage(truth, target, job.poses_n, job.poses_seed)
            renders, _, _ = render_stage(job.renderer, truth, target, poses, job.settings)
            dets, _ = detect_stage([r.image for r in renders], target)
            stored[spec] = observations_from(truth, target, poses, dets)
            print(f"{spec}: rendered and detected in {time.perf_counter() - t0:.1f} s",
                  flush=True)
            with open(cache, "wb") as f:
                pickle.dump(stored, f)
        out[spec] = (stored[spec], truth, target)
    return out


def bench(spec, obs, truth, target, repeats):
    from harness.runner import calibrate_stage
    calibrate_stage("jpl", obs, target, truth.family, truth, {})   # warm-up
    cpu, wall = [], []
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        r = calibrate_stage("jpl", obs, target, truth.family, truth, {})
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    if r.status != "ok":
        raise SystemExit(f"{spec}: the jpl fit failed: {r.reason}")
    passes = r.info["passes"]
    return {"job": spec, "family": truth.family, "imagersize": [truth.width, truth.height],
            "n_points": int(obs.found.sum()), "repeats": repeats,
            "cpu_s": statistics.median(cpu), "wall_s": statistics.median(wall),
            "cpu_s_all": cpu, "wall_s_all": wall,
            "nfev": [p.get("nfev") for p in passes], "iterations": r.iterations,
            "rms_px": r.residual_stats()["rms"],
            "q_fit": r.model.project(obs.p_ref()[obs.found]).tolist()}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--jobs", default=DEFAULT_JOBS)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--obs", type=Path, default=Path("/tmp/camval_bench_jpl_obs.pkl"))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "jpl.json")
    ap.add_argument("--compare", type=Path, help="an earlier output: report model differences")
    args = ap.parse_args()
    specs = args.jobs.split(",")
    data = observations(specs, args.obs)
    old = {}
    if args.compare:
        old = {r["job"]: r for r in json.loads(args.compare.read_text())["records"]}
    records = []
    print(f"{'job':<12} {'size':>10} {'N':>4} {'cpu s':>7} {'wall s':>7} {'nfev':>16} "
          f"{'rms px':>9}" + (f" {'d_old px':>9} {'old cpu':>8}" if old else ""))
    for spec in specs:
        obs, truth, target = data[spec]
        rec = bench(spec, obs, truth, target, args.repeats)
        line = (f"{spec:<12} {truth.width:>5}x{truth.height:<4} {rec['n_points']:>4} "
                f"{rec['cpu_s']:>7.3f} {rec['wall_s']:>7.3f} {str(rec['nfev']):>16} "
                f"{rec['rms_px']:>9.2e}")
        if spec in old:
            d = np.abs(np.array(rec["q_fit"]) - np.array(old[spec]["q_fit"])).max()
            rec["max_diff_vs_compare_px"] = float(d)
            rec["compare_cpu_s"] = old[spec]["cpu_s"]
            line += f" {d:>9.2e} {old[spec]['cpu_s']:>8.3f}"
        print(line, flush=True)
        records.append(rec)
    total = sum(r["cpu_s"] for r in records)
    print(f"total CPU per fit set: {total:.3f} s")
    from harness.calibrators import _jpl_kernels as jk
    from reference_models import kernels as rk
    sigs = {k.__name__: len(k.signatures) for k in (rk.project_points, rk._residuals_kernel,
                                                     jk._chart_kernel, jk._jacobian_kernel)}
    print(f"compiled signatures: {sigs}")
    doc = {"benchmark": "jpl", "date": datetime.now(UTC).isoformat(timespec="seconds"),
           "commit": git_commit()["commit"], "python": platform.python_version(),
           "env": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                                   "NUMBA_NUM_THREADS")},
           "command": " ".join(sys.argv), "total_cpu_s": total, "signatures": sigs,
           "records": records}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

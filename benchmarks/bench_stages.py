r'''Pose planning and comparison with the truth: CPU seconds of two small campaign stages

SYNOPSIS

    uv run python benchmarks/bench_stages.py [--campaign campaigns/paper.toml]
        [--compare-jobs 3/CAHVORE,8/CAHVORE,15/CAHVOR,15/CAHV | --pickles '/tmp/prof/*.pkl']
        [--repeats 3]
        [--ref dd2ca39] [--out benchmarks/results/stages.json]

poses: harness.runner.poses_stage (targets.poses.plan_poses) for every job of
the campaign (the paper: 66 jobs; a job whose camera cannot give its family is
skipped, as the campaign does), timed per job; the total per repetition.

compare: the chosen jobs (camera/family) are rendered, detected and
calibrated once by every calibrator of the campaign, as harness.runner.run_job
does; then harness.runner.compare_stage runs on each successful record, job
by job in the campaign's order, timed per record. --pickles: instead, pickled
paper jobs (dicts with obs, truth, target_name; files CAMERA_FAMILY.pkl) are
calibrated by their job's calibrators, nothing rendered. The truth-points memo of
harness.compare is emptied before each repetition, so a repetition costs what
a worker's first pass over these jobs costs.

--ref REV: the same measurements with targets/poses.py and harness/compare.py
as they are at git revision REV (loaded from git in place of the current
modules), and whether the results are the same: the poses bit for bit, the
compare figures (parameter errors, projection statistics) to 1e-12 relative.

CPU seconds (time.process_time) and wall seconds, min and median over the
repetitions; the machine is shared, so the load average is recorded too.
Prints a summary and writes one JSON document.
'''

import argparse
import importlib.util
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MODULES = {"targets.poses": "targets/poses.py", "harness.compare": "harness/compare.py"}


def _git(*args):
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout


def _module_at(rev, name):
    r'''The module `name` as its file is at git revision rev (a fresh module object)'''
    src = _git("show", f"{rev}:{MODULES[name]}")
    spec = importlib.util.spec_from_loader(name, loader=None)
    mod = importlib.util.module_from_spec(spec)
    mod.__file__ = str(ROOT / MODULES[name])
    exec(compile(src, f"{rev}:{MODULES[name]}", "exec"), mod.__dict__)
    return mod


@contextmanager
def _modules(mods):
    r'''Run the runner's stages with the given {name: module} in place of the current ones'''
    import harness
    import targets
    saved = {n: sys.modules[n] for n in mods}
    parents = {"targets.poses": targets, "harness.compare": harness}
    try:
        for n, m in mods.items():
            sys.modules[n] = m
            setattr(parents[n], n.split(".")[1], m)
        yield
    finally:
        for n, m in saved.items():
            sys.modules[n] = m
            setattr(parents[n], n.split(".")[1], m)


def _stats(xs):
    return {"min": min(xs), "median": statistics.median(xs), "all": xs}


def time_poses(setups, repeats):
    r'''(per-repetition CPU and wall totals, {job: poses or the failure reason})'''
    from harness.runner import StageFailed, poses_stage
    cpu, wall = [], []
    out = {}
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        for job, truth, target in setups:
            try:
                out[job.key] = poses_stage(truth, target, job.poses_n, job.poses_seed)
            except StageFailed as e:
                out[job.key] = e.reason
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return {"cpu_s": _stats(cpu), "wall_s": _stats(wall)}, out


def calibrated_records(campaign, jobs, wanted):
    r'''[(job key, calibrator/model, truth, CalibrationResult)] of the wanted jobs (ok only)'''
    from harness.runner import (
        _target,
        calibrate_stage,
        camera_stage,
        detect_stage,
        observations_from,
        poses_stage,
        render_stage,
    )
    out = []
    for job in jobs:
        if f"{job.camera_key}/{job.family}" not in wanted:
            continue
        _, truth = camera_stage(job)
        target = _target(job.target)
        poses = poses_stage(truth, target, job.poses_n, job.poses_seed)
        renders, _, _ = render_stage(job.renderer, truth, target, poses, job.settings)
        dets, _ = detect_stage([r.image for r in renders], target)
        obs = observations_from(truth, target, poses, dets)
        for cal, model, options in job.calibrators:
            res = calibrate_stage(cal, obs, target, model, truth, options)
            print(f"  calibrated {job.key} {cal}/{model}: {res.status}", flush=True)
            if res.status == "ok":
                out.append((job.key, f"{cal}/{model}", truth, res))
    return out


def pickled_records(jobs, paths):
    r'''calibrated_records() of pickled paper jobs (dicts with obs, truth, target_name,
named CAMERA_FAMILY.pkl): calibrated by every calibrator of the job, nothing rendered'''
    import pickle

    from harness.runner import _target, calibrate_stage
    by_key = {f"{j.camera_key}_{j.family}": j for j in jobs}
    out = []
    for path in sorted(paths):
        job = by_key.get(Path(path).stem)
        if job is None:
            continue
        with open(path, "rb") as f:
            d = pickle.load(f)
        target = _target(d["target_name"])
        for cal, model, options in job.calibrators:
            res = calibrate_stage(cal, d["obs"], target, model, d["truth"], options)
            print(f"  calibrated {job.key} {cal}/{model}: {res.status}", flush=True)
            if res.status == "ok":
                out.append((job.key, f"{cal}/{model}", d["truth"], res))
    return out


def time_compare(records, repeats):
    r'''(per-repetition CPU and wall totals and CPU per record, the figures of each record)'''
    import harness.compare
    from harness.runner import compare_stage
    cpu, wall = [], []
    per = {f"{k} {c}": [] for k, c, _, _ in records}
    out = []
    for _ in range(repeats):
        memo = getattr(harness.compare, "_TRUTH_POINTS", None)
        if memo is not None:
            memo.clear()
        out = []
        c0, w0 = time.process_time(), time.perf_counter()
        for key, cal, truth, res in records:
            c1 = time.process_time()
            params, proj, themap = compare_stage(truth, res)
            per[f"{key} {cal}"].append(time.process_time() - c1)
            out.append((params, proj, themap))
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return {"records": len(records), "cpu_s": _stats(cpu), "wall_s": _stats(wall),
            "cpu_s_per_record": {k: min(v) for k, v in per.items()}}, out


def same_poses(a, b):
    if a.keys() != b.keys():
        return False
    for k in a:
        if isinstance(a[k], str) or isinstance(b[k], str):
            if a[k] != b[k]:
                return False
        elif not all(x.tobytes() == y.tobytes() for x, y in zip(a[k], b[k], strict=True)):
            return False
    return True


def compare_rel_diff(a, b):
    r'''Largest relative difference between two lists of compare_stage() figures (inf if
they differ in what is None or in the keys)'''
    worst = 0.0
    for (pa, ja, _), (pb, jb, _) in zip(a, b, strict=True):
        flat_a = dict(pa) | {f"{m}.{k}": v for m, d in ja.items() if isinstance(d, dict)
                             for k, v in d.items()}
        flat_b = dict(pb) | {f"{m}.{k}": v for m, d in jb.items() if isinstance(d, dict)
                             for k, v in d.items()}
        if flat_a.keys() != flat_b.keys():
            return float("inf")
        for k, x in flat_a.items():
            y = flat_b[k]
            if isinstance(x, float) and isinstance(y, float):
                if x != y:
                    worst = max(worst, abs(x - y) / max(abs(x), abs(y)))
            elif x != y:
                return float("inf")
    return worst


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaign", default="campaigns/paper.toml")
    ap.add_argument("--compare-jobs", default="3/CAHVORE,8/CAHVORE,15/CAHVOR,15/CAHV",
                    help="camera/family of the jobs whose records are compared")
    ap.add_argument("--pickles", default=None,
                    help="glob of pickled paper jobs (e.g. '/tmp/prof/*.pkl'): compare their "
                         "records instead of rendering --compare-jobs")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ref", default=None,
                    help="git revision whose poses.py and compare.py are measured too")
    ap.add_argument("--out", default="benchmarks/results/stages.json")
    args = ap.parse_args()

    from harness.campaign import load_campaign
    from harness.runner import StageFailed, _target, camera_stage, expand_jobs
    campaign = load_campaign(args.campaign)
    jobs = expand_jobs(campaign)
    setups = []
    for job in jobs:
        try:
            setups.append((job, camera_stage(job)[1], _target(job.target)))
        except StageFailed:
            pass
    if args.pickles:
        import glob
        paths = glob.glob(args.pickles)
        wanted = {Path(p).stem.replace("_", "/") for p in paths}
        print(f"calibrating the records of {len(paths)} pickled jobs", flush=True)
        records = pickled_records(jobs, paths)
    else:
        wanted = set(args.compare_jobs.split(","))
        print(f"calibrating the records to compare ({', '.join(sorted(wanted))})", flush=True)
        records = calibrated_records(campaign, jobs, wanted)
    # warm: imports (scipy.optimize) and first calls out of the timings
    time_poses(setups[:1], 1)
    time_compare(records[:1], 1)

    variants = {"current": {}}
    if args.ref:
        variants[f"ref {args.ref}"] = {n: _module_at(args.ref, n) for n in MODULES}
    results, outputs = {}, {}
    for label, mods in variants.items():
        with _modules(mods):
            p, poses = time_poses(setups, args.repeats)
            c, figures = time_compare(records, args.repeats)
        results[label] = {"poses": dict(p, jobs=len(setups),
                                        planned=sum(not isinstance(v, str)
                                                    for v in poses.values())),
                          "compare": c}
        outputs[label] = (poses, figures)
        print(f"{label}: poses {len(setups)} jobs: CPU {p['cpu_s']['min']:.2f} s "
              f"(median {p['cpu_s']['median']:.2f}), wall {p['wall_s']['min']:.2f} s; "
              f"compare {len(records)} records: CPU {c['cpu_s']['min']:.3f} s "
              f"(median {c['cpu_s']['median']:.3f}), wall {c['wall_s']['min']:.3f} s",
              flush=True)
    doc = {"date": datetime.now(UTC).isoformat(timespec="seconds"),
           "commit": _git("rev-parse", "HEAD").strip(), "ref": args.ref,
           "campaign": args.campaign, "compare_jobs": sorted(wanted),
           "repeats": args.repeats, "cpus": os.cpu_count(), "machine": platform.machine(),
           "python": platform.python_version(), "numpy": np.__version__,
           "load_average": os.getloadavg(), "results": results}
    if args.ref:
        (pc, fc), (pr, fr) = outputs["current"], outputs[f"ref {args.ref}"]
        rel = compare_rel_diff(fr, fc)
        maps = all(np.array_equal(a[2], b[2], equal_nan=True)
                   for a, b in zip(fr, fc, strict=True))
        doc["same_results"] = {"poses_bit_identical": same_poses(pr, pc),
                               "compare_max_rel_diff": rel, "compare_maps_identical": maps}
        print(f"same results: {doc['same_results']}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

r'''Campaign wall time: the quick and the paper campaign, first and repeated runs, per-stage CPU

SYNOPSIS

    uv run python benchmarks/bench_campaign.py [--campaigns quick paper] [-j 2]
        [--repeats 1] [--first] [--keep DIR]

Runs each campaign (campaigns/quick.toml: target <= 20 s; campaigns/paper.toml:
22 cameras x CAHV/CAHVOR/CAHVORE x 6 poses of the dots (jpl/mrcal/opencv) and of the
AprilTag grid (jpl), target <= 90 s (set for the dots alone: the AprilTag grid doubles its CPU);
or any campaign TOML) with the local process executor, each run in a fresh
child process and a fresh run directory (a temporary one unless --keep),
without the report.

Repeated runs (--repeats, default 1): the renderer's numba kernels are first
compiled (or found up to date) in this process (the harness's warm_up on the
campaign's jobs), so the timed runs load them, as every run after the first
one does. --first adds the first run after a kernel change: a child with an
empty NUMBA_CACHE_DIR, whose parent compiles every kernel before the workers
start.

Per run: the wall time against the target, the seconds summed per stage
(poses, render, detect, calibrate per calibrator, compare; CPU-side seconds
summed over the workers, so they can exceed the wall time), the number of
images rendered (twin cameras share their images), the record counts, the
numba warm-up the campaign did before its workers started, the workers' malloc setting
(harness.executors.worker_top_pad, or the environment's MALLOC_* variables they keep), and
the peak resident memory, CPU seconds (system too) and minor page faults of the campaign's
process and of each worker (sampled from /proc: common.ProcessTree).
Records: campaign/<name>/first, campaign/<name>/repeat-<i>, and
campaign/<name>/repeated (wall seconds: min and median over the repeats).
Not a test: the machine is shared, so the figures depend on its load (the
load average is recorded).
'''

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import common

SCRIPT = "bench_campaign"
TARGETS = {"quick": 20.0, "paper": 90.0}


def child(campaign_path, run_dir, workers):
    r'''Run one campaign in this (fresh) process; print its figures as JSON'''
    from common import load_campaign, run_campaign, stage_seconds

    campaign = load_campaign(campaign_path)
    entries = campaign.validate()
    malloc = _malloc_setting(entries)
    with common.ProcessTree() as tree, common.Stopwatch() as sw:
        doc = run_campaign(campaign, run_dir, workers=workers, progress=False, entries=entries)
    procs = tree.processes
    worker_peaks = [p["peak_rss_bytes"] for p in procs if p["role"] == "worker"]
    stages, images = stage_seconds(doc["records"])
    counts = {}
    for r in doc["records"].values():
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    print(json.dumps({
        "wall_s": sw.wall_s, "workers": workers, "jobs": doc["execution"]["jobs"],
        "images": images,
        "twin_jobs": sum(len(v) for v in (doc["execution"].get("twins") or {}).values()),
        "records": len(doc["records"]), "statuses": counts, "stage_seconds": stages,
        "warm_up": doc["execution"].get("warm_up"),
        "cpu_s": sw.cpu_s,
        "peak_rss_bytes": common.peak_rss_bytes(),
        "peak_rss_worker_bytes": max(worker_peaks, default=None),
        "malloc": malloc,
        "processes": procs}))


def _malloc_setting(entries):
    r'''The malloc setting the campaign's local workers start with: {"top_pad": bytes}
(harness.executors.worker_top_pad of the largest camera), or {"environment": the malloc
variables set here, which the workers keep instead}; {} where the tree has neither'''
    try:
        from harness.executors import malloc_environment, worker_top_pad
    except ImportError:     # a tree before the workers' malloc setting
        return {}
    env = malloc_environment()
    if env:
        return {"environment": env}
    return {"top_pad": worker_top_pad(max(e.model.width * e.model.height
                                          for e in entries.values()))}


def one_run(path, workers, run_dir, env=None):
    cmd = [sys.executable, __file__, "--child", str(path), str(run_dir), "-j", str(workers)]
    load = list(os.getloadavg())
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=common.ROOT,
                       env=dict(os.environ, **(env or {})))
    # the load average (1, 5, 15 min) when the run started and when it ended
    loads = {"load_average_start": load, "load_average": list(os.getloadavg())}
    if r.returncode != 0:
        return {"status": "failed", "reason": " ".join(r.stderr.strip().splitlines()[-3:]),
                **loads}
    return dict(json.loads(r.stdout.strip().splitlines()[-1]), **loads)


def _campaign_path(name):
    path = Path(name)
    return path if path.suffix else common.CAMPAIGNS / f"{name}.toml"


def measure(out, path, workers, first=False, repeats=1, keep=None):
    r'''Time one campaign: the first run (fresh numba cache) if `first`, then `repeats` runs
with the kernels compiled -> the records added (campaign/<name>/first, .../repeat-<i>,
.../repeated)'''
    from common import warm_up

    label = path.stem
    runs = []
    with tempfile.TemporaryDirectory(prefix="camval-bench-") as tmp:
        base = Path(keep) if keep else Path(tmp)
        if first:
            with tempfile.TemporaryDirectory(prefix="numba-cache-") as cache:
                runs.append(("first", one_run(path, workers, base / f"{label}-first",
                                              {"NUMBA_CACHE_DIR": cache})))
        if repeats:
            with common.Stopwatch() as sw:
                info = warm_up(common.campaign_jobs(path), force=True)
            print(f"{label}: numba warm-up in this process {sw.wall_s:.1f} s "
                  f"({info.get('renders')})", flush=True)
        for i in range(repeats):
            runs.append((f"repeat-{i + 1}", one_run(path, workers, base / f"{label}-{i + 1}")))
    walls, added = [], []
    for kind, r in runs:
        rec = out.add(f"campaign/{label}/{kind}", r, campaign=str(path),
                      target_s=TARGETS.get(label))
        added.append(rec)
        if rec["status"] != "ok":
            print(f"{label} {kind}: {rec['status']}: {rec['reason']}")
            continue
        # what a gate spec judges (campaigns/gate-speed.toml): wall seconds, and the CPU
        # seconds of the campaign's process and all its descendants (less load-bound)
        rec["seconds"] = {"campaign": rec["wall_s"], "campaign_cpu": rec["cpu_s"] + sum(
            p["cpu_s"] for p in rec.get("processes") or [])}
        if kind != "first":
            walls.append(rec["wall_s"])
        target = rec["target_s"]
        if target is not None:
            rec["meets_target"] = bool(rec["wall_s"] <= target)
        workers_rss = [p["peak_rss_bytes"] / 2**20 for p in rec.get("processes") or []
                       if p["role"] == "worker"]
        warm = rec.get("warm_up") or {}
        print(f"\n{label} {kind}: {rec['wall_s']:.1f} s wall"
              + (f" (target <= {target:.0f} s: {'met' if rec['meets_target'] else 'NOT met'})"
                 if target is not None else "")
              + f", {rec['jobs']} jobs ({rec['twin_jobs']} of them twins rendered with "
              f"another camera), {rec['images']} images, {rec['records']} records "
              f"{rec['statuses']}, {rec['workers']} workers; numba warm-up before the workers "
              f"{warm.get('seconds', 0):.1f} s (cached: {warm.get('cached')}); workers' "
              f"malloc {rec.get('malloc') or 'as glibc starts it'}; peak RSS "
              f"{rec['peak_rss_bytes'] / 2**20:.0f} MiB (campaign process), workers "
              + (", ".join(f"{m:.0f}" for m in workers_rss) or "none seen") + " MiB"
              f"; load average {rec['load_average_start'][0]:.1f} at the start, "
              f"{rec['load_average'][0]:.1f} at the end", flush=True)
        for p in rec.get("processes") or []:
            print(f"  process {p['pid']:>7} {p['role']:<6} peak RSS "
                  f"{p['peak_rss_bytes'] / 2**20:6.0f} MiB, CPU {p['cpu_s']:6.1f} s (system "
                  f"{p.get('sys_s', 0.0):.1f} s), {p.get('minflt', 0)} minor page faults")
        print(f"  {'campaign process CPU':20s} {rec['cpu_s']:8.1f} s")
        print(f"  {'all processes CPU':20s} {rec['seconds']['campaign_cpu']:8.1f} s")
        for stage, t in rec["stage_seconds"].items():
            print(f"  {stage:20s} {t:8.1f} s ({'CPU' if stage.startswith('cpu:') else 'wall'}"
                  f" in the workers, summed)")
    if walls:
        cpus = [r["seconds"]["campaign_cpu"] for r in added
                if r["status"] == "ok" and not r["fullname"].endswith("/first")]
        added.append(out.add(f"campaign/{label}/repeated", campaign=str(path),
                             wall_s=common.summary(walls), target_s=TARGETS.get(label),
                             seconds={"campaign": min(walls), "campaign_cpu": min(cpus)}))
    return added


def run(args, out):
    if args.child:
        campaign, run_dir = args.child
        child(campaign, run_dir, args.jobs)
        sys.exit(0)
    for name in args.campaigns:
        measure(out, _campaign_path(name), args.jobs, args.first, args.repeats, args.keep)


def make_parser():
    ap = common.parser(__doc__, repeats=1, warmup=0)
    ap.add_argument("--campaigns", nargs="+", default=["quick", "paper"],
                    help="campaign names (campaigns/NAME.toml) or TOML paths")
    ap.add_argument("-j", "--jobs", type=int, default=os.cpu_count(), help="local workers")
    ap.add_argument("--first", action="store_true",
                    help="also the first run after a kernel change (empty numba cache)")
    ap.add_argument("--keep", metavar="DIR", help="keep the run directories under DIR")
    ap.add_argument("--child", nargs=2, metavar=("CAMPAIGN", "RUN_DIR"),
                    help=__import__("argparse").SUPPRESS)
    ap.set_defaults(run=run)
    return ap


if __name__ == "__main__":
    sys.exit(common.main(SCRIPT, make_parser()))

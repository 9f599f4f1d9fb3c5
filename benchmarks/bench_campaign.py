r'''Campaign wall time: the quick and the full paper campaign, with per-stage time

SYNOPSIS

    uv run python benchmarks/bench_campaign.py [--only quick|paper] [-j 2]
        [--out benchmarks/results/campaign.json] [--keep DIR]

Runs campaigns/quick.toml (target <= 20 s) and campaigns/paper.toml (22
cameras x CAHV/CAHVOR/CAHVORE x 6 poses, jpl/mrcal/opencv; target <= 90 s)
with the local process executor, each into a fresh run directory (a temporary
one unless --keep), without the report. First one small job runs in this
process (unless --cold) so that the renderer's compiled kernels are cached
and the workers load them instead of compiling. Prints the wall time against the
target, the time summed per stage (poses, render, detect, calibrate per
calibrator, compare; these are CPU-side seconds summed over the workers, so
they can exceed the wall time), the number of images rendered (twin cameras
share their images), and the record counts.
Writes one JSON document. Not a test: the machine is shared, so the figures
depend on its load (the load average is recorded).
'''

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TARGETS = {"quick": 20.0, "paper": 90.0}


def warm_up():
    r'''Run the quick campaign's 640x480 jobs (CAHV, CAHVOR, CAHVORE) once in this process:
compiles (and caches) the renderer's numba kernels for every model family and imports every
stage, so the timed runs measure the work, not the JIT'''
    from harness.campaign import load_campaign
    from harness.runner import expand_jobs, run_job
    campaign = load_campaign(ROOT / "campaigns" / "quick.toml")
    jobs = [j for j in expand_jobs(campaign) if j.camera_key == "17"]
    t0 = time.perf_counter()
    statuses = [r["status"] for j in jobs for r in run_job(j)["records"]]
    return {"jobs": [j.key for j in jobs], "seconds": time.perf_counter() - t0,
            "statuses": statuses}


def bench(name, workers, keep=None):
    from harness.campaign import load_campaign
    from harness.runner import run_campaign, stage_seconds
    campaign = load_campaign(ROOT / "campaigns" / f"{name}.toml")
    entries = campaign.validate()
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(keep) / name if keep else Path(tmp) / name
        t0 = time.perf_counter()
        doc = run_campaign(campaign, run_dir, workers=workers, progress=True, entries=entries)
        wall = time.perf_counter() - t0
    stages, images = stage_seconds(doc["records"])
    counts = {}
    for r in doc["records"].values():
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    return {"campaign": name, "wall_seconds": wall, "target_seconds": TARGETS[name],
            "meets_target": wall <= TARGETS[name], "workers": workers,
            "jobs": doc["execution"]["jobs"], "images": images,
            "twin_jobs": sum(len(v) for v in (doc["execution"].get("twins") or {}).values()),
            "records": len(doc["records"]), "statuses": counts, "stage_seconds": stages,
            "load_average": os.getloadavg()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("quick", "paper"))
    ap.add_argument("-j", "--jobs", type=int, default=os.cpu_count())
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "campaign.json"))
    ap.add_argument("--keep", metavar="DIR", help="keep the run directories under DIR")
    ap.add_argument("--cold", action="store_true",
                    help="no warm-up job: include the numba compilation in the times")
    args = ap.parse_args(argv)
    names = [args.only] if args.only else ["quick", "paper"]
    warm = None
    if not args.cold:
        warm = warm_up()
        print(f"warm-up: {len(warm['jobs'])} jobs in {warm['seconds']:.1f} s "
              f"({warm['statuses']})")
    results = []
    for name in names:
        r = bench(name, args.jobs, args.keep)
        results.append(r)
        print(f"\n{name}: {r['wall_seconds']:.1f} s wall (target <= {r['target_seconds']:.0f} s: "
              f"{'met' if r['meets_target'] else 'NOT met'}), {r['jobs']} jobs "
              f"({r['twin_jobs']} of them twins rendered with another camera), "
              f"{r['images']} images, {r['records']} records {r['statuses']}, "
              f"{r['workers']} workers, load average {r['load_average'][0]:.1f}")
        for stage, t in r["stage_seconds"].items():
            print(f"  {stage:20s} {t:8.1f} s")
    doc = {"benchmark": "bench_campaign", "utc": datetime.now(UTC).isoformat(),
           "machine": {"node": platform.node(), "cpus": os.cpu_count(),
                       "python": platform.python_version()},
           "warm_up": warm, "results": results}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1) + "\n")
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

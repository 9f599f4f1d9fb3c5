r'''Numba warm-up before local workers: a campaign after a kernel change, with and without

SYNOPSIS

    uv run python benchmarks/bench_warmup.py [--campaign campaigns/quick.toml] [-j 2]
        [--out benchmarks/results/warmup.json]

After a change to the ray-cast kernels numba's cache is stale and every
process that renders compiles the kernels again. harness.runner.run_jobs
therefore compiles them once in the parent (warm_up) before it starts the
local worker processes, which then load the cached kernels. This benchmark
runs the campaign three times in fresh child processes: with an empty
NUMBA_CACHE_DIR (the state right after a kernel change) and warm=False (every
worker compiles); with another empty one and warm=True (the parent compiles,
the workers load); and again on that now filled cache with warm=True (the
warm-up only reads numba's cache index). It prints the wall time,
the warm-up's seconds, and the render seconds of the slowest job (the first
job of a worker, which includes the compilation when not warmed), and writes
one JSON document. Not a test: the machine is shared, so the figures depend on
its load (recorded).
'''

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(campaign_path, workers, warm):
    sys.path.insert(0, str(ROOT))
    from harness.campaign import load_campaign
    from harness.runner import run_campaign
    campaign = load_campaign(campaign_path)
    entries = campaign.validate()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        doc = run_campaign(campaign, Path(tmp) / "run", workers=workers, progress=False,
                           entries=entries, warm=warm)
        wall = time.perf_counter() - t0
    jobs = {}
    for r in doc["records"].values():
        jobs.setdefault(r["fullname"].rsplit("/", 1)[0], r.get("seconds") or {})
    renders = sorted((s.get("render", 0.0) for s in jobs.values()), reverse=True)
    counts = {}
    for r in doc["records"].values():
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    return {"warm": warm, "wall_seconds": wall, "workers": workers,
            "warm_up": doc["execution"].get("warm_up"),
            "slowest_job_render_seconds": renders[:workers + 1],
            "render_seconds_total": sum(renders), "statuses": counts,
            "load_average": os.getloadavg()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", default=str(ROOT / "campaigns" / "quick.toml"))
    ap.add_argument("-j", "--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "warmup.json"))
    ap.add_argument("--child", choices=("warm", "cold"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.campaign, args.jobs, args.child == "warm")))
        return 0
    results = []
    labels = {"cold": "stale cache, no warm-up", "warm": "stale cache, warm-up",
              "cached": "cache up to date, warm-up"}
    with tempfile.TemporaryDirectory(prefix="numba-cache-") as tmp:
        # cold: every worker compiles; warm: the parent compiles, the workers load;
        # cached: the same cache again (the warm-up only checks numba's index)
        for mode, cache in (("cold", "a"), ("warm", "b"), ("cached", "b")):
            env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / cache))
            t0 = time.perf_counter()
            out = subprocess.run([sys.executable, __file__, "--child",
                                  "cold" if mode == "cold" else "warm", "--campaign",
                                  args.campaign, "-j", str(args.jobs)], env=env, cwd=ROOT,
                                 capture_output=True, text=True, check=False)
            if out.returncode != 0:
                print(out.stderr[-3000:], file=sys.stderr)
                return 1
            r = json.loads(out.stdout.strip().splitlines()[-1])
            r["mode"] = mode
            r["process_seconds"] = time.perf_counter() - t0
            results.append(r)
            wu = r["warm_up"]
            print(f"{labels[mode]:26s} wall {r['wall_seconds']:6.1f} s (process "
                  f"{r['process_seconds']:6.1f} s), warm-up {wu['seconds'] if wu else 0.0:5.1f} s"
                  f", slowest job renders "
                  f"{', '.join(f'{x:.1f}' for x in r['slowest_job_render_seconds'])} s, "
                  f"render total {r['render_seconds_total']:.1f} s, load "
                  f"{r['load_average'][0]:.1f}, {r['statuses']}", flush=True)
    doc = {"benchmark": "bench_warmup", "utc": datetime.now(UTC).isoformat(),
           "campaign": args.campaign, "cpus": os.cpu_count(), "results": results}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

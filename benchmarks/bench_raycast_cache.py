r'''The ray cache of the ray-cast renderer on the large cameras of the paper campaign

SYNOPSIS

    uv run python benchmarks/bench_raycast_cache.py [--cameras 3 21] [--reps 2] [--threads N]
        [--out benchmarks/results/raycast_cache.json]

For each camera (default: the 5120x3840 slots 3 and 21 of campaigns/paper.toml)
and each model family of the campaign (CAHV, CAHVOR, CAHVORE), the job's 6
poses are rendered as the campaign renders them (harness.runner.render_stage:
raycast, K = 16, adaptive), starting from an empty ray cache, as a job of a
new camera does. Reported per job: CPU seconds (time.process_time, all
threads) and wall seconds of the 6 renders, the ray-cache seconds of each
render (metadata ray_cache_seconds), the bytes the cache holds afterwards,
and the sha256 of each image (to check that a change of the renderer leaves
every pixel as it was). numba is warmed first (harness.runner.warm_up on the jobs).
The machine is shared: each job is run --reps times and the minimum is
reported next to every repeat; the load average is recorded. --threads sets
numba's thread count (default: all): with another process busy on a core,
numba's spinning threads inflate CPU seconds, and --threads 1 gives the
cleaner count of the work.

Prints the figures and writes one JSON document.
'''

import argparse
import hashlib
import json
import os
import platform
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.records import git_commit  # noqa: E402

CAMPAIGN = ROOT / "campaigns" / "paper.toml"


def _job_once(job):
    from harness.runner import _renderer, _target, camera_stage, poses_stage, render_stage

    _, truth = camera_stage(job)
    target = _target(job.target)
    poses = poses_stage(truth, target, job.poses_n, job.poses_seed)
    renderer = _renderer(job.renderer)
    renderer.clear_cache()
    c0 = time.process_time()
    t0 = time.perf_counter()
    results, _, _ = render_stage(job.renderer, truth, target, poses, job.settings)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    cache_bytes = renderer._cache_size()
    renderer.clear_cache()
    return {
        "cpu_s": cpu,
        "wall_s": wall,
        "render_s": [r.metadata["seconds"] for r in results],
        "ray_cache_s": [r.metadata["ray_cache_seconds"] for r in results],
        "board_fraction": [r.metadata["board_fraction"] for r in results],
        "samples": [r.metadata["samples"] for r in results],
        "adaptive_fraction": [r.metadata["adaptive_fraction"] for r in results],
        "cache_bytes": int(cache_bytes),
        "sha256": [hashlib.sha256(r.image.tobytes()).hexdigest() for r in results],
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cameras", nargs="+", default=["3", "21"])
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "raycast_cache.json"))
    args = ap.parse_args(argv)

    from harness.campaign import load_campaign
    from harness.runner import expand_jobs, warm_up

    if args.threads is not None:
        import numba
        numba.set_num_threads(args.threads)
    campaign = load_campaign(CAMPAIGN)
    jobs = [j for j in expand_jobs(campaign) if j.camera in args.cameras
            and j.renderer == "raycast"]
    if not jobs:
        raise SystemExit(f"no raycast job of cameras {args.cameras} in {CAMPAIGN}")

    t0 = time.perf_counter()
    warm_up(jobs, force=True)   # compile or load the kernels in this process
    print(f"numba warm-up: {time.perf_counter() - t0:.2f} s wall")

    rows = []
    for job in jobs:
        runs = [_job_once(job) for _ in range(args.reps)]
        hashes = {tuple(r["sha256"]) for r in runs}
        if len(hashes) != 1:
            raise SystemExit(f"{job.key}: repeats gave different images")
        best = min(runs, key=lambda r: r["cpu_s"])
        row = {"job": job.key, "camera": job.camera, "family": job.family,
               "cpu_s": best["cpu_s"], "wall_s": min(r["wall_s"] for r in runs),
               "cpu_s_reps": [r["cpu_s"] for r in runs],
               "wall_s_reps": [r["wall_s"] for r in runs],
               "render_s": best["render_s"], "ray_cache_s": best["ray_cache_s"],
               "board_fraction": best["board_fraction"], "samples": best["samples"],
               "adaptive_fraction": best["adaptive_fraction"], "cache_bytes": best["cache_bytes"],
               "sha256": best["sha256"]}
        rows.append(row)
        print(f"{job.key:55s} cpu {row['cpu_s']:6.2f} s  wall {row['wall_s']:6.2f} s  "
              f"(reps cpu {', '.join(f'{c:.2f}' for c in row['cpu_s_reps'])})  "
              f"cache {row['cache_bytes'] / 2**20:6.0f} MiB  "
              f"renders {' '.join(f'{s:.2f}' for s in row['render_s'])} s")
    total_cpu = sum(r["cpu_s"] for r in rows)
    total_wall = sum(r["wall_s"] for r in rows)
    print(f"total: cpu {total_cpu:.2f} s, wall {total_wall:.2f} s over {len(rows)} jobs")

    doc = {
        "benchmark": "raycast_cache",
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "commit": git_commit()["commit"],
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "loadavg": os.getloadavg()},
        "campaign": str(CAMPAIGN.relative_to(ROOT)),
        "reps": args.reps,
        "threads": args.threads,
        "jobs": rows,
        "total_cpu_s": total_cpu,
        "total_wall_s": total_wall,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

r'''The ray-cast renderer on the 5120x3840 cameras of the paper campaign

SYNOPSIS

    NUMBA_NUM_THREADS=1 uv run python benchmarks/bench_raycast_paper.py [--reps 2]
        [--cameras 1 3 21] [--families CAHVOR] [--save DIR | --compare DIR]
        [--out benchmarks/results/raycast_paper.json]

The jobs of campaigns/paper.toml whose camera is 5120x3840 (slots 1, 2, 3, 4,
19, 20, 21, 22 under CAHV, CAHVOR and CAHVORE: 24 jobs) are built as the
campaign builds them (harness.runner.camera_stage, poses_stage: the same
truth models and 6 poses), and each is rendered as a job of a new camera
renders it: the ray cache is emptied, built (timed on its own), then the 6
images are rendered (raycast, K = 16, adaptive, as the campaign's settings).

Reported per job: CPU seconds (time.process_time) of the ray cache and of each
render, their total, and the sha256 of every image (a change that should leave
every pixel as it was must leave these as they were). Run it with
NUMBA_NUM_THREADS=1: CPU seconds of a single thread are the cleanest count of
the work on a shared machine. Each job is run --reps times; the minimum of
each figure is reported with the spread of the totals.

--evict leaves the cache as a job left it instead of emptying it around every
job: the next job's camera evicts it, as in a campaign worker (which renders
job after job with one shared cache), so that the ray cache's figure includes
what eviction saves or costs (RaycastRenderer reuses the arrays of the camera
it drops for a new one of the same size).

--save DIR writes every image (zlib-compressed float32) to DIR; --compare DIR
reads them back and reports, per job and in all, the number of pixels that
differ and the largest absolute difference.

Prints the figures and writes one JSON document.
'''

import argparse
import hashlib
import json
import os
import platform
import sys
import time
import zlib
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.records import git_commit  # noqa: E402

CAMPAIGN = ROOT / "campaigns" / "paper.toml"
SIZE = (5120, 3840)


def paper_jobs(cameras=None, families=None):
    r'''The raycast jobs of the paper campaign whose camera is 5120x3840'''
    from harness.campaign import load_campaign
    from harness.runner import expand_jobs

    campaign = load_campaign(CAMPAIGN)
    entries = campaign.validate()
    jobs = []
    for job in expand_jobs(campaign, entries):
        model = entries[job.camera].model
        if (model.width, model.height) != SIZE or job.renderer != "raycast":
            continue
        if cameras and str(job.camera) not in cameras:
            continue
        if families and job.family not in families:
            continue
        jobs.append(job)
    return jobs


def _job_once(job, keep, evict=False):
    from harness.runner import _renderer, _target, camera_stage, poses_stage
    from renderers.base import RenderSettings

    _, truth = camera_stage(job)
    target = _target(job.target)
    poses = poses_stage(truth, target, job.poses_n, job.poses_seed)
    pattern = target.pattern()
    settings = RenderSettings(spp=int(job.settings["spp"]),
                              adaptive=bool(job.settings["adaptive"]),
                              options=dict(job.settings.get("options") or {}))
    renderer = _renderer(job.renderer)
    if evict:
        _as_previous_camera(renderer, truth)
    else:
        renderer.clear_cache()
    c0 = time.process_time()
    renderer.rays(truth)
    cache_cpu = time.process_time() - c0
    render_cpu, images, meta, sha = [], [], [], []
    for Rt in poses:
        c0 = time.process_time()
        result = renderer.render(truth, pattern, Rt, settings)
        render_cpu.append(time.process_time() - c0)
        sha.append(hashlib.sha256(result.image.tobytes()).hexdigest())
        images.append(result.image if keep else None)
        meta.append(result.metadata)
    if not evict:
        renderer.clear_cache()
    return {
        "cache_cpu_s": cache_cpu,
        "render_cpu_s": render_cpu,
        "cpu_s": cache_cpu + sum(render_cpu),
        "sha256": sha,
        "meta": meta,
        "images": images,
    }


def _as_previous_camera(renderer, model):
    r'''--evict: the cache keeps what the last job left, as in a campaign worker, but this
job's own camera is filed under another key (a repeat must build its rays again,
evicting that entry as it would evict another camera's)'''
    from renderers.raycast import _model_key
    with renderer._lock:
        entry = renderer._rays.pop(_model_key(model), None)
        if entry is not None:
            renderer._rays[("previous camera",)] = entry


def _image_file(directory, job, i):
    return Path(directory) / f"{job.key.replace('/', '_')}_{i}.f32z"


def _save(path, image):
    path.write_bytes(zlib.compress(np.ascontiguousarray(image, dtype=np.float32).tobytes(), 1))


def _load(path, shape):
    return np.frombuffer(zlib.decompress(path.read_bytes()), dtype=np.float32).reshape(shape)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cameras", nargs="+", default=None)
    ap.add_argument("--families", nargs="+", default=None)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--evict", action="store_true",
                    help="leave the cache as a job left it (the next camera evicts it, as in "
                         "a campaign worker) instead of emptying it around every job")
    ap.add_argument("--save", default=None)
    ap.add_argument("--compare", default=None)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "raycast_paper.json"))
    args = ap.parse_args(argv)

    import numba

    from harness.runner import warm_up

    jobs = paper_jobs(args.cameras, args.families)
    if not jobs:
        raise SystemExit("no 5120x3840 raycast job matches")
    if args.save:
        Path(args.save).mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    warm_up(jobs, force=True)   # compile or load the kernels in this process
    print(f"numba warm-up: {time.perf_counter() - t0:.2f} s wall; "
          f"numba threads {numba.get_num_threads()}")

    rows = []
    ndiff_all = 0
    maxdiff_all = 0.0
    for job in jobs:
        runs = []
        for rep in range(args.reps):
            keep = rep == 0 and bool(args.save or args.compare)
            runs.append(_job_once(job, keep, args.evict))
        if len({tuple(r["sha256"]) for r in runs}) != 1:
            raise SystemExit(f"{job.key}: repeats gave different images")
        images = runs[0]["images"]
        meta = runs[0]["meta"]
        row = {"job": job.key, "camera": job.camera, "family": job.family,
               "cpu_s": min(r["cpu_s"] for r in runs),
               "cpu_s_reps": [r["cpu_s"] for r in runs],
               "cache_cpu_s": min(r["cache_cpu_s"] for r in runs),
               "render_cpu_s": [min(r["render_cpu_s"][i] for r in runs)
                                for i in range(len(meta))],
               "board_fraction": [m["board_fraction"] for m in meta],
               "adaptive_fraction": [m["adaptive_fraction"] for m in meta],
               "blocks_tested": [m["blocks_tested"] for m in meta],
               "pixels_tested": [m["pixels_tested"] for m in meta],
               "samples": [m["samples"] for m in meta],
               "sha256": runs[0]["sha256"]}
        if args.save:
            for i, im in enumerate(images):
                _save(_image_file(args.save, job, i), im)
        if args.compare:
            nd, md = 0, 0.0
            for i, im in enumerate(images):
                ref = _load(_image_file(args.compare, job, i), im.shape)
                d = np.abs(im.astype(np.float64) - ref.astype(np.float64))
                nd += int(np.count_nonzero(d))
                md = max(md, float(d.max()))
            row["pixels_differing"] = nd
            row["max_abs_difference"] = md
            ndiff_all += nd
            maxdiff_all = max(maxdiff_all, md)
        rows.append(row)
        spread = max(row["cpu_s_reps"]) - min(row["cpu_s_reps"])
        cmp = (f"  differ {row['pixels_differing']} px (max {row['max_abs_difference']:.3g})"
               if args.compare else "")
        print(f"{job.key:45s} cpu {row['cpu_s']:6.2f} s (spread {spread:.2f})  "
              f"cache {row['cache_cpu_s']:5.2f}  renders "
              f"{' '.join(f'{s:.2f}' for s in row['render_cpu_s'])}{cmp}", flush=True)
    total = sum(r["cpu_s"] for r in rows)
    total_cache = sum(r["cache_cpu_s"] for r in rows)
    total_render = sum(sum(r["render_cpu_s"]) for r in rows)
    print(f"total over {len(rows)} jobs: cpu {total:.2f} s (ray cache {total_cache:.2f} s, "
          f"renders {total_render:.2f} s)")
    for family in sorted({r["family"] for r in rows}):
        fam = [r for r in rows if r["family"] == family]
        print(f"  {family:8s} ray cache {sum(r['cache_cpu_s'] for r in fam):6.2f} s, renders "
              f"{sum(sum(r['render_cpu_s']) for r in fam):6.2f} s")
    if args.compare:
        print(f"against {args.compare}: {ndiff_all} pixels differ, max |difference| "
              f"{maxdiff_all:.3g}")

    doc = {
        "benchmark": "raycast_paper",
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "commit": git_commit()["commit"],
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "loadavg": os.getloadavg()},
        "campaign": str(CAMPAIGN.relative_to(ROOT)),
        "numba_threads": numba.get_num_threads(),
        "reps": args.reps,
        "evict": args.evict,
        "jobs": rows,
        "total_cpu_s": total,
        "total_cache_cpu_s": total_cache,
        "total_render_cpu_s": total_render,
    }
    if args.compare:
        doc["compare"] = {"pixels_differing": ndiff_all, "max_abs_difference": maxdiff_all}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

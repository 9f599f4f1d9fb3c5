r'''Dot-grid detector: CPU and wall seconds per image on paper-campaign renders

SYNOPSIS

    uv run --frozen python benchmarks/bench_detect.py [--images /tmp/detbench]
        [--cameras 3,21,5] [--repeats 5] [--save det.npz] [--check det.npz]
        [--out benchmarks/results/detect.json]

The images are the ray-cast renders of the CAHVOR dots jobs of campaigns/paper.toml
for the chosen cameras (3 and 21: 5120x3840, 5: 1024x1024), 6 poses each. They are
rendered once and kept as cam<camera>_<pose>.npy in --images; later runs reuse them.

Each image is detected --repeats times; the minimum over the repeats of
time.process_time() (CPU) and time.perf_counter() (wall) is reported per image,
and their median over the images of one size. --save writes every detection (q,
found, status, info) to an .npz; --check compares with such a file and fails unless q (NaN
positions included), the found masks, statuses and infos are identical: a faster detector must give
the same detections bit for bit.

Prints a table and writes one JSON document.
'''

import argparse
import json
import platform
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.records import git_commit  # noqa: E402


def render_images(directory, cameras):
    r'''Render the CAHVOR dots job of each camera into directory (if not there yet)'''
    from harness.campaign import load_campaign
    from harness.runner import _target, camera_stage, expand_jobs, poses_stage, render_stage

    directory.mkdir(parents=True, exist_ok=True)
    jobs = expand_jobs(load_campaign(ROOT / "campaigns" / "paper.toml"))
    for cam in cameras:
        if list(directory.glob(f"cam{cam}_*.npy")):
            continue
        job = next((j for j in jobs if j.camera == cam and j.family == "CAHVOR"
                    and j.target == "dots"), None)
        if job is None:
            raise SystemExit(f"paper.toml has no CAHVOR dots job for camera {cam}")
        _, truth = camera_stage(job)
        target = _target(job.target)
        poses = poses_stage(truth, target, job.poses_n, job.poses_seed)
        results, _, _ = render_stage(job.renderer, truth, target, poses, job.settings)
        for i, r in enumerate(results):
            np.save(directory / f"cam{cam}_{i}.npy", np.asarray(r.image))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=Path, default=Path("/tmp/detbench"))
    ap.add_argument("--cameras", default="3,21,5")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--save", type=Path)
    ap.add_argument("--check", type=Path)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "detect.json")
    args = ap.parse_args()

    from targets.boards import load_target
    from targets.detect import detect

    cameras = args.cameras.split(",")
    render_images(args.images, cameras)
    target = load_target("dots")
    paths = sorted(p for cam in cameras for p in args.images.glob(f"cam{cam}_*.npy"))
    rows, dets = [], {}
    for p in paths:
        img = np.load(p)
        cpu, wall = [], []
        for _ in range(args.repeats):
            c0, w0 = time.process_time(), time.perf_counter()
            det = detect(img, target)
            cpu.append(time.process_time() - c0)
            wall.append(time.perf_counter() - w0)
        dets[p.stem] = det
        rows.append({"image": p.stem, "shape": list(img.shape), "status": det.status,
                     "n_found": int(det.n_found), "cpu_s": min(cpu), "wall_s": min(wall)})
        print(f"{p.stem:10s} {img.shape[1]:5d}x{img.shape[0]:<5d} {det.status:10s} "
              f"{det.n_found:4d} dots  cpu {min(cpu):.4f} s  wall {min(wall):.4f} s",
              flush=True)

    sizes = {}
    for r in rows:
        sizes.setdefault(f"{r['shape'][1]}x{r['shape'][0]}", []).append(r)
    summary = {k: {"images": len(v), "median_cpu_s": float(np.median([r["cpu_s"] for r in v])),
                   "median_wall_s": float(np.median([r["wall_s"] for r in v]))}
               for k, v in sizes.items()}
    for k, v in summary.items():
        print(f"{k:10s} {v['images']} images: median cpu {v['median_cpu_s']:.4f} s, "
              f"wall {v['median_wall_s']:.4f} s per image")

    if args.save:
        np.savez(args.save, **{f"q_{k}": d.q for k, d in dets.items()},
                 **{f"found_{k}": d.found for k, d in dets.items()},
                 **{f"status_{k}": np.array(d.status) for k, d in dets.items()},
                 **{f"info_{k}": np.array(json.dumps(d.info, sort_keys=True, default=str))
                    for k, d in dets.items()})
    identical = None
    if args.check:
        ref = np.load(args.check)
        bad = [k for k, d in dets.items()
               if not (np.array_equal(ref[f"q_{k}"], d.q, equal_nan=True)
                       and np.array_equal(np.isnan(ref[f"q_{k}"]), np.isnan(d.q))
                       and np.array_equal(ref[f"found_{k}"], d.found)
                       and str(ref[f"status_{k}"]) == d.status
                       and str(ref[f"info_{k}"]) == json.dumps(d.info, sort_keys=True,
                                                               default=str))]
        identical = not bad
        print("detections identical to", args.check if identical else f"{args.check}: NO, {bad}")

    doc = {"date": datetime.now(UTC).isoformat(timespec="seconds"),
           "commit": git_commit()["commit"],
           "python": platform.python_version(), "machine": platform.machine(),
           "repeats": args.repeats, "images": rows, "per_size": summary,
           "identical_to": str(args.check) if args.check else None, "identical": identical}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print("wrote", args.out)
    if identical is False:
        raise SystemExit(1)


if __name__ == "__main__":
    main()

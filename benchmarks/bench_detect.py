r'''Dot-grid detector: CPU and wall seconds per image on paper-campaign renders

SYNOPSIS

    uv run --frozen python benchmarks/bench_detect.py [--images /tmp/detbench]
        [--cameras 3,21,5] [--repeats 5] [--save det.npz] [--check det.npz]
        [--against REV] [--out benchmarks/results/detect.json]

The images are the ray-cast renders of the CAHVOR dots jobs of campaigns/paper.toml
for the chosen cameras (3 and 21: 5120x3840, 5: 1024x1024), 6 poses each. They are
rendered once and kept as cam<camera>_<pose>.npy in --images; later runs reuse them.

Each image is detected --repeats times; the minimum over the repeats of
time.process_time() (CPU) and time.perf_counter() (wall) is reported per image,
and their median over the images of one size. --save writes every detection (q,
found, status, info) to an .npz; --check compares with such a file and fails unless q (NaN
positions included), the found masks, statuses and infos are identical: a faster detector must give
the same detections bit for bit.

--against REV also times targets/detect_dots.py of git revision REV, interleaved with
the working tree's (each repeat runs one, then the other, on the same image), so that
both see the same load of a shared machine; its detections must be identical too. The
per-image figures of REV are reported as cpu_s_against, wall_s_against.

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


def load_against(rev):
    r'''detect_dots() of targets/detect_dots.py at git revision rev, as a module of the
targets package (its relative imports are those of the working tree)'''
    import importlib.util
    import subprocess
    import tempfile

    import targets  # noqa: F401  (the package of the module loaded below)

    src = subprocess.run(["git", "show", f"{rev}:targets/detect_dots.py"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    path = Path(tempfile.mkdtemp()) / "detect_dots_against.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("targets._detect_dots_against", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module.detect_dots


def same_detection(a, b):
    r'''Detections identical: q (NaN positions included), found, status, reason, info'''
    return (np.array_equal(a.q, b.q, equal_nan=True)
            and np.array_equal(np.isnan(a.q), np.isnan(b.q))
            and np.array_equal(a.found, b.found) and a.status == b.status
            and a.reason == b.reason
            and json.dumps(a.info, sort_keys=True, default=str)
            == json.dumps(b.info, sort_keys=True, default=str))


def timed(f, *args):
    r'''(result, CPU seconds, wall seconds) of f(*args)'''
    c0, w0 = time.process_time(), time.perf_counter()
    r = f(*args)
    return r, time.process_time() - c0, time.perf_counter() - w0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=Path, default=Path("/tmp/detbench"))
    ap.add_argument("--cameras", default="3,21,5")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--save", type=Path)
    ap.add_argument("--check", type=Path)
    ap.add_argument("--against", help="git revision whose detect_dots is timed alongside")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "detect.json")
    args = ap.parse_args()

    from targets.boards import load_target
    from targets.detect import detect

    cameras = args.cameras.split(",")
    render_images(args.images, cameras)
    target = load_target("dots")
    against = load_against(args.against) if args.against else None
    paths = sorted(p for cam in cameras for p in args.images.glob(f"cam{cam}_*.npy"))
    rows, dets, differ = [], {}, []
    for p in paths:
        img = np.load(p)
        cpu, wall, cpu_a, wall_a = [], [], [], []
        for _ in range(args.repeats):
            det, c, w = timed(detect, img, target)
            cpu.append(c)
            wall.append(w)
            if against is not None:
                det_a, c, w = timed(against, img, target)
                cpu_a.append(c)
                wall_a.append(w)
        dets[p.stem] = det
        row = {"image": p.stem, "shape": list(img.shape), "status": det.status,
               "n_found": int(det.n_found), "cpu_s": min(cpu), "wall_s": min(wall)}
        line = (f"{p.stem:10s} {img.shape[1]:5d}x{img.shape[0]:<5d} {det.status:10s} "
                f"{det.n_found:4d} dots  cpu {min(cpu):.4f} s  wall {min(wall):.4f} s")
        if against is not None:
            row.update(cpu_s_against=min(cpu_a), wall_s_against=min(wall_a))
            line += f"  ({args.against}: cpu {min(cpu_a):.4f} s)"
            if not same_detection(det, det_a):
                differ.append(p.stem)
        rows.append(row)
        print(line, flush=True)

    sizes = {}
    for r in rows:
        sizes.setdefault(f"{r['shape'][1]}x{r['shape'][0]}", []).append(r)
    summary = {k: {"images": len(v),
                   **{f"median_{key}": float(np.median([r[key] for r in v]))
                      for key in ("cpu_s", "wall_s", "cpu_s_against", "wall_s_against")
                      if key in v[0]}}
               for k, v in sizes.items()}
    for k, v in summary.items():
        print(f"{k:10s} {v['images']} images: median cpu {v['median_cpu_s']:.4f} s, "
              f"wall {v['median_wall_s']:.4f} s per image"
              + (f"; {args.against}: cpu {v['median_cpu_s_against']:.4f} s"
                 if against is not None else ""))
    if against is not None:
        print("detections identical to", args.against if not differ else f"{args.against}: "
              f"NO, {differ}")

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
           "identical_to": str(args.check) if args.check else None, "identical": identical,
           "against": args.against,
           "identical_to_against": None if against is None else not differ}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print("wrote", args.out)
    if identical is False or differ:
        raise SystemExit(1)


if __name__ == "__main__":
    main()

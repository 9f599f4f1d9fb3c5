r'''Targets: pose-planner time over the catalogue, detector time and accuracy per target

SYNOPSIS

    uv run python benchmarks/bench_targets.py [--cameras 5,15,17,1] [--spp 16]
        [--out benchmarks/results/targets.json]

Part 1: plan_poses(model, "dots") for every catalogue camera but SuperCam
(seconds per camera; SuperCam's refusal is recorded with its reason).

Part 2: for each chosen camera and each target (dots, apriltag, chessboard),
the 6 planned poses rendered noise-free by the ray-cast renderer (K x K,
adaptive), then detected: detection seconds per image, points found, and
the error of the detections against the truth - the exact expected centroids
for dots, the exact projections of the corners for tags and chessboards -
as RMS and max over all points of the 6 poses. expected_centroids() seconds
per pose (100 dots, 1440 outline points each) are reported too.

Prints a table and writes one JSON document.
'''

import argparse
import json
import platform
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.records import git_commit  # noqa: E402


def plan_part(catalogue):
    from targets.boards import load_target
    from targets.poses import NotVisibleError, plan_poses

    t = load_target("dots")
    out = []
    for key in catalogue.keys():
        m = catalogue.get(key).model
        t0 = time.perf_counter()
        try:
            plan_poses(m, t)
            rec = {"camera": key, "status": "ok"}
        except NotVisibleError as e:
            rec = {"camera": key, "status": "not-visible", "reason": str(e)}
        rec["seconds"] = time.perf_counter() - t0
        out.append(rec)
    return out


def detect_part(catalogue, cameras, spp):
    import numpy as np

    from renderers.base import RenderSettings, get_renderer
    from targets.boards import load_target
    from targets.centroids import expected_centroids, projected_points
    from targets.detect import detect
    from targets.poses import plan_poses

    renderer = get_renderer("raycast")
    out = []
    for key in cameras:
        m = catalogue.get(key).model
        for name in ("dots", "apriltag", "chessboard"):
            t = load_target(name)
            errs, det_s, cen_s, found, expected, statuses = [], [], [], 0, 0, []
            for Rt in plan_poses(m, t):
                img = renderer.render(m, t.pattern(), Rt, RenderSettings(spp=spp)).image
                t0 = time.perf_counter()
                det = detect(img, t)
                det_s.append(time.perf_counter() - t0)
                if name == "dots":
                    t0 = time.perf_counter()
                    truth = expected_centroids(m, t, Rt)
                    cen_s.append(time.perf_counter() - t0)
                else:
                    truth = projected_points(m, t, Rt)
                statuses.append(det.status)
                found += det.n_found
                expected += det.n_expected
                e = np.linalg.norm(det.q - truth, axis=-1)
                errs.append(e[np.isfinite(e)])
            e = np.concatenate(errs)
            out.append({
                "camera": key, "size": [m.width, m.height], "target": name, "spp": spp,
                "status_ok": statuses.count("ok"), "n_found": found, "n_expected": expected,
                "rms_px": float(np.sqrt(np.mean(e ** 2))) if len(e) else None,
                "max_px": float(e.max()) if len(e) else None,
                "detect_seconds_mean": float(np.mean(det_s)),
                "expected_centroids_seconds_mean": float(np.mean(cen_s)) if cen_s else None,
            })
            r = out[-1]
            print(f"{key:>18} {m.width}x{m.height} {name:10} ok {r['status_ok']}/6 "
                  f"found {found}/{expected}  rms {r['rms_px'] or float('nan'):.4f}  "
                  f"max {r['max_px'] or float('nan'):.4f} px  detect "
                  f"{r['detect_seconds_mean']:.3f} s", flush=True)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", default="5,15,17,1",
                        help="catalogue keys for part 2 (comma-separated)")
    parser.add_argument("--spp", type=int, default=16, help="K for the renders of part 2")
    parser.add_argument("--skip-plan", action="store_true", help="skip part 1")
    parser.add_argument("--out", default=str(ROOT / "benchmarks/results/targets.json"))
    args = parser.parse_args(argv)

    from reference_models.catalogue import load_catalogue

    catalogue = load_catalogue()
    doc = {"schema": 1, "utc": datetime.now(UTC).isoformat(), "commit": git_commit()["commit"],
           "machine": {"node": platform.node(), "python": platform.python_version(),
                       "processor": platform.processor()}}
    if not args.skip_plan:
        plans = plan_part(catalogue)
        ok = [p["seconds"] for p in plans if p["status"] == "ok"]
        print(f"plan_poses: {len(ok)} cameras, {sum(ok) / len(ok):.3f} s mean, "
              f"{max(ok):.3f} s max per camera")
        for p in plans:
            if p["status"] != "ok":
                print(f"  {p['camera']}: {p['reason']}")
        doc["plan_poses"] = plans
    doc["detection"] = detect_part(catalogue, args.cameras.split(","), args.spp)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

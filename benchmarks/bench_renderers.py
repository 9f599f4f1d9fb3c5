r'''Renderer speed and geometric accuracy at 1024x1024: raycast, POV-Ray (both paths), OSMesa

SYNOPSIS

    uv run python benchmarks/bench_renderers.py [--poses 2] [--K 1 4 16]
        [--out benchmarks/results/renderers.json]
    uv run python benchmarks/bench_renderers.py --from-run runs/<id>
        # the recalibration table of a `camval verify campaigns/renderers.toml` run

The navcam-like CAHVOR of /work/shared/FINDINGS.md (1024x1024, f = 1236 px,
O tilted 0.47 deg, R = [0, -0.1, 0.02]) looks at the JPL 10x10 dot board
(targets.boards "dots") in poses from targets.poses.plan_poses. Each renderer
renders every pose at K = 1, 4, 16; the dot detector (targets.detect) finds
the dots and each detection is compared with the exact centroid of the
projected dot outline (targets.centroids.expected_centroids). Reported per
(renderer, K): wall seconds per image (median over poses; the first render of
a camera includes building its rays or warp map, reported apart), centroid
error RMS and max over all found dots, dots found.

POV-Ray's mesh camera (a smooth mesh_camera on the pixel-corner grid,
adaptive K x K where pattern edges are) runs at every K.

"warp-only" isolates the resampling error of the warp paths: the ray caster
renders the warp's own pinhole camera (an exact CAHV, K x K area samples),
then renderers.warp maps it to the model as POV-Ray's and OSMesa's paths do.
Whatever it adds to the ray caster's own error is the warp's.

"-area2" configurations render the pinhole twice as fine with 2 x 2 warp
samples per model pixel (renderers.warp area sampling) at K/2, the same
number of samples per model pixel as K (povray-perspective-area2 only with
--only, it is slow).

The machine is shared: the load average is recorded with the results.
'''

import argparse
import json
import os
import platform
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.records import git_commit  # noqa: E402


def navcam_like():
    from reference_models.cahvore import CAHVOR

    f, W, H = 1236.0, 1024, 1024
    A = np.array([0.0, 0.0, 1.0])
    t = np.radians(0.47)
    O = np.array([np.sin(t), 0.0, np.cos(t)])
    return CAHVOR(C=[0, 0, 0], A=A, H=f * np.array([1.0, 0, 0]) + 511.7 * A,
                  V=f * np.array([0, 1.0, 0]) + 512.2 * A, O=O, R=[0.0, -0.1, 0.02],
                  width=W, height=H)


def pinhole_cahv(pinhole):
    r'''The CAHV model of a renderers.warp.Pinhole (camera frame = world frame)'''
    from reference_models.cahvore import CAHV

    A = np.array([0.0, 0.0, 1.0])
    return CAHV(C=[0.0, 0.0, 0.0], A=A, H=pinhole.fx * np.array([1.0, 0, 0]) + pinhole.cx * A,
                V=pinhole.fy * np.array([0, 1.0, 0]) + pinhole.cy * A,
                width=pinhole.width, height=pinhole.height)


def warp_only(raycast, model, pattern, Rt_cam_board, K):
    r'''The exact pinhole render (ray caster, K x K) warped to the model (bilinear)'''
    from renderers.base import RenderSettings
    from renderers.warp import PinholeWarp

    warp = PinholeWarp.for_model(model)
    pin = raycast.render(pinhole_cahv(warp.pinhole), pattern, Rt_cam_board,
                         RenderSettings(spp=K)).image
    return warp.apply(pin, "bilinear", Rt_cam_board=Rt_cam_board)


def run_table(run_dir):
    r'''Print one row per (camera, model, renderer path, K) of a campaign run: time per
image, projection-difference RMS, residual RMS, Hc/Vc errors, and the 0.002 px bars'''
    from harness.records import load_run

    recs = load_run(run_dir)["records"]
    rows = []
    for r in recs.values():
        s = r["settings"]
        path = r["renderer"] + "".join(f" {k}={v}" for k, v in sorted(s["options"].items()))
        rows.append((r["camera"], r["model"], path, s["spp"], r))
    rows.sort(key=lambda x: (x[0], x[1], x[2], x[3]))
    print(f"{'camera':6s} {'model':8s} {'renderer path':28s} {'K':>3s} {'s/image':>8s} "
          f"{'proj RMS':>9s} {'resid RMS':>9s} {'Hc err':>8s} {'Vc err':>8s}  bars")
    for cam, model, path, K, r in rows:
        if r["status"] != "ok":
            print(f"{cam:6s} {model:8s} {path:28s} {K:3d}  {r['status']}: {r['reason'][:70]}")
            continue
        t = r["seconds"]["render_per_image"]
        pr, rr = r["projection"]["rms"], r["residuals"]["rms"]
        hc, vc = r["params"]["Hc"], r["params"]["Vc"]
        bars = "meets" if pr <= 0.002 and rr <= 0.002 else "misses"
        print(f"{cam:6s} {model:8s} {path:28s} {K:3d} {t:8.2f} {pr:9.4f} {rr:9.4f} "
              f"{hc:+8.4f} {vc:+8.4f}  {bars}")


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--from-run":
        run_table(sys.argv[2])
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=2)
    ap.add_argument("--K", type=int, nargs="+", default=[1, 4, 16])
    ap.add_argument("--only", nargs="*", default=None,
                    help="renderer configs to run (raycast, osmesa, povray-perspective, "
                         "povray-mesh)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "renderers.json"))
    ap.add_argument("--append", action="store_true",
                    help="keep the other renderers' results already in --out")
    args = ap.parse_args()

    from renderers.base import RendererError, RenderSettings, get_renderer
    from targets.boards import load_target
    from targets.centroids import expected_centroids
    from targets.detect import detect
    from targets.poses import plan_poses

    model = navcam_like()
    target = load_target("dots")
    pattern = target.pattern()
    poses = plan_poses(model, target, n=args.poses, seed=0)
    truth = [expected_centroids(model, target, Rt) for Rt in poses]
    area = {"warp_scale": 2.0, "warp_samples": 2}
    configs = [("raycast", "raycast", {}), ("osmesa", "osmesa", {}),
               ("povray-perspective", "povray", {"camera": "perspective"}),
               ("povray-mesh", "povray", {"camera": "mesh"}),
               ("warp-only", "raycast", {}),
               ("osmesa-area2", "osmesa", area),
               ("povray-perspective-area2", "povray", dict(area, camera="perspective"))]
    if args.only:
        configs = [c for c in configs if c[0] in args.only]
    else:
        configs = [c for c in configs if c[0] != "povray-perspective-area2"]
    previous = []
    if args.append and os.path.exists(args.out):
        with open(args.out) as f:
            previous = [r for r in json.load(f)["results"]
                        if r["renderer"] not in {c[0] for c in configs}]
    results = []
    for label, name, options in configs:
        try:
            renderer = get_renderer(name)
        except RendererError as e:
            results.append(dict(renderer=label, status="unavailable", reason=str(e)))
            continue
        for K in args.K:
            if label.endswith("-area2"):
                # a pinhole twice as fine: K/2 samples per pinhole pixel is K per model pixel
                K = max(1, K // 2)
            times, errors, found = [], [], 0
            first = None
            for Rt, q_true in zip(poses, truth, strict=True):
                t0 = time.perf_counter()
                if label == "warp-only":
                    image = warp_only(renderer, model, pattern, Rt, K)
                else:
                    res = renderer.render(model, pattern, Rt,
                                          RenderSettings(spp=K, options=options))
                    image = res.image
                dt = time.perf_counter() - t0
                if first is None:
                    first = dt
                else:
                    times.append(dt)
                det = detect(image, target)
                ok = det.found
                found += int(ok.sum())
                errors.append(np.linalg.norm(det.q[ok] - q_true[ok], axis=-1))
            e = np.concatenate(errors) if errors else np.array([])
            rec = dict(renderer=label, version=renderer.version(), K=K, options=options,
                       status="ok",
                       seconds_first=round(first, 3),
                       seconds_per_image=round(float(np.median(times)) if times else first, 3),
                       centroid_rms_px=float(np.sqrt(np.mean(e ** 2))) if len(e) else None,
                       centroid_max_px=float(e.max()) if len(e) else None,
                       dots_found=found, dots_expected=len(poses) * len(target.points()),
                       load_average=os.getloadavg()[0])
            results.append(rec)
            print(f"{label:20s} K={K:2d}  {rec['seconds_per_image']:8.3f} s/image "
                  f"(first {rec['seconds_first']:.3f})  centroid RMS "
                  f"{rec['centroid_rms_px']:.4f} max {rec['centroid_max_px']:.4f} px  "
                  f"found {found}/{rec['dots_expected']}  load {rec['load_average']:.1f}",
                  flush=True)
    doc = dict(schema=1, benchmark="renderers", utc=datetime.now(UTC).isoformat(),
               commit=git_commit()["commit"], machine=platform.node(), cpus=os.cpu_count(),
               model="navcam-like CAHVOR 1024x1024 f=1236 (FINDINGS.md)",
               target="dots", poses=len(poses), results=previous + results)
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(doc, f, indent=1, allow_nan=False)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

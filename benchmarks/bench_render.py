r'''Renderers: the ray caster's accuracy and speed, campaign jobs, other renderers, terrain, shadows

SYNOPSIS

    uv run python benchmarks/bench_render.py raycast [--cameras 5,12,15] [--K 1 2 4 8 16]
        [--repeats 3] [--skip-accuracy] [--skip-speed] [--skip-large]
    NUMBA_NUM_THREADS=1 uv run python benchmarks/bench_render.py jobs [--campaign paper]
        [--cameras 3 21] [--families CAHVOR] [--repeats 2]
    uv run python benchmarks/bench_render.py renderers [--poses 2] [--K 1 4 16] [--only ...]
    uv run python benchmarks/bench_render.py renderers --from-run runs/<id>
    uv run python benchmarks/bench_render.py terrain [--repeats 9]
    uv run python benchmarks/bench_render.py shadows [--elevations 8,15,30,50]

Each part writes one JSON document, benchmarks/results/<UTC stamp>-bench_render-<part>.json
(benchmarks/common.py: one record per measured case, keyed by its fullname).
`bench_render.py PART --help` says what the part measures.

raycast    dot-centre accuracy against K (12 cameras of 1024x1024 x 6 poses), warm speed
           at 1024x1024, and a 5120x3840 camera in a fresh process (time, peak memory)
jobs       the ray-cast jobs of a campaign (default: the paper's 5120x3840 cameras), each
           rendered as a campaign job renders them (no ray cache: every image alike)
renderers  raycast, POV-Ray (both paths), OSMesa and the warp at 1024x1024: time and
           centroid error
terrain    terrain ray casting, 1024x1024 with exact shadow rays (bar <= 0.5 s)
shadows    terrain shadows: exact shadow rays, POV-Ray and the OSMesa shadow map compared
'''

import argparse
import json
import os
import subprocess
import sys
import time

import common
import numpy as np

SCRIPT = "bench_render"


# ---------------------------------------------------------------- raycast

RAYCAST_BARS = {"accuracy_K16_rms_px": 0.0015, "accuracy_K16_max_px": 0.005,
                "speed_1024_K16_s": 0.050, "speed_5120x3840_K16_s": 1.0,
                "peak_memory_5120x3840_GiB": 2.0}
SPEED_CAMERAS = ("15", "12")
LARGE_CAMERA = "1"


def _render(renderer, model, target, Rt, K):
    from renderers.base import RenderSettings
    with common.Stopwatch() as sw:
        res = renderer.render(model, target.pattern(), Rt, RenderSettings(spp=K, adaptive=True))
    return res, sw.wall_s, sw.cpu_s


def raycast_accuracy(out, cameras, Ks):
    from reference_models.catalogue import load_catalogue
    from renderers.raycast import RaycastRenderer
    from targets.boards import load_target
    from targets.centroids import expected_centroids
    from targets.detect import detect
    from targets.poses import plan_poses

    cat = load_catalogue()
    target = load_target("dots")
    renderer = RaycastRenderer()
    errors = {K: [] for K in Ks}
    missing = {K: 0 for K in Ks}
    for cam in cameras:
        model = cat.get(cam).model
        poses = plan_poses(model, target, n=6, seed=0)
        for K in Ks:
            errs = []
            for Rt in poses:
                res, wall, _ = _render(renderer, model, target, Rt, K)
                det = detect(res.image, target)
                truth = expected_centroids(model, target, Rt)
                ok = det.found & np.all(np.isfinite(truth), axis=-1)
                missing[K] += int(target.Npoints - ok.sum())
                errs.append(np.linalg.norm(det.q[ok] - truth[ok], axis=-1))
            e = np.concatenate(errs)
            errors[K].append(e)
            out.add(f"raycast/accuracy/{cam}/K={K}", camera=cam, family=model.family,
                    central=bool(model.is_central), K=K, rms_px=float(np.sqrt(np.mean(e**2))),
                    max_px=float(e.max()), n=int(e.size))
        print(f"  camera {cam:>2} {model.family:<7} " + "  ".join(
            f"K={K}: {out.records[f'raycast/accuracy/{cam}/K={K}']['rms_px']:.4f}/"
            f"{out.records[f'raycast/accuracy/{cam}/K={K}']['max_px']:.4f}" for K in Ks),
            flush=True)
    for K in Ks:
        e = np.concatenate(errors[K])
        rec = out.add(f"raycast/accuracy/all/K={K}", cameras=list(cameras), K=K,
                      rms_px=float(np.sqrt(np.mean(e**2))), max_px=float(e.max()),
                      n=int(e.size), not_found=missing[K])
        if K == 16:
            rec["bars"] = {"rms_px": RAYCAST_BARS["accuracy_K16_rms_px"],
                           "max_px": RAYCAST_BARS["accuracy_K16_max_px"]}
            rec["meets_bars"] = bool(rec["rms_px"] <= RAYCAST_BARS["accuracy_K16_rms_px"]
                                     and rec["max_px"] <= RAYCAST_BARS["accuracy_K16_max_px"])
        print(f"  all  K={K:<2}: RMS {rec['rms_px']:.4f} px, max {rec['max_px']:.4f} px "
              f"({rec['n']} dots, {rec['not_found']} not found)")


def raycast_speed(out, cameras, repeats):
    from reference_models.catalogue import load_catalogue
    from renderers.raycast import RaycastRenderer
    from targets.boards import load_target
    from targets.poses import plan_poses

    cat = load_catalogue()
    target = load_target("dots")
    for cam in cameras:
        model = cat.get(cam).model
        renderer = RaycastRenderer()
        poses = plan_poses(model, target, n=6, seed=0)
        res, cold, _ = _render(renderer, model, target, poses[0], 16)   # the first image
        walls, cpus, fractions, samples = [], [], [], []
        for _ in range(repeats):
            for Rt in poses:
                res, wall, cpu = _render(renderer, model, target, Rt, 16)
                walls.append(wall)
                cpus.append(cpu)
                fractions.append(res.metadata["adaptive_fraction"])
                samples.append(res.metadata["samples"])
        r = out.add(f"raycast/speed/{cam}/K=16", camera=cam, family=model.family,
                    size=[model.width, model.height], central=bool(model.is_central),
                    cold_first_s=cold, wall_s=common.summary(walls), cpu_s=common.summary(cpus),
                    adaptive_fraction=float(np.median(fractions)),
                    rays_per_image=int(np.median(samples)), n=len(walls),
                    threads=res.metadata["threads"], bar_s=RAYCAST_BARS["speed_1024_K16_s"])
        r["meets_bar"] = bool(r["wall_s"]["median"] <= r["bar_s"])
        print(f"  camera {cam:>2} {model.family:<7}: median {r['wall_s']['median']:.4f} s "
              f"(min {r['wall_s']['min']:.4f}, CPU {r['cpu_s']['median']:.4f} s), "
              f"{100 * r['adaptive_fraction']:.2f}% supersampled, "
              f"{r['rays_per_image']} rays", flush=True)


def raycast_large_child(camera):
    r'''Run in a fresh process: 5120x3840 render times and peak memory, as JSON on stdout'''
    from reference_models.catalogue import load_catalogue
    from renderers.raycast import RaycastRenderer
    from targets.boards import load_target
    from targets.poses import plan_poses

    model = load_catalogue().get(camera).model
    target = load_target("dots")
    poses = plan_poses(model, target, n=6, seed=0)
    # compile (or load the compiled kernels) on a small camera first: not a 5120x3840 cost
    small = load_catalogue().get("17").model
    RaycastRenderer().render(small, target.pattern(), plan_poses(small, target, n=1)[0])
    rss0 = common.peak_rss_bytes() / 2**30
    renderer = RaycastRenderer()
    res, cold, _ = _render(renderer, model, target, poses[0], 16)
    outline_s = res.metadata["outline_seconds"]
    walls, cpus = [], []
    for Rt in poses:
        res, wall, cpu = _render(renderer, model, target, Rt, 16)
        walls.append(wall)
        cpus.append(cpu)
    print(json.dumps({"camera": camera, "size": [model.width, model.height],
                      "family": model.family, "central": bool(model.is_central),
                      "cold_s": cold, "outline_s": outline_s,
                      "wall_s": common.summary(walls), "cpu_s": common.summary(cpus),
                      "adaptive_fraction": res.metadata["adaptive_fraction"],
                      "peak_rss_GiB": common.peak_rss_bytes() / 2**30,
                      "rss_before_render_GiB": rss0}))


def raycast_large(out, camera):
    r = subprocess.run([sys.executable, __file__, "raycast", "--large-child", camera],
                       capture_output=True, text=True, cwd=common.ROOT)
    name = f"raycast/large/{camera}/K=16"
    if r.returncode != 0:
        out.add(name, status="failed", reason=" ".join(r.stderr.strip().splitlines()[-1:]))
        return
    rec = out.add(name, json.loads(r.stdout.strip().splitlines()[-1]),
                  bars={"wall_s": RAYCAST_BARS["speed_5120x3840_K16_s"],
                        "peak_rss_GiB": RAYCAST_BARS["peak_memory_5120x3840_GiB"]})
    rec["meets_bars"] = bool(rec["wall_s"]["median"] <= rec["bars"]["wall_s"]
                             and rec["peak_rss_GiB"] <= rec["bars"]["peak_rss_GiB"])
    print(f"  camera {rec['camera']} {rec['size'][0]}x{rec['size'][1]} {rec['family']}: "
          f"first {rec['cold_s']:.2f} s (outlines {rec['outline_s']:.3f} s), warm median "
          f"{rec['wall_s']['median']:.3f} s (CPU {rec['cpu_s']['median']:.3f}), "
          f"peak RSS {rec['peak_rss_GiB']:.2f} GiB", flush=True)


def part_raycast(args, out):
    r'''The exact ray-cast renderer: dot-centre accuracy against K, speed, memory

Accuracy: every 1024x1024 catalogue camera (slots 5-16; CAHVORE hazcams with
E != 0 and CAHVOR pancams/navcams) x the 6 poses of targets.poses.plan_poses
(the 10x10 "dots" target), rendered noise-free at K = 1, 2, 4, 8, 16
(adaptive); targets.detect finds the dots and each found dot is compared with
the exact centroid of its projected outline (targets.centroids.
expected_centroids). Bars at K = 16: RMS <= 0.0015 px, max <= 0.005 px.

Speed: the dot target at K = 16 adaptive, compiled, per image,
median over the 6 poses x --repeats, for the 1024x1024 navcam (slot 15, CAHVOR)
and hazcam (slot 12, noncentral CAHVORE); bar <= 0.050 s. CPU seconds
(all threads) are reported next to wall seconds.

Large: a 5120x3840 camera (slot 1, noncentral CAHVORE) in a fresh process:
first and next render times at K = 16 adaptive (bar <= 1 s),
and the peak resident memory of the process (getrusage ru_maxrss; bar
<= 2 GiB).

Records: raycast/accuracy/<camera|all>/K=<K>, raycast/speed/<camera>/K=16,
raycast/large/<camera>/K=16.
'''
    if args.large_child:
        raycast_large_child(args.large_child)
        sys.exit(0)
    cameras = args.cameras or common.catalogue_slots((1024, 1024))
    if not args.skip_speed:
        print("speed, 1024x1024, K=16 adaptive:")
        raycast_speed(out, args.speed_cameras, args.repeats)
    if not args.skip_large:
        print("5120x3840, K=16 adaptive (fresh process):")
        raycast_large(out, args.large_camera)
    if not args.skip_accuracy:
        print(f"accuracy (detected - expected centroid, RMS/max px), cameras {cameras}:")
        raycast_accuracy(out, cameras, args.K)


def _raycast_arguments(p):
    p.add_argument("--cameras", type=common.ids, default=None,
                   help="accuracy: catalogue slots (default: every 1024x1024 slot)")
    p.add_argument("--K", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    p.add_argument("--speed-cameras", type=common.ids, default=list(SPEED_CAMERAS))
    p.add_argument("--large-camera", default=LARGE_CAMERA)
    p.add_argument("--skip-accuracy", action="store_true")
    p.add_argument("--skip-speed", action="store_true")
    p.add_argument("--skip-large", action="store_true")
    p.add_argument("--large-child", metavar="CAMERA", help=argparse.SUPPRESS)


# ---------------------------------------------------------------- jobs

def _job_once(job):
    import hashlib

    from common import render_stage

    truth, target, poses = common.job_inputs(job)
    with common.Stopwatch() as sw:
        results, _, _ = render_stage(job.renderer, truth, target, poses, job.settings)
    return {
        "cpu_s": sw.cpu_s,
        "wall_s": sw.wall_s,
        "render_s": [r.metadata["seconds"] for r in results],
        "outline_s": [r.metadata.get("outline_seconds", 0.0) for r in results],
        "board_fraction": [r.metadata["board_fraction"] for r in results],
        "samples": [r.metadata["samples"] for r in results],
        "adaptive_fraction": [r.metadata["adaptive_fraction"] for r in results],
        "sha256": [hashlib.sha256(r.image.tobytes()).hexdigest() for r in results],
    }


def part_jobs(args, out):
    r'''The renders of a campaign's ray-cast jobs

For each job of --campaign (default campaigns/paper.toml) whose camera is one of
--cameras (default: its 5120x3840 cameras, slots 1-4 and 19-22) and whose family
is one of --families, the job's 6 poses are rendered as the campaign renders
them (harness render_stage: raycast, K = 16, adaptive; no ray cache is kept
between renders). numba is warmed first (the harness's
warm_up on the jobs). Each job is run --repeats times.

Reported per job: CPU seconds (time.process_time, all threads) and wall seconds
of the 6 renders (min, median, every repeat), the outline seconds and the
render seconds of each image (renderer metadata), and the sha256 of each image
(to check that a change of the renderer leaves every pixel as it was; repeats must
agree). Run with
NUMBA_NUM_THREADS=1: CPU seconds of a single thread are the cleanest count of
the work on a shared machine.

Records: jobs/<job key>.
'''
    from common import warm_up

    sizes = None if args.cameras else [(5120, 3840)]
    jobs = [j for j in common.campaign_jobs(args.campaign, args.cameras, args.families,
                                            sizes=sizes) if j.renderer == "raycast"]
    if not jobs:
        raise SystemExit(f"no raycast job of cameras {args.cameras or '5120x3840'} in "
                         f"{args.campaign}")
    with common.Stopwatch() as sw:
        warm_up(jobs, force=True)   # compile or load the kernels in this process
    print(f"numba warm-up: {sw.wall_s:.2f} s wall; numba threads {common.numba_threads()}")
    total_cpu = 0.0
    for job in jobs:
        runs = [_job_once(job) for _ in range(max(1, args.repeats))]
        if len({tuple(r["sha256"]) for r in runs}) != 1:
            raise SystemExit(f"{job.key}: repeats gave different images")
        best = min(runs, key=lambda r: r["cpu_s"])
        rec = out.add(f"jobs/{job.key}", job=job.key, camera=job.camera_key, family=job.family,
                      cpu_s=common.summary([r["cpu_s"] for r in runs]),
                      wall_s=common.summary([r["wall_s"] for r in runs]),
                      **{k: best[k] for k in ("render_s", "outline_s", "board_fraction",
                                              "samples", "adaptive_fraction", "sha256")})
        total_cpu += rec["cpu_s"]["min"]
        print(f"{job.key:55s} cpu {rec['cpu_s']['min']:6.2f} s  wall {rec['wall_s']['min']:6.2f} s"
              f"  (repeats cpu {', '.join(f'{c:.2f}' for c in rec['cpu_s']['values'])})  "
              f"outlines {max(rec['outline_s']):.3f} s  renders "
              f"{' '.join(f'{s:.2f}' for s in rec['render_s'])} s", flush=True)
    print(f"total: cpu {total_cpu:.2f} s over {len(jobs)} jobs")


def _jobs_arguments(p):
    p.add_argument("--campaign", default="paper", help="a campaign name or TOML path")
    p.add_argument("--cameras", type=common.ids, default=None)
    p.add_argument("--families", type=common.families, default=None)


part_jobs.repeats_warmup = (2, 0)


# ---------------------------------------------------------------- renderers

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


def run_table(out, run_dir):
    r'''One row per (camera, model, renderer path, K) of a campaign run: time per
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
        name = f"from-run/{r['fullname']}"
        if r["status"] != "ok":
            out.add(name, status=r["status"], reason=r.get("reason"))
            print(f"{cam:6s} {model:8s} {path:28s} {K:3d}  {r['status']}: {r['reason'][:70]}")
            continue
        t = r["seconds"]["render_per_image"]
        pr, rr = r["projection"]["rms"], r["residuals"]["rms"]
        hc, vc = r["params"]["Hc"], r["params"]["Vc"]
        bars = "meets" if pr <= 0.002 and rr <= 0.002 else "misses"
        out.add(name, camera=cam, model=model, path=path, K=K, seconds_per_image=t,
                projection_rms_px=pr, residuals_rms_px=rr, Hc=hc, Vc=vc, bars=bars)
        print(f"{cam:6s} {model:8s} {path:28s} {K:3d} {t:8.2f} {pr:9.4f} {rr:9.4f} "
              f"{hc:+8.4f} {vc:+8.4f}  {bars}")


def part_renderers(args, out):
    r'''Renderer speed and geometric accuracy at 1024x1024: raycast, POV-Ray (both paths), OSMesa

The navcam-like CAHVOR of /work/shared/FINDINGS.md (1024x1024, f = 1236 px,
O tilted 0.47 deg, R = [0, -0.1, 0.02]) looks at the JPL 10x10 dot board
(targets.boards "dots") in --poses poses from targets.poses.plan_poses. Each
renderer renders every pose at each --K; the dot detector (targets.detect)
finds the dots and each detection is compared with the exact centroid of the
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

--from-run RUN: instead, the recalibration table of a
`camval verify campaigns/renderers.toml` run (one record per row).

Records: renderers/<config>/K=<K> (status "unavailable" for a renderer this
machine lacks), or from-run/<fullname>.
'''
    if args.from_run:
        run_table(out, args.from_run)
        return
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
    for label, name, options in configs:
        try:
            renderer = get_renderer(name)
        except RendererError as e:
            out.add(f"renderers/{label}", status="unavailable", reason=str(e))
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
            rec = out.add(f"renderers/{label}/K={K}", renderer=label, version=renderer.version(),
                          K=K, options=options, model="navcam-like CAHVOR 1024x1024 f=1236",
                          target="dots", poses=len(poses), seconds_first=first,
                          wall_s=common.summary(times or [first]),
                          centroid_rms_px=float(np.sqrt(np.mean(e ** 2))) if len(e) else None,
                          centroid_max_px=float(e.max()) if len(e) else None,
                          dots_found=found, dots_expected=len(poses) * len(target.points()),
                          load_average=os.getloadavg()[0])
            print(f"{label:20s} K={K:2d}  {rec['wall_s']['median']:8.3f} s/image "
                  f"(first {first:.3f})  centroid RMS "
                  f"{rec['centroid_rms_px']:.4f} max {rec['centroid_max_px']:.4f} px  "
                  f"found {found}/{rec['dots_expected']}  load {rec['load_average']:.1f}",
                  flush=True)


def _renderers_arguments(p):
    p.add_argument("--poses", type=int, default=2)
    p.add_argument("--K", type=int, nargs="+", default=[1, 4, 16])
    p.add_argument("--only", nargs="*", default=None,
                   help="renderer configs to run (raycast, osmesa, povray-perspective, "
                        "povray-mesh, warp-only, osmesa-area2, povray-perspective-area2)")
    p.add_argument("--from-run", metavar="RUN", help="tabulate a renderers campaign run")


# ---------------------------------------------------------------- terrain

TERRAIN_BAR_SECONDS = 0.5
TERRAIN = dict(extent=(-1, 20, -12, 12), cell=0.05, texel=0.01, seed=1)
SUN = dict(azimuth_deg=120, elevation_deg=30)

# run in a fresh interpreter: what a new process pays before its first image
COLD = r'''
import json, sys, time
t0 = time.perf_counter()
sys.path.insert(0, sys.argv[1])
from reference_models.catalogue import load_catalogue
from renderers.raycast_terrain import render_terrain
from targets.terrain import Sun, ground_pose, make_terrain
t_import = time.perf_counter() - t0
terrain = make_terrain(**json.loads(sys.argv[2]), sun=Sun(**json.loads(sys.argv[3])))
model = load_catalogue().get(12).model
t1 = time.perf_counter()
r = render_terrain(model, terrain, ground_pose(0.30), spp=1)
t2 = time.perf_counter()
render_terrain(model, terrain, ground_pose(0.30), spp=1)
t3 = time.perf_counter()
print(json.dumps({"seconds_import": t_import, "seconds_first_render": t2 - t1,
                  "first_render_rays": r.metadata["seconds_rays"],
                  "first_render_prepare": r.metadata["seconds_prepare"],
                  "first_render_trace": r.metadata["seconds_trace"],
                  "seconds_second_render": t3 - t2}))
'''


def part_terrain(args, out):
    r'''Terrain ray-casting speed: 1024x1024 with exact shadow rays (bar: <= 0.5 s)

Renders the generated terrain (targets.terrain.make_terrain, 21 x 24 m, 5 cm
cells, 1 cm texels, rocks) through the MER B front-left hazcam (catalogue slot
12, CAHVORE, 1024x1024, 0.30 m above the ground) and through the Mars 2020
navcam (slot 21) scaled by 0.2 to 1024x768 (harness.studies.stereo.scale_model), on a
mast 1.9 m high pitched 20 deg down, with shadows on and off, K = 1; and the
hazcam again with the sun 10 deg high (long shadows, a larger sun bound).

The figure against the bar is the wall time of a whole warm render_terrain call
(pixel rays cached per (model, K), the terrain's pyramids made): primary rays,
Lambertian shading, one shadow ray per lit hit, the image assembled. Reports
the minimum and the median over --repeats, the numba thread count and the
load average before and after each case, since the machine is shared; and the
CPU time per thread (process CPU seconds / numba threads), close to what the
wall time would be with the cores free.

The cold cost is measured in a fresh process (numba's on-disk cache already
filled by this one): import, the first render (its pixel rays, the terrain's
pyramid and sun bound, loading the compiled kernels) and the second render.

Records: terrain/<case>/shadows=<on|off>, terrain/cold-start.
'''
    import numba

    from harness.studies.stereo import scale_model
    from reference_models.catalogue import load_catalogue
    from renderers.raycast_terrain import pixel_rays, render_terrain
    from targets.terrain import Sun, ground_pose, make_terrain

    cat = load_catalogue()
    t0 = time.perf_counter()
    terrain = make_terrain(**TERRAIN, sun=Sun(**SUN))
    t_gen = time.perf_counter() - t0
    hazcam = cat.get(12).model
    navcam = scale_model(cat.get(21).model, 0.2)
    low_sun = terrain.replace(sun=Sun(azimuth_deg=SUN["azimuth_deg"], elevation_deg=10.0))
    cases = [("hazcam12", "hazcam slot 12 (MER B front left, CAHVORE 1024x1024)", hazcam,
              ground_pose(0.30), terrain),
             ("navcam21x0.2", "navcam slot 21 scaled 0.2 (CAHVORE 1024x768), mast pitched "
              "20 deg", navcam, ground_pose(1.9, pitch_deg=20.0), terrain),
             ("hazcam12-sun10", "hazcam slot 12, sun 10 deg high (long shadows)", hazcam,
              ground_pose(0.30), low_sun)]
    for key, name, model, pose, terrain in cases[:args.cases]:
        t0 = time.perf_counter()
        pixel_rays(model, 1)
        t_rays = time.perf_counter() - t0
        first = render_terrain(model, terrain, pose, spp=1)   # compile / warm
        for shadows in (True, False):
            load_before = os.getloadavg()
            t = common.timed(lambda: render_terrain(model, terrain, pose, spp=1,  # noqa: B023
                                                    shadows=shadows),  # noqa: B023
                             repeats=args.repeats, warmup=0)
            r = t["result"]
            # CPU seconds / threads: the wall time the render would take with the
            # cores to itself (the machine is shared; the wall time includes waiting)
            cpu_per_thread = t["cpu_s"]["min"] / numba.get_num_threads()
            rec = out.add(f"terrain/{key}/shadows={'on' if shadows else 'off'}",
                          camera=name, width=model.width, height=model.height,
                          shadows=shadows, spp=1, wall_s=t["wall_s"], cpu_s=t["cpu_s"],
                          cpu_seconds_per_thread_min=cpu_per_thread,
                          load_average_before=load_before, load_average_after=os.getloadavg(),
                          seconds_pixel_rays_once=t_rays,
                          seconds_prepare_once=first.metadata["seconds_prepare"]
                          if shadows else None,
                          seconds_terrain_generation=t_gen,
                          terrain_hit_fraction=float(np.mean(np.isfinite(r.range))),
                          shadowed_fraction=float(np.mean((r.shadow == 1) | (r.shadow == 2))))
            if shadows:
                rec["bar_s"] = TERRAIN_BAR_SECONDS
                rec["meets_bar_wall_min"] = bool(t["wall_s"]["min"] <= TERRAIN_BAR_SECONDS)
                rec["meets_bar_wall_median"] = bool(t["wall_s"]["median"] <= TERRAIN_BAR_SECONDS)
                rec["meets_bar_cpu_per_thread"] = bool(cpu_per_thread <= TERRAIN_BAR_SECONDS)
            print(f"{name:68s} shadows={shadows!s:5s} wall min {t['wall_s']['min']:.3f} s  "
                  f"median {t['wall_s']['median']:.3f} s  cpu {t['cpu_s']['min']:.3f} s "
                  f"({cpu_per_thread:.3f} s/thread)  load {load_before[0]:.1f} -> "
                  f"{os.getloadavg()[0]:.1f}")
        print(f"{'':68s} pixel rays once {t_rays:.2f} s, terrain pyramid + sun bound "
              f"{first.metadata['seconds_prepare']:.3f} s (first render)")
    if args.no_cold:
        return
    r = subprocess.run([sys.executable, "-c", COLD, str(common.ROOT), json.dumps(TERRAIN),
                        json.dumps(SUN)], capture_output=True, text=True, cwd=common.ROOT)
    if r.returncode != 0:
        out.add("terrain/cold-start", status="failed",
                reason=" ".join(r.stderr.strip().splitlines()[-1:]))
    else:
        out.add("terrain/cold-start", json.loads(r.stdout.strip().splitlines()[-1]))
    print("cold, fresh process:", json.dumps(out.records["terrain/cold-start"]))


def _terrain_arguments(p):
    p.add_argument("--cases", type=int, default=3, help="the first N cases only")
    p.add_argument("--no-cold", action="store_true", help="skip the fresh-process case")


part_terrain.repeats_warmup = (9, 0)


# ---------------------------------------------------------------- shadows

SUN_STEPS_DEG = (0.1, 0.25, 0.5, 1.0)


def _marginal(terrain, exact, diff):
    r'''Of the differing triangles, the fraction whose exact state flips when the sun
moves by each step (elevation or azimuth, either way)'''
    from renderers.raycast_terrain import cell_shadows as raycast_cell_shadows
    from targets.terrain import Sun

    s = exact != 0
    az, el = terrain.sun.azimuth_deg, terrain.sun.elevation_deg
    res = {}
    nd = int(diff.sum())
    for d in SUN_STEPS_DEG:
        flip = np.zeros_like(s)
        for a, e in ((az, el - d), (az, el + d), (az - d, el), (az + d, el)):
            if not 0 < e <= 90:
                continue
            flip |= (raycast_cell_shadows(terrain.replace(sun=Sun(a, e))) != 0) != s
        res[f"{d:g}"] = float((diff & flip).sum() / nd) if nd else 1.0
    return res


def _camera_renders(out, terrain):
    from harness.studies.stereo import scale_model
    from reference_models.catalogue import load_catalogue
    from renderers import osmesa_terrain, povray_terrain, raycast_terrain
    from targets.terrain import ground_pose

    model = scale_model(load_catalogue().get(21).model, 0.2)
    # the terrain starts 1 m ahead of the mast
    x0, y0 = terrain.origin
    terrain = terrain.replace(origin=(1.0, y0 - (terrain.extent()[3] - y0) / 2))
    pose = ground_pose(1.9, pitch_deg=20.0)
    print(f"\ncamera renders: slot 21 scaled 0.2 ({model.width}x{model.height}), K = 2, "
          f"sun elevation {terrain.sun.elevation_deg:g} deg")
    raycast_terrain.render_terrain(model, terrain, pose, spp=2)     # compile, rays
    renders = {}
    for name, fn in (("raycast", raycast_terrain.render_terrain),
                     ("povray", lambda *a, **k: povray_terrain.render_terrain(
                         *a, shadow_codes=True, **k)),
                     ("osmesa", osmesa_terrain.render_terrain)):
        t0 = time.perf_counter()
        r = fn(model, terrain, pose, spp=2)
        seconds = time.perf_counter() - t0
        renders[name] = r
        rec = {"renderer": name, "seconds": seconds, "width": model.width,
               "height": model.height, "spp": 2,
               "elevation_deg": float(terrain.sun.elevation_deg)}
        if name != "raycast":
            e = renders["raycast"]
            d = np.abs(r.image.astype(np.float64) - e.image)
            rec.update(image_mean_abs_diff=float(d.mean()),
                       image_median_abs_diff=float(np.median(d)),
                       image_p99_abs_diff=float(np.percentile(d, 99)),
                       pixels_agree_lit_unlit=float(np.mean((r.shadow != 0) == (e.shadow != 0))),
                       pixels_agree_sky=float(np.mean((r.shadow == 255) == (e.shadow == 255))))
            print(f"  {name:8s} {seconds:6.2f} s; |image - exact| mean {d.mean():.4f} median "
                  f"{np.median(d):.4f} p99 {np.percentile(d, 99):.4f}; lit/unlit agree on "
                  f"{rec['pixels_agree_lit_unlit']:.2%} of pixels")
        else:
            g = np.isfinite(r.range)
            rec.update(ground_fraction=float(g.mean()),
                       unlit_fraction_of_ground=float(np.mean(r.shadow[g] != 0)))
            print(f"  {name:8s} {seconds:6.2f} s; ground {g.mean():.1%} of pixels, "
                  f"{rec['unlit_fraction_of_ground']:.1%} of it unlit")
        out.add(f"shadows/camera/{name}", rec)


def part_shadows(args, out):
    r'''Terrain shadows three ways: how often exact shadow rays, POV-Ray and the shadow map disagree

On a generated terrain (targets.terrain.make_terrain, size x size m, 5 cm
cells, relief 0.3 m, rocks up to 0.4 m: 205k triangles at the defaults), with
the sun at azimuth 120 deg and each elevation, asks three methods which
triangles are in shadow at their centroids (renderers.terrain_shadows):
raycast_terrain's exact shadow rays, POV-Ray's own shadows
(povray_terrain.cell_shadows) and the paper's two-pass z-buffer in OSMesa
(osmesa_terrain.cell_shadows) for each shadow-map size (slope_bias 0.5, the
default) and, at 4096, slope_bias 0.25 and 1.0. Prints and records for each pair the
fraction of triangles (and cells) that differ, the share of direct sunlight
that lands differently, and where the differences are: within one cell of an
exact shadow edge, on triangles nearly edge-on to the sun (cos i < 0.1),
and whether moving the sun by <= 0.1 / 0.25 / 0.5 / 1 deg (elevation or
azimuth) flips the exact answer there ("marginal"). Timings of each method.

Then (unless --no-camera) renders the terrain at the first elevation through
the Mars 2020 navcam (slot 21) scaled by 0.2 (1024x768, CAHVORE) on a mast
1.9 m high pitched 20 deg down, with each renderer's render_terrain (K = 2,
shadow codes on), and records the time, the image difference from the exact
render and the per-pixel shadow agreement.

Records: shadows/sun=<elevation>/<a>~<b>, shadows/camera/<renderer>.
'''
    from renderers import osmesa_terrain, povray_terrain
    from renderers.raycast_terrain import cell_shadows as raycast_cell_shadows
    from renderers.terrain_shadows import compare
    from targets.terrain import Sun, make_terrain

    elevations = [float(v) for v in args.elevations.split(",")]
    map_sizes = [int(v) for v in args.map_sizes.split(",")]
    base = make_terrain(extent=(0, args.size, 0, args.size), cell=args.cell, texel=0.05,
                        seed=args.seed, relief_m=0.3, relief_wavelength_m=3.0,
                        rocks_per_m2=1.5, rock_radius_m=(0.05, 0.4))
    ny, nx = base.heights.shape
    print(f"terrain {args.size} x {args.size} m, cell {args.cell} m: {(ny - 1) * (nx - 1)} cells, "
          f"{2 * (ny - 1) * (nx - 1)} triangles; POV-Ray {povray_terrain.povray_version()}, "
          f"OpenGL {osmesa_terrain.gl_version()}")
    raycast_cell_shadows(base)          # compile
    keys = ("disagree_fraction", "disagree_cells_fraction", "sunlight_weighted_disagreement",
            "disagree_fraction_not_grazing", "near_edge_fraction", "grazing_fraction",
            "edge_or_grazing_fraction",
            "max_edge_distance_cells", "facing_disagree", "shadowed_fraction_a",
            "shadowed_fraction_b", "cast_fraction_a", "cast_fraction_b")
    for el in elevations:
        t = base.replace(sun=Sun(120.0, el))
        t0 = time.perf_counter()
        exact = raycast_cell_shadows(t)
        t_ray = time.perf_counter() - t0
        t0 = time.perf_counter()
        pov = povray_terrain.cell_shadows(t)
        t_pov = time.perf_counter() - t0
        methods = [("raycast", exact, t_ray, {}), ("povray", pov, t_pov, {})]
        settings = [(S, 0.5) for S in map_sizes] + [(4096, 0.25), (4096, 1.0)]
        for S, sb in settings:
            t0 = time.perf_counter()
            code = osmesa_terrain.cell_shadows(t, map_size=S, slope_bias=sb)
            methods.append((f"osmesa map {S} bias {sb:g}", code, time.perf_counter() - t0,
                            {"map_size": S, "slope_bias": sb}))
        print(f"\nsun elevation {el:g} deg: exact shadowed {np.mean(exact != 0):.1%} "
              f"(cast {np.mean(exact == 2):.1%}); raycast {t_ray:.2f} s, povray {t_pov:.2f} s")
        pairs = [(methods[0], m) for m in methods[1:]] + [(methods[1], m) for m in methods[2:]]
        for (na, ca, _, _), (nb, cb, tb, opts) in pairs:
            c = compare(ca, cb, t)
            diff = (ca != 0) != (cb != 0)
            marginal = _marginal(t, exact, diff) if na == "raycast" else None
            name = f"shadows/sun={el:g}/{na}~{nb.replace(' ', '-')}"
            if name not in out.records:
                out.add(name, elevation_deg=el, azimuth_deg=120.0, a=na, b=nb, seconds_b=tb,
                        **opts, **{k: c[k] for k in keys}, n_triangles=c["n_triangles"],
                        disagree_triangles=c["disagree_triangles"],
                        marginal_sun_fraction=marginal, terrain_size_m=args.size,
                        cell_m=args.cell, seed=args.seed)
            m = "" if marginal is None else \
                "  marginal@" + "/".join(f"{v:.2f}" for v in marginal.values())
            print(f"  {na:8s} vs {nb:26s} differ {c['disagree_fraction']:7.3%} of triangles, "
                  f"{c['disagree_cells_fraction']:7.3%} of cells, sunlight "
                  f"{c['sunlight_weighted_disagreement']:6.3%}; at edge "
                  f"{c['near_edge_fraction']:.2f} grazing {c['grazing_fraction']:.2f} either "
                  f"{c['edge_or_grazing_fraction']:.3f} "
                  f"max {c['max_edge_distance_cells']} cells{m}  ({tb:.2f} s)")
    if not args.no_camera:
        _camera_renders(out, base.replace(sun=Sun(120.0, elevations[0])))


def _shadows_arguments(p):
    p.add_argument("--size", type=float, default=16.0, help="terrain side (m)")
    p.add_argument("--cell", type=float, default=0.05, help="grid cell (m)")
    p.add_argument("--elevations", default="8,15,30,50")
    p.add_argument("--map-sizes", default="1024,2048,4096,8192")
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--no-camera", action="store_true", help="skip the camera renders")


part_shadows.repeats_warmup = (1, 0)

PARTS = {"raycast": (part_raycast, _raycast_arguments),
         "jobs": (part_jobs, _jobs_arguments),
         "renderers": (part_renderers, _renderers_arguments),
         "terrain": (part_terrain, _terrain_arguments),
         "shadows": (part_shadows, _shadows_arguments)}


if __name__ == "__main__":
    sys.exit(common.main(SCRIPT, common.parser(__doc__, PARTS)))

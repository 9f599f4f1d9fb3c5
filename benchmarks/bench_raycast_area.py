r'''The ray caster's area coverage against K x K point sampling: dot-centroid accuracy and warm time

SYNOPSIS

    NUMBA_NUM_THREADS=2 uv run python benchmarks/bench_raycast_area.py
        [--cameras 15,17,1] [--poses 6] [--repeats 3]
        [--settings K=4 K=16 area area@1e-3 tested:area] [--memory-camera 1]

For each camera (catalogue slots; default 15: 1024x1024 CAHVOR navcam, 17:
640x480 CAHVORE fisheye hazcam, 1: 5120x3840 noncentral CAHVORE) and each
setting (point sampling K=<n> adaptive: coverage="point"; coverage="area", the
default, "area@<tolerance>" with options area_tolerance; a prefix "tested:" renders
with RaycastRenderer(outlines=False): edge pixels found by testing pixels instead
of from the projected outlines, for comparison), the 10x10 "dots" target at the
poses of targets.poses.plan_poses (seed 0) is rendered (kernels compiled; no ray
cache is kept between renders); targets.detect finds the dots and each is
compared with the exact centroid of its projected outline (targets.centroids.expected_centroids):
RMS and max over all dots of all poses. Time: wall and CPU seconds per image,
min and median over the poses x --repeats (pose 0 apart: the figure of issue
18). Bars (issue 18): 1024x1024 centroid RMS <= 0.001 px in <= 0.010 s warm on
2 threads; 5120x3840 <= 0.1 s and <= 400 MB peak. The machine is shared: the
load average at start and end is in the document (environment).

--memory-camera: that camera is also rendered in area mode in a fresh process,
which reports its peak resident memory (getrusage) and its first and next times,
wall and CPU (the first image's memory is fresh; the next ones reuse the buffers of
dropped images, renderers.memory.ImagePool).

Records: raycast_area/<camera>/<setting> (rms_px, max_px, n, wall_s, cpu_s,
pose0_wall_s, fractions), raycast_area/memory/<camera>/area.
'''

import json
import subprocess
import sys

import common
import numpy as np

SCRIPT = "bench_raycast_area"
BARS = {"rms_px": 0.001, "wall_1024_s": 0.010, "wall_5120x3840_s": 0.1,
        "peak_rss_5120x3840_MB": 400.0}


def settings_of(name):
    from renderers.base import RenderSettings
    name = name.removeprefix("tested:")
    if name == "area":
        return RenderSettings(spp=16, options={"coverage": "area"})
    if name.startswith("area@"):
        return RenderSettings(spp=16, options={"coverage": "area",
                                               "area_tolerance": float(name[5:])})
    if name.startswith("K="):
        return RenderSettings(spp=int(name[2:]), adaptive=True, options={"coverage": "point"})
    raise SystemExit(f"setting {name!r}: expected K=<n>, area or area@<tolerance>")


def measure(out, cam, setting_names, nposes, repeats):
    from reference_models.catalogue import load_catalogue
    from renderers.raycast import RaycastRenderer
    from targets.boards import load_target
    from targets.centroids import expected_centroids
    from targets.detect import detect
    from targets.poses import plan_poses

    model = load_catalogue().get(cam).model
    target = load_target("dots")
    pattern = target.pattern()
    poses = plan_poses(model, target, n=6, seed=0)[:nposes]
    truths = [expected_centroids(model, target, Rt) for Rt in poses]
    for name in setting_names:
        settings = settings_of(name)
        renderer = RaycastRenderer(outlines=not name.startswith("tested:"))
        renderer.render(model, pattern, poses[0], settings)     # compile
        walls, cpus, pose0, errs, md = [], [], [], [], None
        missing = 0
        for i, Rt in enumerate(poses):
            for _ in range(repeats):
                with common.Stopwatch() as sw:
                    res = renderer.render(model, pattern, Rt, settings)
                walls.append(sw.wall_s)
                cpus.append(sw.cpu_s)
                if i == 0:
                    pose0.append(sw.wall_s)
            md = res.metadata
            det = detect(res.image, target)
            ok = det.found & np.all(np.isfinite(truths[i]), axis=-1)
            missing += int(target.Npoints - ok.sum())
            errs.append(np.linalg.norm(det.q[ok] - truths[i][ok], axis=-1))
        e = np.concatenate(errs)
        rec = out.add(f"raycast_area/{cam}/{name}", camera=cam, family=model.family,
                      size=[model.width, model.height], setting=name,
                      options=settings.options, K=settings.spp, poses=len(poses),
                      rms_px=float(np.sqrt(np.mean(e ** 2))), max_px=float(e.max()),
                      n=int(e.size), not_found=missing, wall_s=common.summary(walls),
                      cpu_s=common.summary(cpus), pose0_wall_s=common.summary(pose0),
                      threads=md["threads"], adaptive_fraction=md["adaptive_fraction"],
                      area_fraction=md.get("area_fraction"),
                      area_point_sampled_fraction=md.get("area_point_sampled_fraction"),
                      edges=md["edges"], pixels_tested_last_image=md["pixels_tested"],
                      rays_last_image=md["samples"])
        print(f"  camera {cam:>2} {model.family:<7} {model.width}x{model.height} {name:<5} "
              f"({md['edges']}): "
              f"centroid RMS {rec['rms_px']:.5f} max {rec['max_px']:.5f} px ({rec['n']} dots)  "
              f"wall min {rec['wall_s']['min'] * 1e3:.1f} median "
              f"{rec['wall_s']['median'] * 1e3:.1f} ms (pose 0 min "
              f"{rec['pose0_wall_s']['min'] * 1e3:.1f}), CPU median "
              f"{rec['cpu_s']['median'] * 1e3:.1f} ms", flush=True)


def memory_child(cam, repeats):
    r'''In a fresh process: area-mode renders of one camera; JSON on stdout'''
    from reference_models.catalogue import load_catalogue
    from renderers.raycast import RaycastRenderer
    from targets.boards import load_target
    from targets.poses import plan_poses

    target = load_target("dots")
    # compile (or load the compiled kernels) on a small camera first
    small = load_catalogue().get("17").model
    RaycastRenderer().render(small, target.pattern(), plan_poses(small, target, n=1)[0],
                             settings_of("area"))
    rss0 = common.peak_rss_bytes()
    model = load_catalogue().get(cam).model
    # Linux: reset the peak (VmHWM) so that it measures this camera's renders alone
    reset = _reset_peak_rss()
    poses = plan_poses(model, target, n=6, seed=0)
    renderer = RaycastRenderer()
    with common.Stopwatch() as cold:
        renderer.render(model, target.pattern(), poses[0], settings_of("area"))
    walls, cpus = [], []
    for _ in range(repeats):
        for Rt in poses:
            with common.Stopwatch() as sw:
                renderer.render(model, target.pattern(), Rt, settings_of("area"))
            walls.append(sw.wall_s)
            cpus.append(sw.cpu_s)
    md = renderer.render(model, target.pattern(), poses[0], settings_of("area")).metadata
    print(json.dumps({"camera": cam, "size": [model.width, model.height],
                      "edges": md["edges"],
                      "cold_s": cold.wall_s, "cold_cpu_s": cold.cpu_s,
                      "wall_s": common.summary(walls), "cpu_s": common.summary(cpus),
                      "peak_rss_MB": (_vm("VmHWM") if reset else common.peak_rss_bytes()) / 1e6,
                      "peak_rss_since": "the camera" if reset else "process start",
                      "peak_rss_before_MB": rss0 / 1e6, "rss_before_MB": reset / 1e6}))


def _vm(field):
    r'''A field of /proc/self/status in bytes (0 where there is none)'''
    return common.proc_status("self", field)


def _reset_peak_rss():
    r'''Reset the process's peak resident memory (/proc/self/clear_refs "5"); the resident
memory now, or 0 where the reset is not possible'''
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return 0
    return _vm("VmRSS")


def memory(out, cam, repeats=1):
    r'''Render one camera in area mode in a fresh process (memory_child) -> the record added
(raycast_area/memory/<camera>/area): first and next seconds, peak resident memory'''
    r = subprocess.run([sys.executable, __file__, "--memory-child", cam,
                        "--repeats", str(repeats)], capture_output=True, text=True,
                       cwd=common.ROOT)
    name = f"raycast_area/memory/{cam}/area"
    if r.returncode != 0:
        return out.add(name, status="failed",
                       reason=" ".join(r.stderr.strip().splitlines()[-1:]) or "no output")
    rec = out.add(name, json.loads(r.stdout.strip().splitlines()[-1]),
                  bar_peak_rss_MB=BARS["peak_rss_5120x3840_MB"])
    print(f"  camera {rec['camera']} area, edges {rec['edges']}, fresh process: "
          f"first {rec['cold_s']:.2f} s ({rec['cold_cpu_s']:.2f} CPU s), next "
          f"median {rec['wall_s']['median']:.3f} s ({rec['cpu_s']['median']:.3f} CPU s), "
          f"peak RSS {rec['peak_rss_MB']:.0f} MB "
          f"since {rec['peak_rss_since']} (resident before the camera: "
          f"{rec['rss_before_MB']:.0f} MB)", flush=True)
    return rec


def run(args, out):
    if args.memory_child:
        memory_child(args.memory_child, args.repeats)
        sys.exit(0)
    print(f"dots, {args.poses} poses x {args.repeats} repeats:")
    for cam in args.cameras:
        measure(out, cam, args.settings, args.poses, args.repeats)
    if args.memory_camera:
        memory(out, args.memory_camera, 1)
    return 0


def make_parser():
    ap = common.parser(__doc__, repeats=3, warmup=1)
    ap.add_argument("--cameras", type=common.ids, default=["15", "17", "1"])
    ap.add_argument("--poses", type=int, default=6)
    ap.add_argument("--settings", nargs="+", default=["K=4", "K=16", "area"])
    ap.add_argument("--memory-camera", default="1")
    ap.add_argument("--memory-child", help=common.argparse.SUPPRESS)
    ap.set_defaults(run=run)
    return ap


if __name__ == "__main__":
    sys.exit(common.main(SCRIPT, make_parser()))

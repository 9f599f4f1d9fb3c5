r'''Terrain ray-casting speed: 1024x1024 with exact shadow rays (bar: <= 0.5 s)

SYNOPSIS

    uv run python benchmarks/bench_terrain.py [--repeats 9] [--out benchmarks/results/terrain.json]

Renders the generated terrain (targets.terrain.make_terrain, 21 x 24 m, 5 cm
cells, 1 cm texels, rocks) through the MER B front-left hazcam (catalogue slot
12, CAHVORE, 1024x1024, 0.30 m above the ground) and through the Mars 2020
navcam (slot 21) scaled by 0.2 to 1024x768 (harness.stereo.scale_model), on a
mast 1.9 m high pitched 20 deg down, with shadows on and off, K = 1; and the
hazcam again with the sun 10 deg high (long shadows, a larger sun bound).

The figure against the bar is the wall time of a whole warm render_terrain call
(pixel rays cached per (model, K), the terrain's pyramids made): primary rays,
Lambertian shading, one shadow ray per lit hit, the image assembled. Reports
the minimum and the median over the repeats, the numba thread count and the
load average before and after each case, since the machine is shared; and the
CPU time per thread (process CPU seconds / numba threads), close to what the
wall time would be with the cores free.

The cold cost is measured in a fresh process (numba's on-disk cache already
filled by this one): import, the first render (its pixel rays, the terrain's
pyramid and sun bound, loading the compiled kernels) and the second render.
'''

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BAR_SECONDS = 0.5
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


def cold_start():
    args = [sys.executable, "-c", COLD, str(ROOT), json.dumps(TERRAIN), json.dumps(SUN)]
    out = subprocess.run(args, capture_output=True, text=True, cwd=ROOT)
    if out.returncode != 0:
        return {"status": "failed", "reason": out.stderr.strip().splitlines()[-1:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "terrain.json"))
    args = ap.parse_args()

    import numba

    from harness.stereo import scale_model
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
    cases = [("hazcam slot 12 (MER B front left, CAHVORE 1024x1024)", hazcam, ground_pose(0.30),
              terrain),
             ("navcam slot 21 scaled 0.2 (CAHVORE 1024x768), mast pitched 20 deg",
              navcam, ground_pose(1.9, pitch_deg=20.0), terrain),
             ("hazcam slot 12, sun 10 deg high (long shadows)", hazcam, ground_pose(0.30),
              low_sun)]
    records = []
    for name, model, pose, terrain in cases:
        t0 = time.perf_counter()
        pixel_rays(model, 1)
        t_rays = time.perf_counter() - t0
        first = render_terrain(model, terrain, pose, spp=1)   # compile / warm
        for shadows in (True, False):
            load_before = os.getloadavg()
            ts, cpu = [], []
            for _ in range(args.repeats):
                c0, w0 = time.process_time(), time.perf_counter()
                r = render_terrain(model, terrain, pose, spp=1, shadows=shadows)
                ts.append(time.perf_counter() - w0)
                cpu.append(time.process_time() - c0)
            # CPU seconds / threads: the wall time the render would take with the
            # cores to itself (the machine is shared; the wall time includes waiting)
            cpu_per_thread = min(cpu) / numba.get_num_threads()
            rec = {"camera": name, "width": model.width, "height": model.height,
                   "shadows": shadows, "spp": 1, "repeats": args.repeats,
                   "seconds_min": min(ts), "seconds_median": float(np.median(ts)),
                   "seconds_all": ts, "cpu_seconds_min": min(cpu),
                   "cpu_seconds_per_thread_min": cpu_per_thread,
                   "load_average_before": load_before, "load_average_after": os.getloadavg(),
                   "seconds_pixel_rays_once": t_rays,
                   "seconds_prepare_once": first.metadata["seconds_prepare"]
                   if shadows else None,
                   "terrain_hit_fraction": float(np.mean(np.isfinite(r.range))),
                   "shadowed_fraction": float(np.mean((r.shadow == 1) | (r.shadow == 2))),
                   "meets_bar_wall_min": bool(min(ts) <= BAR_SECONDS) if shadows else None,
                   "meets_bar_wall_median": bool(np.median(ts) <= BAR_SECONDS)
                   if shadows else None,
                   "meets_bar_cpu_per_thread": bool(cpu_per_thread <= BAR_SECONDS)
                   if shadows else None}
            records.append(rec)
            print(f"{name:68s} shadows={shadows!s:5s} wall min {min(ts):.3f} s  "
                  f"median {np.median(ts):.3f} s  cpu {min(cpu):.3f} s "
                  f"({cpu_per_thread:.3f} s/thread)  load {load_before[0]:.1f} -> "
                  f"{os.getloadavg()[0]:.1f}")
        print(f"{'':68s} pixel rays once {t_rays:.2f} s, terrain pyramid + sun bound "
              f"{first.metadata['seconds_prepare']:.3f} s (first render)")
    cold = cold_start()
    print("cold, fresh process:", json.dumps(cold))
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True).stdout.strip()
    except OSError:
        commit = None
    doc = {"schema": 2, "benchmark": "terrain", "utc": datetime.now(UTC).isoformat(),
           "commit": commit, "machine": platform.machine(), "cpus": os.cpu_count(),
           "numba": numba.__version__, "numba_threads": numba.get_num_threads(),
           "threading_layer": numba.threading_layer(),
           "load_average": os.getloadavg(), "bar_seconds": BAR_SECONDS,
           "terrain": cases[0][3].as_dict(), "terrain_generation_seconds": t_gen,
           "records": records, "cold_start": cold}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1, allow_nan=False))
    print(f"load average {os.getloadavg()}; wrote {args.out}")


if __name__ == "__main__":
    main()

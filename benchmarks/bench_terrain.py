r'''Terrain ray-casting speed: 1024x1024 with exact shadow rays (bar: <= 0.5 s)

SYNOPSIS

    uv run python benchmarks/bench_terrain.py [--repeats 7] [--out benchmarks/results/terrain.json]

Renders the generated terrain (targets.terrain.make_terrain, 21 x 24 m, 5 cm
cells, 1 cm texels, rocks) through the MER B front-left hazcam (catalogue slot
12, CAHVORE, 1024x1024, 0.53 m above the ground) and through the Mars 2020
navcam (slot 21) scaled by 0.2 to 1024x768 (harness.stereo.scale_model), on a
mast 1.9 m high pitched 20 deg down, with shadows on and off, K = 1.
The pixel rays are computed once per camera and cached (their cost is
reported apart); the figure against the bar is the trace time: primary rays,
Lambertian shading and one shadow ray per lit hit. Reports the minimum and
median over the repeats, the numba thread count and the load average, since
the machine is shared; and the CPU time per thread (process CPU seconds /
numba threads), which is what the wall time would be with the cores free.
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "terrain.json"))
    args = ap.parse_args()

    import numba

    from harness.stereo import scale_model
    from reference_models.catalogue import load_catalogue
    from renderers.raycast_terrain import pixel_rays, render_terrain
    from targets.terrain import Sun, ground_pose, make_terrain

    cat = load_catalogue()
    t0 = time.perf_counter()
    terrain = make_terrain(extent=(-1, 20, -12, 12), cell=0.05, texel=0.01, seed=1,
                           sun=Sun(azimuth_deg=120, elevation_deg=30))
    t_gen = time.perf_counter() - t0
    hazcam = cat.get(12).model
    navcam = scale_model(cat.get(21).model, 0.2)
    cases = [("hazcam slot 12 (MER B front left, CAHVORE 1024x1024)", hazcam, ground_pose(0.30)),
             ("navcam slot 21 scaled 0.2 (CAHVORE 1024x768), mast pitched 20 deg",
              navcam, ground_pose(1.9, pitch_deg=20.0))]
    records = []
    for name, model, pose in cases:
        t0 = time.perf_counter()
        pixel_rays(model, 1)
        t_rays = time.perf_counter() - t0
        render_terrain(model, terrain, pose, spp=1)   # compile / warm
        for shadows in (True, False):
            ts, cpu = [], []
            for _ in range(args.repeats):
                c0 = time.process_time()
                r = render_terrain(model, terrain, pose, spp=1, shadows=shadows)
                cpu.append(time.process_time() - c0)
                ts.append(r.metadata["seconds_trace"])
            # CPU seconds / threads: the wall time the render would take with the
            # cores to itself (the machine is shared; the wall time includes waiting)
            cpu_per_thread = min(cpu) / numba.get_num_threads()
            rec = {"camera": name, "width": model.width, "height": model.height,
                   "shadows": shadows, "spp": 1, "seconds_min": min(ts),
                   "seconds_median": float(np.median(ts)), "seconds_all": ts,
                   "cpu_seconds_per_thread_min": cpu_per_thread,
                   "seconds_pixel_rays_once": t_rays,
                   "terrain_hit_fraction": float(np.mean(np.isfinite(r.range))),
                   "shadowed_fraction": float(np.mean((r.shadow == 1) | (r.shadow == 2))),
                   "meets_bar_wall": bool(min(ts) <= BAR_SECONDS) if shadows else None,
                   "meets_bar_cpu_per_thread": bool(cpu_per_thread <= BAR_SECONDS)
                   if shadows else None}
            records.append(rec)
            print(f"{name:70s} shadows={shadows!s:5s} wall min {min(ts):.3f} s  "
                  f"median {np.median(ts):.3f} s  cpu/thread {cpu_per_thread:.3f} s  "
                  f"(rays once {t_rays:.2f} s)")
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True).stdout.strip()
    except OSError:
        commit = None
    doc = {"schema": 1, "benchmark": "terrain", "utc": datetime.now(UTC).isoformat(),
           "commit": commit, "machine": platform.machine(), "cpus": os.cpu_count(),
           "numba": numba.__version__, "numba_threads": numba.get_num_threads(),
           "load_average": os.getloadavg(), "bar_seconds": BAR_SECONDS,
           "terrain": terrain.as_dict(), "terrain_generation_seconds": t_gen,
           "records": records}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1, allow_nan=False))
    print(f"load average {os.getloadavg()}; wrote {args.out}")


if __name__ == "__main__":
    main()

r'''Terrain shadows three ways: how often exact shadow rays, POV-Ray and the shadow map disagree

SYNOPSIS

    uv run python benchmarks/bench_shadows.py [--size 16] [--cell 0.05]
        [--elevations 8,15,30,50] [--map-sizes 1024,2048,4096,8192]
        [--out benchmarks/results/shadows.json]

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

SUN_STEPS_DEG = (0.1, 0.25, 0.5, 1.0)


def _marginal(terrain, exact, diff):
    r'''Of the differing triangles, the fraction whose exact state flips when the sun
moves by each step (elevation or azimuth, either way)'''
    from renderers.terrain_shadows import raycast_cell_shadows
    from targets.terrain import Sun

    s = exact != 0
    az, el = terrain.sun.azimuth_deg, terrain.sun.elevation_deg
    out = {}
    nd = int(diff.sum())
    for d in SUN_STEPS_DEG:
        flip = np.zeros_like(s)
        for a, e in ((az, el - d), (az, el + d), (az - d, el), (az + d, el)):
            if not 0 < e <= 90:
                continue
            flip |= (raycast_cell_shadows(terrain.replace(sun=Sun(a, e))) != 0) != s
        out[f"{d:g}"] = float((diff & flip).sum() / nd) if nd else 1.0
    return out


def _camera_renders(terrain):
    from harness.stereo import scale_model
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
    out = {}
    records = []
    for name, fn in (("raycast", raycast_terrain.render_terrain),
                     ("povray", lambda *a, **k: povray_terrain.render_terrain(
                         *a, shadow_codes=True, **k)),
                     ("osmesa", osmesa_terrain.render_terrain)):
        t0 = time.perf_counter()
        r = fn(model, terrain, pose, spp=2)
        seconds = time.perf_counter() - t0
        out[name] = r
        rec = {"renderer": name, "seconds": seconds, "width": model.width,
               "height": model.height, "spp": 2}
        if name != "raycast":
            e = out["raycast"]
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
        records.append(rec)
    return records


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=float, default=16.0, help="terrain side (m)")
    ap.add_argument("--cell", type=float, default=0.05, help="grid cell (m)")
    ap.add_argument("--elevations", default="8,15,30,50")
    ap.add_argument("--map-sizes", default="1024,2048,4096,8192")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--no-camera", action="store_true", help="skip the camera renders")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "shadows.json"))
    args = ap.parse_args()

    from renderers import osmesa_terrain, povray_terrain
    from renderers.terrain_shadows import compare, raycast_cell_shadows
    from targets.terrain import Sun, make_terrain

    elevations = [float(v) for v in args.elevations.split(",")]
    map_sizes = [int(v) for v in args.map_sizes.split(",")]
    base = make_terrain(extent=(0, args.size, 0, args.size), cell=args.cell, texel=0.05,
                        seed=args.seed, relief_m=0.3, relief_wavelength_m=3.0,
                        rocks_per_m2=1.5, rock_radius_m=(0.05, 0.4))
    ny, nx = base.heights.shape
    print(f"terrain {args.size} x {args.size} m, cell {args.cell} m: {(ny - 1) * (nx - 1)} cells, "
          f"{2 * (ny - 1) * (nx - 1)} triangles")
    raycast_cell_shadows(base)          # compile
    records = []
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
            rec = {"elevation_deg": el, "azimuth_deg": 120.0, "a": na, "b": nb,
                   "seconds_b": tb, **opts, **{k: c[k] for k in keys},
                   "n_triangles": c["n_triangles"], "disagree_triangles": c["disagree_triangles"],
                   "marginal_sun_fraction": marginal}
            records.append(rec)
            m = "" if marginal is None else \
                "  marginal@" + "/".join(f"{v:.2f}" for v in marginal.values())
            print(f"  {na:8s} vs {nb:26s} differ {c['disagree_fraction']:7.3%} of triangles, "
                  f"{c['disagree_cells_fraction']:7.3%} of cells, sunlight "
                  f"{c['sunlight_weighted_disagreement']:6.3%}; at edge "
                  f"{c['near_edge_fraction']:.2f} grazing {c['grazing_fraction']:.2f} either "
                  f"{c['edge_or_grazing_fraction']:.3f} "
                  f"max {c['max_edge_distance_cells']} cells{m}  ({tb:.2f} s)")
    camera_records = [] if args.no_camera else _camera_renders(base.replace(
        sun=Sun(120.0, elevations[0])))
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True).stdout.strip()
    except OSError:
        commit = None
    doc = {"schema": 1, "benchmark": "shadows", "utc": datetime.now(UTC).isoformat(),
           "commit": commit, "machine": platform.machine(), "cpus": os.cpu_count(),
           "load_average": os.getloadavg(), "povray": povray_terrain.povray_version(),
           "opengl": osmesa_terrain.gl_version(), "terrain": base.as_dict(),
           "sun_steps_deg": list(SUN_STEPS_DEG), "records": records,
           "camera_renders": camera_records}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1, allow_nan=False))
    print(f"\nload average {os.getloadavg()}; wrote {args.out}")


if __name__ == "__main__":
    main()

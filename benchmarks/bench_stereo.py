r'''Stereo range check: the 1% bars at 5 m, what each matching step buys, and its cost

SYNOPSIS

    uv run python benchmarks/bench_stereo.py [--ablation] [--out benchmarks/results/stereo.json]

Runs harness.stereo.run_stereo_check on clean images (K = 2) for the two pairs
of the bar: the MER B front hazcams (slots 12, 11) at full resolution
(1024x1024) and the Mars 2020 navcams (slots 21, 22) at quarter scale
(1280x960). For each it reports, in the band of true ranges 4.5-5.5 m, the
median |range error| (the bar: < 1%), the signed median, the 95th percentile
and the valid fraction, for the refined disparities and for StereoSGBM's
alone; and the time of each step (wall and process CPU; the machine is
shared, so CPU seconds / threads is what the wall time would be with the
cores free).

--ablation adds, for the hazcams, the settings the pipeline had before:
rectified grid at 1 px per raw px (oversample 1.0), no prefilter, no
refinement, so the gain of each change is measured rather than asserted.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BAR = 0.01


def _band(stats):
    b = stats["band"]
    return {"n": b.get("n", 0), "valid_fraction": b["valid_fraction"],
            "median_rel_error": b.get("median_rel_error"),
            "median_abs_rel_error": b.get("median_abs_rel_error"),
            "p95_abs_rel_error": b.get("p95_abs_rel_error"),
            "all_valid_fraction": stats["valid_fraction"],
            "all_median_abs_rel_error": stats["all"].get("median_abs_rel_error")}


def run_case(name, left, right, scale, **kw):
    import numba

    from harness.stereo import StereoSetup, run_stereo_check
    setup = StereoSetup.from_catalogue(left, right, scale=scale)
    c0, t0 = time.process_time(), time.perf_counter()
    r = run_stereo_check(setup, variants={"clean": {}}, spp=2, **kw)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    v = r.variants["clean"]
    rec = {"case": name, "pair": [str(left), str(right)], "scale": scale, "options": kw,
           "rectified_size": r.meta["rectified_size"], "pixels_per_deg": r.meta["pixels_per_deg"],
           "matcher": r.meta["matcher"], "refined": _band(v.stats), "sgbm": _band(v.stats_sgbm),
           "refinement_status": v.stats.get("refinement"),
           "seconds": {**r.meta["seconds"], **v.seconds, "total_wall": wall,
                       "total_cpu": cpu, "numba_threads": numba.get_num_threads()}}
    b, s = rec["refined"], rec["sgbm"]
    ok = b["median_abs_rel_error"] is not None and b["median_abs_rel_error"] < BAR
    rec["meets_bar"] = bool(ok)
    print(f"{name:52s} 4.5-5.5 m: median |err| {100 * b['median_abs_rel_error']:.3f}% "
          f"(signed {100 * b['median_rel_error']:+.3f}%, p95 {100 * b['p95_abs_rel_error']:.2f}%, "
          f"valid {100 * b['valid_fraction']:.1f}%) | SGBM alone "
          f"{100 * s['median_abs_rel_error']:.3f}% (signed {100 * s['median_rel_error']:+.3f}%)"
          f" | refine {v.seconds['refine']:.1f} s wall, total {wall:.0f} s wall / {cpu:.0f} s "
          f"CPU {'ok' if ok else 'MISSED'}", flush=True)
    return rec


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ablation", action="store_true",
                    help="also run the hazcams with the earlier settings, one change at a time")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "stereo.json"))
    args = ap.parse_args()

    import cv2
    import mrcal
    import numba

    records = [run_case("hazcams 12/11, 1024x1024 (default settings)", 12, 11, 1.0),
               run_case("navcams 21/22, scale 0.25 (default settings)", 21, 22, 0.25)]
    if args.ablation:
        records += [
            run_case("hazcams: oversample 1.0 (refined, prefilter 0.8)", 12, 11, 1.0,
                     oversample=1.0),
            run_case("hazcams: no prefilter (oversample 1.5, refined)", 12, 11, 1.0,
                     prefilter_px=0.0),
            run_case("hazcams: refinement radius 3", 12, 11, 1.0, refine_radius=3),
            run_case("hazcams: oversample 1.0, SGBM only (the old pipeline)", 12, 11, 1.0,
                     oversample=1.0, refine=False)]
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True).stdout.strip()
    except OSError:
        commit = None
    doc = {"schema": 1, "benchmark": "stereo", "utc": datetime.now(UTC).isoformat(),
           "commit": commit, "machine": platform.machine(), "cpus": os.cpu_count(),
           "numba": numba.__version__, "numba_threads": numba.get_num_threads(),
           "opencv": cv2.__version__, "mrcal": getattr(mrcal, "__version__", "?"),
           "load_average": os.getloadavg(), "bar_median_abs_rel_error": BAR,
           "records": records}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1, allow_nan=False))
    print(f"load average {os.getloadavg()}; wrote {args.out}")


if __name__ == "__main__":
    main()

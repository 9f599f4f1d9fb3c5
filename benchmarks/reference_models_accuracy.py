r'''Accuracy and speed of the exact camera models over all 33 catalogue models

SYNOPSIS

    uv run python benchmarks/reference_models_accuracy.py [--step 8]

For every catalogue model: project(unproject(q)) - q over every STEP-th pixel
of the whole image (ray points at 0.5, 2 and 50 m), and mrcal.project of the
theta = 90 version against it; the time per point of project and unproject.
Prints a table and writes benchmarks/results/reference_models_accuracy.json.
'''

import argparse
import json
import platform
import time
from datetime import UTC, datetime
from pathlib import Path

import mrcal
import numpy as np

from reference_models.catalogue import load_catalogue
from reference_models.mrcal_convert import to_mrcal

RANGES = (0.5, 2.0, 50.0)


def grid(m, step):
    xs = np.unique(np.r_[np.arange(0, m.width, step), m.width - 1, -0.5, m.width - 0.5])
    ys = np.unique(np.r_[np.arange(0, m.height, step), m.height - 1, -0.5, m.height - 0.5])
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


def measure(e, step):
    m = e.model
    q = grid(m, step)
    t0 = time.perf_counter()
    o, v = m.unproject(q)
    t_unproject = (time.perf_counter() - t0) / len(q)
    rt = 0.0
    for k in RANGES:
        p = o + k * v
        t0 = time.perf_counter()
        q2 = m.project(p)
        t_project = (time.perf_counter() - t0) / len(q)
        rt = max(rt, float(np.max(np.abs(q2 - q))))
    m90 = m.with_theta_90()
    cm = to_mrcal(m90)
    o9, v9 = m90.unproject(q)
    mr = 0.0
    for k in RANGES:
        p = o9 + k * v9
        qm = mrcal.project(mrcal.transform_point_Rt(cm.Rt_cam_ref(), p), *cm.intrinsics())
        mr = max(mr, float(np.max(np.abs(qm - q))))
    return dict(key=e.key, family=m.family, width=m.width, height=m.height, npoints=len(q),
                theta_deg=m.photogrammetric().theta_deg, round_trip_max_px=rt,
                mrcal_theta90_max_px=mr, unproject_us_per_point=t_unproject * 1e6,
                project_us_per_point=t_project * 1e6)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--step", type=int, default=8, help="pixel step of the grid (default 8)")
    args = ap.parse_args()
    rows = [measure(e, args.step) for e in load_catalogue()]
    print(f"{'camera':<18} {'model':<8} {'points':>8} {'theta':>9} {'round trip':>11} "
          f"{'vs mrcal':>10} {'unproj us':>9} {'proj us':>8}")
    for r in rows:
        print(f"{r['key']:<18} {r['family']:<8} {r['npoints']:>8} {r['theta_deg']:>9.4f} "
              f"{r['round_trip_max_px']:>11.2e} {r['mrcal_theta90_max_px']:>10.2e} "
              f"{r['unproject_us_per_point']:>9.3f} {r['project_us_per_point']:>8.3f}")
    worst_rt = max(r["round_trip_max_px"] for r in rows)
    worst_mr = max(r["mrcal_theta90_max_px"] for r in rows)
    print(f"worst round trip {worst_rt:.2e} px; worst mrcal difference {worst_mr:.2e} px")
    out = Path(__file__).parent / "results" / "reference_models_accuracy.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(dict(
        schema=1, utc=datetime.now(UTC).isoformat(), machine=platform.node(),
        numpy=np.__version__, mrcal=getattr(mrcal, "__version__", "unknown"), step=args.step,
        worst_round_trip_px=worst_rt, worst_mrcal_px=worst_mr, models=rows),
        indent=1, allow_nan=False))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

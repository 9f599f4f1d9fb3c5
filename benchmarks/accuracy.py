r'''Accuracy and speed of the exact camera models over all 33 catalogue models

SYNOPSIS

    uv run python benchmarks/accuracy.py [--step 8] [--cameras 15,17]

For every catalogue model (or those of --cameras): project(unproject(q)) - q
over every STEP-th pixel of the whole image (ray points at 0.5, 2 and 50 m),
and mrcal.project of the theta = 90 version against it; the time per point of
project and unproject. Prints a table and writes one JSON document,
benchmarks/results/<UTC stamp>-accuracy.json: one record per model
(accuracy/<catalogue key>) and accuracy/all (the worst of each figure).
'''

import sys
import time

import common
import numpy as np

SCRIPT = "accuracy"
RANGES = (0.5, 2.0, 50.0)


def grid(m, step):
    xs = np.unique(np.r_[np.arange(0, m.width, step), m.width - 1, -0.5, m.width - 0.5])
    ys = np.unique(np.r_[np.arange(0, m.height, step), m.height - 1, -0.5, m.height - 0.5])
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


def measure(e, step):
    import mrcal

    from reference_models.mrcal_convert import to_mrcal

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


def run(args, out):
    from reference_models.catalogue import load_catalogue

    entries = [e for e in load_catalogue() if not args.cameras or e.key in args.cameras]
    if not entries:
        raise SystemExit(f"no catalogue model matches {args.cameras}")
    rows = [measure(e, args.step) for e in entries]
    print(f"{'camera':<18} {'model':<8} {'points':>8} {'theta':>9} {'round trip':>11} "
          f"{'vs mrcal':>10} {'unproj us':>9} {'proj us':>8}")
    for r in rows:
        out.add(f"accuracy/{r['key']}", r, step=args.step)
        print(f"{r['key']:<18} {r['family']:<8} {r['npoints']:>8} {r['theta_deg']:>9.4f} "
              f"{r['round_trip_max_px']:>11.2e} {r['mrcal_theta90_max_px']:>10.2e} "
              f"{r['unproject_us_per_point']:>9.3f} {r['project_us_per_point']:>8.3f}")
    worst_rt = max(r["round_trip_max_px"] for r in rows)
    worst_mr = max(r["mrcal_theta90_max_px"] for r in rows)
    out.add("accuracy/all", models=len(rows), step=args.step, round_trip_max_px=worst_rt,
            mrcal_theta90_max_px=worst_mr)
    print(f"worst round trip {worst_rt:.2e} px; worst mrcal difference {worst_mr:.2e} px")


def make_parser():
    ap = common.parser(__doc__)
    ap.add_argument("--step", type=int, default=8, help="pixel step of the grid (default 8)")
    ap.add_argument("--cameras", type=common.ids, default=None,
                    help="catalogue keys (default: every model)")
    ap.set_defaults(run=run)
    return ap


if __name__ == "__main__":
    sys.exit(common.main(SCRIPT, make_parser()))

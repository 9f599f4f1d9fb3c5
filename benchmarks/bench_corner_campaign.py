r'''Issue 16's accuracy bar over the catalogue: corner targets recalibrated by jpl, per slot

SYNOPSIS

    uv run --frozen python benchmarks/bench_corner_campaign.py [--cameras 1-22]
        [--models CAHV,CAHVOR,CAHVORE] [--targets apriltag,chessboard] [-j 2]
        [--keep DIR | --run DIR] [--bar 0.005] [--out-dir benchmarks/results]

Runs campaigns/corners.toml (the exact ray caster, K = 16 adaptive, area coverage;
jpl with its iterated corner-bias correction) on every catalogue slot (default: all
22) in every model family a slot can give, for the AprilTag grid and the chessboard,
and tabulates each record: corners found of expected, the corners dropped and why,
jpl's residual RMS (px) and the projection difference RMS against the truth (px,
rotation fitted: harness.compare). A cell above --bar (issue 16: 0.005 px for both)
is marked "<-"; a slot where the board cannot be planned is listed with its reason
(status not-applicable or failed). --run DIR tabulates an existing run directory
(a `camval verify` of any corner campaign) instead of running one; --keep DIR keeps
the run (default: a temporary directory). Identical cameras (the MER hazcam twins)
share their images and fit (the campaign's share_identical_cameras): their rows are
the same numbers.

Writes one JSON document, <out-dir>/<UTC stamp>-bench_corner_campaign.json
(benchmarks/common.Results): a record per campaign record (fullname as the
campaign's) with the figures above, and corners/summary: the cells, how many are
above the bar and the worst of each figure. Not a test (the campaign takes ~25 min
with -j 2 on a loaded 2-core machine; the load average is recorded).
'''

import sys
import tempfile
from pathlib import Path

import common

SCRIPT = "bench_corner_campaign"
# issue 16: residual RMS and projection difference RMS, px
BAR_PX = 0.005


def slots(text):
    r'''"1-22" or "5,8,15" -> ["1", ..., "22"] / ["5", "8", "15"]'''
    out = []
    for part in common.ids(text):
        if "-" in part:
            lo, hi = (int(x) for x in part.split("-"))
            out.extend(str(i) for i in range(lo, hi + 1))
        else:
            out.append(part)
    return out


def run(args):
    r'''Run the corner campaign on the chosen slots -> the run directory'''
    import tomllib

    from common import parse_campaign, run_campaign

    doc = tomllib.loads((common.CAMPAIGNS / "corners.toml").read_text())
    doc.update(name="corners-catalogue", keep_maps=False, targets=args.targets,
               models=args.models,
               cameras=[int(c) if c.isdigit() else c for c in args.cameras])
    campaign = parse_campaign(doc, source="corners.toml (bench_corner_campaign)",
                              base_dir=common.CAMPAIGNS)
    run_dir = args.keep or Path(tempfile.mkdtemp(prefix="camval-corners-")) / "run"
    run_campaign(campaign, run_dir, workers=args.jobs, progress=True)
    return run_dir


def records_of(run_dir):
    r'''The run's jpl records, in slot, family and target order'''
    import json
    recs = []
    for f in sorted(Path(run_dir, "records").glob("*.json")):
        recs.extend(r for r in json.loads(f.read_text())["records"]
                    if r.get("calibrator") == "jpl")

    def key(r):
        cam = str(r["camera"])
        fam = r.get("model") or r.get("family") or ""
        return (int(cam) if cam.isdigit() else 1000, cam,
                common.FAMILIES.index(fam) if fam in common.FAMILIES else 9, r["target"])
    return sorted(recs, key=key)


def cell(r, bar):
    r'''The figures of one record (None where the record has none)'''
    det = r.get("detections") or {}
    dropped = {}
    for p in det.get("corners_dropped") or []:
        for k, v in p.items():
            dropped[k] = dropped.get(k, 0) + v
    res = (r.get("residuals") or {}).get("rms")
    proj = (r.get("projection") or {}).get("rms")
    out = {"camera": str(r["camera"]), "family": r.get("model"), "target": r["target"],
           "status": r["status"], "reason": r.get("reason") or "",
           "found": det.get("n_found"), "expected": det.get("n_expected"),
           "corners_dropped": dropped,
           "residual_rms_px": res, "projection_rms_px": proj,
           "projection_max_px": (r.get("projection") or {}).get("max")}
    if r["status"] == "ok":
        out["above_bar"] = bool(res > bar or proj > bar)
    return out


def main():
    ap = common.parser(__doc__, repeats=1, warmup=0)
    ap.add_argument("--cameras", type=slots, default="1-22")
    ap.add_argument("--models", type=common.families, default="CAHV,CAHVOR,CAHVORE")
    ap.add_argument("--targets", type=common.ids, default="apriltag,chessboard")
    ap.add_argument("-j", "--jobs", type=int, default=2, help="local worker processes")
    ap.add_argument("--keep", type=Path, default=None, help="run directory to keep (new)")
    ap.add_argument("--run", type=Path, default=None,
                    help="tabulate this existing run directory instead of running")
    ap.add_argument("--bar", type=float, default=BAR_PX, help="px (issue 16: 0.005)")
    args = ap.parse_args()
    out = common.Results(SCRIPT, args)
    with common.Stopwatch() as sw:
        run_dir = args.run or run(args)
    cells = []
    print(f"\njpl on the exact ray caster (K=16, area coverage): residual and projection "
          f"difference RMS, px; '<-' above {args.bar} px")
    print(f"{'slot':>5s} {'family':8s} {'target':10s} {'found':>9s} {'residual':>9s} "
          f"{'proj diff':>9s}  status")
    for r in records_of(run_dir):
        c = cell(r, args.bar)
        cells.append(c)
        out.add(r["fullname"], c)
        if c["status"] != "ok":
            print(f"{c['camera']:>5s} {c['family'] or '':8s} {c['target']:10s} "
                  f"{'':>9s} {'':>9s} {'':>9s}  {c['status']}: {c['reason'][:90]}")
            continue
        print(f"{c['camera']:>5s} {c['family']:8s} {c['target']:10s} "
              f"{c['found']:4d}/{c['expected']:<4d} {c['residual_rms_px']:9.5f} "
              f"{c['projection_rms_px']:9.5f}  ok" + ("  <-" if c["above_bar"] else "")
              + (f"  dropped {c['corners_dropped']}" if c["corners_dropped"] else ""))
    ok = [c for c in cells if c["status"] == "ok"]
    above = [c for c in ok if c["above_bar"]]
    summary = {"bar_px": args.bar, "cells": len(cells), "ok": len(ok),
               "not_ok": {c["status"]: sum(x["status"] == c["status"] for x in cells)
                          for c in cells if c["status"] != "ok"},
               "above_bar": [f"{c['camera']}/{c['family']}/{c['target']}" for c in above],
               "residual_rms_max_px": max((c["residual_rms_px"] for c in ok), default=None),
               "projection_rms_max_px": max((c["projection_rms_px"] for c in ok),
                                            default=None),
               "run_dir": str(run_dir), "wall_s": sw.wall_s}
    out.add("corners/summary", summary)
    print(f"\n{len(ok)} of {len(cells)} records ok, {len(above)} above {args.bar} px; worst "
          f"residual RMS {summary['residual_rms_max_px']}, projection difference RMS "
          f"{summary['projection_rms_max_px']} px ({sw.wall_s:.0f} s)")
    out.write()
    return 1 if above else 0


if __name__ == "__main__":
    sys.exit(main())

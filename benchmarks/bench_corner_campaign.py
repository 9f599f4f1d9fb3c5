r'''Issue 16's accuracy bar over the catalogue: corner targets recalibrated by jpl, per slot

SYNOPSIS

    uv run --frozen python benchmarks/bench_corner_campaign.py [--cameras 1-22]
        [--models CAHV,CAHVOR,CAHVORE] [--targets apriltag,chessboard] [-j 2]
        [--pose-seed 0] [--poses 6] [--keep DIR | --run DIR] [--bar 0.005]
        [--out-dir benchmarks/results]

Runs campaigns/corners.toml (the exact ray caster, K = 16 adaptive, area coverage;
jpl with its iterated corner-bias correction) on every catalogue slot (default: all
22) in every model family a slot can give, for the AprilTag grid and the chessboard,
and tabulates each record: corners found of expected, the corners dropped and why, the
views (poses) the board was not detected in and why,
jpl's residual RMS (px) and the projection difference RMS against the truth (px,
rotation fitted: harness.compare). A cell above --bar (issue 16: 0.005 px for both)
is marked "<-"; a slot where the board cannot be planned is listed with its reason
(status not-applicable or failed). --run DIR tabulates an existing run directory
(a `camval verify` of any corner campaign) instead of running one; --keep DIR keeps
the run (default: a temporary directory). --pose-seed and --poses set the campaign's
[poses] seed and n (default its own: seed 0, 6 poses; poses past six reach the image's
corners and edges, targets.poses cover "corners"): other board placements than the
catalogue's on the same cameras. Identical cameras (the MER hazcam twins)
share their images and fit (the campaign's share_identical_cameras): their rows are
the same numbers.

--response PROFILE --seeds 0-3 instead runs campaigns/response-corners.toml (dots beside the
corner targets, jpl, that profile only; the campaign's noise seed and its poses' seed set to
each seed in turn, one run directory per seed under --keep) and tabulates issue 16's second
bar: target / dots ratio of jpl's residual RMS and projection difference RMS per camera and
family, pooled over the seeds (the RMS over the seeds of each, then the ratio), with each
seed's ratios and the corners kept, and the ratio of the verdict's predicted projection sigma
(verdict.renderer.sigma.projection_rms: the noise carried through each fit's geometry, no
single noise draw in it; a seed's projection ratio is one draw, 0.1-9 on one pair). --run
DIR tabulates such a DIR (its seed-* run directories) again; --response blur is the
realistic profile's blur alone (no noise: the targets' model errors). --dots-from DIR takes
the dots' records from DIR's seed-* runs (a run of the same cameras and seeds: the dots do
not change with a corner detector) and runs the corner targets only.

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
    r'''"1-22" or "5,8,15" -> ["1", ..., "22"] / ["5", "8", "15"]; a model file's path as it is'''
    out = []
    for part in common.ids(text):
        if "-" in part and all(x.isdigit() for x in part.split("-")):
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
    if args.pose_seed is not None:
        doc["poses"]["seed"] = args.pose_seed
    if args.poses is not None:
        doc["poses"]["n"] = args.poses
    campaign = parse_campaign(doc, source="corners.toml (bench_corner_campaign)",
                              base_dir=common.CAMPAIGNS)
    run_dir = args.keep or Path(tempfile.mkdtemp(prefix="camval-corners-")) / "run"
    run_campaign(campaign, run_dir, workers=args.jobs, progress=True)
    return run_dir


def run_seeds(args):
    r'''The response campaign once per seed -> the directory holding seed-<n>/ run dirs'''
    import tomllib

    from common import parse_campaign, run_campaign

    top = args.keep or Path(tempfile.mkdtemp(prefix="camval-corner-ratio-"))
    for seed in args.seeds:
        doc = tomllib.loads((common.CAMPAIGNS / "response-corners.toml").read_text())
        doc.update(name=f"corner-ratio-seed{seed}", keep_maps=False, seed=int(seed),
                   targets=sorted(set(args.targets) | ({"dots"} if not args.dots_from else set())),
                   models=args.models,
                   cameras=[int(c) if c.isdigit() else c for c in args.cameras])
        doc["poses"]["seed"] = int(seed)
        doc["calibrator"] = [c for c in doc["calibrator"] if c["name"] == "jpl"]
        # "blur": the realistic profile's blur alone (no noise): what the corner models leave
        doc["response"].setdefault("blur", {"psf": doc["response"]["realistic"]["psf"]})
        for r in doc["renderer"]:
            r["response"] = [args.response]
        campaign = parse_campaign(doc, source="response-corners.toml (bench_corner_campaign)",
                                  base_dir=common.CAMPAIGNS)
        run_campaign(campaign, top / f"seed-{seed}", workers=args.jobs, progress=True)
    return top


def ratio_table(top, profile, out, dots_from=None):
    r'''Print and record the target / dots ratios of the runs under top (its seed-* dirs;
the dots' from dots_from's where given)'''
    import math
    rows = {}
    seeds = sorted(Path(top).glob("seed-*"), key=lambda p: int(p.name.split("-")[1]))
    for d in seeds:
        recs = records_of(d)
        if dots_from:
            recs = [r for r in recs if r["target"] != "dots"] + [
                r for r in records_of(Path(dots_from) / d.name) if r["target"] == "dots"]
        for r in recs:
            if (r.get("settings") or {}).get("response") != profile or r["status"] != "ok":
                continue
            c = cell(r, BAR_PX)
            rows.setdefault((str(r["camera"]), r.get("model"), r["target"]), {})[d.name] = (
                c["residual_rms_px"], c["projection_rms_px"], c["found"], c["expected"],
                c["projection_sigma_px"])

    def pooled(per, i):
        v = [x[i] for x in per.values() if x[i] is not None]
        return math.sqrt(sum(x * x for x in v) / len(v)) if v else math.nan

    print(f"\n{profile}: target / dots jpl ratio, residual RMS / projection difference RMS / "
          f"predicted projection sigma, pooled over {len(seeds)} seeds (RMS over the seeds, then "
          f"the ratio); per seed (residual / projection); kept")
    for (cam, fam, tgt), per in sorted(rows.items()):
        dots = rows.get((cam, fam, "dots"))
        if tgt == "dots" or not dots:
            continue
        both = [s for s in per if s in dots]
        per, dp = {s: per[s] for s in both}, {s: dots[s] for s in both}
        rr, pr = pooled(per, 0) / pooled(dp, 0), pooled(per, 1) / pooled(dp, 1)
        sr = pooled(per, 4) / pooled(dp, 4)
        each = [(per[s][0] / dp[s][0], per[s][1] / dp[s][1]) for s in both]
        kept = [per[s][2] for s in both]
        print(f"{cam:>5s} {fam:8s} {tgt:10s} {rr:5.2f} / {pr:5.2f} / {sr:5.2f}   "
              + ", ".join(f"{a:.2f} / {b:.2f}" for a, b in each)
              + f"   kept {min(kept)}-{max(kept)} of {per[both[0]][3]}"
              + f"   px {pooled(per, 0):.5f} / {pooled(per, 1):.5f}"
              + f" (dots {pooled(dp, 0):.5f} / {pooled(dp, 1):.5f})")
        out.add(f"ratio/{profile}/{cam}/{fam}/{tgt}", {
            "residual_ratio": rr, "projection_ratio": pr,
            "projection_sigma_ratio": None if math.isnan(sr) else sr, "seeds": both,
            "per_seed": each, "kept": kept,
            "residual_rms_px": pooled(per, 0), "projection_rms_px": pooled(per, 1),
            "dots_residual_rms_px": pooled(dp, 0), "dots_projection_rms_px": pooled(dp, 1)})


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
           # the views the board was not detected in (or kept too few corners), and why
           "views_failed": {str(k): v for k, v in (det.get("failed_reasons") or {}).items()},
           "views": len(det.get("per_pose") or []),
           "residual_rms_px": res, "projection_rms_px": proj,
           "projection_max_px": (r.get("projection") or {}).get("max"),
           # the verdict's predicted projection error: the noise through the fit's geometry
           "projection_sigma_px": ((((r.get("verdict") or {}).get("renderer") or {})
                                    .get("sigma") or {}).get("projection_rms"))}
    if r["status"] == "ok":
        out["above_bar"] = bool(res > bar or proj > bar)
    return out


def main():
    ap = common.parser(__doc__, repeats=1, warmup=0)
    ap.add_argument("--cameras", type=slots, default="1-22")
    ap.add_argument("--models", type=common.families, default="CAHV,CAHVOR,CAHVORE")
    ap.add_argument("--targets", type=common.ids, default="apriltag,chessboard")
    ap.add_argument("--pose-seed", type=int, default=None,
                    help="the campaign's [poses] seed (default corners.toml's, 0)")
    ap.add_argument("--poses", type=int, default=None,
                    help="poses per camera (default corners.toml's, 6)")
    ap.add_argument("-j", "--jobs", type=int, default=2, help="local worker processes")
    ap.add_argument("--keep", type=Path, default=None, help="run directory to keep (new)")
    ap.add_argument("--run", type=Path, default=None,
                    help="tabulate this existing run directory instead of running")
    ap.add_argument("--bar", type=float, default=BAR_PX, help="px (issue 16: 0.005)")
    ap.add_argument("--response", default=None,
                    help="profile of campaigns/response-corners.toml: the ratio mode")
    ap.add_argument("--seeds", type=slots, default="0-3", help="the ratio mode's seeds")
    ap.add_argument("--dots-from", type=Path, default=None,
                    help="the ratio mode's dots records from this earlier run's seed-* dirs")
    args = ap.parse_args()
    out = common.Results(SCRIPT, args)
    if args.response:
        with common.Stopwatch() as sw:
            top = args.run or run_seeds(args)
        ratio_table(top, args.response, out, args.dots_from)
        print(f"({sw.wall_s:.0f} s; run directories under {top})")
        out.write()
        return 0
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
              + (f"  dropped {c['corners_dropped']}" if c["corners_dropped"] else "")
              + (f"  views failed {len(c['views_failed'])} of {c['views']}: "
                 + "; ".join(f"{k}: {v[:200]}" for k, v in c["views_failed"].items())
                 if c["views_failed"] else ""))
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

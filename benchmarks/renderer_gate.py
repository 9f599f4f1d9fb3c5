r'''The renderer gate (campaigns/gate-renderer.toml) on faulty and clean renderers

    uv run --frozen python benchmarks/renderer_gate.py OUT_DIR [--cameras 15,17]
        [--faults shift_001,focal_scale,...] [--clean CAMERA,...|all] [--seeds 0,1,...|0-9]
        [--clean-families CAHV,CAHVOR,CAHVORE] [-j 2]

Each fault of renderers.legacy.FAULTS is injected into the exact ray caster
(renderer "faulty", harness.mutation) on each camera, and jpl, mrcal and
OpenCV (OPENCV5) calibrate the images; the renderer gate must flag every
fault (it judges verdict.renderer against each record's sigma). The clean
ray caster runs on the --clean cameras (e.g. the narrow extras; "all": every
catalogue slot and extra) under each of --clean-families (a family richer than
the camera is a not-applicable record), one campaign per pose seed of --seeds,
and must pass. Prints one line per run (the failing
fields, per calibrator), the exact fit's and verdict's CPU seconds per record, and the
minimum detectable faults; exits 1 if a fault is missed or a clean run fails.

Measured (2026-11-25, 2 shared cores, K=16, 6 poses):
- clean, --clean all --seeds 0-9 -j 2 (33 cameras x CAHV/CAHVOR/CAHVORE, 297 records a
  seed): PASS on all 10 seeds (`camval gate` of each run too), 2310 ok records; RMS z
  of every judged quantity 0.93-1.08, largest 4.34 of 7288; 128-1788 s a seed (load 4-27).
  Cost per ok record: exact fit 0.38 s + verdict 0.27 s against the image fit's 0.86 s.
- clean, all 22 slots + 11 extras, CAHV + CAHVOR, jpl/mrcal/OPENCV5: pose seed 3, 198
  records, PASS (SuperCam not-applicable); also seeds 0-2 on 15, 17, MCAM_Z_LEFT-Z026/
  Z100, MCAM_Z_RIGHT-Z110, seeds 0-1 on 1, 8, 13, 21, seed 0 on the other 23 cameras:
  PASS once re-judged under the rules of f318e33 (they ran before it).
- faults on cameras 13, 15, 17, 21: focal_scale, half_pixel, r1_sign, round_centre,
  rounded_aspect flagged on all four; shift_001 on 15, 17, 21 (pancam 13: minimum
  detectable Hc shift 0.03-0.09 px); theta90 on 13, 15, 21 (camera 17's theta is 90).
- cost per ok record (seed 3 run): exact fit 0.44 s + verdict 0.17 s against the image
  fit's 0.35 s; the quick campaign took 67% longer than without them.
'''

import argparse
import sys
import time
from pathlib import Path


def campaign(cameras, family, renderer, seed, name):
    return {"name": name, "cameras": cameras, "models": [family], "targets": ["dots"],
            "poses": {"n": 6, "seed": seed}, "renderer": [renderer],
            "calibrator": [{"name": "jpl"}, {"name": "mrcal"},
                           {"name": "opencv", "models": ["OPENCV5"]}]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--cameras", default="15,17")
    ap.add_argument("--faults", default="shift_001,focal_scale,half_pixel,r1_sign,theta90")
    ap.add_argument("--clean", default="", help="cameras, or 'all': every slot and extra")
    ap.add_argument("--family", default="CAHVOR")
    ap.add_argument("--clean-families", default="CAHV,CAHVOR,CAHVORE",
                    help="a family richer than a camera is a not-applicable record")
    ap.add_argument("--seeds", default="0", help="0,1,... or a range 0-9")
    ap.add_argument("-j", "--jobs", type=int, default=1, help="workers of the clean runs")
    ap.add_argument("--spp", type=int, default=16)
    args = ap.parse_args(argv)

    from harness.campaign import parse_campaign
    from harness.gate import DEFAULT_SPEC, check, explain, load_gate_spec
    from harness.runner import run_campaign

    spec = load_gate_spec(DEFAULT_SPEC)
    out = Path(args.out)
    ok = True
    cost = {"exact_fit": 0.0, "verdict": 0.0, "calibrate": 0.0, "records": 0}

    def run(doc, tag, workers=1):
        t0 = time.perf_counter()
        r = run_campaign(parse_campaign(doc), out / tag, progress=False, workers=workers)
        for rec in r["records"].values():
            s = rec.get("seconds") or {}
            if rec["status"] == "ok":
                cost["records"] += 1
                for k in ("exact_fit", "verdict", "calibrate"):
                    cost[k] += float(s.get(k, 0.0) or 0.0)
        return r, check(r, spec), time.perf_counter() - t0

    cams = [c if not c.isdigit() else int(c) for c in args.cameras.split(",") if c]
    for fault in [f for f in args.faults.split(",") if f]:
        family = "CAHV" if fault == "theta90" else args.family
        for cam in cams:
            renderer = {"name": "faulty", "spp": args.spp, "options": {"fault": fault}}
            r, failures, secs = run(campaign([cam], family, renderer, 0, f"fault-{fault}"),
                                    f"fault-{fault}-{cam}")
            by_cal = {}
            for f in failures:
                by_cal.setdefault(f.fullname.rsplit("/", 1)[-1], []).append(
                    f"{f.field.rsplit('.', 1)[-1]} {f.value}")
            flagged = bool(failures)
            ok &= flagged
            print(f"{fault:12s} {cam!s:18s} {family:7s} {'FLAGGED' if flagged else 'MISSED '} "
                  f"({secs:.0f} s)", flush=True)
            for cal, lines in sorted(by_cal.items()):
                print(f"    {cal:18s} {'; '.join(lines[:3])}", flush=True)
    if args.clean == "all":
        from reference_models.catalogue import load_catalogue
        clean = [e.id if e.kind == "slot" else e.key for e in load_catalogue()]
    else:
        clean = [c if not c.isdigit() else int(c) for c in args.clean.split(",") if c]
    seeds = [int(s) for s in args.seeds.split(",") if s and "-" not in s]
    for a, b in (s.split("-") for s in args.seeds.split(",") if "-" in s):
        seeds += range(int(a), int(b) + 1)
    fams = [f for f in args.clean_families.split(",") if f]
    for seed in seeds if clean else []:
        renderer = {"name": "raycast", "spp": args.spp, "adaptive": True}
        doc = campaign(clean, fams[0], renderer, seed, "clean") | {"models": fams}
        r, failures, secs = run(doc, f"clean-{seed}", workers=args.jobs)
        ok &= not failures
        n_ok = sum(x["status"] == "ok" for x in r["records"].values())
        print(f"clean seed {seed} {'/'.join(fams)}: {len(r['records'])} records ({n_ok} ok), "
              f"{'PASS' if not failures else 'FAIL'} ({secs:.0f} s)", flush=True)
        for f in failures:
            print(f"    {f.fullname}  {f.field}  {f.value}  {f.limit}", flush=True)
        if seed == seeds[0]:
            print("\n".join(explain(r, spec)), flush=True)
    n = max(cost["records"], 1)
    print(f"cost per ok record: exact fit {cost['exact_fit'] / n:.3f} s, verdict "
          f"{cost['verdict'] / n:.3f} s, image fit {cost['calibrate'] / n:.3f} s "
          f"({cost['records']} records)")
    print("renderer gate:", "PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

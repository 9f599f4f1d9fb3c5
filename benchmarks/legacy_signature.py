r'''The paper's Figures 4-5 signature: under legacy mode, recovered (Hc, Vc) sit on the half pixel

SYNOPSIS

    uv run python benchmarks/legacy_signature.py [--campaign campaigns/legacy.toml]
        [--cameras 15 13 8 17] [--spp 16] [-j 2] [--run-dir DIR]
        [--out benchmarks/results/legacy_signature.json]

Runs the legacy campaign (campaigns/legacy.toml: the ray caster carrying the
paper's ROAMS defects, renderers.legacy: (Hc, Vc) rounded to the half pixel,
Hs from a rounded aspect ratio, theta = 90 under CAHV, float32 vectors; and
the clean ray caster as the control; jpl calibrator, 6 poses of the dot
board), writes its report (with the Figs. 4-5 section) and prints, from the
report's own rows (reports.tables.legacy_signature_rows), the recovered Hc,
Vc errors against the true values (Figure 4: spread over +-0.25 px) and
against the true values rounded to the nearest half pixel (Figure 5: near
zero). --cameras and --spp override the campaign's.
'''

import argparse
import json
import os
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", default=str(ROOT / "campaigns" / "legacy.toml"))
    ap.add_argument("--cameras", nargs="+", default=None)
    ap.add_argument("--spp", type=int, default=None)
    ap.add_argument("-j", "--jobs", type=int, default=2)
    ap.add_argument("--run-dir", default=None, help="where the run goes (default: a temp dir)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                         "legacy_signature.json"))
    args = ap.parse_args()

    import tomllib

    from harness.campaign import parse_campaign
    from harness.records import load_run
    from harness.runner import run_campaign
    from reports.build import build_report

    with open(args.campaign, "rb") as f:
        doc = tomllib.load(f)
    if args.cameras:
        doc["cameras"] = [int(c) if c.isdigit() else c for c in args.cameras]
    if args.spp:
        for r in doc.get("renderer", []):
            r["spp"] = args.spp
    run_dir = args.run_dir or tempfile.mkdtemp(prefix="camval-legacy-")
    t0 = time.perf_counter()
    run_campaign(parse_campaign(doc, source=args.campaign), run_dir, progress=False,
                 workers=args.jobs)
    wall = time.perf_counter() - t0
    run = load_run(run_dir)
    paths = build_report(run_dir)
    rows = paths["legacy_rows"]
    for r in rows:
        print(f"{r['mode']:6s} camera {r['camera']:>3s} {r['model']:6s}  "
              f"Hc {r['Hc_error']:+.4f} Vc {r['Vc_error']:+.4f} px   "
              f"vs rounded: Hc {r['Hc_error_vs_rounded']:+.4f} "
              f"Vc {r['Vc_error_vs_rounded']:+.4f} px", flush=True)
    for r in run["records"].values():
        if r["status"] != "ok":
            print(f"{r['fullname']}: {r['status']}: {r.get('reason')}")
    legacy = [r for r in rows if r["mode"] == "legacy"]
    summary = {
        "legacy_max_abs_error_px": max(abs(r[k]) for r in legacy for k in ("Hc_error",
                                                                             "Vc_error")),
        "legacy_max_abs_error_vs_rounded_px": max(abs(r[k]) for r in legacy for k in (
            "Hc_error_vs_rounded", "Vc_error_vs_rounded")),
        "clean_max_abs_error_px": max(abs(r[k]) for r in rows if r["mode"] == "clean"
                                      for k in ("Hc_error", "Vc_error")),
    }
    print(json.dumps(summary, indent=1))
    print(f"campaign {wall:.1f} s wall with {args.jobs} workers; report {paths['html']}")
    out = dict(schema=2, benchmark="legacy_signature", utc=datetime.now(UTC).isoformat(),
               campaign=args.campaign, cameras=doc["cameras"], wall_seconds=wall,
               summary=summary, rows=rows)
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1, allow_nan=False)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

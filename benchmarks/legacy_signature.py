r'''The paper's Figures 4-5 signature: under legacy mode, recovered (Hc, Vc) sit on the half pixel

SYNOPSIS

    uv run python benchmarks/legacy_signature.py [--campaign campaigns/legacy.toml]
        [--cameras 15 13 8 17] [--spp 16] [-j 2] [--run-dir DIR]

Runs the legacy campaign (campaigns/legacy.toml: the ray caster carrying the
paper's ROAMS defects, renderers.legacy: (Hc, Vc) rounded to the half pixel,
Hs from a rounded aspect ratio, theta = 90 under CAHV, float32 vectors; and
the clean ray caster as the control; jpl calibrator, 6 poses of the dot
board), writes its report (with the Figs. 4-5 section) and prints, from the
report's own rows (reports.tables.legacy_signature_rows), the recovered Hc,
Vc errors against the true values (Figure 4: spread over +-0.25 px) and
against the true values rounded to the nearest half pixel (Figure 5: near
zero). --cameras and --spp override the campaign's. Writes one JSON document,
benchmarks/results/<UTC stamp>-legacy_signature.json: one record per row of
the figure (legacy_signature/<mode>/<camera>/<model>) and
legacy_signature/summary.
'''

import json
import sys
import tempfile

import common

SCRIPT = "legacy_signature"


def run(args, out):
    import tomllib

    from common import parse_campaign, run_campaign

    from harness.records import load_run
    from reports.build import build_report

    with open(args.campaign, "rb") as f:
        doc = tomllib.load(f)
    if args.cameras:
        doc["cameras"] = [int(c) if c.isdigit() else c for c in args.cameras]
    if args.spp:
        for r in doc.get("renderer", []):
            r["spp"] = args.spp
    run_dir = args.run_dir or tempfile.mkdtemp(prefix="camval-legacy-")
    with common.Stopwatch() as sw:
        run_campaign(parse_campaign(doc, source=args.campaign), run_dir, progress=False,
                     workers=args.jobs)
    run = load_run(run_dir)
    paths = build_report(run_dir)
    rows = paths["legacy_rows"]
    for r in rows:
        out.add(f"legacy_signature/{r['mode']}/{r['camera']}/{r['model']}", r)
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
    out.add("legacy_signature/summary", summary, campaign=args.campaign,
            cameras=doc["cameras"], wall_s=sw.wall_s, workers=args.jobs, run_dir=str(run_dir))
    print(json.dumps(summary, indent=1))
    print(f"campaign {sw.wall_s:.1f} s wall with {args.jobs} workers; report {paths['html']}")


def make_parser():
    ap = common.parser(__doc__, repeats=1, warmup=0)
    ap.add_argument("--campaign", default=str(common.CAMPAIGNS / "legacy.toml"))
    ap.add_argument("--cameras", type=common.ids, default=None)
    ap.add_argument("--spp", type=int, default=None)
    ap.add_argument("-j", "--jobs", type=int, default=2)
    ap.add_argument("--run-dir", default=None, help="where the run goes (default: a temp dir)")
    ap.set_defaults(run=run)
    return ap


if __name__ == "__main__":
    sys.exit(common.main(SCRIPT, make_parser()))

r'''Stability sweeps: vary one difficulty at a time and mark where each method breaks

camval sweep [--camera 15] [--model CAHVOR] [--target dots] [--difficulty noise,blur]
             [--levels 0,100,1000] [--calibrators jpl:CAHVOR,mrcal:CAHVOR,opencv:OPENCV5]
             [-o DIR]

For each difficulty (noise, blur, motion, spp, poses; see harness/sweep.py)
renders the target through the camera, applies the level (camera-response
stages for noise / blur / motion; re-rendering for spp / poses), detects,
calibrates with every calibrator and compares with the truth. Writes
DIR/sweep_<difficulty>.json (one record per level and calibrator, and each
method's breakdown level: detection below 100%, a failed calibration, or a
projection difference above --bar px RMS) and DIR/sweep_<difficulty>.png
(the stability chart, breakdowns marked).
'''


def add_arguments(p):
    p.add_argument("--camera", default="15", help="catalogue slot, extra or model file")
    p.add_argument("--model", default="CAHVOR", help="truth model family (default CAHVOR)")
    p.add_argument("--target", default="dots", help="target (default dots)")
    p.add_argument("--difficulty", default="noise",
                   help="comma-separated difficulties: noise, blur, motion, spp, poses")
    p.add_argument("--levels", default=None,
                   help="comma-separated levels (one difficulty only; default: its own)")
    p.add_argument("--calibrators", default="jpl:CAHVOR,mrcal:CAHVOR,opencv:OPENCV5",
                   help="comma-separated name:model pairs")
    p.add_argument("--renderer", default="raycast")
    p.add_argument("--spp", type=int, default=8, help="supersampling K (default 8)")
    p.add_argument("--poses", type=int, default=6, help="board poses (default 6)")
    p.add_argument("--bar", type=float, default=None,
                   help="projection difference (px RMS) above which a method is broken "
                        "(default 0.05)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--out", default=".", help="output directory")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")


def run(args):
    import json
    from pathlib import Path

    from harness.sweep import DEFAULT_BAR_PX, SweepError, run_sweep, stability_chart

    diffs = [d.strip() for d in args.difficulty.split(",") if d.strip()]
    levels = None
    if args.levels:
        if len(diffs) != 1:
            raise SweepError("--levels needs exactly one --difficulty")
        try:
            levels = [float(v) if "." in v or "e" in v else int(v)
                      for v in args.levels.split(",")]
        except ValueError:
            raise SweepError(f"--levels must be numbers separated by commas; got "
                             f"{args.levels!r}") from None
    cals = []
    for item in args.calibrators.split(","):
        name, _, model = item.strip().partition(":")
        if not name or not model:
            raise SweepError(f"calibrator {item!r} must be name:model (e.g. mrcal:CAHVOR)")
        cals.append((name, model))
    out = Path(args.out)
    for d in diffs:
        for suffix in ("json", "png"):
            p = out / f"sweep_{d}.{suffix}"
            if p.exists() and not args.force:
                raise SweepError(f"'{p}' exists; pass --force to overwrite it")
    out.mkdir(parents=True, exist_ok=True)
    for d in diffs:
        sw = run_sweep(args.camera, family=args.model, target=args.target, difficulty=d,
                       levels=levels, calibrators=tuple(cals), renderer=args.renderer,
                       spp=args.spp, n_poses=args.poses, seed=args.seed,
                       bar_px=args.bar if args.bar is not None else DEFAULT_BAR_PX,
                       progress=lambda s: print(f"  {s}", flush=True))
        (out / f"sweep_{d}.json").write_text(json.dumps(sw, indent=1, allow_nan=False,
                                                        default=float))
        stability_chart(sw, out / f"sweep_{d}.png")
        for key, b in sw["breakdown"].items():
            where = ("never broke" if b["level"] is None
                     else f"breaks at {b['level']} ({b['reason']})")
            print(f"{d:7s} {key:18s} {where}")
        print(f"wrote {out / f'sweep_{d}.json'} and {out / f'sweep_{d}.png'}")
    return 0


if __name__ == "__main__":
    # `camval sweep` once harness/cli.py lists this module; until then:
    # uv run python -m harness.commands.sweep --difficulty noise -o out/
    import argparse
    import sys

    from reference_models.errors import CamvalError
    ap = argparse.ArgumentParser(prog="camval sweep", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(ap)
    try:
        sys.exit(run(ap.parse_args()))
    except CamvalError as e:
        print(f"camval sweep: error: {e}", file=sys.stderr)
        sys.exit(2)

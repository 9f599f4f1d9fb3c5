r'''Stability sweeps: vary one difficulty at a time and mark where each method breaks

camval sweep [--camera 15] [--model CAHVOR] [--target dots] [--difficulty noise,tilt]
             [--levels 0,100,1000] [--calibrators jpl:CAHVOR,mrcal:CAHVOR,opencv:OPENCV5]
             [--spp 8] [--poses 6] [--bar 0.05] [-o DIR] [--force]

Difficulties (harness/studies/sweep.py; "all" runs every one):

  noise   read noise, e- (shot noise, 20000 e- well, 12 bit)   rendered once
  blur    Gaussian PSF sigma, px                               rendered once
  motion  motion-blur length, px                               rendered once
  spp     supersampling K                                      re-rendered
  poses   number of board poses                                re-planned
  tilt    board tilt, deg off fronto-parallel (every pose)     re-planned
  range   board range, x the range at which it fills the image re-planned
  dots    dot diameter, px (median; the board's dots scaled)   re-rendered
  fov     one camera per level (slot, extra or model file), ordered by
          horizontal field of view; --camera is not used

For each level: render the target through the camera, detect, calibrate with
every calibrator and compare with the truth. Writes DIR/sweep_<difficulty>.json
(one record per level and calibrator, and each method's breakdown level:
detection below 100%, a failed calibration, or a projection difference above
--bar px RMS), DIR/sweep_<difficulty>.png (the stability chart, breakdowns
marked), and the sweep report of every sweep in DIR: DIR/sweep_report.html
(self-contained), DIR/sweep_report.md and DIR/sweep_figures/. Sweeps written
into a run directory (or its sweeps/ folder) also appear in that run's
`camval report`.
'''


def add_arguments(p):
    p.add_argument("--camera", default="15", help="catalogue slot, extra or model file")
    p.add_argument("--model", default="CAHVOR", help="truth model family (default CAHVOR)")
    p.add_argument("--target", default="dots", help="target (default dots)")
    p.add_argument("--difficulty", default="noise",
                   help="comma-separated difficulties: noise, blur, motion, spp, poses, tilt, "
                        "range, dots, fov, or all")
    p.add_argument("--levels", default=None,
                   help="comma-separated levels (one difficulty only; default: its own; for "
                        "fov: cameras)")
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


def parse_levels(text, difficulty):
    r'''"0,100,1e3" -> [0, 100, 1000.0]; camera names stay strings for fov'''
    from harness.studies.sweep import SweepError
    items = [v.strip() for v in text.split(",") if v.strip()]
    if not items:
        raise SweepError("--levels is empty")
    if difficulty == "fov":
        return items
    try:
        return [float(v) if any(c in v for c in ".eE") else int(v) for v in items]
    except ValueError:
        raise SweepError(f"--levels must be numbers separated by commas; got {text!r}") from None


def run(args):
    import json
    from pathlib import Path

    from harness.studies.sweep import DEFAULT_BAR_PX, DIFFICULTIES, SweepError, run_sweep
    from reports.build import build_sweep_report
    from reports.figures import stability_chart

    diffs = [d.strip() for d in args.difficulty.split(",") if d.strip()]
    if diffs == ["all"]:
        diffs = list(DIFFICULTIES)
    for d in diffs:
        if d not in DIFFICULTIES:
            raise SweepError(f"unknown difficulty {d!r}; known: {', '.join(DIFFICULTIES)}, all")
    levels = None
    if args.levels:
        if len(diffs) != 1:
            raise SweepError("--levels needs exactly one --difficulty")
        levels = parse_levels(args.levels, diffs[0])
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
        print(f"wrote {out / f'sweep_{d}.json'} and {out / f'sweep_{d}.png'}", flush=True)
    paths = build_sweep_report(out)
    print(f"camval sweep: {paths['html']}")
    print(f"camval sweep: {paths['markdown']}")
    return 0

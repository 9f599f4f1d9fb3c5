r'''Which lens model does a camera need: the floor of every candidate model

  camval models CAMERA [CAMERA ...] [--tolerance PX] [--criterion max|rms]
                       [--range M ...] [--only NAME ...] [--json FILE] [--plot PNG]
  camval models all ...                  every camera of the catalogue

CAMERA is a slot id (1-22), an extra's name or a model file. Every candidate
model (CAHV, CAHVOR, CAHVORE; mrcal's LENSMODEL_PINHOLE/CAHVOR/CAHVORE/
OPENCV4/5/8/12 and SPLINED_STEREOGRAPHIC; OpenCV's 4/5/8/12/14-coefficient
and fisheye models, which are also COLMAP's OPENCV, FULL_OPENCV and
OPENCV_FISHEYE) is fitted to the camera's exact projections over the whole
field of view; the table gives each one's floor (projection difference RMS
and max over the image, the worst corner) and parameter count, then the
simplest model within the tolerance (default 0.01 px, on the max), overall
and per calibrator. A calibrator's choice (what `models = ["best"]` picks in a
campaign) is made on its OWN fits of the models it has: jpl, mrcal and OpenCV
each fit exact observations of 14 poses covering the whole image under their
own frame, constraints and solver, compared with the truth as the verdict
compares a record's exact-observation fit; the table lists those floors below
the direct ones. See harness/model_benchmark.py for how each is fitted.
'''


def add_arguments(parser):
    parser.add_argument("camera", metavar="CAMERA", nargs="+",
                        help="slot id, extra name or model file; 'all': the whole catalogue")
    parser.add_argument("--tolerance", type=float, default=None, metavar="PX",
                        help="floor a model must reach (default 0.01 px)")
    parser.add_argument("--criterion", choices=("max", "rms"), default="max",
                        help="which floor the tolerance applies to (default max)")
    parser.add_argument("--range", type=float, action="append", dest="ranges", metavar="M",
                        help="range of the points along the rays, m (repeatable; default 2, "
                             "the projection-difference range)")
    parser.add_argument("--only", action="append", metavar="NAME",
                        help="benchmark only this candidate (repeatable)")
    parser.add_argument("--json", metavar="FILE", help="also write the benchmarks as JSON")
    parser.add_argument("--plot", metavar="PNG",
                        help="also plot floor vs parameter count per camera")
    parser.add_argument("--overlay", action="append", metavar="F",
                        help="catalogue overlay TOML (repeatable)")


def run(args):
    import json
    import os

    from harness.model_benchmark import (
        DEFAULT_TOLERANCE,
        benchmark,
        candidate_names,
        format_table,
    )
    from reference_models.catalogue import load_catalogue
    from reference_models.errors import CamvalError

    if args.only:
        unknown = [n for n in args.only if n not in candidate_names()]
        if unknown:
            raise CamvalError(f"unknown candidate model(s) {', '.join(unknown)}; known: "
                              f"{', '.join(candidate_names())}")
    for out in (args.json, args.plot):
        if out and os.path.exists(out):
            raise CamvalError(f"{out} exists; not overwriting it")
    tol = DEFAULT_TOLERANCE if args.tolerance is None else args.tolerance
    if not tol > 0:
        raise CamvalError(f"--tolerance must be positive; got {tol!r}")
    cat = load_catalogue(overlay=args.overlay or None)
    specs = cat.keys() if args.camera == ["all"] else args.camera
    entries = [(spec, cat.get(spec)) for spec in specs]
    benches = {}
    for spec, entry in entries:
        b = benchmark(entry.model, tolerance=tol, ranges_m=args.ranges,
                      candidates=args.only, criterion=args.criterion)
        benches[str(spec)] = b
        cam = b["camera"]
        kind = cam["family"] + ("" if cam["central"] else f" (noncentral, linearity "
                                                          f"{cam['linearity']:g})")
        print(f"camera {spec}: {kind} {cam['width']}x{cam['height']}; "
              f"{b['fit_points']} fit points, floors over {b['eval_points']} points every "
              f"{b['eval_step']} px at range {', '.join(f'{r:g}' for r in b['ranges_m'])} m")
        print(format_table(b))
        d = b["diagnostics"]
        if d["n"]:
            kinds = ", ".join(f"{k} {n}" for k, n in d["kinds"].items())
            print(f"(library messages during the fits, kept off the terminal: {kinds})")
        print(f"{b['seconds']:.1f} s\n", flush=True)
    if len(benches) > 1:
        print(summary_table(benches))
    if args.json:
        from harness.calibrators.base import jsonable
        with open(args.json, "x") as f:
            json.dump(jsonable(benches), f, indent=1, allow_nan=False)
    if args.plot:
        import tempfile
        from pathlib import Path

        from reports.figures import fig_model_floors
        with tempfile.TemporaryDirectory() as tmp:
            fig = fig_model_floors(benches, tmp)
            if fig is not None:
                Path(args.plot).write_bytes(Path(fig.path).read_bytes())
    return 0


def summary_table(benches):
    r'''One line per camera: the recommended model and each calibrator's choice'''
    cals = ("jpl", "mrcal", "opencv", "colmap")
    lines = [f"{'camera':18s} {'recommended':34s} {'floor px':>9s}  " +
             " ".join(f"{c:>14s}" for c in cals)]
    for cam, b in benches.items():
        rec = b["recommended"]
        crit = b["criterion"]
        name, floor = (rec["name"], f"{rec[crit]:9.2g}") if rec else ("none", "        -")
        picks = []
        for c in cals:
            ch = b["per_calibrator"][c]
            m = ch["model"] or "-"
            picks.append(f"{m + ('' if ch.get('why', '').startswith('simplest') else '*'):>14s}")
        lines.append(f"{cam:18s} {name:34s} {floor}  " + " ".join(picks))
    lines.append("(* no model of that calibrator within tolerance: its lowest floor)")
    return "\n".join(lines)

r'''Write the report of a run: HTML, Markdown and PNG figures

SYNOPSIS

    camval report runs/20261122T150000Z
    camval report runs/20261122T150000Z --out somewhere/
    camval report sweeps/                  # a directory of camval sweep results only

Figures follow the paper: min/max/RMS residual per camera (Fig. 3), Hc/Vc
error (Figs. 4-5), Hs/Vs fractional error (Fig. 6), theta, C (Fig. 7), A
(Fig. 8), O (Fig. 9), R absolute and fractional (Figs. 10-11), projection-
difference maps, and time per image against projection-difference RMS for
every renderer setting (one line per renderer path, K labelled, Pareto front
marked). One summary table per calibrator sits beside the paper's numbers;
failures are listed with their reasons. The HTML page embeds its figures
(data URIs): it is one file.

When the run holds legacy-mode records (renderer option legacy = true, e.g.
campaigns/legacy.toml) the report adds the paper's Figs. 4-5 signature: the
recovered Hc/Vc error against the truth and against the truth rounded to the
half pixel, per camera, beside the clean renderer's. Sweep results of
`camval sweep` (sweep_*.json) in RUN_DIR or RUN_DIR/sweeps/ add one stability
chart per difficulty with each method's breakdown marked. A directory with
sweep results and no run document gets the sweep report alone
(sweep_report.html / .md).
'''


def add_arguments(parser):
    parser.add_argument("run", metavar="RUN_DIR", help="a run directory written by camval verify")
    parser.add_argument("--out", metavar="DIR",
                        help="where to write the report (default: RUN_DIR/report)")


def run(args):
    from pathlib import Path

    from reports.build import build_report, build_sweep_report, find_sweeps
    d = Path(args.run)
    if d.is_dir() and not (d / "run.json").exists() and find_sweeps(d):
        paths = build_sweep_report(d, out_dir=args.out)
    else:
        paths = build_report(args.run, out_dir=args.out)
    print(f"camval report: {paths['html']}")
    print(f"camval report: {paths['markdown']}")
    print(f"camval report: {len(paths['figures'])} figures in {paths['figures_dir']}")
    return 0

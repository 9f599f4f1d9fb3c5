r'''Write the report of a run: HTML, Markdown and PNG figures

SYNOPSIS

    camval report runs/20261122T150000Z
    camval report runs/20261122T150000Z --out somewhere/

Figures follow the paper: min/max/RMS residual per camera (Fig. 3), Hc/Vc
error (Figs. 4-5), Hs/Vs fractional error (Fig. 6), theta, C (Fig. 7), A
(Fig. 8), O (Fig. 9), R absolute and fractional (Figs. 10-11), projection-
difference maps, and time per image against projection-difference RMS for
every renderer setting (Pareto front marked). One summary table per
calibrator sits beside the paper's numbers; failures are listed with their
reasons. The HTML page embeds its figures (data URIs): it is one file.
'''


def add_arguments(parser):
    parser.add_argument("run", metavar="RUN_DIR", help="a run directory written by camval verify")
    parser.add_argument("--out", metavar="DIR",
                        help="where to write the report (default: RUN_DIR/report)")


def run(args):
    from reports.build import build_report
    paths = build_report(args.run, out_dir=args.out)
    print(f"camval report: {paths['html']}")
    print(f"camval report: {paths['markdown']}")
    print(f"camval report: {len(paths['figures'])} figures in {paths['figures_dir']}")
    return 0

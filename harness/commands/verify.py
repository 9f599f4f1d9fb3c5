r'''Run a verification campaign and write its report

SYNOPSIS

    camval verify                                  # campaigns/paper.toml, local processes
    camval verify campaigns/quick.toml -j 2
    camval verify --executor dask --scheduler tcp://10.0.0.5:8786
    camval verify --resume runs/20261122T150000Z   # finish an interrupted run

Renders every camera x model x target x renderer setting of the campaign,
detects the target, recalibrates with every calibrator and compares the
recovered models with the truth. Writes runs/<UTC time>/ (or --out DIR):
run.json (one record per camera/model/target/renderer/calibrator) and the
report (report.html, report.md, figures). Prints where. Failing jobs are
records with a status and a reason; the campaign goes on. The exit status
is 0 when the campaign ran (whatever its records say; `camval gate` judges
them) and 2 for a bad campaign file or bad options.
'''

DEFAULT_CAMPAIGN = "campaigns/paper.toml"


def add_arguments(parser):
    parser.add_argument("campaign", nargs="?", metavar="CAMPAIGN",
                        help=f"campaign TOML (default {DEFAULT_CAMPAIGN})")
    parser.add_argument("--executor", choices=("local", "dask"), default="local",
                        help="local processes (default) or a Dask distributed cluster")
    parser.add_argument("--scheduler", metavar="ADDR",
                        help="Dask scheduler address (with --executor dask)")
    parser.add_argument("-j", "--jobs", type=int, metavar="N",
                        help="local worker processes (default: the number of cores)")
    parser.add_argument("--out", metavar="DIR",
                        help="run directory to write (default runs/<UTC time>; must be new)")
    parser.add_argument("--resume", metavar="RUN_DIR",
                        help="resume an interrupted run: redo only the jobs it lacks")
    parser.add_argument("--no-report", action="store_true", help="skip the report")
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def _default_campaign():
    from pathlib import Path
    here = Path(DEFAULT_CAMPAIGN)
    if here.is_file():
        return here
    return Path(__file__).resolve().parents[2] / DEFAULT_CAMPAIGN


def run(args):
    import sys
    from pathlib import Path

    from harness.campaign import Campaign, load_campaign
    from harness.jobs import RunnerError
    from harness.records import utc_stamp
    from harness.runner import run_campaign

    if args.jobs is not None and args.jobs < 1:
        raise RunnerError(f"-j must be >= 1; got {args.jobs}")
    if args.executor == "dask" and not args.scheduler:
        raise RunnerError("--executor dask needs --scheduler ADDRESS (e.g. tcp://host:8786)")
    if args.scheduler and args.executor != "dask":
        raise RunnerError("--scheduler is for --executor dask")
    if args.resume:
        if args.campaign or args.out:
            raise RunnerError("--resume RUN_DIR continues that run's own campaign; "
                              "give no CAMPAIGN and no --out with it")
        from harness.records import RunStore
        run_dir = Path(args.resume)
        campaign = Campaign.from_dict(RunStore.open(run_dir).campaign())
    else:
        campaign = load_campaign(args.campaign or _default_campaign())
        run_dir = Path(args.out) if args.out else Path("runs") / utc_stamp()
    entries = campaign.validate()
    print(f"camval verify: campaign {campaign.name!r} -> {run_dir}", file=sys.stderr)
    try:
        doc = run_campaign(campaign, run_dir, executor=args.executor, workers=args.jobs,
                           scheduler=args.scheduler, resume=bool(args.resume),
                           progress=not args.quiet, entries=entries)
    except KeyboardInterrupt:
        print(f"camval verify: interrupted; the finished jobs are kept: resume with "
              f"camval verify --resume {run_dir}", file=sys.stderr)
        return 130
    counts = {}
    for r in doc["records"].values():
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    summary = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    ex = doc.get("execution", {})
    print(f"camval verify: {len(doc['records'])} records ({summary}) from {ex.get('jobs')} "
          f"jobs, {ex.get('jobs_run')} run now, in {ex.get('wall_seconds', 0):.1f} s")
    print(f"camval verify: run document {run_dir / 'run.json'}")
    if not args.no_report:
        from reports.build import build_report
        paths = build_report(run_dir)
        print(f"camval verify: report {paths['html']}")
        print(f"camval verify: report {paths['markdown']}")
    return 0

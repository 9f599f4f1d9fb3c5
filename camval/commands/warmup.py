r'''Compile numba's kernels of campaigns into numba's cache (an install step)

SYNOPSIS

    camval warm-up                                    # campaigns/paper.toml
    camval warm-up campaigns/paper.toml campaigns/quick.toml -j 2

Compiles (or finds in numba's on-disk cache) every numba kernel the campaigns'
jobs call, the ray caster's, the detectors' and the calibrators', in two
processes at once (harness.warmup.warm_up, which `camval verify` also runs
before its workers start). scripts/setup.sh runs it, as uv's --compile-bytecode
compiles the .pyc files: a fresh clone's first campaign then loads the kernels
(~0.1 s per process) instead of compiling them (~60 CPU s on this machine
kind). When the cache is current it only checks numba's cache index and ends.
The cache is numba's: __pycache__ beside the sources, or NUMBA_CACHE_DIR.
'''


def add_arguments(parser):
    parser.add_argument("campaigns", nargs="*", metavar="CAMPAIGN",
                        help="campaign TOML files (default campaigns/paper.toml)")
    parser.add_argument("-j", "--jobs", type=int, default=2, metavar="N",
                        help="processes that compile at once (default 2)")
    parser.add_argument("--force", action="store_true",
                        help="warm even when numba's cache is current")


def run(args):
    import sys
    import time

    from camval.commands.verify import _default_campaign
    from harness.campaign import load_campaign, resolve_best
    from harness.jobs import expand_jobs
    from harness.warmup import warm_up

    t0 = time.perf_counter()
    jobs = []
    for path in args.campaigns or [_default_campaign()]:
        campaign = load_campaign(path)
        entries = campaign.validate()
        resolve_best(campaign, entries, None)
        jobs += expand_jobs(campaign, entries=entries)
    info = warm_up(jobs, force=args.force, workers=args.jobs)
    what = ", ".join(info["renders"] + info["fits"]) or "nothing to compile"
    cached = f"; cached already: {', '.join(info['cached'])}" if info["cached"] else ""
    parts = "".join(f"; {name} {t['seconds']:.1f} s wall, {t['cpu']:.1f} CPU s"
                    for name, t in info["parts"].items() if t)
    print(f"camval warm-up: {what}{cached} ({time.perf_counter() - t0:.1f} s{parts})",
          file=sys.stderr)
    for f in info["failed"]:
        print(f"camval warm-up: not warmed: {f}", file=sys.stderr)
    return 0

r'''The time of a run's report (camval report): figures, tables, the HTML and Markdown pages

SYNOPSIS

    uv run --frozen camval verify campaigns/paper.toml -j 2 --out RUN --no-report
    uv run --frozen python benchmarks/bench_report.py RUN [--workers 1,2] [--repeats 3]

For each number of figure workers (reports.build.build_report(workers=)), builds the
report of RUN into a temporary directory `repeats` times (after `warmup` untimed
builds) and prints its wall and CPU seconds. CPU is this process's: with 1 worker it
is the whole report's; with 2 one figure process is a child of multiprocessing's
fork server and its CPU is not counted, so compare wall times there, on an idle
machine. The load average is printed beside every figure (and written in the JSON
document): under load the wall time says little.
'''

import os
import sys
import tempfile
from pathlib import Path

import common


def main(argv=None):
    ap = common.parser(__doc__, repeats=3, warmup=1)
    ap.add_argument("run", help="a run directory (with run.json)")
    ap.add_argument("--workers", type=common.ids, default="1,2",
                    help="figure worker counts to time, comma separated (default 1,2)")
    args = ap.parse_args(argv)
    from reports.build import build_report
    out = common.Results("bench_report", args)
    for workers in (int(w) for w in args.workers):
        with tempfile.TemporaryDirectory(prefix="camval-bench-report-") as tmp:
            def build(workers=workers, tmp=tmp):
                return build_report(args.run, out_dir=Path(tmp) / "report", workers=workers)
            load0 = os.getloadavg()[0]
            t = common.timed(build, repeats=args.repeats, warmup=args.warmup)
            load1 = os.getloadavg()[0]
        paths = t.pop("result")
        print(f"report of {args.run}, {workers} figure worker(s): wall "
              f"{t['wall_s']['median']:.2f} s (min {t['wall_s']['min']:.2f}), this process's "
              f"CPU {t['cpu_s']['median']:.2f} s (min {t['cpu_s']['min']:.2f}); "
              f"{len(paths['figures'])} figures; load {load0:.1f} -> {load1:.1f}")
        out.add(f"report/{Path(args.run).name}/workers={workers}", wall_s=t["wall_s"],
                cpu_s=t["cpu_s"], figures=len(paths["figures"]), load=[load0, load1])
    out.write()
    return 0


if __name__ == "__main__":
    sys.exit(main())

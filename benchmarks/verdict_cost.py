r'''The verdict's share of a campaign's time, from a run's per-record seconds

SYNOPSIS

    uv run --frozen camval verify campaigns/paper.toml -j 2 --out RUN --no-report
    uv run --frozen python benchmarks/verdict_cost.py RUN [RUN2 ...]

Sums each record's `seconds` (what the workers measured; with several workers
they add up to more than the wall time) into the campaign's own stages (poses,
render, detect once per job; calibrate and compare per record:
harness.runner.stage_seconds) and the verdict's extra work: the exact-observation
fit (exact_fit), computing the exact observations (exact_observations, when the
run records it) and the comparisons and scatter (verdict). Prints both, per
calibrator, and extra / own stages (wall seconds; the jobs' CPU seconds, cpu:*, are
printed beside them and not added): issue 14's bar is <= 10% (the campaign
within 10% of its time without the verdict). The figures are seconds under the
machine's load at the time (the run's load is not recorded: state it).
'''

import json
import sys
from pathlib import Path

import common

EXTRA = ("exact_fit", "exact_observations", "verdict")


def cost(run_dir):
    from common import stage_seconds
    doc = json.loads((Path(run_dir) / "run.json").read_text())
    recs = doc["records"]
    own, _ = stage_seconds(recs)
    extra = {}
    for r in recs.values():
        s = r.get("seconds") or {}
        for k in EXTRA:
            if s.get(k):
                key = f"{k}:{r['calibrator']}"
                extra[key] = extra.get(key, 0.0) + float(s[k])
    wall = (doc.get("execution") or {}).get("wall_seconds")
    return own, extra, wall, len(recs)


def main(argv=None):
    ap = common.parser(__doc__, repeats=1, warmup=0)
    ap.add_argument("runs", nargs="+", help="run directories (with run.json)")
    args = ap.parse_args(argv)
    out = common.Results("verdict_cost", args)
    for run in args.runs:
        own, extra, wall, n = cost(run)
        # the stages' wall seconds; cpu:* are the CPU seconds of the same work (printed
        # beside them, not added: they would count it twice)
        t_own = sum(v for k, v in own.items() if not k.startswith("cpu:"))
        t_extra = sum(extra.values())
        print(f"{run}: {n} records, wall {wall:.1f} s" if wall else f"{run}: {n} records")
        for k, v in own.items():
            print(f"  {'cpu' if k.startswith('cpu:') else 'own':5s} {k:28s} {v:8.1f} s")
        for k, v in sorted(extra.items()):
            print(f"  extra {k:28s} {v:8.1f} s")
        print(f"  own stages {t_own:.1f} s, verdict's extra work {t_extra:.1f} s: "
              f"{100 * t_extra / t_own:.1f}% (bar 10%)")
        out.add(f"cost/{Path(run).name}", own=own, extra=extra, own_s=t_own, extra_s=t_extra,
                percent=100 * t_extra / t_own, wall_s=wall, records=n)
    out.write()


if __name__ == "__main__":
    sys.exit(main())

r'''Check a run against a gate spec (and a baseline); exit 1 on any failure

SYNOPSIS

    camval gate runs/20261122T150000Z --spec campaigns/gate.toml
    camval gate runs/20261122T150000Z --spec my-gate.toml --baseline baseline.json

Absolute tolerances against the truth come from the spec; regressions
(`field:abs` or `field:N%`) are checked against the baseline, joined on each
record's fullname. Every failure is collected and printed as one table
(fullname, field, value, limit); the exit status is 1 when any check fails,
0 when all hold, 2 for usage errors (a spec with regressions and no
--baseline, a missing run, a malformed spec).
'''


def add_arguments(parser):
    parser.add_argument("run", metavar="RUN_DIR", help="a run directory (or its run.json)")
    parser.add_argument("--spec", required=True, help="the gate spec (TOML)")
    parser.add_argument("--baseline", metavar="FILE",
                        help="a baseline written by `camval baseline save`")


def run(args):
    from harness.gate import check, format_failures, load_gate_spec
    from harness.records import load_run

    spec = load_gate_spec(args.spec)
    doc = load_run(args.run)
    baseline = load_run(args.baseline) if args.baseline else None
    failures = check(doc, spec, baseline)
    n = len(doc["records"])
    if failures:
        print(format_failures(failures))
        print(f"camval gate: FAILED: {len(failures)} failure(s) in {n} records "
              f"(spec {args.spec}{', baseline ' + args.baseline if args.baseline else ''})")
        return 1
    print(f"camval gate: passed: {n} records, {len(spec.limits)} limits, "
          f"{len(spec.regressions)} regression checks"
          f"{' against ' + args.baseline if args.baseline else ''}")
    return 0

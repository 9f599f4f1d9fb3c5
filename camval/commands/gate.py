r'''Check a run against a gate spec (and a baseline); exit 1 on any failure

SYNOPSIS

    camval gate runs/20261122T150000Z        # the renderer gate, campaigns/gate-renderer.toml
    camval gate runs/20261122T150000Z --explain   # what it judges + minimum detectable faults
    camval gate runs/20261122T150000Z --spec campaigns/gate.toml   # absolute limits (K=16)
    camval gate runs/20261122T150000Z --spec my-gate.toml --baseline baseline.json

The default spec (campaigns/gate-renderer.toml) judges what the images cost:
each record's renderer difference (image fit minus the fit of the exact
observations) against the expected scatter the record carries, on any camera
and calibrator. Absolute tolerances against the truth come from a spec's
[limits]; regressions
(`field:abs` or `field:N%`) are checked against the baseline, joined on each
record's fullname. Every failure is collected and printed as one table
(fullname, field, value, limit); the exit status is 1 when any check fails,
0 when all hold, 2 for usage errors (a spec with regressions and no
--baseline, a missing run, a malformed spec).
'''


def add_arguments(parser):
    parser.add_argument("run", metavar="RUN_DIR", help="a run directory (or its run.json, or "
                        "a benchmark's JSON document: benchmarks/speed.py)")
    parser.add_argument("--spec", default=None,
                        help="the gate spec (TOML; default campaigns/gate-renderer.toml)")
    parser.add_argument("--explain", action="store_true",
                        help="print what the spec judges and each camera's minimum detectable "
                             "fault, then check")
    parser.add_argument("--baseline", metavar="FILE",
                        help="a baseline written by `camval baseline save`")


def run(args):
    from harness.gate import DEFAULT_SPEC, check, explain, format_failures, load_gate_spec
    from harness.records import GATED_KINDS, load_run

    if args.spec is None:
        args.spec = str(DEFAULT_SPEC)
    spec = load_gate_spec(args.spec)
    doc = load_run(args.run, kinds=GATED_KINDS)
    if args.explain:
        print("\n".join(explain(doc, spec)))
    baseline = load_run(args.baseline, kinds=GATED_KINDS) if args.baseline else None
    failures = check(doc, spec, baseline)
    n = len(doc["records"])
    if failures:
        print(format_failures(failures))
        print(f"camval gate: FAILED: {len(failures)} failure(s) in {n} records "
              f"(spec {args.spec}{', baseline ' + args.baseline if args.baseline else ''})")
        return 1
    print(f"camval gate: passed: {n} records, {len(spec.limits)} limits, "
          f"{len(spec.scatter)} scatter limits, {len(spec.joint)} joint limits, "
          f"{len(spec.regressions)} regression checks"
          f"{' against ' + args.baseline if args.baseline else ''}")
    return 0

r'''Save a run's records as a baseline for `camval gate --baseline` (never overwrites)

SYNOPSIS

    camval baseline save runs/20261122T150000Z -o baselines/raycast.json

The baseline is the run document marked as a baseline. An existing FILE is
never overwritten: choose another name or delete the old baseline yourself.
'''


def add_arguments(parser):
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    save = sub.add_parser("save", help="write a new baseline from a run")
    save.add_argument("run", metavar="RUN_DIR", help="a run directory (or its run.json)")
    save.add_argument("-o", "--output", required=True, metavar="FILE",
                      help="the baseline file to write (must not exist)")


def run(args):
    import os
    import tempfile
    from pathlib import Path

    from harness.gate import make_baseline
    from harness.records import GATED_KINDS, RunError, dumps, load_run

    out = Path(args.output)
    doc = make_baseline(load_run(args.run, kinds=GATED_KINDS))
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.exists():
        raise RunError(f"baseline '{out}' already exists; baselines are never overwritten "
                       f"(choose another -o FILE)")
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(dumps(doc))
        # link, unlike rename, fails when the name exists: no race can overwrite a baseline
        os.link(tmp, out)
    except FileExistsError:
        raise RunError(f"baseline '{out}' already exists; baselines are never overwritten "
                       f"(choose another -o FILE)") from None
    finally:
        os.unlink(tmp)
    print(f"camval baseline: wrote {out} ({len(doc['records'])} records)")
    return 0

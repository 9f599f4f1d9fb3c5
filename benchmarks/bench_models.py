r'''Wall and CPU time of the camera-model benchmark (`camval models`) per camera

SYNOPSIS

    uv run --frozen python benchmarks/bench_models.py [--cameras 15,9,1] [--repeats 1]
        [--out benchmarks/results/models.json]

For each camera, harness.model_benchmark.benchmark() with every candidate
(what `camval models CAMERA` runs, without the process start-up) --repeats
times; the table gives the median wall and CPU seconds, the slowest candidate
and its seconds, and the recommended model with its floor. The issue's bar:
<= 60 s wall per camera for 15, 9 and 1 on a 2-core machine.
'''

import argparse
import json
import os
import platform
import statistics
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.records import git_commit  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", default="15,9,1")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)

    from harness.calibrators.base import jsonable
    from harness.model_benchmark import benchmark
    from reference_models.catalogue import load_catalogue

    cat = load_catalogue()
    out = {"script": "bench_models", "created": datetime.now(UTC).isoformat(),
           "commit": git_commit(ROOT), "machine": platform.node(), "records": {}}
    print(f"{'camera':10s} {'wall s':>8s} {'cpu s':>8s}  {'slowest candidate':34s} "
          f"{'s':>6s}  recommended")
    for spec in args.cameras.split(","):
        truth = cat.get(spec).model
        walls, cpus, b = [], [], None
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            b = benchmark(truth)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        slow = max(b["rows"], key=lambda r: r["seconds"])
        rec = b["recommended"]
        rec_txt = f"{rec['name']} {rec['max']:.2g} px" if rec else "none"
        own = {cal: round(o["seconds"], 1) for cal, o in b.get("own", {}).items()}
        picks = {cal: c["model"] for cal, c in b["per_calibrator"].items()}
        print(f"{spec:10s} {statistics.median(walls):8.1f} {statistics.median(cpus):8.1f}  "
              f"{slow['name'][:34]:34s} {slow['seconds']:6.1f}  {rec_txt}; own fits s {own}; "
              f"choices {picks}; load {os.getloadavg()[0]:.1f}", flush=True)
        out["records"][f"models/{spec}"] = {
            "wall_s": statistics.median(walls), "cpu_s": statistics.median(cpus),
            "slowest": slow["name"], "slowest_s": slow["seconds"],
            "recommended": rec["name"] if rec else None, "load_1min": os.getloadavg()[0],
            "own_fit_seconds": {cal: o["seconds"] for cal, o in b.get("own", {}).items()},
            "choices": {cal: c["model"] for cal, c in b["per_calibrator"].items()},
            "floor_max_px": rec["max"] if rec else None,
            "rows": [{k: r.get(k) for k in ("name", "nparams", "rms", "max", "seconds")}
                     for r in b["rows"]]}
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        with open(args.out, "x") as f:
            json.dump(jsonable(out), f, indent=1, allow_nan=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())

r'''The mutation suite: renderer faults the gate must catch, clean renderers it must pass

SYNOPSIS

    from harness.mutation import run_suite

    report = run_suite("runs/mutation", reruns=10)
    report["ok"]                  # every effective fault flagged, every clean rerun passed
    report["faults"]["half_pixel"]["failures"]   # ["params.Hc: 0.5 > 0.006", ...]

Each fault of renderers.legacy.FAULTS is injected into the exact ray caster
(renderer "faulty", options {"fault": name}) and a small campaign is run on a
camera where the fault means something (MER B navcam, slot 15, CAHVOR: Hc and
Vc 0.25 px from the half pixel, aspect 0.99966, theta 90.024 deg; CAHV of the
same camera for theta90; MER A front hazcam, slot 8, CAHVORE with E != 0, for
ignore_e). The gate (campaigns/mutation-gate.toml) must fail every faulty run,
and at least one failure must name a parameter the fault moves
(FAULT_FIELDS). The clean renderer (raycast) runs on every case (CLEAN_CASES)
and must pass; the first case is rerun `reruns` times (the others once: the
CAHVORE jobs are slow) and must pass every time.

float32 (ROAMS's single-precision model vectors) moves projections by less
than 1e-4 px on these cameras: no gate at the calibrators' accuracy
(~0.001 px) can see it, so it is run and reported as "below detection", not
required to fail.
'''

import tempfile
import time
from pathlib import Path

SUITE_SPP = 16
SUITE_POSES = 6
GATE_SPEC = Path(__file__).resolve().parents[1] / "campaigns" / "mutation-gate.toml"

# fault -> (camera, model family) it is injected on
FAULT_CASES = {
    "half_pixel": (15, "CAHVOR"),
    "swap_hv": (15, "CAHVOR"),
    "r1_sign": (15, "CAHVOR"),
    "ignore_e": (8, "CAHVORE"),
    "focal_scale": (15, "CAHVOR"),
    "shift_001": (15, "CAHVOR"),
    "round_centre": (15, "CAHVOR"),
    "rounded_aspect": (15, "CAHVOR"),
    "theta90": (15, "CAHV"),
    "float32": (15, "CAHVOR"),
}
# gate fields that name the parameter each fault moves (any of them must fail)
FAULT_FIELDS = {
    "half_pixel": ("params.Hc", "params.Vc"),
    "swap_hv": ("status", "params.Hc", "params.Vc", "params.Hs", "params.Vs",
                "params.theta_deg", "projection.rms"),
    "r1_sign": ("params.R1",),
    "ignore_e": ("params.E0",),
    "focal_scale": ("params.Hs", "params.Vs"),
    "shift_001": ("params.Hc",),
    "round_centre": ("params.Hc", "params.Vc"),
    "rounded_aspect": ("params.Hs",),
    "theta90": ("params.theta_deg",),
    "float32": (),
}
BELOW_DETECTION = {"float32": "float32 rounding of C, A, H, V, O, R moves projections by "
                              "< 1e-4 px; below any gate at the calibrators' accuracy"}
# the clean renderer on every case a fault runs on (so a caught fault is the fault's doing);
# the first case is rerun `reruns` times, the others once (CAHVORE jobs are the slow ones)
CLEAN_CASES = ((15, "CAHVOR"), (15, "CAHV"), (8, "CAHVORE"))


def campaign_doc(camera, family, fault=None, spp=SUITE_SPP, poses=SUITE_POSES, name=None):
    renderer = {"name": "raycast", "spp": spp}
    if fault is not None:
        renderer = {"name": "faulty", "spp": spp, "options": {"fault": fault}}
    return {"name": name or f"mutation-{fault or 'clean'}", "cameras": [camera],
            "models": [family], "targets": ["dots"], "poses": {"n": poses, "seed": 0},
            "renderer": [renderer], "calibrator": [{"name": "jpl"}]}


def _run(doc, run_dir, spec):
    from harness.campaign import parse_campaign
    from harness.gate import check
    from harness.runner import run_campaign

    # workers=1: "faulty" is registered in this process only (until renderers.base lists it)
    run = run_campaign(parse_campaign(doc), run_dir, progress=False, workers=1)
    failures = check(run, spec)
    return run, failures


def _describe(f):
    return f"{f.field}: {f.value} (expected {f.limit}) [{f.fullname}]"


def run_suite(run_dir=None, faults=None, reruns=10, spp=SUITE_SPP, poses=SUITE_POSES,
              progress=None):
    r'''Run every fault and the clean reruns; returns a JSON-able report (see module doc)'''
    from harness.gate import load_gate_spec

    spec = load_gate_spec(GATE_SPEC)
    base = Path(run_dir) if run_dir else Path(tempfile.mkdtemp(prefix="camval-mutation-"))
    base.mkdir(parents=True, exist_ok=True)
    report = {"gate": str(GATE_SPEC), "spp": spp, "poses": poses, "faults": {}, "clean": []}
    for fault in (faults or list(FAULT_CASES)):
        camera, family = FAULT_CASES[fault]
        t0 = time.perf_counter()
        run, failures = _run(campaign_doc(camera, family, fault, spp, poses),
                             base / f"fault-{fault}", spec)
        fields = {f.field for f in failures}
        wanted = FAULT_FIELDS[fault]
        named = sorted(fields & set(wanted))
        if fault in BELOW_DETECTION:
            verdict = "below detection"
        elif failures and named:
            verdict = "caught"
        elif failures:
            verdict = "caught, wrong parameter"
        else:
            verdict = "missed"
        report["faults"][fault] = dict(
            camera=camera, model=family, verdict=verdict, named=named,
            failures=[_describe(f) for f in failures],
            seconds=round(time.perf_counter() - t0, 1))
        if progress:
            progress(f"{fault:15s} {verdict:25s} {', '.join(named) or '-'}")
    for i in range(max(reruns, 1)):
        for camera, family in (CLEAN_CASES if i == 0 else CLEAN_CASES[:1]):
            t0 = time.perf_counter()
            run, failures = _run(campaign_doc(camera, family, None, spp, poses),
                                 base / f"clean-{camera}-{family}-{i}", spec)
            report["clean"].append(dict(camera=camera, model=family, rerun=i,
                                        passed=not failures,
                                        failures=[_describe(f) for f in failures],
                                        seconds=round(time.perf_counter() - t0, 1)))
            if progress:
                progress(f"clean {camera} {family} rerun {i}: "
                         f"{'pass' if not failures else 'FAIL ' + str(len(failures))}")
    report["ok"] = (all(v["verdict"] in ("caught", "below detection")
                        for v in report["faults"].values())
                    and all(c["passed"] for c in report["clean"]))
    return report


def main(argv=None):
    r'''python -m harness.mutation [RUN_DIR] [--reruns N] [--out report.json]'''
    import argparse
    import json

    ap = argparse.ArgumentParser(description="camval mutation suite: renderer faults vs the gate")
    ap.add_argument("run_dir", nargs="?", default=None)
    ap.add_argument("--reruns", type=int, default=10)
    ap.add_argument("--out", default=None, help="write the report as JSON here")
    args = ap.parse_args(argv)
    report = run_suite(args.run_dir, reruns=args.reruns, progress=print)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1, allow_nan=False)
    print("mutation suite:", "PASS" if report["ok"] else "FAIL")
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    raise SystemExit(main())

r'''The mrcal calibrator on rendered paper jobs: CPU seconds of its fit and of the exact fit

SYNOPSIS

    OPENBLAS_NUM_THREADS=1 uv run python benchmarks/bench_mrcal.py \
        [--jobs 15/CAHVOR,17/CAHVORE,...] [--obs /tmp/camval_bench_mrcal_obs.pkl] [--profile]
    OPENBLAS_NUM_THREADS=1 uv run python benchmarks/bench_mrcal.py \
        --stages /tmp/camval_bench_fits.pkl [--jobs ...]   # bench_fits.py's saved images

For each job (camera/family of --campaign, default the paper campaign) the
images are rendered and the dots detected once and kept in the --obs pickle
(bench_stages.observations); with --stages, the observations are made from the
detections that `bench_fits.py run --stages` kept (the campaign's own poses and
detections, so the fits are those of a campaign's records bit for bit; a job not
kept there is an error). Then, as a campaign record does
(harness.job_records): the mrcal fit (calibrate_stage), the comparison with the
truth (compare_stage) and the verdict with its exact fit warm-started from the
image fit. Each job is timed in process CPU seconds (time.process_time; set
OPENBLAS_NUM_THREADS=1) for the fit and the exact fit separately, with the number
of mrcal.optimize calls and their CPU seconds, and the figures a record keeps:
projection difference RMS (rotation mode), residual RMS, the exact fit's
residual RMS, the verdict's floor and renderer differences. --profile prints the
top functions of a cProfile of each job (cumulative time). At the end, the
mrcal.optimize calls of every job summed by where in mrcal_fit._fit_poses they were
made (the chain of its inner functions that called solve(), e.g. restarts<polish<refit
for the coarse restarts after a bias pass; "direct" for a solve of _fit_poses itself: the seed,
the race's regularised start) and the grid step they ran on (2: the coarse grid), for
the image fits and the exact fits apart.

Records: mrcal/<camera>/<family>, mrcal/phases/<fit|exact>/<chain>/<step>.
'''

import sys
import time
import types
from pathlib import Path

import common

SCRIPT = "bench_mrcal"
DEFAULT_JOBS = ("1/CAHVOR,1/CAHVORE,2/CAHVOR,2/CAHVORE,3/CAHVOR,3/CAHVORE,4/CAHVOR,4/CAHVORE,"
                "5/CAHVOR,5/CAHVORE,9/CAHVOR,9/CAHVORE,13/CAHVOR,15/CAHVOR,16/CAHVOR,"
                "17/CAHVOR,17/CAHVORE,19/CAHVOR,19/CAHVORE,20/CAHVOR,20/CAHVORE,"
                "21/CAHVOR,21/CAHVORE,22/CAHVOR,22/CAHVORE")


class _Counted:
    r'''mrcal.optimize wrapped: calls and CPU seconds, in total and per phase'''

    def __init__(self, mrcal):
        self.mrcal, self.inner = mrcal, mrcal.optimize
        self.calls, self.cpu = 0, 0.0
        self.phases = {}   # (chain, step) -> [calls, CPU s] since the last take()

    def __call__(self, *a, **kw):
        c0 = time.process_time()
        try:
            return self.inner(*a, **kw)
        finally:
            cpu = time.process_time() - c0
            self.calls += 1
            self.cpu += cpu
            t = self.phases.setdefault(_phase(sys._getframe(1)), [0, 0.0])
            t[0] += 1
            t[1] += cpu

    def take(self):
        out = (self.calls, self.cpu)
        self.calls, self.cpu = 0, 0.0
        return out

    def take_phases(self):
        out, self.phases = self.phases, {}
        return out


def _phase(frame):
    r'''(chain, step) of an mrcal.optimize call: the mrcal_fit._fit_poses inner functions
that led to it, innermost first ("restarts<polish<refit"), and solve()'s grid step'''
    chain, step = [], 1
    while frame is not None:
        code = frame.f_code
        if code.co_filename.endswith("mrcal_fit.py"):
            if code.co_name == "_fit_poses":
                break
            if code.co_name == "solve":
                step = frame.f_locals.get("step", 1)
            else:
                chain.append(code.co_name)
        frame = frame.f_back
    return "<".join(chain), step


def _figure(d, *keys):
    for k in keys:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    return d


def _stage_observations(campaign, specs, path):
    r'''{spec: (obs, truth, target)} from bench_fits.py's --stages pickle, as run_job makes them'''
    import pickle

    from bench_stages import _jobs_of

    from harness.stages import observations_from

    with open(path, "rb") as f:
        stored = pickle.load(f)
    out = {}
    for spec, job in zip(specs, _jobs_of(campaign, specs), strict=True):
        if job.key not in stored:
            raise SystemExit(f"{path} has no images of {job.key}: run bench_fits.py run "
                             f"--stages {path} --jobs {spec} first")
        truth, target, poses = common.job_inputs(job)
        out[spec] = (observations_from(truth, target, poses, stored[job.key].detections),
                     truth, target)
    return out


def run(args, out):
    import cProfile
    import io
    import pstats

    import mrcal
    from bench_stages import observations
    from common import calibrate_stage, compare_stage

    import harness.stages
    from harness.job_records import _verdict
    from harness.jobs import camera_frame_model

    stages = types.SimpleNamespace(calibrate_stage=harness.stages.calibrate_stage)

    counted = _Counted(mrcal)
    mrcal.optimize = counted
    data = (_stage_observations(args.campaign, args.jobs, args.stages) if args.stages
            else observations(args.campaign, args.jobs, args.obs))
    head = (f"{'job':<12} {'fit s':>6} {'n':>3} {'opt s':>6} {'exact s':>7} {'n':>3} "
            f"{'proj rms':>9} {'resid rms':>9} {'x resid':>9} {'floor':>9} {'renderer':>9}")
    print(head)
    tot = [0.0, 0.0]
    phases = {}   # (fit|exact, chain, step) -> [calls, CPU s]

    def add_phases(kind):
        for (chain, step), (n, cpu) in counted.take_phases().items():
            t = phases.setdefault((kind, chain, step), [0, 0.0])
            t[0] += n
            t[1] += cpu
    for spec in args.jobs:
        obs, truth, target = data[spec]
        prof = cProfile.Profile() if args.profile else None
        if prof:
            prof.enable()
        c0 = time.process_time()
        res = calibrate_stage("mrcal", obs, target, truth.family, truth, {})
        fit_cpu = time.process_time() - c0
        fit_calls, fit_opt = counted.take()
        add_phases("fit")
        if res.status != "ok":
            out.add(f"mrcal/{spec}", status="failed", reason=res.reason)
            print(f"{spec:<12} failed: {res.reason}")
            continue
        # compared and judged in the truth's camera frame, as harness.job_records does for a
        # fit that does not read the world frame
        frame = camera_frame_model(truth)
        params, projection, _ = compare_stage(frame, res)
        sec, exact_cpu = {}, []

        def timed_stage(*a, exact_cpu=exact_cpu, **kw):   # the verdict's exact fit, CPU s
            c0 = time.process_time()
            try:
                return stages.calibrate_stage(*a, **kw)
            finally:
                exact_cpu.append(time.process_time() - c0)
        c0 = time.process_time()
        harness.stages.calibrate_stage = timed_stage
        try:
            verdict, _ = _verdict("mrcal", truth.family, {}, obs, target, truth, frame, res,
                                  params, projection, {}, sec)
        finally:
            harness.stages.calibrate_stage = stages.calibrate_stage
        verdict_cpu = time.process_time() - c0
        x_calls, x_opt = counted.take()
        add_phases("exact")
        if prof:
            prof.disable()
        rec = out.add(
            f"mrcal/{spec}", job=spec, fit_cpu_s=fit_cpu, fit_optimize_calls=fit_calls,
            fit_optimize_cpu_s=fit_opt, exact_fit_cpu_s=sum(exact_cpu),
            exact_fit_wall_s=sec.get("exact_fit"),
            verdict_cpu_s=verdict_cpu, exact_optimize_calls=x_calls,
            exact_optimize_cpu_s=x_opt, iterations=res.iterations,
            projection_rms_px=projection["rms"], residual_rms_px=res.residual_stats()["rms"],
            exact_residual_rms_px=_figure(verdict, "exact_fit", "residuals", "rms"),
            floor_rms_px=_figure(verdict, "floor", "projection", "rms"),
            renderer_rms_px=_figure(verdict, "renderer", "projection", "rms"),
            verdict_error=verdict.get("error"))
        tot[0] += fit_cpu
        tot[1] += rec["exact_fit_cpu_s"]
        print(f"{spec:<12} {fit_cpu:>6.2f} {fit_calls:>3} {fit_opt:>6.2f} "
              f"{rec['exact_fit_cpu_s']:>7.3f} {x_calls:>3} {rec['projection_rms_px']:>9.3e} "
              f"{rec['residual_rms_px']:>9.3e} {rec['exact_residual_rms_px'] or 0:>9.3e} "
              f"{rec['floor_rms_px'] or 0:>9.3e} {rec['renderer_rms_px'] or 0:>9.3e}"
              + (f"  verdict error: {rec['verdict_error']}" if rec["verdict_error"] else ""),
              flush=True)
        if prof:
            s = io.StringIO()
            pstats.Stats(prof, stream=s).sort_stats("cumulative").print_stats(25)
            print(s.getvalue())
    out.add("mrcal/total", fit_cpu_s=tot[0], exact_fit_cpu_s=tot[1])
    print(f"total CPU s: fit {tot[0]:.2f}, exact fit {tot[1]:.2f}")
    print("mrcal.optimize by phase (the calls' CPU s, calls, ms per call):")
    for (kind, chain, step), (n, cpu) in sorted(phases.items(), key=lambda x: -x[1][1]):
        out.add(f"mrcal/phases/{kind}/{chain or 'direct'}/{step}", calls=n, cpu_s=cpu)
        print(f"  {kind:<5} {chain or 'direct':<28} step {step}  {cpu:7.2f} s {n:5d} "
              f"{1e3 * cpu / n:7.1f} ms")


def arguments(ap):
    ap.add_argument("--campaign", default="paper", help="a campaign name or TOML path")
    ap.add_argument("--jobs", type=common.ids, default=common.ids(DEFAULT_JOBS))
    ap.add_argument("--obs", type=Path, default=Path("/tmp/camval_bench_mrcal_obs.pkl"),
                    help="where the observations are kept between runs")
    ap.add_argument("--stages", type=Path, default=None,
                    help="bench_fits.py's --stages pickle: the observations from its images")
    ap.add_argument("--profile", action="store_true", help="cProfile each job")
    return ap


if __name__ == "__main__":
    ap = arguments(common.parser(__doc__, repeats=1, warmup=0))
    ap.set_defaults(run=run)
    sys.exit(common.main(SCRIPT, ap))

r'''Campaign stages one at a time: pose planning, detection, calibrators, comparison, stereo

SYNOPSIS

    uv run python benchmarks/bench_stages.py poses [--campaign paper] [--repeats 3]
    uv run python benchmarks/bench_stages.py compare [--jobs 3/CAHVORE,8/CAHVORE,15/CAHVOR,15/CAHV]
    uv run python benchmarks/bench_stages.py detect [--cameras 3,21,5] [--repeats 5] [--check F.npz]
    OPENBLAS_NUM_THREADS=1 uv run python benchmarks/bench_stages.py jpl [--jobs 5/CAHV,...]
    uv run python benchmarks/bench_stages.py calibrators [--cameras 5,8,15] [--skip-exact]
    uv run python benchmarks/bench_stages.py targets [--cameras 5,15,17,1] [--spp 16]
    uv run python benchmarks/bench_stages.py stereo [--ablation]

Each part writes one JSON document, benchmarks/results/<UTC stamp>-bench_stages-<part>.json
(benchmarks/common.py: one record per measured case, keyed by its fullname).
`bench_stages.py PART --help` says what the part measures.

poses        CPU seconds of the pose planner over every job of a campaign
compare      CPU seconds of the comparison with the truth, per calibrated record
detect       the dot-grid detector's CPU and wall seconds per image on paper renders
jpl          CPU seconds of the jpl calibrator's fits on rendered paper jobs
calibrators  calibrator accuracy: exact correspondences over the catalogue, and renders
targets      pose-planner time over the catalogue, detector time and accuracy per target
stereo       the stereo range check at 5 m (1% bars), what each matching step buys, its cost
'''

import json
import pickle
import sys
import time
from pathlib import Path

import common
import numpy as np

SCRIPT = "bench_stages"


def _job_spec(spec):
    camera, family = spec.split("/")
    return camera, family


def _jobs_of(campaign, specs):
    r'''The campaign's jobs named camera/family in specs, in that order (SystemExit if absent)'''
    jobs = common.campaign_jobs(campaign)
    out = []
    for spec in specs:
        camera, family = _job_spec(spec)
        job = next((j for j in jobs if j.camera_key == camera and j.family == family), None)
        if job is None:
            raise SystemExit(f"no job {spec} in {campaign}")
        out.append(job)
    return out


# ---------------------------------------------------------------- poses

def part_poses(args, out):
    r'''Pose planning: CPU seconds of harness poses_stage over every job of a campaign

poses_stage (targets.poses.plan_poses) runs for every job of --campaign (the
paper: 132 jobs; a job whose camera cannot give its family is skipped, as the
campaign does), --repeats times after --warmup untimed passes over the first
job. Records: poses/all (the total per repetition: CPU and wall seconds, min
and median) and poses/<job key> (CPU seconds of each job, min over repeats).
'''
    from common import StageFailed, cached_target, camera_stage, poses_stage

    setups = []
    for job in common.campaign_jobs(args.campaign):
        try:
            setups.append((job, camera_stage(job)[1], cached_target(job.target)))
        except StageFailed:
            pass
    per_job = {job.key: [] for job, _, _ in setups}
    planned = {}

    def one_pass(setups=setups, record=True):
        for job, truth, target in setups:
            c0 = time.process_time()
            try:
                poses_stage(truth, target, job.poses_n, job.poses_seed, job.poses_cover)
                planned[job.key] = True
            except StageFailed as e:
                planned[job.key] = e.reason
            if record:
                per_job[job.key].append(time.process_time() - c0)

    for _ in range(args.warmup):
        one_pass(setups[:1], record=False)
    t = common.timed(one_pass, repeats=args.repeats, warmup=0)
    rec = out.add("poses/all", campaign=args.campaign, jobs=len(setups),
                  planned=sum(v is True for v in planned.values()), cpu_s=t["cpu_s"],
                  wall_s=t["wall_s"])
    for key, cpus in per_job.items():
        out.add(f"poses/{key}", cpu_s=common.summary(cpus),
                **({} if planned[key] is True else {"status": "failed",
                                                    "reason": planned[key]}))
    print(f"poses, {rec['jobs']} jobs ({rec['planned']} planned): CPU {t['cpu_s']['min']:.2f} s "
          f"(median {t['cpu_s']['median']:.2f}), wall {t['wall_s']['min']:.2f} s")


def _poses_arguments(p):
    p.add_argument("--campaign", default="paper", help="a campaign name or TOML path")


# ---------------------------------------------------------------- compare

def calibrated_records(jobs):
    r'''[(job key, calibrator/model, truth, CalibrationResult)] of the jobs (ok only)'''
    from common import (
        calibrate_stage,
        detect_stage,
        observations_from,
        render_stage,
    )
    out = []
    for job in jobs:
        truth, target, poses = common.job_inputs(job)
        renders, _, _ = render_stage(job.renderer, truth, target, poses, job.settings)
        dets, _ = detect_stage([r.image for r in renders], target)
        obs = observations_from(truth, target, poses, dets)
        for cal, model, options in job.calibrators:
            res = calibrate_stage(cal, obs, target, model, truth, options)
            print(f"  calibrated {job.key} {cal}/{model}: {res.status}", flush=True)
            if res.status == "ok":
                out.append((job, cal, model, truth, res))
    return out


def part_compare(args, out):
    r'''Comparison with the truth: CPU seconds of harness compare_stage per calibrated record

The chosen jobs (camera/family of --campaign) are rendered, detected and
calibrated once by every calibrator of the campaign, as the campaign's
run_job does; then compare_stage runs on each successful record, job by job
in the campaign's order, --repeats times (after --warmup untimed calls on the
first record). The truth-points memo of harness.compare is emptied before each
repetition, so a repetition costs what a worker's first pass over these jobs
costs. Records: compare/all (the total per repetition), compare/<fullname>
(CPU seconds of each record, min over repeats).
'''
    from common import compare_stage

    import harness.compare

    records = calibrated_records(_jobs_of(args.campaign, args.jobs))
    if not records:
        raise SystemExit("no calibrated record to compare")
    per = {job.fullname(cal, model): [] for job, cal, model, _, _ in records}

    def one_pass(records=records, record=True):
        memo = getattr(harness.compare, "_TRUTH_POINTS", None)
        if memo is not None:
            memo.clear()
        for job, cal, model, truth, res in records:
            c0 = time.process_time()
            compare_stage(truth, res)
            if record:
                per[job.fullname(cal, model)].append(time.process_time() - c0)

    for _ in range(args.warmup):
        one_pass(records[:1], record=False)
    t = common.timed(one_pass, repeats=args.repeats, warmup=0)
    out.add("compare/all", campaign=args.campaign, jobs=args.jobs, records=len(records),
            cpu_s=t["cpu_s"], wall_s=t["wall_s"])
    for name, cpus in per.items():
        out.add(f"compare/{name}", cpu_s=common.summary(cpus))
    print(f"compare, {len(records)} records: CPU {t['cpu_s']['min']:.3f} s "
          f"(median {t['cpu_s']['median']:.3f}), wall {t['wall_s']['min']:.3f} s")


def _compare_arguments(p):
    p.add_argument("--campaign", default="paper", help="a campaign name or TOML path")
    p.add_argument("--jobs", type=common.ids, default=["3/CAHVORE", "8/CAHVORE", "15/CAHVOR",
                                                       "15/CAHV"],
                   help="camera/family of the jobs whose records are compared")


# ---------------------------------------------------------------- detect

def render_images(directory, cameras, campaign):
    r'''Render the CAHVOR dots job of each camera into directory (if not there yet)'''
    from common import render_stage

    directory.mkdir(parents=True, exist_ok=True)
    jobs = common.campaign_jobs(campaign, families=["CAHVOR"], targets=["dots"])
    for cam in cameras:
        if list(directory.glob(f"cam{cam}_*.npy")):
            continue
        job = next((j for j in jobs if j.camera_key == cam), None)
        if job is None:
            raise SystemExit(f"{campaign} has no CAHVOR dots job for camera {cam}")
        truth, target, poses = common.job_inputs(job)
        results, _, _ = render_stage(job.renderer, truth, target, poses, job.settings)
        for i, r in enumerate(results):
            np.save(directory / f"cam{cam}_{i}.npy", np.asarray(r.image))


def part_detect(args, out):
    r'''Dot-grid detector: CPU and wall seconds per image on paper-campaign renders

The images are the ray-cast renders of the CAHVOR dots jobs of --campaign
(campaigns/paper.toml) for the chosen cameras (3 and 21: 5120x3840, 5:
1024x1024), 6 poses each. They are rendered once and kept as
cam<camera>_<pose>.npy in --images; later runs reuse them.

Each image is detected --repeats times after --warmup untimed calls;
time.process_time() (CPU) and time.perf_counter() (wall) are reported per
image (min, median), and per image size the median over its images of the
minima. Records: detect/<image>, detect/<width>x<height>.

--save FILE writes every detection (q, found, status, info) to an .npz;
--check FILE compares with such a file and fails (exit status 1) unless q
(NaN positions included), the found masks, statuses and infos are identical
(--check-px TOL: the centroids within TOL px, e.g. 1e-5 for a detector whose sums
run in another order; the largest and RMS change are printed and recorded).
'''
    from targets.boards import load_target
    from targets.detect import detect

    render_images(args.images, args.cameras, args.campaign)
    target = load_target("dots")
    paths = sorted(p for cam in args.cameras for p in args.images.glob(f"cam{cam}_*.npy"))
    sizes, dets = {}, {}
    for p in paths:
        img = np.load(p)
        t = common.timed(lambda img=img: detect(img, target), repeats=args.repeats,
                         warmup=args.warmup)
        det = dets[p.stem] = t["result"]
        size = f"{img.shape[1]}x{img.shape[0]}"
        out.add(f"detect/{p.stem}", image=p.stem, shape=list(img.shape), detection=det.status,
                n_found=int(det.n_found), cpu_s=t["cpu_s"], wall_s=t["wall_s"])
        sizes.setdefault(size, []).append(t)
        print(f"{p.stem:10s} {size:>11s} {det.status:10s} {det.n_found:4d} dots  cpu "
              f"{t['cpu_s']['min']:.4f} s  wall {t['wall_s']['min']:.4f} s", flush=True)
    for size, ts in sizes.items():
        rec = out.add(f"detect/{size}", images=len(ts),
                      cpu_s_median=float(np.median([t["cpu_s"]["min"] for t in ts])),
                      wall_s_median=float(np.median([t["wall_s"]["min"] for t in ts])))
        print(f"{size:10s} {len(ts)} images: median cpu {rec['cpu_s_median']:.4f} s, "
              f"wall {rec['wall_s_median']:.4f} s per image")
    if args.save:
        np.savez(args.save, **{f"q_{k}": d.q for k, d in dets.items()},
                 **{f"found_{k}": d.found for k, d in dets.items()},
                 **{f"status_{k}": np.array(d.status) for k, d in dets.items()},
                 **{f"info_{k}": np.array(json.dumps(d.info, sort_keys=True, default=str))
                    for k, d in dets.items()})
    if args.check:
        ref = np.load(args.check)
        tol = args.check_px
        moved = {k: _centroid_change(ref[f"q_{k}"], d.q) for k, d in dets.items()}
        bad = [k for k, d in dets.items()
               if not ((np.array_equal(ref[f"q_{k}"], d.q, equal_nan=True) if tol == 0
                        else moved[k] is not None and moved[k].max(initial=0.0) <= tol)
                       and np.array_equal(np.isnan(ref[f"q_{k}"]), np.isnan(d.q))
                       and np.array_equal(ref[f"found_{k}"], d.found)
                       and str(ref[f"status_{k}"]) == d.status
                       and str(ref[f"info_{k}"]) == json.dumps(d.info, sort_keys=True,
                                                               default=str))]
        d = np.concatenate([m for m in moved.values() if m is not None] or [np.zeros(0)])
        change = {"max_px": float(d.max(initial=0.0)),
                  "rms_px": float(np.sqrt(np.mean(d ** 2))) if len(d) else 0.0,
                  "centroids": int(len(d))}
        out.add("detect/check", identical=not bad, against=str(args.check), differ=bad,
                tolerance_px=tol, centroid_change=change)
        print(f"centroids moved: max {change['max_px']:.3g} px, RMS {change['rms_px']:.3g} px "
              f"over {change['centroids']}")
        what = "identical to" if tol == 0 else f"within {tol:g} px of"
        print(f"detections {what}", args.check if not bad else f"{args.check}: NO, {bad}")
        return 1 if bad else 0


def _centroid_change(q_ref, q):
    r'''|q - q_ref| (px) of the centroids found in both, or None if they differ in which
are found'''
    if not np.array_equal(np.isnan(q_ref), np.isnan(q)):
        return None
    d = np.linalg.norm(np.asarray(q) - q_ref, axis=1)
    return d[np.isfinite(d)]


def _detect_arguments(p):
    p.add_argument("--campaign", default="paper", help="a campaign name or TOML path")
    p.add_argument("--images", type=Path, default=Path("/tmp/detbench"),
                   help="where the rendered images are kept between runs")
    p.add_argument("--cameras", type=common.ids, default=["3", "21", "5"])
    p.add_argument("--save", type=Path, help="write the detections to this .npz")
    p.add_argument("--check", type=Path, help="fail unless the detections equal this .npz's")
    p.add_argument("--check-px", type=float, default=0.0,
                   help="with --check: centroids may move this far (px; default 0: bit "
                        "for bit); found dots, status and info must still be equal")


part_detect.repeats_warmup = (5, 0)


# ---------------------------------------------------------------- jpl

def observations(campaign, specs, cache):
    r'''{spec: (obs, truth, target)}: rendered and detected once, kept in the pickle `cache`'''
    from common import detect_stage, observations_from, render_stage

    stored = {}
    if cache.exists():
        with open(cache, "rb") as f:
            stored = pickle.load(f)
    out = {}
    for spec, job in zip(specs, _jobs_of(campaign, specs), strict=True):
        truth, target, poses = common.job_inputs(job)
        if spec not in stored:
            t0 = time.perf_counter()
            renders, _, _ = render_stage(job.renderer, truth, target, poses, job.settings)
            dets, _ = detect_stage([r.image for r in renders], target)
            stored[spec] = observations_from(truth, target, poses, dets)
            print(f"{spec}: rendered and detected in {time.perf_counter() - t0:.1f} s",
                  flush=True)
            with open(cache, "wb") as f:
                pickle.dump(stored, f)
        out[spec] = (stored[spec], truth, target)
    return out


def part_jpl(args, out):
    r'''CPU time of the jpl calibrator's fits on rendered paper-campaign jobs

For each job (camera/family of --campaign, campaigns/paper.toml: 6 poses of
the dot target, ray-cast at spp=16, adaptive) the images are rendered and the
dots detected once; the observations are kept in the --obs pickle (reused by
later runs: the rendering of a 5120x3840 camera takes minutes). Then the
harness's calibrate_stage("jpl", ...) runs --repeats times after --warmup fits
(which load or compile the numba kernels); the records give the CPU
(time.process_time) and wall seconds per fit (with more CPU than wall seconds,
BLAS threads spin: set OPENBLAS_NUM_THREADS=1), the solver's function
evaluations and the final RMS residual. Records: jpl/<camera>/<family>.
'''
    from common import calibrate_stage

    data = observations(args.campaign, args.jobs, args.obs)
    print(f"{'job':<12} {'size':>10} {'N':>4} {'cpu s':>7} {'wall s':>7} {'nfev':>16} "
          f"{'rms px':>9}")
    total = 0.0
    for spec in args.jobs:
        obs, truth, target = data[spec]
        t = common.timed(lambda: calibrate_stage("jpl", obs, target, truth.family,  # noqa: B023
                                                 truth, {}),  # noqa: B023
                         repeats=args.repeats, warmup=args.warmup)
        r = t["result"]
        name = f"jpl/{spec}"
        if r.status != "ok":
            out.add(name, status="failed", reason=r.reason)
            print(f"{spec:<12} the jpl fit failed: {r.reason}")
            continue
        rec = out.add(name, job=spec, family=truth.family, imagersize=[truth.width, truth.height],
                      n_points=int(obs.found.sum()), cpu_s=t["cpu_s"], wall_s=t["wall_s"],
                      nfev=[p.get("nfev") for p in r.info["passes"]], iterations=r.iterations,
                      rms_px=r.residual_stats()["rms"])
        total += rec["cpu_s"]["median"]
        print(f"{spec:<12} {truth.width:>5}x{truth.height:<4} {rec['n_points']:>4} "
              f"{rec['cpu_s']['median']:>7.3f} {rec['wall_s']['median']:>7.3f} "
              f"{str(rec['nfev']):>16} {rec['rms_px']:>9.2e}", flush=True)
    print(f"total CPU per fit set: {total:.3f} s")


def _jpl_arguments(p):
    p.add_argument("--campaign", default="paper", help="a campaign name or TOML path")
    p.add_argument("--jobs", type=common.ids,
                   default=["5/CAHV", "5/CAHVOR", "5/CAHVORE", "3/CAHV", "3/CAHVOR", "3/CAHVORE"])
    p.add_argument("--obs", type=Path, default=Path("/tmp/camval_bench_jpl_obs.pkl"),
                   help="where the observations are kept between runs")


# ---------------------------------------------------------------- calibrators

RENDER_BARS = {"rms": 0.002, "max": 0.01, "Hc": 0.01, "Vc": 0.01, "theta_deg": 0.001,
               "proj_rms": 0.002}


def _fmt(v, f="{:.2e}"):
    return "-" if v is None else f.format(v)


def calibrators_exact(out):
    from synthetic import (
        catalogue_models,
        default_target,
        exact_observations,
        synthetic_poses,
    )

    from harness.calibrators import calibrate
    from harness.compare import projection_difference, with_R0
    target = default_target()
    print("\n== exact correspondences (no rendering) ==")
    print(f"{'camera':18s} {'family':8s} {'calib':6s} {'proj max px':>12s} "
          f"{'dtheta deg':>11s} {'s':>6s}  bar")
    for key, model in catalogue_models():
        for cal in ("jpl", "mrcal"):
            if cal == "mrcal" and model.family == "CAHV":
                continue
            truth = model if cal == "jpl" else model.with_theta_90()
            obs = exact_observations(truth, target, synthetic_poses(truth, target))
            r = calibrate(cal, obs, target, truth.family, truth=truth, bias_correction=False)
            rec = {"camera": key, "family": truth.family, "calibrator": cal,
                   "status": r.status, "reason": r.reason, "seconds": r.seconds}
            if r.ok:
                mode = "world" if cal == "jpl" else "rotation"
                d = projection_difference(truth, r.model, mode=mode, step=32)
                rec["proj_max"] = d["max"]
                if cal == "jpl":
                    t = with_R0(truth, 0.0) if truth.family != "CAHV" else truth
                    rec["dtheta_deg"] = (r.model.photogrammetric().theta_deg
                                         - t.photogrammetric().theta_deg)
                ok = d["max"] <= 1e-6 and abs(rec.get("dtheta_deg", 0.0)) <= 1e-7
            else:
                ok = False
            rec["meets_bar"] = ok
            out.add(f"calibrators/exact/{key}/{truth.family}/{cal}", rec)
            print(f"{key:18s} {truth.family:8s} {cal:6s} {_fmt(rec.get('proj_max')):>12s} "
                  f"{_fmt(rec.get('dtheta_deg')):>11s} {r.seconds:6.2f}  "
                  f"{'ok' if ok else 'MISSED ' + r.reason}")


def calibrators_rendered(out, cameras):
    from synthetic import (
        catalogue_models,
        default_target,
        rendered_observations,
    )

    from harness.calibrators import calibrate
    from harness.compare import compare
    from reference_models.cahvore import truncate
    target = default_target()
    models = dict(catalogue_models())
    runs = [("jpl", None, True), ("jpl", None, False), ("mrcal", "CAHVOR", True),
            ("opencv", "OPENCV5", True), ("colmap", "OPENCV", True)]
    print("\n== rendered: ray-cast K=16, noise-free, 6 planned poses ==")
    print(f"{'cam':4s} {'truth':7s} {'calibrator':20s} {'res rms':>8s} {'res max':>8s} "
          f"{'dHc':>8s} {'dVc':>8s} {'dtheta':>9s} {'proj rms':>9s} {'proj max':>9s} "
          f"{'s':>5s}  bar")
    for key in cameras:
        for family in ("CAHV", "CAHVOR"):
            truth = truncate(models[key], family)
            t0 = time.perf_counter()
            obs, info = rendered_observations(truth, target, spp=16)
            t_rd = time.perf_counter() - t0
            for cal, model_name, bias in runs:
                name = model_name or family
                if cal == "mrcal" and family == "CAHV":
                    continue
                r = calibrate(cal, obs, target, name, truth=truth, bias_correction=bias)
                s = compare(r, truth)
                label = f"{cal} {name}" + ("" if bias else " raw")
                rec = {"camera": key, "truth_family": family, "calibrator": cal,
                       "model": name, "bias_correction": bias, "status": r.status,
                       "reason": r.reason, "seconds": r.seconds,
                       "render_detect_seconds": t_rd, "n_found": info["n_found"],
                       "residuals": s["residuals"], "parameters": s["parameters"],
                       "projection": s["projection"], "library_version": r.library_version}
                bar = ""
                if r.ok:
                    p, res = s["parameters"], s["residuals"]
                    pr = s["projection"]["rotation"]
                    if cal == "jpl" and bias:
                        ok = (res["rms"] <= RENDER_BARS["rms"] and res["max"] <= RENDER_BARS["max"]
                              and abs(p["Hc"]) <= RENDER_BARS["Hc"]
                              and abs(p["Vc"]) <= RENDER_BARS["Vc"]
                              and abs(p["theta_deg"]) <= RENDER_BARS["theta_deg"]
                              and pr["rms"] <= RENDER_BARS["proj_rms"])
                        rec["meets_bar"] = ok
                        bar = "ok" if ok else "MISSED"
                    print(f"{key:4s} {family:7s} {label:20s} {res['rms']:8.4f} {res['max']:8.4f} "
                          f"{p['Hc']:8.4f} {p['Vc']:8.4f} {_fmt(p['theta_deg'], '{:9.2e}'):>9s} "
                          f"{pr['rms']:9.4f} {pr['max']:9.4f} {r.seconds:5.2f}  {bar}")
                else:
                    print(f"{key:4s} {family:7s} {label:20s} {r.status}: {r.reason}")
                out.add(f"calibrators/rendered/{key}/{family}/{cal}/{name}/"
                        f"{'bias' if bias else 'raw'}", rec)


def part_calibrators(args, out):
    r'''Calibrator accuracy: exact correspondences over the catalogue, and rendered images

Part 1 (exact): for every catalogue model, the dot centres projected exactly at
6 synthetic poses (tests/synthetic.py); jpl fits the model's own
family (bar: projection difference <= 1e-6 px, theta <= 1e-7 deg, theta
compared in the fit's R0 gauge); mrcal fits CAHVOR/CAHVORE to the theta = 90
version (bar: projection difference, fitted rotation, <= 1e-6 px).

Part 2 (rendered): for each 1024x1024 catalogue camera of --cameras (slots 5-16)
truncated to CAHV and to CAHVOR: 6 poses planned by targets.poses.plan_poses,
rendered noise-free by the ray-cast renderer at K=16, dots detected by
targets.detect.detect; then jpl (with and without the bias correction), mrcal
(CAHVOR, board poses estimated), opencv OPENCV5 and colmap OPENCV. Bars for
jpl, bias-corrected: RMS residual <= 0.002 px, worst <= 0.01 px, |Hc|,|Vc|
errors <= 0.01 px, |theta| error <= 0.001 deg, projection difference RMS
(fitted rotation) <= 0.002 px.

Records: calibrators/exact/<camera>/<family>/<calibrator>,
calibrators/rendered/<camera>/<family>/<calibrator>/<model>/<bias|raw>; each
with "meets_bar" where a bar applies. Exit status 1 when a bar is missed.
'''
    out.doc["bars"] = {"exact_proj_max_px": 1e-6, "exact_theta_deg": 1e-7,
                       "rendered": RENDER_BARS}
    if not args.skip_exact:
        calibrators_exact(out)
    if not args.skip_rendered:
        calibrators_rendered(out, args.cameras)
    missed = [n for n, r in out.records.items() if r.get("meets_bar") is False]
    print(f"\n{len(out.records)} records, {len(missed)} missed a bar")
    for m in missed:
        print(f"  missed: {m}")
    return 1 if missed else 0


def _calibrators_arguments(p):
    p.add_argument("--cameras", type=common.ids, default=[str(c) for c in range(5, 17)],
                   help="catalogue slots for the rendered part (1024x1024 ones)")
    p.add_argument("--skip-exact", action="store_true")
    p.add_argument("--skip-rendered", action="store_true")


# ---------------------------------------------------------------- targets

def targets_plan(out, catalogue):
    from targets.boards import load_target
    from targets.poses import NotVisibleError, plan_poses

    t = load_target("dots")
    for key in catalogue.keys():
        m = catalogue.get(key).model
        t0 = time.perf_counter()
        try:
            plan_poses(m, t)
            rec = {"camera": key, "status": "ok"}
        except NotVisibleError as e:
            rec = {"camera": key, "status": "not-visible", "reason": str(e)}
        rec["seconds"] = time.perf_counter() - t0
        out.add(f"targets/plan/{key}", rec)
    plans = [r for n, r in out.records.items() if n.startswith("targets/plan/")]
    ok = [p["seconds"] for p in plans if p["status"] == "ok"]
    print(f"plan_poses: {len(ok)} cameras, {sum(ok) / len(ok):.3f} s mean, "
          f"{max(ok):.3f} s max per camera")
    for p in plans:
        if p["status"] != "ok":
            print(f"  {p['camera']}: {p['reason']}")


def targets_detect(out, catalogue, cameras, spp):
    from renderers.base import RenderSettings, get_renderer
    from targets.boards import load_target
    from targets.centroids import expected_centroids, projected_points
    from targets.detect import detect
    from targets.poses import plan_poses

    renderer = get_renderer("raycast")
    for key in cameras:
        m = catalogue.get(key).model
        for name in ("dots", "apriltag", "chessboard"):
            t = load_target(name)
            errs, det_s, cen_s, found, expected, statuses = [], [], [], 0, 0, []
            for Rt in plan_poses(m, t):
                img = renderer.render(m, t.pattern(), Rt, RenderSettings(spp=spp)).image
                t0 = time.perf_counter()
                det = detect(img, t)
                det_s.append(time.perf_counter() - t0)
                if name == "dots":
                    t0 = time.perf_counter()
                    truth = expected_centroids(m, t, Rt)
                    cen_s.append(time.perf_counter() - t0)
                else:
                    truth = projected_points(m, t, Rt)
                statuses.append(det.status)
                found += det.n_found
                expected += det.n_expected
                e = np.linalg.norm(det.q - truth, axis=-1)
                errs.append(e[np.isfinite(e)])
            e = np.concatenate(errs)
            r = out.add(f"targets/detect/{key}/{name}/K={spp}", {
                "camera": key, "size": [m.width, m.height], "target": name, "spp": spp,
                "status_ok": statuses.count("ok"), "n_found": found, "n_expected": expected,
                "rms_px": float(np.sqrt(np.mean(e ** 2))) if len(e) else None,
                "max_px": float(e.max()) if len(e) else None,
                "detect_seconds_mean": float(np.mean(det_s)),
                "expected_centroids_seconds_mean": float(np.mean(cen_s)) if cen_s else None,
            })
            print(f"{key:>18} {m.width}x{m.height} {name:10} ok {r['status_ok']}/6 "
                  f"found {found}/{expected}  rms {r['rms_px'] or float('nan'):.4f}  "
                  f"max {r['max_px'] or float('nan'):.4f} px  detect "
                  f"{r['detect_seconds_mean']:.3f} s", flush=True)


def part_targets(args, out):
    r'''Targets: pose-planner time over the catalogue, detector time and accuracy per target

Part 1 (unless --skip-plan): plan_poses(model, "dots") for every catalogue
camera but SuperCam (seconds per camera; SuperCam's refusal is recorded with
its reason).

Part 2: for each of --cameras and each target (dots, apriltag, chessboard),
the 6 planned poses rendered noise-free by the ray-cast renderer (--spp x
--spp, adaptive), then detected: detection seconds per image, points found,
and the error of the detections against the truth - the exact expected
centroids for dots, the exact projections of the corners for tags and
chessboards - as RMS and max over all points of the 6 poses.
expected_centroids() seconds per pose (100 dots, outline points from its error
bound: targets.centroids.CENTROID_TOLERANCE_PX) are reported too.

Records: targets/plan/<camera>, targets/detect/<camera>/<target>/K=<spp>.
'''
    from reference_models.catalogue import load_catalogue

    catalogue = load_catalogue()
    if not args.skip_plan:
        targets_plan(out, catalogue)
    targets_detect(out, catalogue, args.cameras, args.spp)


def _targets_arguments(p):
    p.add_argument("--cameras", type=common.ids, default=["5", "15", "17", "1"],
                   help="catalogue keys for part 2")
    p.add_argument("--spp", type=int, default=16, help="K for the renders of part 2")
    p.add_argument("--skip-plan", action="store_true", help="skip part 1")


# ---------------------------------------------------------------- stereo

STEREO_BAR = 0.01


def _band(stats):
    b = stats["band"]
    return {"n": b.get("n", 0), "valid_fraction": b["valid_fraction"],
            "median_rel_error": b.get("median_rel_error"),
            "median_abs_rel_error": b.get("median_abs_rel_error"),
            "p95_abs_rel_error": b.get("p95_abs_rel_error"),
            "all_valid_fraction": stats["valid_fraction"],
            "all_median_abs_rel_error": stats["all"].get("median_abs_rel_error")}


def stereo_case(out, key, name, left, right, scale, **kw):
    from harness.studies.stereo import StereoSetup, run_stereo_check
    setup = StereoSetup.from_catalogue(left, right, scale=scale)
    with common.Stopwatch() as sw:
        r = run_stereo_check(setup, variants={"clean": {}}, spp=2, **kw)
    v = r.variants["clean"]
    rec = out.add(f"stereo/{key}", {
        "case": name, "pair": [str(left), str(right)], "scale": scale, "options": kw,
        "rectified_size": r.meta["rectified_size"], "pixels_per_deg": r.meta["pixels_per_deg"],
        "matcher": r.meta["matcher"], "refined": _band(v.stats), "sgbm": _band(v.stats_sgbm),
        "refinement_status": v.stats.get("refinement"),
        "seconds": {**r.meta["seconds"], **v.seconds, "total_wall": sw.wall_s,
                    "total_cpu": sw.cpu_s, "numba_threads": common.numba_threads()}})
    b, s = rec["refined"], rec["sgbm"]
    ok = b["median_abs_rel_error"] is not None and b["median_abs_rel_error"] < STEREO_BAR
    rec["meets_bar"] = bool(ok)
    print(f"{name:52s} 4.5-5.5 m: median |err| {100 * b['median_abs_rel_error']:.3f}% "
          f"(signed {100 * b['median_rel_error']:+.3f}%, p95 {100 * b['p95_abs_rel_error']:.2f}%, "
          f"valid {100 * b['valid_fraction']:.1f}%) | SGBM alone "
          f"{100 * s['median_abs_rel_error']:.3f}% (signed {100 * s['median_rel_error']:+.3f}%)"
          f" | refine {v.seconds['refine']:.1f} s wall, total {sw.wall_s:.0f} s wall / "
          f"{sw.cpu_s:.0f} s CPU {'ok' if ok else 'MISSED'}", flush=True)


def part_stereo(args, out):
    r'''Stereo range check: the 1% bars at 5 m, what each matching step buys, and its cost

Runs harness.studies.stereo.run_stereo_check on clean images (K = 2) for the two pairs
of the bar: the MER B front hazcams (slots 12, 11) at full resolution
(1024x1024) and the Mars 2020 navcams (slots 21, 22) at quarter scale
(1280x960). For each it reports, in the band of true ranges 4.5-5.5 m, the
median |range error| (the bar: < 1%), the signed median, the 95th percentile
and the valid fraction, for the refined disparities and for StereoSGBM's
alone; and the time of each step (wall and process CPU; the machine is
shared, so CPU seconds / threads is what the wall time would be with the
cores free).

--ablation adds, for the hazcams, the settings the pipeline had before:
rectified grid at 1 px per raw px (oversample 1.0), no prefilter, no
refinement, so the gain of each change is measured rather than asserted.
--pairs hazcams or navcams runs one pair only.

Records: stereo/<pair>, stereo/ablation/<change>.
'''
    out.doc["bar_median_abs_rel_error"] = STEREO_BAR
    if "hazcams" in args.pairs:
        stereo_case(out, "hazcams-12-11", "hazcams 12/11, 1024x1024 (default settings)",
                    12, 11, 1.0)
    if "navcams" in args.pairs:
        stereo_case(out, "navcams-21-22-x0.25", "navcams 21/22, scale 0.25 (default settings)",
                    21, 22, 0.25)
    if args.ablation:
        stereo_case(out, "ablation/oversample-1.0",
                    "hazcams: oversample 1.0 (refined, prefilter 0.8)", 12, 11, 1.0,
                    oversample=1.0)
        stereo_case(out, "ablation/no-prefilter",
                    "hazcams: no prefilter (oversample 1.5, refined)", 12, 11, 1.0,
                    prefilter_px=0.0)
        stereo_case(out, "ablation/refine-radius-3", "hazcams: refinement radius 3",
                    12, 11, 1.0, refine_radius=3)
        stereo_case(out, "ablation/sgbm-only",
                    "hazcams: oversample 1.0, SGBM only (the old pipeline)", 12, 11, 1.0,
                    oversample=1.0, refine=False)


def _stereo_arguments(p):
    p.add_argument("--pairs", type=common.ids, default=["hazcams", "navcams"],
                   help="hazcams (12/11), navcams (21/22 at scale 0.25)")
    p.add_argument("--ablation", action="store_true",
                   help="also run the hazcams with the earlier settings, one change at a time")


part_stereo.repeats_warmup = (1, 0)
part_calibrators.repeats_warmup = (1, 0)
part_targets.repeats_warmup = (1, 0)

PARTS = {"poses": (part_poses, _poses_arguments),
         "compare": (part_compare, _compare_arguments),
         "detect": (part_detect, _detect_arguments),
         "jpl": (part_jpl, _jpl_arguments),
         "calibrators": (part_calibrators, _calibrators_arguments),
         "targets": (part_targets, _targets_arguments),
         "stereo": (part_stereo, _stereo_arguments)}

if __name__ == "__main__":
    sys.exit(common.main(SCRIPT, common.parser(__doc__, PARTS)))

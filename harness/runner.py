r'''Run a campaign: jobs as plain values, stages as plain functions, local or Dask executors

SYNOPSIS

    from harness.campaign import load_campaign
    from harness.jobs import expand_jobs
    from harness.runner import run_campaign, run_job

    campaign = load_campaign("campaigns/quick.toml")
    run_dir = run_campaign(campaign, "runs/x", executor="local", workers=2)
    # runs/x/run.json holds one record per camera x model x target x renderer
    # setting x calibrator model

    jobs = expand_jobs(campaign)                # [Job, ...]
    out = run_job(jobs[0])                      # {"job": key, "records": [dict, ...]}

A Job (harness.jobs) is camera x model family x target x renderer setting.
run_job() runs the stages of harness.stages (camera, poses, render, response,
detect, calibrate, compare; its docstring lists them), each a plain function on
plain values, and returns one record per calibrator model (harness.job_records).
Render, response and detect run image by image (stages.render_detect_stage): a
job holds one image at a time unless it keeps its images.
A stage that fails (the camera cannot see the target, the renderer raises, nothing is
detected, the calibrator diverges) ends the job's records with status
"failed", the stage and the reason; it never raises. Jobs are independent;
the executor (harness.executors) runs them in local processes or on a Dask
cluster, storing each job's records as soon as it ends, so an interrupted run
resumes with only the missing jobs.

run_campaign() folds the jobs of cameras that are one camera into one
(harness.jobs.group_twins; the campaign key share_identical_cameras = false
turns it off): the images are rendered once and each camera gets its own
records. Before local worker processes start, harness.warmup.warm_up()
compiles (or loads) the renderer's numba kernels once in this process.
'''

import os
import statistics
import sys
import time
import traceback
from pathlib import Path

from .executors import run_jobs, start_local_workers
from .job_records import (
    calibrator_records,
    detections_summary,
    failure_records,
    member_failures,
    save_detections,
    save_images,
)
from .jobs import expand_jobs, group_twins
from .progress import Progress, job_stage
from .records import RunStore
from .stages import (
    StageFailed,
    cached_target,
    camera_stage,
    failure_reason,
    observations_from,
    poses_stage,
    render_detect_stage,
    render_features,
    render_summary,
)


def run_job(job):
    r'''Run one job's stages -> {"job": key, "records": [record dict, ...]}

Never raises for a failing stage: the records say which stage failed and why.
A job with twins (group_twins) gives the records of each of its cameras.
'''
    members = job.members()
    job = members[0]
    entry = None
    seconds = {}
    cpu = {}    # CPU seconds (all threads of this process) per stage group: seconds["cpu"]
    c0 = time.process_time()
    features = None
    try:
        job_stage(job, "poses")
        entry, truth = camera_stage(job)
        target = cached_target(job.target)
        t0 = time.perf_counter()
        poses = poses_stage(truth, target, job.poses_n, job.poses_seed, job.poses_cover)
        seconds["poses"] = time.perf_counter() - t0
        cpu["poses"] = time.process_time() - c0
        keep = bool(job.keep_images and job.run_dir)
        job_stage(job, f"render + detect ({len(poses)} images)")
        # each image is detected as soon as it is rendered, then dropped
        out = render_detect_stage(job, truth, target, poses, keep_images=keep)
        cpu["render_detect"] = time.process_time() - c0 - cpu["poses"]
        rsecs, rversion = out.render_seconds, out.version
        seconds["render"] = float(sum(rsecs))
        # the median: the first image of a camera also builds the renderer's caches
        seconds["render_per_image"] = float(statistics.median(rsecs))
        seconds["render_first_image"] = float(rsecs[0])
        features = render_features(out.metadata)
        if out.failure is not None and out.failure.stage == "response":
            raise out.failure
        if out.response_seconds:
            seconds["response"] = float(sum(out.response_seconds.values()))
            seconds["response_stages"] = out.response_seconds
        artifacts = {}
        if keep:
            artifacts["images"] = save_images(job, out.images)
        if out.failure is not None:
            raise out.failure
        dets = out.detections
        seconds["detect"] = out.detect_seconds
        detections = detections_summary(dets)
        if keep:
            artifacts["detections"] = save_detections(job, dets, poses)
        obs = observations_from(truth, target, poses, dets)
    except StageFailed as e:
        job_stage(job, None)
        return {"job": job.key, "records": member_failures(
            members, e.stage, e.reason, status=e.status, entry=entry, seconds=seconds,
            **({"features": features} if features else {}))}
    except Exception as e:  # a bug in a stage: still a record, with where it happened
        job_stage(job, None)
        tb = traceback.extract_tb(e.__traceback__)[-1]
        return {"job": job.key, "records": member_failures(
            members, "internal", f"{failure_reason(e)} ({Path(tb.filename).name}:{tb.lineno})",
            entry=entry, seconds=seconds, **({"features": features} if features else {}))}

    render_info = render_summary(out.metadata)
    ctx = dict(obs=obs, target=target, truth=truth, entry=entry, seconds=seconds,
               detections=detections, artifacts=artifacts, rversion=rversion,
               render_info=render_info, features=features,
               render_metadata=list(out.metadata), Rt_cam_board=list(poses))
    job_stage(job, "calibrate + verdict (" + ", ".join(sorted({c for c, _, _ in job.calibrators}))
              + ")")
    fits = {} if len(members) > 1 else None
    twins = [m.camera_key for m in members[1:]]
    records = calibrator_records(job, ctx, fits, {"twins": twins} if twins else None)
    for twin in members[1:]:
        try:
            entry_t, truth_t = camera_stage(twin)
        except StageFailed as e:
            records += failure_records(twin, e.stage, e.reason, status=e.status)
            continue
        seconds_t = {"poses": 0.0, "render": 0.0,
                     "render_per_image": seconds["render_per_image"], "detect": 0.0}
        ctx_t = dict(ctx, obs=observations_from(truth_t, target, poses, dets), truth=truth_t,
                     entry=entry_t, seconds=seconds_t)
        records += calibrator_records(twin, ctx_t, fits, {"with": job.camera_key})
    # the fits and verdicts of every camera of the job, on the records of the first one
    cpu["calibrate_compare"] = time.process_time() - c0 - cpu["poses"] - cpu["render_detect"]
    for r in records:
        if r["fullname"].startswith(job.key + "/") and isinstance(r.get("seconds"), dict):
            r["seconds"] = dict(r["seconds"], cpu=dict(cpu))
    job_stage(job, None)
    return {"job": job.key, "records": records}



def adapters_from_records(records):
    r'''{"renderers": {...}, "calibrators": {...}, "libraries": {...}} seen in a run'''
    out = {"renderers": {}, "calibrators": {}, "libraries": library_versions()}
    for r in records.values():
        v = r.get("versions") or {}
        if v.get("renderer"):
            # keyed by the campaign's label when it gives one: two command renderers
            # (different programs, one name "command") keep a version each
            label = (r.get("settings") or {}).get("label") or r["renderer"]
            out["renderers"][label] = v["renderer"]
        if v.get("calibrator"):
            out["calibrators"][r["calibrator"]] = v["calibrator"]
    return out


def library_versions():
    from importlib import metadata
    out = {"python": sys.version.split()[0]}
    for dist in ("numpy", "scipy", "numba", "mrcal", "opencv-python-headless", "pycolmap",
                 "pupil-apriltags", "matplotlib", "dask", "distributed", "camval"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def run_campaign(campaign, run_dir, executor="local", workers=None, scheduler=None,
                 resume=False, progress=True, entries=None, warm=True):
    r'''Run (or resume) a campaign into run_dir; write run.json; return the run document

warm: compile the renderer's kernels once before local workers start (run_jobs).
progress: True/False, or a harness.progress.Progress: the stages (the "best" models
chosen per camera and family, the kernels' warm-up, the jobs) with ETA; a bar on a
terminal, plain lines otherwise.
The document's "execution" says how the jobs ran (and the warm-up's seconds).
'''
    bar = progress if isinstance(progress, Progress) else Progress(enabled=bool(progress))
    try:
        return _run_campaign(campaign, run_dir, executor, workers, scheduler, resume, bar,
                             entries, warm)
    finally:
        if bar is not progress:
            bar.close()


def _run_campaign(campaign, run_dir, executor, workers, scheduler, resume, bar, entries,
                  warm):
    from .campaign import resolve_best
    # the workers' fork server starts while the jobs are prepared (on the other core)
    start_local_workers(executor, workers)
    if resume:
        store = RunStore.open(run_dir)
    else:
        store = RunStore.create(run_dir, campaign.as_dict())
    if entries is None:
        entries = campaign.validate()
    # the "best" models before the jobs are expanded: with their progress, not silently
    resolve_best(campaign, entries, bar)
    jobs = expand_jobs(campaign, entries=entries, run_dir=store.dir)
    expected = {j.key for j in jobs}
    if campaign.share_identical_cameras:
        jobs = group_twins(jobs, skip=store.done_jobs())
    t0 = time.perf_counter()
    report = {}
    n = run_jobs(jobs, store, executor=executor, workers=workers, scheduler=scheduler,
                 progress=bar, warm=warm, report=report,
                 pixels=max((e.model.width * e.model.height for e in entries.values()),
                            default=None))
    wall = time.perf_counter() - t0
    records = store.records()
    stray = {k for k in store.done_jobs() if k not in expected}
    return store.assemble(adapters=adapters_from_records(records),
                          extra={"execution": {"executor": executor,
                                               "workers": None if executor == "dask"
                                               else workers or os.cpu_count(),
                                               "scheduler": scheduler,
                                               "jobs": len(expected), "jobs_run": n,
                                               "twins": {j.key: [k for _, k in j.twins]
                                                         for j in jobs if j.twins},
                                               "stray_jobs": sorted(stray),
                                               "wall_seconds": wall,
                                               "warm_up": report.get("warm_up")}})


def stage_seconds(records):
    r'''({stage: seconds summed over a run}, number of images rendered), for benchmarks

Stages: poses, render, detect (once per job), compare and calibrate:NAME (per
record). Seconds are those each worker measured, so with several workers they
sum to more than the wall time. Twins (group_twins) add only their own work.
cpu:poses, cpu:render_detect, cpu:calibrate_compare: the CPU seconds of the jobs
(all threads of a worker; a job's twins are in its calibrate_compare).
'''
    jobs = {}
    out = {"poses": 0.0, "render": 0.0, "detect": 0.0, "compare": 0.0}
    per_cal = {}
    for r in records.values():
        s = r.get("seconds") or {}
        jobs.setdefault(r["fullname"].rsplit("/", 1)[0], r)
        if "calibrate" in s:
            per_cal[r["calibrator"]] = per_cal.get(r["calibrator"], 0.0) + s["calibrate"]
        out["compare"] += s.get("compare", 0.0) or 0.0
    images = 0
    for r in jobs.values():
        s = r.get("seconds") or {}
        for k in ("poses", "render", "detect"):
            out[k] += s.get(k, 0.0) or 0.0
        for k, v in (s.get("cpu") or {}).items():
            out[f"cpu:{k}"] = out.get(f"cpu:{k}", 0.0) + v
        if s.get("render"):
            images += int(((r.get("info") or {}).get("render") or {}).get("images", 0))
    for cal, t in sorted(per_cal.items()):
        out[f"calibrate:{cal}"] = t
    return out, images

r'''A job's records: one per calibrator model, from the outputs of its stages

SYNOPSIS

    from harness.job_records import calibrator_records, failure_records

    records = failure_records(job, "render", "RendererError: ...")  # a stage failed
    records = calibrator_records(job, ctx, None, None)              # calibrate, compare

harness.runner.run_job runs a job's stages (harness.stages) up to the
observations, then calibrator_records() calibrates once per calibrator model,
compares the fit with the truth (compare_stage), keeps the difference map when
asked (maps/<fullname>.npy) and assembles each record (harness.records.Record).
A stage that fails ends the job's records with status "failed" (or
"not-applicable"), the stage and the reason: failure_records(), or
member_failures() for a job and its twins (harness.jobs.group_twins).
save_images() and save_detections() keep a job's images and detections in the
run directory (images/<job key>/).
'''

import time
import traceback
from pathlib import Path

from .jobs import TWIN_STAGES, slug
from .stages import (
    BOARD_FEATURES,
    StageFailed,
    calibrate_stage,
    camera_stage,
    compare_stage,
    downsample_map,
    failure_reason,
    response_info,
)


def _record(job, cal, model, entry, **kw):
    from .records import Record
    model_obj = getattr(entry, "model", None) if entry is not None else None
    label = ""
    if entry is not None:
        label = " ".join(str(x) for x in (getattr(entry, "rover", ""),
                                          getattr(entry, "role", ""),
                                          getattr(entry, "side", "")) if x)
    base = dict(fullname=job.fullname(cal, model), camera=job.camera_key, camera_label=label,
                model=job.family, target=job.target, renderer=job.renderer,
                settings=job.settings, calibrator=cal, calibrator_model=model,
                image_size=[model_obj.width, model_obj.height] if model_obj is not None
                else None, response=response_info(job), features=dict(BOARD_FEATURES))
    base.update(kw)
    return Record(**base).as_dict()


def failure_records(job, stage, reason, status="failed", entry=None, **kw):
    r'''One record per calibrator model of the job, all with this status and reason'''
    return [_record(job, cal, model, entry, status=status, stage=stage, reason=reason, **kw)
            for cal, model, _ in job.calibrators]


def _named_version(name, version):
    r'''"mrcal 2.5.2" from ("mrcal", "2.5.2") or ("mrcal", "mrcal 2.5.2")'''
    version = str(version or "").strip()
    if not name or version.startswith(str(name)):
        return version
    return f"{name} {version}".strip()


def member_failures(members, stage, reason, *, entry, seconds, **kw):
    r'''failure_records of a job and of each of its twins (their own catalogue entries)'''
    out = failure_records(members[0], stage, reason, entry=entry, seconds=seconds, **kw)
    for twin in members[1:]:
        try:
            entry_t = camera_stage(twin)[0]
        except StageFailed:
            entry_t = None
        out += failure_records(twin, stage, reason, entry=entry_t, **kw)
    return out


def calibrator_records(job, ctx, fits, shared):
    r'''One record per calibrator model of the job (ctx: run_job's stage outputs)

fits: None, or {(calibrator, model, options): CalibrationResult} shared by the
cameras of a twin group: a calibrator that does not read the world frame fits
once (on observations without the surveyed poses) and the other cameras reuse it.
shared: the record's info["shared"] ({"twins": [...]} for the camera that ran
the stages, {"with": key, "stages": [...]} for its twins), or None.
'''
    import dataclasses

    from harness.calibrators import uses_world_frame
    from harness.campaign import MODEL_CHOICE
    records = []
    exact_cache = {}    # this camera's exact observations and detection noise (verdict)
    for cal, model, options in job.calibrators:
        choice = options.get(MODEL_CHOICE)   # why "best" chose this model: the record's, not
        options = {k: v for k, v in options.items() if k != MODEL_CHOICE}   # the fit's
        res, info = None, shared
        try:
            if fits is not None and not uses_world_frame(cal, options):
                k = (cal, model, repr(sorted(options.items())))
                if k in fits:
                    res = fits[k]
                    info = dict(shared, stages=list(TWIN_STAGES) + ["calibrate"])
                else:
                    obs = dataclasses.replace(ctx["obs"], Rt_ref_board=None)
                    res = fits[k] = calibrate_stage(cal, obs, ctx["target"], model,
                                                    ctx["truth"], options)
            if info is not None and "with" in info and "stages" not in info:
                info = dict(info, stages=list(TWIN_STAGES))
            records.append(_calibrator_record(job, cal, model, options, res=res, shared=info,
                                              choice=choice, fits=fits,
                                              exact_cache=exact_cache, **ctx))
        except Exception as e:  # a bug after the calibrator ran: this record only
            tb = traceback.extract_tb(e.__traceback__)[-1]
            records.append(_record(job, cal, model, ctx["entry"], status="failed",
                                   stage="internal",
                                   reason=f"{failure_reason(e)} ({Path(tb.filename).name}:"
                                          f"{tb.lineno})", seconds=dict(ctx["seconds"]),
                                   detections=ctx["detections"], artifacts=ctx["artifacts"],
                                   features=ctx["features"]))
    return records


def _calibrator_record(job, cal, model, options, *, obs, target, truth, entry, seconds,
                       detections, artifacts, rversion, render_info, features, res=None,
                       shared=None, choice=None, fits=None, exact_cache=None):
    r'''Calibrate (unless res is given: a fit shared with a twin), compare, keep the map
-> one record dict'''
    import numpy as np
    reused = res is not None and shared is not None and "calibrate" in shared.get("stages", ())
    if res is None:
        res = calibrate_stage(cal, obs, target, model, truth, options)
    sec = dict(seconds, calibrate=0.0 if reused else float(res.seconds))
    info = {"iterations": int(res.iterations), "render": render_info}
    if choice is not None:
        info["model_choice"] = choice
    if (res.info or {}).get("diagnostics"):   # library messages (harness.quiet)
        info["diagnostics"] = res.info["diagnostics"]
    if shared is not None:
        info["shared"] = shared
    common = dict(residuals=res.residual_stats(), seconds=sec, detections=detections,
                  versions={"renderer": _named_version(job.renderer, rversion),
                            "calibrator": _named_version(res.library, res.library_version)},
                  info=info, features=features)
    if res.status != "ok":
        return _record(job, cal, model, entry, status=res.status, stage="calibrate",
                       reason=res.reason or "(no reason given)", artifacts=artifacts,
                       **common)
    t0 = time.perf_counter()
    try:
        params, projection, themap = compare_stage(truth, res)
    except Exception as e:
        sec["compare"] = time.perf_counter() - t0
        return _record(job, cal, model, entry, status="failed", stage="compare",
                       reason=failure_reason(e), artifacts=artifacts, **common)
    sec["compare"] = time.perf_counter() - t0
    verdict, reason = _verdict(cal, model, options, obs, target, truth, res, params,
                               projection, fits, {} if exact_cache is None else exact_cache, sec)
    arts = dict(artifacts)
    if job.keep_maps and job.run_dir and themap is not None:
        rel = Path("maps") / (slug(job.fullname(cal, model)) + ".npy")
        path = Path(job.run_dir) / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, downsample_map(themap).astype(np.float32))
        arts["map"] = str(rel)
    return _record(job, cal, model, entry, status="ok", params=params, projection=projection,
                   artifacts=arts, verdict=verdict, reason=reason, **common)


def _verdict(cal, model, options, obs, target, truth, res, params, projection, fits, cache,
             sec):
    r'''(record's verdict, reason) of an ok record (harness.verdict): the fit of the exact
observations (shared by twins like the image fits), floor / renderer / total; sec gets
"exact_fit" (the extra fit, 0 when reused) and "verdict" (its comparisons). The reason
is the floor's, in words, when the floor is far from the truth; a verdict that cannot
be computed says why in verdict["error"] and leaves the record ok.'''
    from . import verdict as vd
    t0 = time.perf_counter()
    try:
        # not shared with twins (fits=None): their exact observations agree to ~1e-12 px,
        # not bit for bit, and an ill-conditioned fit (mrcal CAHVOR of camera 17) lands
        # px apart from such differences: shared records must equal unshared ones
        exact, noise, reused = vd.exact_fit(cal, model, options, obs, target, truth, cache,
                                            None, start=res)
        sec["exact_fit"] = 0.0 if reused else float(exact.seconds)
        t1 = time.perf_counter()
        v = vd.assess(truth, res, exact, noise, params, projection, obs=obs)
        sec["verdict"] = time.perf_counter() - t1
    except Exception as e:  # the record's own figures stand; its verdict says why not
        tb = traceback.extract_tb(e.__traceback__)[-1]
        sec["verdict"] = time.perf_counter() - t0
        return {"error": f"{failure_reason(e)} ({Path(tb.filename).name}:{tb.lineno})"}, ""
    return v, "; ".join(x for x in (v.get("floor_reason"), v.get("disagree_reason")) if x)


def save_images(job, images):
    from renderers.png import save_png16
    rels = []
    for i, im in enumerate(images):
        rel = Path("images") / slug(job.key) / f"pose{i}.png"
        (Path(job.run_dir) / rel).parent.mkdir(parents=True, exist_ok=True)
        save_png16(Path(job.run_dir) / rel, im)
        rels.append(str(rel))
    return rels


def save_detections(job, dets, poses):
    import numpy as np
    rel = Path("images") / slug(job.key) / "detections.npz"
    np.savez_compressed(Path(job.run_dir) / rel,
                        q=np.stack([np.asarray(d.q, dtype=np.float64) for d in dets]),
                        Rt_cam_board=np.stack([np.asarray(p) for p in poses]))
    return str(rel)

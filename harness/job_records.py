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

from .campaign import VERDICT_MODES
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


def _failure_reason(res, truth, cal):
    r'''A failed fit's reason, with what its model cannot represent of the truth where that
can be why it ended above max_rms (mrcal CAHV on a theta = 88 deg camera read "diverged: RMS
residual 1.02 px": its best misfit, not a divergence)'''
    from . import verdict as vd
    reason = res.reason or "(no reason given)"
    if res.status != "failed" or not reason.startswith("diverged: RMS residual"):
        return reason
    causes = vd.unrepresentable(truth, cal)
    return (f"{reason}; {'; '.join(causes)}: it may have converged to the best misfit its "
            f"model allows" if causes else reason)


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
once (on observations without the surveyed poses) and the other cameras reuse it,
with its comparison and verdict (_calibrator_record: computed in the camera frame,
the same bits for every twin).
shared: the record's info["shared"] ({"twins": [...]} for the camera that ran
the stages, {"with": key, "stages": [...]} for its twins), or None.
'''
    import dataclasses

    from harness.calibrators import uses_world_frame
    from harness.campaign import MODEL_CHOICE, POSE_COUNT

    from . import verdict as vd
    from .jobs import camera_frame_model
    records = []
    exact_caches = {}   # per pose count: this camera's exact observations and detection
    # the job's detections are the verdict's reference corners: not rendered again
    own_reference = vd.is_reference_render(job.renderer, job.settings, job.response)
    # the truth in its own camera frame: what fits that do not read the world frame are
    # compared with (one object for the camera's records: the comparisons' memos)
    camera = camera_frame_model(ctx["truth"])
    for cal, model, options in job.calibrators:     # noise (verdict)
        choice = options.get(MODEL_CHOICE)   # why "best" chose this model: the record's, not
        n_poses = options.get(POSE_COUNT)    # the fit's; so is its pose count
        options = {k: v for k, v in options.items() if k not in (MODEL_CHOICE, POSE_COUNT)}
        res, info, k = None, shared, None
        cctx = pose_subset(ctx, n_poses)
        exact_cache = exact_caches.setdefault(cctx["poses_used"]["n"], {})
        if own_reference:
            exact_cache.setdefault("reference", cctx["obs"].q)
        try:
            if fits is not None and not uses_world_frame(cal, options):
                k = (cal, model, repr(sorted(options.items())), cctx["poses_used"]["n"])
                if k in fits:
                    res = fits[k]
                    info = dict(shared, stages=list(TWIN_STAGES) + ["calibrate"])
                else:
                    obs = dataclasses.replace(cctx["obs"], Rt_ref_board=None)
                    res = fits[k] = calibrate_stage(cal, obs, cctx["target"], model,
                                                    cctx["truth"], options)
            if info is not None and "with" in info and "stages" not in info:
                info = dict(info, stages=list(TWIN_STAGES))
            records.append(_calibrator_record(job, cal, model, options, res=res, shared=info,
                                              choice=choice, fits=fits, fit_key=k,
                                              camera=camera, exact_cache=exact_cache,
                                              **cctx))
        except Exception as e:  # a bug after the calibrator ran: this record only
            tb = traceback.extract_tb(e.__traceback__)[-1]
            records.append(_record(job, cal, model, ctx["entry"], status="failed",
                                   stage="internal",
                                   reason=f"{failure_reason(e)} ({Path(tb.filename).name}:"
                                          f"{tb.lineno})", seconds=dict(ctx["seconds"]),
                                   detections=ctx["detections"], artifacts=ctx["artifacts"],
                                   features=ctx["features"]))
    return explain_against_reference(records)


# a record's total projection difference this many times the reference calibrator's
# (jpl) is explained in its reason: issue 15's bar (within 5x of jpl, or say why)
FAR_FACTOR = 5.0
REFERENCE_CALIBRATOR = "jpl"


def explain_against_reference(records):
    r'''records, where an ok record's projection difference (rotation RMS) exceeds
FAR_FACTOR x that of the ok jpl record of the same job gets a sentence in its reason
saying why, in words, from its verdict: the floor (its fit of the exact observations
is already that far from the truth: the model or the calibrator, not the images), or
the renderer part (its fits of the images and of the exact observations differ: the
detection errors move this model's parameters that far), and the poses and model it
fitted. Records without a jpl record, or jpl failed: unchanged.'''
    ref = next((r for r in records if r.get("calibrator") == REFERENCE_CALIBRATOR
                and r.get("status") == "ok"), None)
    ref_rms = ((ref or {}).get("projection") or {}).get("rms")
    if not ref_rms:
        return records
    for r in records:
        rms = (r.get("projection") or {}).get("rms")
        if r is ref or r.get("status") != "ok" or rms is None or rms <= FAR_FACTOR * ref_rms:
            continue
        r["reason"] = "; ".join(x for x in (r.get("reason"), _far_sentence(r, rms, ref_rms))
                                if x)
    return records


def _far_sentence(r, rms, ref_rms):
    v = r.get("verdict") if isinstance(r.get("verdict"), dict) else {}
    info = r.get("info") or {}
    n = (info.get("poses") or {}).get("n")
    what = f"{r['calibrator']} {r['calibrator_model']}"
    head = (f"{what} is {rms / ref_rms:.3g}x jpl's projection difference ({rms:.3g} vs "
            f"{ref_rms:.3g} px RMS)")
    floor = ((v.get("floor") or {}).get("projection") or {}).get("rms")
    rend = ((v.get("renderer") or {}).get("projection") or {}).get("rms")
    noise = (v.get("detection_noise") or {}).get("rms")
    if floor is not None and floor > 0.5 * rms:
        why = (f"because the model cannot get closer even from exact detections: its fit of "
               f"the exact observations is already {floor:.3g} px from the truth")
    elif rend is not None and rend > 0.5 * rms:
        why = (f"because the detection errors ({noise:.3g} px RMS) move this model's "
               f"parameters: its fit of the images lies {rend:.3g} px from its fit of the "
               f"exact observations (floor {floor if floor is None else format(floor, '.3g')} "
               f"px), so {n if n else 'its'} poses do not constrain it as well as jpl's "
               f"known board poses constrain jpl")
    else:
        why = "for no single cause: floor and renderer part are each below half of it"
        if floor is not None and rend is not None:
            why += f" (floor {floor:.3g} px, renderer part {rend:.3g} px)"
    poses = f", fitted on {n} poses" if n else ""
    return f"{head}{poses}, {why}"


def detections_summary(dets):
    r'''The record's detections: counts, the failed poses with the detector's reasons, the
corners a refiner dropped, and the images' clipped pixels and column bleed

{"n_expected", "n_found", "per_pose", "failed_poses", "failed_reasons" (by pose index),
"corners_dropped" (corner targets: {reason: count} per pose, where any),
"saturation" (targets.saturation.summarise of the images' info["saturation"], where an
image has pixels at full scale)}'''
    from targets.saturation import summarise
    out = {"n_expected": int(sum(d.n_expected for d in dets)),
           "n_found": int(sum(d.n_found for d in dets)),
           "per_pose": [int(d.n_found) for d in dets],
           "failed_poses": [i for i, d in enumerate(dets) if d.status != "ok"],
           # why, in the detector's words, by pose index
           "failed_reasons": {str(i): d.reason for i, d in enumerate(dets)
                              if d.status != "ok"}}
    # corner targets: the corners the refiner dropped, {reason: count} per pose
    dropped = [dict(d.info.get("corners_dropped") or {}) for d in dets]
    if any(dropped):
        out["corners_dropped"] = dropped
    saturation = summarise([d.info.get("saturation") for d in dets])
    if saturation is not None:
        out["saturation"] = saturation
    return out


def saturation_reason(detections):
    r'''The sentence of a record whose images bloom (targets.saturation.sentence), else ""'''
    from targets.saturation import sentence
    return sentence((detections or {}).get("saturation"))


def pose_subset(ctx, n):
    r'''run_job's stage outputs (ctx) for a calibrator that fits the first n poses

n None (or every pose): ctx itself. Otherwise the observations, the detections'
summary and the renders' summary cover the first n poses only (the campaign's
shared poses: a calibrator at the campaign's n gets the record it had without the
extra poses; the seconds stay those of the job), and so do the planned board poses
(ctx["Rt_cam_board"], when run_job gives them). ctx["poses_used"] =
{"n": poses fitted, "rendered": poses of the job} (the record's info["poses"]).
'''
    obs = ctx["obs"]
    total = int(obs.q.shape[0])
    out = dict(ctx)
    out.pop("render_metadata", None)
    if n is None or n >= total:
        out["poses_used"] = {"n": total, "rendered": total}
        return out
    import dataclasses

    from .stages import render_summary
    n = int(n)
    out["obs"] = dataclasses.replace(
        obs, q=obs.q[:n],
        p_board=obs.p_board[:n] if getattr(obs.p_board, "ndim", 2) == 3 else obs.p_board,
        Rt_ref_board=None if obs.Rt_ref_board is None else obs.Rt_ref_board[:n],
        corner_model=None if obs.corner_model is None else obs.corner_model[:n],
        corner_blur_px=None if obs.corner_blur_px is None else obs.corner_blur_px[:n],
        corner_spans=None if obs.corner_spans is None else obs.corner_spans[:n],
        corner_sigma_px=None if obs.corner_sigma_px is None else obs.corner_sigma_px[:n])
    if ctx.get("Rt_cam_board") is not None:
        out["Rt_cam_board"] = ctx["Rt_cam_board"][:n]
    det = dict(ctx["detections"])
    per_pose = list(det.get("per_pose", []))
    if len(per_pose) == total:
        # every image of a job expects the same points (one target)
        det["n_expected"] = int(det["n_expected"]) * n // total
        det["per_pose"] = per_pose[:n]
        det["n_found"] = int(sum(per_pose[:n]))
        det["failed_poses"] = [i for i in det.get("failed_poses", []) if i < n]
        if "failed_reasons" in det:
            det["failed_reasons"] = {k: v for k, v in det["failed_reasons"].items()
                                     if int(k) < n}
        if "corners_dropped" in det:
            det["corners_dropped"] = det["corners_dropped"][:n]
        if "saturation" in det:
            from targets.saturation import subset
            sat = subset(det["saturation"], n)
            if sat is None:
                del det["saturation"]
            else:
                det["saturation"] = sat
    out["detections"] = det
    metas = ctx.get("render_metadata")
    if metas is not None and len(metas) == total:
        out["render_info"] = render_summary(metas[:n])
    out["poses_used"] = {"n": n, "rendered": total}
    return out


def _calibrator_record(job, cal, model, options, *, obs, target, truth, entry, seconds,
                       detections, artifacts, rversion, render_info, features, res=None,
                       shared=None, choice=None, fits=None, fit_key=None, camera=None,
                       exact_cache=None, poses_used=None, Rt_cam_board=None):
    r'''Calibrate (unless res is given: a fit shared with a twin), compare, keep the map
-> one record dict

A fit that does not read the world frame (res.world_frame False) is compared with the
truth in its own camera frame (camera: harness.jobs.camera_frame_model(truth)), and so
is its verdict: the same numbers, to the last bits of the rotation into that frame,
and the same bits for twins, whose camera-frame models are the same. A twin's record of
a shared fit (fits, fit_key: calibrator_records) then takes the comparison and verdict
computed for the first camera with those bits (its seconds 0, info["shared"]["stages"]
naming them).'''
    import copy

    import numpy as np
    reused = res is not None and shared is not None and "calibrate" in shared.get("stages", ())
    if res is None:
        res = calibrate_stage(cal, obs, target, model, truth, options)
    sec = dict(seconds, calibrate=0.0 if reused else float(res.seconds))
    info = {"iterations": int(res.iterations), "render": render_info}
    if poses_used is not None and poses_used["n"] != poses_used["rendered"]:
        info["poses"] = dict(poses_used)     # fitted on the first n of the job's poses
    elif poses_used is not None:
        info["poses"] = {"n": poses_used["n"]}
    if choice is not None:
        info["model_choice"] = choice
    if (res.info or {}).get("diagnostics"):   # library messages (harness.quiet)
        info["diagnostics"] = res.info["diagnostics"]
    if (res.info or {}).get("crawl"):   # the fit's restarts ran out in a misfit (mrcal)
        info["crawl"] = res.info["crawl"]
    if shared is not None:
        info["shared"] = shared
    common = dict(residuals=res.residual_stats(), seconds=sec, detections=detections,
                  versions={"renderer": _named_version(job.renderer, rversion),
                            "calibrator": _named_version(res.library, res.library_version)},
                  info=info, features=features)
    # images that bloom move the detections: every record of them says so (its reason)
    bloom = saturation_reason(detections)
    if res.status != "ok":
        return _record(job, cal, model, entry, status=res.status, stage="calibrate",
                       reason=_joined(_failure_reason(res, truth, cal), bloom),
                       artifacts=artifacts, **common)
    frame = truth if res.world_frame or camera is None else camera
    key = None
    if fits is not None and fit_key is not None and frame is camera:
        key = ("compare+verdict", fit_key, _bits_key(camera, Rt_cam_board, obs))
    hit = fits.get(key) if key is not None else None
    if hit is not None and hit[0] is res:
        params, projection, themap, verdict, reason = copy.deepcopy(hit[1:])
        sec.update(compare=0.0, exact_fit=0.0, exact_observations=0.0, verdict=0.0)
        info["shared"] = dict(shared, stages=list(shared.get("stages", ()))
                              + ["compare", "verdict"])
    else:
        t0 = time.perf_counter()
        try:
            params, projection, themap = compare_stage(frame, res)
        except Exception as e:
            sec["compare"] = time.perf_counter() - t0
            return _record(job, cal, model, entry, status="failed", stage="compare",
                           reason=failure_reason(e), artifacts=artifacts, **common)
        sec["compare"] = time.perf_counter() - t0
        verdict, reason = _verdict(cal, model, options, obs, target, truth, frame, res,
                                   params, projection,
                                   {} if exact_cache is None else exact_cache, sec,
                                   Rt_cam_board, job.verdict_modes)
        if key is not None:
            fits[key] = (res,) + copy.deepcopy((params, projection, themap, verdict, reason))
    arts = dict(artifacts)
    if job.keep_maps and job.run_dir and themap is not None:
        rel = Path("maps") / (slug(job.fullname(cal, model)) + ".npy")
        path = Path(job.run_dir) / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, downsample_map(themap).astype(np.float32))
        arts["map"] = str(rel)
    return _record(job, cal, model, entry, status="ok", params=params, projection=projection,
                   artifacts=arts, verdict=verdict, reason=_joined(reason, bloom), **common)


def _joined(*parts):
    return "; ".join(p for p in parts if p)


def _bits_key(camera, Rt_cam_board, obs):
    r'''Every bit a camera-frame comparison and verdict read besides the fit: the
camera-frame model, the planned poses and the detections'''
    import hashlib

    import numpy as np

    from .compare import _model_key
    h = hashlib.sha256(repr(_model_key(camera)).encode())
    for a in (Rt_cam_board, obs.q, obs.p_board, obs.corner_model, obs.corner_blur_px):
        h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _verdict(cal, model, options, obs, target, truth, frame, res, params, projection, cache,
             sec, Rt_cam_board=None, modes=VERDICT_MODES):
    r'''(record's verdict, reason) of an ok record (harness.verdict): the fit of the exact
observations, floor / renderer / total against frame (the truth, or for a fit that
does not read the world frame the truth in its camera frame: _calibrator_record); sec
gets "exact_fit" (the extra fit, 0 when reused: a twin's fit that does not read the
world frame, harness.verdict.exact_fit), "exact_observations" (computing them: once
per camera and pose count, ~0 for the job's other calibrators and for twins) and
"verdict" (its comparisons and scatter). The reason is the floor's, in words, when the
floor is far from the truth; a verdict that cannot be computed says why in
verdict["error"] and leaves the record ok. modes: the floor's and renderer's
projection-difference modes (the campaign's verdict_modes).'''
    from . import verdict as vd
    t0 = time.perf_counter()
    try:
        exact, noise, reused = vd.exact_fit(cal, model, options, obs, target, truth, cache,
                                            start=res, Rt_cam_board=Rt_cam_board)
        t1 = time.perf_counter()
        sec["exact_fit"] = 0.0 if reused else float(exact.seconds)
        sec["exact_observations"] = max(0.0, t1 - t0 - sec["exact_fit"])
        v = vd.assess(frame, res, exact, noise, params, projection, obs=obs, modes=modes)
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

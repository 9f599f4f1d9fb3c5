r'''Run a campaign: jobs as plain values, stages as plain functions, local or Dask executors

SYNOPSIS

    from harness.campaign import load_campaign
    from harness.runner import expand_jobs, run_campaign

    campaign = load_campaign("campaigns/quick.toml")
    run_dir = run_campaign(campaign, "runs/x", executor="local", workers=2)
    # runs/x/run.json holds one record per camera x model x target x renderer
    # setting x calibrator model

    jobs = expand_jobs(campaign)                # [Job, ...]
    out = run_job(jobs[0])                      # {"job": key, "records": [dict, ...]}

A Job is camera x model family x target x renderer setting. run_job() runs the
stages, each a plain function on plain values:

    camera_stage     catalogue entry -> truth model (truncated to the family)
    poses_stage      truth, target -> [Rt_cam_board] (targets.poses.plan_poses)
    render_stage     truth, pattern, poses -> [RenderResult]
    response_stage   images -> images through the job's camera-response profile
                     (renderers/response.py; skipped for a clean job)
    detect_stage     images, target -> [Detection]
    calibrate_stage  detections -> CalibrationResult, once per calibrator model
    compare_stage    truth, CalibrationResult -> parameter errors, projection difference

and returns one record per calibrator model. A stage that fails (the camera
cannot see the target, the renderer raises, nothing is detected, the
calibrator diverges) ends the job's records with status "failed", the stage
and the reason; it never raises. Jobs are independent; the executor runs them
in local processes (concurrent.futures, forkserver) or on a Dask cluster
(--executor dask --scheduler ADDRESS). Each job's records are stored in the
run directory as soon as the job ends, so an interrupted run resumes with only
the missing jobs.

Cameras that are one camera (twins): a catalogue slot derived from another by a
rigid motion (a stereo partner, a rear-facing copy) images every point of its
camera frame at the same pixel. For a renderer that is exact in the camera
frame (camera_frame_exact, the ray caster) and a clean job, its poses, images
and detections are those of its twin, and so is the fit of every calibrator
that does not read the world frame. run_campaign() folds such jobs into one
(group_twins; the campaign key share_identical_cameras = false turns it off):
the images are rendered once, the world-frame calibrators (jpl) fit each
camera, and each camera gets its own records, compared with its own truth,
with info["shared"] saying what was computed for which camera.

Before local worker processes start, warm_up() compiles (or loads) the
renderer's numba kernels once in this process, so the workers load the
cached kernels instead of each compiling them.
'''

import hashlib
import math
import os
import pickle
import statistics
import sys
import time
import traceback
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from reference_models.errors import CamvalError

from .records import RunStore, jsonable, make_fullname, settings_label

FAMILY_ORDER = ("CAHV", "CAHVOR", "CAHVORE")
MAP_SIZE = 96            # longest side of a stored projection-difference map
EXECUTORS = ("local", "dask")


class RunnerError(CamvalError):
    '''Bad runner options (unknown executor, missing scheduler address).'''


@dataclass(frozen=True)
class Job:
    r'''One camera x model family x target x renderer setting, and the calibrators to run

key:          camera/model/target/renderer[settings] (the records' fullname prefix)
camera:       the campaign's camera spec (slot id, extra name, model file)
camera_key:   the catalogue key used in fullnames
calibrators:  ((name, model, options), ...)
run_dir:      where images and maps are kept (None: keep nothing)
response:     the camera-response profile's configuration ({} : clean)
response_name: the profile's name ("" : the campaign has no profiles)
seed:         the campaign's noise seed
twins:        ((camera spec, camera key), ...) of other cameras that are this one
              (group_twins): run_job() gives their records too
'''

    key: str
    camera: str
    camera_key: str
    family: str
    target: str
    renderer: str
    settings: dict
    calibrators: tuple
    poses_n: int = 6
    poses_seed: int = 0
    keep_images: bool = False
    keep_maps: bool = False
    catalogue: str = None
    run_dir: str = None
    cost: float = 1.0
    response: dict = field(default_factory=dict)
    response_name: str = ""
    seed: int = 0
    twins: tuple = ()

    def fullname(self, calibrator, model):
        return make_fullname(self.camera_key, self.family, self.target, self.renderer,
                             self.settings, calibrator, model)

    def members(self):
        r'''[this job, then one job per twin camera] (each with its own key, no twins)'''
        import dataclasses
        out = [dataclasses.replace(self, twins=())]
        for spec, key in self.twins:
            out.append(dataclasses.replace(
                self, camera=spec, camera_key=key, twins=(),
                key=key + self.key[len(self.camera_key):]))
        return out


def expand_jobs(campaign, entries=None, run_dir=None):
    r'''The campaign's jobs, in a stable order (camera, model, target, renderer, setting)

entries: {camera spec: CatalogueEntry} from campaign.validate() (validated here if None).
'''
    if entries is None:
        entries = campaign.validate()
    jobs = []
    for spec in campaign.cameras:
        entry = entries[spec]
        key = camera_key(entry, spec)
        w, h = entry.model.width, entry.model.height
        for family in campaign.models:
            for target in campaign.targets:
                for r in campaign.renderers:
                    for s, prof in zip(r.settings(campaign.responses),
                                       r.profiles(campaign.responses), strict=True):
                        cals = tuple((c.name, m, dict(c.options)) for c in campaign.calibrators
                                     for m in c.models_for(family))
                        jobs.append(Job(
                            key=f"{key}/{family}/{target}/{r.name}[{settings_label(s)}]",
                            camera=spec, camera_key=key, family=family, target=target,
                            renderer=r.name, settings=s, calibrators=cals,
                            poses_n=campaign.poses_n, poses_seed=campaign.poses_seed,
                            keep_images=campaign.keep_images, keep_maps=campaign.keep_maps,
                            catalogue=campaign.catalogue,
                            run_dir=str(run_dir) if run_dir is not None else None,
                            cost=float(w * h) * (1.0 + 0.02 * s["spp"]),
                            response=dict(prof.config) if prof is not None else {},
                            response_name=prof.name if prof is not None else "",
                            seed=int(getattr(campaign, "seed", 0))))
    keys = [j.key for j in jobs]
    if len(set(keys)) != len(keys):
        dup = sorted({k for k in keys if keys.count(k) > 1})
        raise RunnerError(f"the campaign lists the same job twice: {dup[0]} (a camera named "
                          f"twice under different specs?)")
    return jobs


def camera_key(entry, spec):
    r'''The camera's part of a fullname: "15", "SuperCam", "file-<name>" (never a path)'''
    key = str(getattr(entry, "key", None) or spec)
    if getattr(entry, "kind", "") == "file" or "/" in key:
        key = "file-" + _slug(Path(key).name)
    return key


# --- cameras that are one camera ------------------------------------------------
# twins project every camera-frame point to within this many px of the same pixel
TWIN_TOLERANCE_PX = 1e-9
TWIN_GRID = 17
TWIN_RANGES_M = (0.05, 0.5, 5.0, 500.0)
# what a twin takes from the camera that ran its job
TWIN_STAGES = ("poses", "render", "detect")


def same_camera(a, b, tolerance_px=TWIN_TOLERANCE_PX):
    r'''Whether models a and b image every point of their own camera frames alike

SYNOPSIS

    same_camera(slot8.model, slot7.model)   # True: slot 7 is slot 8 yawed 180 degrees

Compared: the class, the image size, and the pixels of points of a
TWIN_GRID x TWIN_GRID grid of a's pixels (corners included) unprojected by a
to TWIN_RANGES_M (so a moving entrance pupil counts), carried from a's camera
frame (Rt_ref_cam) into b's and projected by b: each within tolerance_px of
the pixel it came from. Then a renderer exact in the camera frame gives b
the images of a for the same camera-frame board poses.
'''
    import numpy as np
    if type(a) is not type(b) or (a.width, a.height) != (b.width, b.height):
        return False
    if getattr(a, "linearity", None) != getattr(b, "linearity", None):
        return False
    x = np.linspace(-0.5, a.width - 0.5, TWIN_GRID)
    y = np.linspace(-0.5, a.height - 0.5, TWIN_GRID)
    q = np.stack(np.meshgrid(x, y), axis=-1).reshape(-1, 2)
    try:
        origin, v = a.unproject(q)
        Ra, Rb = a.Rt_ref_cam(), b.Rt_ref_cam()
        for r in TWIN_RANGES_M:
            p_cam = (origin + r * v - Ra[3]) @ Ra[:3]
            qa = a.project(origin + r * v)
            qb = b.project(p_cam @ Rb[:3].T + Rb[3])
            if not (np.all(np.isfinite(qa)) and np.all(np.isfinite(qb))):
                return False
            if np.max(np.abs(qb - qa)) > tolerance_px:
                return False
    except (CamvalError, ValueError, FloatingPointError):
        return False
    return True


def camera_frame_exact(renderer_name):
    r'''Whether the renderer declares that it renders exactly in the camera frame (then
two cameras for which same_camera() holds get the same images)'''
    try:
        from renderers.base import renderer_class
        return bool(getattr(renderer_class(renderer_name), "camera_frame_exact", False))
    except CamvalError:
        return False


def group_twins(jobs, skip=()):
    r'''Jobs with the jobs of twin cameras folded into the first of them

SYNOPSIS

    jobs = group_twins(expand_jobs(campaign), skip=store.done_jobs())
    jobs[i].twins       # ((camera spec, camera key), ...) it also gives records for

Two jobs are folded when everything but the camera is the same, the job is
clean (no camera-response profile: noise differs per camera), the renderer is
camera_frame_exact(), and same_camera() holds for their truths. Jobs in skip
(finished in an earlier run) and jobs whose camera stage fails are left
alone. The order of the remaining jobs is kept.
'''
    import dataclasses
    skip = set(skip)
    exact = {}
    leaders = []      # [job, truth, [twins]]
    out = []
    for job in jobs:
        if job.key in skip or job.response or job.twins:
            out.append(job)
            continue
        if job.renderer not in exact:
            exact[job.renderer] = camera_frame_exact(job.renderer)
        try:
            truth = camera_stage(job)[1] if exact[job.renderer] else None
        except StageFailed:
            truth = None
        if truth is None:
            out.append(job)
            continue
        sig = _twin_signature(job)
        for lead in leaders:
            if _twin_signature(lead[0]) == sig and same_camera(lead[1], truth):
                lead[2].append((job.camera, job.camera_key))
                break
        else:
            leaders.append([job, truth, []])
            out.append(leaders[-1])
    return [dataclasses.replace(x[0], twins=tuple(x[2]),
                                cost=x[0].cost * (1.0 + 0.25 * len(x[2])))
            if isinstance(x, list) else x for x in out]


def _twin_signature(job):
    return (job.family, job.target, job.renderer, settings_label(job.settings),
            repr(job.calibrators), job.poses_n, job.poses_seed, job.keep_images,
            job.keep_maps, job.catalogue, job.run_dir, job.seed)


# --- per-process caches (a worker runs many jobs) -----------------------------
_CACHE = {}


def _cached(kind, key, make):
    k = (kind, key)
    if k not in _CACHE:
        _CACHE[k] = make()
    return _CACHE[k]


def _catalogue(overlay):
    def make():
        from reference_models.catalogue import load_catalogue
        return load_catalogue(overlay=overlay) if overlay else load_catalogue()
    return _cached("catalogue", overlay, make)


def _target(name):
    def make():
        from targets.boards import load_target
        return load_target(name)
    return _cached("target", name, make)


def _renderer(name):
    def make():
        from renderers.base import get_renderer
        return get_renderer(name)
    return _cached("renderer", name, make)


# --- stages ---------------------------------------------------------------------
class StageFailed(Exception):
    r'''A stage that cannot go on: becomes records with status (failed / not-applicable)'''

    def __init__(self, stage, reason, status="failed"):
        super().__init__(reason)
        self.stage = stage
        self.reason = reason
        self.status = status


def _reason(e):
    msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
    if isinstance(e, CamvalError):
        return msg or type(e).__name__
    return f"{type(e).__name__}: {msg}" if msg else type(e).__name__


def camera_stage(job):
    r'''-> (CatalogueEntry, truth model of the job's family)'''
    from reference_models.cahvore import truncate
    try:
        entry = _catalogue(job.catalogue).get(job.camera)
    except CamvalError as e:
        raise StageFailed("camera", _reason(e)) from None
    have = entry.model.family
    if FAMILY_ORDER.index(job.family) > FAMILY_ORDER.index(have):
        raise StageFailed("camera", f"camera {job.camera_key} is a {have}; a {job.family} "
                                    f"cannot be derived from it", status="not-applicable")
    return entry, truncate(entry.model, job.family)


def poses_stage(truth, target, n, seed):
    r'''-> [Rt_cam_board (4,3)] * n'''
    from targets.poses import plan_poses
    try:
        return plan_poses(truth, target, n=n, seed=seed)
    except Exception as e:  # NotVisibleError and any planner bug alike end this job only
        raise StageFailed("poses", _reason(e)) from None


def render_stage(renderer_name, truth, target, poses, settings):
    r'''-> ([RenderResult], seconds per image (list), renderer version)

A renderer that cannot render this camera by design (RendererNotApplicable: a
field of view no pinhole warp covers) makes the job not-applicable.'''
    from renderers.base import RendererNotApplicable, RenderSettings
    try:
        renderer = _renderer(renderer_name)
        rs = RenderSettings(spp=int(settings["spp"]), adaptive=bool(settings["adaptive"]),
                            options=dict(settings.get("options") or {}))
        pattern = target.pattern()
        results, secs = [], []
        for Rt in poses:
            t0 = time.perf_counter()
            results.append(renderer.render(truth, pattern, Rt, rs))
            secs.append(time.perf_counter() - t0)
        version = renderer.version() if hasattr(renderer, "version") else ""
    except Exception as e:
        status = "not-applicable" if isinstance(e, RendererNotApplicable) else "failed"
        raise StageFailed("render", _reason(e), status=status) from None
    return results, secs, version


def noise_seed(job, i_image):
    r'''The noise seed of image i of a job: [campaign seed, profile seed, sha256(job key)
as four 32-bit words, i] (numpy.random.default_rng takes the list)'''
    d = hashlib.sha256(job.key.encode()).digest()
    words = [int.from_bytes(d[k:k + 4], "little") for k in range(0, 16, 4)]
    return [int(job.seed), int((job.response or {}).get("seed", 0)), *words, int(i_image)]


def response_info(job):
    r'''The record's "response" entry: profile, stages with their parameters, seeds

Deterministic (no timings); the same for every record of the job, whether it
ran or failed earlier. A clean job records {"profile", "stages": []} only.
'''
    cfg = job.response or {}
    info = {"profile": job.response_name, "stages": [],
            "seed": {"campaign": int(job.seed), "profile": int(cfg.get("seed", 0)),
                     "job_sha256": hashlib.sha256(job.key.encode()).hexdigest()[:16]}}
    try:
        from renderers.response import ResponseChain
        chain = ResponseChain.from_config(cfg)
    except Exception as e:  # reported by response_stage as the job's failure
        info["error"] = _reason(e)
        return jsonable(info)
    if not chain.stages:   # nothing drawn: the seeds play no part
        return {"profile": job.response_name, "stages": []}
    info["full_well_e"] = chain.full_well_e
    info["stages"] = [{"stage": st.name, "params": st.describe()} for st in chain.stages]
    return jsonable(info)


def response_stage(job, truth, images):
    r'''-> (images through the job's camera response, {stage: seconds summed over images})

The seconds also hold "setup": building the chain (imports, kernels). A clean
job (no stages) returns the images unchanged and {}. Image i's noise
comes from noise_seed(job, i): the same job gives the same images bit for bit.
'''
    cfg = job.response or {}
    t0 = time.perf_counter()
    try:
        from renderers.response import ResponseChain
        chain = ResponseChain.from_config(cfg)
        if not chain.stages:
            return images, {}
        out, secs = [], {"setup": time.perf_counter() - t0}
        for i, im in enumerate(images):
            r = chain.apply(im, model=truth, seed=noise_seed(job, i))
            out.append(r.image)
            for st in r.stages:
                secs[st["stage"]] = secs.get(st["stage"], 0.0) + float(st["seconds"])
    except Exception as e:
        raise StageFailed("response", _reason(e)) from None
    return out, secs


# what a renderer modelled beyond geometry; a board (targets.pattern.Pattern) is
# flat albedo under no light: none of them
BOARD_FEATURES = {"shading": False, "texture": False, "shadows": False}


def render_features(metadatas):
    r'''{"shading", "texture", "shadows"}: any render of the job that reported the feature

A renderer may report metadata["features"] = {name: bool}; one that does not
drew a board pattern, which needs none.
'''
    out = dict(BOARD_FEATURES)
    for m in metadatas:
        f = m.get("features") if isinstance(m, dict) else None
        if isinstance(f, dict):
            for k, v in f.items():
                out[str(k)] = bool(out.get(str(k), False) or v)
    return out


def detect_stage(images, target):
    r'''-> ([Detection], seconds)'''
    from targets.detect import detect
    t0 = time.perf_counter()
    try:
        dets = [detect(im, target) for im in images]
    except Exception as e:
        raise StageFailed("detect", _reason(e)) from None
    secs = time.perf_counter() - t0
    if not any(d.n_found for d in dets):
        reasons = sorted({d.reason for d in dets if d.reason})
        raise StageFailed("detect", "the target was found in none of the "
                                    f"{len(dets)} images" + (f": {reasons[0]}" if reasons else ""))
    return dets, secs


def observations_from(truth, target, poses, detections):
    r'''Detections -> harness.calibrators Observations (board poses surveyed, as the paper)'''
    import mrcal
    import numpy as np

    from harness.calibrators.base import Observations
    q = np.stack([np.asarray(d.q, dtype=np.float64) for d in detections])
    Rt_ref_cam = truth.Rt_ref_cam()
    Rt_ref_board = np.stack([mrcal.compose_Rt(Rt_ref_cam, np.asarray(Rt, dtype=np.float64))
                             for Rt in poses])
    ids = target.point_ids() if hasattr(target, "point_ids") else None
    return Observations(q=q, p_board=np.asarray(target.points(), dtype=np.float64),
                        imagersize=(truth.width, truth.height), Rt_ref_board=Rt_ref_board,
                        point_ids=ids)


def calibrate_stage(name, obs, target, model, truth, options):
    r'''-> CalibrationResult (never raises: a crash is a failed result)'''
    from harness.calibrators import calibrate
    from harness.calibrators.base import CalibrationResult
    t0 = time.perf_counter()
    try:
        return calibrate(name, obs, target, model, truth=truth, **options)
    except Exception as e:
        return CalibrationResult(calibrator=name, model_name=model, status="failed",
                                 reason=_reason(e), seconds=time.perf_counter() - t0)


def _downsample(m, size=MAP_SIZE):
    import numpy as np
    m = np.asarray(m, dtype=np.float64)
    if m.ndim == 3:  # (H,W,2) difference vectors -> magnitudes
        m = np.linalg.norm(m, axis=-1)
    step = max(1, math.ceil(max(m.shape) / size))
    if step == 1:
        return m
    H, W = (m.shape[0] // step) * step, (m.shape[1] // step) * step
    if H == 0 or W == 0:
        return m[::step, ::step]
    blocks = m[:H, :W].reshape(H // step, step, W // step, step)
    # blocks the fit cannot project at all stay NaN (nanmax would warn about them)
    return np.fmax.reduce(np.fmax.reduce(blocks, axis=3), axis=1)


def compare_stage(truth, result):
    r'''-> (params {name: error or None}, projection {"rms", "max", mode: {...}}, map)

The same figures as harness.compare.compare(result, truth) (a test holds them
equal), computed here from its parts so that the rotation-mode difference map
(ny,nx) px is kept without computing it twice. projection["rms"] and ["max"]
are the rotation-mode values: the headline projection difference.
'''
    from harness import compare as cmp
    world = bool(result.info.get("world_frame", result.calibrator == "jpl"))
    theta = result.calibrator == "jpl"
    params = cmp.parameter_errors(truth, result.model, theta_estimated=theta,
                                  world_frame=world)
    proj = {}
    themap = None
    for mode in ("rotation", "intrinsics") + (("world",) if world else ()):
        d = cmp.projection_difference(truth, result.model, mode=mode)
        if mode == "rotation":
            themap = d["map"]
        proj[mode] = {k: v for k, v in d.items() if k not in ("q", "map")}
    proj["rms"] = proj["rotation"]["rms"]
    proj["max"] = proj["rotation"]["max"]
    return jsonable(params), jsonable(proj), themap


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


def _slug(s):
    import re
    return re.sub(r"[^A-Za-z0-9=.,_-]+", "_", s)


def run_job(job):
    r'''Run one job's stages -> {"job": key, "records": [record dict, ...]}

Never raises for a failing stage: the records say which stage failed and why.
A job with twins (group_twins) gives the records of each of its cameras.
'''
    members = job.members()
    job = members[0]
    entry = None
    seconds = {}
    features = None
    try:
        entry, truth = camera_stage(job)
        target = _target(job.target)
        t0 = time.perf_counter()
        poses = poses_stage(truth, target, job.poses_n, job.poses_seed)
        seconds["poses"] = time.perf_counter() - t0
        renders, rsecs, rversion = render_stage(job.renderer, truth, target, poses,
                                                job.settings)
        seconds["render"] = float(sum(rsecs))
        # the median: the first image of a camera also builds the renderer's caches
        seconds["render_per_image"] = float(statistics.median(rsecs))
        seconds["render_first_image"] = float(rsecs[0])
        features = render_features([r.metadata for r in renders])
        images, rsec = response_stage(job, truth, [r.image for r in renders])
        if rsec:
            seconds["response"] = float(sum(rsec.values()))
            seconds["response_stages"] = rsec
        artifacts = {}
        if job.keep_images and job.run_dir:
            artifacts["images"] = _keep_images(job, images)
        dets, seconds["detect"] = detect_stage(images, target)
        detections = {"n_expected": int(sum(d.n_expected for d in dets)),
                      "n_found": int(sum(d.n_found for d in dets)),
                      "per_pose": [int(d.n_found) for d in dets],
                      "failed_poses": [i for i, d in enumerate(dets) if d.status != "ok"]}
        if job.keep_images and job.run_dir:
            artifacts["detections"] = _keep_detections(job, dets, poses)
        obs = observations_from(truth, target, poses, dets)
    except StageFailed as e:
        return {"job": job.key, "records": _member_failures(
            members, e.stage, e.reason, status=e.status, entry=entry, seconds=seconds,
            **({"features": features} if features else {}))}
    except Exception as e:  # a bug in a stage: still a record, with where it happened
        tb = traceback.extract_tb(e.__traceback__)[-1]
        return {"job": job.key, "records": _member_failures(
            members, "internal", f"{_reason(e)} ({Path(tb.filename).name}:{tb.lineno})",
            entry=entry, seconds=seconds, **({"features": features} if features else {}))}

    render_info = render_summary([r.metadata for r in renders])
    ctx = dict(obs=obs, target=target, truth=truth, entry=entry, seconds=seconds,
               detections=detections, artifacts=artifacts, rversion=rversion,
               render_info=render_info, features=features)
    fits = {} if len(members) > 1 else None
    twins = [m.camera_key for m in members[1:]]
    records = _calibrator_records(job, ctx, fits, {"twins": twins} if twins else None)
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
        records += _calibrator_records(twin, ctx_t, fits, {"with": job.camera_key})
    return {"job": job.key, "records": records}


def _member_failures(members, stage, reason, *, entry, seconds, **kw):
    r'''failure_records of a job and of each of its twins (their own catalogue entries)'''
    out = failure_records(members[0], stage, reason, entry=entry, seconds=seconds, **kw)
    for twin in members[1:]:
        try:
            entry_t = camera_stage(twin)[0]
        except StageFailed:
            entry_t = None
        out += failure_records(twin, stage, reason, entry=entry_t, **kw)
    return out


def _calibrator_records(job, ctx, fits, shared):
    r'''One record per calibrator model of the job (ctx: run_job's stage outputs)

fits: None, or {(calibrator, model, options): CalibrationResult} shared by the
cameras of a twin group: a calibrator that does not read the world frame fits
once (on observations without the surveyed poses) and the other cameras reuse it.
shared: the record's info["shared"] ({"twins": [...]} for the camera that ran
the stages, {"with": key, "stages": [...]} for its twins), or None.
'''
    import dataclasses

    from harness.calibrators import uses_world_frame
    records = []
    for cal, model, options in job.calibrators:
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
                                              **ctx))
        except Exception as e:  # a bug after the calibrator ran: this record only
            tb = traceback.extract_tb(e.__traceback__)[-1]
            records.append(_record(job, cal, model, ctx["entry"], status="failed",
                                   stage="internal",
                                   reason=f"{_reason(e)} ({Path(tb.filename).name}:"
                                          f"{tb.lineno})", seconds=dict(ctx["seconds"]),
                                   detections=ctx["detections"], artifacts=ctx["artifacts"],
                                   features=ctx["features"]))
    return records


def _calibrator_record(job, cal, model, options, *, obs, target, truth, entry, seconds,
                       detections, artifacts, rversion, render_info, features, res=None,
                       shared=None):
    r'''Calibrate (unless res is given: a fit shared with a twin), compare, keep the map
-> one record dict'''
    import numpy as np
    reused = res is not None and shared is not None and "calibrate" in shared.get("stages", ())
    if res is None:
        res = calibrate_stage(cal, obs, target, model, truth, options)
    sec = dict(seconds, calibrate=0.0 if reused else float(res.seconds))
    info = {"iterations": int(res.iterations), "render": render_info}
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
                       reason=_reason(e), artifacts=artifacts, **common)
    sec["compare"] = time.perf_counter() - t0
    arts = dict(artifacts)
    if job.keep_maps and job.run_dir and themap is not None:
        rel = Path("maps") / (_slug(job.fullname(cal, model)) + ".npy")
        path = Path(job.run_dir) / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, _downsample(themap).astype(np.float32))
        arts["map"] = str(rel)
    return _record(job, cal, model, entry, status="ok", params=params, projection=projection,
                   artifacts=arts, **common)


# renderer metadata that depends only on the job (not on caches, threads or timing)
DETERMINISTIC_METADATA = ("samples", "adaptive_fraction", "board_fraction")


def render_summary(metadatas):
    r'''{"images": n, "samples": total over the poses, "adaptive_fraction": mean, ...} of
the renders'''
    out = {"images": len(metadatas)}
    for k in DETERMINISTIC_METADATA:
        vals = [m[k] for m in metadatas if isinstance(m, dict)
                and isinstance(m.get(k), (int, float)) and not isinstance(m.get(k), bool)]
        if len(vals) == len(metadatas) and vals:
            out[k] = int(sum(vals)) if k == "samples" else float(sum(vals) / len(vals))
    return out


def _keep_images(job, images):
    from renderers.png import save_png16
    rels = []
    for i, im in enumerate(images):
        rel = Path("images") / _slug(job.key) / f"pose{i}.png"
        (Path(job.run_dir) / rel).parent.mkdir(parents=True, exist_ok=True)
        save_png16(Path(job.run_dir) / rel, im)
        rels.append(str(rel))
    return rels


def _keep_detections(job, dets, poses):
    import numpy as np
    rel = Path("images") / _slug(job.key) / "detections.npz"
    np.savez_compressed(Path(job.run_dir) / rel,
                        q=np.stack([np.asarray(d.q, dtype=np.float64) for d in dets]),
                        Rt_cam_board=np.stack([np.asarray(p) for p in poses]))
    return str(rel)


# --- warm-up ------------------------------------------------------------------------
# renderers whose kernels numba compiles (and caches on disk) on first use, and the
# kernels a render calls from Python (module, names)
NUMBA_RENDERERS = {"raycast": ("renderers._raycast_kernels", ("render_kernel",
                                                               "_fill_ray_cache"))}


def kernels_cached(renderer):
    r'''True when numba's on-disk cache holds the renderer's kernels for their current source

Reads only numba's cache index (its stamp of the source file), loads no code:
False after a kernel change, for a new cache directory, or when numba's
internals cannot be read (then warming is the safe choice).
'''
    import importlib
    if renderer not in NUMBA_RENDERERS:
        return True
    modname, names = NUMBA_RENDERERS[renderer]
    try:
        mod = importlib.import_module(modname)
        return all(bool(getattr(mod, n)._cache._cache_file._load_index()) for n in names)
    except Exception:
        return False


def warm_up(jobs, force=False):
    r'''Compile (or load from numba's cache) the kernels the jobs need, in this process

SYNOPSIS

    info = warm_up(jobs)   # {"seconds", "renders": ["raycast/CAHV", ...], "cached", "failed"}
    # force=True: warm even when numba's cache is up to date

Renders one image per model family used by the jobs' numba renderers (the
job's own camera and first planned pose, K=1, with a private ray cache that is
dropped afterwards), and runs the blooming kernel if a job's response uses it.
numba writes what it compiles to its cache directory, so worker processes
started afterwards load the kernels instead of each compiling them (after a
kernel change that is minutes per worker on a loaded machine). A renderer
whose kernels are already cached for their source (kernels_cached) is not
warmed: loading them here too would only add the loading time (seconds under
load) before the workers start. Never raises: a job that cannot be warmed
fails later, in its own record.
'''
    t0 = time.perf_counter()
    done, failed, cached = [], [], []
    seen = set()
    for name in sorted({j.renderer for j in jobs if j.renderer in NUMBA_RENDERERS}):
        if not force and kernels_cached(name):
            cached.append(name)
    for job in jobs:
        key = (job.renderer, job.family)
        if job.renderer not in NUMBA_RENDERERS or job.renderer in cached or key in seen:
            continue
        try:
            from renderers.base import RenderSettings, get_renderer
            _, truth = camera_stage(job)
            target = _target(job.target)
            Rt = poses_stage(truth, target, 1, job.poses_seed)[0]
            renderer = get_renderer(job.renderer, shared_cache=False)
            renderer.render(truth, target.pattern(), Rt, RenderSettings(spp=1, adaptive=True))
            seen.add(key)
            done.append(f"{job.renderer}/{job.family}")
        except Exception as e:  # not-applicable family, invisible target: try the next job
            failed.append(f"{job.key}: {_reason(e)}")
    if any((j.response or {}).get("saturation", {}).get("blooming") for j in jobs):
        try:
            import numpy as np

            from renderers.response import ResponseChain
            ResponseChain.from_config({"saturation": {"blooming": True}}).apply(
                np.full((4, 4), 2.0))
            done.append("response/blooming")
        except Exception as e:
            failed.append(f"response/blooming: {_reason(e)}")
    return {"seconds": time.perf_counter() - t0, "renders": done, "cached": cached,
            "failed": sorted(set(failed))[:10]}


# --- executors --------------------------------------------------------------------
def _local_results(fn, jobs, workers):
    r'''Yield (job, result or exception) as jobs finish, in local processes'''
    if workers <= 1:
        for job in jobs:
            try:
                yield job, fn(job)
            except Exception as e:
                yield job, e
        return
    import concurrent.futures as cf
    import multiprocessing
    # forkserver, not fork: the parent may hold threads (the progress bar, BLAS)
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["harness.runner"])
    with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as ex:
        futs = {ex.submit(fn, job): job for job in jobs}
        try:
            for fut in cf.as_completed(futs):
                try:
                    yield futs[fut], fut.result()
                except Exception as e:
                    yield futs[fut], e
        except BaseException:
            for f in futs:
                f.cancel()
            raise


def _call_pickled(fn, blob):
    return fn(pickle.loads(blob))


def _dask_results(fn, jobs, scheduler):
    r'''Yield (job, result or exception) as jobs finish on a Dask cluster'''
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise RunnerError("--executor dask needs dask.distributed; install camval's "
                          "dependencies (uv sync)") from None
    import dask.config
    # dask's own connect timeout (30 s unless configured, e.g. by
    # DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT): a loaded machine answers slowly
    timeout = dask.config.get("distributed.comm.timeouts.connect")
    try:
        client = Client(scheduler, timeout=timeout)
    except (OSError, TimeoutError) as e:
        raise RunnerError(f"cannot reach the Dask scheduler at {scheduler!r} within "
                          f"{timeout}: {e}") from None
    try:
        futs = {}
        for i, job in enumerate(jobs):
            # pickled: Dask must not take the Job dataclass apart and rebuild it
            f = client.submit(_call_pickled, fn, pickle.dumps(job), pure=False,
                              key=f"camval-{i}-{_slug(job.key)}-{uuid.uuid4().hex[:8]}")
            futs[f] = job
        for fut in as_completed(list(futs)):
            try:
                yield futs[fut], fut.result()
            except Exception as e:
                yield futs[fut], e
    finally:
        _close_client(client)


def _close_client(client):
    r'''Close a Dask client; a slow or failed close (a loaded scheduler) is not an error:
every job's records are stored by then'''
    import dask.config
    from dask.utils import parse_timedelta
    timeout = 4 * parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), "s")
    try:
        client.close(timeout=timeout)
    except (OSError, TimeoutError) as e:
        print(f"camval: the Dask client did not close cleanly ({type(e).__name__}); the "
              f"records are stored", file=sys.stderr)


class _Progress:
    r'''A rich progress bar with ETA on a terminal; one plain line per job otherwise'''

    def __init__(self, total, enabled=True, stream=None):
        self.total = total
        self.done = 0
        self.stream = stream or sys.stderr
        self.t0 = time.monotonic()
        self.enabled = enabled
        self.bar = None
        if enabled and total and getattr(self.stream, "isatty", lambda: False)():
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )
            self.bar = Progress(TextColumn("[bold]verify"), BarColumn(), MofNCompleteColumn(),
                                TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                                TextColumn("{task.description}"),
                                console=Console(file=self.stream), transient=False)
            self.task = self.bar.add_task("", total=total)
            self.bar.start()

    def advance(self, job_key, statuses):
        self.done += 1
        summary = ", ".join(f"{n} {s}" for s, n in sorted(statuses.items()))
        if self.bar is not None:
            self.bar.update(self.task, advance=1, description=f"{job_key} ({summary})")
        elif self.enabled:
            el = time.monotonic() - self.t0
            eta = el / self.done * (self.total - self.done)
            print(f"[{self.done}/{self.total}] {job_key}: {summary}  "
                  f"(elapsed {el:.0f} s, ETA {eta:.0f} s)", file=self.stream, flush=True)

    def close(self):
        if self.bar is not None:
            self.bar.stop()


def run_jobs(jobs, store, fn=run_job, executor="local", workers=None, scheduler=None,
             progress=True, warm=True, report=None):
    r'''Run jobs, storing each job's records in `store` as it finishes

SYNOPSIS

    n_done = run_jobs(jobs, RunStore.open(run_dir), executor="local", workers=2)

Jobs already stored are skipped (resume). A job whose worker crashed is
stored as failed records (stage "worker") that resume runs again. Largest
jobs are started first, so the slowest ones do not finish last. Returns the
number of jobs run (a job with twins counts each of its cameras).

warm: before starting local worker processes (workers > 1, fn = run_job),
compile the renderer's kernels once here (warm_up) so that the workers load
them from numba's cache. report: a dict that receives {"warm_up": {...}}.
'''
    if executor not in EXECUTORS:
        raise RunnerError(f"unknown executor {executor!r}; known: {', '.join(EXECUTORS)}")
    if executor == "dask" and not scheduler:
        raise RunnerError("--executor dask needs --scheduler ADDRESS (e.g. tcp://host:8786)")
    done = store.done_jobs()
    todo = sorted((j for j in jobs if j.key not in done), key=lambda j: (-j.cost, j.key))
    if workers is None:
        workers = min(len(todo), os.cpu_count() or 1)
    if (warm and executor == "local" and workers > 1 and fn is run_job and todo):
        info = warm_up(todo)
        if report is not None:
            report["warm_up"] = info
    bar = _Progress(len(todo), enabled=progress)
    try:
        results = (_dask_results(fn, todo, scheduler) if executor == "dask"
                   else _local_results(fn, todo, workers))
        for job, out in results:
            members = job.members()
            if isinstance(out, BaseException):
                # the worker died (killed, out of memory): reported, and retried on resume
                recs = [r for m in members for r in failure_records(m, "worker", _reason(out))]
            else:
                recs = out["records"]
            for m in members:   # each camera's records under its own job key
                mine = [r for r in recs if r["fullname"].startswith(m.key + "/")]
                final = not isinstance(out, BaseException)
                if not mine:    # never silently done: reported, and run again on resume
                    mine = failure_records(m, "internal", "the job returned no records for "
                                                          f"camera {m.camera_key}")
                    recs = recs + mine
                    final = False
                store.save_job(m.key, mine, final=final)
            statuses = {}
            for r in recs:
                statuses[r["status"]] = statuses.get(r["status"], 0) + 1
            bar.advance(job.key, statuses)
    finally:
        bar.close()
    return sum(1 + len(j.twins) for j in todo)


def adapters_from_records(records):
    r'''{"renderers": {...}, "calibrators": {...}, "libraries": {...}} seen in a run'''
    out = {"renderers": {}, "calibrators": {}, "libraries": library_versions()}
    for r in records.values():
        v = r.get("versions") or {}
        if v.get("renderer"):
            out["renderers"][r["renderer"]] = v["renderer"]
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
The document's "execution" says how the jobs ran (and the warm-up's seconds).
'''
    if resume:
        store = RunStore.open(run_dir)
    else:
        store = RunStore.create(run_dir, campaign.as_dict())
    jobs = expand_jobs(campaign, entries=entries, run_dir=store.dir)
    expected = {j.key for j in jobs}
    if campaign.share_identical_cameras:
        jobs = group_twins(jobs, skip=store.done_jobs())
    t0 = time.perf_counter()
    report = {}
    n = run_jobs(jobs, store, executor=executor, workers=workers, scheduler=scheduler,
                 progress=progress, warm=warm, report=report)
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
        if s.get("render"):
            images += int(((r.get("info") or {}).get("render") or {}).get("images", 0))
    for cal, t in sorted(per_cal.items()):
        out[f"calibrate:{cal}"] = t
    return out, images

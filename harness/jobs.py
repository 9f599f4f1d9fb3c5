r'''Campaign jobs as plain values, and the cameras that are one camera (twins)

SYNOPSIS

    from harness.jobs import expand_jobs, group_twins

    jobs = expand_jobs(campaign)                # [Job, ...]
    jobs = group_twins(jobs, skip=store.done_jobs())
    jobs[0].key               # "15/CAHVOR/dots/raycast[spp=8,adaptive,coverage=area]"

A Job is camera x model family x target x renderer setting, with the
calibrators to run on it: a frozen dataclass that pickles by value, so the
executors (harness.executors) send it to local processes or a Dask cluster
as it is, and harness.runner.run_job runs its stages (harness.stages).

Cameras that are one camera (twins): a catalogue slot derived from another by a
rigid motion (a stereo partner, a rear-facing copy) images every point of its
camera frame at the same pixel. For a renderer that is exact in the camera
frame (camera_frame_exact, the ray caster) and a clean job, its poses, images
and detections are those of its twin, and so is the fit of every calibrator
that does not read the world frame. run_campaign() folds such jobs into one
(group_twins; the campaign key share_identical_cameras = false turns it off):
the images are rendered once, the world-frame calibrators (jpl) fit each
camera, and each camera gets its own records, compared with its own truth,
with info["shared"] saying what was computed for which camera
(harness.job_records). A fit that does not read the world frame is compared,
and judged (harness.verdict: its exact observations and exact fit), in the
camera frame (camera_frame_model), the same bits for twins: computed once.
'''

import re
from dataclasses import dataclass, field
from pathlib import Path

from reference_models.errors import CamvalError

from .campaign import VERDICT_MODES
from .records import make_fullname, renderer_key
from .stages import StageFailed, camera_stage


class RunnerError(CamvalError):
    '''Bad runner options (unknown executor, missing scheduler address).'''


def slug(s):
    r'''s with every run of characters outside [A-Za-z0-9=.,_-] replaced by "_": a key as a
file name (images, maps) or a Dask task key'''
    return re.sub(r"[^A-Za-z0-9=.,_-]+", "_", s)


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
poses_n:      the poses rendered: the most any calibrator fits (a calibrator's options
              [harness.campaign.POSE_COUNT] = N: it fits the first N; none: all)
poses_cover:  targets.poses.plan_poses(cover=...) for the poses beyond the first six
twins:        ((camera spec, camera key), ...) of other cameras that are this one
              (group_twins): run_job() gives their records too
verdict_modes: the projection-difference modes of the verdict's floor and renderer
              (the campaign's verdict_modes; harness.verdict.assess)
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
    poses_cover: str = "paper"
    keep_images: bool = False
    keep_maps: bool = False
    catalogue: str = None
    run_dir: str = None
    cost: float = 1.0
    response: dict = field(default_factory=dict)
    response_name: str = ""
    seed: int = 0
    twins: tuple = ()
    verdict_modes: tuple = VERDICT_MODES

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
                if not getattr(campaign, "renders", lambda *a: True)(target, family,
                                                                       entry.model.family):
                    continue
                for r in campaign.renderers:
                    for s, prof in zip(r.settings(campaign.responses),
                                       r.profiles(campaign.responses), strict=True):
                        cals = tuple((c.name, m, _with_pose_count(o, c, campaign))
                                     for c in campaign.calibrators
                                     if getattr(c, "fits", lambda t: True)(target)
                                     for m, o in c.models_and_options(family, entry.model))
                        jobs.append(Job(
                            key=f"{key}/{family}/{target}/{renderer_key(r.name, s)}",
                            camera=spec, camera_key=key, family=family, target=target,
                            renderer=r.name, settings=s, calibrators=cals,
                            poses_n=_poses_rendered(campaign), poses_seed=campaign.poses_seed,
                            poses_cover=getattr(campaign, "poses_cover", "paper"),
                            keep_images=campaign.keep_images, keep_maps=campaign.keep_maps,
                            catalogue=campaign.catalogue,
                            run_dir=str(run_dir) if run_dir is not None else None,
                            cost=float(w * h) * (1.0 + 0.02 * s["spp"]),
                            response=dict(prof.config) if prof is not None else {},
                            response_name=prof.name if prof is not None else "",
                            seed=int(getattr(campaign, "seed", 0)),
                            verdict_modes=tuple(getattr(campaign, "verdict_modes",
                                                        VERDICT_MODES))))
    keys = [j.key for j in jobs]
    if len(set(keys)) != len(keys):
        dup = sorted({k for k in keys if keys.count(k) > 1})
        raise RunnerError(f"the campaign lists the same job twice: {dup[0]} (a camera named "
                          f"twice under different specs?)")
    return jobs


def _poses_rendered(campaign):
    r'''The poses a job renders: the campaign's n, or more when a calibrator asks for more'''
    return max([campaign.poses_n] + [c.poses for c in campaign.calibrators
                                     if getattr(c, "poses", None) is not None])


def _with_pose_count(options, spec, campaign):
    r'''A calibrator's options with its pose count when the job renders another number
(harness.job_records fits it on the first N poses); unchanged otherwise, so a campaign
without calibrator pose counts has the jobs (and the twins' signatures) it had'''
    from .campaign import POSE_COUNT
    n = spec.poses if getattr(spec, "poses", None) is not None else campaign.poses_n
    if n == _poses_rendered(campaign):
        return options
    return dict(options, **{POSE_COUNT: n})


def camera_key(entry, spec):
    r'''The camera's part of a fullname: "15", "SuperCam", "file-<name>" (never a path)'''
    key = str(getattr(entry, "key", None) or spec)
    if getattr(entry, "kind", "") == "file" or "/" in key:
        key = "file-" + slug(Path(key).name)
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


def camera_frame_model(model):
    r'''The model moved into its own camera frame: what twins share, bit for bit

SYNOPSIS

    m = camera_frame_model(truth)       # m.Rt_ref_cam() ~ identity, m.C = 0
    m.project(p_cam)                    # ~ truth.project(p_cam carried to the world)

A JPL-family model's C, A, H, V (and O) carried into its camera frame
(Rt_ref_cam: p_cam = (p_ref - C) @ R, vectors v @ R; R, E and the image size
kept). It images every camera-frame point as the model does, to the last bits
of that rotation. Two twins (same_camera) that differ by a translation, or by
a rotation of the world whose matrix entries are 0 and +-1 (a stereo partner,
a camera yawed 180 deg about a world axis: every twin of the catalogue), give
the same numbers here bit for bit, where their own projections of the same camera-frame
points differ in the last bits (the world-frame C and rotation enter them):
what is computed from this model and camera-frame poses (the verdict's exact
observations, a fit that does not read the world frame and its comparisons)
is then the same for both, and a campaign computes it once
(harness.verdict.exact_fit, harness.job_records). Twins related by another
rotation get models that differ in the last bits: nothing is shared then.
Any other model is returned as it is.
'''
    import numpy as np

    from reference_models.cahvore import FAMILIES
    if getattr(model, "family", None) not in FAMILIES:
        return model
    R = model.Rt_ref_cam()[:3]
    moved = {"C": np.zeros(3)}
    for k in ("A", "H", "V", "O"):
        v = getattr(model, k, None)
        if v is not None:
            moved[k] = v @ R
    return model.replace(**moved)


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
    return (job.family, job.target, job.renderer, renderer_key(job.renderer, job.settings),
            repr(job.settings.get("setup")),
            repr(job.calibrators), job.poses_n, job.poses_seed, job.poses_cover, job.keep_images,
            job.keep_maps, job.catalogue, job.run_dir, job.seed, job.verdict_modes)

r'''Stability sweeps: vary one difficulty at a time and find where each method breaks

SYNOPSIS

    from harness.sweep import run_sweep, breakdowns, stability_chart

    sw = run_sweep(camera=15, family="CAHVOR", target="dots", difficulty="noise",
                   calibrators=(("jpl", "CAHVOR"), ("mrcal", "CAHVOR"), ("opencv", "OPENCV5")))
    sw["levels"]        # the difficulty's levels, easiest first
    sw["records"]       # one per (level, calibrator): detection rate, status,
                        # projection difference RMS/max (px), residual RMS, the scene
                        # of the level (mean range m, mean tilt deg, median dot px)
    sw["breakdown"]     # {calibrator/model: first level where it breaks, or None}
    stability_chart(sw, "sweep_noise.png")

A sweep is one camera x model x target x renderer job of the campaign runner
(harness/stages.py: poses, render, detect, calibrate,
compare) repeated over the levels of one difficulty, everything else fixed:

    noise   read noise sigma in electrons, with shot noise, a 20000 e- well and
            12-bit quantisation (renderers/response.py); the images are rendered
            once and the noise drawn per level
    blur    Gaussian lens PSF sigma in pixels (rendered once)
    motion  motion-blur length in pixels along the rows (rendered once)
    spp     supersampling K of the renderer (re-rendered per level)
    poses   number of board poses (re-planned and re-rendered per level)
    tilt    board tilt, degrees off fronto-parallel: every pose at this tilt (about
            the planner's tilt axes), re-planned and re-rendered per level
    range   board range as a multiple of the range at which the board just fills
            the image (1 = fills it; the planner's own poses use 1-1.55); every pose
            at this multiple, re-planned and re-rendered per level
    dots    dot diameter in pixels (median over the dots of every pose): the
            board's dots (and the orientation mark) scaled about their centres,
            the poses kept, re-rendered per level
    fov     field of view across the catalogue: each level is a camera (slot,
            extra name or model file), the levels ordered by horizontal field of
            view; each camera's own poses and images

A method BREAKS at the first level where the target is no longer detected in
every point of every image (detection rate < 100%), the calibrator fails, or
its projection difference (rotation mode, RMS over the image) exceeds
`bar_px`. Every level is still run after a break, so the record shows how the
method degrades. A level that cannot be set up (a board that does not fit the
image at that tilt or range, dots that would overlap, a camera the planner
refuses) is a "not-applicable" record with the reason; it is no breakdown.
'''

import math
import time

import numpy as np

from reference_models.errors import CamvalError

DIFFICULTIES = {
    "noise": {"levels": [0.0, 30.0, 100.0, 300.0, 1000.0, 3000.0, 6000.0, 10000.0],
              "unit": "read noise, e- (20000 e- well, shot noise, 12 bit)", "rerender": False},
    "blur": {"levels": [0.0, 0.5, 1.0, 2.0, 3.0, 5.0, 8.0],
             "unit": "PSF sigma, px", "rerender": False},
    "motion": {"levels": [0.0, 1.0, 2.0, 4.0, 8.0, 16.0],
               "unit": "motion blur length, px", "rerender": False},
    "spp": {"levels": [16, 8, 4, 2, 1], "unit": "supersampling K (falling)", "rerender": True},
    "poses": {"levels": [12, 9, 6, 4, 3], "unit": "board poses", "rerender": True},
    "tilt": {"levels": [0.0, 15.0, 30.0, 45.0, 60.0, 70.0, 75.0, 80.0],
             "unit": "board tilt, deg off fronto-parallel", "rerender": True},
    "range": {"levels": [1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0],
              "unit": "board range, x the range at which it fills the image", "rerender": True},
    "dots": {"levels": [16.0, 12.0, 8.0, 6.0, 4.0, 3.0, 2.5, 2.0],
             "unit": "dot diameter, px (median)", "rerender": True},
    "fov": {"levels": ["MCAM_Z_LEFT-Z110", "13", "MCAM_Z_LEFT-Z026", "15", "21", "8", "17"],
            "unit": "camera, ordered by horizontal field of view", "rerender": True},
}
DEFAULT_BAR_PX = 0.05
# beyond the planner's own obliquity limit (78 deg): the tilt sweep goes there on purpose
SWEEP_MAX_VIEW_ANGLE_DEG = 89.0
DOT_OUTLINE_POINTS = 64


class SweepError(CamvalError):
    '''A sweep that cannot be set up (unknown difficulty, bad levels).'''


class LevelNotApplicable(Exception):
    '''A level that cannot be set up for this camera (recorded as not-applicable).'''


def response_for(difficulty, level):
    r'''The camera-response configuration of a level of an image-side difficulty'''
    if difficulty == "noise":
        if level == 0:
            return {}
        return {"full_well_e": 20000.0, "shot_noise": {}, "read_noise": {"sigma_e": float(level)},
                "quantise": {"bits": 12}}
    if difficulty == "blur":
        return {} if level == 0 else {"psf": {"kind": "gaussian", "sigma_px": float(level)}}
    if difficulty == "motion":
        return {} if level == 0 else {"motion_blur": {"velocity_px": [float(level), 0.0]}}
    return {}


def level_text(v):
    r'''A level as tick and table text: 1000.0 -> "1000", 2.5 -> "2.5", "15" -> "15"'''
    return f"{v:g}" if isinstance(v, float) else str(v)


def _finite(v):
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


# ---------------------------------------------------------------------------------------------
# the geometry of a level
def horizontal_fov_deg(model):
    r'''Angle (deg) between the rays of the left and right image edges on the middle row

SYNOPSIS

    horizontal_fov_deg(catalogue.get(15).model)     # 45.4
'''
    y = (model.height - 1) / 2.0
    _, v = model.unproject(np.array([[-0.5, y], [model.width - 0.5, y]], dtype=np.float64))
    if not np.all(np.isfinite(v)):
        return math.nan
    return math.degrees(math.acos(float(np.clip(v[0] @ v[1], -1.0, 1.0))))


def plan_sweep_poses(model, target, n, seed=0, tilt_deg=None, range_factor=None):
    r'''Board poses like targets.poses.plan_poses, with the tilt or the range forced

SYNOPSIS

    Rt_cam_board_all = plan_sweep_poses(model, target, 6, tilt_deg=60.0)
    Rt_cam_board_all = plan_sweep_poses(model, target, 6, range_factor=4.0)
    # lists of n arrays of shape (4,3), camera frame of model.Rt_ref_cam()

The planner's six templates (centre, the four corners, centre again), their
tilt axes, rolls and seed jitter, with every pose's tilt set to tilt_deg
(none jittered) and/or its range set to range_factor times the range at
which the board just fits in the middle of the image. Obliquity is allowed up
to SWEEP_MAX_VIEW_ANGLE_DEG. Raises LevelNotApplicable when a pose does not
fit the image.
'''
    from targets import poses as tp
    W, H = model.width, model.height
    planner = tp._Planner(model, target, tp._margin_px(model), tp.DEFAULT_MAX_RANGE)
    planner.cos_view_max = math.cos(math.radians(SWEEP_MAX_VIEW_ANGLE_DEG))
    q_centre = np.array([(W - 1) / 2, (H - 1) / 2])
    rng = np.random.default_rng(seed)
    corners = {(-1, -1): (-0.5, -0.5), (1, -1): (W - 0.5, -0.5),
               (1, 1): (W - 0.5, H - 0.5), (-1, 1): (-0.5, H - 0.5)}
    out = []
    for i in range(n):
        anchor, tilt, azimuth, roll, factor = tp._TEMPLATES[i % len(tp._TEMPLATES)]
        if i >= len(tp._TEMPLATES):
            azimuth += 60.0 * (i // len(tp._TEMPLATES))
            factor *= 1.0 + 0.15 * (i // len(tp._TEMPLATES))
        tilt = min(tp.MAX_TILT_DEG, max(0.0, tilt + rng.uniform(-5.0, 5.0)))
        azimuth += rng.uniform(-15.0, 15.0)
        roll += rng.uniform(-3.0, 3.0)
        factor *= rng.uniform(0.95, 1.05)
        if tilt_deg is not None:
            tilt = float(tilt_deg)
        if range_factor is not None:
            factor = float(range_factor)
        d_fit = planner.closest_fit_range(q_centre, tilt, azimuth, roll)
        if d_fit is None:
            raise LevelNotApplicable(
                f"pose {i}: the board does not fit the {W}x{H} image at tilt {tilt:.0f} deg "
                f"at any range up to {tp.DEFAULT_MAX_RANGE:g} m")
        d = max(1.0, factor) * d_fit if range_factor is None else factor * d_fit
        q_anchor = q_centre if anchor is None else planner.push(
            q_centre, corners[anchor], d, tilt, azimuth, roll)
        Rt = planner.pose(q_anchor, d, tilt, azimuth, roll)
        if not planner.fits(Rt):
            raise LevelNotApplicable(f"pose {i}: no placement of the board fits the {W}x{H} "
                                     f"image at {d:.3g} m with tilt {tilt:.0f} deg")
        out.append(Rt)
    return out


def dot_diameters_px(model, target, poses):
    r'''(Nposes, Npoints) diameter (px) of the circle of equal area to each projected dot'''
    Rt_ref_cam = model.Rt_ref_cam()
    outl = target.dot_outlines(DOT_OUTLINE_POINTS)
    out = []
    for Rt in poses:
        Rt = np.asarray(Rt, dtype=np.float64)
        p_cam = outl @ Rt[:3].T + Rt[3]
        q = model.project(p_cam @ Rt_ref_cam[:3].T + Rt_ref_cam[3])
        x, y = q[..., 0], q[..., 1]
        area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y,
                                   axis=-1))
        out.append(2.0 * np.sqrt(area / math.pi))
    return np.asarray(out)


def scene_of(model, target, poses):
    r'''{"range_m", "tilt_deg" (means over the poses), "dot_px" (median dot diameter)}'''
    from targets.poses import pose_summary
    s = [pose_summary(model, target, Rt) for Rt in poses]
    out = {"range_m": _finite(np.mean([x["range_m"] for x in s])),
           "tilt_deg": _finite(np.mean([x["tilt_deg"] for x in s]))}
    if target.kind == "dots":
        out["dot_px"] = _finite(np.nanmedian(dot_diameters_px(model, target, poses)))
    return out


def scaled_dots(target, scale):
    r'''The dot target with every dot diameter (and the orientation mark's) times scale'''
    from targets.boards import TargetError, target_from_dict
    if target.kind != "dots":
        raise SweepError(f"the dots difficulty needs a dot target; {target.name!r} is "
                         f"{target.kind!r}")
    spec = {k: (dict(v) if isinstance(v, dict) else v) for k, v in target.spec.items()}
    spec["dot_diameter"] = float(spec["dot_diameter"]) * scale
    if spec.get("orientation_mark"):
        spec["orientation_mark"]["dot_diameter"] = (
            float(spec["orientation_mark"]["dot_diameter"]) * scale)
    try:
        return target_from_dict(spec, source=f"{target.source} (dots x {scale:.4g})")
    except TargetError as e:
        raise LevelNotApplicable(f"dots scaled by {scale:.3g}: {e}") from None


def order_by_fov(cameras, catalogue=None):
    r'''[(camera spec, fov deg)] sorted by horizontal field of view (unknown cameras last)'''
    from reference_models.catalogue import load_catalogue
    cat = catalogue or load_catalogue()
    out = []
    for c in cameras:
        try:
            fov = horizontal_fov_deg(cat.get(str(c)).model)
        except CamvalError:
            fov = math.nan
        out.append((str(c), fov))
    return sorted(out, key=lambda cf: (not math.isfinite(cf[1]), cf[1]))


# ---------------------------------------------------------------------------------------------
def _detect_and_calibrate(truth, target, poses, images, calibrators, level, bar_px, extra):
    from harness import stages
    recs = []
    try:
        dets, t_det = stages.detect_stage(images, target)
    except stages.StageFailed as e:
        for cal, model in calibrators:
            recs.append({"level": level, "calibrator": cal, "model": model, "status": "failed",
                         "stage": "detect", "reason": e.reason, "detection_rate": 0.0,
                         "broken": True, **extra})
        return recs
    n_exp = sum(d.n_expected for d in dets)
    n_found = sum(d.n_found for d in dets)
    rate = n_found / max(n_exp, 1)
    obs = stages.observations_from(truth, target, poses, dets)
    for cal, model in calibrators:
        rec = {"level": level, "calibrator": cal, "model": model,
               "detection_rate": rate, "detect_seconds": t_det, **extra}
        res = stages.calibrate_stage(cal, obs, target, model, truth, {})
        rec["calibrate_seconds"] = float(res.seconds)
        if res.status != "ok":
            rec.update(status=res.status, stage="calibrate", reason=res.reason,
                       broken=res.status == "failed")
            recs.append(rec)
            continue
        try:
            _, proj, _ = stages.compare_stage(truth, res)
        except Exception as e:   # a comparison that cannot be made: the method broke here
            rec.update(status="failed", stage="compare", reason=stages.failure_reason(e),
                       broken=True)
            recs.append(rec)
            continue
        rs = res.residual_stats()
        rec.update(status="ok", projection_rms_px=_finite(proj["rms"]),
                   projection_max_px=_finite(proj["max"]),
                   residual_rms_px=_finite(rs.get("rms")) if rs else None)
        rec["broken"] = bool(rate < 1.0 or not (rec["projection_rms_px"] is not None
                                                and rec["projection_rms_px"] <= bar_px))
        recs.append(rec)
    return recs


def _camera(spec, family):
    r'''(entry, truth, truth family): the family asked for, or the camera's own when it is
less (the fov sweep crosses CAHV, CAHVOR and CAHVORE cameras)'''
    from harness import stages
    from reference_models.cahvore import truncate
    try:
        return (*stages.camera_truth(str(spec), family), family)
    except stages.StageFailed as e:
        if e.status != "not-applicable":
            raise
    entry = stages.cached_catalogue(None).get(str(spec))
    return entry, truncate(entry.model, entry.model.family), entry.model.family


def run_sweep(camera, family="CAHVOR", target="dots", difficulty="noise", levels=None,
              calibrators=(("jpl", "CAHVOR"), ("mrcal", "CAHVOR"), ("opencv", "OPENCV5")),
              renderer="raycast", spp=8, n_poses=6, seed=0, bar_px=DEFAULT_BAR_PX,
              progress=None):
    r'''Run one stability sweep

SYNOPSIS

    sw = run_sweep(15, "CAHVOR", "dots", "noise")
    sw = run_sweep(17, "CAHVOR", "dots", "tilt", levels=[0, 45, 75], spp=2, n_poses=4)
    sw = run_sweep(None, "CAHVOR", "dots", "fov", levels=["13", "15", "17"])

ARGUMENTS

- camera: catalogue slot, extra name or model file (ignored by "fov", whose
  levels are the cameras)
- difficulty: a key of DIFFICULTIES; levels: its levels (default: its own)
- calibrators: ((name, model), ...)
- renderer, spp (K), n_poses, seed: the fixed setting of the other difficulties
- bar_px: the projection difference (px RMS) above which a method is broken

RETURNED VALUE: a dict (JSON-ready) with the setting, levels, level_labels
(tick labels: the level, and for fov the camera's field of view), records and
breakdown. A stage failing at one level is a record, never an exception.
'''
    from harness import stages
    from renderers.response import ResponseChain
    say = progress or (lambda s: None)
    if difficulty not in DIFFICULTIES:
        raise SweepError(f"unknown difficulty {difficulty!r}; known: {', '.join(DIFFICULTIES)}")
    spec = DIFFICULTIES[difficulty]
    levels = list(spec["levels"] if levels is None else levels)
    if not levels:
        raise SweepError("a sweep needs at least one level")
    labels = [level_text(lv) for lv in levels]
    if difficulty == "fov":
        ordered = order_by_fov(levels)
        levels = [c for c, _ in ordered]
        labels = [f"{c}\n{fov:.0f} deg" if math.isfinite(fov) else c for c, fov in ordered]
    elif difficulty != "poses":
        try:
            levels = [float(lv) for lv in levels]
        except (TypeError, ValueError):
            raise SweepError(f"{difficulty} levels must be numbers; got {levels!r}") from None
    t_start = time.perf_counter()
    tgt = stages.cached_target(target)
    if difficulty == "dots" and tgt.kind != "dots":
        raise SweepError(f"the dots difficulty scales the dots of a dot target; target "
                         f"{target!r} is {tgt.kind!r}")
    entry = truth = truth_family = None
    if difficulty != "fov":
        try:
            entry, truth, truth_family = _camera(camera, family)
        except stages.StageFailed as e:
            raise SweepError(f"camera {camera}: {e.reason}") from None
    records = []
    settings = {"spp": int(spp), "adaptive": True}
    fixed_poses = None      # the poses of every level, where the difficulty keeps them
    fixed_images = None     # the images of every level of an image-side difficulty
    dot_px0 = None
    for i, level in enumerate(levels):
        say(f"{difficulty} = {level}")
        extra = {}
        lv_target = tgt
        try:
            if difficulty == "fov":
                try:
                    entry, truth, truth_family = _camera(level, family)
                except (stages.StageFailed, CamvalError) as e:
                    raise LevelNotApplicable(getattr(e, "reason", None) or str(e)) from None
                extra.update(camera=str(level), fov_deg=_finite(horizontal_fov_deg(truth)))
            extra["truth_family"] = truth_family
            if difficulty in ("tilt", "range"):
                kw = {"tilt_deg": level} if difficulty == "tilt" else {"range_factor": level}
                poses = plan_sweep_poses(truth, tgt, n_poses, seed, **kw)
            elif difficulty in ("poses", "fov") or fixed_poses is None:
                n = int(level) if difficulty == "poses" else n_poses
                try:
                    poses = stages.poses_stage(truth, tgt, n, seed)
                except stages.StageFailed as e:
                    if difficulty == "fov":
                        raise LevelNotApplicable(e.reason) from None
                    raise
                if difficulty not in ("poses", "fov"):
                    fixed_poses = poses
            else:
                poses = fixed_poses
            if difficulty == "dots":
                if dot_px0 is None:
                    dot_px0 = float(np.nanmedian(dot_diameters_px(truth, tgt, poses)))
                lv_target = scaled_dots(tgt, float(level) / dot_px0)
            extra["scene"] = scene_of(truth, lv_target, poses)
            if spec["rerender"] or fixed_images is None:
                st = dict(settings, spp=int(level)) if difficulty == "spp" else settings
                renders, secs, _ = stages.render_stage(renderer, truth, lv_target, poses, st)
                images = [r.image for r in renders]
                extra["render_seconds_per_image"] = float(np.mean(secs))
                if not spec["rerender"]:
                    fixed_images = images
            else:
                images = fixed_images
            chain = ResponseChain.from_config(response_for(difficulty, level))
            if chain.stages:
                images = [chain.apply(im, model=truth, seed=seed * 1000 + 17 * i + k).image
                          for k, im in enumerate(images)]
        except LevelNotApplicable as e:
            for cal, model in calibrators:
                records.append({"level": level, "calibrator": cal, "model": model,
                                "status": "not-applicable", "stage": "setup",
                                "reason": str(e), "broken": False, **extra})
            continue
        except stages.StageFailed as e:
            for cal, model in calibrators:
                records.append({"level": level, "calibrator": cal, "model": model,
                                "status": "failed", "stage": e.stage, "reason": e.reason,
                                "broken": True, **extra})
            continue
        records.extend(_detect_and_calibrate(truth, lv_target, poses, images, calibrators,
                                             level, bar_px, extra))
    if difficulty == "fov":
        cam, cam_label = "catalogue", "one camera per level"
    else:
        cam = str(camera)
        cam_label = f"{entry.rover} {entry.role} {entry.side}"
    return {"difficulty": difficulty, "unit": spec["unit"], "levels": levels,
            "level_labels": labels, "camera": cam, "camera_label": cam_label,
            "family": family, "target": target, "renderer": renderer, "spp": spp,
            "n_poses": n_poses, "bar_px": bar_px, "seed": seed,
            "seconds": time.perf_counter() - t_start,
            "records": records, "breakdown": breakdowns(records, levels)}


def breakdowns(records, levels):
    r'''{calibrator/model: {"level": first breaking level or None, "reason": why}}'''
    out = {}
    for rec in records:
        key = f"{rec['calibrator']}/{rec['model']}"
        out.setdefault(key, {"level": None, "reason": None})
    for lv in levels:
        for rec in records:
            if rec["level"] != lv or not rec.get("broken"):
                continue
            key = f"{rec['calibrator']}/{rec['model']}"
            if out[key]["level"] is None and rec.get("status") != "not-applicable":
                rate = rec.get("detection_rate")
                parts = []
                if rate is not None and rate < 1.0:
                    parts.append(f"detection rate {100 * rate:.1f}%")
                if rec.get("reason"):
                    parts.append(rec["reason"])
                elif rec.get("projection_rms_px") is not None:
                    parts.append(f"projection difference {rec['projection_rms_px']:.3g} px RMS")
                why = "; ".join(parts) or "broken"
                out[key] = {"level": lv, "reason": why}
    return out


def tick_labels(sweep):
    r'''The x tick label of every level: the level, with the camera's field of view (fov)
or the mean board range in metres (range)'''
    levels = sweep["levels"]
    labels = list(sweep.get("level_labels") or [level_text(v) for v in levels])
    if sweep["difficulty"] == "range":
        for i, lv in enumerate(levels):
            sc = next((r.get("scene") for r in sweep["records"]
                       if r["level"] == lv and r.get("scene")), None)
            if sc and sc.get("range_m") is not None:
                labels[i] = f"{lv:g}\n{sc['range_m']:.2g} m"
    return labels


def stability_chart(sweep, path):
    r'''One stability chart: projection difference per method against the level,
breakdown points marked (X and a dotted line), detection rate on a second axis,
levels that could not be set up shaded'''
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.6))
    ax2 = ax.twinx()
    levels = sweep["levels"]
    xs = np.arange(len(levels))
    keys = sorted({f"{r['calibrator']}/{r['model']}" for r in sweep["records"]})
    floor = None
    for k, key in enumerate(keys):
        ys = []
        for lv in levels:
            r = next((r for r in sweep["records"] if r["level"] == lv
                      and f"{r['calibrator']}/{r['model']}" == key), None)
            v = r.get("projection_rms_px") if r else None
            ys.append(np.nan if v is None else max(v, 1e-6))
        finite = [y for y in ys if np.isfinite(y)]
        if finite:
            floor = min(finite) if floor is None else min(floor, min(finite))
        b = sweep["breakdown"].get(key, {}).get("level")
        label = key + (f" (breaks at {level_text(b)})" if b is not None else " (never broke)")
        ax.plot(xs, ys, "o-", color=f"C{k}", label=label)
        if b is not None:
            ib = levels.index(b)
            ax.axvline(ib, color=f"C{k}", ls=":", alpha=0.7)
            ax.plot([ib], [ys[ib] if np.isfinite(ys[ib]) else sweep["bar_px"]], "X",
                    color=f"C{k}", ms=14, mec="k")
    for i, lv in enumerate(levels):
        recs = [r for r in sweep["records"] if r["level"] == lv]
        if recs and all(r.get("status") == "not-applicable" for r in recs):
            ax.axvspan(i - 0.5, i + 0.5, color="0.85", zorder=0)
            ax.text(i, sweep["bar_px"], "n/a", ha="center", va="bottom", fontsize=7,
                    color="0.4")
    rates = []
    for lv in levels:
        rs = [r["detection_rate"] for r in sweep["records"]
              if r["level"] == lv and r.get("detection_rate") is not None]
        rates.append(max(rs) if rs else np.nan)
    ax2.plot(xs, 100 * np.asarray(rates, float), "s--", color="0.5", label="detection rate")
    ax2.set_ylabel("detection rate, %")
    ax2.set_ylim(0, 105)
    ax.axhline(sweep["bar_px"], color="k", lw=0.8, ls="--", label=f"bar {sweep['bar_px']:g} px")
    ax.set_yscale("log")
    top = max([sweep["bar_px"]] + [r["projection_rms_px"] for r in sweep["records"]
                                   if r.get("projection_rms_px") is not None])
    ax.set_ylim(min(floor or sweep["bar_px"], sweep["bar_px"]) / 2, top * 3)
    ax.set_xticks(xs, tick_labels(sweep), fontsize=8)
    ax.set_xlim(-0.5, len(levels) - 0.5)
    ax.set_xlabel(sweep["unit"])
    ax.set_ylabel("projection difference, px RMS (rotation mode)")
    where = ("cameras of the catalogue" if sweep["difficulty"] == "fov" else
             f"camera {sweep['camera']} ({sweep['camera_label']})")
    ax.set_title(f"stability: {sweep['difficulty']} - {where}, {sweep['family']}, "
                 f"{sweep['target']}, {sweep['renderer']} K={sweep['spp']}; X = breakdown",
                 fontsize=9)
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=3,
              fontsize=7, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)

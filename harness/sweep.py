r'''Stability sweeps: vary one difficulty at a time and find where each method breaks

SYNOPSIS

    from harness.sweep import run_sweep, breakdowns

    sw = run_sweep(camera=15, family="CAHVOR", target="dots", difficulty="noise",
                   calibrators=(("jpl", "CAHVOR"), ("mrcal", "CAHVOR"), ("opencv", "OPENCV5")))
    sw["levels"]        # the difficulty's levels, easiest first
    sw["records"]       # one per (level, calibrator): detection rate, status,
                        # projection difference RMS/max (px), residual RMS
    sw["breakdown"]     # {calibrator/model: first level where it breaks, or None}

A sweep is one camera x model x target x renderer job of the campaign runner
(harness/runner.py stage functions: poses, render, detect, calibrate,
compare) repeated over the levels of one difficulty, everything else fixed:

    noise   read noise sigma in electrons, with shot noise, a 20000 e- well and
            12-bit quantisation (renderers/response.py); the images are rendered
            once and the noise drawn per level
    blur    Gaussian lens PSF sigma in pixels (rendered once)
    motion  motion-blur length in pixels along the rows (rendered once)
    spp     supersampling K of the renderer (re-rendered per level)
    poses   number of board poses (re-planned and re-rendered per level)

A method BREAKS at the first level where the target is no longer detected in
every point of every image (detection rate < 100%), the calibrator fails, or
its projection difference (rotation mode, RMS over the image) exceeds
`bar_px`. Every level is still run after a break, so the record shows how the
method degrades.
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
    "spp": {"levels": [1, 2, 4, 8, 16], "unit": "supersampling K", "rerender": True},
    "poses": {"levels": [12, 9, 6, 4, 3], "unit": "board poses", "rerender": True},
}
DEFAULT_BAR_PX = 0.05


class SweepError(CamvalError):
    '''A sweep that cannot be set up (unknown difficulty, bad levels).'''


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


def _finite(v):
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _detect_and_calibrate(truth, target, poses, images, calibrators, level, bar_px):
    from harness import runner
    recs = []
    try:
        dets, t_det = runner.detect_stage(images, target)
    except runner.StageFailed as e:
        for cal, model in calibrators:
            recs.append({"level": level, "calibrator": cal, "model": model, "status": "failed",
                         "stage": "detect", "reason": e.reason, "detection_rate": 0.0,
                         "broken": True})
        return recs
    n_exp = sum(d.n_expected for d in dets)
    n_found = sum(d.n_found for d in dets)
    rate = n_found / max(n_exp, 1)
    obs = runner.observations_from(truth, target, poses, dets)
    for cal, model in calibrators:
        rec = {"level": level, "calibrator": cal, "model": model,
               "detection_rate": rate, "detect_seconds": t_det}
        res = runner.calibrate_stage(cal, obs, target, model, truth, {})
        rec["calibrate_seconds"] = float(res.seconds)
        if res.status != "ok":
            rec.update(status=res.status, stage="calibrate", reason=res.reason,
                       broken=res.status == "failed")
            recs.append(rec)
            continue
        try:
            _, proj, _ = runner.compare_stage(truth, res)
        except Exception as e:   # a comparison that cannot be made: the method broke here
            rec.update(status="failed", stage="compare", reason=runner._reason(e), broken=True)
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


def run_sweep(camera, family="CAHVOR", target="dots", difficulty="noise", levels=None,
              calibrators=(("jpl", "CAHVOR"), ("mrcal", "CAHVOR"), ("opencv", "OPENCV5")),
              renderer="raycast", spp=8, n_poses=6, seed=0, bar_px=DEFAULT_BAR_PX,
              progress=None):
    r'''Run one stability sweep

SYNOPSIS

    sw = run_sweep(15, "CAHVOR", "dots", "noise")

RETURNED VALUE: a dict (JSON-ready) with the setting, levels, records and
breakdown. A stage failing at one level is a record, never an exception.
'''
    from harness import runner
    from renderers.response import ResponseChain
    say = progress or (lambda s: None)
    if difficulty not in DIFFICULTIES:
        raise SweepError(f"unknown difficulty {difficulty!r}; known: {', '.join(DIFFICULTIES)}")
    spec = DIFFICULTIES[difficulty]
    levels = list(spec["levels"] if levels is None else levels)
    if not levels:
        raise SweepError("a sweep needs at least one level")
    job = runner.Job(key="sweep", camera=str(camera), camera_key=str(camera), family=family,
                     target=target, renderer=renderer, settings={}, calibrators=())
    t_start = time.perf_counter()
    entry, truth = runner.camera_stage(job)
    tgt = runner._target(target)
    records = []
    settings = {"spp": int(spp), "adaptive": True}
    base = None
    for i, level in enumerate(levels):
        say(f"{difficulty} = {level}")
        try:
            if spec["rerender"] or base is None:
                n = int(level) if difficulty == "poses" else n_poses
                poses = runner.poses_stage(truth, tgt, n, seed)
                st = dict(settings, spp=int(level)) if difficulty == "spp" else settings
                renders, _, _ = runner.render_stage(renderer, truth, tgt, poses, st)
                images = [r.image for r in renders]
                if not spec["rerender"]:
                    base = (poses, images)
            else:
                poses, images = base
            chain = ResponseChain.from_config(response_for(difficulty, level))
            if chain.stages:
                images = [chain.apply(im, model=truth, seed=seed * 1000 + 17 * i + k).image
                          for k, im in enumerate(images)]
        except runner.StageFailed as e:
            for cal, model in calibrators:
                records.append({"level": level, "calibrator": cal, "model": model,
                                "status": "failed", "stage": e.stage, "reason": e.reason,
                                "broken": True})
            continue
        records.extend(_detect_and_calibrate(truth, tgt, poses, images, calibrators, level,
                                             bar_px))
    return {"difficulty": difficulty, "unit": spec["unit"], "levels": levels,
            "camera": str(camera), "camera_label": f"{entry.rover} {entry.role} {entry.side}",
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
                why = rec.get("reason") or (
                    f"detection rate {100 * rec['detection_rate']:.1f}%"
                    if rec.get("detection_rate", 1.0) < 1.0 else
                    f"projection difference {rec.get('projection_rms_px') or math.nan:.3g} px RMS")
                out[key] = {"level": lv, "reason": why}
    return out


def stability_chart(sweep, path):
    r'''One stability chart: projection difference per method against the level,
breakdown points marked, detection rate on a second axis'''
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    ax2 = ax.twinx()
    levels = sweep["levels"]
    xs = np.arange(len(levels))
    keys = sorted({f"{r['calibrator']}/{r['model']}" for r in sweep["records"]})
    for k, key in enumerate(keys):
        ys = []
        for lv in levels:
            r = next((r for r in sweep["records"] if r["level"] == lv
                      and f"{r['calibrator']}/{r['model']}" == key), None)
            v = r.get("projection_rms_px") if r else None
            ys.append(np.nan if v is None else v)
        ax.plot(xs, ys, "o-", color=f"C{k}", label=key)
        b = sweep["breakdown"].get(key, {}).get("level")
        if b is not None:
            ib = levels.index(b)
            ax.axvline(ib, color=f"C{k}", ls=":", alpha=0.7)
            ax.plot([ib], [ys[ib] if np.isfinite(ys[ib]) else sweep["bar_px"]], "X",
                    color=f"C{k}", ms=14)
    rates = []
    for lv in levels:
        rs = [r.get("detection_rate", np.nan) for r in sweep["records"] if r["level"] == lv]
        rates.append(np.nanmax(rs) if rs else np.nan)
    ax2.plot(xs, 100 * np.asarray(rates, float), "s--", color="0.5", label="detection rate")
    ax2.set_ylabel("detection rate, %")
    ax2.set_ylim(0, 105)
    ax.axhline(sweep["bar_px"], color="k", lw=0.8, ls="--")
    ax.set_yscale("log")
    ax.set_xticks(xs, [str(v) for v in levels])
    ax.set_xlabel(sweep["unit"])
    ax.set_ylabel("projection difference, px RMS (rotation mode)")
    ax.set_title(f"stability: {sweep['difficulty']} - camera {sweep['camera']} "
                 f"({sweep['camera_label']}), {sweep['family']}, {sweep['target']}; "
                 "X = breakdown", fontsize=9)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)

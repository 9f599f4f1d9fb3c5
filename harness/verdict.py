r'''How much of a record's error the images caused: floor, renderer and total

SYNOPSIS

    from harness import verdict

    obs_x = verdict.exact_observations(obs, truth, target)   # what a perfect renderer
                                                              # and detector give
    noise = verdict.detection_noise(obs, obs_x)               # detected - exact, px
    res_x = calibrate_stage(cal, obs_x, target, model, truth, options)
    v = verdict.assess(truth, res, res_x, noise, total_params, total_projection)
    v["floor"]["projection"]["rms"]      # exact-observation fit vs the truth, px
    v["renderer"]["projection"]["rms"]   # image fit vs exact-observation fit, px
    v["total"]["projection"]["rms"]      # image fit vs the truth (the record's headline)
    v["floor_far"], v["floor_reason"]    # a floor the images cannot be judged through

Three comparisons, each with parameter differences and projection differences:

- floor:    the fit of the EXACT observations of the same poses vs the truth: what
            this calibrator and model can do at all (representability, gauge
            runoff, an unconstrained model). Exact observations are the exact
            dot centroids (targets.centroids.expected_centroids of the truth at the
            poses) or, for corner targets, the corners the detector finds on
            camval's exact render of the poses (reference_corners: the corner
            refiner's systematic errors are the detector's, not the renderer's);
            only the points the detector found are kept, so both fits see the
            same points.
- renderer: the image fit vs the exact-observation fit: what the images cost. A
            deterministic calibrator's runoff and misfit are the same in both
            fits and cancel here: this is the renderer's verdict.
- total:    the image fit vs the truth: the record's params and projection.

Two fits of any model are compared by fit_parameter_differences() and
fit_projection_difference(): the same quantities as harness.compare (Hc, Vc
px; Hs, Vs fractional; the rest for JPL-family fits), the projection
difference over the truth's image grid with a fitted rotation between the two
fits' camera frames (mode "rotation", the headline), none ("intrinsics") or
the world frames identified ("world", both fits in the world frame). The floor
and renderer comparisons compute the modes asked (assess(modes=...): a campaign's
verdict_modes, harness.campaign.VERDICT_MODES by default: "rotation" only, the
one the gate, the report and the sigma read); the total is the record's own,
with every mode.

Expected scatter (scatter()): the covariance of the image fit from its
Jacobian at the solution, under the detection noise of each image, gives a
sigma for every reported parameter and for the projection RMS over the image;
verdict.renderer.z holds each renderer difference over its sigma, and
verdict.renderer.joint all of them at once by their full covariance (chi2, dof
and its equivalent Gaussian z: joint_statistic). The notes
above scatter() say where that noise model stops holding.

Twins (harness.jobs): the exact observations are computed from camera-frame
quantities (the planned board poses, the truth in its own camera frame:
harness.jobs.camera_frame_model), the same bits for twin cameras, so a campaign
computes them once, and the exact fit of a calibrator that does not read the world
frame too (exact_fit). Bit for bit matters: computed from each camera's world frame
they agree to ~1e-12 px only, and an ill-conditioned fit lands far apart from such
differences (mrcal CAHVOR of camera 17: px), which would make a twin's shared record
differ from its unshared one. jpl reads the world frame and fits every camera.

The exact fit starts from the image fit (exact_fit(start=...), harness.job_records):
the two sets of observations differ by the detection error (~1e-3 px), so it converges
in a few steps and in the image fit's own minimum. jpl and OpenCV land where their cold
fits land (projection within 1e-11 and 1e-8 px); mrcal skips its seed, race and
restarts and so no longer crawls along its flat R0 / focal-length valleys into another
minimum than the image fit's (quick campaign, camera 17 CAHVOR: cold floor 0.0107 px,
warm 1.1e-7 px); where the cold fit was in the image fit's minimum the floors differ
by < 2e-5 px (tests/test_verdict.py holds warm = cold to 1e-5 px on navcam 15).

A floor is "far" when it exceeds both what the images can show (the measured
detection noise, detected minus exact positions) and FLOOR_TOLERANCE_PX: the
record's total error is then the calibrator's, not the images'; floor_reason
says so in words, with the cause where it can be named (mrcal's and OpenCV's
model frames hold theta at 90 deg; residuals on exact observations = the
model cannot represent the camera; small residuals = the observations leave
the model unconstrained).
'''

import functools
import math
import threading

import numpy as np

from reference_models.cahvore import FAMILIES as JPL_FAMILIES
from reference_models.cahvore import solve_theta_each, with_R0
from reference_models.poseutils import transform_point_Rt

from .campaign import VERDICT_MODES
from .compare import (
    DEFAULT_GRID_STEP,
    DEFAULT_RANGE_M,
    _distance,
    _fit_rotation,
    _frac,
    _intrinsics,
    _projector,
    _rotated_into,
    fit_pixels,
    parameter_errors,
    truth_points,
)

# A floor below this many px cannot mislead anyone: it is below the sampling error of
# the image centroid of a 10 px dot (targets.centroids: 0.03 r^-1.5 px = 0.001 px) ten
# times over, and a hundredth of the 0.5 px a navigation camera's error budget allows.
FLOOR_TOLERANCE_PX = 0.01
# theta differing from 90 deg by more than this (deg) is named as the cause of a far floor
# for a calibrator whose model frame holds theta at 90 deg (mrcal, OpenCV, COLMAP): at
# 1000 px from the centre 1e-4 deg moves a pixel by 1.7e-3 px * f/1000 px
THETA_NAMED_DEG = 1e-4
# parameter_errors' names a non-JPL fit does not estimate (None: "not estimated")
JPL_ONLY_PARAMS = ("Hs*(1+R0)", "Vs*(1+R0)", "theta_deg", "C_mm", "A_deg", "O_deg", "roll_deg",
                   "R0", "R0_frac", "R1", "R1_frac", "R2", "R2_frac", "E0", "E1", "E2")
# the fit of exact observations "cannot represent" the camera when its residual RMS is
# this many times the detection noise (and above FLOOR_TOLERANCE_PX / 10)
MISFIT_FACTOR = 3.0


def Rt_cam_board_from(obs, truth):
    r'''The board poses (Nposes,4,3) in the truth's camera frame, from obs.Rt_ref_board'''
    Rt_ref_cam = truth.Rt_ref_cam()
    R, t = Rt_ref_cam[:3], Rt_ref_cam[3]
    out = []
    for Rt in obs.Rt_ref_board:
        out.append(np.vstack((R.T @ Rt[:3], R.T @ (Rt[3] - t))))
    return np.array(out)


# The reference render of a corner target's exact observations (reference_corners): camval's
# exact ray caster with exact-area coverage of edge pixels (pixel values to 1e-4 of their
# value: corner positions to ~1e-4 px), K only for the few pixels area coverage cannot
# integrate.
REFERENCE_RENDER = {"renderer": "raycast", "spp": 16, "adaptive": True,
                    "options": {"coverage": "area"}}


def is_reference_render(renderer, settings, response=None):
    r'''True when a job's images ARE the reference render (REFERENCE_RENDER, no camera
response): its detections are then the reference corners, bit for bit (the same
deterministic render and detector), and reference_corners need not render again'''
    from renderers.response import STAGES

    from .records import renderer_key
    if renderer != REFERENCE_RENDER["renderer"] or any(k in STAGES for k in (response or {})):
        return False
    own = {k: settings.get(k) for k in ("spp", "adaptive", "options")}
    ref = {k: REFERENCE_RENDER[k] for k in ("spp", "adaptive", "options")}
    return renderer_key(renderer, own) == renderer_key(renderer, ref)


def exact_observations(obs, truth, target, reference=None, Rt_cam_board=None):
    r'''The observations a perfect renderer would give, at the same poses

SYNOPSIS

    obs_x = exact_observations(obs, truth, target)   # obs.q replaced; same mask
    obs_x = exact_observations(obs, truth, target, Rt_cam_board=poses)   # the planned
                                                     # camera-frame poses (Nposes,4,3)

Rt_cam_board: the board poses in the truth's camera frame, as the campaign planned
them (harness.stages.poses_stage); None: from the surveyed poses of obs
(Rt_ref_board, as observations_from gives: Rt_cam_board_from, one rigid motion and
back). The positions are computed through the truth in its own camera frame
(harness.jobs.camera_frame_model): from the planned poses they are then the same
bits for two twin cameras (harness.jobs), which a campaign computes once (exact_fit).

For a dot target, the exact dot centroids (a perfect renderer and a
perfect detector: the dot detector's errors on exact renders are small and
independent from dot to dot, ~0.0005 px). For corner targets, the corners the
detector finds on a perfect render (reference_corners): the corner refiner's
errors on exact renders are systematic (up to ~0.001 px, the same for the same
corner geometry, correlated along each edge), so exact projections would charge
them to the renderer: the verdict's independent-noise scatter put a perfect
renderer's AprilTag records at z 7-17. Against the reference render they cancel,
and the floor holds the detector's share. NaN where obs has NaN (the detector did
not find the point) or the truth cannot image the point; a corner found in the
images but not on the reference render takes its exact projection. reference: the reference
corners when the caller has them (the job's own detections when its images are the
reference render: is_reference_render), else they are rendered here. The exact
observations' corner blurs (Observations.corner_blur_px, what the bias step corrects the
board lines' corners under) are those of the reference corners' detections: obs's for
the job's own, the reference render's (sharp: None) otherwise, never the blur of images
the reference corners were not detected on. So are their tag edges' span records
(Observations.corner_spans, what the bias step computes a TAG_EDGES corner's bias from):
the reference render's own detections' (None when none recorded any), obs's only when obs's
detections are the reference; never the spans of corners other than the reference ones.
The corners' predicted errors (Observations.corner_sigma_px) are obs's, the images': they
say how the image's noise moves each corner, which the exact corners have none of, and a
fit weighted by them fits the exact observations as it fits the images' (the same weights).
'''
    from targets.centroids import expected_centroids, projected_points

    from .jobs import camera_frame_model
    if Rt_cam_board is None:
        Rt_cam_board = Rt_cam_board_from(obs, truth)
    Rts = np.asarray(Rt_cam_board, dtype=np.float64)
    camera = camera_frame_model(truth)
    exact = expected_centroids if target.kind == "dots" else projected_points
    q = np.stack([exact(camera, target, Rt) for Rt in Rts])
    model, blur, spans = None, None, None
    if target.kind != "dots":
        if reference is None:
            ref, model, blur, spans = reference_corners(camera, target, Rts)
            blur = blur if blur.any() else None
        else:
            # the job's own detections: their corner models, blurs and spans are obs's
            ref, model = np.asarray(reference, dtype=np.float64), obs.corner_model
            blur, spans = obs.corner_blur_px, obs.corner_spans
        q = np.where(np.isfinite(ref), ref, q)
        # a corner the reference render did not give takes its exact projection, which
        # has no corner bias to correct
        if model is not None:
            model = np.where(np.isfinite(ref[..., 0]), model, EXACT_PROJECTION)
            model = np.where(obs.found, model, "")
    q = np.where(obs.found[..., None], q, np.nan)
    return obs.replace(q=q, corner_model=model, corner_blur_px=blur, corner_spans=spans)


# the corner model of an exact observation that is the corner's projection (Observations
# .corner_model): not a detector's, no corner bias
EXACT_PROJECTION = "exact projection"


def reference_corners(truth, target, Rts):
    r'''The detector's points on camval's exact renders of the poses (REFERENCE_RENDER):
(Nposes,Npoints,2), NaN where it finds none, their corner models (Nposes,Npoints) str
(Detection.corner_model; None when the detector does not record them), the blurs
their board lines' corners were fitted under (Nposes,) px (Detection.corner_blur_px) and
their tag edges' span records (Nposes,Npoints,2,R) (Detection.corner_spans, NaN for a pose
without; None when no pose has any, as on sharp renders); one image in memory at a time'''
    from renderers.base import RenderSettings
    from targets.detect import detect
    from targets.detection import stack_corner_models, stack_corner_spans

    from .stages import cached_renderer
    renderer = cached_renderer(REFERENCE_RENDER["renderer"])
    rs = RenderSettings(spp=REFERENCE_RENDER["spp"], adaptive=REFERENCE_RENDER["adaptive"],
                        options=dict(REFERENCE_RENDER["options"]))
    pattern = target.pattern()
    out, models, blurs, spans = [], [], [], []
    for Rt in Rts:
        image = renderer.render(truth, pattern, Rt, rs).image
        det = detect(image, target)
        out.append(np.asarray(det.q, dtype=np.float64))
        models.append(det.corner_model)
        blurs.append(float(getattr(det, "corner_blur_px", 0.0)))
        spans.append(getattr(det, "corner_spans", None))
        del image
    q = np.stack(out)
    return q, stack_corner_models(models, q), np.array(blurs), stack_corner_spans(spans)


def detection_noise(obs, obs_exact, bias=None):
    r'''Detected minus exact positions: {"rms", "max", "n", "per_pose_rms", "mean"} px

per_pose_rms[i] is the RMS of |detected - exact| over the points of image i
(None for an image without points); mean is the mean offset (dx, dy) over all.
bias: None, or (b, b_exact) (Nposes,Npoints,2): each one's corner bias under the truth
(corner_biases), taken off before the difference: a blurred chessboard's corners carry
their lines' bias, the sharp reference corners the window's, and what the calibrators'
bias step removes from each is no noise (camera 1 CAHVORE realistic: 0.0123 px with it,
0.0024 without, the corners' own error against their projections).
'''
    d = obs.q - obs_exact.q
    if bias is not None:
        d = d - (bias[0] - bias[1])
    ok = np.all(np.isfinite(d), axis=-1)
    n2 = np.sum(d * d, axis=-1)
    per = [float(math.sqrt(n2[i][ok[i]].mean())) if ok[i].any() else None
           for i in range(d.shape[0])]
    if not ok.any():
        return {"n": 0, "rms": None, "max": None, "per_pose_rms": per, "mean": None}
    return {"n": int(ok.sum()), "rms": float(math.sqrt(n2[ok].mean())),
            "max": float(math.sqrt(n2[ok].max())), "per_pose_rms": per,
            "mean": [float(x) for x in d[ok].mean(axis=0)]}


def corner_biases(obs, obs_x, truth, target, Rt_cam_board):
    r'''(b, b_exact): the corner bias (harness.calibrators.bias.bias_step, under the truth in
its camera frame and the camera-frame poses) of the detections and of the exact
observations, each under its own corner models, blurs and tag edges' span records
(Observations.corner_spans: a TAG_EDGES corner's bias is tag_edges_bias of its own spans);
None for dots, or when both were fitted alike (the same corner models, blurs and spans: the
biases are the same and cancel)'''
    if getattr(target, "kind", "dots") == "dots" or obs.corner_model is None or \
            Rt_cam_board is None:
        return None
    same_model = obs_x.corner_model is not None and np.array_equal(obs.corner_model,
                                                                    obs_x.corner_model)
    blur, blur_x = obs.corner_blur_px, obs_x.corner_blur_px
    same_blur = (blur is None and blur_x is None) or (
        blur is not None and blur_x is not None and np.array_equal(blur, blur_x))
    spans, spans_x = obs.corner_spans, obs_x.corner_spans
    same_spans = (spans is None and spans_x is None) or (
        spans is not None and spans_x is not None and
        np.array_equal(spans, spans_x, equal_nan=True))
    if same_model and same_blur and same_spans:
        return None
    from harness.calibrators.bias import bias_step

    from .jobs import camera_frame_model
    camera = camera_frame_model(truth)
    b, _ = bias_step(camera, target, Rt_cam_board, obs.p_board, corner_model=obs.corner_model,
                     corner_blur_px=blur, corner_spans=spans, corner_q=obs.q)
    bx, _ = bias_step(camera, target, Rt_cam_board, obs.p_board,
                      corner_model=obs_x.corner_model, corner_blur_px=blur_x,
                      corner_spans=spans_x, corner_q=obs_x.q)
    if b is None or bx is None:
        return None
    return np.nan_to_num(b), np.nan_to_num(bx)


def _is_jpl(m):
    return getattr(m, "family", None) in JPL_FAMILIES


def _distortion(m):
    r'''The distortion coefficients of a non-JPL fit (OpenCV dist, mrcal intrinsics[4:])'''
    if hasattr(m, "dist"):
        return np.asarray(m.dist, dtype=np.float64).ravel()
    if hasattr(m, "intrinsics"):
        return np.asarray(m.intrinsics, dtype=np.float64).ravel()[4:]
    return np.zeros(0)


def _roll_deg(ref, fit):
    r'''The roll of fit's image axes about ref's A, deg: the angle from ref's H' to fit's H'
(projected on the plane perpendicular to ref's A), signed about A. Of world-frame fits only
(jpl on surveyed points): a sensor rolled about A keeps Hc, Vc, Hs, Vs, theta, C, A and O,
and moved the image 0.0064 px RMS at 0.001 deg on a 1000x800 camera (campaigns/cameras/
aspect-1000x800.cahvor) with no reported quantity seeing it (h-unseen, benchmarks/
renderer_gate.py's roll fault: 0 of 6 cameras flagged); a pose-fitting calibrator (mrcal,
OpenCV) takes the roll into its board poses.'''
    a = np.asarray(ref.A, dtype=np.float64)
    h0 = ref.photogrammetric().Hp
    h1 = fit.photogrammetric().Hp
    h1 = h1 - (h1 @ a) * a
    return math.degrees(math.atan2(float(np.cross(h0, h1) @ a), float(h0 @ h1)))


def fit_parameter_differences(ref, fit, theta_estimated=None, world_frame=None, signed=False):
    r'''fit - ref for two fits of one calibrator model (any model)

SYNOPSIS

    d = fit_parameter_differences(exact_fit, image_fit, theta_estimated=True,
                                  world_frame=True)

JPL-family fits: harness.compare.parameter_errors with ref as the truth (ref
moved to fit's R0 first; signed: its vectors by component). Others: Hc, Vc
(px), Hs, Vs (fractional) and D0, D1, ... the differences of the distortion
coefficients.
'''
    if _is_jpl(ref) and _is_jpl(fit):
        out = parameter_errors(ref, fit, theta_estimated=theta_estimated,
                               world_frame=world_frame, signed=signed)
        out["roll_deg"] = _roll_deg(ref, fit) if out.get("A_deg") is not None else None
        return out
    Hc, Vc, Hs, Vs = _intrinsics(fit)
    rHc, rVc, rHs, rVs = _intrinsics(ref)
    out = {"Hc": float(Hc - rHc), "Vc": float(Vc - rVc), "Hs": _frac(Hs, rHs),
           "Vs": _frac(Vs, rVs)}
    da, db = _distortion(fit), _distortion(ref)
    for i in range(min(len(da), len(db))):
        out[f"D{i}"] = float(da[i] - db[i])
    for k in JPL_ONLY_PARAMS:     # not estimated by this model (as parameter_errors says)
        out.setdefault(k, None)
    return {k: (None if v is None else float(v)) for k, v in out.items()}


def fit_projection_difference(ref, fit, truth, mode="rotation", range_m=DEFAULT_RANGE_M,
                              step=DEFAULT_GRID_STEP):
    r'''|fit - ref| in projection over the truth's image grid, for two fits of any model

SYNOPSIS

    d = fit_projection_difference(exact_fit, image_fit, truth, mode="rotation")
    d["rms"], d["max"], d["n"], d["n_invalid"]      # px; d["map"] (ny,nx)

The sample points are the truth's: points at range_m along its rays through
the image grid, in its camera frame (harness.compare.truth_points), or, when
both fits are CAHVOR/CAHVORE in the same R0 gauge (jpl holds R0), in the frame
of the truth moved to that gauge: the points the record's floor and total
compare each fit on, so ref's and fit's pixels of them are shared (fit_pixels'
memo; the two frames differ by the gauge's small turn of A, which moves the grid's
rays by a fraction of a pixel over a smooth difference map). Each fit projects
them from its own camera frame, one of the two rotated by the rotation that best
matches the other's pixels (mode "rotation"), neither rotated ("intrinsics"), or
both fits project the world points ("world": both must live in the truth's world
frame). The grid is projected as harness.compare.projection_difference
projects it (compiled for JPL-family fits: _projector); the rotation is fitted
as it fits it (_fit_rotation).

Which fit mode "rotation" rotates: ref, onto fit's unrotated pixels, where those are
the pixels fit's own comparison with the truth projected already (mode "intrinsics"
on the same points: fit_pixels' memo; the image fit's record compares it just before
its verdict), which saves a projection of the whole grid; fit, onto ref's, where ref
was moved to another R0 gauge (the points are then the truth's own frame's, not
those of the record's comparison). The two minima are the same comparison to second
order in the rotation between the fits: rotating the exact fit instead of the image
fit moved the paper campaign's renderer projection RMS and max by < 4e-4 of their
sigma (benchmarks/bench_verdict.py, 154 records). In the moved case it moved the
mrcal CAHVOR records, whose fits differ by a larger rotation, by up to 0.11 sigma
(unjudged: their floors are far), and would save nothing: fit keeps being rotated.
'''
    same = fit is ref   # a fit compared with itself: no difference to measure (see below)
    world_ref = ref     # world points: the same pixels in any R0 gauge (fit_pixels' memo)
    R0, moved = None, False
    if not same and getattr(fit, "family", None) in ("CAHVOR", "CAHVORE") and \
            getattr(ref, "family", None) in ("CAHVOR", "CAHVORE"):
        R0 = float(fit.R[0])
        if float(ref.R[0]) != R0:
            # the same projection in fit's R0 gauge, on the truth's own frame's points
            ref, R0, moved = _moved_to_R0(ref, R0), None, True
    _, p_ref, p_cam = truth_points(truth, range_m, step, R0=R0)
    with np.errstate(all="ignore"):
        if mode == "world":
            qa = fit_pixels(world_ref, p_ref, False)
            qb = qa if same else fit_pixels(fit, p_ref, False)
            R = None
        elif same:
            # the fit against itself (an exact fit that IS the image fit: exact_fit's
            # reuse): exactly zero where it projects, the rotation exactly none; the
            # fitted rotation and second projection only measured their own rounding
            # (1e-12 px)
            qa = qb = fit_pixels(ref, p_cam, True)
            R = np.eye(3)
        elif mode == "rotation" and not moved:
            # ref rotated onto fit's own pixels (see the docstring)
            qb = fit_pixels(fit, p_cam, True)
            R = _fit_rotation(ref, p_cam, qb)
            qa = _projector(ref)(_rotated_into(ref.Rt_ref_cam(), p_cam, R))
        elif mode == "rotation":
            qa = fit_pixels(ref, p_cam, True)
            R = _fit_rotation(fit, p_cam, qa)
            qb = _projector(fit)(_rotated_into(fit.Rt_ref_cam(), p_cam, R))
        else:
            qa, qb = fit_pixels(ref, p_cam, True), fit_pixels(fit, p_cam, True)
            R = np.eye(3)
    d = _distance(qa, qb)
    finite = np.isfinite(d)
    out = {"mode": mode, "range_m": range_m, "step": step, "map": d,
           "n": int(finite.sum()), "n_invalid": int((~finite).sum()),
           "rms": float(np.sqrt(np.mean(d[finite] ** 2))) if finite.any() else None,
           "max": float(d[finite].max()) if finite.any() else None}
    if R is not None:
        out["rotation_deg"] = math.degrees(math.acos(max(-1.0, min(1.0,
                                                                   (np.trace(R) - 1) / 2))))
    return out


# _moved_to_R0's last (model, R0, moved model): fit_comparison compares the same two fits in
# each mode, and the moved model, the same object each time, keeps fit_pixels' memo of its
# pixels (mode "intrinsics" reuses mode "rotation"'s: one projection of the image grid less)
_MOVED = [None]


def _moved_to_R0(model, R0):
    r'''with_R0(model, R0), kept for the last model and R0 asked (models are frozen: keyed
on the object itself)'''
    hit = _MOVED[0]
    if hit is not None and hit[0] is model and hit[1] == R0:
        return hit[2]
    moved = with_R0(model, R0)
    _MOVED[0] = (model, R0, moved)     # one tuple: atomic for a worker's threads
    return moved


def _world(res):
    return res.world_frame


def fit_comparison(ref, fit, truth, theta_estimated, world_frame, modes=VERDICT_MODES):
    r'''{"params": fit_parameter_differences, "projection": {"rms", "max", mode: {...}}}

modes: the projection-difference modes computed ("rotation" among them; "world" only
when world_frame)'''
    params = fit_parameter_differences(ref, fit, theta_estimated=theta_estimated,
                                       world_frame=world_frame)
    proj = {}
    for mode in modes:
        if mode == "world" and not world_frame:
            continue
        d = fit_projection_difference(ref, fit, truth, mode=mode)
        proj[mode] = {k: v for k, v in d.items() if k != "map"}
    proj["rms"] = proj["rotation"]["rms"]
    proj["max"] = proj["rotation"]["max"]
    return {"params": params, "projection": proj}


def floor_comparison(truth, exact_res, modes=VERDICT_MODES):
    r'''The exact-observation fit vs the truth: harness.stages.compare_stage's figures, in
the projection-difference modes asked'''
    from .stages import compare_stage
    params, projection, _ = compare_stage(truth, exact_res, modes=modes)
    return {"params": params, "projection": projection}


def _in_modes(projection, modes):
    r'''A record's projection ({"rms", "max", mode: {...}}) with only the modes asked'''
    return {k: v for k, v in projection.items() if k in ("rms", "max") or k in modes}


def _theta_deg(model):
    if _is_jpl(model):
        return float(model.photogrammetric().theta_deg)
    return None


def unrepresentable(truth, calibrator):
    r'''[reason, ...]: what of the truth calibrator's model frame cannot hold, in words

Only what the truth alone shows: theta (every non-JPL calibrator's frame holds
theta at 90 deg; named beyond THETA_NAMED_DEG). Used by floor_judgement and by
a failed fit's reason (harness.job_records): a fit that ends above max_rms
because its model cannot represent the camera has not "diverged".
'''
    th = _theta_deg(truth)
    if calibrator != "jpl" and th is not None and abs(th - 90.0) > THETA_NAMED_DEG:
        return [f"{calibrator}'s model frame cannot represent theta = {th:.6g} deg"]
    return []


def floor_judgement(truth, calibrator, model_name, floor_projection, exact_residuals, noise):
    r'''(far, reason): is the floor beyond what the images can show, and why in words

far: the floor's projection difference (rotation-mode RMS) exceeds both the
measured detection noise RMS and FLOOR_TOLERANCE_PX. The reason names the
cause where it can: theta (a model frame holding theta at 90 deg), a misfit
of the exact observations (residual RMS above MISFIT_FACTOR x the noise: the
model cannot represent the camera, or, for a model of the truth's own family
with no theta named, the solver stopped short), or an unconstrained model (exact
observations fitted, the model still far from the truth).
'''
    rms = (floor_projection or {}).get("rms")
    if rms is None:
        return False, ""
    noise_rms = (noise or {}).get("rms") or 0.0
    limit = max(FLOOR_TOLERANCE_PX, noise_rms)
    if rms <= limit:
        return False, ""
    what = f"{calibrator} {model_name}"
    fl = f"floor {rms:.3g} px"
    causes = unrepresentable(truth, calibrator)
    res_rms = (exact_residuals or {}).get("rms")
    if res_rms is not None and res_rms > max(MISFIT_FACTOR * noise_rms,
                                             FLOOR_TOLERANCE_PX / 10):
        # a misfit of a model of the truth's own family, with no theta named, is the
        # solver's: that family holds the truth exactly
        family = getattr(truth, "family", None)
        why = (f"its solver stopped short: the truth is a {family}, which it can represent"
               if family is not None and model_name == family and not causes else
               "its model cannot represent the camera, or its solver stopped short")
        causes.append(f"{what} cannot fit the exact observations (residual RMS "
                      f"{res_rms:.3g} px; {why})")
    elif not causes:
        causes.append(f"the exact observations leave {what} unconstrained (residual RMS "
                      f"{res_rms if res_rms is None else format(res_rms, '.3g')} px, yet far "
                      f"from the truth)")
    return True, (f"{'; '.join(causes)}: {fl} (exact-observation fit vs truth; detection "
                  f"noise {noise_rms:.3g} px, tolerance {FLOOR_TOLERANCE_PX:g} px): the total "
                  f"error is the calibrator's, not the images'")


def minima_judgement(res, exact_res, noise):
    r'''(disagree, reason): did the two fits land in different minima?

The image fit could take the exact fit's parameters: its residuals would then
be at most the detection errors plus the exact fit's residuals, so its RMS
residual cannot exceed noise RMS + exact RMS unless it stopped short of the
best fit of its detections (and symmetrically for the exact fit). Beyond
MISFIT_FACTOR times that bound (and FLOOR_TOLERANCE_PX / 10) the two fits sit
in different minima of the calibrator's problem (mrcal CAHVOR of camera 5:
image fit 0.023 px, exact fit 4e-9 px, detection errors 0.0012 px): their
difference is the calibrator's, not the images'.
'''
    a = (res.residual_stats() or {}).get("rms")
    b = (exact_res.residual_stats() or {}).get("rms")
    n = (noise or {}).get("rms") or 0.0
    if a is None or b is None:
        return False, ""
    for x, y, what in ((a, b, "image fit"), (b, a, "exact-observation fit")):
        if x > max(MISFIT_FACTOR * (y + n), FLOOR_TOLERANCE_PX / 10):
            return True, (f"the {what} stopped in another minimum: residual RMS "
                          f"{x:.3g} px against {y:.3g} px of the other fit, with detections "
                          f"{n:.3g} px RMS from the exact positions: the difference between "
                          f"the fits is the calibrator's, not the images'")
    return False, ""


def assess(truth, res, exact_res, noise, total_params, total_projection, seconds=None,
           obs=None, modes=VERDICT_MODES):
    r'''The record's "verdict": floor, renderer, total, the exact fit and the noise

res: the image fit (ok); exact_res: the fit of exact_observations() (any status);
noise: detection_noise(); total_params, total_projection: the record's params
and projection (compare_stage); obs: the observations of the image fit (with
the surveyed poses): given, the renderer comparison gets "sigma" (scatter())
and "z" (z_scores()), and the verdict "scatter" (the noise per image, the
numbers fitted) or its "error"; modes: the floor's and renderer's projection-difference
modes (the campaign's verdict_modes; the total keeps the record's). Returns a JSON-able
dict:

    {"floor": {"params", "projection"} | None, "renderer": {...} | None,
     "total": {"params", "projection": {"rms", "max"}},
     "exact_fit": {"status", "reason", "residuals"},   (its seconds: record seconds)
     "detection_noise": noise, "floor_far": bool, "floor_reason": str,
     "fits_disagree": bool, "disagree_reason": str}   (minima_judgement)

A failed exact fit leaves floor and renderer None with exact_fit saying why.
'''
    from . import blas
    with blas.one_thread():
        return _assess(truth, res, exact_res, noise, total_params, total_projection,
                       seconds, obs, modes)


def _assess(truth, res, exact_res, noise, total_params, total_projection, seconds, obs,
            modes):
    from .records import jsonable
    theta = res.theta_estimated
    world = _world(res)
    out = {"total": {"params": total_params,
                     "projection": {k: (total_projection or {}).get(k)
                                    for k in ("rms", "max")}},
           "exact_fit": {"status": exact_res.status, "reason": exact_res.reason,
                         "residuals": exact_res.residual_stats(),
                         **{k: (exact_res.info or {})[k] for k in ("moved_from_start",)
                            if k in (exact_res.info or {})}},
           "detection_noise": noise, "floor": None, "renderer": None,
           "floor_far": False, "floor_reason": "", "fits_disagree": False,
           "disagree_reason": ""}
    if seconds is not None:
        out["seconds"] = seconds
    if exact_res.status != "ok" or exact_res.model is None:
        return jsonable(out)
    if exact_res is res and total_params is not None and total_projection is not None:
        # the exact observations were the image ones (exact_fit returned the image fit):
        # the floor is the record's own comparison, the same function of the same fit
        out["floor"] = {"params": total_params,
                        "projection": _in_modes(total_projection, modes)}
    else:
        out["floor"] = floor_comparison(truth, exact_res, modes)
    out["renderer"] = fit_comparison(exact_res.model, res.model, truth, theta,
                                     world and _world(exact_res), modes)
    far, why = floor_judgement(truth, res.calibrator, res.model_name,
                               out["floor"]["projection"], exact_res.residual_stats(), noise)
    out["floor_far"], out["floor_reason"] = far, why
    out["fits_disagree"], out["disagree_reason"] = minima_judgement(res, exact_res, noise)
    if obs is not None:
        from .stages import failure_reason
        try:
            sc = scatter(res, exact_res, obs, truth, noise)
        except Exception as e:  # the verdict stands without its sigma; say why
            sc = {"error": failure_reason(e)}
        if sc is None:
            sc = {"error": f"no linearisation of a {res.calibrator} {res.model_name} fit "
                           f"(known poses, regularised or another calibrator)"}
        if "sigma" in sc:
            out["renderer"]["sigma"] = sc.pop("sigma")
            out["renderer"]["z"] = z_scores(out["renderer"], out["renderer"]["sigma"])
        if "joint" in sc:
            out["renderer"]["joint"] = sc.pop("joint")
        out["scatter"] = sc
    return jsonable(out)


def exact_fit(cal, model, options, obs, target, truth, cache, start=None, Rt_cam_board=None):
    r'''The calibrator's fit of the exact observations -> (CalibrationResult, noise, reused)

obs: the job's observations (with the surveyed poses); cache: a dict kept for
one camera's records (the exact observations and the detection noise are
computed once per camera; cache["reference"], when the caller sets it, holds the
reference corners: exact_observations). Rt_cam_board: the planned camera-frame board
poses (exact_observations; harness.job_records passes them).

Twins (harness.jobs): the exact observations are computed from the truth in its own
camera frame (harness.jobs.camera_frame_model) and the planned poses, so two twin
cameras, which share the poses and the detections, get the same bits: they are
computed once per process for those bits (_exact_observations), and so is the fit of a
calibrator that does not read the world frame (harness.calibrators.uses_world_frame):
it fits the observations without the surveyed poses, with the camera-frame model as
the truth (a calibrator reads only the truth's type and linearity), so its inputs,
and its result, are the same for every twin. A fit of bit-identical inputs made
earlier in this process (a twin, another renderer of the same camera and poses) is
reused (reused True; see _exact_key). A calibrator that reads the world frame (jpl)
fits each camera: its inputs hold the camera's surveyed poses.

start: None (a cold fit, as the calibrator fits images), or the image fit (an ok
CalibrationResult): a calibrator whose fit() takes start= (jpl, mrcal, OpenCV) fits
the exact observations from it (warm_options()). The exact observations differ from the
image ones by the detection error (~1e-3 px): the fit converges in a few steps, in the
image fit's own minimum (the cold one could land in another: mrcal CAHVOR). A warm fit
is reused only for the same start (bit for bit: _exact_key). When the exact observations
ARE the image observations, bit for bit (a corner target on a job whose images are the
reference render: is_reference_render, its detections are the reference corners), the
start itself is the exact fit (reused True): the calibrators are deterministic, and
fitting the same observations again from the image fit's solution lands on it (the
renderer difference measured 0 to 1e-12 px on every AprilTag record of the paper
campaign) at the cost of a second fit (jpl on an AprilGrid: ~0.4 CPU-s a record).
'''
    from harness.calibrators import uses_world_frame

    from .jobs import camera_frame_model
    from .stages import calibrate_stage
    if "obs" not in cache:
        q, corner_model, blur, spans, cache["noise"] = _exact_observations(
            obs, truth, target, cache.get("reference"), Rt_cam_board)
        cache["obs"] = obs.replace(q=q, corner_model=corner_model, corner_blur_px=blur,
                                   corner_spans=spans)
    obs_x, noise = cache["obs"], cache["noise"]
    if start is not None and np.array_equal(obs_x.q, obs.q, equal_nan=True):
        return start, noise, True
    options = warm_options(cal, options, start)
    if not uses_world_frame(cal, options):
        obs_x, truth = obs_x.replace(Rt_ref_board=None), camera_frame_model(truth)
    key = _exact_key(cal, model, options, obs_x, target, truth)
    with _EXACT_LOCK:
        hit = _EXACT_FITS.get(key)
    if hit is not None:
        return hit, noise, True
    res = calibrate_stage(cal, obs_x, target, model, truth, options)
    with _EXACT_LOCK:
        _EXACT_FITS[key] = res
        while len(_EXACT_FITS) > EXACT_FITS_MEMO:
            del _EXACT_FITS[next(iter(_EXACT_FITS))]
    return res, noise, False


def _exact_observations(obs, truth, target, reference, Rt_cam_board):
    r'''(q, corner model, corner blur, corner spans, detection noise) of
exact_observations(), made once per process for the same bits of what they are computed
from: the truth in its camera frame (harness.jobs.camera_frame_model), the camera-frame
poses, the detections (their mask and the noise), the board and the reference corners.
Twins have the same bits of all of them (exact_fit); from the surveyed poses (Rt_cam_board
None) the poses differ in their last bits, and each camera computes its own.'''
    import hashlib

    from .compare import _model_key
    from .jobs import camera_frame_model
    if Rt_cam_board is None:
        Rt_cam_board = Rt_cam_board_from(obs, truth)
    Rt_cam_board = np.asarray(Rt_cam_board, dtype=np.float64)
    h = hashlib.sha256()
    for a in (Rt_cam_board, obs.q, obs.p_board, reference,
              None if reference is None else obs.corner_model,
              None if reference is None else obs.corner_blur_px,
              None if reference is None else obs.corner_spans):
        h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
    h.update(repr((getattr(target, "name", None), getattr(target, "source", None),
                   target.kind, _model_key(camera_frame_model(truth)))).encode())
    key = h.hexdigest()
    with _EXACT_LOCK:
        hit = _EXACT_OBS.get(key)
    if hit is None:
        obs_x = exact_observations(obs, truth, target, reference, Rt_cam_board)
        for a in (obs_x.q, obs_x.corner_model, obs_x.corner_spans):
            if a is not None:
                a.setflags(write=False)    # shared by the twins' records
        hit = (obs_x.q, obs_x.corner_model, obs_x.corner_blur_px, obs_x.corner_spans,
               detection_noise(obs, obs_x, corner_biases(obs, obs_x, truth, target,
                                                         Rt_cam_board)))
        with _EXACT_LOCK:
            _EXACT_OBS[key] = hit
            while len(_EXACT_OBS) > EXACT_OBS_MEMO:
                del _EXACT_OBS[next(iter(_EXACT_OBS))]
    return hit


# The exact fit depends on the calibrator, its model and options, the exact observations
# (truth, poses, the detected mask), the target and what the calibrator reads of the truth;
# a cold fit (start=None) not on the renderer: the jobs of one camera and pose set under
# several renderers or settings fit it once per process. A warm fit (harness.job_records
# passes the image fit as start) also depends on its start, which is part of the key: it is
# reused only for the same image fit (a warm fit costs a few solver steps; reusing another
# renderer's would measure the image fit against an exact fit near ANOTHER image fit, the
# "different minima" of mrcal's flat valleys). Keyed on every bit of those inputs; the
# calibrators are deterministic, so a hit is the same fit. A fit that does not read the
# world frame is keyed without the surveyed poses and on the camera-frame model: the same
# key for twins (exact_fit).
EXACT_FITS_MEMO = 64
_EXACT_FITS = {}
_EXACT_LOCK = threading.Lock()
# _exact_observations' memo: a job's cameras (a camera and its twins) follow each other
EXACT_OBS_MEMO = 8
_EXACT_OBS = {}


def _exact_key(cal, model, options, obs_x, target, truth):
    import hashlib

    from .compare import _model_key
    h = hashlib.sha256()
    for a in (obs_x.q, obs_x.p_board, obs_x.Rt_ref_board, obs_x.corner_model,
              obs_x.corner_blur_px, obs_x.corner_spans, obs_x.corner_sigma_px):
        h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
    start = options.get("start")
    h.update(repr(_start_key(start)).encode())
    options = {k: v for k, v in options.items() if k != "start"}
    h.update(repr((cal, model, sorted(options.items()), obs_x.imagersize,
                   getattr(target, "name", None), getattr(target, "source", None),
                   _model_key(truth))).encode())
    return h.hexdigest()


def warm_options(cal, options, start):
    r'''options + {"start": start} when the calibrator's fit() takes a start and start is
an ok fit; options unchanged otherwise (a cold fit)'''
    import inspect

    from harness.calibrators import calibrator_module
    if start is None or getattr(start, "status", None) != "ok":
        return options
    try:
        fit = calibrator_module(cal).fit
        if "start" not in inspect.signature(fit).parameters:
            return options
    except (TypeError, ValueError, ImportError):
        return options
    return dict(options, start=start)


def _start_key(start):
    r'''Every number a warm start hands the calibrator (None: a cold fit)'''
    if start is None:
        return None
    h = []
    for a in (getattr(start, "Rt_cam_board", None),
              (start.info or {}).get("intrinsics"), (start.info or {}).get("K"),
              (start.info or {}).get("dist")):
        h.append(None if a is None else np.ascontiguousarray(a, dtype=np.float64).tobytes())
    m = getattr(start, "model", None)
    if _is_jpl(m):
        from .compare import _model_key
        h.append(repr(_model_key(m)))
    return repr(h)


# --- expected scatter: the covariance of a fit from its Jacobian at the solution ---------
#
# Where this noise model stops holding (the z-scores are only as good as these):
# - The detection errors are taken as independent between points, isotropic, with one
#   variance per image. A renderer's sampling error on a dot centroid is a deterministic
#   function of the dot's sub-pixel phase and size: nearly independent between dots of
#   a board, not exactly; neighbouring dots of nearly the same phase err alike. Most of it
#   does not average away with more samples: camera 17 CAHVOR, pose seed 0, detected -
#   exact 0.0023 px RMS at K=16 and 0.0018 px at K=64, the two 76% correlated dot by dot.
#   That record's mrcal renderer difference (paper campaign) is 0.0051 px at a sigma of
#   0.0037 px (z 1.4), with both fits converged (a further warm refit of the image fit
#   moves it 4e-5 px; the exact fit is the truth to 1e-7 px): scatter, not crawl.
# - The variance of image i is the RMS over its points of (image-fit residual -
#   exact-fit residual), scaled by sqrt(2 n_i / (2 n_i - t_i)) for the t_i fitted numbers
#   its rows carry (the fit's leverage over them: noise_per_pose): the detection error
#   left once the model has absorbed what it can. A fault the model
#   absorbs (a shift of the centre, a focal scale) does not inflate it, which is the
#   point; a fault it cannot absorb (jitter, a wrong distortion) counts as noise and
#   lowers the z-scores of the rest. The detected-minus-exact RMS per image is recorded
#   beside it (verdict.detection_noise).
# - Linear: the fit moves linearly with the observations. It stops holding for a
#   parameter whose sigma is a sizeable fraction of its own range (an unconstrained
#   model: a huge sigma says so) or near a model's singularity (theta -> 0 or 180 deg).
# - The dot-centroid bias correction is held fixed (it depends on the model to second
#   order); regularised fits (mrcal SPLINED) are not linearised (their sigma is None).
# - Pose-estimating calibrators (mrcal, OpenCV without known poses) are linearised in
#   the intrinsics and every board pose; the jpl calibrator in its own chart (C, A, H,
#   V, O, R1, R2, E; R0 held, as the fit holds it: harness.calibrators.jpl_fit).

# parameters whose differences are magnitudes: their sigma is that of the vector
VECTOR_PARAMS = ("C_mm", "A_deg", "O_deg")
PROJECTION_SAMPLES = 1200      # grid points the projection sigma is evaluated on


class Linearisation:
    r'''A fit as a function of its parameters: x0, residual pixels and the model

x0:        (n,) the fit's parameters at the solution
project:   x -> (2N,) the projections of the fit's observed points (pose-major)
model:     x -> the fitted model (a JPL model, OpenCVModel, MrcalModel)
pose:      (N,) the image of each observed point
n_model:   the model depends on x[:n_model] only (the rest: board poses)
quantity_jacobian: (m0, ref, names, theta_estimated, qvec) -> (len(names), n_model)
           d qvec(model(x)) / d x[:n_model] at x0 (m0 = model(x0); qvec: the quantities
           _signed_quantities names, against ref), where it is known in closed form
           (jpl_quantity_jacobian), or None (or returning None: stepped models)
grid_jacobian: P -> (Jg, Jw): Jg (2M, n_model) d _grid_projector(P)(model(x)) /
           d x[:n_model] at x0, in closed form (jpl_grid_jacobian) or the calibrator's own
           (mrcal), and Jw (2M, 3) its derivatives in a turn of the points
           (_projection_sigma), or None
row_weights: None (an unweighted fit), or (2N,) what the fit multiplied each residual row
           by (rows as project's: x, y of each point, pose-major): the fit minimised
           |w (q - project(x))|^2, so its covariance is (J^T W J)^-1 J^T W D W J
           (J^T W J)^-1 with W = diag(row_weights^2): the scatter's J rows and D's
           variances are scaled by w and w^2 (jpl_linearisation: the jpl fit's
           info["weights"], jpl_fit.point_weights)
'''

    def __init__(self, x0, project, model, pose, steps, n_model=None, jacobian=None,
                 quantity_jacobian=None, grid_jacobian=None, row_weights=None):
        self.x0, self.project, self.model, self.pose, self.steps = x0, project, model, pose, steps
        self.row_weights = row_weights
        self.quantity_jacobian, self.grid_jacobian = quantity_jacobian, grid_jacobian
        self.n_model = len(x0) if n_model is None else n_model
        self._jacobian = jacobian

    def jacobian(self):
        r'''(2N, n) d project / d x at x0 (central differences; the fit's own jacobian(),
where it gives them faster: jpl_linearisation, posed_linearisation)'''
        if self._jacobian is not None:
            return self._jacobian()
        return _central_jacobian(self.project, self.x0, self.steps)

    def model_jacobians(self, fs, cols=None):
        r'''[d f(model(x)) / d x[:n_model] for f in fs]: each (len(f), n_model), or its
columns cols only (len(f), len(cols))

Central differences, as _central_jacobian takes them (the same numbers), with each
stepped model built once for every f (and without its geometry's checks:
reference_models.cahvore.checked_once): building a model and its frame costs as much
as a function of it.'''
        from reference_models.cahvore import checked_once
        n, rest = self.n_model, self.x0[self.n_model:]
        x0, h = self.x0[:n], self.steps[:n]
        out = [[] for _ in fs]
        for i in (range(n) if cols is None else cols):
            xp, xm = x0.copy(), x0.copy()
            xp[i] += h[i]
            xm[i] -= h[i]
            with checked_once():    # steps of the fitted model, checked by the fit
                mp = self.model(np.concatenate((xp, rest)))
                mm = self.model(np.concatenate((xm, rest)))
            for c, f in zip(out, fs, strict=True):
                c.append((np.asarray(f(mp), dtype=np.float64).ravel()
                          - np.asarray(f(mm), dtype=np.float64).ravel()) / (xp[i] - xm[i]))
        return [np.stack(c, axis=-1) for c in out]


def _central_jacobian(f, x0, h):
    cols = []
    for i in range(len(x0)):
        xp, xm = x0.copy(), x0.copy()
        xp[i] += h[i]
        xm[i] -= h[i]
        cols.append((np.asarray(f(xp), dtype=np.float64).ravel()
                     - np.asarray(f(xm), dtype=np.float64).ravel()) / (xp[i] - xm[i]))
    return np.stack(cols, axis=-1)


def jpl_linearisation(res, obs):
    r'''The jpl fit in its own chart (harness.calibrators.jpl_fit; R0 held) -> Linearisation,
with the fit's row weights (Linearisation.row_weights) where it was weighted'''
    from harness.calibrators.jpl_fit import _Chart
    from reference_models.kernels import project
    m = res.model
    R0 = float(m.R[0]) if m.family != "CAHV" else 0.0
    chart = _Chart(m.family, m, getattr(m, "model_type", None), getattr(m, "linearity", None),
                   R0)
    found = obs.found
    p = np.ascontiguousarray(obs.p_ref()[found])
    pose = np.nonzero(found)[0]
    x0 = chart.x0()
    h = 1e-6 * np.maximum(np.abs(x0), 1.0)

    def jacobian():
        # in closed form, as the grid's (jpl_grid_jacobian) on the observed world points:
        # within 1.2e-6 of a column's scale of the central differences of the fit's own
        # compiled kernel (_jpl_kernels.jacobian_chart, steps +-h) on the paper campaign's
        # jpl records, their truncation
        return jpl_grid_jacobian(chart, chart.model(x0), p, world=True)
    # the fit's weights (jpl_fit.point_weights: each point's residual divided by its
    # predicted error), rows x, y of each found point; None: unweighted
    w = (res.info or {}).get("weights")
    row_weights = None if w is None else \
        np.repeat(np.asarray(w, dtype=np.float64)[found], 2)
    return Linearisation(x0, lambda x: project(chart.model(x), p), chart.model, pose, h,
                         jacobian=jacobian, row_weights=row_weights,
                         quantity_jacobian=lambda m0, ref, names, theta, qvec:
                         jpl_quantity_jacobian(chart, m0, ref, names, theta),
                         grid_jacobian=lambda P: _split_turns(
                             jpl_grid_jacobian(chart, chart.model(x0), P, turns=True)))


# --- the jpl chart's derivatives, analytic -----------------------------------------------
#
# The scatter of a jpl fit needs two Jacobians of its model in its chart (jpl_fit._Chart: C,
# A (2), H, V [, O (2), R1, R2 [, E]]; R0 held): G, of the reported quantities, and Jg, of
# the projection of the image grid's points (PROJECTION_SAMPLES of them, in the model's own
# camera frame: _grid_projector). Central differences build 2 x 11-18 stepped models and
# project the grid through each (the CAHVORE ones through a Newton solve per point): 5-10 ms
# of a record's ~15. Here both are derived in closed form instead, forward mode through the
# chart, the camera frame and the projection of reference_models.kernels.project_point
# (CAHVORE's Newton solve for the angle differentiated implicitly), vectorised over the
# points: the same derivatives to ~1e-8 relative (the differences' own truncation and
# rounding; tests/test_verdict.py), in ~1 ms.

def _chart_directions(chart, m):
    r'''{name: (3, n) d vector / d chart} for A, H, V, O and (n,) rows for C0..2, R1, R2,
E0..2 of a jpl_fit._Chart at its x0 (model m = chart.model(chart.x0()))'''
    fam = chart.family
    n = {"CAHV": 11, "CAHVOR": 15, "CAHVORE": 18}[fam]
    d = {k: np.zeros((3, n)) for k in ("C", "A", "H", "V", "O")}
    for k in range(3):
        d["C"][k, k] = d["H"][k, 5 + k] = d["V"][k, 8 + k] = 1.0

    def unit(base, e, col, u):
        # u = (base + a e0 + b e1) / |.|: d u / d a = (I - u u^T) e0 / |base|
        nb = math.sqrt(float(base @ base))
        for j in range(2):
            d[u][:, col + j] = (e[j] - u_vec[u] * float(u_vec[u] @ e[j])) / nb
    u_vec = {"A": np.asarray(m.A, dtype=np.float64)}
    unit(np.asarray(chart.m0.A, dtype=np.float64), chart.eA, 3, "A")
    if fam != "CAHV":
        u_vec["O"] = np.asarray(m.O, dtype=np.float64)
        unit(np.asarray(chart.m0.O, dtype=np.float64), chart.eO, 11, "O")
    rows = {}
    if fam != "CAHV":
        for i, name in ((13, "R1"), (14, "R2")):
            rows[name] = np.zeros(n)
            rows[name][i] = 1.0
    if fam == "CAHVORE":
        for i in range(3):
            rows[f"E{i}"] = np.zeros(n)
            rows[f"E{i}"][15 + i] = 1.0
    return d, rows, n


def _cross_cols(a, B):
    r'''a x B[:, j] for every column j: a (3,), B (3, n) -> (3, n)'''
    return np.stack((a[1] * B[2] - a[2] * B[1], a[2] * B[0] - a[0] * B[2],
                     a[0] * B[1] - a[1] * B[0]))


def _frame_directions(m, d):
    r'''The camera frame's axes H', A x H' and their (3, n) derivatives, and those of Hc,
Vc, Hs, Vs, V' ((n,) or (3, n)), from d = _chart_directions()'''
    A, H, V = (np.asarray(v, dtype=np.float64) for v in (m.A, m.H, m.V))
    dA, dH, dV = d["A"], d["H"], d["V"]
    out = {}
    for name, W, dW in (("H", H, dH), ("V", V, dV)):
        c = float(W @ A)
        dc = A @ dW + W @ dA
        w = W - c * A
        dw = dW - A[:, None] * dc - c * dA
        s = math.sqrt(float(w @ w))
        u = w / s
        ds = u @ dw
        out[name] = (c, dc, s, ds, u, (dw - u[:, None] * ds) / s)
    Hp, dHp = out["H"][4], out["H"][5]
    Y = np.cross(A, Hp)
    dY = _cross_cols(A, dHp) - _cross_cols(Hp, dA)
    return out, Hp, dHp, Y, dY


def _mrcal_directions(lensmodel, intr):
    r'''_chart_directions' layout for from_mrcal of a mrcal model at the identity pose
(posed_linearisation), in its intrinsics fx, fy, cx, cy [, alpha, beta, R0, R1, R2 [, E]]:
H = (fx, 0, cx), V = (0, fy, cy), A = z, C = 0, O = (sin a cos b, sin b, cos a cos b)
(reference_models.mrcal_convert.from_mrcal). R0's column is left zero: R0 is not held
(the truth side moves with it), the caller differences it.'''
    n = len(intr)
    d = {k: np.zeros((3, n)) for k in ("C", "A", "H", "V", "O")}
    d["H"][0, 0] = d["H"][2, 2] = d["V"][1, 1] = d["V"][2, 3] = 1.0
    rows = {}
    if lensmodel != "LENSMODEL_PINHOLE":
        a, b = float(intr[4]), float(intr[5])
        d["O"][:, 4] = (math.cos(a) * math.cos(b), 0.0, -math.sin(a) * math.cos(b))
        d["O"][:, 5] = (-math.sin(a) * math.sin(b), math.cos(b), -math.cos(a) * math.sin(b))
        for name, i in (("R1", 7), ("R2", 8), ("E0", 9), ("E1", 10), ("E2", 11)):
            if i < n:
                rows[name] = np.zeros(n)
                rows[name][i] = 1.0
    return d, rows, n


def jpl_grid_jacobian(chart, m, P, turns=False, world=False):
    r'''(2M, n) d grid / d chart of a jpl fit: _grid_projector(P)(chart.model(x)) at the
chart's x0 (model m), rows x, y of each point, in closed form; NaN rows where m does not
project a point (as the differences give NaN). turns: 3 more columns, the derivatives in
a turn w of the points in the camera frame (P -> R(w) P: _projection_sigma's). world: P
are world points instead, fixed as the model moves (the fit's own Jacobian: its observed
points, jpl_linearisation)'''
    d, rows, n = _chart_directions(chart, m)
    if turns:
        d = {k: np.concatenate((v, np.zeros((3, 3))), axis=1) for k, v in d.items()}
        rows = {k: np.concatenate((v, np.zeros(3))) for k, v in rows.items()}
        n += 3
    ph, Hp, dHp, Y, dY = _frame_directions(m, d)
    A, H, V = (np.asarray(v, dtype=np.float64) for v in (m.A, m.H, m.V))
    dA, dH, dV = d["A"], d["H"], d["V"]
    P = np.asarray(P, dtype=np.float64)
    # the point in the model's world frame, less C (C moves the frame and the point alike:
    # its columns are zero): p = P0 H' + P1 (A x H') + P2 A. Its derivative dp (M, 3, n) is
    # only ever dotted with a vector: dp_dot(w) = sum_k w_k dp[:, k, :] (M, n), for w (3,) or
    # one per point (M, 3), without forming dp
    if world:
        p = P - np.asarray(m.C, dtype=np.float64)
        dC = d["C"]

        def dp_dot(w):
            return np.broadcast_to(-(w @ dC), (len(P), n))
    else:
        p = P[:, 0:1] * Hp + P[:, 1:2] * Y + P[:, 2:3] * A                 # (M, 3)
        # d R(w) P / d w_k = e_k x P, in the world frame (the turns' columns)
        turned = [c[:, 0:1] * Hp + c[:, 1:2] * Y + c[:, 2:3] * A
                  for c in (np.cross(np.eye(3)[k], P) for k in range(3))] if turns else []

        def dp_dot(w):
            out = (P[:, 0:1] * (w @ dHp) + P[:, 1:2] * (w @ dY)
                   + P[:, 2:3] * (w @ dA))
            for k, t in enumerate(turned):
                out[:, n - 3 + k] = t @ w if w.ndim == 1 else np.einsum("mk,mk->m", t, w)
            return out
    bad = np.zeros(len(P), dtype=bool)
    if m.family != "CAHV":
        O, dO = np.asarray(m.O, dtype=np.float64), d["O"]
        R = np.asarray(m.R, dtype=np.float64)
        z = p @ O
        dz = dp_dot(O) + p @ dO
        lv = p - z[:, None] * O
        # l = p - z O: dl . w = dp . w - z (w . dO) - dz (O . w)
        lv_dl = dp_dot(lv) - z[:, None] * (lv @ dO) - dz * (lv @ O)[:, None]
        dR1, dR2 = rows["R1"], rows["R2"]
        if m.family == "CAHVOR":
            tau = np.einsum("mk,mk->m", lv, lv) / (z * z)
            dtau = 2 * lv_dl / (z * z)[:, None] - 2 * (tau / z)[:, None] * dz
            mu = R[0] + tau * (R[1] + tau * R[2])
            dmu = dtau * (R[1] + 2 * tau * R[2])[:, None] + tau[:, None] * dR1 \
                + (tau * tau)[:, None] * dR2
            bad |= ~(z > 0)
            q = p + mu[:, None] * lv

            def dq_dot(w):      # q = p + mu l
                dp_w = dp_dot(w)
                dl_w = dp_w - z[:, None] * (w @ dO) - dz * (O @ w)
                return dp_w + dmu * (lv @ w)[:, None] + mu[:, None] * dl_w
        else:
            E, L = np.asarray(m.E, dtype=np.float64), float(m.linearity)
            ln = np.sqrt(np.einsum("mk,mk->m", lv, lv))
            with np.errstate(all="ignore"):
                dln = np.where(ln[:, None] > 0, lv_dl / ln[:, None], 0.0)
            th = solve_theta_each(z, ln, E)
            s, c = np.sin(th), np.cos(th)
            t2 = th * th
            e = E[0] + t2 * (E[1] + t2 * E[2])
            de = th * (2.0 * E[1] + 4.0 * E[2] * t2)
            dF = z * c + ln * s - (1.0 - c) * e - (th - s) * de         # dF / dtheta
            # F = z sin - l cos - (theta - sin) e(theta) = 0: dtheta = -dF/dx / dF/dtheta
            num = s[:, None] * dz - c[:, None] * dln
            w = -(th - s)
            for i in range(3):
                num = num + (w * t2 ** i)[:, None] * rows[f"E{i}"]
            dth = -num / dF[:, None]
            if L > 1e-15:
                chi = np.tan(L * th) / L
                dchi = 1.0 / np.cos(L * th) ** 2
            elif L < -1e-15:
                chi = np.sin(L * th) / L
                dchi = np.cos(L * th)
            else:
                chi, dchi = th, np.ones_like(th)
            dchi = dchi[:, None] * dth
            bad |= ~(th * abs(L) <= math.pi / 2)
            small = th <= 1e-8
            with np.errstate(all="ignore"):
                zp = np.where(small, z, ln / chi)
                dzp = np.where(small[:, None], dz,
                               dln / chi[:, None] - (ln / (chi * chi))[:, None] * dchi)
                c2 = chi * chi
                mu = np.where(small, 0.0, R[0] + c2 * (R[1] + c2 * R[2]))
                dmu = np.where(small[:, None], 0.0,
                               (2 * chi * (R[1] + 2 * c2 * R[2]))[:, None] * dchi
                               + c2[:, None] * dR1 + (c2 * c2)[:, None] * dR2)
            q = zp[:, None] * O + (1.0 + mu)[:, None] * lv

            def dq_dot(w):      # q = zp O + (1 + mu) l
                dl_w = dp_dot(w) - z[:, None] * (w @ dO) - dz * (O @ w)
                return (dzp * (O @ w) + zp[:, None] * (w @ dO) + dmu * (lv @ w)[:, None]
                        + (1.0 + mu)[:, None] * dl_w)
    else:
        q, dq_dot = p, dp_dot
    qa = q @ A
    bad |= ~(qa > 0)
    dqa = dq_dot(A) + q @ dA
    J = np.empty((len(P), 2, n))
    for j, (W, dW) in enumerate(((H, dH), (V, dV))):
        x = (q @ W) / qa
        J[:, j] = (dq_dot(W) + q @ dW - x[:, None] * dqa) / qa[:, None]
    J[bad] = np.nan
    return J.reshape(2 * len(P), n)


def jpl_quantity_jacobian(chart, m, ref, names, theta_estimated):
    r'''(len(names), n) d _signed_quantities(ref, chart.model(x)) / d chart at the chart's x0
(model m), in closed form; None when a name is not one this knows (the caller then
differences stepped models)'''
    return _quantity_jacobian(*_chart_directions(chart, m), m, ref, names, theta_estimated)


def _quantity_jacobian(d, rows, n, m, ref, names, theta_estimated):
    r'''jpl_quantity_jacobian for the model's derivatives d, rows (_chart_directions' layout)
in any n parameters that hold R0 (the truth side, ref moved to m's R0, is fixed)'''
    from .compare import _truth_side
    ph, Hp, dHp, Y, dY = _frame_directions(m, d)
    fam = m.family
    has_O = fam != "CAHV" and ref.family != "CAHV"
    fit_R0 = float(m.R[0]) if fam != "CAHV" else 0.0
    t, t_ph, traw, _ = _truth_side(ref, fit_R0 if has_O else None, fam == "CAHV")
    truth_R0 = float(ref.R[0]) if ref.family != "CAHV" else 0.0
    A = np.asarray(m.A, dtype=np.float64)
    Hc, dHc, Hs, dHs, _, _ = ph["H"]
    Vc, dVc, Vs, dVs, Vp, dVp = ph["V"]
    known = {"Hc": dHc, "Vc": dVc}
    for k, ds, ts, traw_s in (("Hs", dHs, t_ph.Hs, traw.Hs), ("Vs", dVs, t_ph.Vs, traw.Vs)):
        if ts != 0:
            known[k] = ds / abs(ts)
        tr = traw_s * (1 + truth_R0)
        if tr != 0:
            known[f"{k}*(1+R0)"] = ds * (1 + fit_R0) / abs(tr)
    if theta_estimated:
        c = float(np.dot(Hp, Vp))
        if abs(c) < 1.0:
            known["theta_deg"] = -math.degrees(1.0) * (Hp @ dVp + Vp @ dHp) / math.sqrt(1 - c * c)
    for i in range(3):
        known[f"C_mm[{i}]"] = 1e3 * d["C"][i]
    a_ref = np.asarray(ref.A, dtype=np.float64)
    e = _tangent_basis_of(a_ref)
    for i in range(2):
        known[f"A_deg[{i}]"] = math.degrees(1.0) * (e[i] @ d["A"])
    # _roll_deg: atan2(s, c), s = (a x h0) . h1, c = h0 . h1, h1 = H' less its a component
    h0 = ref.photogrammetric().Hp
    h1 = Hp - (Hp @ a_ref) * a_ref
    ah0 = np.cross(a_ref, h0)
    s_, c_ = float(ah0 @ h1), float(h0 @ h1)
    ds, dc = ah0 @ dHp, h0 @ dHp - (h0 @ a_ref) * (a_ref @ dHp)
    known["roll_deg"] = math.degrees(1.0) * (c_ * ds - s_ * dc) / (c_ * c_ + s_ * s_)
    if has_O:
        O, dO = np.asarray(m.O, dtype=np.float64), d["O"]
        dfit_O = np.stack((O @ dHp + Hp @ dO, O @ dY + Y @ dO, O @ d["A"] + A @ dO))
        e = _tangent_basis_of(_truth_side(ref, fit_R0, False)[3])
        for i in range(2):
            known[f"O_deg[{i}]"] = math.degrees(1.0) * (e[i] @ dfit_O)
        known["R0"] = known["R0_frac"] = np.zeros(n)
        for i in (1, 2):
            known[f"R{i}"] = rows[f"R{i}"]
            if float(t.R[i]) != 0:
                known[f"R{i}_frac"] = rows[f"R{i}"] / abs(float(t.R[i]))
    for i in range(3):
        if f"E{i}" in rows:
            known[f"E{i}"] = rows[f"E{i}"]
    if any(k not in known for k in names):
        return None
    return np.stack([known[k] for k in names])


def _opencv_quantity_jacobian(ref, names, n):
    r'''(len(names), n) d fit_parameter_differences(ref, OpenCVModel(intrinsics)) / d
intrinsics (fx, fy, cx, cy, distortion...): Hc = cx - ref's, Hs = (fx - ref's) / |ref's|,
D_i = dist_i - ref's; None for a name this does not know or a ref of another model'''
    from harness.calibrators.opencv_fit import OpenCVModel
    if not isinstance(ref, OpenCVModel):
        return None
    e = np.eye(n)
    known = {"Hc": e[2], "Vc": e[3]}
    if ref.fx != 0:
        known["Hs"] = e[0] / abs(ref.fx)
    if ref.fy != 0:
        known["Vs"] = e[1] / abs(ref.fy)
    for i in range(n - 4):
        known[f"D{i}"] = e[4 + i]
    if any(k not in known for k in names):
        return None
    return np.stack([known[k] for k in names])


def _opencv_grid_jacobian(intr, P):
    r'''(2M, n) d q / d intrinsics of OpenCV's 5- or 8-coefficient model
(opencv_fit._project_rational: fx, fy, cx, cy, k1, k2, p1, p2, k3 [, k4, k5, k6]) at
camera-frame points P, in closed form; NaN rows where z is not > 0'''
    P = np.asarray(P, dtype=np.float64)
    n = len(intr)
    fx, fy = intr[0], intr[1]
    k = np.zeros(8)
    k[:n - 4] = intr[4:12]
    k1, k2, p1, p2, k3, k4, k5, k6 = k
    with np.errstate(all="ignore"):
        z = P[:, 2]
        a, b = P[:, 0] / z, P[:, 1] / z
        r2 = a * a + b * b
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        radial = num / den
        x = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        y = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
        # d (x, y) / d k1..k6, p1, p2 (in the layout of intr[4:])
        r4, r6 = r2 * r2, r2 * r2 * r2
        dr = {0: r2 / den, 1: r4 / den, 4: r6 / den, 5: -radial * r2 / den,
              6: -radial * r4 / den, 7: -radial * r6 / den}
    J = np.zeros((len(P), 2, n))
    J[:, 0, 0], J[:, 1, 1] = x, y
    J[:, 0, 2] = J[:, 1, 3] = 1.0
    for i in range(n - 4):
        if i in dr:
            dx, dy = a * dr[i], b * dr[i]
        elif i == 2:    # p1
            dx, dy = 2 * a * b, r2 + 2 * b * b
        else:           # p2
            dx, dy = r2 + 2 * a * a, 2 * a * b
        J[:, 0, 4 + i], J[:, 1, 4 + i] = fx * dx, fy * dy
    J[~(z > 0)] = np.nan
    return J.reshape(2 * len(P), n)


def _split_turns(J):
    r'''(Jg, Jw) of a grid Jacobian whose last 3 columns are the turns'''
    return J[:, :-3], J[:, -3:]


def _rodrigues(r):
    from reference_models.poseutils import R_from_r as _R_from_r
    return _R_from_r(r)


def posed_linearisation(res, obs):
    r'''A pose-estimating fit (mrcal, OpenCV): intrinsics + 6 numbers per board pose

-> Linearisation, or None for a fit this cannot parametrise (known poses,
regularised, an unknown model type).'''
    from harness.calibrators.opencv_fit import OpenCVModel
    m = res.model
    if res.Rt_cam_board is None or _world(res) or res.info.get("regularization"):
        return None
    cm = res.info.get("cameramodel")
    if cm is not None:
        import mrcal
        lensmodel, intr0 = cm.intrinsics()
        intr0 = np.asarray(intr0, dtype=np.float64)
        W, H = (int(v) for v in cm.imagersize())
        jpl = _is_jpl(m)

        def model_of(theta):
            from harness.calibrators.mrcal_fit import MrcalModel
            c = mrcal.cameramodel(intrinsics=(lensmodel, np.asarray(theta)),
                                  imagersize=np.array((W, H)),
                                  Rt_ref_cam=np.vstack((np.eye(3), np.zeros(3))))
            if jpl:
                from reference_models.mrcal_convert import from_mrcal
                return from_mrcal(c)
            return MrcalModel(c, m.family)

        def projector(theta):
            theta = np.asarray(theta)
            return lambda p_cam: mrcal.project(np.ascontiguousarray(p_cam), lensmodel, theta)
    elif isinstance(m, OpenCVModel):
        intr0 = np.concatenate(([m.fx, m.fy, m.cx, m.cy], m.dist))

        def model_of(theta):
            K = np.array([[theta[0], 0, theta[2]], [0, theta[1], theta[3]], [0, 0, 1.0]])
            return OpenCVModel(m.family, K, theta[4:], m.width, m.height)

        def projector(theta):
            return model_of(theta).project
    else:
        return None
    Rts = np.asarray(res.Rt_cam_board, dtype=np.float64)
    # a pose the fit left out (too few points: NaN board pose, as OpenCV's and mrcal's
    # views leave it) contributes nothing
    found = obs.found & np.all(np.isfinite(Rts), axis=(1, 2))[:, None]
    pose = np.nonzero(found)[0]
    nth = len(intr0)
    Np = obs.Nposes
    x0 = np.concatenate((intr0, np.zeros(6 * Np)))
    pb = [obs.p_board[i][found[i]] for i in range(Np)]

    def rotated(i, w):
        R = _rodrigues(w) @ Rts[i][:3]
        return pb[i] @ R.T
    # the board points at each pose's own rotation (no rotation step: the Jacobian's
    # intrinsics and translation steps, every projection at the solution), rotated once
    at_pose = [rotated(i, np.zeros(3)) for i in range(Np)]

    def pose_points(i, d):
        return (rotated(i, d[:3]) if d[:3].any() else at_pose[i]) + Rts[i][3] + d[3:]

    def project(x):
        cam = projector(x[:nth])
        return np.concatenate([cam(pose_points(i, x[nth + 6 * i: nth + 6 * i + 6]))
                               for i in range(Np) if len(pb[i])], axis=0)

    h = np.concatenate((1e-6 * np.maximum(np.abs(intr0), 1.0), np.full(6 * Np, 1e-6)))

    def jacobian():
        # a pose's six numbers move its own points only: the k-th number of every pose is
        # stepped at once, each pose's rows differenced on its own step (the same numbers as
        # differencing each column on everything: the projection is point by point), 12
        # projections of the points for all the poses' columns; the intrinsics' columns
        # project every pose's points at once: at the solution (no pose step: the identity
        # rotation, exactly) they are the same camera-frame points for each intrinsics
        # step, transformed once
        J = np.zeros((2 * len(pose), len(x0)))
        used = [i for i in range(Np) if len(pb[i])]
        p0 = np.concatenate([pose_points(i, x0[nth + 6 * i: nth + 6 * i + 6]) for i in used],
                            axis=0)
        J[:, :nth] = _central_jacobian(lambda t: projector(t)(p0), intr0, h[:nth])
        cam0 = projector(intr0)
        rows = np.repeat(np.arange(len(used)), [2 * len(pb[i]) for i in used])
        for k in range(6):
            cols = nth + 6 * np.asarray(used) + k
            xp, xm = x0.copy(), x0.copy()
            xp[cols] += h[cols]
            xm[cols] -= h[cols]
            fp = np.asarray(cam0(np.concatenate(
                [pose_points(i, xp[nth + 6 * i: nth + 6 * i + 6]) for i in used], axis=0)),
                dtype=np.float64).ravel()
            fm = np.asarray(cam0(np.concatenate(
                [pose_points(i, xm[nth + 6 * i: nth + 6 * i + 6]) for i in used], axis=0)),
                dtype=np.float64).ravel()
            J[np.arange(len(rows)), cols[rows]] = (fp - fm) / (xp - xm)[cols[rows]]
        return J

    grid_jacobian = quantity_jacobian = None
    # (the fit's own Jacobian J stays differenced: mrcal.project's derivatives agree with the
    # differences to 1e-10 of a column, as the differences with steps x2 agree with
    # themselves, but the near-null direction of mrcal's CAHVOR R0 / focal-length valley
    # (cameras 1 and 22 of the paper campaign, floor_far) moves their sigmas 10-25% on
    # such a change, steps x2 itself 1-7%)
    if cm is not None and jpl:
        # from_mrcal of a model at the identity pose: its camera frame is the identity
        # (A = z, H' = x) for every intrinsics, and it projects as mrcal.project (the
        # paper campaign's mrcal grids: within 2.3e-13 px): the grid's derivatives are
        # mrcal's own
        def grid_jacobian(P):
            P = np.ascontiguousarray(P, dtype=np.float64)
            _, dq_dp, dq_di = mrcal.project(P, lensmodel, intr0, get_gradients=True)
            # the turns of the points (_projection_sigma): d R(w) P / d w_k = e_k x P
            Jw = np.stack([np.einsum("mij,mj->mi", dq_dp, np.cross(np.eye(3)[k], P)).ravel()
                           for k in range(3)], axis=-1)
            return dq_di.reshape(2 * len(P), nth), Jw

        # the quantities in closed form in every intrinsic but R0, which the truth side
        # of the differences moves with (ref moved to the fit's R0): that column differenced
        def quantity_jacobian(m0, ref, names, theta, qvec):
            G = _quantity_jacobian(*_mrcal_directions(lensmodel, intr0), m0, ref, names,
                                   theta)
            if G is not None and lensmodel != "LENSMODEL_PINHOLE":
                G[:, 6] = lin.model_jacobians([qvec], cols=[6])[0][:, 0]
            return G

    if cm is None:
        # OpenCV: the quantities are cx, cy, fx, fy, the distortion: linear in the intrinsics
        def quantity_jacobian(m0, ref, names, theta, qvec):
            return _opencv_quantity_jacobian(ref, names, nth)
        if m.family != "FISHEYE":
            def grid_jacobian(P):
                return _opencv_grid_jacobian(intr0, P), None

    lin = Linearisation(x0, project, lambda x: model_of(x[:nth]), pose, h, n_model=nth,
                        jacobian=jacobian, quantity_jacobian=quantity_jacobian,
                        grid_jacobian=grid_jacobian)
    return lin


def linearisation(res, obs):
    r'''The Linearisation of a fit (jpl, or a pose-estimating mrcal/OpenCV fit), or None'''
    if res.calibrator == "jpl" and _is_jpl(res.model) and obs.has_world_points:
        return jpl_linearisation(res, obs)
    if res.calibrator in ("mrcal", "opencv"):
        return posed_linearisation(res, obs)
    return None


def _signed_quantities(ref, m, theta, world):
    r'''The reported parameter differences m - ref as signed numbers (vectors by component)

C by its three components (C_mm[0..2]); the unit vectors A and O by their two components in
the plane perpendicular to ref's (_unit_components; O in the camera frame with ref moved to
m's R0, as fit_parameter_differences(signed=True) compares it).'''
    from .compare import _truth_side
    d = fit_parameter_differences(ref, m, theta_estimated=theta, world_frame=world,
                                  signed=True)
    out = {k: v for k, v in d.items() if v is not None and k not in VECTOR_PARAMS}
    for k in VECTOR_PARAMS:
        v = d.get(k)
        if v is None:
            continue
        if k == "C_mm":
            comps = [float(x) for x in v]
        else:
            # the vector the difference was taken from: ref's A (world frame), or ref's O in
            # its camera frame at m's R0 (compare's memo of the truth side it just used)
            u_ref = ref.A if k == "A_deg" else _truth_side(ref, float(m.R[0]), False)[3]
            comps = _unit_components(u_ref, None, dv_deg=v)
        for i, x in enumerate(comps):
            out[f"{k}[{i}]"] = x
    return out


def _tangent_basis_of(u):
    r'''harness.calibrators.jpl_fit._tangent_basis(u), kept for the last two u (by value): the
scatter's stepped models all take their A and O components about the exact fit's A and O'''
    return _tangent_basis_by_value(np.asarray(u, dtype=np.float64).tobytes())


@functools.lru_cache(maxsize=2)
def _tangent_basis_by_value(key):
    from harness.calibrators.jpl_fit import _tangent_basis
    b = _tangent_basis(np.frombuffer(key, dtype=np.float64))
    for e in b:
        e.setflags(write=False)     # shared by every caller
    return b


def _unit_components(u_ref, u, dv_deg=None):
    r'''The move u - u_ref of a unit vector, deg, as its two components in the plane
perpendicular to u_ref (harness.calibrators.jpl_fit._tangent_basis, the fit's own chart)

Its component along u_ref is -|u - u_ref|^2 / 2: second order, which the linear covariance
gives no variance. In world components it is spread over the three when u_ref is oblique
(the eigen cut of joint_statistic drops it), but it IS a component when u_ref lies along
an axis: camera 17's A = (0, 0, 1) gave A_deg[2] a sigma of 1e-10 deg (rounding of the
Jacobian's differences), a mean of -12 standard errors and a clean jpl chi2/dof of 1.7-1.9
under the noise model's own Gaussian noise (CAHVOR and CAHVORE; 0.97-1.07 without it).'''
    e1, e2 = _tangent_basis_of(np.asarray(u_ref, dtype=np.float64))
    if dv_deg is None:      # or the move given as its world components, deg
        dv_deg = np.degrees(np.asarray(u, dtype=np.float64) - u_ref)
    return [float(e1 @ dv_deg), float(e2 @ dv_deg)]


# The smallest detection scatter the model assumes, px: differences below it are below
# what a renderer's output resolves (float32 model vectors move a projection by ~1e-4 px,
# harness/mutation.py; area coverage fixes a pixel to 1e-4 of its value). Without it an
# image equal to the reference render (a corner target through camval's own ray caster:
# detected - reference ~1e-12 px, the float rounding of the pose round trip) would get a
# sigma of 1e-13 and judge rounding noise at z 8.
DETECTION_RESOLUTION_PX = 1e-4


def noise_per_pose(res, exact_res, Nposes, n_params, absorbed=None, direct=None):
    r'''(Nposes,) sigma px of the detection error per image (see the notes above), at
least DETECTION_RESOLUTION_PX; NaN where an image has no point

The image's residual differences d (image fit - exact fit) are its detection errors less
what the fit absorbed: E |d|^2 = sigma^2 / 2 (2 n_i - t_i) over its n_i points, t_i the
trace of the fit's hat matrix over the image's rows (absorbed, (Nposes,): its own board
pose's six and its share of the model's, fit_leverage; None: n_params spread evenly over
the points, the scaling sqrt(2N / (2N - n)) of the notes above). An image whose rows keep
k_i = 2 n_i - t_i <= 2 residual degrees of freedom cannot say its own noise: the sigma the
scatter divides by would be read from k_i dof, and E[k / chi2_k] = k / (k - 2) is unbounded
for k <= 2 (a view of two corners, its residuals absorbed by its pose, read 2e-4 px where
its corners erred by 0.0064: tiny-320x240 AprilTag seed 1, joint chi2 2598 on 15). Such an
image takes direct[i], its detected - exact RMS (detection_noise's per_pose_rms), when
given: a fault the fit would absorb shows in it, but only over the few points of an image
that carries little of the fit. The images' noise differ too much to pool (small-fish-348
AprilTag seed 1: 0.004-0.16 px).'''
    d = np.asarray(res.residuals, dtype=np.float64) - np.asarray(exact_res.residuals,
                                                                   dtype=np.float64)
    ok = np.all(np.isfinite(d), axis=-1)
    n_i = ok.sum(axis=1).astype(np.float64)
    N = float(n_i.sum())
    ss = np.array([float(np.sum(d[i][ok[i]] ** 2)) for i in range(Nposes)])
    even = n_params * n_i / max(N, 1.0)
    t = even if absorbed is None else np.asarray(absorbed, dtype=np.float64)
    out = np.full(Nposes, np.nan)
    for i in range(Nposes):
        if not n_i[i]:
            continue
        k = 2 * n_i[i] - t[i]
        if k > 2 or direct is None or direct[i] is None or not np.isfinite(direct[i]):
            # (no direct reading: the even spread's, as before the leverage)
            k = k if k > 2 else max(2 * n_i[i] - even[i], 1.0)
            sigma = math.sqrt(2 * ss[i] / k)
        else:
            sigma = float(direct[i])
        out[i] = max(sigma, DETECTION_RESOLUTION_PX)
    return out


def fit_leverage(J, pose, Nposes, normal=None):
    r'''(Nposes,) the trace of the fit's hat matrix J (J^T J)^+ J^T over each image's rows: the
residual degrees of freedom each image's points lost to the fit (its board pose's six and
its share of the model's). J (2N, n) the fit's Jacobian (a weighted fit's rows scaled by its
weights), rows x, y of each point, pose-major; pose (N,) each point's image; normal
(Ninv, s_col) of _normal_inverse(J) when the caller has it'''
    Ninv, s_col = _normal_inverse(J) if normal is None else normal
    Js = J / s_col
    h = np.einsum("ij,jk,ik->i", Js, Ninv, Js, optimize=True)
    return np.bincount(np.repeat(np.asarray(pose), 2), weights=h, minlength=Nposes)


def _fitted_points(obs, pose):
    r'''(pi, pt): the image and point index of each fitted point (pose: Linearisation.pose,
the points of obs.found, pose-major, of the images the fit kept), or None when pose is not
that order (corner_shares, corner_correlation)'''
    pose = np.asarray(pose)
    keep = obs.found & np.isin(np.arange(obs.Nposes), pose)[:, None]
    pi, pt = np.nonzero(keep)
    if not np.array_equal(pi, pose):
        return None
    return pi, pt


def corner_shares(obs, pose):
    r'''(N,) each fitted point's share of its image's measured noise variance, or None (the
detector predicted none: every point alike)

pose: (N,) the image of each fitted point (Linearisation.pose: the points of obs.found,
pose-major, of the images the fit kept). noise_per_pose measures one variance per image;
tag-edge corners differ (the board's rim tags, seen by fewer and shorter spans, scatter
~1.7x the inner ones' on the pupil job), and their detector predicts each one's
(Observations.corner_sigma_px: per corner 0.99 of the scatter measured over 120 noise
draws there). Each predicted point's share is its predicted variance over the mean of the
image's predicted ones; a point without a prediction keeps 1. The image's mean share is 1:
its measured variance is spread over its points, not changed.'''
    sig = getattr(obs, "corner_sigma_px", None)
    if sig is None:
        return None
    fitted = _fitted_points(obs, pose)
    if fitted is None:
        return None
    pi, pt = fitted
    v = np.asarray(sig, dtype=np.float64)[pi, pt] ** 2
    has = np.isfinite(v) & (v > 0)
    out = np.ones(len(pose))
    for i in np.unique(pi[has]):
        m = has & (pi == i)
        out[m] = v[m] / v[m].mean()
    return out


# Gauss-Legendre nodes per piece of a board line (an edge, or its part inside a span's
# reach): the products of two spans' polynomials (degree <= 6) exactly
_LINE_NODES = np.polynomial.legendre.leggauss(8)


def _span_degree(h, tol=1e-6):
    r'''The degree of a span's polynomial from its functional h (..., 6) on a board line's
quintic (targets.tag_edges.SPAN_RECORD): the fit follows a polynomial up to its degree
exactly (h_l ~ 0 for l <= degree); an int per leading index'''
    a = np.abs(np.asarray(h, dtype=np.float64))
    big = a > tol * np.maximum(a.max(axis=-1, keepdims=True), 1e-300)
    return np.where(big.any(axis=-1), np.argmax(big, axis=-1) - 1, 5)


def line_correlation(ends, pieces):
    r'''(m, m) the correlation of m edge ends' errors across one board line

ends: [(u_a, u_b, tc, degree, r0, r1)] each end's edge from corner a (tau -1) to b (tau 1)
in the line's board coordinate u, its corner's tau (+-1), its span's polynomial degree and
its reach r0 < r1 in u; pieces: [(u0, u1)] where the line has pixels (its tags' edges).

Each end is the least-squares polynomial of its degree in its own tau over the pixels of
its reach, evaluated at its corner: a linear function of the pixels' noise, phi(u)
(targets.tag_edges._span_choice's variance is its sum of squares). With the noise and the
pixels' information alike along the line (the light level and contrast left out: a
symmetric profile's are nearly orthogonal to its position), two ends' covariance is the
integral of phi_a phi_b over the pixels both reach. (One line of _line_correlations.)'''
    return _line_correlations([(ends, pieces)])[0, :len(ends), :len(ends)]


def _line_correlations(lines):
    r'''(L, M, M) line_correlation of each of L lines [(ends, pieces)], at once: line l's
in [l, :m_l, :m_l], padded with the identity

Every end's normal equations are solved in one numpy batched solve: each end's
Vandermonde matrix over its line's Gauss-Legendre nodes (the lines' padded with nodes of
weight 0), its rows outside the reach and its columns past its degree zero, the unused
columns' block of the normal matrix the identity (their solution 0). An end with fewer
nodes in reach than coefficients or a singular system is left uncorrelated.'''
    xs, ws = [], []
    for ends, pieces in lines:
        cuts = sorted({x for e in ends for x in e[4:6]})
        x, w = [], []
        for u0, u1 in pieces:
            b = [u0] + [c for c in cuts if u0 < c < u1] + [u1]
            for a0, a1 in zip(b[:-1], b[1:], strict=True):
                x.append(0.5 * (a0 + a1) + 0.5 * (a1 - a0) * _LINE_NODES[0])
                w.append(0.5 * (a1 - a0) * _LINE_NODES[1])
        xs.append(np.concatenate(x))
        ws.append(np.concatenate(w))
    nl, ne, nx = len(lines), max(len(e) for e, _ in lines), max(len(x) for x in xs)
    X, W, real = np.zeros((nl, nx)), np.zeros((nl, nx)), np.zeros((nl, nx), dtype=bool)
    E = np.zeros((nl, ne, 6))
    E[..., 1] = 1.0              # padded ends: u_b 1, degree 0, reach empty (r0 1 > r1 0)
    E[..., 4] = 1.0
    for l, ((ends, _), x, w) in enumerate(zip(lines, xs, ws, strict=True)):
        X[l, :len(x)], W[l, :len(w)], real[l, :len(x)] = x, w, True
        E[l, :len(ends)] = np.asarray(ends, dtype=np.float64).reshape(-1, 6)
    ua, ub, tc, r0, r1 = (E[..., j] for j in (0, 1, 2, 4, 5))
    deg = E[..., 3].astype(int)
    xx = X[:, None, :]
    m = (xx >= r0[..., None]) & (xx <= r1[..., None]) & real[:, None, :]  # (L, M, nodes)
    cols = np.arange(deg.max() + 1)
    on = cols <= deg[..., None]                                        # (L, M, degree + 1)
    # np.vander's powers (repeated products), per end in its own tau
    V = np.empty(m.shape + cols.shape)
    V[..., 0] = 1.0
    with np.errstate(all="ignore"):     # a zero-length edge: its end is left out below
        if len(cols) > 1:
            V[..., 1:] = (2.0 * (xx - ua[..., None]) / (ub - ua)[..., None] - 1.0)[..., None]
            np.multiply.accumulate(V[..., 1:], axis=-1, out=V[..., 1:])
        V = np.where(m[..., None] & on[..., None, :], V, 0.0)
        A = np.swapaxes(V, -1, -2) @ (V * W[:, None, :, None])
    A[..., cols, cols] += ~on
    rhs = np.where(on, tc[..., None] ** cols, 0.0)
    good = (m.sum(axis=-1) > deg) & np.isfinite(A).all(axis=(-2, -1))
    c = np.zeros(on.shape)
    try:
        c[good] = np.linalg.solve(A[good], rhs[good][..., None])[..., 0]
    except np.linalg.LinAlgError:
        for k in zip(*np.nonzero(good), strict=True):
            try:
                c[k] = np.linalg.solve(A[k], rhs[k])
            except np.linalg.LinAlgError:
                continue
    V[~good] = 0.0                                                     # (NaN there)
    Phi = (V @ c[..., None])[..., 0]                                   # (L, M, nodes)
    C = (Phi * W[:, None, :]) @ np.swapaxes(Phi, -1, -2)
    d = np.sqrt(np.diagonal(C, axis1=-2, axis2=-1))
    ok = d > 0
    both = ok[..., :, None] & ok[..., None, :]
    with np.errstate(all="ignore"):
        out = np.where(both, C / (d[..., :, None] * d[..., None, :]), 0.0)
    out[:, np.arange(ne), np.arange(ne)] = 1.0
    return out


def corner_correlation(obs, pose):
    r'''[(rows, C)] per image: the rows (2n,) of its n fitted points (x, y interleaved, as
Linearisation's) and C (2n, 2n) their errors' correlation across the board lines their
edges share, unit diagonal; None without tag edges' span records (Observations
.corner_spans) or predictions (corner_sigma_px)

A tag-edge corner is where two edges' curves meet; each edge is fitted over a span of its
board line (the edge alone, with its neighbour's nearer part, or the whole line:
targets.tag_edges._span_choice), and corners whose spans share pixels err alike across
that line (the pupil job's 120 draws: 0.67 across the gap to the next tag, 0.33 at the
two ends of one edge). Each corner's error is split into its two lines' normals
(orthonormalised), each line's ends correlated by line_correlation (an image's lines at
once: _line_correlations), its reach and degree from the span records; C is then a sum of
correlation matrices, positive semidefinite.'''
    spans = getattr(obs, "corner_spans", None)
    if spans is None or getattr(obs, "corner_sigma_px", None) is None:
        return None
    fitted = _fitted_points(obs, pose)
    if fitted is None:
        return None
    pi, pt = fitted
    out = []
    row0 = 0
    for i in np.unique(pi):
        pts = pt[pi == i]
        n = len(pts)
        rows = np.arange(row0, row0 + 2 * n)
        row0 += 2 * n
        C = np.eye(2 * n)
        sp, q, pb = spans[i], obs.q[i], obs.p_board[i][:, :2]
        # each point's two edges (slot 0: from its other corner o to it, tau 1; slot 1:
        # from it to o, tau -1), an end where the record, both corners and a board-axis
        # line are there: its line (axis, board coordinate across), its (u_a, u_b, tc,
        # degree, r0, r1) and its image normal, flattened (point, slot)
        r = sp[pts]                                                  # (n, 2, R)
        keep = np.isfinite(r).all(axis=-1)
        o = np.where(keep, r[..., -1], 0).astype(int)
        p2 = np.broadcast_to(pts[:, None], o.shape)
        a = np.where([0, 1], p2, o)
        b = np.where([0, 1], o, p2)
        keep &= np.isfinite(q[a]).all(axis=-1) & np.isfinite(q[b]).all(axis=-1)
        d = pb[b] - pb[a]
        ax = np.argmax(np.abs(d), axis=-1)
        L = np.hypot(d[..., 0], d[..., 1])
        side = np.take_along_axis(d, 1 - ax[..., None], axis=-1)[..., 0]
        with np.errstate(invalid="ignore"):
            keep &= (L > 0) & ~(np.abs(side) > 1e-9 * L)
        across = np.take_along_axis(pb[a], 1 - ax[..., None], axis=-1)[..., 0]
        ua = np.take_along_axis(pb[a], ax[..., None], axis=-1)[..., 0]
        ub = np.take_along_axis(pb[b], ax[..., None], axis=-1)[..., 0]
        s0 = ua + 0.5 * (r[..., -3] + 1.0) * (ub - ua)
        s1 = ua + 0.5 * (r[..., -2] + 1.0) * (ub - ua)
        end = np.stack([ua, ub, np.broadcast_to([1.0, -1.0], ua.shape), _span_degree(r[..., :6]),
                        np.minimum(s0, s1), np.maximum(s0, s1)], axis=-1).reshape(-1, 6)
        e = q[b] - q[a]
        with np.errstate(invalid="ignore", divide="ignore"):
            nrm = np.stack([-e[..., 1], e[..., 0]], axis=-1) / np.hypot(
                e[..., 0], e[..., 1])[..., None]
        normal = np.where(keep[..., None], nrm, np.nan)
        # each corner's two directions: its first edge's normal, the second's made
        # orthogonal to it (its sign kept: the same for every end of a line)
        unit = normal.copy()
        n0, n1 = normal[:, 0], normal[:, 1]
        two = np.isfinite(n0).all(axis=-1) & np.isfinite(n1).all(axis=-1)
        v = n1[two] - (n1[two] * n0[two]).sum(axis=-1)[:, None] * n0[two]
        unit[two, 1] = v / np.hypot(v[:, 0], v[:, 1])[:, None]
        unit = unit.reshape(-1, 2)
        # the board lines (in order of their first end) with two ends or more
        idx = np.flatnonzero(keep.ravel())
        groups = {}
        for j, key in zip(idx.tolist(), zip(ax.ravel()[idx].tolist(),
                                            [round(u, 9) for u in across.ravel()[idx].tolist()],
                                            strict=True), strict=True):
            groups.setdefault(key, []).append(j)
        members = [g for g in groups.values() if len(g) >= 2]
        if members:
            R = _line_correlations([
                (end[g], [tuple(p) for p in np.unique(np.sort(end[g, :2], axis=1), axis=0)])
                for g in members])
            G = np.full(R.shape[:2], -1)
            for l, g in enumerate(members):
                G[l, :len(g)] = g
            k = np.where(G >= 0, G // 2, -1)
            U = np.where((G >= 0)[..., None], unit[np.maximum(G, 0)], np.nan)
            fin = np.isfinite(U).all(axis=-1)
            pair = (k[..., :, None] != k[..., None, :]) & fin[..., :, None] & fin[..., None, :]
            li, ri, ci = np.nonzero(pair)
            C4 = np.zeros((n, n, 2, 2))
            np.add.at(C4, (k[li, ri], k[li, ci]), R[li, ri, ci, None, None]
                      * U[li, ri, :, None] * U[li, ci, None, :])
            C += C4.transpose(0, 2, 1, 3).reshape(2 * n, 2 * n)
        out.append((rows, C))
    return out


def scatter(res, exact_res, obs, truth, noise=None):
    r'''Expected scatter of the image fit about the exact fit (see _scatter), with numpy's
linear algebra on one thread (harness.blas.one_thread: its matrices have a few dozen
columns, where OpenBLAS's threads only wait for each other)'''
    from . import blas
    with blas.one_thread():
        return _scatter(res, exact_res, obs, truth, noise)


def _scatter(res, exact_res, obs, truth, noise=None):
    r'''Expected scatter of the image fit about the exact fit, from its Jacobian

SYNOPSIS

    s = scatter(res, exact_res, obs, truth)
    s["sigma"]["Hc"], s["sigma"]["theta_deg"], s["sigma"]["projection_rms"]
    s["noise_per_pose"]     # sigma px per image (the model's input)
    s["joint"]["chi2"], s["joint"]["dof"], s["joint"]["z"]   # joint_of_fit (with the
                                                             # resolution term)

None when the fit cannot be linearised here (see linearisation()). noise: the record's
detection_noise(), whose per-image detected - exact RMS an image too small to read its own
noise from its residuals takes (noise_per_pose). Sigma of a
vector parameter (C_mm, A_deg, O_deg) is that of its length: sqrt of the trace.
projection_rms is the expected RMS over the image grid of the rotation-mode
projection difference (the rotation's own freedom projected out).
'''
    lin = linearisation(res, obs)
    if lin is None:
        return None
    theta = res.theta_estimated
    world = _world(res)
    n = len(lin.x0)
    m0 = lin.model(lin.x0)
    # The differences are taken against the exact fit, as the renderer comparison takes
    # them: a fractional one (Hs, R1_frac, ...) is (image - exact) / |exact|, so its sigma
    # is the image fit's sigma over |exact|. Over |image| instead (the image fit's own
    # value) the two disagree by |image / exact|, which is ~1 unless the parameter is
    # near zero against its sigma (a nearly distortion-free lens: Mastcam-Z Z110's R2
    # gave R2_frac z 32 for an R2 at z 1.5; navcam 15 with R1 = 1e-8, R1_frac z 1270 for
    # an R1 at z 1.4: a false alarm of the renderer gate, which judges R1_frac).
    ref = exact_res.model if getattr(exact_res, "model", None) is not None else m0
    q0 = _signed_quantities(ref, m0, theta, world)
    names = list(q0)

    def qvec(m):
        q = _signed_quantities(ref, m, theta, world)
        return np.array([q.get(k, 0.0) for k in names])
    P = projection_points(truth)
    # the model's Jacobians: the reported quantities (G) and the projection of the image
    # grid (Jg), in closed form where the Linearisation knows them (jpl:
    # jpl_quantity_jacobian, jpl_grid_jacobian; mrcal: its own grid derivatives and the
    # quantities but R0's), otherwise in one pass over its stepped models; then the
    # fit's own Jacobian J
    with np.errstate(all="ignore"):
        G = None if lin.quantity_jacobian is None else \
            lin.quantity_jacobian(m0, ref, names, theta, qvec)   # (m, n_model)
        Jg, Jw = (None, None) if lin.grid_jacobian is None else lin.grid_jacobian(P)
        if G is None and Jg is None:
            G, Jg = lin.model_jacobians([qvec, _grid_projector(P)])
        elif G is None:
            G, = lin.model_jacobians([qvec])
        elif Jg is None:
            Jg, = lin.model_jacobians([_grid_projector(P)])
        J = lin.jacobian()                                       # (2N, n)
    # the resolution term of the joint test is a metric of the unweighted projection moves
    # (|J dx|^2), so it takes the unweighted J's normal inverse
    res_normal = _normal_inverse(J)
    J_fit = J if lin.row_weights is None else J * lin.row_weights[:, None]
    normal = res_normal if lin.row_weights is None else _normal_inverse(J_fit)
    # each image's noise, read from its residual degrees of freedom (fit_leverage: what
    # the fit's hat matrix took from its rows)
    sig_pose = noise_per_pose(res, exact_res, obs.Nposes, n,
                              absorbed=fit_leverage(J_fit, lin.pose, obs.Nposes, normal),
                              direct=None if noise is None else noise.get("per_pose_rms"))
    # per coordinate: sigma_image^2 / 2 (sigma is the RMS of the 2-d error), spread over
    # the image's corners by their detector's prediction where it has one (corner_shares)
    var_row = np.repeat(sig_pose[lin.pose] ** 2 / 2.0, 2)
    shares = corner_shares(obs, lin.pose)
    if shares is not None:
        var_row = var_row * np.repeat(shares, 2)
    if not np.all(np.isfinite(var_row)):
        return None
    if lin.row_weights is not None:
        # a weighted fit (Linearisation.row_weights w) minimised |w r|^2: its move is
        # (J^T W J)^-1 J^T W dq, W = diag(w^2), so cov = (J^T W J)^-1 J^T W D W J (J^T W J)^-1:
        # J's rows scaled by w, and D = S C S's S by w (var_row by w^2; C unchanged)
        J = J_fit
        var_row = var_row * lin.row_weights ** 2
    # cov = (J^T J)^-1 J^T D J (J^T J)^-1 with J's columns scaled to unit length (narrow
    # lenses make J^T J ill-conditioned) and a pseudo-inverse for directions the fit does
    # not determine at all (_normal_inverse); then the block of the parameters the model
    # depends on (the board poses marginalised)
    Ninv, s_col = normal
    Js = J / s_col
    # the model block as a Gram matrix: cov = F^T D F with F (2N, n_model) the image rows'
    # influence on the model parameters, factored cov = R^T R by the QR decomposition of
    # D^1/2 F (R: n_model x n_model). A variance a^T cov a is then the sum of squares
    # |R a|^2, never below zero: the triple product a^T cov a cancels to rounding in a
    # direction the fit barely determines (mrcal's CAHVOR R0 valley: its projection sigma
    # came out 0.0 on catalogue slot 16, leaving only the gate's floor). Householder QR is
    # backward stable: |R a| carries the rounding of |D^1/2 F a| itself (relative eps
    # |F| |a| / |F a|), at n_model columns instead of 2N per quantity.
    nm = lin.n_model
    F = Js @ (Ninv[:, :nm] / s_col[:nm])
    R = _gram_factor(F, var_row, None if shares is None else
                     corner_correlation(obs, lin.pose))
    cov = R.T @ R
    var = _variances(R, G)
    sigma = {}
    for k, v in zip(names, var, strict=True):
        base = k.split("[")[0]
        if base in VECTOR_PARAMS:
            sigma[base] = sigma.get(base, 0.0) + float(v)
        else:
            sigma[k] = float(math.sqrt(v))
    for k in VECTOR_PARAMS:
        if k in sigma:
            sigma[k] = math.sqrt(sigma[k])
    sigma["projection_rms"] = _projection_sigma(m0, P, Jg, R, Jw)
    # the joint test's covariance adds the renderer resolution (joint_resolution_cov)
    res_cov = joint_resolution_cov(*res_normal, len(lin.pose))[:lin.n_model, :lin.n_model]
    return {"sigma": sigma, "joint": joint_of_fit(names, q0, G, cov + res_cov, ref),
            "noise_per_pose": [None if not np.isfinite(s) else float(s)
                               for s in sig_pose],
            "n_params": n, "n_points": int(len(lin.pose))}


def _normal_inverse(J):
    r'''(Ninv, s_col): the pseudo-inverse of J's normal matrix with J's columns scaled to unit
length (s_col, their norms; 1 for a zero column), directions below 1e-15 of the largest
eigenvalue left out: Ninv = (Js^T Js)^+ for Js = J / s_col'''
    s_col = np.linalg.norm(J, axis=0)
    s_col[s_col == 0] = 1.0
    Js = J / s_col
    w, V = np.linalg.eigh(Js.T @ Js)
    keep = w > w[-1] * 1e-15
    return (V[:, keep] / w[keep]) @ V[:, keep].T, s_col


def projection_points(truth):
    r'''(M,3) the points of the projection sigma: PROJECTION_SAMPLES of the truth's image
grid (harness.compare.truth_points), in its camera frame'''
    _, _, p_cam = truth_points(truth)
    P = p_cam.reshape(-1, 3)
    if len(P) > PROJECTION_SAMPLES:
        P = P[np.linspace(0, len(P) - 1, PROJECTION_SAMPLES).astype(int)]
    return P


def _grid_projector(P):
    r'''m -> (M,2) m's projection of the points P of its own camera frame

A JPL-family model's camera frame (Rt_ref_cam: origin C, axes H', A x H', A) depends on
its C, A and H only: the points are moved into it once for the stepped models that share
them (model_jacobians' steps of V, O, R and E), the same numbers.'''
    frame = [None, None]

    def grid(m):
        if not _is_jpl(m):
            return _projector(m)(_rotated_into(m.Rt_ref_cam(), P))
        key = (m.C.tobytes(), m.A.tobytes(), m.H.tobytes())
        if frame[0] != key:
            frame[:] = key, _rotated_into(m.Rt_ref_cam(), P)
        return _projector(m)(frame[1])
    return grid


def _gram_factor(F, var_row, blocks=None):
    r'''R (n, n) with R^T R = F^T D F, D = diag(var_row): the R of the QR decomposition of
D^1/2 F (see _scatter). blocks: None, or [(rows, C)]: D's rows correlated, D = S C S on
those rows (S = diag(var_row)^1/2, C a correlation matrix: corner_correlation), factored
C = B^T B per block (its eigen decomposition, negative rounding clipped) and D^1/2 F's
rows there B S F'''
    X = F * np.sqrt(var_row)[:, None]
    if blocks:
        X = X.copy()
        for rows, C in blocks:
            w, V = np.linalg.eigh(C)
            X[rows] = (np.sqrt(np.clip(w, 0.0, None))[:, None] * V.T) @ X[rows]
    return np.linalg.qr(X, mode="r")


def _variances(R, A):
    r'''diag(A cov A^T) for cov = R^T R, as sums of squares (each >= 0)'''
    B = A @ R.T
    return np.einsum("ij,ij->i", B, B)


def _projection_sigma(m0, P, Jg, R, Jw=None):
    r'''Expected RMS px over the points P of the rotation-mode projection difference, from
Jg (2M, n_model) = d grid / d model parameters (_grid_projector) and their covariance
R^T R (scatter); Jw (2M, 3): d grid / d w of a turn R(w) of the points (the
Linearisation's grid_jacobian), or None: central differences'''
    if Jw is None:
        project, Rt_ref_cam = _projector(m0), m0.Rt_ref_cam()

        def rotated(w):
            return project(transform_point_Rt(Rt_ref_cam, P @ _rodrigues(w).T))
        with np.errstate(all="ignore"):
            Jw = _central_jacobian(rotated, np.zeros(3), np.full(3, 1e-7))
    ok = np.all(np.isfinite(Jg), axis=1) & np.all(np.isfinite(Jw), axis=1)
    Jg, Jw = Jg[ok], Jw[ok]
    M = ok.sum() / 2
    if M < 1:
        return None
    Qw, _ = np.linalg.qr(Jw)
    Jg = Jg - Qw @ (Qw.T @ Jg)          # the rotation fitted between the two fits
    return float(math.sqrt(_variances(R, Jg).sum() / M))


def z_scores(renderer, sigma):
    r'''{quantity: renderer difference / sigma} (projection_rms: RMS / its sigma)'''
    out = {}
    params = renderer.get("params") or {}
    for k, s in sigma.items():
        v = (renderer.get("projection") or {}).get("rms") if k == "projection_rms" \
            else params.get(k)
        if v is None or s is None or not s > 0:
            continue
        out[k] = float(abs(v) / s)
    return out


# --- the joint test: every renderer difference at once, by its full covariance -----------
#
# The marginal test judges each difference against its own sigma. A fault the fit can
# represent moves the differences along one direction of parameter space; where the
# parameters are correlated (R1 with the focal length, O with A and Hc) that direction's
# sigma, given the others, is far below each marginal sigma, and only the Mahalanobis
# distance d^T S^+ d sees it at that size. Under the noise model (the notes above
# scatter()) it is chi-square distributed with dof = the rank of S kept; the resolution
# term (JOINT_RESOLUTION_Z) only adds to S, so with it chi2 is smaller (a test at most as
# likely to alarm as its chi-square threshold says). Measured on clean jpl fits of every
# catalogue slot and extra (benchmarks/renderer_gate.py): without the term CAHV and CAHVOR
# are near chi-square (chi2/dof 0.89), CAHVORE was over-dispersed (1.65: hazcam 17's A along
# the world z axis, _unit_components; the wide hazcams, campaigns/gate-renderer.toml); with
# it chi2/dof is ~0.2 where the detection noise sits at the 1e-4 px floor (most slots, area
# coverage).
#
# JOINT_EIGEN_CUT: directions of the correlation matrix (S scaled to unit diagonal) whose
# eigenvalue is below this fraction of the largest are left out of the statistic and of
# its dof. Two kinds sit there: exact redundancies of the reported quantities (R1 and
# R1_frac, Hs and Hs*(1+R0): 0 up to rounding; the unit vectors A and O are reported by
# their two tangent components, _unit_components) and what the covariance cannot
# resolve. G's columns are central differences with steps 1e-6 of each parameter (jpl,
# mrcal (but R0's) and OpenCV fits' are in closed form, jpl_quantity_jacobian and the
# Linearisation's quantity_jacobian: rounding only), so
# they carry a relative rounding error of about
# 2.2e-16 / 1e-6 = 2e-10; the correlation matrix inherits ~1e-10 per entry and its
# eigenvalues ~m x 1e-10 (m ~ 25 quantities): ~3e-9. The cut sits a factor 3 above that:
# a kept direction's conditional sigma is at least 1e-4 of the marginal ones.
JOINT_EIGEN_CUT = 1e-8
# The renderer resolution in the joint test. DETECTION_RESOLUTION_PX (1e-4 px: what float32
# model vectors move a projection by) floors the noise per image, but as independent noise
# per point, which averages away over a fit's ~600 points; a renderer's sub-resolution
# errors are coherent (float32 rounding of C moves every point alike), and the joint test,
# which sees coherent moves by their conditional sigma (1.2e-5 px of Hc on pancam 13),
# flagged float32 model vectors on pancam 13 at z 8.1 without it. So its covariance adds a
# coherent resolution term: any move of the fit's parameters dx costs
# (RMS over the observed points of its projection change / r)^2, r = DETECTION_RESOLUTION_PX
# / JOINT_RESOLUTION_Z: a coherent 1e-4 px alone is a 6-sigma event, as the [[scatter]]
# floors of campaigns/gate-renderer.toml put 1e-4 px (or what moves pixels by it) at z 6.
JOINT_RESOLUTION_Z = 6.0


def joint_statistic(d, S, cut=JOINT_EIGEN_CUT, basis=None):
    r'''The Mahalanobis distance of differences d under their covariance S

SYNOPSIS

    j = joint_statistic(d, S)      # d has shape (m,); S (m,m)
    j["chi2"], j["dof"], j["z"]    # d^T S^+ d, rank kept, equivalent Gaussian z

S is scaled to unit diagonal (the quantities' units drop out) and inverted on the
eigen-directions above cut x its largest eigenvalue (JOINT_EIGEN_CUT): the gauge,
exact redundancies and directions the fit does not determine are left out, and dof
counts the directions kept. A quantity with zero variance (one the fit holds: R0)
is left out with its difference. z: the Gaussian z whose two-sided tail has the
probability of chi2 under the chi-square distribution with dof degrees of freedom
(joint_z), so z = 6 is as strict as the per-quantity gate's z = 6.
Returns {"chi2", "dof", "z", "n"} (n quantities taken), chi2 and z None when dof is 0.
basis: a JointBasis(S, cut) to take the eigen-directions from (joint_of_fit: one
decomposition of S for the statistic and every fault sigma; the same numbers).
'''
    d = np.asarray(d, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    s = np.sqrt(np.maximum(np.diag(S), 0.0))
    ok = (s > 0) & np.isfinite(s) & np.isfinite(d)
    out = {"chi2": None, "dof": 0, "z": None, "n": int(ok.sum())}
    if not ok.any():
        return out
    V, w = (basis or JointBasis(S, cut)).of(s, ok)
    u = V.T @ (d[ok] / s[ok])
    chi2 = float(np.sum(u * u / w))
    dof = len(w)
    return {"chi2": chi2, "dof": dof, "z": joint_z(chi2, dof), "n": out["n"]}


def _joint_basis(S, s, ok, cut):
    r'''(V, w): the eigen-directions of the correlation matrix of S on the quantities ok
(s: their sigmas) whose eigenvalue w is above cut x the largest (joint_statistic)'''
    w, V = np.linalg.eigh(S[np.ix_(ok, ok)] / np.outer(s[ok], s[ok]))
    keep = w > cut * w[-1]
    return V[:, keep], w[keep]


class JointBasis:
    r'''_joint_basis of one covariance S and cut, decomposed once per set of quantities:
joint_of_fit asks it for the statistic and for each minimum-detectable fault, on the
same quantities (all of them, unless a difference is not finite): one eigh, not six'''

    def __init__(self, S, cut=JOINT_EIGEN_CUT):
        self.S, self.cut, self._memo = S, cut, {}

    def of(self, s, ok):
        key = ok.tobytes()
        hit = self._memo.get(key)
        if hit is None:
            hit = self._memo[key] = _joint_basis(self.S, s, ok, self.cut)
        return hit


def joint_resolution_cov(Ninv, s_col, n_points):
    r'''The resolution covariance of the fit's parameters (see JOINT_RESOLUTION_Z):
r^2 n_points (J^T J)^+, from _scatter's Ninv = (Js^T Js)^+ of the column-scaled Jacobian
Js = J / s_col; under it a move dx has Mahalanobis distance^2 = |J dx|^2 / (n_points r^2)'''
    r = DETECTION_RESOLUTION_PX / JOINT_RESOLUTION_Z
    return r * r * n_points * Ninv / np.outer(s_col, s_col)


def joint_fault_sigma(v, S, cut=JOINT_EIGEN_CUT, basis=None):
    r'''The sigma the joint statistic sees a fault by: a fault moving the quantities by
d x v (v (m,): the move per unit fault) adds (d / sigma)^2 to chi2; None when v lies in
the directions left out (joint_statistic's cut) or has no component in S's support;
basis: as joint_statistic's'''
    v = np.asarray(v, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    s = np.sqrt(np.maximum(np.diag(S), 0.0))
    ok = (s > 0) & np.isfinite(s)
    if not ok.any():
        return None
    V, w = (basis or JointBasis(S, cut)).of(s, ok)
    u = V.T @ (v[ok] / s[ok])
    q = float(np.sum(u * u / w))
    return 1.0 / math.sqrt(q) if q > 0 else None


def joint_z(chi2, dof):
    r'''The Gaussian z with the two-sided tail probability of chi2 under chi-square(dof)

Far in the tail (chi2 of a gross fault: scipy's log survival underflows) the upper
incomplete gamma function's leading term is used: log Q(a, x) ~ (a - 1) log x - x -
log Gamma(a), x = chi2 / 2, a = dof / 2, relative error ~(a - 1) / x.'''
    # scipy.special, not scipy.stats: the same functions (stats.chi2.logsf is log(chdtrc),
    # stats.chi2.isf chdtri, stats.norm.sf ndtr(-z)) without ~1 s of import per worker
    from scipy import special
    if chi2 is None or dof < 1:
        return None
    with np.errstate(divide="ignore"):
        logp = float(np.log(special.chdtrc(dof, chi2)))
    if not np.isfinite(logp):
        a, x = dof / 2.0, chi2 / 2.0
        logp = (a - 1) * math.log(x) - x - math.lgamma(a)
    return float(-special.ndtri_exp(logp - math.log(2.0)))


def joint_limit(z, dof):
    r'''chi2 at which joint_z reaches z: the chi-square(dof) quantile at the two-sided
Gaussian tail probability of z'''
    from scipy import special
    return float(special.chdtri(dof, 2.0 * special.ndtr(-z)))


# The faults of the minimum detectable fault (harness.gate.MDF_FAULTS), each as the move of
# the reported quantities per unit fault: a focal scale moves every focal fraction alike,
# an R1 scale R1_frac by 1 and R1 by |R1| of the exact fit.
def _joint_fault_directions(names, ref):
    idx = {k: i for i, k in enumerate(names)}
    R1 = abs(float(ref.R[1])) if _is_jpl(ref) and ref.family != "CAHV" else 0.0
    faults = {"Hc": {"Hc": 1.0}, "Vc": {"Vc": 1.0}, "theta_deg": {"theta_deg": 1.0},
              "roll_deg": {"roll_deg": 1.0},
              "Hs": {"Hs": 1.0, "Vs": 1.0, "Hs*(1+R0)": 1.0, "Vs*(1+R0)": 1.0},
              "R1_frac": {"R1_frac": 1.0, "R1": R1}}
    out = {}
    for p, move in faults.items():
        if p not in idx:
            continue
        v = np.zeros(len(names))
        for k, x in move.items():
            if k in idx:
                v[idx[k]] = x
        out[p] = v
    return out


def joint_of_fit(names, q0, G, cov, ref):
    r'''verdict.renderer.joint: joint_statistic of the renderer differences q0 (the signed
reported quantities names, image fit minus exact fit ref) under G cov G^T (_scatter passes
the fit's covariance plus the resolution term joint_resolution_cov), with the sigma each
minimum-detectable fault is seen by ("fault_sigma", joint_fault_sigma) and the direction
that carries most of chi2 ("direction", joint_direction)'''
    S = G @ cov @ G.T
    d = np.array([q0[k] for k in names], dtype=np.float64)
    basis = JointBasis(S)
    out = joint_statistic(d, S, basis=basis)
    out["fault_sigma"] = {p: joint_fault_sigma(v, S, basis=basis)
                          for p, v in _joint_fault_directions(names, ref).items()}
    out["direction"] = joint_direction(names, d, S, basis=basis)
    return out


# quantities joint_direction names a direction by (its largest loadings)
JOINT_DIRECTION_LOADINGS = 5


def joint_direction(names, d, S, cut=JOINT_EIGEN_CUT, basis=None):
    r'''The eigen-direction of joint_statistic that carries the largest part of chi2:
{"chi2": its part, "share": of the whole, "relative_eigenvalue": its eigenvalue over the
largest kept (its conditional sigma over the marginal ones, squared), "loading": {quantity:
component} of the JOINT_DIRECTION_LOADINGS largest components of the unit direction, in the
quantities scaled to unit variance, signed as the difference moved along it}, or None when
chi2 is None or 0

What a failed joint test with every marginal z small names: a combination of quantities
the covariance holds tight and the two fits do not (the small-sensor false alarm of session
21: share 0.52 at relative eigenvalue 9.6e-7, loading E2, E1, E0, R1 and C, a wrong bias
correction of one fit's corners, docs/corners.md).'''
    d = np.asarray(d, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    s = np.sqrt(np.maximum(np.diag(S), 0.0))
    ok = (s > 0) & np.isfinite(s) & np.isfinite(d)
    if not ok.any():
        return None
    V, w = (basis or JointBasis(S, cut)).of(s, ok)
    if len(w) == 0:
        return None
    u = V.T @ (d[ok] / s[ok])
    part = u * u / w
    total = float(part.sum())
    if not total > 0:
        return None
    i = int(np.argmax(part))
    v = V[:, i] if u[i] >= 0 else -V[:, i]      # signed as the difference moved along it
    kept = [k for k, o in zip(names, ok, strict=True) if o]
    top = np.argsort(-np.abs(v), kind="stable")[:JOINT_DIRECTION_LOADINGS]
    return {"chi2": float(part[i]), "share": float(part[i] / total),
            "relative_eigenvalue": float(w[i] / w.max()),
            "loading": {kept[j]: float(v[j]) for j in top}}

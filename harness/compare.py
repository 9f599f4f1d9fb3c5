r'''Compare a calibrator's result with the truth: parameters, projections, residuals

SYNOPSIS

    from harness.compare import compare, parameter_errors, projection_difference

    summary = compare(result, truth)           # a JSON-able dict
    errors = parameter_errors(truth, fit, theta_estimated=True, world_frame=True)
    errors["Hc"], errors["theta_deg"]          # float, or None: "not estimated"
    d = projection_difference(truth, fit, mode="rotation")
    d["rms"], d["max"]                         # px over the whole image grid
    d["map"]                                   # (ny,nx) |q_fit - q_truth|, px

Parameter errors (fit - truth):

- Hc, Vc (px); Hs, Vs (fractional); Hs*(1+R0), Vs*(1+R0) (fractional, raw
  models); theta_deg (deg); C_mm (|C_fit - C_truth|, mm); A_deg, O_deg (angle,
  deg); R0, R1, R2 (absolute and fractional; R0 against the raw truth, R1
  and R2 against the truth moved to the fit's R0); E0, E1, E2 (absolute).
- None means "not estimated": the fit's family lacks the parameter (O, R, E
  for CAHV, OpenCV and COLMAP fits; theta for every calibrator but jpl, whose
  fits are the only ones with independent H and V), or the fit's world frame
  is not the truth's (C, A when the board poses were estimated).
- R0 gauge: in CAHVOR and CAHVORE R0 is exactly redundant with A, H and V
  (harness.calibrators.jpl_fit, R0_GAUGE). Before comparing, the truth is
  moved to the fit's R0 by with_R0(), an exact re-parametrisation; the raw
  truth's Hs*(1+R0) is compared as well, since it is nearly gauge-free.
- O is compared in each model's own camera frame (x = H', y = A x H', z = A),
  so it is meaningful also when the world frames differ.

Projection difference: pixels q over a grid covering the whole image are
unprojected with the truth; points at range_m (2 m) along those rays
(noncentral CAHVORE needs a range) are expressed in the truth's camera frame
and projected by the fit placed in its own camera frame:

- "intrinsics": nothing aligned: the camera frames are identified.
- "rotation": the rotation between the two camera frames that minimises the
  projection difference is fitted first (as mrcal.projection_diff aligns the
  two cameras; a pure rotation here).
- "world": no frames at all: the fit projects the world points (only when
  the fit lives in the truth's world frame, e.g. jpl).
'''

import dataclasses
import math
import threading

import numpy as np

from reference_models.cahvore import FAMILIES, with_R0
from reference_models.poseutils import R_from_r, transform_point_Rt

# the projection-difference modes (projection_difference): "world" only for fits in the
# world frame
PROJECTION_MODES = ("rotation", "intrinsics", "world")

DEFAULT_RANGE_M = 2.0
DEFAULT_GRID_STEP = 16


def _angle_deg(u, v):
    c = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
    return math.degrees(math.atan2(math.hypot(*c), u[0] * v[0] + u[1] * v[1] + u[2] * v[2]))


def _intrinsics(model):
    r'''(Hc, Vc, Hs, Vs) of any fitted model'''
    if getattr(model, "family", None) in FAMILIES:
        ph = model.photogrammetric()
        return ph.Hc, ph.Vc, ph.Hs, ph.Vs
    return model.cx, model.cy, model.fx, model.fy


def _in_cam(model, v, ph=None):
    r'''v (3,) in model's camera frame (Rt_ref_cam: x = H', y = A x H', z = A); ph: model's
photogrammetric() when the caller has it'''
    Hp = (model.photogrammetric() if ph is None else ph).Hp
    A = model.A
    y = (A[1] * Hp[2] - A[2] * Hp[1], A[2] * Hp[0] - A[0] * Hp[2], A[0] * Hp[1] - A[1] * Hp[0])
    return np.array((Hp[0] * v[0] + Hp[1] * v[1] + Hp[2] * v[2],
                     y[0] * v[0] + y[1] * v[1] + y[2] * v[2],
                     A[0] * v[0] + A[1] * v[1] + A[2] * v[2]))


def _frac(a, b):
    return None if b == 0 else (a - b) / abs(b)


def parameter_errors(truth, fit, theta_estimated=None, world_frame=None, signed=False):
    r'''Errors of the fitted parameters against the truth (fit - truth)

SYNOPSIS

    e = parameter_errors(truth, fit, theta_estimated=True, world_frame=True)
    # dict of floats; None where the fit does not estimate the parameter

theta_estimated defaults to True for JPL-family fits; world_frame (the fit's
C and A are in the truth's world frame) defaults to False. signed: C_mm, A_deg
and O_deg as their signed components (fit - truth, (3,) each: C in mm, A and O
(in each camera frame) in deg per axis, the truth moved to the fit's R0), not
their magnitudes: the scatter's Jacobian (harness.verdict).
'''
    fam = getattr(fit, "family", None)
    jpl = fam in FAMILIES
    if theta_estimated is None:
        theta_estimated = jpl
    world_frame = bool(world_frame)
    has_O = jpl and fam != "CAHV" and truth.family != "CAHV"
    fit_R0 = float(fit.R[0]) if jpl and fam != "CAHV" else 0.0
    t, t_ph, traw, t_O = _truth_side(truth, fit_R0 if has_O else None, jpl and fam == "CAHV")
    fit_ph = fit.photogrammetric() if jpl else None
    Hc, Vc, Hs, Vs = ((fit_ph.Hc, fit_ph.Vc, fit_ph.Hs, fit_ph.Vs) if jpl
                      else _intrinsics(fit))
    out = {"Hc": Hc - t_ph.Hc, "Vc": Vc - t_ph.Vc, "Hs": _frac(Hs, t_ph.Hs),
           "Vs": _frac(Vs, t_ph.Vs)}
    truth_R0 = float(truth.R[0]) if truth.family != "CAHV" else 0.0
    out["Hs*(1+R0)"] = _frac(Hs * (1 + fit_R0), traw.Hs * (1 + truth_R0))
    out["Vs*(1+R0)"] = _frac(Vs * (1 + fit_R0), traw.Vs * (1 + truth_R0))
    out["theta_deg"] = (fit_ph.theta_deg - t_ph.theta_deg
                        if theta_estimated and jpl else None)
    world_frame = world_frame and jpl
    fit_O = _in_cam(fit, fit.O, fit_ph) if has_O else None
    if signed:
        out["C_mm"] = 1e3 * (fit.C - t.C) if world_frame else None
        out["A_deg"] = np.degrees(fit.A - t.A) if world_frame else None
        out["O_deg"] = np.degrees(fit_O - t_O) if has_O else None
    else:
        out["C_mm"] = 1e3 * float(np.linalg.norm(fit.C - t.C)) if world_frame else None
        out["A_deg"] = _angle_deg(fit.A, t.A) if world_frame else None
        out["O_deg"] = _angle_deg(fit_O, t_O) if has_O else None
    for i in range(3):
        name = f"R{i}"
        # R0 against the raw truth (how far the fit slid along the R0 gauge); R1, R2
        # against the truth moved to the fit's R0
        ref = truth if i == 0 else t
        if has_O:
            out[name] = float(fit.R[i] - ref.R[i])
            out[name + "_frac"] = _frac(float(fit.R[i]), float(ref.R[i]))
        else:
            out[name] = out[name + "_frac"] = None
    has_E = jpl and fam == "CAHVORE" and t.family == "CAHVORE"
    for i in range(3):
        out[f"E{i}"] = float(fit.E[i] - t.E[i]) if has_E else None
    return {k: (None if v is None else v if isinstance(v, np.ndarray) else float(v))
            for k, v in out.items()}


# parameter_errors' side of the truth, for the truth and R0 gauge asked last: the scatter's
# Jacobian (harness.verdict) compares ~40 stepped models with one truth, mostly at one R0
_TRUTH_SIDE = [None]


def _truth_side(truth, R0, cahv):
    r'''(t, t.photogrammetric(), truth.photogrammetric(), t's O in its camera frame or
None) for parameter_errors: t is the truth moved to R0 (R0 None: not moved, no O) or,
cahv, truncated to CAHV; the last one asked is kept (keyed on the truth object itself:
models are frozen)'''
    hit = _TRUTH_SIDE[0]
    if hit is not None and hit[0] is truth and hit[1] == (R0, cahv):
        return hit[2]
    t = truth
    if R0 is not None:
        t = with_R0(truth, R0)
    if cahv:
        t = truth.to_cahv()
    traw = truth.photogrammetric()
    side = (t, t.photogrammetric() if t is not truth else traw, traw,
            None if R0 is None else _in_cam(t, t.O))
    _TRUTH_SIDE[0] = (truth, (R0, cahv), side)     # one tuple: atomic for a worker's threads
    return side


def image_grid(width, height, step=DEFAULT_GRID_STEP):
    r'''Pixel centres on a regular grid covering the whole image, edges included

SYNOPSIS

    q = image_grid(W, H, step=16)   # q has shape (ny,nx,2)
'''
    nx = max(2, int(math.ceil((width - 1) / step)) + 1)
    ny = max(2, int(math.ceil((height - 1) / step)) + 1)
    x = np.linspace(0.0, width - 1.0, nx)
    y = np.linspace(0.0, height - 1.0, ny)
    return np.stack(np.meshgrid(x, y), axis=-1)


def _projector(fit):
    r'''fit.project, compiled for a JPL-family fit

SYNOPSIS

    project = _projector(fit)
    q = project(p)          # as fit.project(p)

A CAHV, CAHVOR or CAHVORE fit projects with
reference_models.kernels (the equations of reference_models.cahvore
point by point, within 1e-10 px of fit.project; the maps of 42 jpl/mrcal
records of paper jobs within 1.1e-10 px, their rms and max within 1e-11 px);
any other fit (OpenCV, COLMAP) with its own project(). projection_difference
projects with it, and so does _fit_rotation (_rotated_pixels): the rotation's
least-squares path is sensitive to the last bits of the residuals: the
compiled projection moved the paper campaign's 172 ok records by at most
5.5e-7 of their sigma (benchmarks/bench_fits.py diff), compare() 12-15% faster.
'''
    from reference_models.kernels import KINDS, project_packed
    if getattr(fit, "family", None) not in KINDS:
        return fit.project
    cam = _packed(fit)
    return lambda p: project_packed(cam, p)


# the last JPL-family models packed (_packed): a comparison projects one fit several times
# (its grid, its rotation fit) and the verdict's scatter each pair of stepped models twice
# (the image grid, then the fit's points: harness.verdict.Linearisation.model_jacobians)
_PACKED = [()]
PACKED_MEMO = 2


def _packed(fit):
    r'''reference_models.kernels.pack_model(fit), kept for the last PACKED_MEMO fits asked
(keyed on the objects themselves: models are frozen)'''
    from reference_models.kernels import pack_model
    memo = _PACKED[0]
    for m, cam in memo:
        if m is fit:
            return cam
    cam = pack_model(fit)
    _PACKED[0] = ((fit, cam),) + memo[:PACKED_MEMO - 1]     # one tuple: atomic for threads
    return cam


# _fit_rotation's Gauss-Newton: it stops when its next step would move no pixel by more than
# this (px: a ten-thousandth of the smallest detection scatter the verdict resolves,
# harness.verdict.DETECTION_RESOLUTION_PX, and below the 4e-8 px by which MINPACK's own
# stopping point wandered), and hands over to MINPACK's Levenberg-Marquardt after this many
# steps or a step that does not lower the sum of squares
ROTATION_SETTLED_PX = 1e-8
ROTATION_GN_STEPS = 8
# ... or when a step does not lower the sum of squares and moves no pixel by more than
# this (px: a hundredth of DETECTION_RESOLUTION_PX): the step is then the rounding of a
# differenced Jacobian at the minimum, which grows with the residuals (far floors: residuals
# of px, steps of 4e-8 to 1.2e-7 px on the paper campaign's), not a way down; stopping
# there moves the maximum by at most this and the RMS by its square (the minimum's
# gradient is zero), where MINPACK took ~43 more projections to wander as far
ROTATION_ROUNDING_PX = 1e-6

# _fit_rotation asks the last step's Jacobian whether the next step would settle
# (_settled_by) when that step moved no pixel by more than this (px): the Jacobian's own
# change over the step is then ~1e-7 of it (a pixel per 1e-3 rad of a 1000 px lens: a
# rotation of 1e-7 rad), below its forward differences' rounding
ROTATION_CHORD_PX = 1e-4


def _settled_by(J, f, moved):
    r'''True when the Gauss-Newton step at residuals f by the previous step's Jacobian J
(the chord: no new Jacobian, 3 projections fewer) moves no pixel by more than a tenth of
ROTATION_SETTLED_PX, after a previous step that moved none by more than
ROTATION_CHORD_PX (moved)'''
    if not moved <= ROTATION_CHORD_PX:
        return False
    try:
        step = np.linalg.solve(J.T @ J, -(J.T @ f))
    except np.linalg.LinAlgError:
        return False
    return bool(np.max(np.abs(J @ step)) <= 0.1 * ROTATION_SETTLED_PX)


# the residual of a point the fit cannot project, px (the rotation fit's)
UNPROJECTABLE_PX = 1e3


def _residual(pixels, q):
    r'''(pixels - q).ravel(), UNPROJECTABLE_PX where not finite: the numbers of
reference_models.kernels.residuals_packed (the same subtraction, element by element)'''
    d = pixels - q
    return np.where(np.isfinite(d), d, UNPROJECTABLE_PX).ravel()


# _rotated_pixels' last (fit, P, {r bytes: pixels}): fit's pixels of the sample points P at
# no rotation and at the first Jacobian's steps from it, which do not depend on the pixels
# fitted: a record's verdict fits the exact fit's rotation twice on the same points, onto
# the truth's grid (its floor) and onto the image fit's pixels (its renderer comparison)
_ROTATED_PIXELS = [()]
ROTATED_PIXELS_MEMO = 2


def _rotated_pixels(fit, P):
    r'''pixels(r) -> fit's pixels (N,2) of the points P (N,3) of the truth's camera frame
turned by R_from_r(r) into fit's camera frame (compiled for JPL-family fits, as
_projector's projection is, whatever projection the grid is given); those at r with at
most one non-zero component (no rotation and the forward differences' steps from it) are
kept for the last ROTATED_PIXELS_MEMO (fit, P) (keyed on the objects themselves: models
are frozen, _rotation_points' P are not written)'''
    from reference_models.kernels import KINDS, project_packed
    Rt_ref_cam = fit.Rt_ref_cam()
    project = fit.project
    if getattr(fit, "family", None) in KINDS:
        cam = _packed(fit)

        def project(p):
            return project_packed(cam, p)
    kept = None
    for f, pts, d in _ROTATED_PIXELS[0]:
        if f is fit and pts is P:
            kept = d
            break
    if kept is None:
        kept = {}
        _ROTATED_PIXELS[0] = ((fit, P, kept),) + _ROTATED_PIXELS[0][:ROTATED_PIXELS_MEMO - 1]

    def pixels(r):
        one = np.count_nonzero(r) <= 1
        key = r.tobytes()
        q = kept.get(key) if one else None
        if q is None:
            q = project(transform_point_Rt(Rt_ref_cam, P @ R_from_r(r).T))
            if one:
                kept[key] = q
        return q
    return pixels


def finite_rows(a):
    r'''np.all(np.isfinite(a), axis=-1), column by column: (...,k) -> (...,) bool

The same booleans; numpy's reduction along a short last axis takes ~10x as long (the
image grid of a 5120x3840 camera, 77k rows: 3-6 ms, a grid projection's worth).'''
    ok = np.isfinite(a[..., 0])
    for i in range(1, a.shape[-1]):
        ok &= np.isfinite(a[..., i])
    return ok


# _rotation_points' last (p_cam, q, nmax, idx, P, Q): the arrays themselves, kept alive here so
# that identity stays a key (read-only arrays that own their data: truth_points' grid and
# points, fit_pixels' pixels)
_ROTATION_POINTS = []
ROTATION_POINTS_MEMO = 4


def _rotation_points(p_cam, q, nmax):
    r'''(P, Q): the rows of p_cam (...,3) and q (...,2) _fit_rotation fits on (both finite;
at most nmax, evenly spaced), Q C-contiguous; kept for the last few pairs of read-only
arrays that own their data (keyed on the objects): a record's comparison with the truth
and its verdict's floor fit a rotation onto the same grid from the same points (the
finiteness of a 77k-point grid costs ~1 ms a pair)'''
    frozen = all(a.base is None and not a.flags.writeable for a in (p_cam, q))
    if frozen:
        with _TRUTH_POINTS_LOCK:
            for a, b, n, _, P, Q in _ROTATION_POINTS:
                if a is p_cam and b is q and n == nmax:
                    return P, Q
    p2, q2 = p_cam.reshape(-1, 3), q.reshape(-1, 2)
    ok = finite_rows(q2) & finite_rows(p2)
    idx = np.flatnonzero(ok)
    if len(idx) > nmax:
        idx = idx[np.linspace(0, len(idx) - 1, nmax).astype(int)]
    P = None
    if frozen:
        # the same points of p_cam as another pair's (the same rows of q finite): the same
        # P object, whose rotated pixels _rotated_pixels keeps
        with _TRUTH_POINTS_LOCK:
            for a, _, n, i, P1, _ in _ROTATION_POINTS:
                if a is p_cam and n == nmax and np.array_equal(i, idx):
                    P = P1
                    break
    if P is None:
        P = p2[idx]
    Q = np.ascontiguousarray(q2[idx])
    if frozen:
        # not flagged read-only (_fit_rotation does not write them)
        with _TRUTH_POINTS_LOCK:
            _ROTATION_POINTS.append((p_cam, q, nmax, idx, P, Q))
            del _ROTATION_POINTS[:-ROTATION_POINTS_MEMO]
    return P, Q


def _fit_rotation(fit, p_cam, q, nmax=2000):
    r'''The rotation R minimising |fit(R p_cam) - q| (p_cam (...,3) in the truth's camera
frame, q (...,2))

Gauss-Newton from no rotation, with scipy's forward-difference Jacobian: the two
frames differ by a small rotation on which the pixels depend almost linearly, so it
reaches the minimum in 2-3 steps (4 projections each). After a small step the last
Jacobian tells whether the next would settle (_settled_by): where it would, the
Jacobian there is not differenced at all, 3 of the typical 8 projections (on the
paper campaign's 256 comparisons of 100 captured records 445 of 1937 projections
fewer; where a new Jacobian still settled at the same point, the same rotation bit
for bit, and 4 far floors (px) moved by <= 1.7e-8 px, the size of the step it
skipped: benchmarks/bench_verdict.py). A step that does not lower
the sum of squares ends it where it is when that step is rounding
(ROTATION_ROUNDING_PX: far floors, whose px residuals round the last steps);
MINPACK's Levenberg-Marquardt (scipy least_squares "lm", tolerances 1e-15) takes
over from where it stopped if a larger step does not lower it or the steps do not
settle (a fit whose points leave the model's domain): its path to 1e-15 took ~43
projections. Both stop at the same minimum: on 32 paper records (cameras 5,
15, 17, 21; benchmarks/bench_verdict.py) the verdict's projection RMS moved by < 1e-12
px and its maxima by < 4.2e-8 px, MINPACK's own wander (ROTATION_SETTLED_PX).
'''
    import scipy.optimize
    P, Q = _rotation_points(p_cam, q, nmax)
    pixels = _rotated_pixels(fit, P)

    def res(r):
        return _residual(pixels(r), Q)

    from harness.least_squares import forward_difference, remembering
    r = np.zeros(3)
    J, moved = None, math.inf
    with np.errstate(all="ignore"):
        f = res(r)
        cost = f @ f
        for _ in range(ROTATION_GN_STEPS):
            if J is not None and _settled_by(J, f, moved):
                return R_from_r(r)
            J = forward_difference(res, r, f)
            step = np.linalg.lstsq(J, -f, rcond=None)[0]
            moved = np.max(np.abs(J @ step))
            if moved <= ROTATION_SETTLED_PX:
                # settled: at the minimum the steps are the rounding of f and of the
                # differenced J (~1e-12 rad where the fits differ by px), and comparing sums
                # of squares there would only compare rounding
                return R_from_r(r)
            f1 = res(r + step)
            cost1 = f1 @ f1
            if not cost1 <= cost:
                if moved <= ROTATION_ROUNDING_PX:
                    return R_from_r(r)
                break
            r, f, cost = r + step, f1, cost1
        # scipy's 2-point Jacobian, bit for bit, remembering the last point's residuals and
        # Jacobian (scipy asks for the Jacobian at the solution again when MINPACK returns)
        fun, jac = remembering(res, lambda r, f0: forward_difference(res, r, f0))
        sol = scipy.optimize.least_squares(fun, r, jac=jac, method="lm",
                                           ftol=1e-15, xtol=1e-15, gtol=1e-15)
    return R_from_r(sol.x)


# the truth's side of projection_difference(), for the few truths compared last (each with
# the camera frames of the R0 gauges it was compared in: raw, and moved to the jpl and
# mrcal image and exact fits' R0)
_TRUTH_POINTS = {}
_TRUTH_POINTS_LOCK = threading.Lock()   # a Dask worker may compare in several threads
TRUTH_POINTS_MEMO = 4


def _model_key(model):
    r'''A hashable key holding every parameter of a JPL-family model, exactly'''
    return (type(model),) + tuple(
        (f.name, v.tobytes() if isinstance(v, np.ndarray) else v)
        for f in dataclasses.fields(model) for v in (getattr(model, f.name),))


def truth_points(truth, range_m=DEFAULT_RANGE_M, step=DEFAULT_GRID_STEP, R0=None):
    r'''The image grid, and points at range_m along the truth's rays through it

SYNOPSIS

    q, p_ref, p_cam = truth_points(truth, range_m=2.0, step=16)
    # q (ny,nx,2) px; p_ref (ny,nx,3) in the truth's world frame, p_cam the same
    # points in its camera frame (Rt_ref_cam); all three read-only
    q, p_ref, p_cam = truth_points(truth, R0=fit.R[0])
    # the same q and p_ref; p_cam in the camera frame of with_R0(truth, R0)

The same for every fit compared with this truth, so the last few are
memoised (keyed on every parameter of the truth, exactly): unprojecting the
grid of a 5120x3840 CAHVORE costs as much as projecting it. R0 (CAHVOR and
CAHVORE truths): the truth moved to another R0 gauge (with_R0) images the
same rays, so it shares the grid's points and only changes the camera frame:
a record's comparisons move the truth to each fit's R0 (the image fit's and
the exact fit's: harness.verdict), each of them one frame, not one
unprojection of the grid.
'''
    key = (_model_key(truth), float(range_m), step)
    frame = None if R0 is None or truth.family not in ("CAHVOR", "CAHVORE") else float(R0)
    with _TRUTH_POINTS_LOCK:
        hit = _TRUTH_POINTS.pop(key, None)
    if hit is None:
        q = image_grid(truth.width, truth.height, step)
        o, v = truth.unproject(q)
        p_ref = o + range_m * v
        for a in (q, p_ref):
            a.setflags(write=False)
        hit = (q, p_ref, {})
    q, p_ref, frames = hit
    p_cam = frames.get(frame)
    if p_cam is None:
        Rt = (truth if frame is None else with_R0(truth, frame)).Rt_ref_cam()
        p_cam = (p_ref - Rt[3]) @ Rt[:3]
        p_cam.setflags(write=False)
    with _TRUTH_POINTS_LOCK:
        frames[frame] = p_cam
        _TRUTH_POINTS[key] = hit      # the most recently used last
        while len(_TRUTH_POINTS) > TRUTH_POINTS_MEMO:
            del _TRUTH_POINTS[next(iter(_TRUTH_POINTS))]
    return q, p_ref, p_cam


def _rotated_into(Rt, p, R=None):
    r'''transform_point_Rt(Rt, p @ R.T) (R None: not rotated) in one pass: p (...,3) ->
(...,3), the image grid's points (77k of a 5120x3840 camera). Written out by coordinate:
a (77k,3) x (3,3) matrix product goes to OpenBLAS's threads, 10x slower on two busy
cores than the 9 multiply-adds (measured 2026-11-28 at load 15: 33 ms against 2 ms CPU)'''
    M = Rt[:3] if R is None else Rt[:3] @ R
    t = Rt[3]
    out = np.empty(p.shape)
    for i in range(3):
        out[..., i] = p[..., 0] * M[i, 0] + p[..., 1] * M[i, 1] + p[..., 2] * M[i, 2] + t[i]
    return out


def _distance(qa, qb):
    r'''|qb - qa| (...,) of pixels (...,2)'''
    d = qb - qa
    return np.hypot(d[..., 0], d[..., 1])


# fit_pixels() of the last few (fit, points) asked: a record's comparison with the truth
# (compare_stage) and its verdict's comparisons (harness.verdict: the exact fit with the
# truth, the image fit with the exact fit) project the same fits on the same grid points:
# the world points in every mode "world", and the truth's camera-frame points where the
# fit has no R0 gauge (CAHV, OpenCV) in mode "intrinsics"
_FIT_PIXELS = []
FIT_PIXELS_MEMO = 6


def fit_pixels(fit, points, frame):
    r'''fit's pixels (...,2) of grid points (...,3): world points (frame False), or points of
the truth's camera frame identified with fit's own (frame True: mode "intrinsics"); kept
for the last FIT_PIXELS_MEMO (fit, points) objects (models and truth_points' arrays are
not modified: keyed on the objects themselves). Read-only.'''
    with _TRUTH_POINTS_LOCK:
        for f, pts, fr, q in _FIT_PIXELS:
            if f is fit and pts is points and fr == frame:
                return q
    q = _projector(fit)(_rotated_into(fit.Rt_ref_cam(), points) if frame else points)
    q.setflags(write=False)
    with _TRUTH_POINTS_LOCK:
        _FIT_PIXELS.append((fit, points, frame, q))
        del _FIT_PIXELS[:-FIT_PIXELS_MEMO]
    return q


def projection_difference(truth, fit, mode="rotation", range_m=DEFAULT_RANGE_M,
                          step=DEFAULT_GRID_STEP):
    r'''|fit - truth| in projection over the whole image

SYNOPSIS

    d = projection_difference(truth, fit, mode="rotation")
    # d["map"] (ny,nx) px, NaN where the fit cannot project; d["q"] (ny,nx,2)
    # d["rms"], d["max"] px over the finite entries; d["n_invalid"]
    # (d["q"] is read-only: the truth's side is memoised, see truth_points)

mode: "rotation" (fitted rotation between the camera frames), "intrinsics"
(camera frames identified) or "world" (the world frames identified).
'''
    if mode not in PROJECTION_MODES:
        from reference_models.errors import CamvalError
        raise CamvalError(f"projection-difference mode {mode!r}; expected rotation, "
                          "intrinsics or world")
    # the same projection, in the camera frame matching the fit's R0 gauge
    R0 = float(fit.R[0]) if getattr(fit, "family", None) in ("CAHVOR", "CAHVORE") else None
    q, p_ref, p_cam = truth_points(truth, range_m, step, R0=R0)
    R = None
    if mode == "rotation":
        R = _fit_rotation(fit, p_cam, q)
        qf = _projector(fit)(_rotated_into(fit.Rt_ref_cam(), p_cam, R))
    else:
        qf = fit_pixels(fit, p_cam if mode == "intrinsics" else p_ref, mode == "intrinsics")
        R = np.eye(3) if mode == "intrinsics" else None
    d = _distance(q, qf)
    finite = np.isfinite(d)
    out = {"mode": mode, "range_m": range_m, "step": step, "q": q, "map": d,
           "n": int(finite.sum()), "n_invalid": int((~finite).sum()),
           "rms": float(np.sqrt(np.mean(d[finite] ** 2))) if finite.any() else None,
           "max": float(d[finite].max()) if finite.any() else None}
    if R is not None:
        out["rotation_deg"] = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2))))
    return out


def compare(result, truth, range_m=DEFAULT_RANGE_M, step=DEFAULT_GRID_STEP):
    r'''Everything the report needs about one CalibrationResult, as a JSON-able dict

SYNOPSIS

    s = compare(result, truth)
    # s["residuals"]: {"n","min","max","rms","mean"} per point, px
    # s["parameters"]: parameter_errors(); s["projection"][mode]: {"rms","max",...}
'''
    from harness.calibrators.base import jsonable
    out = {"calibrator": result.calibrator, "model_name": result.model_name,
           "status": result.status, "reason": result.reason,
           "residuals": result.residual_stats()}
    if not result.ok or result.model is None:
        out["parameters"] = None
        out["projection"] = None
        return out
    world = result.world_frame
    theta = result.theta_estimated
    out["parameters"] = parameter_errors(truth, result.model, theta_estimated=theta,
                                         world_frame=world)
    modes = ("rotation", "intrinsics") + (("world",) if world else ())
    proj = {}
    for mode in modes:
        d = projection_difference(truth, result.model, mode=mode, range_m=range_m, step=step)
        proj[mode] = {k: v for k, v in d.items() if k not in ("q", "map")}
    out["projection"] = proj
    return jsonable(out)

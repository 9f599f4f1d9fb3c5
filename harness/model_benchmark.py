r'''Which lens model does a camera need: the floor of every candidate model

SYNOPSIS

    from harness.model_benchmark import benchmark, best_model, CANDIDATES

    b = benchmark(truth, tolerance=0.01)
    for row in b["rows"]:
        row["name"], row["nparams"], row["rms"], row["max"], row["corner"]
    b["recommended"]                      # the simplest candidate whose floor <= tolerance
    b["per_calibrator"]["mrcal"]          # {"model": "CAHVORE", "why": "...", ...}
    b["own"]["mrcal"]["rows"]             # mrcal's own fits: the floors its choice is made on

    name, why = best_model(truth, "opencv", tolerance=0.01)   # "FISHEYE", "floor ..."

A model's floor is how close it can come to the camera at all: the candidate
is fitted to the truth's exact projections over the whole field of view, with
nothing else in the way (no target, no detector, no pose estimation), and the
projection difference left over is its floor. A calibrator fitting that model
from images cannot do better than its floor.

The observations: a grid of pixels over the whole image (edges included,
about FIT_POINTS across), unprojected by the truth and placed at the ranges
`ranges_m` along the rays (default harness.compare's projection-difference
range, 2 m: for a noncentral CAHVORE the floors hold at that range; central
models have one point per pixel and range, so a noncentral truth shows up as a
floor once two ranges are given). The floor is evaluated on the finer grid of
harness.compare (every DEFAULT_GRID_STEP px) at the same ranges.

How each candidate is fitted (all by least squares on those exact points):

- CAHV, CAHVOR, CAHVORE (the JPL family): harness.calibrators.jpl_fit.fit_model
  on the world points (C, A, H, V, O, R, E; theta free; R0 held at 0; CAHVORE
  with the truth's type and linearity, or type 1).
- mrcal's LENSMODEL_PINHOLE, LENSMODEL_CAHVOR, LENSMODEL_CAHVORE_linearity=L,
  LENSMODEL_OPENCV4/5/8/12 and LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=16_
  Ny=12_fov_x_deg=F (the mrcal calibrator's configuration, F from the pinhole
  field of view x 1.2 as it computes it): mrcal.project with its gradients,
  intrinsics and a rotation of the camera frame fitted by scipy's
  Levenberg-Marquardt (the camera frame's origin stays at the truth's C); the
  OpenCV models are seeded stage by stage (4 -> 5 -> 8 -> 12 coefficients).
- OpenCV's 5-coefficient, 8-coefficient (rational), 12 (thin prism) and 14
  (tilted sensor) models and cv2.fisheye: cv2.projectPoints /
  cv2.fisheye.projectPoints with their Jacobians, the same fit.
- COLMAP's OPENCV (k1 k2 p1 p2), FULL_OPENCV (k1..k6 p1 p2) and
  OPENCV_FISHEYE are OpenCV's 4-, 8-coefficient and fisheye projections
  (COLMAP's pixel origin differs by 0.5 px, which a floor does not see): their
  rows are fitted with cv2 as well.

The choice per calibrator (jpl, mrcal, OpenCV: OWN_FIT) is made on the floors of the
calibrator's OWN fit of exact observations of whole-image poses (own_floor(); see "a
calibrator's own floor" below): its model frame and constraints, its solver. The direct
fits' floors are what each model can do at all; a calibrator's can be higher (OpenCV
weighs the field by its boards) or lower (mrcal's solver follows the CAHVOR R0 valley
to a skewed camera that the direct fit crawls towards).

nparams counts the intrinsic parameters a calibrator fits (CAHV 5: fx, fy, cx,
cy and the skew theta; CAHVOR +2 O +2 R (R0 is a gauge); CAHVORE +3 E).
"Simplest" is the fewest parameters, then the order of CANDIDATES.
'''

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

DEFAULT_TOLERANCE = 0.01
# the fit grid has about this many points along the image's longer side
FIT_POINTS = 40
SPLINED_NX, SPLINED_NY = 16, 12
CRITERIA = ("max", "rms")
# The fits stop when a step gains less than this fraction of the cost (0.05% of the RMS). The
# splined model of the MER navcam (slot 15) reaches 0.000680 px RMS in 5 steps, then crawls:
# 0.000666 px after 200 (52 s on a loaded 2-core machine).
STOP_GAIN = 1e-3
# at most this many evaluations for the splined model: slot 15 reaches its floor in 5, hazcam
# 9 in ~20; SuperCam (theta 75 deg, 1.1 deg field of view) crawls for 700 (241 s) to 2 px
SPLINED_EVALUATIONS = 40
# calibrators whose floors come from their own fits (see "a calibrator's own floor" below)
OWN_FIT = ("jpl", "mrcal", "opencv")
# six templates and the eight corner and edge anchors of targets.poses's "corners" cover
FLOOR_POSES = 14
FLOOR_COVER = "corners"
FLOOR_TARGET = "dots"


@dataclass(frozen=True)
class Candidate:
    r'''One lens model to try: name, how it is fitted, which calibrators fit it'''
    name: str
    library: str
    kind: str                       # "jpl" | "mrcal" | "cv2" | "cv2-fisheye"
    spec: str = ""                  # the family, lensmodel or number of coefficients
    calibrators: dict = field(default_factory=dict)   # calibrator -> its model name
    same_as: str = ""               # a candidate with the identical projection


CANDIDATES = (
    Candidate("CAHV", "jpl (scipy)", "jpl", "CAHV", {"jpl": "CAHV"}),
    Candidate("CAHVOR", "jpl (scipy)", "jpl", "CAHVOR", {"jpl": "CAHVOR"}),
    Candidate("CAHVORE", "jpl (scipy)", "jpl", "CAHVORE", {"jpl": "CAHVORE"}),
    Candidate("LENSMODEL_PINHOLE", "mrcal", "mrcal", "LENSMODEL_PINHOLE", {"mrcal": "CAHV"}),
    Candidate("LENSMODEL_CAHVOR", "mrcal", "mrcal", "LENSMODEL_CAHVOR", {"mrcal": "CAHVOR"}),
    Candidate("LENSMODEL_CAHVORE", "mrcal", "mrcal", "LENSMODEL_CAHVORE", {"mrcal": "CAHVORE"}),
    Candidate("LENSMODEL_OPENCV4", "mrcal", "mrcal", "LENSMODEL_OPENCV4"),
    Candidate("LENSMODEL_OPENCV5", "mrcal", "mrcal", "LENSMODEL_OPENCV5"),
    Candidate("LENSMODEL_OPENCV8", "mrcal", "mrcal", "LENSMODEL_OPENCV8", {"mrcal": "OPENCV8"}),
    Candidate("LENSMODEL_OPENCV12", "mrcal", "mrcal", "LENSMODEL_OPENCV12"),
    Candidate("LENSMODEL_SPLINED_STEREOGRAPHIC", "mrcal", "mrcal", "SPLINED",
              {"mrcal": "SPLINED"}),
    Candidate("cv2 4 (COLMAP OPENCV)", "opencv", "cv2", "4", {"colmap": "OPENCV"}),
    Candidate("cv2 5 (OPENCV5)", "opencv", "cv2", "5", {"opencv": "OPENCV5"}),
    Candidate("cv2 8 rational (RATIONAL, COLMAP FULL_OPENCV)", "opencv", "cv2", "8",
              {"opencv": "RATIONAL", "colmap": "FULL_OPENCV"}),
    Candidate("cv2 12 thin prism", "opencv", "cv2", "12"),
    Candidate("cv2 14 tilted", "opencv", "cv2", "14"),
    Candidate("cv2 fisheye (FISHEYE, COLMAP OPENCV_FISHEYE)", "opencv", "cv2-fisheye", "4",
              {"opencv": "FISHEYE", "colmap": "OPENCV_FISHEYE"}),
)


def candidate_names():
    return [c.name for c in CANDIDATES]


# ---------------------------------------------------------------- observations

def _points(truth, step, ranges_m):
    r'''q (N,2), p_ref (N,3), p_cam (N,3): the grid at every range, stacked'''
    from harness.compare import truth_points
    qs, prs, pcs = [], [], []
    for r in ranges_m:
        q, p_ref, p_cam = truth_points(truth, float(r), step)
        qs.append(q.reshape(-1, 2))
        prs.append(p_ref.reshape(-1, 3))
        pcs.append(p_cam.reshape(-1, 3))
    q, p_ref, p_cam = (np.concatenate(x) for x in (qs, prs, pcs))
    ok = np.all(np.isfinite(p_ref), axis=-1) & np.all(np.isfinite(p_cam), axis=-1)
    return q[ok], p_ref[ok], p_cam[ok]


def _corners(W, H):
    return {"top-left": (0.0, 0.0), "top-right": (W - 1.0, 0.0),
            "bottom-left": (0.0, H - 1.0), "bottom-right": (W - 1.0, H - 1.0)}


# ---------------------------------------------------------------- fitters

def _rotate(r, p):
    import mrcal
    return mrcal.rotate_point_r(r, p, get_gradients=True)


def _lm(residual_and_jacobian, x0, max_iterations=100, max_evaluations=300):
    r'''Levenberg-Marquardt (numpy): x minimising |f(x)|^2; (x, number of evaluations)

The Jacobian's columns are scaled to unit norm and the damping is lambda I on
the scaled normal equations, so unobserved parameters (spline knots beyond
the field of view) stay where they are instead of making the step singular.
'''
    x = np.asarray(x0, dtype=np.float64).copy()
    f, J = residual_and_jacobian(x)
    cost = float(f @ f)
    lam, nfev = 1e-6, 1
    for _ in range(max_iterations):
        s = np.linalg.norm(J, axis=0)
        s[s == 0] = 1.0
        Js = J / s
        A = Js.T @ Js
        g = Js.T @ f
        improved = False
        while lam < 1e12 and nfev < max_evaluations:
            try:
                dx = -np.linalg.solve(A + lam * np.eye(len(x)), g) / s
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            f1, J1 = residual_and_jacobian(x + dx)
            nfev += 1
            c1 = float(f1 @ f1)
            if np.isfinite(c1) and c1 < cost:
                x, f, J = x + dx, f1, J1
                # a step gaining less than STOP_GAIN of the cost moves the RMS floor by less
                # than half of that; an exact fit converges quadratically (gains near 1 per
                # step) and does not stop before the rounding floor
                done = cost - c1 <= STOP_GAIN * cost or c1 < 1e-26 * len(f)
                cost = c1
                lam = max(lam / 10.0, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved or done:
            break
    return x, nfev


def _center_start(truth):
    r'''(r, [fx, fy, cx, cy]): a pinhole looking through the image centre, at its local scale

The rotation r turns the truth's camera frame so that z is the ray through the image centre
and x the direction of increasing column there; fx, fy are the focal lengths of the truth
there. Every model is fitted from it: the truth's own frame can be far from any pinhole's
(SuperCam: the axis A is 28 deg off its 1.1 deg field of view, theta 75 deg).
'''
    import mrcal
    W, H = truth.width, truth.height
    c = np.array([(W - 1) / 2.0, (H - 1) / 2.0])
    _, v = truth.unproject(np.array([c, c + (1.0, 0.0), c + (0.0, 1.0)]))
    R_ref_cam = truth.Rt_ref_cam()[:3]
    v = v @ R_ref_cam           # directions in the truth's camera frame
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    z = v[0]
    x = v[1] - (v[1] @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack((x, y, z))     # truth camera frame -> the start's frame
    fx = 1.0 / math.tan(math.acos(min(1.0, float(v[0] @ v[1]))))
    fy = 1.0 / math.tan(math.acos(min(1.0, float(v[0] @ v[2]))))
    return mrcal.r_from_R(R), np.array([fx, fy, c[0], c[1]])


def _seed(truth):
    return _center_start(truth)[1]


def _splined_lensmodel(truth):
    fx = _seed(truth)[0]
    fov = 2.0 * math.degrees(math.atan(0.5 * truth.width / fx)) * 1.2
    return (f"LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx={SPLINED_NX}_Ny={SPLINED_NY}_"
            f"fov_x_deg={int(math.ceil(min(fov, 179.0)))}")


def _mrcal_lensmodel(c, truth):
    if c.spec == "LENSMODEL_CAHVORE":
        lin = truth.linearity if truth.family == "CAHVORE" else 1.0
        return f"LENSMODEL_CAHVORE_linearity={float(lin)!r}"
    if c.spec == "SPLINED":
        return _splined_lensmodel(truth)
    return c.spec


def _fit_mrcal(lensmodel, truth, q, p_cam, seed_intrinsics=None, seed_r=None):
    r'''intrinsics and rotation r minimising |project(R p_cam) - q| -> (project, info)'''
    import mrcal
    nint = mrcal.lensmodel_num_params(lensmodel)
    x0 = np.zeros(3 + nint)
    x0[3:7] = _seed(truth)
    if seed_intrinsics is not None:
        n = min(len(seed_intrinsics), nint)
        x0[3:3 + n] = seed_intrinsics[:n]
    x0[:3] = _center_start(truth)[0] if seed_r is None else seed_r
    qf = q.ravel()

    def rj(x):
        pr, dpr_dr, _ = _rotate(x[:3], p_cam)
        qp, dq_dp, dq_di = mrcal.project(pr, lensmodel, x[3:], get_gradients=True)
        f = (qp.ravel() - qf)
        J = np.concatenate((np.einsum("nij,njk->nik", dq_dp, dpr_dr), dq_di), axis=-1)
        f = np.where(np.isfinite(f), f, 1e6)
        J = np.where(np.isfinite(J), J, 0.0).reshape(-1, 3 + nint)
        return f, J

    # the splined model's evaluations cost ~0.3 s (388 parameters, dense): it gets fewer
    x, nfev = _lm(rj, x0, max_evaluations=SPLINED_EVALUATIONS if nint > 40 else 300)

    def project(p):
        return mrcal.project(mrcal.rotate_point_r(x[:3], p), lensmodel, x[3:])
    return project, {"lensmodel": lensmodel, "nparams": nint, "nfev": nfev,
                     "intrinsics": x[3:], "r": x[:3]}


def _radial_seed(truth, q, p_cam, ncoef):
    r'''fx fy cx cy (the truth's, at the centre) and the radial coefficients that fit q best
with no rotation: OpenCV's radial terms are linear in the coefficients once the core is
held (the rational model after multiplying out its denominator). ncoef: 4, 5, 8 or
"fisheye"; the tangential terms are 0.'''
    import mrcal
    r0, core = _center_start(truth)
    p_cam = mrcal.rotate_point_r(r0, p_cam)
    ok = p_cam[:, 2] > 0
    x = p_cam[ok, :2] / p_cam[ok, 2:]
    xd = (q[ok] - core[2:]) / core[:2]
    r2 = np.sum(x * x, axis=-1)[:, None]
    if ncoef == "fisheye":
        r = np.sqrt(r2[:, 0])
        th = np.arctan(r)
        A = np.stack([th ** (2 * k + 3) for k in range(4)], axis=-1)
        b = np.linalg.norm(xd, axis=-1) - th
        k = np.linalg.lstsq(A, b, rcond=None)[0]
        return np.concatenate((core, k))
    ncoef = int(ncoef)
    nrad = {4: 2, 5: 3, 8: 3}[ncoef]
    cols = [x * r2 ** (i + 1) for i in range(nrad)]
    if ncoef == 8:
        cols += [-xd * r2 ** (i + 1) for i in range(3)]
    A = np.stack([c.ravel() for c in cols], axis=-1)
    k = np.linalg.lstsq(A, (xd - x).ravel(), rcond=None)[0]
    d = np.zeros(ncoef)
    d[:2] = k[:2]
    d[4:4 + len(k) - 2] = k[2:]
    return np.concatenate((core, d))


# models that divide by z: they cannot see a point 90 deg or more off their axis (OpenCV
# projects it mirrored); such points are left out of their fits and count as not projected
FRONT_ONLY = ("LENSMODEL_PINHOLE", "LENSMODEL_OPENCV")


def _front_only_lensmodel(lensmodel):
    return lensmodel.startswith(FRONT_ONLY) or lensmodel == "LENSMODEL_CAHVOR"


def _front(p, min_cos=1e-6):
    p = np.asarray(p)
    return p[..., 2] > min_cos * np.linalg.norm(p, axis=-1)


def _front_only(project):
    def wrapped(p):
        qp = np.array(project(p), dtype=np.float64)
        qp[~_front(p)] = np.nan
        return qp
    return wrapped


def _fit_cv2(ncoef, truth, q, p_cam, seed_intrinsics=None, seed_r=None):
    import cv2
    ncoef = int(ncoef)
    x0 = np.zeros(3 + 4 + ncoef)
    x0[:3], x0[3:7] = _center_start(truth)
    if seed_r is not None:
        x0[:3] = seed_r
    if seed_intrinsics is not None:
        n = min(len(seed_intrinsics), 4 + ncoef)
        x0[3:3 + n] = seed_intrinsics[:n]
    P = np.ascontiguousarray(p_cam.reshape(-1, 1, 3))
    qf = q.ravel()
    zero = np.zeros(3)

    def K_of(x):
        return np.array([[x[3], 0.0, x[5]], [0.0, x[4], x[6]], [0.0, 0.0, 1.0]])

    def rj(x):
        qp, J = cv2.projectPoints(P, x[:3], zero, K_of(x), x[7:])
        # Jacobian columns: rvec 3, tvec 3, fx fy 2, cx cy 2, distortion ncoef
        J = np.concatenate((J[:, :3], J[:, 6:]), axis=1)
        f = qp.reshape(-1) - qf
        return np.where(np.isfinite(f), f, 1e6), np.where(np.isfinite(J), J, 0.0)

    x, nfev = _lm(rj, x0)

    def project(p):
        qp, _ = cv2.projectPoints(np.ascontiguousarray(np.asarray(p).reshape(-1, 1, 3)),
                                  x[:3], zero, K_of(x), x[7:])
        return qp.reshape(np.shape(p)[:-1] + (2,))
    return project, {"nparams": 4 + ncoef, "nfev": nfev, "intrinsics": x[3:], "r": x[:3]}


def _fit_fisheye(truth, q, p_cam):
    import cv2
    x0 = np.zeros(3 + 4 + 4)
    x0[:3] = _center_start(truth)[0]
    x0[3:] = _radial_seed(truth, q, p_cam, "fisheye")
    P = np.ascontiguousarray(p_cam.reshape(-1, 1, 3))
    qf = q.ravel()
    zero = np.zeros((3, 1))

    def K_of(x):
        return np.array([[x[3], 0.0, x[5]], [0.0, x[4], x[6]], [0.0, 0.0, 1.0]])

    def rj(x):
        qp, J = cv2.fisheye.projectPoints(P, x[:3].reshape(3, 1), zero, K_of(x),
                                          x[7:].reshape(4, 1))
        # Jacobian columns: f 2, c 2, k 4, rvec 3, tvec 3, alpha 1 (the skew, held at 0)
        J = np.concatenate((J[:, 8:11], J[:, 0:8]), axis=1)
        f = qp.reshape(-1) - qf
        return np.where(np.isfinite(f), f, 1e6), np.where(np.isfinite(J), J, 0.0)

    x, nfev = _lm(rj, x0)

    def project(p):
        qp, _ = cv2.fisheye.projectPoints(
            np.ascontiguousarray(np.asarray(p).reshape(-1, 1, 3)), x[:3].reshape(3, 1), zero,
            K_of(x), x[7:].reshape(4, 1))
        return qp.reshape(np.shape(p)[:-1] + (2,))
    return project, {"nparams": 8, "nfev": nfev, "intrinsics": x[3:]}


JPL_NPARAMS = {"CAHV": 5, "CAHVOR": 9, "CAHVORE": 12}


def _fit_jpl(family, truth, q, p_ref):
    from harness.calibrators.jpl_fit import fit_model
    mtype = lin = None
    if family == "CAHVORE":
        mtype, lin = ((truth.model_type, truth.linearity) if truth.family == "CAHVORE"
                      else (1, None))
    from reference_models.cahvore import truncate
    order = ("CAHV", "CAHVOR", "CAHVORE")
    # from the truth truncated to the family, as mrcal-convert-lensmodel starts from the
    # source model (the DLT start of a CAHVORE fit of a wide noncentral camera at one range
    # ends in a local minimum: 145 px on hazcam 9); a richer family than the truth's from
    # the DLT, staged
    m0 = truncate(truth, family) if order.index(family) <= order.index(truth.family) else None
    model, info = fit_model(p_ref, q, family, truth.width, truth.height, model_type=mtype,
                            linearity=lin, m0=m0)
    return model.project, {"nparams": JPL_NPARAMS[family], "nfev": info["nfev"],
                           "world": True, "model": model}


def _mrcal_seed_from_jpl(model, truth):
    r'''(intrinsics, r) of the jpl fit as a mrcal model (theta made 90 deg), in the truth's
camera frame'''
    import mrcal

    from reference_models.mrcal_convert import to_mrcal
    cm = to_mrcal(model, orthogonalise=True)
    R = cm.Rt_cam_ref()[:3] @ truth.Rt_ref_cam()[:3]
    return np.asarray(cm.intrinsics()[1], dtype=np.float64), mrcal.r_from_R(R)


# ---------------------------------------------------------------- the benchmark

def _floor(project, q, p, W, H):
    qp = project(p)
    d = np.linalg.norm(qp - q, axis=-1)
    bad = ~np.isfinite(d)
    out = {"n": int(d.size), "n_invalid": int(bad.sum())}
    if bad.all():
        return {**out, "rms": None, "max": None, "corner": None, "corner_px": None}
    dd = np.where(bad, np.nan, d)
    out["rms"] = float(math.sqrt(np.mean(d[~bad] ** 2)))
    out["max"] = float(d[~bad].max())
    worst, worst_px = None, -1.0
    for name, c in _corners(W, H).items():
        near = np.all(np.abs(q - np.array(c)) < 0.5, axis=-1)
        if near.any():
            v = float(np.nanmax(np.where(np.isnan(dd[near]), np.inf, dd[near])))
            if v > worst_px:
                worst, worst_px = name, v
    out["corner"], out["corner_px"] = worst, (worst_px if worst else None)
    return out


# OpenCV's models nest: n coefficients are the first ones of the next model's (the rational
# model's k4..k6 come after k3, thin prism s1..s4 and tilt after those)
_SIMPLER = {5: 4, 8: 5, 12: 8, 14: 12}


def _best_start(fit, n, truth, q, p_cam, seeds, simpler_key, key, front_only):
    r'''Fit an OpenCV model from the linear radial seed and from the next simpler model's fit
(padded with zeros); keep the better: either start alone ends in a local minimum on some
cameras (slot 15's OPENCV8 from the radial seed: 3.0 px max, from OPENCV5's fit 0.25 px)'''
    starts = []
    if n in (4, 5, 8):
        starts.append((_radial_seed(truth, q, p_cam, n), None))
    prev = seeds.get(simpler_key)
    if prev is not None:
        pad = np.zeros(4 + n)
        pad[:len(prev)] = prev
        starts.append((pad, seeds.get(simpler_key + ":r")))
    best = None
    for start in starts or [(None, None)]:
        project, info = fit(*start)
        with np.errstate(all="ignore"):
            d = np.linalg.norm(project(p_cam) - q, axis=-1)
        cost = float(np.mean(np.where(np.isfinite(d), d, 1e6) ** 2))
        if best is None or cost < best[0]:
            best = (cost, project, info)
    _, project, info = best
    seeds[key] = info["intrinsics"]
    seeds[key + ":r"] = info["r"]
    return (_front_only(project) if front_only else project), info


def _fit_one(c, truth, fit_pts, seeds):
    q, p_ref, p_cam = fit_pts
    if c.kind == "jpl":
        project, info = _fit_jpl(c.spec, truth, q, p_ref)
        seeds["jpl:" + c.spec] = info.pop("model")
        return project, info
    if c.kind in ("cv2", "cv2-fisheye") or _front_only_lensmodel(c.spec):
        front = _front(p_cam)
        q, p_ref, p_cam = q[front], p_ref[front], p_cam[front]
    if c.kind == "mrcal":
        lm = _mrcal_lensmodel(c, truth)
        seed = None
        if lm.startswith("LENSMODEL_OPENCV"):
            n = int(lm[16:])
            return _best_start(lambda sd, r: _fit_mrcal(lm, truth, q, p_cam, sd, r), n, truth, q,
                               p_cam, seeds, f"LENSMODEL_OPENCV{_SIMPLER.get(n)}", c.spec,
                               _front_only_lensmodel(lm))
        seed_r = None
        if lm.startswith("LENSMODEL_SPLINED"):
            seed = seeds.get("LENSMODEL_PINHOLE")
            seed_r = seeds.get("LENSMODEL_PINHOLE:r")
        family = lm.split("_")[1].replace("PINHOLE", "CAHV")
        jpl = seeds.get("jpl:" + family)
        if jpl is None and lm.startswith("LENSMODEL_CAHVOR"):
            jpl = _fit_jpl(family, truth, q, p_ref)[1]["model"]
        starts = [(seed, seed_r)]
        if jpl is not None and lm.startswith(("LENSMODEL_CAHVOR", "LENSMODEL_PINHOLE")):
            # also from the jpl fit of the same family: mrcal's CAHVOR optimum lies along a
            # flat valley (R0 against the focal length) the centre start does not reach
            starts.append(_mrcal_seed_from_jpl(jpl, truth))
        best = None
        for start in starts:
            project, info = _fit_mrcal(lm, truth, q, p_cam, *start)
            with np.errstate(all="ignore"):
                d = np.linalg.norm(project(p_cam) - q, axis=-1)
            cost = float(np.mean(np.where(np.isfinite(d), d, 1e6) ** 2))
            if best is None or cost < best[0]:
                best = (cost, project, info)
        _, project, info = best
        seeds[c.spec] = info["intrinsics"]
        seeds[c.spec + ":r"] = info["r"]
        return (_front_only(project) if _front_only_lensmodel(lm) else project), info
    if c.kind == "cv2":
        n = int(c.spec)
        return _best_start(lambda sd, r: _fit_cv2(n, truth, q, p_cam, sd, r), n, truth, q, p_cam,
                           seeds, f"cv2:{_SIMPLER.get(n)}", f"cv2:{n}", True)
    if c.kind == "cv2-fisheye":
        project, info = _fit_fisheye(truth, q, p_cam)
        return _front_only(project), info
    raise ValueError(f"unknown candidate kind {c.kind!r}")


def _nparams(c, truth):
    if c.kind == "jpl":
        return JPL_NPARAMS[c.spec]
    if c.kind == "mrcal":
        import mrcal
        return mrcal.lensmodel_num_params(_mrcal_lensmodel(c, truth))
    return 4 + (4 if c.kind == "cv2-fisheye" else int(c.spec))


def benchmark(truth, tolerance=DEFAULT_TOLERANCE, ranges_m=None, candidates=None,
              criterion="max", fit_points=FIT_POINTS, eval_step=None, first_within=False,
              own_fits=OWN_FIT):
    r'''Fit every candidate model to the truth's exact projections; the floors and the choice

SYNOPSIS

    b = benchmark(truth)                 # a reference_models CAHV/CAHVOR/CAHVORE
    b["rows"]          # one dict per candidate: name, library, nparams, status, reason,
                       # rms, max, corner, corner_px (px), seconds, calibrators
    b["recommended"]   # the row of the simplest candidate within tolerance, or None
    b["per_calibrator"][cal] = {"model", "why", "floor", "nparams"} or {"model": None, "why"}

ARGUMENTS

- truth: the camera (a JPL-family model)
- tolerance: px; a candidate is within it when its floor (criterion: "max" over the
  evaluation grid, or "rms") is <= tolerance
- ranges_m: ranges of the points along the truth's rays (default: harness.compare's
  projection-difference range)
- candidates: names from candidate_names() (default all)
- fit_points: fit-grid points along the longer image side; eval_step: px between the
  evaluation grid's points (default harness.compare.DEFAULT_GRID_STEP)
- first_within: try the candidates from the fewest parameters up and stop at the first
  within tolerance (the splined model, slowest, comes last)
- own_fits: calibrators whose choice comes from their own fits (own_fit_choice(); default
  OWN_FIT): b["own"][cal] = {"choice", "rows", "poses", "seconds", "diagnostics"}

A candidate whose fit raises is a row with status "failed" and the reason.
'''
    from harness.compare import DEFAULT_GRID_STEP, DEFAULT_RANGE_M
    from harness.quiet import capture
    if criterion not in CRITERIA:
        raise ValueError(f"criterion {criterion!r}; expected one of {CRITERIA}")
    ranges_m = tuple(float(r) for r in (ranges_m or (DEFAULT_RANGE_M,)))
    eval_step = eval_step or DEFAULT_GRID_STEP
    W, H = truth.width, truth.height
    fit_step = max(1.0, (max(W, H) - 1.0) / (fit_points - 1))
    fit_pts = _points(truth, fit_step, ranges_m)
    q_e, p_ref_e, p_cam_e = _points(truth, eval_step, ranges_m)
    chosen = [c for c in CANDIDATES if candidates is None or c.name in candidates]
    if first_within:
        chosen.sort(key=lambda c: _nparams(c, truth))   # stable: CANDIDATES order in a tie
    rows, seeds = [], {}
    t_all = time.perf_counter()
    with capture() as cap:
        for c in chosen:
            t0 = time.perf_counter()
            row = {"name": c.name, "library": c.library, "calibrators": dict(c.calibrators)}
            try:
                project, info = _fit_one(c, truth, fit_pts, seeds)
                with np.errstate(all="ignore"):
                    fl = _floor(project, q_e, p_ref_e if info.get("world") else p_cam_e,
                                W, H)
                row.update(status="ok", reason="", nparams=int(info["nparams"]),
                           lensmodel=info.get("lensmodel", c.spec), **fl)
                if fl["max"] is None:
                    row.update(status="failed", reason="the fitted model projects no point")
                elif fl["n_invalid"]:
                    row["reason"] = (f"{fl['n_invalid']} of {fl['n']} points do not project "
                                     "(outside the model's domain: 90 deg or more off its "
                                     "axis); the floor is over the others")
            except Exception as e:   # a model that cannot be fitted is a row, not a crash
                row.update(status="failed", reason=f"{type(e).__name__}: {e}".splitlines()[0],
                           nparams=None, rms=None, max=None, corner=None, corner_px=None)
            row["seconds"] = time.perf_counter() - t0
            rows.append(row)
            if first_within and _value(row, criterion) <= tolerance:
                break
    out = {"camera": {"family": truth.family, "width": W, "height": H,
                      "linearity": getattr(truth, "linearity", None),
                      "central": bool(getattr(truth, "is_central", True))},
           "tolerance": float(tolerance), "criterion": criterion, "ranges_m": list(ranges_m),
           "fit_points": int(len(fit_pts[0])), "eval_step": eval_step,
           "eval_points": int(len(q_e)), "rows": rows,
           "seconds": time.perf_counter() - t_all, "diagnostics": cap.summary()}
    out["recommended"] = _simplest(rows, tolerance, criterion)
    out["own"] = {}
    for cal in (c for c in own_fits if any(c in x.calibrators for x in chosen)):
        t0 = time.perf_counter()
        with capture() as cap:
            choice, own_rows = own_fit_choice(truth, cal, tolerance, criterion)
        out["own"][cal] = {"choice": choice, "rows": own_rows, "poses": FLOOR_POSES,
                           "seconds": time.perf_counter() - t0, "diagnostics": cap.summary()}
    out["seconds"] = time.perf_counter() - t_all
    out["per_calibrator"] = {cal: choose(out, cal) for cal in ("jpl", "mrcal", "opencv",
                                                                "colmap")}
    return out


def _value(row, criterion):
    r'''The row's floor; inf when it failed or cannot project the whole field of view'''
    v = row.get(criterion)
    if v is None or row.get("status") != "ok" or row.get("n_invalid"):
        return math.inf
    return float(v)


def _simplest(rows, tolerance, criterion):
    ok = [r for r in rows if _value(r, criterion) <= tolerance]
    if not ok:
        return None
    return min(ok, key=lambda r: (r["nparams"], rows.index(r)))


def choose(bench, calibrator):
    r'''The calibrator's simplest model within the benchmark's tolerance, and why

SYNOPSIS

    c = choose(b, "mrcal")
    # {"model": "CAHVORE", "candidate": "LENSMODEL_CAHVORE", "floor": px, "nparams": 12,
    #  "why": "simplest mrcal model with max floor 1.2e-9 px <= 0.01 px"}

When none is within tolerance: the model with the lowest floor, and "why" says so;
when the calibrator fits no candidate: model None.
'''
    if calibrator in bench.get("own", {}):
        return bench["own"][calibrator]["choice"]
    rows = [r for r in bench["rows"] if calibrator in r["calibrators"]]
    return _choose_rows(rows, calibrator, bench["tolerance"], bench["criterion"])


def _choose_rows(rows, calibrator, tol, crit, how=None):
    if not rows:
        return {"model": None, "why": f"the benchmark has no {calibrator} model"}
    how = f" ({how})" if how else ""
    within = _simplest(rows, tol, crit)
    if within is not None:
        skipped = [r["calibrators"][calibrator] for r in rows
                   if r["nparams"] is not None and r["nparams"] < within["nparams"]]
        why = (f"simplest {calibrator} model with {crit} floor {within[crit]:.2g} px <= "
               f"{tol:g} px{how}" + (f" ({', '.join(skipped)}: floors above)" if skipped
                                     else ""))
        r = within
    else:
        fitted = [r for r in rows if r.get("status") == "ok" and r.get(crit) is not None]
        if not fitted:
            return {"model": None, "why": f"no {calibrator} model could be fitted{how}"}
        lowest = min(fitted, key=lambda r: (r.get("n_invalid") or 0, r[crit], rows.index(r)))
        # floors that differ by less than the tolerance are alike at that tolerance: the
        # simplest of those (a richer model fitted for a gain below the tolerance only adds
        # parameters the images must determine: OpenCV's rational model diverged on 6 poses
        # of hazcam 17 for 0.025 px against OPENCV5's)
        alike = [r for r in fitted if (r.get("n_invalid") or 0) == (lowest.get("n_invalid") or 0)
                 and r[crit] <= lowest[crit] + tol]
        r = min(alike, key=lambda r: (r["nparams"], rows.index(r)))
        why = (f"no {calibrator} model within {tol:g} px{how}; the lowest {crit} floor is "
               f"{lowest[crit]:.3g} px ({lowest['calibrators'][calibrator]})")
        if r is not lowest:
            why += (f"; the simplest within {tol:g} px of it: {r['calibrators'][calibrator]} "
                    f"({r[crit]:.3g} px)")
        if r.get("n_invalid"):
            why += (f" over the field of view it can see ({r['n_invalid']} of {r['n']} points "
                    "are 90 deg or more off its axis)")
    return {"model": r["calibrators"][calibrator], "candidate": r["name"],
            "floor": r[crit], "nparams": r["nparams"], "why": why}


# ---------------------------------------------------------------- a calibrator's own floor
#
# The direct fits above ask what each model can do at all: intrinsics and a rotation of the
# camera frame, by Levenberg-Marquardt over the whole field of view, every point weighed
# alike. A calibrator's floor is what ITS fit of the model can do, under its own frame and
# constraints: jpl fits C, A, H, V, O, R, E in the world frame with the boards at their
# surveyed poses (theta free); OpenCV fits K without skew, the distortion and every board's
# pose; mrcal fits its orthonormal camera frame's intrinsics and every board's pose with its
# own solver and recipe. These differ from the direct fits: mrcal's LENSMODEL_CAHVOR reaches
# a camera with theta != 90 deg only by running off along the R0 / focal-length valley
# (harness/calibrators/mrcal_fit.py), which its dogleg solver and restarts do (navcam 15: 1e-9
# px) and a direct fit crawls along (0.23 px after 300 evaluations, 0.035 px after 2000);
# OpenCV weighs the field by where the boards are, so its floor over the whole image is
# 1.2-1.8x the direct fit's RMS and ~2x its max (constructed cameras, 2026-11-25).
# So each calibrator in OWN_FIT gets its floor from its own fit, as the verdict gets a
# record's (harness.verdict): exact observations of the target's points (no dots, no bias
# correction) in FLOOR_POSES poses planned to cover the whole image (targets.poses, cover
# "corners": the four corners and the edge midpoints), compared with the truth by
# harness.verdict.floor_comparison (rotation-mode projection difference over the truth's
# image grid at the projection-difference range). The campaign's own pose set can leave
# parts of the image unobserved; its records' floors are then larger where it extrapolates.


def floor_observations(truth, n=FLOOR_POSES, target_name=FLOOR_TARGET, cover=FLOOR_COVER):
    r'''(obs, target): exact observations of n whole-image poses (targets.poses's planner)'''
    from harness import stages
    from targets.centroids import projected_points
    target = stages.cached_target(target_name)
    poses = stages.poses_stage(truth, target, n, 0, cover)
    dets = [projected_points(truth, target, Rt) for Rt in poses]
    return stages.observations_from(truth, target, poses, dets), target


def own_floor(truth, calibrator, model, observations=None):
    r'''The calibrator's floor for a model: its own fit of exact whole-image observations

SYNOPSIS

    r = own_floor(truth, "mrcal", "CAHVOR")
    r["status"], r["reason"], r["rms"], r["max"], r["residual_rms"], r["seconds"]

observations: (obs, target) from floor_observations() (made here when None). A fit
that fails is status "failed" with the calibrator's reason.
'''
    from harness import stages, verdict
    t0 = time.perf_counter()
    obs, target = observations or floor_observations(truth)
    res = stages.calibrate_stage(calibrator, obs, target, model, truth,
                                 {"bias_correction": False})
    out = {"calibrator": calibrator, "model": model, "status": res.status,
           "reason": res.reason or "", "rms": None, "max": None, "residual_rms": None,
           "poses": int(obs.Nposes)}
    if res.status == "ok":
        try:
            fl = verdict.floor_comparison(truth, res)["projection"]
            out.update(rms=fl.get("rms"), max=fl.get("max"),
                       residual_rms=(res.residual_stats() or {}).get("rms"))
            if out["max"] is None:
                out.update(status="failed", reason="the fitted model projects no point")
        except Exception as e:   # a comparison that fails is a row with its reason
            out.update(status="failed", reason=f"{type(e).__name__}: {e}".splitlines()[0])
    out["seconds"] = time.perf_counter() - t0
    return out


def _own_models(calibrator, truth):
    r'''The calibrator's models of the candidates, fewest parameters first'''
    seen, out = set(), []
    for c in sorted((c for c in CANDIDATES if calibrator in c.calibrators),
                    key=lambda c: _nparams(c, truth)):
        m = c.calibrators[calibrator]
        if m not in seen:
            seen.add(m)
            out.append((m, c, _nparams(c, truth)))
    return out


def own_fit_choice(truth, calibrator, tolerance=DEFAULT_TOLERANCE, criterion="max",
                   first_within=True):
    r'''choose()'s answer for a calibrator in OWN_FIT, from its own fits (own_floor)

Returns (choice, rows): rows one per model tried, fewest parameters first (stopping at
the first within tolerance when first_within).
'''
    rows = []
    try:
        observations = floor_observations(truth)
    except Exception as e:
        from harness.stages import failure_reason
        return ({"model": None, "why": f"no whole-image poses for {calibrator}'s own fits: "
                                       f"{failure_reason(e)}"}, rows)
    for model, c, n in _own_models(calibrator, truth):
        r = own_floor(truth, calibrator, model, observations)
        rows.append({**r, "name": c.name, "nparams": n,
                     "calibrators": {calibrator: model}})
        if first_within and _value(r, criterion) <= tolerance:
            break
    return _choose_rows(rows, calibrator, tolerance, criterion,
                        how=f"its own fit of exact observations of {FLOOR_POSES} "
                            "whole-image poses"), rows


# per process: a campaign asks for the same camera once per job
_MEMO = {}
# on disk: a campaign's choices cost 0.2-15 s per camera, family and calibrator; a rerun of
# the campaign (or another campaign with the same cameras) finds them here
CACHE_ENV = "CAMVAL_CACHE_DIR"


def cache_dir():
    r'''Where best_model keeps its choices: $CAMVAL_CACHE_DIR/best-models, else
$XDG_CACHE_HOME/camval/best-models (~/.cache/camval/best-models)'''
    import os
    from pathlib import Path
    root = os.environ.get(CACHE_ENV)
    if root:
        return Path(root) / "best-models"
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(xdg) / "camval" / "best-models"


@functools.cache
def _code_version():
    r'''The sources a choice depends on (this module, the calibrators, the planner, the
comparison) and the fitting libraries' versions: a choice made by other code is not
reused'''
    import hashlib
    from importlib import metadata
    from pathlib import Path
    here = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for f in [Path(__file__), here / "compare.py", here / "verdict.py",
              here.parent / "targets" / "poses.py",
              *sorted((here / "calibrators").glob("*.py"))]:
        if f.is_file():
            h.update(f.read_bytes())
    for dist in ("mrcal", "opencv-python-headless", "numpy", "scipy"):
        try:
            h.update(f"{dist} {metadata.version(dist)}".encode())
        except metadata.PackageNotFoundError:
            pass
    return h.hexdigest()


def _cache_key(truth, calibrator, tolerance, criterion):
    import hashlib

    from harness.compare import _model_key
    key = (_model_key(truth), calibrator, float(tolerance), criterion)
    h = hashlib.sha256(repr(key).encode())
    h.update(_code_version().encode())
    return key, h.hexdigest()[:32]


def _read_cached(digest):
    import json
    try:
        with open(cache_dir() / f"{digest}.json") as f:
            c = json.load(f)
    except (OSError, ValueError):
        return None
    return c if isinstance(c, dict) and "model" in c and "why" in c else None


def _write_cached(digest, choice):
    import json
    import os
    d = cache_dir()
    try:
        d.mkdir(parents=True, exist_ok=True)
        tmp = d / f".{digest}.{os.getpid()}.tmp"
        with open(tmp, "w") as f:
            json.dump({k: choice.get(k) for k in ("model", "candidate", "floor", "nparams",
                                                   "why")}, f, allow_nan=False)
        os.replace(tmp, d / f"{digest}.json")
    except (OSError, ValueError):     # a cache that cannot be written is no cache
        pass


def best_model(truth, calibrator, tolerance=DEFAULT_TOLERANCE, criterion="max"):
    r'''(model name, why) of the calibrator's simplest model within tolerance for this camera

SYNOPSIS

    name, why = best_model(truth, "mrcal")    # ("CAHVORE", "simplest mrcal model ...")

Benchmarks only the calibrator's own candidates (a calibrator in OWN_FIT: with its own
fits, own_fit_choice()); memoised per process and kept on disk
(cache_dir(), keyed on every parameter of the truth, the calibrator, tolerance,
criterion and this module's source).
'''
    key, digest = _cache_key(truth, calibrator, tolerance, criterion)
    if key not in _MEMO:
        c = _read_cached(digest)
        if c is None:
            if calibrator in OWN_FIT:
                from harness.quiet import capture
                with capture():
                    c = own_fit_choice(truth, calibrator, tolerance, criterion)[0]
            else:
                names = [c.name for c in CANDIDATES if calibrator in c.calibrators]
                b = benchmark(truth, tolerance=tolerance, candidates=names,
                              criterion=criterion, first_within=True, own_fits=())
                c = choose(b, calibrator)
            _write_cached(digest, c)
        _MEMO[key] = c
    c = _MEMO[key]
    return c["model"], c["why"]


def cached_choice(camera_model, family, calibrator, tolerance=None, criterion="max"):
    r'''Whether best_model's choice for this camera truncated to the family is already
made (in this process or on disk)'''
    from reference_models.cahvore import truncate
    try:
        truth = truncate(camera_model, family)
    except Exception:       # no such family: nothing to benchmark
        return False
    tol = DEFAULT_TOLERANCE if tolerance is None else float(tolerance)
    key, digest = _cache_key(truth, calibrator, tol, criterion)
    return key in _MEMO or (cache_dir() / f"{digest}.json").is_file()


def format_table(bench):
    r'''The benchmark as text: one line per candidate, then the recommendation'''
    crit = bench["criterion"]
    lines = [f"{'model':48s} {'library':11s} {'params':>6s} {'rms px':>10s} {'max px':>10s} "
             f"{'worst corner':>22s} {'s':>6s}"]

    def f(v):
        return "-" if v is None else f"{v:10.3g}"
    for r in bench["rows"]:
        corner = "-" if not r.get("corner") else (
            f"{r['corner']} {r['corner_px']:.3g}" if math.isfinite(r["corner_px"])
            else f"{r['corner']} no proj.")
        n = "-" if r.get("nparams") is None else str(r["nparams"])
        line = (f"{r['name']:48s} {r['library']:11s} {n:>6s} {f(r.get('rms'))} "
                f"{f(r.get('max'))} {corner:>22s} {r['seconds']:6.2f}")
        if r["status"] != "ok":
            line += f"  [{r['status']}: {r['reason']}]"
        elif r.get("n_invalid"):
            line += f"  [{r['n_invalid']} of {r['n']} points not projected]"
        lines.append(line)
    for cal, own in bench.get("own", {}).items():
        lines.append("")
        lines.append(f"{cal}'s own fits (its calibrator on exact observations of {own['poses']} "
                     f"whole-image poses; the floors its choice is made on), "
                     f"{own['seconds']:.1f} s:")
        for r in own["rows"]:
            line = (f"  {cal + ' ' + r['model']:46s} {cal:11s} {r['nparams']:>6d} "
                    f"{f(r.get('rms'))} {f(r.get('max'))} {'':>22s} {r['seconds']:6.2f}")
            if r["status"] != "ok":
                line += f"  [{r['status']}: {r['reason']}]"
            lines.append(line)
    rec = bench["recommended"]
    tol = bench["tolerance"]
    lines.append("")
    if rec is None:
        lines.append(f"recommended: none of the models is within {tol:g} px ({crit} floor)")
    else:
        lines.append(f"recommended: {rec['name']} ({rec['nparams']} parameters, {crit} floor "
                     f"{rec[crit]:.2g} px <= {tol:g} px)")
    for cal, c in bench["per_calibrator"].items():
        lines.append(f"  {cal:7s} {c['model'] or '-':14s} {c['why']}")
    return "\n".join(lines)

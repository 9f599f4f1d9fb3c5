r'''OpenCV as a reference calibrator: 5-coefficient, rational and fisheye models

SYNOPSIS

    from harness.calibrators import calibrate

    r = calibrate("opencv", obs, target, "OPENCV5")    # cv2.calibrateCamera
    r = calibrate("opencv", obs, target, "RATIONAL")   # + cv2.CALIB_RATIONAL_MODEL
    r = calibrate("opencv", obs, target, "FISHEYE")    # cv2.fisheye.calibrate
    r.model.project(p)    # an OpenCVModel: the fitted camera, in its own frame

What OpenCV is given: the detections and the target's board-frame points; it
estimates the board poses itself (OpenCV cannot hold them at surveyed poses:
known_poses=True is not applicable). The fitted camera is the reference frame,
so C and A are not comparable, and OpenCV has no theta (its skew is fixed at 0).

Models (OpenCV's pixel centres are at integer coordinates, as ours):

- "OPENCV5": k1, k2, p1, p2, k3
- "RATIONAL": k1..k6 with p1, p2 (CALIB_RATIONAL_MODEL, 8 coefficients). On
  these data it is unusable (coefficients of +-10..87 and several px off in
  the unobserved corners, ../shared/FINDINGS.md): the fit is still reported as
  it comes out, with info["max_abs_coefficient"], so the table shows it.
- "FISHEYE": cv2.fisheye (equidistant + k1..k4), for wide hazcams.

Bias correction as for jpl/mrcal: each detection is corrected by the dot
centroid bias computed with the current model and board poses, and the fit
repeated (at most bias_passes times, until the bias changes by less than
bias_tolerance px).
'''

import time

import numpy as np
from numba import njit

from harness.quiet import diagnostics_of

from .base import (
    CalibrationFailed,
    CalibrationResult,
    check_homography_conditioning,
    check_pose_diversity,
)
from .skeleton import applied_bias, board_residuals, fitted_result, iterate_bias, start_bias

NAME = "opencv"
LIBRARY = "opencv"
MODELS = ("OPENCV5", "RATIONAL", "FISHEYE")
ALIASES = {"OPENCV8": "RATIONAL", "OPENCV_RATIONAL": "RATIONAL", "OPENCV_FISHEYE": "FISHEYE"}


def uses_world_frame(**options):
    r'''False: OpenCV estimates the board poses; the fitted camera is its own frame'''
    return False


def library_version():
    import cv2
    return f"opencv {cv2.__version__}"


def canonical_model(name):
    n = str(name).upper()
    return ALIASES.get(n, n)


class OpenCVModel:
    r'''A camera fitted by OpenCV, projectable by compare.py

SYNOPSIS

    m = OpenCVModel("OPENCV5", K, dist, width, height)
    q = m.project(p)   # p (...,3) in the world frame (= the camera frame here); q (...,2)
    m.fx, m.fy, m.cx, m.cy, m.dist, m.Rt_ref_cam()
'''

    def __init__(self, family, K, dist, width, height, Rt_ref_cam=None):
        self.family = family
        self.K = np.asarray(K, dtype=np.float64)
        self.dist = np.asarray(dist, dtype=np.float64).ravel()
        self.width, self.height = int(width), int(height)
        self.fx, self.fy = float(self.K[0, 0]), float(self.K[1, 1])
        self.cx, self.cy = float(self.K[0, 2]), float(self.K[1, 2])
        self._Rt_ref_cam = (np.vstack((np.eye(3), np.zeros(3))) if Rt_ref_cam is None
                            else np.asarray(Rt_ref_cam, dtype=np.float64))

    def Rt_ref_cam(self):
        return self._Rt_ref_cam.copy()

    def project(self, p):
        r'''OpenCV's projection (cv2.projectPoints / cv2.fisheye.projectPoints), in numpy

The formulas are OpenCV's, written out: cv2.projectPoints costs 0.3 us per
point here, too slow for the bias correction's dot outlines. A test checks
agreement with cv2 to 1e-9 px. The 5- and 8-coefficient models are compiled
(_project_rational), the fisheye in numpy.
'''
        p = np.asarray(p, dtype=np.float64)
        Rt = self._Rt_ref_cam
        p_cam = (p - Rt[3]) @ Rt[:3]
        d = self.dist
        if self.family != "FISHEYE":
            k = np.zeros(8)
            k[:len(d)] = d[:8]
            q = np.empty(p_cam.shape[:-1] + (2,))
            _project_rational(np.ascontiguousarray(p_cam.reshape(-1, 3)), k,
                              np.array([self.fx, self.fy, self.cx, self.cy]), q.reshape(-1, 2))
            return q
        z = p_cam[..., 2]
        with np.errstate(all="ignore"):
            a = p_cam[..., 0] / z
            b = p_cam[..., 1] / z
            r2 = a * a + b * b
            r = np.sqrt(r2)
            th = np.arctan(r)
            t2 = th * th
            thd = th * (1 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))
            s = np.where(r > 1e-12, thd / r, 1.0)
            x, y = a * s, b * s
            q = np.stack((self.fx * x + self.cx, self.fy * y + self.cy), axis=-1)
        q[~(z > 0)] = np.nan
        return q

    def project_cv2(self, p):
        r'''The same projection by OpenCV itself (slow; for tests)'''
        import cv2
        p = np.asarray(p, dtype=np.float64)
        Rt = self._Rt_ref_cam
        p_cam = ((p - Rt[3]) @ Rt[:3]).reshape(-1, 3)
        z = np.zeros(3)
        if self.family == "FISHEYE":
            q, _ = cv2.fisheye.projectPoints(p_cam[None], z, z, self.K, self.dist)
        else:
            q, _ = cv2.projectPoints(p_cam, z, z, self.K, self.dist)
        return q.reshape(p.shape[:-1] + (2,)).astype(np.float64)

    def __repr__(self):
        return f"OpenCVModel({self.family}, K={self.K.tolist()}, dist={self.dist.tolist()})"


@njit(cache=True, error_model="numpy")
def _project_rational(p_cam, k, f_c, q):
    r'''OpenCVModel.project's 5- and 8-coefficient model on camera-frame points p_cam (N,3)
into q (N,2), NaN where z is not > 0: the formulas as the numpy code before it evaluated
them, the same operations in the same order with fastmath off (bit-identical to it on 300
random models and point sets; 2.4x faster on 19200 points), without numpy's temporaries'''
    k1, k2, p1, p2, k3, k4, k5, k6 = k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7]
    fx, fy, cx, cy = f_c[0], f_c[1], f_c[2], f_c[3]
    for i in range(p_cam.shape[0]):
        z = p_cam[i, 2]
        if not z > 0:
            q[i, 0] = q[i, 1] = np.nan
            continue
        a = p_cam[i, 0] / z
        b = p_cam[i, 1] / z
        r2 = a * a + b * b
        radial = ((1 + r2 * (k1 + r2 * (k2 + r2 * k3)))
                  / (1 + r2 * (k4 + r2 * (k5 + r2 * k6))))
        x = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        y = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
        q[i, 0] = fx * x + cx
        q[i, 1] = fy * y + cy


def compiled_entry_points():
    r'''The numba kernels this module calls from Python (harness.warmup compiles them)'''
    return (_project_rational,)


def _Rt(rvec, tvec):
    import cv2
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))
    return np.vstack((R, np.asarray(tvec, dtype=np.float64).reshape(3)))


def _calibrate(model_name, objs, imgs, size, K0=None, dist0=None):
    r'''One OpenCV calibration, on one thread: with its default thread pool the fitted
coefficients differ between identical runs by up to 1e-6 (measured on a Mars 2020 navcam);
on one thread they are bit-identical, so that a campaign is deterministic'''
    import cv2
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        return _calibrate_threaded(model_name, objs, imgs, size, K0, dist0)
    finally:
        cv2.setNumThreads(threads)


def _calibrate_threaded(model_name, objs, imgs, size, K0=None, dist0=None):
    import cv2
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    if model_name == "FISHEYE":
        fe = cv2.fisheye
        flags = (getattr(fe, "CALIB_RECOMPUTE_EXTRINSIC", cv2.CALIB_RECOMPUTE_EXTRINSIC)
                 | getattr(fe, "CALIB_FIX_SKEW", cv2.CALIB_FIX_SKEW))
        K = np.zeros((3, 3)) if K0 is None else K0.copy()
        D = np.zeros((4, 1)) if dist0 is None else dist0.reshape(4, 1).copy()
        if K0 is not None:
            flags |= getattr(fe, "CALIB_USE_INTRINSIC_GUESS", cv2.CALIB_USE_INTRINSIC_GUESS)
        rms, K, D, rvecs, tvecs = cv2.fisheye.calibrate(
            [o[None] for o in objs], [i[None] for i in imgs], size, K, D,
            flags=flags, criteria=crit)
        return rms, K, D.ravel(), rvecs, tvecs
    # calibrateCamera takes only float32 points (6e-5 px at 1000 px: negligible here)
    objs = [o.astype(np.float32) for o in objs]
    imgs = [i.astype(np.float32) for i in imgs]
    flags = cv2.CALIB_RATIONAL_MODEL if model_name == "RATIONAL" else 0
    if K0 is not None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    rms, K, D, rvecs, tvecs = cv2.calibrateCamera(
        objs, imgs, size, None if K0 is None else K0.copy(),
        None if dist0 is None else dist0.copy(), flags=flags, criteria=crit)
    return rms, K, D.ravel(), rvecs, tvecs


@diagnostics_of(LIBRARY)
def fit(obs, target, model_name, truth=None, known_poses=False, bias_correction=True,
        bias_passes=4, bias_tolerance=1e-5, max_rms=1.0, start=None):
    r'''The OpenCV calibrator (see the module docstring); returns a CalibrationResult

start: None, or an ok CalibrationResult of this calibrator and model (harness.verdict: the
image fit, to fit the exact observations): the first pass starts from its K and
distortion (CALIB_USE_INTRINSIC_GUESS, as the bias passes do), made to the detections
corrected by its bias, which is held (no bias pass: skeleton.iterate_bias's b_start
says why); another model is ignored.
'''
    t0 = time.perf_counter()
    if known_poses:
        return CalibrationResult(
            calibrator=NAME, model_name=model_name, status="not-applicable",
            reason="OpenCV cannot hold the board poses at surveyed values (known_poses)",
            library=LIBRARY, library_version=library_version())
    found = obs.found
    views = [i for i in range(obs.Nposes) if found[i].sum() >= 6]
    if sum(int(found[i].sum()) for i in views) < 30 or len(views) < 2:
        raise CalibrationFailed(f"too few points: {int(found.sum())} found in {len(views)} "
                                "usable poses; OpenCV needs >= 30 points in >= 2 poses")
    check_homography_conditioning(obs)
    W, H = obs.imagersize

    def run(q, K0=None, dist0=None):
        objs = [np.ascontiguousarray(obs.p_board[i][found[i]], dtype=np.float64)
                for i in views]
        imgs = [np.ascontiguousarray(q[i][found[i]], dtype=np.float64) for i in views]
        return _calibrate(model_name, objs, imgs, (W, H), K0, dist0)

    def state(K, D, rvecs, tvecs):
        model = OpenCVModel(model_name, K, D, W, H)
        Rts = np.full((obs.Nposes, 4, 3), np.nan)
        for j, i in enumerate(views):
            Rts[i] = _Rt(rvecs[j], tvecs[j])
        return model, Rts

    K0 = D0 = None
    if getattr(start, "status", None) == "ok" and \
            isinstance(getattr(start, "model", None), OpenCVModel) and \
            start.model.family == model_name:
        K0 = np.array(start.info["K"], dtype=np.float64)
        D0 = np.array(start.info["dist"], dtype=np.float64)
    # a warm start's bias (start_bias): the first fit is made to the detections it corrects
    b_start = start_bias(start, obs) if K0 is not None and bias_correction \
        and target is not None else None
    rms, K, D, rvecs, tvecs = run(obs.q if b_start is None else obs.q - b_start, K0, D0)
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D))):
        raise CalibrationFailed("diverged: OpenCV returned non-finite intrinsics")
    model, Rts = state(K, D, rvecs, tvecs)
    check_pose_diversity(Rts)
    passes = [{"pass": 1, "opencv_rms": float(rms)}]

    def refit(q_used, change):
        nonlocal K, D, model, Rts
        rms, K, D, rvecs, tvecs = run(q_used, K, D)
        model, Rts = state(K, D, rvecs, tvecs)
        return {"opencv_rms": float(rms), "bias_change_max": change}

    q_used, bias_applied = iterate_bias(
        obs, target, lambda: (model, Rts), refit, passes,
        bias_passes=bias_passes if bias_correction and target is not None else 0,
        bias_tolerance=bias_tolerance, views=views, b_start=b_start)
    return fitted_result(
        NAME, LIBRARY, library_version(), model_name, t0, model=model,
        residuals=board_residuals(model, Rts, obs.p_board, q_used), found=found,
        max_rms=max_rms, Rt_cam_board=Rts, iterations=len(passes),
        info={"K": K, "dist": D, "max_abs_coefficient": float(np.max(np.abs(D))),
              "passes": passes, "bias_corrected": bias_applied, "world_frame": False,
              "known_poses": False, **applied_bias(obs, q_used, bias_applied),
              **({} if start is None else {"warm_start": K0 is not None})})

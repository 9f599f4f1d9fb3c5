r'''What every calibrator is given and what it returns

SYNOPSIS

    from harness.calibrators.base import Observations, CalibrationResult

    obs = Observations(q=q, p_board=p_board, imagersize=(1024, 1024),
                       Rt_ref_board=Rt_ref_board)
    # q has shape (Nposes,Npoints,2): detected pixels, NaN where not found
    # p_board has shape (Npoints,3): the surveyed target points, board frame
    # Rt_ref_board has shape (Nposes,4,3) or is None: surveyed board poses

    result = calibrate("jpl", obs, target, "CAHVOR")
    result.status            # "ok" | "failed" | "not-applicable"
    result.model             # fitted model (its own family), or None
    result.residuals         # (Nposes,Npoints,2) px, NaN where not observed

What each calibrator may use:

- q, p_board, imagersize: always. They are what a real calibration has: the
  detections and the target's surveyed geometry.
- Rt_ref_board, the board poses in the world ("ref") frame: the paper's JPL
  procedure surveyed the target, so the 3D position of every dot in the
  world frame is known. The jpl calibrator requires them and fits C, A, H, V,
  O, R, E directly from 3D-2D pairs (the fitted camera lives in the world
  frame). mrcal, OpenCV and COLMAP ignore them by default and estimate the
  board poses themselves (the usual calibration); with the option
  known_poses=True they hold the boards at Rt_ref_board and fit the camera's
  pose instead.
- target: the target definition (targets.boards.Target), used only for the
  dot-centroid bias correction (the dots' radius) and for the calibrators'
  grid layout (mrcal wants a regular grid).
- truth: used ONLY for what the paper also fixed from outside the data: the
  CAHVORE type and linearity. No calibrator reads the truth's C, A, H, V, O,
  R or E.

A method that fails (too few points, degenerate poses, divergence, an
exception inside the library) returns a CalibrationResult with status
"failed" and a one-line reason; a model the calibrator cannot fit returns
"not-applicable". Neither raises.
'''

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from reference_models.errors import CamvalError

STATUSES = ("ok", "failed", "not-applicable")


class CalibratorError(CamvalError):
    '''Bad input to a calibrator (inconsistent shapes, unknown calibrator or model).'''


class UnknownCalibratorError(CalibratorError):
    pass


class CalibrationFailed(Exception):
    r'''Raised inside a calibrator to end it with status "failed" and this reason

Never escapes calibrate(): the dispatcher turns it into a failed result.
'''


@dataclass(frozen=True, eq=False)
class Observations:
    r'''Detections of a planar target in several poses, with the target's geometry

q:            (Nposes,Npoints,2) float64 detected pixels; NaN where not found
p_board:      (Npoints,3) or (Nposes,Npoints,3) float64 target points, board frame
imagersize:   (width, height)
Rt_ref_board: (Nposes,4,3) surveyed board poses in the world frame, or None
point_ids:    (Npoints,) ids of the points (for the record), or None
corner_model: (Nposes,Npoints) str, the corner model of each detection
              (targets.detection.Detection.corner_model), or None (not recorded)
corner_blur_px: (Nposes,) float, the blur kernel's sigma each pose's CORNER_LINES corners
              were fitted with (Detection.corner_blur_px; 0 sharp), or None (0)
corner_spans: (Nposes,Npoints,2,R) float, each TAG_EDGES corner's two edges' spans
              (targets.detect_apriltag's Detection.corner_spans: refine_tag_edges'
              info["edge_spans"] and the row of each edge's other corner; NaN: none), or
              None (no tag edges' corners)
corner_sigma_px: (Nposes,Npoints) float, each corner's error as its detector predicts it
              under the image's noise (Detection.corner_sigma_px: targets.tag_edges'
              info["corner_sigma_px"]): the RMS of its 2-d error in px (per coordinate it
              is this over sqrt 2); NaN where the detector has no prediction, or None
              (none has any: dots, chessboards, sharp AprilTag images)
'''

    q: np.ndarray
    p_board: np.ndarray
    imagersize: tuple
    Rt_ref_board: np.ndarray = None
    point_ids: np.ndarray = None
    corner_model: np.ndarray = None
    corner_blur_px: np.ndarray = None
    corner_spans: np.ndarray = None
    corner_sigma_px: np.ndarray = None

    def __post_init__(self):
        q = np.array(self.q, dtype=np.float64)
        if q.ndim != 3 or q.shape[-1] != 2:
            raise CalibratorError(f"observations q must have shape (Nposes,Npoints,2); "
                                  f"got {q.shape}")
        p = np.array(self.p_board, dtype=np.float64)
        if p.ndim == 2:
            p = np.broadcast_to(p, (q.shape[0],) + p.shape).copy()
        if p.shape != q.shape[:2] + (3,):
            raise CalibratorError(f"p_board must have shape (Npoints,3) or (Nposes,Npoints,3) "
                                  f"matching q {q.shape}; got {np.shape(self.p_board)}")
        if not np.all(np.isfinite(p)):
            raise CalibratorError("p_board has non-finite values; expected the surveyed "
                                  "3D points of every target point")
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "p_board", p)
        w, h = (int(x) for x in self.imagersize)
        if w <= 0 or h <= 0:
            raise CalibratorError(f"imagersize must be positive; got {self.imagersize!r}")
        object.__setattr__(self, "imagersize", (w, h))
        if self.Rt_ref_board is not None:
            Rt = np.array(self.Rt_ref_board, dtype=np.float64)
            if Rt.shape != (q.shape[0], 4, 3):
                raise CalibratorError(f"Rt_ref_board must have shape (Nposes,4,3) = "
                                      f"({q.shape[0]},4,3); got {Rt.shape}")
            object.__setattr__(self, "Rt_ref_board", Rt)
        if self.corner_model is not None:
            m = np.asarray(self.corner_model, dtype=str)
            if m.shape != q.shape[:2]:
                raise CalibratorError(f"corner_model must have shape (Nposes,Npoints) = "
                                      f"{q.shape[:2]}; got {m.shape}")
            object.__setattr__(self, "corner_model", m)
        if self.corner_blur_px is not None:
            s = np.array(self.corner_blur_px, dtype=np.float64)
            if s.shape != q.shape[:1]:
                raise CalibratorError(f"corner_blur_px must have shape (Nposes,) = "
                                      f"({q.shape[0]},); got {s.shape}")
            object.__setattr__(self, "corner_blur_px", s)
        if self.corner_spans is not None:
            s = np.array(self.corner_spans, dtype=np.float64)
            if s.ndim != 4 or s.shape[:3] != q.shape[:2] + (2,):
                raise CalibratorError(f"corner_spans must have shape (Nposes,Npoints,2,R) = "
                                      f"{q.shape[:2] + (2,)}+(R,); got {s.shape}")
            object.__setattr__(self, "corner_spans", s)
        if self.corner_sigma_px is not None:
            s = np.array(self.corner_sigma_px, dtype=np.float64)
            if s.shape != q.shape[:2]:
                raise CalibratorError(f"corner_sigma_px must have shape (Nposes,Npoints) = "
                                      f"{q.shape[:2]}; got {s.shape}")
            object.__setattr__(self, "corner_sigma_px", s)

    @property
    def Nposes(self):
        return self.q.shape[0]

    @property
    def Npoints(self):
        return self.q.shape[1]

    @property
    def found(self):
        r'''(Nposes,Npoints) bool: the point was detected'''
        return np.all(np.isfinite(self.q), axis=-1)

    @property
    def has_world_points(self):
        return self.Rt_ref_board is not None

    def p_ref(self):
        r'''The surveyed target points in the world frame

SYNOPSIS

    p = obs.p_ref()   # (Nposes,Npoints,3); needs Rt_ref_board
'''
        if self.Rt_ref_board is None:
            raise CalibratorError("the board poses Rt_ref_board are not known; the world "
                                  "points of the target need them")
        R = self.Rt_ref_board[:, :3, :]
        t = self.Rt_ref_board[:, 3, :]
        return np.einsum("fij,fnj->fni", R, self.p_board) + t[:, None, :]

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_camera_poses(cls, q, p_board, imagersize, Rt_cam_board=None, Rt_ref_cam=None,
                          point_ids=None, corner_model=None, corner_blur_px=None,
                          corner_spans=None, corner_sigma_px=None):
        r'''Observations from board poses in a camera frame (what a render sidecar gives)

SYNOPSIS

    obs = Observations.from_camera_poses(q, target.points(), (W, H),
                                         Rt_cam_board, truth.Rt_ref_cam())

The survey in the world frame is Rt_ref_board = Rt_ref_cam o Rt_cam_board;
without Rt_cam_board the poses are unknown. Rt_ref_cam defaults to identity.
corner_model, corner_blur_px, corner_spans, corner_sigma_px: the detections' corner
models, blurs, tag edges' spans and predicted errors (the fields above), or None.
'''
        Rt_ref_board = None
        if Rt_cam_board is not None:
            import mrcal
            Rt = (np.vstack((np.eye(3), np.zeros(3))) if Rt_ref_cam is None
                  else np.asarray(Rt_ref_cam, dtype=np.float64))
            Rt_ref_board = np.stack([mrcal.compose_Rt(Rt, np.asarray(x, dtype=np.float64))
                                     for x in Rt_cam_board])
        return cls(q=q, p_board=p_board, imagersize=imagersize, Rt_ref_board=Rt_ref_board,
                   point_ids=point_ids, corner_model=corner_model,
                   corner_blur_px=corner_blur_px, corner_spans=corner_spans,
                   corner_sigma_px=corner_sigma_px)


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    r'''What a calibrator returns

calibrator:     "jpl" | "mrcal" | "opencv" | "colmap"
model_name:     the model asked for ("CAHVOR", "OPENCV5", ...)
status:         "ok" | "failed" | "not-applicable"
reason:         why not ok ("" when ok)
model:          the fitted model in the calibrator's own family (a reference_models
                CAHV/CAHVOR/CAHVORE, or an object with project(p), Rt_ref_cam(),
                width, height, family), None when not ok
residuals:      (Nposes,Npoints,2) px (observed - projected), NaN where not observed
Rt_cam_board:   (Nposes,4,3) board poses in the fitted camera's frame, or None
iterations:     the solver work: jpl, scipy function evaluations; mrcal, calls of
                mrcal.optimize; opencv, calls of calibrateCamera; colmap, bundle
                adjustments (these libraries do not report their inner iterations)
seconds:        wall time of the fit
library:        name of the library that did the fit; library_version its version
info:           calibrator-specific figures (first pass, coefficients, options); two
                keys are read by the comparison (world_frame, theta_estimated below)
'''

    calibrator: str
    model_name: str
    status: str
    reason: str = ""
    model: Any = None
    residuals: np.ndarray = None
    Rt_cam_board: np.ndarray = None
    iterations: int = 0
    seconds: float = 0.0
    library: str = ""
    library_version: str = ""
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.status not in STATUSES:
            raise CalibratorError(f"status {self.status!r} is not one of {STATUSES}")

    @property
    def ok(self):
        return self.status == "ok"

    @property
    def world_frame(self):
        r'''Whether the fitted model sits in the surveyed world frame (info["world_frame"],
set by each calibrator: jpl and mrcal with known poses do; OpenCV and COLMAP fit
their own camera frame), so its C, A, H, V compare with the truth's directly'''
        return bool(self.info.get("world_frame", False))

    @property
    def theta_estimated(self):
        r'''Whether the fit estimates the angle theta between the image axes
(info["theta_estimated"]; jpl's CAHV* fits do). A model frame with square pixel
axes (mrcal, OpenCV, COLMAP) holds theta at 90 deg, so its theta error is the
truth's own departure from 90 deg, not a fit error'''
        return bool(self.info.get("theta_estimated", False))

    @property
    def residual_norms(self):
        r'''(Nposes,Npoints) |residual| per point, px; NaN where not observed'''
        if self.residuals is None:
            return None
        return np.linalg.norm(self.residuals, axis=-1)

    def residual_stats(self):
        r'''min, max and RMS of the per-point residual norms (the paper's Fig. 3), px'''
        return residual_stats(self.residuals)

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)

    def as_dict(self):
        r'''A JSON-serialisable summary (no model object; NaN become None)'''
        out = {
            "calibrator": self.calibrator,
            "model_name": self.model_name,
            "status": self.status,
            "reason": self.reason,
            "family": getattr(self.model, "family", None),
            "iterations": int(self.iterations),
            "seconds": float(self.seconds),
            "library": self.library,
            "library_version": self.library_version,
            "residuals": self.residual_stats(),
            "info": jsonable(self.info),
        }
        return out


# board normals all within this angle of each other: the focal length is not observable
MIN_TILT_SPREAD_DEG = 2.0


def check_pose_diversity(Rt_cam_board, min_spread_deg=MIN_TILT_SPREAD_DEG):
    r'''Raise CalibrationFailed if all board planes are (nearly) parallel

SYNOPSIS

    check_pose_diversity(Rt_cam_board)   # (Nposes,4,3); NaN poses are ignored

A planar target calibrates a camera with unknown board poses only if the
boards are tilted differently (Zhang): with all normals parallel the focal
length trades against the range. The spread is the largest angle between two
board normals.
'''
    Rt = np.asarray(Rt_cam_board, dtype=np.float64)
    n = Rt[:, :3, 2]
    n = n[np.all(np.isfinite(n), axis=-1)]
    if len(n) < 2:
        raise CalibrationFailed("degenerate poses: fewer than 2 board poses")
    c = np.clip(np.abs(n @ n.T), -1.0, 1.0)
    spread = math.degrees(math.acos(c.min()))
    if spread < min_spread_deg:
        raise CalibrationFailed(
            f"degenerate poses: all {len(n)} board planes are within {spread:.3g} deg of "
            f"parallel (need >= {min_spread_deg:g} deg of tilt between poses to observe the "
            "focal length)")
    return spread


# Zhang's constraints: second-smallest / largest singular value below this = degenerate
MIN_ZHANG_CONDITION = 1e-3


def check_homography_conditioning(obs, min_ratio=MIN_ZHANG_CONDITION):
    r'''Raise CalibrationFailed if the board views cannot determine the intrinsics

SYNOPSIS

    ratio = check_homography_conditioning(obs)   # for unknown board poses

Zhang's method: each view's board-to-image homography gives two linear
constraints on the image of the absolute conic (6 unknowns, plus zero skew).
With boards all parallel (e.g. translated in their plane) the system keeps a
second null direction: the focal length trades against the range, and a
calibrator returns a focal length of any size with small residuals. The
ratio of the second-smallest to the largest singular value (image coordinates
scaled by the width) measures it: 0.01-0.25 for the planned poses of the
catalogue cameras, 2e-5-1e-4 for translated fronto-parallel boards of
narrow lenses. Distorted wide lenses make even parallel boards look tilted
(0.01): this check does not catch those; check_pose_diversity() after the fit
does.
'''
    import cv2
    W, H = obs.imagersize
    N = np.array([[1.0 / W, 0.0, -0.5], [0.0, 1.0 / W, -0.5 * H / W], [0.0, 0.0, 1.0]])

    def v(a, b):
        return np.array([a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[1] * b[1],
                         a[2] * b[0] + a[0] * b[2], a[2] * b[1] + a[1] * b[2], a[2] * b[2]])

    rows = [np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0])]  # zero skew
    for i in range(obs.Nposes):
        f = obs.found[i]
        if f.sum() < 4:
            continue
        Hm, _ = cv2.findHomography(obs.p_board[i][f][:, :2], obs.q[i][f], 0)
        if Hm is None or not np.all(np.isfinite(Hm)):
            continue
        Hm = N @ Hm
        h1, h2 = Hm[:, 0], Hm[:, 1]
        rows += [v(h1, h2), v(h1, h1) - v(h2, h2)]
    if len(rows) < 6:
        raise CalibrationFailed(f"degenerate poses: only {(len(rows) - 1) // 2} usable board "
                                "views; need at least 3 for unknown board poses")
    s = np.linalg.svd(np.array(rows), compute_uv=False)
    ratio = float(s[-2] / s[0])
    if ratio < min_ratio:
        raise CalibrationFailed(
            f"degenerate poses: the board views leave the focal length undetermined (Zhang "
            f"condition {ratio:.2g} < {min_ratio:g}; boards parallel to each other?)")
    return ratio


def residual_stats(residuals):
    r'''min, max and RMS over points of the residual norms

SYNOPSIS

    s = residual_stats(residuals)   # residuals (...,2), NaN rows ignored
    # {"n": int, "min": px, "max": px, "rms": px, "mean": px}
'''
    if residuals is None:
        return None
    r = np.linalg.norm(np.asarray(residuals, dtype=np.float64).reshape(-1, 2), axis=-1)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return {"n": 0, "min": None, "max": None, "rms": None, "mean": None}
    return {"n": int(r.size), "min": float(r.min()), "max": float(r.max()),
            "rms": float(math.sqrt(np.mean(r * r))), "mean": float(r.mean())}


def jsonable(x):
    r'''Convert numpy values (recursively) to plain JSON values; NaN/inf -> None'''
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


@runtime_checkable
class Calibrator(Protocol):
    r'''A calibrator adapter: a module (or object) with these attributes

NAME (registry name), LIBRARY (the library doing the fit), MODELS (model names
it fits), library_version(), fit(...) -> CalibrationResult (may raise
CalibrationFailed); optionally canonical_model(name) to accept aliases and
uses_world_frame(**options) -> bool (taken as True when missing: see
harness.calibrators.uses_world_frame). The registry (harness.calibrators) holds
the built-in modules and the plugins of the entry-point group
"camval.calibrators".
'''

    NAME: str
    LIBRARY: str
    MODELS: tuple

    def library_version(self) -> str: ...

    def fit(self, observations, target, model_name, truth=None,
            **options) -> CalibrationResult: ...

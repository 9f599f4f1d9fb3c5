r'''What a detector returns, and the helpers every detector builds it with

SYNOPSIS

    from targets.detection import Detection, as_float_image, failed, result

    img = as_float_image(image)              # (H,W) float64 in [0,1] (uint8/uint16 scaled)
    det = result(target, q, "mydetector")    # q (N,2), NaN where a point was not found
    det = failed(target, "no blobs", "mydetector")
    det.status                               # "ok" | "failed"
    det.q[det.found]                         # (Nfound,2) pixel positions, camval's convention
    det.corner_model                         # (N,) str: the corner model of each point, or None

A detector (targets.detect: the registry) never raises because the target was
not found: it returns status "failed" with the reason. Only input that is not
an image at all raises DetectionInputError. q[i] belongs to
target.point_ids()[i].

Kept apart from targets.detect so that the detectors import it and the
registry imports the detectors (lazily) without a cycle.
'''

import dataclasses
from dataclasses import dataclass

import numpy as np

from reference_models.errors import CamvalError


class DetectionInputError(CamvalError):
    '''An image or option a detector cannot work on (not a "target not found").'''


@dataclass(frozen=True, eq=False)
class Detection:
    r'''What a detector found

q:          (N,2) float64 pixel positions, NaN for points not found
found:      (N,) bool
status:     "ok" (at least the detector's min_found points found; n_found says how many)
            | "failed" (target not found or too few points; reason says why)
reason:     "" when ok, else why not
n_expected: N, the number of points of the target
n_found:    number of points found
point_ids:  (N,) ids of the points (target.point_ids())
detector:   name of the detector
info:       detector-specific figures (JSON-able)
corner_model: (N,) str, the model each found corner's position comes from (CORNER_WINDOW,
            TAG_EDGES, or the detector's own name for its unrefined corners; "" where not
            found), or None when the detector does not say (dots; a corner detector that
            leaves it None has its corners taken as CORNER_WINDOW's). The calibrators' bias
            step (harness.calibrators.bias.corner_bias) corrects only CORNER_WINDOW's.
corner_blur_px: the sigma (px) of the "sampled" blur kernel (targets.corners.blur_kernel)
            that the CORNER_LINES corners were fitted with (their bias depends on it); 0
            for a sharp fit
corner_spans: (N,2,R) float, the TAG_EDGES corners' two edges' span records (targets.
            tag_edges SPAN_RECORD, each with its edge's other corner's row appended; NaN
            where none), for the calibrators' bias step; None when the detector made none
            (a sharp image, dots). Not in as_dict: it is the bias step's, not a figure
corner_sigma_px: (N,) float, each corner's predicted error under the image's noise, the
            RMS of its 2-d error in px (per coordinate: over sqrt 2; targets.tag_edges'
            info["corner_sigma_px"], from its edges' chosen spans); NaN where the detector
            has none; None when it made none (dots, chessboards, sharp images). Not in
            as_dict: the verdict's scatter (and a weighted fit) use it, not a figure
'''

    q: np.ndarray
    found: np.ndarray
    status: str
    reason: str
    n_expected: int
    n_found: int
    point_ids: np.ndarray = None
    detector: str = ""
    info: dict = dataclasses.field(default_factory=dict)
    corner_model: np.ndarray = None
    corner_blur_px: float = 0.0
    corner_spans: np.ndarray = None
    corner_sigma_px: np.ndarray = None

    def as_dict(self):
        return {"status": self.status, "reason": self.reason, "n_expected": self.n_expected,
                "n_found": self.n_found, "detector": self.detector,
                "q": [[float(v) if np.isfinite(v) else None for v in row] for row in self.q],
                "found": self.found.tolist(),
                "point_ids": None if self.point_ids is None else self.point_ids.tolist(),
                "info": self.info,
                "corner_model": None if self.corner_model is None else
                self.corner_model.tolist(), "corner_blur_px": float(self.corner_blur_px)}


# The corner models a detector's corners come from (Detection.corner_model):
# targets.corners.refine_corners: straight edges meeting in a window about each corner; on
# edges that distortion bends its corner moves by the curvature bias that
# harness.calibrators.bias.corner_bias computes and the calibrators subtract
CORNER_WINDOW = "corner window"
# targets.corners.refine_corners on a blurred image: a chessboard's opposite rays are tied
# into one straight line each (targets.corners.CHESSBOARD_LINES); a line fitted to an edge
# that distortion bends through the corner moves it otherwise than two free rays do (about
# -1.9x as far on MER hazcam 8), corner_bias(lines=True)
CORNER_LINES = "corner window, lines"
# targets.tag_edges (blurred images): the meeting point of a tag's two whole border edges,
# each fitted as a curve; no window, no curvature bias
TAG_EDGES = "tag edges"


def stack_corner_spans(spans):
    r'''(Nposes,Npoints,2,R) the span records of each pose's detection (Detection.corner_spans,
one per pose), NaN for a pose without; None when no pose has any (a sharp image, dots)'''
    shape = next((s.shape for s in spans if s is not None), None)
    if shape is None:
        return None
    return np.stack([np.full(shape, np.nan) if s is None else s for s in spans])


def stack_corner_sigma(sigmas):
    r'''(Nposes,Npoints) the predicted corner errors of each pose's detection
(Detection.corner_sigma_px, one per pose), NaN for a pose without; None when no pose has any'''
    shape = next((np.shape(s) for s in sigmas if s is not None), None)
    if shape is None:
        return None
    return np.stack([np.full(shape, np.nan) if s is None else np.asarray(s, dtype=np.float64)
                     for s in sigmas])


def stack_corner_models(models, q):
    r'''(Nposes,Npoints) str: the corner models of each pose's detection (Detection.corner_model,
one per pose; q (Nposes,Npoints,2) their points); None when a pose that found points has
none (its detector records no models: dots) or no pose has any. A detection that found
nothing (failed()) has no model to give: its points take "" (no corner, no bias), as a found
detection's unfound points do, so the other poses keep theirs (were they dropped, the
calibrators' bias step would take every pose's tag-edge corners for the window model's and
subtract its bias: h-joint, session 22, the renderer gate's false alarms on small sensors)'''
    if all(m is None for m in models):
        return None
    out = []
    for m, qi in zip(models, q, strict=True):
        if m is None:
            if np.isfinite(qi).any():
                return None
            m = np.full(len(qi), "")
        out.append(m)
    return np.stack(out)


def corner_models(corner_model, found):
    r'''(N,) str: corner_model (a str for every point, or (N,) str) where found, "" elsewhere;
None for None'''
    if corner_model is None:
        return None
    m = np.broadcast_to(np.asarray(corner_model, dtype=str), found.shape)
    return np.where(found, m, "")


def failed(target, reason, detector, info=None):
    r'''A Detection of nothing, with the reason'''
    n = target.Npoints
    return Detection(q=np.full((n, 2), np.nan), found=np.zeros(n, bool), status="failed",
                     reason=reason, n_expected=n, n_found=0, point_ids=target.point_ids(),
                     detector=detector, info=info or {})


# fewest points of a view that a calibrator can use: the board-to-image homography that
# seeds each view's pose (harness.calibrators.base, Zhang's method; cv2.findHomography)
# needs 4 points, no three of them on one line of the board
MIN_POINTS_FOR_POSE = 4


def on_one_line(p_board, tol=1e-9):
    r'''True when the board points (N,2 or 3) lie on one line (or are fewer than 3)'''
    p = np.asarray(p_board, dtype=np.float64)[:, :2]
    if len(p) < 3:
        return True
    d = p - p.mean(axis=0)
    s = np.linalg.svd(d, compute_uv=False)
    return bool(s[1] <= tol * max(s[0], 1e-300))


def result(target, q, detector, min_found=None, info=None, corner_model=None,
           corner_blur_px=0.0):
    r'''A Detection from (N,2) positions with NaN for missing points

min_found: fewest points for status "ok" (None: all of them). Found points that lie on
one line of the board give no pose (MIN_POINTS_FOR_POSE): "failed" with that reason.
corner_model: the corner model of every point (a str) or of each ((N,) str), or None
(Detection.corner_model); corner_blur_px: Detection.corner_blur_px.'''
    q = np.asarray(q, dtype=np.float64)
    found = np.all(np.isfinite(q), axis=-1)
    n = int(found.sum())
    need = target.Npoints if min_found is None else min_found
    why = ""
    if n < need:
        why = f"found {n} of {target.Npoints} points; need {need}"
    elif n < target.Npoints and hasattr(target, "points") and \
            on_one_line(target.points()[found]):
        why = (f"the {n} points found lie on one line of the board: no pose (a view needs "
               f"{MIN_POINTS_FOR_POSE} points, no three on a line)")
    if why:
        return Detection(q=q, found=found, status="failed", reason=why,
                         n_expected=target.Npoints, n_found=n, point_ids=target.point_ids(),
                         detector=detector, info=info or {},
                         corner_model=corner_models(corner_model, found),
                         corner_blur_px=float(corner_blur_px))
    return Detection(q=q, found=found, status="ok", reason="", n_expected=target.Npoints,
                     n_found=n, point_ids=target.point_ids(), detector=detector,
                     info=info or {}, corner_model=corner_models(corner_model, found),
                     corner_blur_px=float(corner_blur_px))


def as_float_image(image, dtype=np.float64):
    r'''An image as float (H,W) in [0,1]: uint8/uint16 scaled, colour averaged

dtype float32 halves the memory and time of the conversion of a large image; a
float32 image is then not copied at all.'''
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] in (3, 4):
        a = a[..., :3].astype(np.float64).mean(axis=-1) if a.dtype.kind == "f" else \
            np.round(a[..., :3].astype(np.float64).mean(axis=-1)).astype(a.dtype)
    if a.ndim != 2 or min(a.shape) < 2:
        raise DetectionInputError(f"expected a 2-D grey image (H,W); got an array of shape "
                                  f"{a.shape}")
    if a.dtype == np.uint8:
        return a.astype(dtype) / dtype(255.0)
    if a.dtype == np.uint16:
        return a.astype(dtype) / dtype(65535.0)
    if a.dtype.kind == "b":
        return a.astype(dtype)
    if a.dtype.kind in "iu":
        raise DetectionInputError(f"integer images must be uint8 or uint16; got {a.dtype}")
    return a.astype(dtype, copy=False) if a.dtype == dtype else a.astype(dtype)


def working_image(image):
    r'''A detector's image: (H,W) float32 in [0,1] (float64 kept as float64), its uint8
copy for OpenCV and the AprilTag library, and its (min, max); None when a pixel is not
finite

SYNOPSIS

    img, img8, (lo, hi) = working_image(image)   # or None

One compiled pass (targets._corner_kernels.image_range_u8): on a 5120x3840 float32 image
it takes 0.04 s of CPU where OpenCV's checkRange, minMaxLoc, max and convertScaleAbs took
0.14 s (load 6, 2 cores), with the same img8 bit for bit (float32 products stay float32).
img8 = round(255 * clip(img, 0, 1)) (round half to even, as numpy's round).
'''
    from ._corner_kernels import image_range_u8
    a = np.asarray(image)
    dtype = np.float64 if a.dtype == np.float64 else np.float32
    img = np.ascontiguousarray(as_float_image(a, dtype=dtype))
    finite, lo, hi, img8 = image_range_u8(img, dtype(255.0))
    if not finite:
        return None
    return img, img8, (lo, hi)


def median(v):
    r'''np.median of a finite 1-D array, the same value bit for bit, without its overhead

The middle order statistic, or the mean (a + b)/2 of the two middle ones as np.median
takes it; np.median costs 30-50 us a call (targets.detect_dots' board level takes 3 per
dot, targets.tag_edges one per tag).'''
    k = len(v) // 2
    if len(v) % 2:
        return np.partition(v, k)[k]
    p = np.partition(v, (k - 1, k))
    return (p[k - 1] + p[k]) / 2

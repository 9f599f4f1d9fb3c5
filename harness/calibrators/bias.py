r'''The dot-centroid bias: where a projected dot's centroid lies vs its centre

SYNOPSIS

    from harness.calibrators.bias import centroid_bias

    b = centroid_bias(model, target, Rt_cam_board)
    # b has shape (Npoints,2): expected centroid - projection of the centre, px
    q_corrected = q_detected - b

The centroid of a projected dot is not the projection of its centre
(perspective and distortion: 0.1 px mean, 0.3 px max on a navcam). The
paper's second pass subtracts this offset, computed with the CURRENT estimate
of model and pose, from each detection and solves again.

The expected centroid is the area centroid of each dot's projected outline (a
circle of the target's dot radius about the point, in the board plane). When
the points are the target's own, targets.centroids.expected_centroids gives it
(its default error bound); otherwise the outline is projected at NOUTLINE points and
their curve's centroid taken (targets.centroids.outline_centroid). Any model
with project(p) and Rt_ref_cam() works (JPL, OpenCV, COLMAP and mrcal fits).

Corner targets (AprilTag, chessboard) have a bias too: targets.corners fits
straight edges to edges that lens distortion bends, which moves a refined
corner by about k w^2 / 10 (0.004-0.007 px RMS on a MER hazcam fisheye,
0.0005-0.001 after correction; corner_bias). centroid_bias returns it for them,
so the same loop corrects both. It belongs to that window model only: a corner
found otherwise (targets.tag_edges on a blurred image fits each whole border edge
as a curve; an exact projection) has none, and bias_step leaves it uncorrected
where the observations' corner_model says so (WINDOW_BIASED).

A blurred AprilTag's corner (TAG_EDGES) has a bias of its own: each edge is followed
by a polynomial over a span of its board line (targets.tag_edges' _span_choice), which
cannot follow the line's bend all the way to the corner, and the blur moves a bent edge
towards its centre of curvature. Both come from the board line's shape, i.e. from the
camera model and the pose: tag_edges_bias computes them (targets.tag_edges.edge_span_bias)
from what the detector recorded of each corner's spans (Observations.corner_spans), so the
same loop corrects them; a TAG_EDGES corner without a record gets none.
'''

import numpy as np

from reference_models.poseutils import transform_point_Rt
from targets.detection import CORNER_LINES, CORNER_WINDOW, TAG_EDGES

# outline points per dot when the points are not the target's own: the centroid of the sampled
# outline (targets.centroids.outline_centroid) converges exponentially, 16 points within 1e-11
# px of the limit on every catalogue camera; 64 leave room for dots far more distorted
NOUTLINE = 64


def dot_radii(target, p_board):
    r'''The radius (m) of the dot centred at each point, or None if the target has no dots

SYNOPSIS

    r = dot_radii(target, p_board)   # p_board (Npoints,3); r (Npoints,)
'''
    if target is None or getattr(target, "kind", "dots") != "dots":
        return None
    if hasattr(target, "dot_radii"):
        pts = np.asarray(target.points(), dtype=np.float64)
        if pts.shape == p_board.shape and np.allclose(pts, p_board, rtol=0, atol=1e-12):
            return np.asarray(target.dot_radii(), dtype=np.float64)
    circles = getattr(target.pattern(), "circles", None)
    if circles is None or len(circles) == 0:
        return None
    circles = np.asarray(circles, dtype=np.float64)
    d2 = ((p_board[:, None, :2] - circles[None, :, :2]) ** 2).sum(axis=-1)
    i = np.argmin(d2, axis=-1)
    if np.any(d2[np.arange(len(i)), i] > 1e-12):
        return None
    return circles[i, 2]


def project_from_cam(model, p_cam):
    r'''Project points given in the model's camera frame (model.Rt_ref_cam())'''
    return model.project(transform_point_Rt(model.Rt_ref_cam(), p_cam))


def outline_centroids(model, p_board, radii, Rt_cam_board, noutline=NOUTLINE):
    r'''Area centroids of the projected outlines of circular dots

SYNOPSIS

    q = outline_centroids(model, p_board, radii, Rt_cam_board)
    # p_board (Npoints,3) dot centres in the board plane, radii (Npoints,);
    # q (Npoints,2); NaN for a dot not wholly projectable
'''
    from targets.centroids import outline_centroid
    phi = np.linspace(0.0, 2.0 * np.pi, noutline, endpoint=False)
    ring = np.stack((np.cos(phi), np.sin(phi), np.zeros_like(phi)), axis=-1)
    outline = p_board[:, None, :] + radii[:, None, None] * ring[None]
    return outline_centroid(project_from_cam(model, transform_point_Rt(Rt_cam_board, outline)))


def centroid_bias(model, target, Rt_cam_board, p_board=None):
    r'''expected centroid - projected centre of each dot, px; None if the target has no dots

For a corner target (CORNER_KINDS): corner_bias, refined - projected corner.

SYNOPSIS

    b = centroid_bias(model, target, Rt_cam_board)   # (Npoints,2)
'''
    if p_board is None:
        p_board = np.asarray(target.points(), dtype=np.float64)
    if getattr(target, "kind", "dots") in CORNER_KINDS:
        return corner_bias(model, target, Rt_cam_board, p_board)
    radii = dot_radii(target, p_board)
    if radii is None:
        return None
    centres = project_from_cam(model, transform_point_Rt(Rt_cam_board, p_board))
    expected = None
    if len(p_board) == len(target.points()):
        try:
            from targets.centroids import expected_centroids
        except ImportError:
            expected_centroids = None
        if expected_centroids is not None:
            expected = np.asarray(expected_centroids(model, target, Rt_cam_board),
                                  dtype=np.float64)
    if expected is None:
        expected = outline_centroids(model, p_board, radii, Rt_cam_board)
    return expected - centres


# targets whose points are corners refined by targets.corners
CORNER_KINDS = ("apriltag", "chessboard")
# the corner models (Observations.corner_model) whose corners carry corner_bias
WINDOW_BIASED = (CORNER_WINDOW, CORNER_LINES)
# the edges' tangents and curvatures from projections this far along them (window units)
CORNER_DIFF_STEP = 0.05


def corner_bias(model, target, Rt_cam_board, p_board, lines=False, blur_px=0.0, q_window=None):
    r'''refined corner - projected corner, px: the bias of straight rays on curved edges

SYNOPSIS

    b = corner_bias(model, target, Rt_cam_board, p_board)   # (Npoints,2)

Each edge leaving a corner (targets.corners.corner_rays) is projected at +-h
along the board (h = CORNER_DIFF_STEP window units) for its image tangent and
curvature; targets.corners.curvature_bias turns them into the shift of the
refiner's fit. NaN where a point does not project. lines=True: a chessboard's corners
fitted with each pair of opposite rays one line (Detection.corner_model CORNER_LINES: a
blurred image); blur_px: the sigma of the "sampled" kernel they were fitted with
(Detection.corner_blur_px), whose taps and smaller window curvature_bias then takes (0:
the sharp pixel terms, which leave 0.65-1.14x of a blurred fit's shift unexplained on
MER hazcams). q_window (Npoints,2): the detected corners (Observations.q), which place each
corner's window as the refiner placed it: about the detection (curvature_bias's window_at),
along the edges' tangents (the refiner's fitted rays) as long as the refiner's steps from the
detections (targets.corners.corner_steps: the chessboard's grid differences, a tag's mean
bits; targets.corners.window_steps), and a tag's shrink from its detected corners. None or
NaN rows: the projected corners instead, which move with the model: the window then gains or
loses a pixel as a bias pass moves it, and the bias jumps (~1e-3 px; the passes need not
settle). The model's derivative at the corner (the steps before) is 1.9% RMS, 7.4% at most
off the refiner's steps on 17 CAHVORE's realistic chessboard (the grid rule's: 0.23%).
'''
    from targets.corners import (
        CHESSBOARD_LINES,
        corner_rays,
        corner_steps,
        curvature_bias,
        window_steps,
    )
    rays, unit, wedges, window = corner_rays(target)
    if len(rays) != len(p_board):
        return np.full((len(p_board), 2), np.nan)
    h = CORNER_DIFF_STEP * unit
    p = np.asarray(p_board, dtype=np.float64)[:, None, :]
    pts = np.concatenate((p, p + h * rays, p - h * rays), axis=1)      # (N,1+2R,3)
    q = project_from_cam(model, transform_point_Rt(Rt_cam_board, pts))
    R = rays.shape[1]
    q0, qp, qm = q[:, :1], q[:, 1:1 + R], q[:, 1 + R:]
    d1 = (qp - qm) / (2 * h)                       # dq/ds, px per metre along each ray
    d2 = (qp - 2 * q0 + qm) / (h * h)
    speed = np.linalg.norm(d1, axis=-1)
    tangents = d1 / speed[..., None]
    curvatures = (d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]) / speed ** 3
    # the window where the refiner laid it: about the detected corner, along the edges' tangents
    # (its fitted rays), as long as the refiner's steps from the detections (corner_steps)
    at = q0[:, 0] if q_window is None else np.asarray(q_window, dtype=np.float64)
    at = np.where(np.all(np.isfinite(at), axis=-1)[:, None], at, q0[:, 0])
    steps = window_steps(tangents, corner_steps(target, at))
    tied = CHESSBOARD_LINES if lines and target.kind == "chessboard" else ()
    return curvature_bias(q0[:, 0], tangents, curvatures, wedges, steps, lines=tied,
                          sigma=blur_px, window_at=at, **window)


def tag_edges_bias(model, Rt_cam_board, p_board, spans):
    r'''(Npoints,2) px: refined - projected corner of TAG_EDGES corners (targets.tag_edges:
each edge followed by its span's polynomial, which misses the bent board line at the corner,
and moved by the blur towards its centre of curvature); NaN where a point has no record

spans (Npoints,2,R): Observations.corner_spans of one pose (targets.tag_edges.SPAN_RECORD
values of each of the corner's two edges, the row of the edge's other corner last).'''
    from targets.tag_edges import edge_span_bias
    p = np.asarray(p_board, dtype=np.float64)
    spans = np.asarray(spans, dtype=np.float64)
    out = np.full((len(p), 2), np.nan)
    ok = np.isfinite(spans).all((1, 2))
    if ok.any():
        rows = spans[ok, :, -1].astype(np.int64)
        out[ok] = edge_span_bias(model, Rt_cam_board, p[ok], p[rows[:, 0]], p[rows[:, 1]],
                                 spans[ok, :, :-1])
    return out


def bias_step(model, target, Rt_cam_board, p_board, b_prev=None, views=None,
              corner_model=None, corner_blur_px=None, corner_spans=None, corner_q=None):
    r'''One pass of the iterated bias correction the calibrators share

SYNOPSIS

    b, change = bias_step(model, target, Rts, obs.p_board, b_prev, views, obs.corner_model,
                          obs.corner_blur_px)
    # b has shape (Nposes,Npoints,2), or is None when the target has no dots
    q_used = obs.q - b

The bias of every dot under the current model and poses Rt_cam_board
(Nposes,4,3); poses outside `views` (when given) get none. For a corner target,
corner_model (Nposes,Npoints) str (Observations.corner_model) gives the corner
model of each detection: only the WINDOW_BIASED ones get corner_bias (CORNER_LINES's with
its lines tied, under the blur corner_blur_px (Nposes,) gives each pose: the sampled
kernel's sigma they were fitted with, Observations.corner_blur_px; None: 0), the rest 0
(None: every corner is the window model's). TAG_EDGES corners with a record in
corner_spans (Nposes,Npoints,2,R) (Observations.corner_spans; None: none) get
tag_edges_bias, the rest of them 0. corner_q (Nposes,Npoints,2): the detected corners
(Observations.q), about which the window model's bias lays each corner's window as the
refiner did (corner_bias's q_window; None: about the projected corners, which move with the
model). `change` is the largest change of the bias since b_prev (its largest value on the
first pass).
'''
    if target is None:
        return None, None
    corners = corner_model is not None and getattr(target, "kind", "dots") in CORNER_KINDS
    if corners:
        corner_model = np.asarray(corner_model)

    def pose_bias(i, Rt):
        if views is not None and i not in views:
            return np.zeros((p_board.shape[-2], 2))
        tied = corner_model[i] == CORNER_LINES if corners else None
        at = None if corner_q is None else corner_q[i]
        if tied is None or not tied.any():
            if getattr(target, "kind", "dots") in CORNER_KINDS:
                return corner_bias(model, target, Rt, p_board[i], q_window=at)
            return centroid_bias(model, target, Rt, p_board[i])
        # corners fitted with their opposite rays tied: the lines' bias, computed once (the
        # window's only for corners of the window model beside them)
        blur = 0.0 if corner_blur_px is None else float(corner_blur_px[i])
        b = corner_bias(model, target, Rt, p_board[i], lines=True,
                        blur_px=blur if np.isfinite(blur) else 0.0, q_window=at)
        if not tied.all():
            b[~tied] = corner_bias(model, target, Rt, p_board[i], q_window=at)[~tied]
        return b
    b = [pose_bias(i, Rt) for i, Rt in enumerate(Rt_cam_board)]
    if any(x is None for x in b):
        return None, None
    b = np.array(b)
    if corners:
        b[~np.isin(corner_model, WINDOW_BIASED)] = 0.0
        if corner_spans is not None:
            for i, Rt in enumerate(Rt_cam_board):
                edged = (corner_model[i] == TAG_EDGES) & \
                    np.isfinite(corner_spans[i]).all((1, 2))
                if edged.any() and (views is None or i in views):
                    t = tag_edges_bias(model, Rt, p_board[i], corner_spans[i])
                    b[i, edged] = np.where(np.isfinite(t[edged]), t[edged], 0.0)
    change = float(np.nanmax(np.abs(b if b_prev is None else b - b_prev)))
    return b, change

r'''Where the target's points land in the image: projections and exact dot centroids

SYNOPSIS

    from targets.centroids import expected_centroids, projected_points

    q_centre   = projected_points(model, target, Rt_cam_board)    # (N,2)
    q_centroid = expected_centroids(model, target, Rt_cam_board)  # (N,2), kind "dots"
    bias = q_centroid - q_centre    # the perspective/distortion bias of each dot

The image of a circular dot is not centred on the projection of the dot's
centre: perspective and lens distortion stretch one side of the dot more than
the other. A detector that takes the centroid of a dot's image measures the
CENTROID OF THE PROJECTED DOT, which expected_centroids() computes exactly:
the dot's circle outline is projected point by point (1440 points by default)
and the area centroid of the resulting polygon is taken with the shoelace
formula (polygon_centroid()). The inscribed polygon's centroid errs by
O(1/Noutline^2) (5e-6 px for a 50 px dot at 1440 points); a Richardson step
with the polygon of every other vertex removes that term, leaving < 1e-8 px
(tests/test_centroids.py checks against the exact conic centre for a
pinhole).

What this centroid means: it is the centroid of the dot's image when the dot
is uniformly dark on a uniform board and each pixel records the area average
of the albedo over its footprint (as camval's renderers do), because then a
pixel's darkness (board level - intensity) is proportional to the dot area it
covers, and the darkness-weighted centroid is the area centroid. Shading,
vignetting, blur or a non-linear sensor response weight the dot unevenly and
move its image centroid away from this value; so does the sampling of the
image into pixels (an error below about 0.03 r^-1.5 px for a dot of radius r
px, measured ~0.001 px at r = 20 px).

Points behind the camera or outside the model's domain give NaN (a dot gives
NaN if any point of its outline does).
'''

import numpy as np

from reference_models.poseutils import compose_Rt, transform_point_Rt

from .boards import TargetError

NOUTLINE_DEFAULT = 1440


def _check_Rt(Rt_cam_board):
    Rt = np.asarray(Rt_cam_board, dtype=np.float64)
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        raise TargetError(f"Rt_cam_board must be a finite (4,3) array (R on top, t last); "
                          f"got shape {Rt.shape}")
    R = Rt[:3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-9) or not np.linalg.det(R) > 0:
        raise TargetError("Rt_cam_board[:3] must be a rotation matrix (orthonormal, det +1)")
    return Rt


def board_to_ref(model, Rt_cam_board, p_board):
    r'''Board-frame points in the model's world frame

SYNOPSIS

    p_ref = board_to_ref(model, Rt_cam_board, p_board)   # p_board (...,3) -> (...,3)

Rt_ref_board = compose(model.Rt_ref_cam(), Rt_cam_board), as renderers use it.
'''
    Rt_ref_board = compose_Rt(model.Rt_ref_cam(), _check_Rt(Rt_cam_board))
    return transform_point_Rt(Rt_ref_board, np.asarray(p_board, dtype=np.float64))


def board_to_cam(Rt_cam_board, p_board):
    r'''Board-frame points in the camera frame: (...,3) -> (...,3)'''
    Rt = _check_Rt(Rt_cam_board)
    return np.asarray(p_board, dtype=np.float64) @ Rt[:3].T + Rt[3]


def projected_points(model, target, Rt_cam_board):
    r'''Projections of the target's surveyed points

SYNOPSIS

    q = projected_points(model, target, Rt_cam_board)   # (N,2); NaN where not imaged
'''
    return model.project(board_to_ref(model, Rt_cam_board, target.points()))


def polygon_centroid(q):
    r'''Area centroid of closed polygons (shoelace formula)

SYNOPSIS

    c = polygon_centroid(q)    # q (...,Nvertices,2) -> c (...,2)

The polygon closes from the last vertex to the first. Vertices are taken
relative to the first one to keep the sums well conditioned far from the
origin. A degenerate polygon (zero area) or a non-finite vertex gives NaN.
'''
    q = np.asarray(q, dtype=np.float64)
    q0 = q[..., :1, :]
    d = q - q0
    x, y = d[..., 0], d[..., 1]
    xn, yn = np.roll(x, -1, axis=-1), np.roll(y, -1, axis=-1)
    cross = x * yn - xn * y
    area2 = cross.sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cx = ((x + xn) * cross).sum(axis=-1) / (3.0 * area2)
        cy = ((y + yn) * cross).sum(axis=-1) / (3.0 * area2)
    c = np.stack((cx, cy), axis=-1) + q0[..., 0, :]
    bad = ~(np.abs(area2) > 0) | ~np.all(np.isfinite(q), axis=(-1, -2))
    c[bad] = np.nan
    return c


def expected_centroids(model, target, Rt_cam_board, Noutline=NOUTLINE_DEFAULT):
    r'''Exact image centroid of each projected dot

SYNOPSIS

    q = expected_centroids(model, target, Rt_cam_board)   # (N,2), kind "dots" only

The area centroid of each dot's projected circle outline (Noutline points, even);
see the module docstring for when this equals the centroid a detector
measures. NaN for a dot any of whose outline points is not imaged.
'''
    if target.kind != "dots":
        raise TargetError(f"expected_centroids() is defined for dot targets; target "
                          f"{target.name!r} is {target.kind!r}: use projected_points()")
    if int(Noutline) < 8 or int(Noutline) % 2:
        raise TargetError(f"Noutline must be an even number >= 8; got {Noutline}")
    outline = target.dot_outlines(Noutline)
    q = model.project(board_to_ref(model, Rt_cam_board, outline))
    # the inscribed polygon's centroid errs by c/Noutline^2: Richardson-extrapolate from
    # the polygon of every other vertex
    c = polygon_centroid(q)
    c_half = polygon_centroid(q[..., ::2, :])
    return c + (c - c_half) / 3.0


def centroid_bias(model, target, Rt_cam_board, Noutline=NOUTLINE_DEFAULT):
    r'''expected_centroids() - projected_points(): the correction of the paper's second pass

SYNOPSIS

    bias = centroid_bias(model, target, Rt_cam_board)   # (N,2) px
    q_centre_estimate = q_detected - bias
'''
    return (expected_centroids(model, target, Rt_cam_board, Noutline)
            - projected_points(model, target, Rt_cam_board))

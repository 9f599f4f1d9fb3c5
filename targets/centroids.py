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
the dot's circle outline is projected point by point and the area centroid
of the resulting polygon is taken with the shoelace formula
(polygon_centroid()). The inscribed polygon's centroid errs by O(1/Noutline^2)
(5e-6 px for a 50 px dot at 1440 points); a Richardson step with the polygon of
every other vertex removes that term, leaving an error c/Noutline^4
(tests/test_centroids.py checks against the exact conic centre for a pinhole).
By default the number of outline points follows from an error bound
(CENTROID_TOLERANCE_PX): the same projected points give the Richardson value
of half as many points, whose error is 16 times as large, so their difference
/ 15 estimates the error; the points double until it is below the bound
(128 points on the catalogue's cameras, within 4e-7 px of 5760).

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

import functools

import numpy as np

from reference_models.poseutils import compose_Rt, transform_point_Rt

from .boards import TargetError

# The error bound of expected_centroids() (px) when no Noutline is given: a hundredth of the
# smallest detection scatter harness.verdict resolves (DETECTION_RESOLUTION_PX, 1e-4 px),
# whose exact observations these are, and far below a renderer's sampling error on a dot
# centroid (~1e-3 px: module docstring)
CENTROID_TOLERANCE_PX = 1e-6
# the first number of outline points tried (a multiple of 4: the error estimate takes the
# Richardson value of half as many, from a polygon of a quarter), and the most: the error
# goes as 1/Noutline^4, 3.6e-6 px at 64 points on the widest catalogue camera (Rocky8
# hazcam CAHVOR), so 8192 points reach 1e-6 px for dots some 70 times as distorted
NOUTLINE_START = 128
NOUTLINE_MAX = 8192


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
The terms of the sums are computed by a compiled kernel
(targets._dot_kernels.polygon_terms, element by element as numpy would), the
sums by numpy: the calibrators' bias takes these centroids, and mrcal's fits
are chaotic in their last bits (harness/calibrators/mrcal_fit.py).
'''
    from . import _dot_kernels
    q = np.asarray(q, dtype=np.float64)
    shape = q.shape[:-2]
    n = q.shape[-2]
    qq = np.ascontiguousarray(q.reshape(-1, n, 2))
    cross, wx, wy = (np.empty(qq.shape[:2]) for _ in range(3))
    bad = np.empty(len(qq), bool)
    _dot_kernels.polygon_terms(qq, cross, wx, wy, bad)
    with np.errstate(divide="ignore", invalid="ignore"):   # (a non-finite vertex: NaN)
        area2 = cross.sum(axis=-1)
        cx = wx.sum(axis=-1) / (3.0 * area2)
        cy = wy.sum(axis=-1) / (3.0 * area2)
    c = np.stack((cx, cy), axis=-1) + qq[:, 0, :]
    c[bad | ~(np.abs(area2) > 0)] = np.nan
    return c.reshape(shape + (2,))


def expected_centroids(model, target, Rt_cam_board, Noutline=None,
                       tolerance=CENTROID_TOLERANCE_PX):
    r'''Exact image centroid of each projected dot

SYNOPSIS

    q = expected_centroids(model, target, Rt_cam_board)   # (N,2), kind "dots" only

The area centroid of each dot's projected circle outline; see the module
docstring for when this equals the centroid a detector measures. Noutline
(even): that many outline points. None: NOUTLINE_START points, doubled until
the estimated error of every dot's centroid is below tolerance px (module
docstring; at most NOUTLINE_MAX points). NaN for a dot any of whose outline
points is not imaged.
'''
    if target.kind != "dots":
        raise TargetError(f"expected_centroids() is defined for dot targets; target "
                          f"{target.name!r} is {target.kind!r}: use projected_points()")
    if Noutline is not None:
        if int(Noutline) < 8 or int(Noutline) % 2:
            raise TargetError(f"Noutline must be an even number >= 8; got {Noutline}")
        return _richardson_centroid(_projected_outlines(model, target, Rt_cam_board,
                                                        Noutline))
    N = NOUTLINE_START
    while True:
        q = _projected_outlines(model, target, Rt_cam_board, N)
        c_half = polygon_centroid(q[..., ::2, :])
        c = _richardson_centroid(q, c_half)
        # the Richardson value of N/2 points errs 16 times as much as that of N (error
        # c/N^4): their difference is 15 times the error of c
        err = np.abs(c - _richardson_centroid(q[..., ::2, :], c=c_half)) / 15.0
        if not np.any(err > tolerance) or N >= NOUTLINE_MAX:
            return c
        N *= 2


def _projected_outlines(model, target, Rt_cam_board, Noutline):
    r'''(Ndots,Noutline,2) the projected outline points of every dot'''
    # model.project, not the compiled kernel (reference_models.kernels, within 1e-10 px):
    # the calibrators' bias correction takes these centroids, and mrcal's fits are chaotic
    # in 1e-10 px of them (harness/calibrators/mrcal_fit.py): the kernel moved 9 CAHVORE's
    # mrcal projection difference by 2.6 sigma, and (2026-11-28) 5-8 CAHVOR's mrcal fits
    # (judged, 0.0005 px) to a 0.108 px minimum
    return model.project(board_to_ref(model, Rt_cam_board, _dot_outlines(target, Noutline)))


@functools.lru_cache(maxsize=16)
def _dot_outlines(target, Noutline):
    r'''target.dot_outlines(Noutline), made once per target and count (read-only): a fit's
bias takes them for every pose of every pass'''
    p = target.dot_outlines(Noutline)
    p.setflags(write=False)
    return p


def _richardson_centroid(q, c_half=None, c=None):
    r'''(...,2) the polygons' centroids Richardson-extrapolated from every other vertex
(c_half, c: the centroids of every other vertex and of all, when the caller has them)'''
    # the inscribed polygon's centroid errs by c/Noutline^2: the polygon of every other
    # vertex errs 4 times as much
    c = polygon_centroid(q) if c is None else c
    c_half = polygon_centroid(q[..., ::2, :]) if c_half is None else c_half
    return c + (c - c_half) / 3.0


def centroid_bias(model, target, Rt_cam_board, Noutline=None):
    r'''expected_centroids() - projected_points(): the correction of the paper's second pass

SYNOPSIS

    bias = centroid_bias(model, target, Rt_cam_board)   # (N,2) px
    q_centre_estimate = q_detected - bias
'''
    return (expected_centroids(model, target, Rt_cam_board, Noutline)
            - projected_points(model, target, Rt_cam_board))

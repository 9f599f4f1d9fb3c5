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
the dot's circle outline is projected at Noutline points equally spaced in
angle, and the area centroid of the closed curve they sample is taken by Green's
theorem (outline_centroid()): A = 1/2 \oint (x y' - y x'), A c_x = 1/2 \oint x^2 y',
A c_y = -1/2 \oint y^2 x', with the derivatives from the samples' Fourier series and
the integrals by the trapezoid rule. For a smooth periodic curve both converge
exponentially in Noutline (the error falls with the curve's Fourier coefficients
beyond about Noutline/3: the integrands are cubic in the samples), where the
inscribed polygon's centroid errs by O(1/Noutline^2): 16 points are within 1e-11 px
of a 2048-point Richardson-extrapolated polygon on every catalogue camera, at the
corner poses of every one. By default the number of points follows from an error
bound (CENTROID_TOLERANCE_PX): the centroid of every other sample, whose error
dominates that of all of them when the convergence is exponential, is compared with
it, and the points double until the two agree within the bound (16 points on the
catalogue's cameras; tests/test_centroids.py checks against the exact conic centre
for a pinhole and against a fine polygon for a fisheye).

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
# the first number of outline points tried (its every other sample, 8 points, gives the error
# estimate), and the most: a dot whose outline needs more than 4096 samples to reach the
# bound is some 10^3 times as distorted across its width as any catalogue camera makes one
NOUTLINE_START = 16
NOUTLINE_MAX = 4096


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
For a polygon; a smooth curve's samples take outline_centroid, exponentially
more accurate (the inscribed polygon errs by O(1/Nvertices^2)).
'''
    q = np.asarray(q, dtype=np.float64)
    q0 = q[..., :1, :]
    d = q - q0
    x, y = d[..., 0], d[..., 1]
    xn, yn = np.roll(x, -1, axis=-1), np.roll(y, -1, axis=-1)
    cross = x * yn - xn * y
    with np.errstate(divide="ignore", invalid="ignore"):   # (a non-finite vertex: NaN)
        area2 = cross.sum(axis=-1)
        cx = ((x + xn) * cross).sum(axis=-1) / (3.0 * area2)
        cy = ((y + yn) * cross).sum(axis=-1) / (3.0 * area2)
    c = np.stack((cx, cy), axis=-1) + q0[..., 0, :]
    c[~(np.abs(area2) > 0) | ~np.all(np.isfinite(q), axis=(-1, -2))] = np.nan
    return c


def expected_centroids(model, target, Rt_cam_board, Noutline=None,
                       tolerance=CENTROID_TOLERANCE_PX):
    r'''Exact image centroid of each projected dot

SYNOPSIS

    q = expected_centroids(model, target, Rt_cam_board)   # (N,2), kind "dots" only

The area centroid of each dot's projected circle outline (outline_centroid); see
the module docstring for when this equals the centroid a detector measures.
Noutline (even): that many outline points. None: NOUTLINE_START points, doubled
until every dot's centroid from every other point agrees with it within tolerance
px (module docstring; at most NOUTLINE_MAX points). NaN for a dot any of whose
outline points is not imaged.
'''
    if target.kind != "dots":
        raise TargetError(f"expected_centroids() is defined for dot targets; target "
                          f"{target.name!r} is {target.kind!r}: use projected_points()")
    if Noutline is not None:
        if int(Noutline) < 8 or int(Noutline) % 2:
            raise TargetError(f"Noutline must be an even number >= 8; got {Noutline}")
        return outline_centroid(_projected_outlines(model, target, Rt_cam_board,
                                                    int(Noutline)))
    N = NOUTLINE_START
    while True:
        q = _projected_outlines(model, target, Rt_cam_board, N)
        c = outline_centroid(q)
        # exponential convergence: the error of N points is far below that of N/2, which
        # their difference measures
        err = np.abs(c - outline_centroid(q[..., ::2, :]))
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


def outline_centroid(q):
    r'''Area centroid of smooth closed curves from samples equally spaced in their parameter

SYNOPSIS

    c = outline_centroid(q)    # q (...,N,2) -> c (...,2)

q[..., k, :] is the curve at parameter 2 pi k / N (N >= 3), going round once, either
way. Green's theorem with the derivatives from the samples' discrete Fourier series
(_fourier_derivative) and the integrals by the trapezoid rule, which is exponentially
accurate for a smooth periodic curve (module docstring); for a polygon's corners it is not:
polygon_centroid is. The samples are taken relative to their mean, near the
centroid, to keep the cubic sums well conditioned far from the origin. A curve with
a non-finite sample or no area gives NaN.
'''
    q = np.asarray(q, dtype=np.float64)
    n = q.shape[-2]
    if n < 3:
        raise TargetError(f"a closed curve needs at least 3 samples; got {n}")
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = q.mean(axis=-2, keepdims=True)
        d = q - mean
        x, y = d[..., 0], d[..., 1]
        D = _fourier_derivative(n)
        dx, dy = x @ D, y @ D
        area = 0.5 * (x * dy - y * dx).sum(axis=-1)
        cx = 0.5 * (x * x * dy).sum(axis=-1) / area
        cy = -0.5 * (y * y * dx).sum(axis=-1) / area
    c = np.stack((cx, cy), axis=-1) + mean[..., 0, :]
    c[~(np.abs(area) > 0) | ~np.all(np.isfinite(q), axis=(-1, -2))] = np.nan
    return c


@functools.lru_cache(maxsize=16)
def _fourier_derivative(n):
    r'''(n,n) the derivative, per unit of parameter (period 2 pi), of the trigonometric
interpolant of n equally spaced samples, at the samples: v @ D for samples v (...,n)

The Fourier differentiation matrix (Trefethen, Spectral Methods in MATLAB, ch. 3),
the same numbers as differentiating the samples' discrete Fourier series (the
Nyquist term's derivative taken as 0 for even n), as one small product instead of
two FFTs: D[j, k] = 1/2 (-1)^(k-j) cot((k-j) pi/n) for even n, 1/2 (-1)^(k-j) /
sin((k-j) pi/n) for odd n, 0 on the diagonal. Read-only.'''
    k = np.arange(n)
    m = k[None, :] - k[:, None]          # D[j, k]: the weight of sample j in the derivative at k
    h = m * (np.pi / n)
    with np.errstate(divide="ignore", invalid="ignore"):
        sign = np.where(m % 2 == 0, 1.0, -1.0)
        D = 0.5 * sign * (np.cos(h) / np.sin(h) if n % 2 == 0 else 1.0 / np.sin(h))
    D[m == 0] = 0.0
    D.setflags(write=False)
    return D


def centroid_bias(model, target, Rt_cam_board, Noutline=None):
    r'''expected_centroids() - projected_points(): the correction of the paper's second pass

SYNOPSIS

    bias = centroid_bias(model, target, Rt_cam_board)   # (N,2) px
    q_centre_estimate = q_detected - bias
'''
    return (expected_centroids(model, target, Rt_cam_board, Noutline)
            - projected_points(model, target, Rt_cam_board))

r'''The projected outlines of a planar target: where the ray caster's edge pixels are

SYNOPSIS

    from renderers.raycast_outlines import project_outlines
    ol = project_outlines(model, Rt_cam_board, compiled_pattern)   # Outlines or None
    # ol.q (N,2) image points of the polylines, ol.starts (Npolylines+1,),
    # ol.closed (Npolylines,) bool, ol.margin (Npolylines,) px

Every boundary of the pattern where the albedo may change (the board
rectangle, the grid lines between cells of different materials, the circles)
is sampled on the board plane and projected through the camera's exact
3D -> 2D projection (reference_models.kernels.project_packed: the model's own
projection, CAHVORE's iterative one included, noncentral pupil and all). A
pixel whose closed square comes within `margin` of a polyline is an edge pixel
(renderers._raycast_kernels._mark_chord); every other pixel lies in a region
of the image that no outline crosses, so its whole area is one material.

Why that is enough. The pixels that see the board are the image of the board
under projection. When the whole board lies in front of the camera
(renderers.raycast.board_image_box: every corner at positive range, the
outline and a grid of interior points projecting finitely; a convex board in
a convex front half-space or cone stays inside the model's domain),
projection is continuous and one to one on it (a board point lies on one
pixel's ray; two board points on one ray would put that ray in the plane), so
it maps each region of the board between boundaries onto a region of the
image bounded by the images of those boundaries, and the region of the image
outside the board's outline sees background (rays beyond the plane's horizon
and rays that meet the plane off the board alike). This holds for a
noncentral CAHVORE: its projection is still a function of the 3-D point, the
pixel whose (shifted-origin) ray passes through it. Where it does not hold -
a corner behind the camera, an outline point beyond a fisheye's field (NaN
projection), a projection that fails its grid check - project_outlines
returns None and the renderer tests pixels as before (renderers.raycast). So
does a projection that is not one to one on the outline: a distortion
polynomial past its maximum (a CAHVOR or CAHVORE whose R makes chi (1 + R0 +
R1 chi^2 + R2 chi^4) fall again) folds the points beyond it back into the
image, where the pixels' rays see other points; every outline point is
therefore checked to be seen by the ray of the pixel it projects to (_round_trip),
except where no fold can happen: a CAHVOR whose polynomial chi (1 + R0 + R1 chi^2 +
R2 chi^4) increases for every chi >= 0 (_cahvor_monotone) maps each direction in
front of O to one chi, hence to one pixel, and each pixel's ray back to the one root
(the same rays, the round trip would pass: it costs ~13000 rays, 1.4 ms of a
1024x1024 navcam's render, the largest serial part), and where the board lies short
of the fold: the polynomial increasing up to a bound of the chi of every board point,
from the corners' angles to O and, for a noncentral CAHVORE, the pupil shift
(_fold_free; the round trip of camera 1's AprilTag grid costs 9.3 ms per image,
its dots 4.1 ms).
The board is convex and the region of angles from O where the projection is
one to one is a cone about O (convex up to 90 degrees; beyond, its
complement is a cone about -O that a board with every corner in front of the
camera does not reach), so the outline inside it keeps the board inside it.
Outline points outside the image are kept (a polyline leaving the image and
coming back still separates what it separates); pixels outside are not marked.

The chord error. A polyline sampled at parameter step h deviates from the
projected curve q(t) by at most the sagitta max |q''| h^2 / 8 of each chord.
h^2 q'' is the second difference q[i+1] - 2 q[i] + q[i-1] of the samples to
third order in the step; the bound of chord i takes the largest second
difference of the four around it and doubles it (the third-order term is
below a few per cent of the second at steps <= MAX_STEP_PX: the curvature of
a projected outline changes over tens of pixels), so a chord's margin is
max |D2| / 4. A feature is resampled finer until every step is <= MAX_STEP_PX
and every margin <= MAX_SAGITTA_PX; its margin is then its largest chord
bound plus PROJECTION_SLOP_PX (the projection agrees with the reference model
to < 1e-10 px, tests/test_kernels.py). The margins come out at 1e-3 px and
less for dots of tens of pixels, so the edge pixels are, to within that, the
pixels the outlines cross.
'''

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from reference_models.kernels import (
    _C,
    _E,
    _KIND,
    _L,
    _O,
    _R,
    KIND_CAHV,
    KIND_CAHVORE,
    _ray_warm_chi,
    _warm_coefficients,
    project_point,
)
from renderers._raycast_kernels import _hit

# the largest step between neighbouring outline points (px): keeps the second differences
# local estimates of the curvature
MAX_STEP_PX = 2.0
# a feature is sampled until its chords' bound is below this (px)
MAX_SAGITTA_PX = 0.02
# added to every margin: the projection's own error is < 1e-10 px
PROJECTION_SLOP_PX = 1e-6
# a pixel's ray meets the board within this fraction of the board's size of the point
# projected to it (exact rays: ~1e-12; a fold in the projection: far more)
ROUND_TRIP_TOLERANCE = 1e-7
# _fold_free: a CAHVORE board point's theta is taken within this of its angle from O (rad)
FOLD_THETA_SLACK = 0.1
# a feature needing more points than this is not outlined (the renderer tests its pixels)
MAX_POINTS = 1 << 20


@dataclass(frozen=True, eq=False)
class Outlines:
    r'''Polylines in the image: points q[starts[i]:starts[i+1]], closed or open, each with
the margin (px) that holds its projected curve'''

    q: np.ndarray        # (N,2) float64
    starts: np.ndarray   # (Npolylines+1,) int64
    closed: np.ndarray   # (Npolylines,) uint8
    margin: np.ndarray   # (Npolylines,) float64


def board_features(cp):
    r'''The boundaries of a compiled pattern on the board plane: (segments, circles),
segments (Ns,4) x0 y0 x1 y1 (board rectangle, runs of cell edges between different
materials), circles (Nc,3) cx cy r; computed once per compiled pattern (cp.derived;
an AprilTag grid's runs of cell edges cost ~10 ms)'''
    features = cp.derived.get("board_features")
    if features is None:
        features = cp.derived["board_features"] = _board_features(cp)
    return features


def _board_features(cp):
    from renderers._raycast_kernels import F_CELLS, F_CIRCLES, I_OFFSETS
    f, ii = cp.f, cp.ii
    xmin, xmax, ymin, ymax = f[:4]
    segs = [(xmin, ymin, xmax, ymin), (xmax, ymin, xmax, ymax), (xmax, ymax, xmin, ymax),
            (xmin, ymax, xmin, ymin)]
    cs = f[F_CELLS + 2]
    if cs > 0.0:
        ox, oy = f[F_CELLS], f[F_CELLS + 1]
        nx, ny = int(f[F_CELLS + 3]), int(f[F_CELLS + 4])
        M = ii[ii[I_OFFSETS]:ii[I_OFFSETS + 1]].reshape(ny + 2, nx + 2)
        # vertical grid line i (x = ox + i cs) between ring columns i and i + 1
        for i in range(nx + 1):
            segs += [(ox + i * cs, oy + a * cs, ox + i * cs, oy + b * cs)
                     for a, b in _runs(M[1:-1, i] != M[1:-1, i + 1])]
        for j in range(ny + 1):
            segs += [(ox + a * cs, oy + j * cs, ox + b * cs, oy + j * cs)
                     for a, b in _runs(M[j, 1:-1] != M[j + 1, 1:-1])]
    circles = f[F_CIRCLES:].reshape(-1, 3)
    return np.array(segs, dtype=np.float64).reshape(-1, 4), circles


def _runs(differ):
    r'''(start, end) of the runs of True in a 1-D bool array'''
    d = np.diff(np.concatenate(([0], differ.astype(np.int8), [0])))
    return zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True)


@njit(cache=True, error_model="numpy")
def _feature_points(segs, circles, k, n, Rt_ref_board, cam, xy, q):
    r"""The points of feature k (segment k: n + 1 points from end to end; circle k - Nsegs:
n points around) on the board, into xy, and projected into the image, into q; returns
whether every point projects finitely"""
    ns = segs.shape[0]
    finite = True
    npts = n + 1 if k < ns else n
    for i in range(npts):
        if k < ns:
            t = i / n
            x = segs[k, 0] + t * (segs[k, 2] - segs[k, 0])
            y = segs[k, 1] + t * (segs[k, 3] - segs[k, 1])
        else:
            a = i * (2.0 * math.pi / n)
            x = circles[k - ns, 0] + circles[k - ns, 2] * math.cos(a)
            y = circles[k - ns, 1] + circles[k - ns, 2] * math.sin(a)
        xy[i, 0] = x
        xy[i, 1] = y
        qx, qy = project_point(cam,
                               Rt_ref_board[0, 0] * x + Rt_ref_board[0, 1] * y + Rt_ref_board[3, 0],
                               Rt_ref_board[1, 0] * x + Rt_ref_board[1, 1] * y + Rt_ref_board[3, 1],
                               Rt_ref_board[2, 0] * x + Rt_ref_board[2, 1] * y + Rt_ref_board[3, 2])
        q[i, 0] = qx
        q[i, 1] = qy
        finite = finite and math.isfinite(qx) and math.isfinite(qy)
    return finite


@njit(cache=True, error_model="numpy")
def _chord_bound(q, closed, d2):
    r"""(largest step, largest chord bound) of the polyline q (see the module docstring);
d2: scratch of q's length"""
    N = q.shape[0]
    last = N - 1
    step = 0.0
    for g in range(N):
        nxt = g + 1 if g < last else (0 if closed else last)
        prv = g - 1 if g > 0 else (last if closed else 0)
        ax = q[nxt, 0] - q[g, 0]
        ay = q[nxt, 1] - q[g, 1]
        step = max(step, math.sqrt(ax * ax + ay * ay))
        bx = q[nxt, 0] - 2.0 * q[g, 0] + q[prv, 0]
        by = q[nxt, 1] - 2.0 * q[g, 1] + q[prv, 1]
        d2[g] = math.sqrt(bx * bx + by * by)
    if not closed:
        # an open polyline's ends have no second difference: their neighbour's
        d2[0] = d2[min(1, last)]
        d2[last] = d2[max(last - 1, 0)]
    w = 0.0
    for g in range(N):
        # chord g (points g, g + 1): the second differences at its points and their
        # neighbours
        nxt = g + 1 if g < last else (0 if closed else last)
        prv = g - 1 if g > 0 else (last if closed else 0)
        nn = nxt + 1 if nxt < last else (0 if closed else last)
        w = max(w, max(max(d2[prv], d2[g]), max(d2[nxt], d2[nn])))
    return step, w / 4.0


@njit(cache=True, error_model="numpy")
def _outline_polylines(segs, circles, Rt_ref_board, cam, max_points):
    r"""The polyline of each feature (segments, then circles), sampled from 16 (segments)
and 32 (circles) intervals up, growing by the shortfall, until it meets MAX_STEP_PX and
MAX_SAGITTA_PX: (status, xy, q, starts, margin), status 0, or -1 where a point does not
project finitely, -2 where the polylines would need more than max_points points"""
    ns = segs.shape[0]
    nf = ns + circles.shape[0]
    starts = np.zeros(nf + 1, dtype=np.int64)
    margin = np.empty(nf)
    cap = 64 * nf + 64
    xy = np.empty((cap, 2))
    q = np.empty((cap, 2))
    d2 = np.empty(cap)
    pos = 0
    for k in range(nf):
        n = 16 if k < ns else 32
        while True:
            npts = n + 1 if k < ns else n
            if pos + npts > max_points:
                return -2, xy, q, starts, margin
            if pos + npts > cap:
                cap = max(2 * cap, pos + npts)
                xy2 = np.empty((cap, 2))
                q2 = np.empty((cap, 2))
                # element by element: an array-to-slice copy compiles numba's shape-mismatch
                # message formatting (~5 CPU-s on a fresh clone)
                for i in range(pos):
                    xy2[i, 0] = xy[i, 0]
                    xy2[i, 1] = xy[i, 1]
                    q2[i, 0] = q[i, 0]
                    q2[i, 1] = q[i, 1]
                xy = xy2
                q = q2
                d2 = np.empty(cap)
            if not _feature_points(segs, circles, k, n, Rt_ref_board, cam, xy[pos:pos + npts],
                                   q[pos:pos + npts]):
                return -1, xy, q, starts, margin
            step, bound = _chord_bound(q[pos:pos + npts], k >= ns, d2)
            # a step or a sagitta too large: more points (the sagitta falls as 1/n^2)
            grow = max(step / MAX_STEP_PX, math.sqrt(bound / MAX_SAGITTA_PX))
            if not grow > 1.0:
                margin[k] = bound + PROJECTION_SLOP_PX
                pos += npts
                starts[k + 1] = pos
                break
            n = int(math.ceil(n * grow * 1.1))
    return 0, xy[:pos], q[:pos], starts, margin


def _round_trip(cam, Rt_ref_board, q, xy, starts):
    r"""Whether the ray of each pixel q meets the board plane at the board point xy it
was projected from (to ROUND_TRIP_TOLERANCE of the board's size): false where the
projection folds (a distortion polynomial past its maximum maps points beyond it
back into the image, where the pixels' rays see other points)"""
    import mrcal
    Rt = mrcal.invert_Rt(Rt_ref_board)
    R, t = Rt[:3], Rt[3]
    xf = np.concatenate((R.ravel(), R @ cam[0:3] + t, R @ cam[12:15]))
    size = float(np.ptp(xy, axis=0).max())
    return bool(_round_trip_kernel(cam, xf, q, xy, starts, ROUND_TRIP_TOLERANCE * size))


@njit(parallel=True, cache=True, error_model="numpy")
def _round_trip_kernel(cam, xf, q, xy, starts, tolerance):
    r"""_round_trip's test, polyline by polyline (in parallel: ~13000 rays for the dots
board on a 1024x1024 navcam, 1.4 ms on one core, the largest serial part of a render),
point by point: exact rays (each Newton solve started from the previous point's
prediction: the same rays, renderers._raycast_kernels)"""
    central = cam[_KIND] == KIND_CAHV
    npoly = starts.shape[0] - 1
    bad = np.zeros(npoly, dtype=np.uint8)
    for p in prange(npoly):
        warm = (math.nan, 0.0, 0.0, 0.0)
        for i in range(starts[p], starts[p + 1]):
            s, vx, vy, vz, u, chi = _ray_warm_chi(cam, q[i, 0], q[i, 1], warm)
            if not central:
                warm = _warm_coefficients(cam, u, chi)
            ok, x, y = _hit(xf, s, vx, vy, vz)
            if not (ok and abs(x - xy[i, 0]) <= tolerance and abs(y - xy[i, 1]) <= tolerance):
                bad[p] = 1
                break
    return not np.any(bad)


def _cahvor_monotone(model):
    r"""Whether model is a CAHVOR whose distortion cannot fold: g(chi) = chi (1 + R0 + R1
chi^2 + R2 chi^4) strictly increasing on chi >= 0, i.e. g' = 1 + R0 + 3 R1 t + 5 R2 t^2
> 0 for every t = chi^2 >= 0

Then projection is one to one on a board in front of the camera (a board point's
direction from C is unique, g maps its chi to one u, the azimuth about O is kept, and
the pinhole part is one to one in front of A: project_point gives NaN behind it), and
g(chi) = u has one root, the one the pixel's ray is solved for."""
    if model.family != "CAHVOR":
        return False
    r0, r1, r2 = (float(v) for v in np.asarray(model.R, dtype=np.float64))
    a, b, c = 1.0 + r0, 3.0 * r1, 5.0 * r2
    if not (a > 0.0 and c >= 0.0):
        return False
    if b >= 0.0:
        return True
    # a parabola opening upwards (c > 0) with its vertex at t = -b / 2c > 0
    return c > 0.0 and a - b * b / (4.0 * c) > 0.0


def _fold_free(cam, Rt_ref_board, rect):
    r"""Whether no point of the board rect (xmin, xmax, ymin, ymax) lies beyond a fold of
a CAHVOR or CAHVORE cam (packed): g(chi) = chi (1 + R0 + R1 chi^2 + R2 chi^4) strictly
increasing for chi in [0, chi_max], chi_max bounding the chi of every board point

Then every outline point passes the round trip (_round_trip), which is skipped. A
board point p (d = p - C at angle alpha from O) projects at the theta of CAHVORE's
equation r sin(theta - alpha) = (theta - sin theta) E(theta) (r = |d|; CAHVOR and E = 0:
theta = alpha), and every point of the line of angle theta through C + s(theta) O at
p's azimuth solves it with that theta: it is the ray of theta's pixel. That pixel's
ray is solved back from its u = g(chi(theta)); when g increases on [0, chi_max] (chi
increases with theta in the model's domain) the root is that chi, so the ray is p's
line and meets the board plane at p. The bound: alpha over the board is largest at a
corner (the points within an angle a < 90 degrees of O from C form a convex cone:
alpha is quasi-convex on the rectangle), and |theta - alpha| <= asin(delta) with delta
= (Theta - sin Theta) max|E| / r_min (Theta = pi / (2 |L|), beyond which a point does
not project; r_min the distance from C to the board), the projection's Newton solve
starting at alpha. chi_max takes 10% more than that bound. False (the round trip
runs) for a board corner 90 degrees or more from O, or delta >= 0.1 (a pupil shift
comparable to the board's distance). The paper's 5120x3840 CAHVOREs (R2 < 0: g falls
again past chi ~ 2.2, about 106 degrees from O) see their boards within ~50 degrees."""
    C = cam[_C:_C + 3]
    O = cam[_O:_O + 3]
    r0, r1, r2 = cam[_R], cam[_R + 1], cam[_R + 2]
    xmin, xmax, ymin, ymax = (float(v) for v in rect)
    R, t = Rt_ref_board[:3], Rt_ref_board[3]
    corners = np.array([[xmin, ymin, 0.0], [xmax, ymin, 0.0], [xmax, ymax, 0.0],
                        [xmin, ymax, 0.0]]) @ R.T + t
    d = corners - C
    zeta = d @ O
    ell = np.linalg.norm(d - zeta[:, None] * O, axis=-1)
    alpha = float(np.arctan2(ell, zeta).max())
    if not (alpha < 0.5 * math.pi):
        return False
    theta = alpha
    if cam[_KIND] == KIND_CAHVORE:
        L = float(cam[_L])
        # theta within FOLD_THETA_SLACK of alpha: the pupil term bounded up to that angle
        top = alpha + FOLD_THETA_SLACK
        if not (top * abs(L) < 0.5 * math.pi):
            return False
        e = np.abs(cam[_E:_E + 3])
        emax = e[0] + e[1] * top ** 2 + e[2] * top ** 4
        # the distance from C to the rectangle: C in board coordinates, clamped into it
        cb = R.T @ (C - t)
        near = np.array([min(max(cb[0], xmin), xmax), min(max(cb[1], ymin), ymax), 0.0])
        rmin = float(np.linalg.norm(cb - near))
        delta = (top - math.sin(top)) * emax / rmin if rmin > 0.0 else math.inf
        if not (delta < math.sin(FOLD_THETA_SLACK)):
            return False
        theta = alpha + math.asin(delta)
        chi = (math.tan(L * theta) / L if L > 1e-15 else
               math.sin(L * theta) / L if L < -1e-15 else theta)
    else:
        chi = math.tan(theta)
    tmax = (1.1 * chi) ** 2
    # g'(t = chi^2) = 1 + R0 + 3 R1 t + 5 R2 t^2 > 0 on [0, tmax]: at both ends and at the
    # parabola's vertex when it lies inside
    def gp(t):
        return 1.0 + r0 + 3.0 * r1 * t + 5.0 * r2 * t * t
    ok = gp(0.0) > 0.0 and gp(tmax) > 0.0
    if ok and r2 != 0.0:
        tv = -3.0 * r1 / (10.0 * r2)
        if 0.0 < tv < tmax:
            ok = gp(tv) > 0.0
    return bool(ok)


def warm_fold_check():
    r"""Compile (or load) the fold check's kernel (_round_trip_kernel) on a one-point
polyline, with the argument types of a render's call

A render skips the check where the board lies short of the fold (_fold_free): none of
the paper's renders calls it, so a warm-up that only renders (harness.warmup) would
leave it uncompiled, and the cache check of compiled_entry_points() would ask for the
warm-up again in every campaign."""
    from reference_models.kernels import NCAM
    pts = np.zeros((4, 2))[:1]       # a row slice, as _outline_polylines' q[:pos]
    _round_trip_kernel(np.zeros(NCAM), np.zeros(15), pts, pts.copy(),
                       np.array([0, 1], dtype=np.int64), 1.0)


def compiled_entry_points():
    r"""The compiled kernels here (numba dispatchers): what harness.warmup's cache checks
read"""
    return (_outline_polylines, _round_trip_kernel)


def project_outlines(model, Rt_cam_board, cp, *, Rt_ref_board=None, cam=None):
    r"""The projected outlines of a compiled pattern (Outlines), or None where the image of
the board is not known to be bounded by them (see the module docstring); Rt_ref_board
(compose(model.Rt_ref_cam(), Rt_cam_board)) and cam (the packed model) may be passed by
a caller that has them"""
    import mrcal

    from reference_models import kernels
    segs, circles = board_features(cp)
    if Rt_ref_board is None:
        Rt_ref_board = mrcal.compose_Rt(model.Rt_ref_cam(), np.asarray(Rt_cam_board, float))
    if cam is None:
        cam = kernels.pack_model(model)
    status, xy, q, starts, margin = _outline_polylines(segs, circles, Rt_ref_board, cam,
                                                       MAX_POINTS)
    if status != 0:
        return None
    closed = np.concatenate((np.zeros(len(segs), np.uint8), np.ones(len(circles), np.uint8)))
    if not (model.family == "CAHV" or _cahvor_monotone(model)
            or _fold_free(cam, Rt_ref_board, cp.f[:4])
            or _round_trip(cam, Rt_ref_board, q, xy, starts)):
        return None
    return Outlines(q=q, starts=starts, closed=closed, margin=margin)

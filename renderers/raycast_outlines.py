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
(renderers._raycast_kernels.mark_outlines); every other pixel lies in a region
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
therefore checked to be seen by the ray of the pixel it projects to (_round_trip).
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
from numba import njit

from reference_models.kernels import _KIND, KIND_CAHV, _ray_warm_chi, _warm_coefficients
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
materials), circles (Nc,3) cx cy r'''
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


def _sample(segs, circles, nseg, ncirc):
    r"""Board points of every feature at its number of intervals, in one array: segment k
nseg[k] + 1 points (open), circle k ncirc[k] points (closed); returns (xy, sizes)"""
    sizes = np.concatenate((nseg + 1, ncirc))
    feature = np.repeat(np.arange(len(sizes)), sizes)
    starts = np.concatenate(([0], np.cumsum(sizes)))
    i = np.arange(starts[-1]) - starts[feature]
    xy = np.empty((starts[-1], 2))
    ns = starts[len(segs)]
    if ns:
        k = feature[:ns]
        t = i[:ns] / nseg[k]
        s = segs[k]
        xy[:ns, 0] = s[:, 0] + t * (s[:, 2] - s[:, 0])
        xy[:ns, 1] = s[:, 1] + t * (s[:, 3] - s[:, 1])
    if len(circles):
        k = feature[ns:] - len(segs)
        a = i[ns:] * (2.0 * math.pi / ncirc[k])
        c = circles[k]
        xy[ns:, 0] = c[:, 0] + c[:, 2] * np.cos(a)
        xy[ns:, 1] = c[:, 1] + c[:, 2] * np.sin(a)
    return xy, sizes


def _chord_bounds(q, sizes, closed):
    r"""(largest step, largest chord bound) of each polyline (see the module docstring)"""
    feature = np.repeat(np.arange(len(sizes)), sizes)
    starts = np.concatenate(([0], np.cumsum(sizes)))
    g = np.arange(len(q))
    first = starts[feature]
    last = starts[feature + 1] - 1
    cl = closed[feature].astype(bool)
    nxt = np.where(g < last, g + 1, np.where(cl, first, last))
    prv = np.where(g > first, g - 1, np.where(cl, last, first))
    step = np.linalg.norm(q[nxt] - q, axis=-1)
    d2 = np.linalg.norm(q[nxt] - 2.0 * q + q[prv], axis=-1)
    # an open polyline's ends have no second difference: their neighbour's
    ends = ~cl & ((g == first) | (g == last))
    d2[ends & (g == first)] = d2[np.minimum(nxt, last)][ends & (g == first)]
    d2[ends & (g == last)] = d2[prv][ends & (g == last)]
    # chord g (points g, nxt): the second differences at its points and their neighbours
    w = np.maximum(np.maximum(d2[prv], d2), np.maximum(d2[nxt], d2[nxt[nxt]]))
    return np.maximum.reduceat(step, starts[:-1]), np.maximum.reduceat(w, starts[:-1]) / 4.0


def _round_trip(cam, Rt_ref_board, q, xy):
    r"""Whether the ray of each pixel q meets the board plane at the board point xy it
was projected from (to ROUND_TRIP_TOLERANCE of the board's size): false where the
projection folds (a distortion polynomial past its maximum maps points beyond it
back into the image, where the pixels' rays see other points)"""
    import mrcal
    Rt = mrcal.invert_Rt(Rt_ref_board)
    R, t = Rt[:3], Rt[3]
    xf = np.concatenate((R.ravel(), R @ cam[0:3] + t, R @ cam[12:15]))
    size = float(np.ptp(xy, axis=0).max())
    return bool(_round_trip_kernel(cam, xf, q, xy, ROUND_TRIP_TOLERANCE * size))


@njit(cache=True, error_model="numpy")
def _round_trip_kernel(cam, xf, q, xy, tolerance):
    r"""_round_trip's test, point by point: exact rays (each Newton solve started from the
previous point's prediction: the same rays, renderers._raycast_kernels)"""
    central = cam[_KIND] == KIND_CAHV
    warm = (math.nan, 0.0, 0.0, 0.0)
    for i in range(q.shape[0]):
        s, vx, vy, vz, u, chi = _ray_warm_chi(cam, q[i, 0], q[i, 1], warm)
        if not central:
            warm = _warm_coefficients(cam, u, chi)
        ok, x, y = _hit(xf, s, vx, vy, vz)
        if not (ok and abs(x - xy[i, 0]) <= tolerance and abs(y - xy[i, 1]) <= tolerance):
            return False
    return True


def compiled_entry_points():
    r"""The compiled kernels here (numba dispatchers): what harness.warmup's cache checks
read"""
    return (_round_trip_kernel,)


def project_outlines(model, Rt_cam_board, cp):
    r"""The projected outlines of a compiled pattern (Outlines), or None where the image of
the board is not known to be bounded by them (see the module docstring)"""
    import mrcal

    from reference_models import kernels
    segs, circles = board_features(cp)
    Rt_ref_board = mrcal.compose_Rt(model.Rt_ref_cam(), np.asarray(Rt_cam_board, float))
    R, t = Rt_ref_board[:3], Rt_ref_board[3]
    cam = kernels.pack_model(model)
    nseg = np.full(len(segs), 16, dtype=np.int64)
    ncirc = np.full(len(circles), 32, dtype=np.int64)
    closed = np.concatenate((np.zeros(len(segs), np.uint8), np.ones(len(circles), np.uint8)))
    while True:
        xy, sizes = _sample(segs, circles, nseg, ncirc)
        if len(xy) > MAX_POINTS:
            return None
        p = xy @ R[:, :2].T + t
        q = kernels.project_packed(cam, p)
        if not np.all(np.isfinite(q)):
            return None
        step, bound = _chord_bounds(q, sizes, closed)
        # a step or a sagitta too large: more points (the sagitta falls as 1/n^2)
        grow = np.maximum(step / MAX_STEP_PX, np.sqrt(bound / MAX_SAGITTA_PX))
        if not np.any(grow > 1.0):
            if not (model.family == "CAHV" or _round_trip(cam, Rt_ref_board, q, xy)):
                return None
            return Outlines(q=q, starts=np.concatenate(([0], np.cumsum(sizes))),
                            closed=closed, margin=bound + PROJECTION_SLOP_PX)
        intervals = sizes - 1 + closed
        n = np.where(grow > 1.0, np.ceil(intervals * grow * 1.1), intervals).astype(np.int64)
        nseg = n[:len(segs)]
        ncirc = n[len(segs):]

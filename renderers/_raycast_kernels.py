r'''numba kernels of the exact ray-cast renderer (float64, fastmath off)

SYNOPSIS

    from reference_models import kernels
    cam = kernels.pack_model(model)                          # (NCAM,) float64
    mark_outlines(q, starts, closed, margin, mask, tiles, T) # edge pixels (raycast_outlines)
    render_kernel(cam, noncentral, xf, K, ...)               # fills an image; see renderers.raycast

The board (hits, materials, the distance to the nearest edge), the edge pixels
from the projected outlines, adaptive supersampling, area coverage and the band
loop of the renderer. The camera - the packed model, its rays (ray,
warm_start, ray_warm) - is reference_models.kernels', compiled into these
kernels.

No ray is cached between renders: a render traces the rays it reads. Where the
edge pixels are not known from the outlines (renderers.raycast_outlines), the
pixel-centre rays a tile's tests read are traced in runs of RAY_RUN grid points
along a row: the first ray of a run is solved cold, each next one from the
previous one's prediction (reference_models.kernels.fill_ray_cache's scheme,
restarted every RAY_RUN points), so a centre ray depends on its grid point
alone, whichever block asks for it.

Everything here is float64 and compiled without fastmath.
'''

import math

import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from reference_models.kernels import (
    _KIND,
    KIND_CAHV,
    _ray_warm_chi,
    _warm_coefficients,
    ray_warm,
    warm_start,
)

# the centre rays are traced in runs of this many grid points along a row (a tile's width:
# a tile's window, columns x0 - 1 .. x0 + TILE, starts a run)
RAY_RUN = 32

# a block of at most this many subsamples is sampled outright, not tested
LEAF_SAMPLES = 4
# adaptive tests use footprint radius * (1 + this) + the quadratic bound
FOOTPRINT_SAFETY = 0.01
# a pixel whose footprint is this far from affine is supersampled outright
MAX_NONLINEARITY = 0.25
# ... and subsamples are predicted (not traced) only where it is closer to affine than this
PREDICT_NONLINEARITY = 0.05
# circles an edge pixel is classified against directly
MAX_LOCAL_CIRCLES = 8
# blocks of pixels are split down to this size before pixels are tested one by one
MIN_BLOCK = 2
# footprints wider than this many buckets are not looked up (they are split)
MAX_BUCKET_SPAN = 4.0


# ---------------------------------------------------------------------------
# The board: hits, materials, and the distance to the nearest edge
#
# A pattern is pat = (f, ii), two flat arrays (renderers.raycast.CompiledPattern):
# f  float64: rect (4) | cells x0, y0, size (0: none), nx, ny (5) |
#             buckets x0, y0, size, 1/size, nbx, nby (6) | circles cx, cy, r (3 each)
# ii int64:   ids background, board, circle (3) | offsets of cmat, cmask, bstart, bitems (4) |
#             cmat, cmask ((ny+2)*(nx+2) each: cells with a ring of board cells) |
#             bstart (nbx*nby+1) | bitems
F_RECT, F_CELLS, F_BUCKETS, F_CIRCLES = 0, 4, 9, 15
I_IDS, I_OFFSETS, I_DATA = 0, 3, 7


@njit(cache=True, error_model="numpy")
def _hit(xf, s, vx, vy, vz):
    r"""Intersect a ray (origin C + s O, direction v; reference frame) with the board plane

xf: R_board_ref (9, row-major), R C + t (3), R O (3). Returns (ok, x, y) in the board frame."""
    bvx = xf[0] * vx + xf[1] * vy + xf[2] * vz
    bvy = xf[3] * vx + xf[4] * vy + xf[5] * vz
    bvz = xf[6] * vx + xf[7] * vy + xf[8] * vz
    boz = xf[11] + s * xf[14]
    t = -boz / bvz
    if not (t > 0.0 and t < math.inf):
        return False, 0.0, 0.0
    x = xf[9] + s * xf[12] + t * bvx
    y = xf[10] + s * xf[13] + t * bvy
    if not (abs(x) < math.inf and abs(y) < math.inf):
        return False, 0.0, 0.0
    return True, x, y


@njit(cache=True, error_model="numpy")
def _material(x, y, pat):
    r"""Material index at a board point, in the painting order of targets.pattern.Pattern"""
    f, ii = pat
    if not (x >= f[0] and x < f[1] and y >= f[2] and y < f[3]):
        return ii[0]
    m = ii[1]
    cs = f[F_CELLS + 2]
    if cs > 0.0:
        fx = math.floor((x - f[F_CELLS]) / cs)
        fy = math.floor((y - f[F_CELLS + 1]) / cs)
        nx = f[F_CELLS + 3]
        if fx >= 0.0 and fy >= 0.0 and fx < nx and fy < f[F_CELLS + 4]:
            m = ii[ii[I_OFFSETS] + (int(fy) + 1) * (int(nx) + 2) + int(fx) + 1]
    nbx = f[F_BUCKETS + 4]
    if nbx > 0.0:
        bx = math.floor((x - f[F_BUCKETS]) * f[F_BUCKETS + 3])
        by = math.floor((y - f[F_BUCKETS + 1]) * f[F_BUCKETS + 3])
        if bx >= 0.0 and by >= 0.0 and bx < nbx and by < f[F_BUCKETS + 5]:
            b = ii[I_OFFSETS + 2] + int(by) * int(nbx) + int(bx)
            items = ii[I_OFFSETS + 3]
            for k in range(ii[b], ii[b + 1]):
                c = F_CIRCLES + 3 * ii[items + k]
                dx = x - f[c]
                dy = y - f[c + 1]
                if dx * dx + dy * dy <= f[c + 2] * f[c + 2]:
                    return ii[2]
    return m


@njit(cache=True, error_model="numpy")
def _classify(x, y, r, pat):
    r"""(clear, material): clear when no edge of the pattern lies within r of the board
point (x, y); then material is the material of the whole disc

Conservative: it may say "not clear" where the albedo is uniform after all (the
pixel is then only supersampled needlessly), never "clear" where it is not."""
    f, ii = pat
    if not (x >= f[0] and x < f[1] and y >= f[2] and y < f[3]):
        dx = max(max(f[0] - x, 0.0), x - f[1])
        dy = max(max(f[2] - y, 0.0), y - f[3])
        # clear when the disc lies wholly outside the board: background only
        return dx * dx + dy * dy > r * r, ii[0]
    if min(min(x - f[0], f[1] - x), min(y - f[2], f[3] - y)) <= r:
        return False, 0
    m = ii[1]
    cs = f[F_CELLS + 2]
    if cs > 0.0:
        fx = (x - f[F_CELLS]) / cs
        fy = (y - f[F_CELLS + 1]) / cs
        ix = math.floor(fx)
        iy = math.floor(fy)
        nx = f[F_CELLS + 3]
        ny = f[F_CELLS + 4]
        if r >= cs:
            # a disc wider than a cell: clear only when it misses the cell grid
            dx = max(max(f[F_CELLS] - x, 0.0), x - (f[F_CELLS] + nx * cs))
            dy = max(max(f[F_CELLS + 1] - y, 0.0), y - (f[F_CELLS + 1] + ny * cs))
            if dx * dx + dy * dy <= r * r:
                return False, 0
        # cmat and cmask have a ring of board cells around the cells; a disc narrower
        # than a cell centred outside the ring misses the cells
        elif ix >= -1.0 and iy >= -1.0 and ix <= nx and iy <= ny:
            cell = (int(iy) + 1) * (int(nx) + 2) + int(ix) + 1
            m = ii[ii[I_OFFSETS] + cell]
            mask = ii[ii[I_OFFSETS + 1] + cell]
            if mask != 0:
                u = fx - ix
                v = fy - iy
                rc = r / cs
                if (mask & 1) and u <= rc:
                    return False, 0
                if (mask & 2) and 1.0 - u <= rc:
                    return False, 0
                if (mask & 4) and v <= rc:
                    return False, 0
                if (mask & 8) and 1.0 - v <= rc:
                    return False, 0
                rc2 = rc * rc
                if (mask & 16) and u * u + v * v <= rc2:
                    return False, 0
                if (mask & 32) and (1.0 - u) * (1.0 - u) + v * v <= rc2:
                    return False, 0
                if (mask & 64) and u * u + (1.0 - v) * (1.0 - v) <= rc2:
                    return False, 0
                if (mask & 128) and (1.0 - u) * (1.0 - u) + (1.0 - v) * (1.0 - v) <= rc2:
                    return False, 0
    nbx = f[F_BUCKETS + 4]
    if nbx > 0.0:
        # every circle within r of (x, y) has its bounding box in a bucket that
        # meets the square (x, y) +- r
        inv = f[F_BUCKETS + 3]
        if 2.0 * r * inv > MAX_BUCKET_SPAN:
            return False, 0
        bx0 = int(max(math.floor((x - r - f[F_BUCKETS]) * inv), 0.0))
        bx1 = int(min(math.floor((x + r - f[F_BUCKETS]) * inv), nbx - 1.0))
        by0 = int(max(math.floor((y - r - f[F_BUCKETS + 1]) * inv), 0.0))
        by1 = int(min(math.floor((y + r - f[F_BUCKETS + 1]) * inv), f[F_BUCKETS + 5] - 1.0))
        start = ii[I_OFFSETS + 2]
        items = ii[I_OFFSETS + 3]
        for jy in range(by0, by1 + 1):
            for jx in range(bx0, bx1 + 1):
                b = start + jy * int(nbx) + jx
                for k in range(ii[b], ii[b + 1]):
                    c = F_CIRCLES + 3 * ii[items + k]
                    dx = x - f[c]
                    dy = y - f[c + 1]
                    d2 = dx * dx + dy * dy
                    rc = f[c + 2]
                    # |d - rc| <= r without a square root
                    hi = rc + r
                    lo = rc - r
                    if d2 <= hi * hi and (lo <= 0.0 or d2 >= lo * lo):
                        return False, 0
                    if d2 <= rc * rc:
                        m = ii[2]
    return True, m


@njit(cache=True, error_model="numpy")
def _sample(cam, xf, x, y, warm, pat):
    s, vx, vy, vz = ray_warm(cam, x, y, warm)
    ok, bx, by = _hit(xf, s, vx, vy, vz)
    if not ok:
        return pat[1][0]
    return _material(bx, by, pat)


@njit(cache=True, error_model="numpy")
def _sample_block(cam, xf, ix, iy, i0, i1, j0, j1, offs, counts, warm, pat):
    r"""Trace every subsample of a block; returns the number of rays"""
    for j in range(j0, j1):
        y = iy + offs[j]
        for i in range(i0, i1):
            counts[_sample(cam, xf, ix + offs[i], y, warm, pat)] += 1
    return (i1 - i0) * (j1 - j0)


@njit(cache=True, error_model="numpy")
def _pixel_value(counts, values, K2):
    r"""The area average from the counts of materials; a uniform pixel is its value
exactly. Resets counts."""
    total = 0.0
    nonzero = 0
    last = 0
    for m in range(counts.shape[0]):
        if counts[m] != 0:
            nonzero += 1
            last = m
            total += counts[m] * values[m]
            counts[m] = 0
    if nonzero == 1:
        return values[last]
    return total / K2


@njit(cache=True, error_model="numpy")
def _push(stack, n, a0, a1, b0, b1):
    if a1 > a0 and b1 > b0:
        stack[n, 0] = a0
        stack[n, 1] = a1
        stack[n, 2] = b0
        stack[n, 3] = b1
        return n + 1
    return n


@njit(cache=True, error_model="numpy")
def _push_quadrants(stack, n, i0, i1, j0, j1):
    im = (i0 + i1) // 2
    jm = (j0 + j1) // 2
    n = _push(stack, n, im, i1, jm, j1)
    n = _push(stack, n, i0, im, jm, j1)
    n = _push(stack, n, im, i1, j0, jm)
    return _push(stack, n, i0, im, j0, jm)


# Literal arguments: numba compiles a callee once per literal value at a call site (False,
# True, 1 are Literal types, and a trivial function returning them is constant-propagated
# too), and _supersample and _board_points are the largest kernels here: their literal
# variants cost a fresh clone's first render ~45 of its ~105 CPU-s of compilation. The call
# sites pass run-time expressions of those values instead (K < 0 is False, K > 0 True: K
# >= 1; nk - nk + 1 is 1). Nor does a kernel here ask numba to inline a callee with
# several call sites (inline="always" types the callee's body again at every call site):
# LLVM inlines what pays, and the first render compiles in ~33 CPU-s instead of ~57 (warm
# renders within 2-5%, the images bit-identical). The exceptions are the callees of area
# coverage's path that have one call site each (_area_value, _area_circles, _area_error,
# _area_pixel, _quad_value): typed once either way, and LLVM left them out of line; inlined,
# navcam 15's edge pixels cost ~15% less CPU (pixel work and corner rays 17.4-18.6 ->
# 14.4-16.1 ms on one thread, load 3-5), the images bit-identical (no fastmath: the same
# operations in the same order).


@njit(cache=True, error_model="numpy")
def _supersample(cam, xf, ix, iy, K, offs, counts, stack, adaptive, jac, values, pat):
    r"""The value of pixel (ix, iy) from its K x K subsamples; returns (value, rays)

adaptive: subdivide the subsamples into quadrants; a block whose footprint
(the affine map jac[0:4] = (dx/dqx, dy/dqx, dx/dqy, dy/dqy) plus the quadratic
bound jac[4]) has no edge is counted towards the material at its centre
without tracing its subsamples."""
    warm = warm_start(cam, ix, iy)
    nrays = 1
    if not adaptive or K * K <= LEAF_SAMPLES:
        nrays += _sample_block(cam, xf, ix, iy, 0, K, 0, K, offs, counts, warm, pat)
        return _pixel_value(counts, values, float(K * K)), nrays
    # the pixel is known to hold an edge: start from its quadrants
    nst = _push_quadrants(stack, 0, 0, K, 0, K)
    while nst > 0:
        nst -= 1
        i0 = stack[nst, 0]
        i1 = stack[nst, 1]
        j0 = stack[nst, 2]
        j1 = stack[nst, 3]
        n = (i1 - i0) * (j1 - j0)
        if n <= LEAF_SAMPLES:
            nrays += _sample_block(cam, xf, ix, iy, i0, i1, j0, j1, offs, counts, warm, pat)
            continue
        cx = 0.5 * (offs[i0] + offs[i1 - 1])
        cy = 0.5 * (offs[j0] + offs[j1 - 1])
        wx = 0.5 * (offs[i1 - 1] - offs[i0])
        wy = 0.5 * (offs[j1 - 1] - offs[j0])
        s, vx, vy, vz = ray_warm(cam, ix + cx, iy + cy, warm)
        nrays += 1
        ok, bx, by = _hit(xf, s, vx, vy, vz)
        if ok:
            ex = wx * jac[0] + wy * jac[2]
            ey = wx * jac[1] + wy * jac[3]
            fx = wx * jac[0] - wy * jac[2]
            fy = wx * jac[1] - wy * jac[3]
            rb = ((max(math.sqrt(ex * ex + ey * ey), math.sqrt(fx * fx + fy * fy))
                   + 2.0 * jac[4]) * (1.0 + FOOTPRINT_SAFETY)
                  + 1e-12 * (1.0 + abs(bx) + abs(by)))
            clear, m = _classify(bx, by, rb, pat)
            if clear:
                counts[m] += n
                continue
        nst = _push_quadrants(stack, nst, i0, i1, j0, j1)
    return _pixel_value(counts, values, float(K * K)), nrays


@njit(cache=True, error_model="numpy")
def _local_circles(x, y, R, cand, pat):
    r"""(ncand, base): the circles whose outline lies within R of (x, y), into cand, and
the material of the disc of radius R apart from them; ncand = -1 when the disc
meets another edge (board rectangle, cells) or too many circles"""
    f, ii = pat
    if f[F_CELLS + 2] > 0.0:
        return -1, 0
    if not (x >= f[0] and x < f[1] and y >= f[2] and y < f[3]):
        return -1, 0
    if min(min(x - f[0], f[1] - x), min(y - f[2], f[3] - y)) <= R:
        return -1, 0
    base = ii[1]
    nbx = f[F_BUCKETS + 4]
    if nbx <= 0.0:
        return 0, base
    inv = f[F_BUCKETS + 3]
    if 2.0 * R * inv > MAX_BUCKET_SPAN:
        return -1, 0
    bx0 = int(max(math.floor((x - R - f[F_BUCKETS]) * inv), 0.0))
    bx1 = int(min(math.floor((x + R - f[F_BUCKETS]) * inv), nbx - 1.0))
    by0 = int(max(math.floor((y - R - f[F_BUCKETS + 1]) * inv), 0.0))
    by1 = int(min(math.floor((y + R - f[F_BUCKETS + 1]) * inv), f[F_BUCKETS + 5] - 1.0))
    start = ii[I_OFFSETS + 2]
    items = ii[I_OFFSETS + 3]
    n = 0
    for jy in range(by0, by1 + 1):
        for jx in range(bx0, bx1 + 1):
            b = start + jy * int(nbx) + jx
            for k in range(ii[b], ii[b + 1]):
                c = ii[items + k]
                dx = x - f[F_CIRCLES + 3 * c]
                dy = y - f[F_CIRCLES + 3 * c + 1]
                rc = f[F_CIRCLES + 3 * c + 2]
                d = math.sqrt(dx * dx + dy * dy)
                if abs(d - rc) <= R:
                    # a circle listed in two buckets is listed here twice: harmless
                    if n == cand.shape[0]:
                        return -1, 0
                    cand[n] = c
                    n += 1
                elif d < rc:
                    base = ii[2]
    return n, base


@njit(cache=True, error_model="numpy")
def _classify_local(x, y, r, cand, ncand, base, pat):
    r"""_classify() against the circles of _local_circles() alone"""
    f, ii = pat
    m = base
    for k in range(ncand):
        c = F_CIRCLES + 3 * cand[k]
        dx = x - f[c]
        dy = y - f[c + 1]
        d2 = dx * dx + dy * dy
        rc = f[c + 2]
        hi = rc + r
        lo = rc - r
        if d2 <= hi * hi and (lo <= 0.0 or d2 >= lo * lo):
            return False, 0
        if d2 <= rc * rc:
            m = ii[2]
    return True, m


@njit(cache=True, error_model="numpy")
def _supersample_predicted(cam, xf, ix, iy, K, offs, counts, stack, jac, cand, values, pat):
    r"""The value of pixel (ix, iy) from its K x K subsamples, tracing only those whose
board point cannot be told from its prediction; returns (value, rays)

Where the pixel's footprint is affine to within jac[4] (the bound on the
quadratic part over the pixel), the board point of the subsample at offset d
from the pixel centre is P(d) = jac[5:7] + J d within
e = jac[4] + FOOTPRINT_SAFETY * (footprint radius): the centre's point is an
exact ray's, J comes from the neighbours' exact rays. Blocks of subsamples
(split into quadrants) whose predicted points keep farther than e (plus the
block's own radius) from every edge count towards the material there; the
subsamples closer than e to an edge are traced."""
    px = jac[5]
    py = jac[6]
    e = jac[7]
    warm = (math.nan, 0.0, 0.0, 0.0)
    have_warm = False
    nrays = 0
    # the circles whose outline comes within the pixel's footprint (radius jac[8]) of
    # the centre: where they are the only edges there, blocks are classified against
    # them alone
    ncand, base = _local_circles(px, py, jac[8], cand, pat)
    # a square block (half-widths w, w) reaches w max(|J_x + J_y|, |J_x - J_y|) from its
    # centre's predicted point
    sx = jac[0] + jac[2]
    sy = jac[1] + jac[3]
    dx = jac[0] - jac[2]
    dy = jac[1] - jac[3]
    g = max(math.sqrt(sx * sx + sy * sy), math.sqrt(dx * dx + dy * dy))
    nst = _push_quadrants(stack, 0, 0, K, 0, K)
    while nst > 0:
        nst -= 1
        i0 = stack[nst, 0]
        i1 = stack[nst, 1]
        j0 = stack[nst, 2]
        j1 = stack[nst, 3]
        cx = 0.5 * (offs[i0] + offs[i1 - 1])
        cy = 0.5 * (offs[j0] + offs[j1 - 1])
        wx = 0.5 * (offs[i1 - 1] - offs[i0])
        wy = 0.5 * (offs[j1 - 1] - offs[j0])
        bx = px + cx * jac[0] + cy * jac[2]
        by = py + cx * jac[1] + cy * jac[3]
        if i1 - i0 == j1 - j0:
            rb = wx * g + e
        else:
            ex = wx * jac[0] + wy * jac[2]
            ey = wx * jac[1] + wy * jac[3]
            fx = wx * jac[0] - wy * jac[2]
            fy = wx * jac[1] - wy * jac[3]
            rb = max(math.sqrt(ex * ex + ey * ey), math.sqrt(fx * fx + fy * fy)) + e
        if ncand >= 0:
            clear, m = _classify_local(bx, by, rb, cand, ncand, base, pat)
        else:
            clear, m = _classify(bx, by, rb, pat)
        n = (i1 - i0) * (j1 - j0)
        if clear:
            counts[m] += n
        elif n == 1:
            if not have_warm:
                warm = warm_start(cam, ix, iy)
                have_warm = True
                nrays += 1
            counts[_sample(cam, xf, ix + offs[i0], iy + offs[j0], warm, pat)] += 1
            nrays += 1
        else:
            nst = _push_quadrants(stack, nst, i0, i1, j0, j1)
    return _pixel_value(counts, values, float(K * K)), nrays


# ---------------------------------------------------------------------------
# Area coverage (coverage = "area"): the exact covered area of an edge pixel
#
# The preimage of pixel (ix, iy) on the board is approximated by the polygon
# through the board points of an (n+1) x (n+1) grid of exact rays over the pixel
# (its corners at n = 1): n x n quadrilaterals, each of image area 1/n^2. In one
# quadrilateral the pixel measure is w(p) dp with w = 1 / |det d(board)/d(pixel)|,
# taken as linear in p (its value and gradient from the quadratic model of the
# board points of the 3 x 3 neighbouring pixel centres). The albedo integral over
# the quadrilateral is exact for that polygon and that density: polygons are
# clipped by the board rectangle and the cells (Sutherland-Hodgman), circles are
# integrated exactly (arcs and segments, Green's theorem: area and first moments).
#
# Error: the true preimage's sides bow away from the straight sides of the polygon
# by the sagitta |P_u x P_uu| / (8 |P_u|) (per side of length |P_u|; zero for a
# pinhole, whose lines stay lines); material inside those slivers may be
# misassigned: at most (|P_u x P_uu| + |P_v x P_vv|) / (6 |det J|) / n^2 of the
# pixel's area (the straight sides inside the pixel are shared by two
# quadrilaterals and cancel); the density's second-order part adds
# kappa^2 / 4 / n^2 (kappa: its relative change across the pixel) (_area_error).
# n is the smallest of 1, 2, 4, 8 with that bound <= tolerance; where none is, or
# where the neighbourhood is not one this handles (circles that overlap near the
# pixel, more than AREA_MAX_CELLS cells under it, a ray missing the plane, a
# footprint far from affine), the pixel is K x K point sampled.
#
# AREA_MAX_CELLS: a cell's clip (a polygon of 4-8 vertices against a box, its moments) costs
# less than one traced ray, and the fallback traces K^2 of them (256 at the campaigns' K =
# 16), so up to 256 cells the integral is exact and no dearer. At 16 (before session 18) an
# AprilGrid's pixels over tag bits under ~1.6 px (its cells a fifth of a bit) were point
# sampled: 2.6 % of the pixels of campaigns/cameras/tiny-320x240's pose 11, the pixel at a
# tag corner 0.6375 against 0.6514 exact; its jpl AprilTag records (12 poses, pose seeds
# 0-3) went from 0.0036-0.0063 px residual RMS to 0.0000-0.0048, CAHV 0.0000-0.0005 (h-tiny,
# benchmarks/bench_corner_campaign.py --cameras campaigns/cameras/tiny-320x240.cahvor --poses
# 12). Render CPU of its 12 poses 0.27 -> 0.24 s, mini-160x120's 0.33 -> 0.26; hazcam 17's and
# the paper campaign's images unchanged to the bit.
AREA_MAX_SUBDIVISION = 8
AREA_MAX_CELLS = 256
AREA_MAX_VERTICES = 16


@njit(cache=True, error_model="numpy")
def _seg_moments(px, py, qx, qy):
    r"""Green's-theorem integrals along the segment p -> q: (area, int x dA, int y dA)"""
    dx = qx - px
    dy = qy - py
    a = 0.5 * (px * qy - py * qx)
    mx = 0.5 * dy * (px * px + px * dx + dx * dx / 3.0)
    my = -0.5 * dx * (py * py + py * dy + dy * dy / 3.0)
    return a, mx, my


@njit(cache=True, error_model="numpy")
def _arc_moments(ax, ay, bx, by, r):
    r"""Green's-theorem integrals along the arc of the circle of radius r about the
origin from the direction of a to the direction of b (the shorter way)"""
    la = math.sqrt(ax * ax + ay * ay)
    lb = math.sqrt(bx * bx + by * by)
    c1 = ax / la
    s1 = ay / la
    c2 = bx / lb
    s2 = by / lb
    d = math.atan2(c1 * s2 - s1 * c2, c1 * c2 + s1 * s2)
    r2 = r * r
    r3 = r2 * r
    a = 0.5 * r2 * d
    mx = 0.5 * r3 * ((s2 - s2 * s2 * s2 / 3.0) - (s1 - s1 * s1 * s1 / 3.0))
    my = 0.5 * r3 * ((c1 - c1 * c1 * c1 / 3.0) - (c2 - c2 * c2 * c2 / 3.0))
    return a, mx, my


@njit(cache=True, error_model="numpy")
def _poly_moments(poly, row, n, ox, oy):
    r"""(area, int x dA, int y dA) of the polygon poly[row:row + 2, :n] about (ox, oy), signed by
its orientation"""
    a = 0.0
    mx = 0.0
    my = 0.0
    for k in range(n):
        kn = k + 1 if k + 1 < n else 0
        da, dmx, dmy = _seg_moments(poly[row, k] - ox, poly[row + 1, k] - oy,
                                    poly[row, kn] - ox, poly[row + 1, kn] - oy)
        a += da
        mx += dmx
        my += dmy
    return a, mx, my


@njit(cache=True, error_model="numpy")
def _disc_poly_moments(poly, row, n, cx, cy, r):
    r"""(area, int x dA, int y dA) of the disc (cx, cy, r) intersected with the polygon
poly[row:row + 2, :n] (signed by its orientation), about the circle's centre

The polygon is a fan of triangles (centre, p_k, p_k+1); each triangle meets the
disc in a region bounded by two radii (which cancel between neighbouring
triangles) and, along the side p_k p_k+1, the side where it is inside the disc
and the arc where it is outside."""
    a = 0.0
    mx = 0.0
    my = 0.0
    r2 = r * r
    for k in range(n):
        kn = k + 1 if k + 1 < n else 0
        px = poly[row, k] - cx
        py = poly[row + 1, k] - cy
        qx = poly[row, kn] - cx
        qy = poly[row + 1, kn] - cy
        dx = qx - px
        dy = qy - py
        dd = dx * dx + dy * dy
        if dd == 0.0:
            continue
        b = (px * dx + py * dy) / dd
        c = (px * px + py * py - r2) / dd
        disc = b * b - c
        t1 = 2.0
        t2 = 2.0
        if disc > 0.0:
            sq = math.sqrt(disc)
            t1 = -b - sq
            t2 = -b + sq
        if disc <= 0.0 or t1 >= 1.0 or t2 <= 0.0:
            # the side lies outside the disc: the arc between its ends' directions
            if px * px + py * py > 0.0 and qx * qx + qy * qy > 0.0:
                da, dmx, dmy = _arc_moments(px, py, qx, qy, r)
                a += da
                mx += dmx
                my += dmy
            continue
        ux = px
        uy = py
        if t1 > 0.0:
            ux = px + t1 * dx
            uy = py + t1 * dy
            da, dmx, dmy = _arc_moments(px, py, ux, uy, r)
            a += da
            mx += dmx
            my += dmy
        vx = qx
        vy = qy
        if t2 < 1.0:
            vx = px + t2 * dx
            vy = py + t2 * dy
        da, dmx, dmy = _seg_moments(ux, uy, vx, vy)
        a += da
        mx += dmx
        my += dmy
        if t2 < 1.0:
            da, dmx, dmy = _arc_moments(vx, vy, qx, qy, r)
            a += da
            mx += dmx
            my += dmy
    return a, mx, my


@njit(cache=True, error_model="numpy")
def _clip(poly, src, n, axis, value, keep_above, dst):
    r"""Sutherland-Hodgman: the part of the convex polygon poly[src:src + 2, :n] where
coordinate `axis` is >= value (keep_above) or <= value, into poly[dst:dst + 2]; returns its
number of vertices"""
    m = 0
    if n == 0:
        return 0
    for k in range(n):
        kp = k - 1 if k > 0 else n - 1
        a = (poly[src, kp] if axis == 0 else poly[src + 1, kp]) - value
        b = (poly[src, k] if axis == 0 else poly[src + 1, k]) - value
        if not keep_above:
            a = -a
            b = -b
        if b >= 0.0:
            if a < 0.0:
                t = a / (a - b)
                poly[dst, m] = poly[src, kp] + t * (poly[src, k] - poly[src, kp])
                poly[dst + 1, m] = poly[src + 1, kp] + t * (poly[src + 1, k] - poly[src + 1, kp])
                m += 1
            poly[dst, m] = poly[src, k]
            poly[dst + 1, m] = poly[src + 1, k]
            m += 1
        elif a >= 0.0:
            t = a / (a - b)
            poly[dst, m] = poly[src, kp] + t * (poly[src, k] - poly[src, kp])
            poly[dst + 1, m] = poly[src + 1, kp] + t * (poly[src + 1, k] - poly[src + 1, kp])
            m += 1
    return m


@njit(cache=True, error_model="numpy")
def _side_test(poly, src, n, axis, value, keep_above):
    r"""(every vertex kept, every vertex dropped) of the polygon poly[src:src + 2, :n] by
_clip's test against the side (`axis`, value, keep_above): the same signed differences"""
    inside = True
    outside = True
    for k in range(n):
        b = (poly[src, k] if axis == 0 else poly[src + 1, k]) - value
        if not keep_above:
            b = -b
        inside = inside and b >= 0.0
        outside = outside and b < 0.0
    return inside, outside


@njit(cache=True, error_model="numpy")
def _clip_box(poly, row, n, x0, x1, y0, y1):
    r"""Clip the polygon poly[row:row + 2, :n] to the box [x0, x1] x [y0, y1] (result in
poly[row:row + 2], poly[2:4] is scratch); returns its number of vertices

The sides are clipped in a loop, so that _clip's arguments are run-time values: numba
compiles a callee once per combination of literal arguments at its call sites (eight
_clip variants when the four sides of the board and of a cell were four calls each).
A side that keeps every vertex is not clipped (_clip would return the polygon as it
is, vertex for vertex: most sides of a cell an edge pixel's quadrilateral reaches into),
and a side that drops every vertex ends the clip with nothing (as _clip would)."""
    src = row
    for side in range(4):
        keep_above = side % 2 == 0
        axis = side // 2
        value = x0 if side == 0 else (x1 if side == 1 else (y0 if side == 2 else y1))
        inside, outside = _side_test(poly, src, n, axis, value, keep_above)
        if inside:
            continue
        if outside:
            return 0
        dst = 2 if src == row else row
        n = _clip(poly, src, n, axis, value, keep_above, dst)
        src = dst
    if src != row:
        for k in range(n):
            poly[row, k] = poly[src, k]
            poly[row + 1, k] = poly[src + 1, k]
    return n


@njit(cache=True, error_model="numpy", inline="always")
def _area_circles(x, y, R, cand, pat):
    r"""(ncand, base): the circles whose outline lies within R of (x, y), into cand, and
the material of the disc of radius R apart from them; ncand = -1 when they cannot
be integrated one by one (circles that overlap near here, too many of them, a
footprint wider than MAX_BUCKET_SPAN buckets); base = -1 when the board's own
material is not uniform near here (cells)"""
    f, ii = pat
    base = ii[1]
    nbx = f[F_BUCKETS + 4]
    if nbx <= 0.0:
        return 0, base
    inv = f[F_BUCKETS + 3]
    if 2.0 * R * inv > MAX_BUCKET_SPAN:
        return -1, 0
    bx0 = int(max(math.floor((x - R - f[F_BUCKETS]) * inv), 0.0))
    bx1 = int(min(math.floor((x + R - f[F_BUCKETS]) * inv), nbx - 1.0))
    by0 = int(max(math.floor((y - R - f[F_BUCKETS + 1]) * inv), 0.0))
    by1 = int(min(math.floor((y + R - f[F_BUCKETS + 1]) * inv), f[F_BUCKETS + 5] - 1.0))
    start = ii[I_OFFSETS + 2]
    items = ii[I_OFFSETS + 3]
    n = 0
    inside = 0
    for jy in range(by0, by1 + 1):
        for jx in range(bx0, bx1 + 1):
            b = start + jy * int(nbx) + jx
            for k in range(ii[b], ii[b + 1]):
                c = ii[items + k]
                dx = x - f[F_CIRCLES + 3 * c]
                dy = y - f[F_CIRCLES + 3 * c + 1]
                rc = f[F_CIRCLES + 3 * c + 2]
                d = math.sqrt(dx * dx + dy * dy)
                if abs(d - rc) <= R:
                    dup = False
                    for j in range(n):
                        dup = dup or cand[j] == c
                    if dup:
                        continue
                    if n == cand.shape[0]:
                        return -1, 0
                    cand[n] = c
                    n += 1
                elif d < rc:
                    inside += 1
    if inside > 0 and n > 0:
        return -1, 0
    if inside > 0:
        base = ii[2]
    # two circles near here that overlap: the painting order is not integrated
    for j in range(n):
        cj = F_CIRCLES + 3 * cand[j]
        for k in range(j):
            ck = F_CIRCLES + 3 * cand[k]
            dx = f[cj] - f[ck]
            dy = f[cj + 1] - f[ck + 1]
            rr = f[cj + 2] + f[ck + 2]
            if dx * dx + dy * dy < rr * rr:
                return -1, 0
    return n, base


@njit(cache=True, error_model="numpy", inline="always")
def _quad_value(w0, gx, gy, ox, oy, cand, ncand, base, values, poly, pat):
    r"""The mean albedo over the quadrilateral poly[6:8, :4] (board) under the density
w0 + g . (p - o); NaN when its cells are too many"""
    f, ii = pat
    inside = True
    for k in range(4):
        x = poly[6, k]
        y = poly[7, k]
        poly[0, k] = x
        poly[1, k] = y
        inside = inside and x >= f[0] and x <= f[1] and y >= f[2] and y <= f[3]
    aq, mxq, myq = _poly_moments(poly, 0, 4, ox, oy)
    wq = w0 * aq + gx * mxq + gy * myq
    n = 4
    wp = wq
    if not inside:
        # (clipping a quadrilateral inside the box returns it unchanged, vertex for vertex)
        n = _clip_box(poly, 0, n, f[0], f[1], f[2], f[3])
        if n < 3:
            return values[ii[0]]
        ap, mxp, myp = _poly_moments(poly, 0, n, ox, oy)
        wp = w0 * ap + gx * mxp + gy * myp
    total = values[ii[0]] * (wq - wp)
    if base != ii[1]:
        # the polygon lies inside a circle
        return (total + values[base] * wp) / wq
    # the circles over the polygon
    wdisc = 0.0
    for k in range(ncand):
        wdisc += _disc_weight(poly, 0, n, w0, gx, gy, ox, oy, cand[k], f)
    rest = wp - wdisc
    total += values[ii[2]] * wdisc
    cs = f[F_CELLS + 2]
    if cs > 0.0:
        # the cells under the polygon, each clipped out of it (less the circles on them)
        xlo = poly[0, 0]
        xhi = xlo
        ylo = poly[1, 0]
        yhi = ylo
        for k in range(1, n):
            xlo = min(xlo, poly[0, k])
            xhi = max(xhi, poly[0, k])
            ylo = min(ylo, poly[1, k])
            yhi = max(yhi, poly[1, k])
        nx = int(f[F_CELLS + 3])
        ny = int(f[F_CELLS + 4])
        cx0 = max(int(math.floor((xlo - f[F_CELLS]) / cs)), 0)
        cx1 = min(int(math.floor((xhi - f[F_CELLS]) / cs)), nx - 1)
        cy0 = max(int(math.floor((ylo - f[F_CELLS + 1]) / cs)), 0)
        cy1 = min(int(math.floor((yhi - f[F_CELLS + 1]) / cs)), ny - 1)
        # (no cell under it where either range is empty: beyond the grid on both axes, two
        # negative lengths made a positive count, and the AprilTag board's margin corners
        # were point sampled)
        if cx0 <= cx1 and cy0 <= cy1 and (cx1 - cx0 + 1) * (cy1 - cy0 + 1) > AREA_MAX_CELLS:
            return math.nan
        for cy in range(cy0, cy1 + 1):
            for cx in range(cx0, cx1 + 1):
                mat = ii[ii[I_OFFSETS] + (cy + 1) * (nx + 2) + cx + 1]
                if mat == ii[1]:
                    continue
                for k in range(n):
                    poly[4, k] = poly[0, k]
                    poly[5, k] = poly[1, k]
                x0 = f[F_CELLS] + cx * cs
                y0 = f[F_CELLS + 1] + cy * cs
                m = _clip_box(poly, 4, n, x0, x0 + cs, y0, y0 + cs)
                if m < 3:
                    continue
                ac, mxc, myc = _poly_moments(poly, 4, m, ox, oy)
                wc = w0 * ac + gx * mxc + gy * myc
                for k in range(ncand):
                    wc -= _disc_weight(poly, 4, m, w0, gx, gy, ox, oy, cand[k], f)
                total += values[mat] * wc
                rest -= wc
    total += values[ii[1]] * rest
    return total / wq


@njit(cache=True, error_model="numpy")
def _disc_weight(poly, row, n, w0, gx, gy, ox, oy, k, f):
    r"""The integral of the density w0 + g . (p - o) over circle k x the polygon
poly[row:row + 2, :n]"""
    c = F_CIRCLES + 3 * k
    a, mx, my = _disc_poly_moments(poly, row, n, f[c], f[c + 1], f[c + 2])
    return (w0 + gx * (f[c] - ox) + gy * (f[c + 1] - oy)) * a + gx * mx + gy * my


@njit(cache=True, error_model="numpy", inline="always")
def _area_pixel(cam, xf, ix, iy, n, jac, hess, cand, ncand, base, values, grid, poly, pat,
                corners, k, c, warm0):
    r"""The area coverage value of pixel (ix, iy) from an (n+1) x (n+1) grid of exact rays
(see above); returns (value, rays), value NaN where it cannot be computed

jac[0:4] = (dx/dqx, dy/dqx, dx/dqy, dy/dqy) at the pixel centre, hess[0:6] =
(P_uu, P_uv, P_vv) (x, y each): the quadratic model of the board points of the
neighbouring pixel centres, for the density.
corners[0:2, k - 1 + j, c - 1 + i]: the board points of the pixel corners (ix - 0.5 + i,
iy - 0.5 + j) traced so far in this band or tile (NaN: not yet), shared between
neighbouring pixels at n = 1 (k, c: the pixel's row and column in the centre rays'
arrays, _render_pixel). warm0: the warm start of the pixel's centre (NaN: not known, solved here).
"""
    warm = (math.nan, 0.0, 0.0, 0.0)
    have_warm = False
    nrays = 0
    inv = 1.0 / n
    for j in range(n + 1):
        y = iy - 0.5 + j * inv
        for i in range(n + 1):
            if n == 1:
                bx = corners[0, k - 1 + j, c - 1 + i]
                if bx == bx:
                    grid[0, j, i] = bx
                    grid[1, j, i] = corners[1, k - 1 + j, c - 1 + i]
                    continue
            if not have_warm:
                warm = warm0
                if not math.isfinite(warm[0]):
                    warm = warm_start(cam, ix, iy)
                    nrays += 1
                have_warm = True
            s, vx, vy, vz = ray_warm(cam, ix - 0.5 + i * inv, y, warm)
            nrays += 1
            ok, bx, by = _hit(xf, s, vx, vy, vz)
            if not ok:
                return math.nan, nrays
            grid[0, j, i] = bx
            grid[1, j, i] = by
            if n == 1:
                corners[0, k - 1 + j, c - 1 + i] = bx
                corners[1, k - 1 + j, c - 1 + i] = by
    acc = 0.0
    for j in range(n):
        dv = (j + 0.5) * inv - 0.5
        for i in range(n):
            du = (i + 0.5) * inv - 0.5
            # the quadrilateral, in the order of the pixel's corners (0,0) (1,0) (1,1) (0,1)
            poly[6, 0] = grid[0, j, i]
            poly[7, 0] = grid[1, j, i]
            poly[6, 1] = grid[0, j, i + 1]
            poly[7, 1] = grid[1, j, i + 1]
            poly[6, 2] = grid[0, j + 1, i + 1]
            poly[7, 2] = grid[1, j + 1, i + 1]
            poly[6, 3] = grid[0, j + 1, i]
            poly[7, 3] = grid[1, j + 1, i]
            ox = 0.25 * (poly[6, 0] + poly[6, 1] + poly[6, 2] + poly[6, 3])
            oy = 0.25 * (poly[7, 0] + poly[7, 1] + poly[7, 2] + poly[7, 3])
            # the Jacobian of the quadratic model at the quadrilateral's centre, and its
            # derivatives: the density w = 1/|D| and its gradient on the board
            bux = jac[0] + hess[0] * du + hess[2] * dv
            buy = jac[1] + hess[1] * du + hess[3] * dv
            bvx = jac[2] + hess[2] * du + hess[4] * dv
            bvy = jac[3] + hess[3] * du + hess[5] * dv
            D = bux * bvy - buy * bvx
            dDu = (hess[0] * bvy - hess[1] * bvx) + (bux * hess[3] - buy * hess[2])
            dDv = (hess[2] * bvy - hess[3] * bvx) + (bux * hess[5] - buy * hess[4])
            gDx = (bvy * dDu - buy * dDv) / D
            gDy = (-bvx * dDu + bux * dDv) / D
            sgn = 1.0 if D > 0.0 else -1.0
            w0 = sgn / D
            gx = -sgn * gDx / (D * D)
            gy = -sgn * gDy / (D * D)
            v = _quad_value(w0, gx, gy, ox, oy, cand, ncand, base, values, poly, pat)
            if not (v - v == 0.0):
                return math.nan, nrays
            acc += v
    return acc * inv * inv, nrays


@njit(cache=True, error_model="numpy", inline="always")
def _area_error(jac, hess):
    r"""The bound on the error of a pixel's area coverage (fraction of its area) at n = 1:
the slivers between the polygon's straight sides and the bowed preimage of the
pixel's sides (sagitta |P_u x P_uu| / (8 |P_u|) over a side of length |P_u|, area
2/3 sagitta x length, two sides each way), plus the second-order part of the
density left out of its linear model (kappa^2 / 4, kappa = the density's relative
change across the pixel); both fall as 1/n^2 with n x n quadrilaterals"""
    D = abs(jac[0] * jac[3] - jac[1] * jac[2])
    cu = abs(jac[0] * hess[1] - jac[1] * hess[0])
    cv = abs(jac[2] * hess[5] - jac[3] * hess[4])
    dDu = (hess[0] * jac[3] - hess[1] * jac[2]) + (jac[0] * hess[3] - jac[1] * hess[2])
    dDv = (hess[2] * jac[3] - hess[3] * jac[2]) + (jac[0] * hess[5] - jac[1] * hess[4])
    kappa = (abs(dDu) + abs(dDv)) / D
    return ((cu + cv) / (6.0 * D) + 0.25 * kappa * kappa) * (1.0 + FOOTPRINT_SAFETY)


@njit(cache=True, error_model="numpy", inline="always")
def _area_value(cam, xf, ix, iy, px, py, R, tol, jac, hess, cand, values, grid, poly, pat,
                corners, k, c, warm0):
    r"""The area coverage value of an edge pixel (board point (px, py) of its centre,
footprint radius R): the subdivision n from the error bound, then _area_pixel;
(NaN, rays) where it is not computed (the pixel is then point sampled)"""
    f, ii = pat
    ncand, base = _area_circles(px, py, R, cand, pat)
    if ncand < 0:
        return math.nan, 0
    e = _area_error(jac, hess)
    n = 1
    while e > tol * n * n:
        n *= 2
        if n > AREA_MAX_SUBDIVISION:
            return math.nan, 0
    return _area_pixel(cam, xf, ix, iy, n, jac, hess, cand, ncand, base, values, grid, poly,
                       pat, corners, k, c, warm0)


@njit(cache=True, error_model="numpy")
def _ring_side(xs, ys, px, py):
    r"""(max |P_i - p|^2, max |P_i - P_i-1|^2) of the points (xs, ys) of one side of a ring"""
    d2max = 0.0
    s2max = 0.0
    lx = xs[0]
    ly = ys[0]
    for i in range(xs.shape[0]):
        x = xs[i]
        y = ys[i]
        d2max = max(d2max, (x - px) * (x - px) + (y - py) * (y - py))
        s2max = max(s2max, (x - lx) * (x - lx) + (y - ly) * (y - ly))
        lx = x
        ly = y
    return d2max, s2max


@njit(cache=True, error_model="numpy")
def _block_uniform(hx, hy, hok, k0, k1, c0, c1, pat):
    r"""(uniform, material) of the block of pixels whose ring of neighbouring pixel
centres is band rows k0, k1 and band columns c0, c1

The board points of the block's pixel areas lie inside the curve through the
board points of the ring (the map from image to board is continuous and one
to one), hence within max |P_ring - P_centre| of the centre point, plus half
the longest step between neighbouring ring points for the curve between them."""
    kc = (k0 + k1) // 2
    cc = (c0 + c1) // 2
    okc = hok[kc, cc]
    nok = 0
    for c in range(c0, c1 + 1):
        nok += hok[k0, c] + hok[k1, c]
    for k in range(k0 + 1, k1):
        nok += hok[k, c0] + hok[k, c1]
    nring = 2 * (c1 - c0 + 1) + 2 * (k1 - k0 - 1)
    if nok == 0 and not okc:
        return True, pat[1][0]
    if nok != nring or not okc:
        return False, 0
    px = hx[kc, cc]
    py = hy[kc, cc]
    # the largest distance from the centre point and the longest step along each side
    d2r0, s2r0 = _ring_side(hx[k0, c0:c1 + 1], hy[k0, c0:c1 + 1], px, py)
    d2r1, s2r1 = _ring_side(hx[k1, c0:c1 + 1], hy[k1, c0:c1 + 1], px, py)
    d2c0, s2c0 = _ring_side(hx[k0:k1 + 1, c0], hy[k0:k1 + 1, c0], px, py)
    d2c1, s2c1 = _ring_side(hx[k0:k1 + 1, c1], hy[k0:k1 + 1, c1], px, py)
    d2max = max(max(d2r0, d2r1), max(d2c0, d2c1))
    s2max = max(max(s2r0, s2r1), max(s2c0, s2c1))
    r = ((math.sqrt(d2max) + 0.5 * math.sqrt(s2max)) * (1.0 + FOOTPRINT_SAFETY)
         + 1e-12 * (1.0 + abs(px) + abs(py)))
    return _classify(px, py, r, pat)


@njit(cache=True, error_model="numpy")
def _render_pixel(cam, xf, ix, iy, k, c, hx, hy, hok, K, offs, counts, stack, jac, cand,
                  values, pat, area, tol, hess, grid, poly, corners, warm0):
    r"""Adaptive value of pixel (ix, iy) (band row k, column c); returns (value, rays, how):
how 0 uniform, 1 point sampled, 2 area coverage (area mode), 3 point sampled in area
mode where area coverage is not computed. warm0: the warm start of the pixel's centre
ray (reference_models.kernels.warm_start; NaN: solved where needed)"""
    nok = 0
    for dk in range(-1, 2):
        for dc in range(-1, 2):
            nok += hok[k + dk, c + dc]
    if nok == 0:
        # the pixel and its neighbours miss the board plane
        return values[pat[1][0]], 0, 0
    if nok < 9:
        v, n = _supersample(cam, xf, ix, iy, K, offs, counts, stack, K < 0, jac, values, pat)
        return v, n, 3 if area else 1
    # the footprint of the pixel from its neighbours' board points: the
    # Jacobian, and a bound on the quadratic part over the pixel
    px = hx[k, c]
    py = hy[k, c]
    jac[0] = 0.5 * (hx[k, c + 1] - hx[k, c - 1])
    jac[1] = 0.5 * (hy[k, c + 1] - hy[k, c - 1])
    jac[2] = 0.5 * (hx[k + 1, c] - hx[k - 1, c])
    jac[3] = 0.5 * (hy[k + 1, c] - hy[k - 1, c])
    d2xx = hx[k, c + 1] - 2.0 * px + hx[k, c - 1]
    d2xy = hy[k, c + 1] - 2.0 * py + hy[k, c - 1]
    d2yx = hx[k + 1, c] - 2.0 * px + hx[k - 1, c]
    d2yy = hy[k + 1, c] - 2.0 * py + hy[k - 1, c]
    dcx = 0.25 * (hx[k + 1, c + 1] - hx[k - 1, c + 1] - hx[k + 1, c - 1] + hx[k - 1, c - 1])
    dcy = 0.25 * (hy[k + 1, c + 1] - hy[k - 1, c + 1] - hy[k + 1, c - 1] + hy[k - 1, c - 1])
    quad = (0.125 * (math.sqrt(d2xx * d2xx + d2xy * d2xy) + math.sqrt(d2yx * d2yx + d2yy * d2yy))
            + 0.25 * math.sqrt(dcx * dcx + dcy * dcy))
    jac[4] = quad
    ax = 0.5 * (jac[0] + jac[2])
    ay = 0.5 * (jac[1] + jac[3])
    bx = 0.5 * (jac[0] - jac[2])
    by = 0.5 * (jac[1] - jac[3])
    lin = max(math.sqrt(ax * ax + ay * ay), math.sqrt(bx * bx + by * by))
    affine = quad <= MAX_NONLINEARITY * lin
    if affine:
        r = (lin + quad) * (1.0 + FOOTPRINT_SAFETY) + 1e-12 * (1.0 + abs(px) + abs(py))
        clear, m = _classify(px, py, r, pat)
        if clear:
            return values[m], 0, 0
        if area:
            hess[0] = d2xx
            hess[1] = d2xy
            hess[2] = dcx
            hess[3] = dcy
            hess[4] = d2yx
            hess[5] = d2yy
            v, n = _area_value(cam, xf, ix, iy, px, py, r, tol, jac, hess, cand, values, grid,
                               poly, pat, corners, k, c, warm0)
            if v - v == 0.0:
                # a mean of albedos in [0, 1]: the sum of signed moments can round past the
                # ends (-2e-16 where a pixel is all background 0)
                return min(max(v, 0.0), 1.0), n, 2
            v, n2 = _supersample(cam, xf, ix, iy, K, offs, counts, stack, K > 0, jac, values,
                                 pat)
            return v, n + n2, 3
        if quad <= PREDICT_NONLINEARITY * lin and K * K > 1:
            jac[5] = px
            jac[6] = py
            jac[7] = quad + FOOTPRINT_SAFETY * lin + 1e-12 * (1.0 + abs(px) + abs(py))
            # every block's disc lies within |J_x|/2 + |J_y|/2 <= 2 lin (+ e) of the centre
            jac[8] = 2.0 * (lin + quad) * (1.0 + FOOTPRINT_SAFETY) + jac[7]
            v, n = _supersample_predicted(cam, xf, ix, iy, K, offs, counts, stack, jac, cand,
                                          values, pat)
            return v, n, 1
    v, n = _supersample(cam, xf, ix, iy, K, offs, counts, stack, affine, jac, values, pat)
    return v, n, 3 if area else 1


@njit(cache=True, error_model="numpy")
def _centre_ray(cam, central, gx, y, warm):
    r"""(s, vx, vy, vz, warm): the centre ray of grid column gx (image x = gx - 1) in the
image row y, and the warm start of the next column of its run (see RAY_RUN)"""
    if gx % RAY_RUN == 0:
        warm = (math.nan, 0.0, 0.0, 0.0)
    s, vx, vy, vz, u, chi = _ray_warm_chi(cam, gx - 1.0, y, warm, True)
    if not central:
        warm = _warm_coefficients(cam, u, chi)
    return s, vx, vy, vz, warm


@njit(cache=True, error_model="numpy")
def _board_points(cam, xf, noncentral, r0, k0, k1, c0, c1, hx, hy, hok):
    r"""The board points of the centre rays of band rows k0..k1-1, band columns c0..c1-1
(image row r0 - 1 + k, column c - 1) into hx, hy, hok, traced in runs of RAY_RUN
from fixed columns (the same rays whichever block asks for them)"""
    central = cam[_KIND] == KIND_CAHV
    for k in range(k0, k1):
        y = r0 + k - 1.0
        warm = (math.nan, 0.0, 0.0, 0.0)
        for gx in range(c0 - c0 % RAY_RUN, c1):
            s, vx, vy, vz, warm = _centre_ray(cam, central, gx, y, warm)
            if gx >= c0:
                ok, x, yb = _hit(xf, s if noncentral else 0.0, vx, vy, vz)
                hok[k, gx] = ok
                hx[k, gx] = x
                hy[k, gx] = yb


@njit(cache=True, error_model="numpy")
def _hit_ring(cam, xf, noncentral, r0, k0, k1, c0, c1, hx, hy, hok):
    r"""The board points of the ring band rows k0, k1 x band columns c0..c1 (and columns
c0, c1 between) and of its centre ((k0+k1)//2, (c0+c1)//2): what _block_uniform reads"""
    for k in (k0, k1):
        _board_points(cam, xf, noncentral, r0, k, k + 1, c0, c1 + 1,
                      hx, hy, hok)
    for k in range(k0 + 1, k1):
        for c in (c0, c1):
            _board_points(cam, xf, noncentral, r0, k, k + 1, c, c + 1,
                          hx, hy, hok)
    kc = (k0 + k1) // 2
    cc = (c0 + c1) // 2
    _board_points(cam, xf, noncentral, r0, kc, kc + 1, cc, cc + 1,
                  hx, hy, hok)


@njit(cache=True, error_model="numpy")
def _on_board(x, y, rect):
    return x >= rect[0] and x < rect[1] and y >= rect[2] and y < rect[3]


@njit(cache=True, error_model="numpy")
def _count_board(hx, hy, hok, k0, k1, c0, c1, rect):
    r"""The number of the points k0..k1-1 x c0..c1-1 that hit the board"""
    n = 0
    for k in range(k0, k1):
        for c in range(c0, c1):
            if hok[k, c] and _on_board(hx[k, c], hy[k, c], rect):
                n += 1
    return n


@njit(cache=True, error_model="numpy")
def _centre_on_board(hx, hy, hok, k0, k1, c0, c1, rect):
    r"""Whether the centre point of the block with ring k0, k1, c0, c1 hits the board;
for a block _block_uniform calls uniform, then so do all its pixel centres (its
disc lies inside the board rectangle or wholly outside it)"""
    kc = (k0 + k1) // 2
    cc = (c0 + c1) // 2
    return hok[kc, cc] and _on_board(hx[kc, cc], hy[kc, cc], rect)


@njit(cache=True, error_model="numpy")
def _band_scratch(K, nvalues, T, W, area, tile):
    r"""The work arrays of a band of at most T image rows of width W, allocated once per
thread and reused for each of its bands: (hx, hy, hok, hu, hchi, need, code, blocks,
bmask, btiles, counts, offs (the K subsample offsets), stack, jac, cand, hess, grid,
poly, corners). hx, hy, hok (T + 2, Nc): the board points of the centre rays of the
band (_render_band: Nc = W + 2, band row k = iy - r0 + 1, column c = ix + 1) or, with
tile, of one tile's window (_render_band_outline: Nc = T + 2, c = ix - x0 + 1), hu, hchi
the u, chi of their Newton solves (_trace_needed); need, code: a tile's
(_render_band_outline); blocks: _render_band's stack; bmask (T, W): the band's edge
pixels, btiles (1, ceil(W / T)) its tiles that hold one; corners (2, T + 1, Nc - 1) in
area mode: the board points of the pixel corners of the band (or tile), NaN until
traced (each band and tile resets what it reads).

A tile's window, not the band's, is what _render_band_outline reads: its arrays stay
in the core's cache (a 5120-pixel band's are 8 MB, and a tile's rays and corners were
stored to lines evicted since the band's last tile)."""
    nc = T + 2 if tile else W + 2
    hx = np.empty((T + 2, nc))
    hy = np.empty((T + 2, nc))
    hok = np.zeros((T + 2, nc), dtype=np.uint8)
    hu = np.empty((T + 2, nc))
    hchi = np.empty((T + 2, nc))
    need = np.zeros((T + 2, T + 2), dtype=np.uint8)
    code = np.empty((T, T), dtype=np.int64)
    blocks = np.empty((4 * (int(math.log2(T)) + 3), 4), dtype=np.int64)
    bmask = np.zeros((T, W), dtype=np.uint8)
    btiles = np.zeros((1, -(-W // T)), dtype=np.uint8)
    counts = np.zeros(nvalues, dtype=np.int64)
    offs = np.empty(K)
    for i in range(K):
        offs[i] = (i + 0.5) / K - 0.5
    stack = np.empty((4 * (int(math.log2(K)) + 3), 4), dtype=np.int64)
    jac = np.zeros(9)
    cand = np.empty(MAX_LOCAL_CIRCLES, dtype=np.int64)
    hess = np.zeros(6)
    grid = np.empty((2, AREA_MAX_SUBDIVISION + 1, AREA_MAX_SUBDIVISION + 1))
    poly = np.empty((8, AREA_MAX_VERTICES))
    corners = np.full((2, T + 1, nc - 1) if area else (2, 1, 1), math.nan)
    return (hx, hy, hok, hu, hchi, need, code, blocks, bmask, btiles, counts, offs, stack, jac,
            cand, hess, grid, poly, corners)


@njit(cache=True, error_model="numpy")
def _render_band(r0, r1, T, cam, noncentral, xf, K, adaptive, values, out, filled, stats, pat,
                 qbox, area, tol, scratch):
    H, W = out.shape
    # no tile of the band is taken to hold one value afterwards (render_kernel's filled)
    filled[:] = math.nan
    nk = r1 - r0 + 2
    # board points of the centre rays of image rows r0-1 .. r1 (band row k = iy - r0 + 1)
    # and columns -1 .. W (band column c = ix + 1)
    (hx, hy, hok, _, _, _, _, blocks, _, _, counts, offs, stack, jac, cand, hess, grid, poly,
     corners) = scratch
    hok[:nk] = 0
    if area:
        corners[:, :r1 - r0 + 1] = math.nan
    rect = pat[0]
    nboard = 0
    if not adaptive:
        # every pixel is supersampled; the board points only count board pixels
        _board_points(cam, xf, noncentral, r0, nk - nk + 1, nk - 1, nk - nk + 1, W + 1, hx, hy,
                      hok)
        nboard = _count_board(hx, hy, hok, 1, nk - 1, 1, W + 1, rect)

    narea = 0
    nfallback = 0
    nrays = 0
    nsuper = 0
    nblocks = 0
    ntested = 0
    for x0 in range(0, W, T):
        x1 = min(W, x0 + T)
        if not adaptive:
            for iy in range(r0, r1):
                for ix in range(x0, x1):
                    v, n = _supersample(cam, xf, ix, iy, K, offs, counts, stack, K < 0, jac,
                                        values, pat)
                    out[iy, ix] = v
                    nrays += n
                    nsuper += 1
            continue
        # blocks of pixels (rows ya..yb, columns xa..xb), split into quadrants
        # until they are uniform or at most MIN_BLOCK pixels wide
        # the board points of a tile's interior are traced only when its ring says
        # that it is not uniform (the blocks inside and their pixels then need them)
        nb = _push(blocks, 0, r0, r1, x0, x1)
        tile = True
        while nb > 0:
            nb -= 1
            ya = blocks[nb, 0]
            yb = blocks[nb, 1]
            xa = blocks[nb, 2]
            xb = blocks[nb, 3]
            if (xb - 0.5 < qbox[0] or xa - 0.5 > qbox[1]
                    or yb - 0.5 < qbox[2] or ya - 0.5 > qbox[3]):
                # the block lies outside the image of the board
                uniform, m = True, pat[1][0]
            else:
                if tile:
                    _hit_ring(cam, xf, noncentral, r0, 0, nk - 1, x0, x1 + 1,
                              hx, hy, hok)
                uniform, m = _block_uniform(hx, hy, hok, ya - r0, yb - r0 + 1, xa, xb + 1, pat)
                nblocks += 1
                if tile:
                    if not uniform:
                        _board_points(cam, xf, noncentral, r0, nk - nk + 1, nk - 1,
                                      x0 + 1, x1 + 1, hx, hy, hok)
                        nboard += _count_board(hx, hy, hok, 1, nk - 1, x0 + 1, x1 + 1, rect)
                    elif _centre_on_board(hx, hy, hok, 0, nk - 1, x0, x1 + 1, rect):
                        # a uniform block whose centre is on the board lies on the board
                        nboard += (r1 - r0) * (x1 - x0)
            tile = False
            if uniform:
                v = values[m]
                for iy in range(ya, yb):
                    for ix in range(xa, xb):
                        out[iy, ix] = v
                continue
            if yb - ya > MIN_BLOCK or xb - xa > MIN_BLOCK:
                nb = _push_quadrants(blocks, nb, ya, yb, xa, xb)
                continue
            for iy in range(ya, yb):
                for ix in range(xa, xb):
                    ntested += 1
                    v, n, how = _render_pixel(cam, xf, ix, iy, iy - r0 + 1, ix + 1, hx, hy,
                                              hok, K, offs, counts, stack, jac, cand, values,
                                              pat, area, tol, hess, grid, poly, corners,
                                              (math.nan, 0.0, 0.0, 0.0))
                    out[iy, ix] = v
                    nrays += n
                    nsuper += how != 0
                    narea += how == 2
                    nfallback += how == 3
    _band_stats(stats, nrays, nsuper, nboard, nblocks, ntested,
                _count_nonfinite(out, r0, r1), narea, nfallback)


# ---------------------------------------------------------------------------
# Edge pixels from the projected outlines (renderers.raycast_outlines)
#
# A pixel is an edge pixel when its closed square [ix-0.5, ix+0.5] x [iy-0.5, iy+0.5]
# comes within a polyline's margin of one of its chords (split into pieces <= MARK_PIECE_PX:
# a piece of a chord is the chord), by the separating-axis test of the square against the
# piece grown by the margin: its bounding box (the x and y axes) and its normal. The
# test keeps every pixel that the grown piece meets (it meets at most the pixels of its
# oriented box) and a few more near the piece's ends (_mark_chord). band_chords lists
# the chords that reach each band of T rows; _render_band_outline marks its band's edge
# pixels from them, renders a tile without edge pixels from one ray, and in the other
# tiles the edge pixels as _render_pixel does and the others from a neighbour of the same
# region.
MARK_PIECE_PX = 2.0
# band_chords lists a chord in the bands of its rows widened by this (px): the pieces'
# ends, computed from the chord's, may round past it
BAND_SLACK_PX = 1e-6


@njit(cache=True, error_model="numpy")
def _mark_chord(ax, ay, bx, by, m, mask, tiles, T, row0, rlo, rhi):
    r"""Mark in mask (rows row0.., W columns) the pixels of image rows rlo..rhi whose
square comes within m of the chord (ax, ay) - (bx, by), and their tiles of T x T pixels
in tiles (tile rows from row0)"""
    W = mask.shape[1]
    dx = bx - ax
    dy = by - ay
    length = math.sqrt(dx * dx + dy * dy)
    npieces = max(1, int(math.ceil(length / MARK_PIECE_PX)))
    nx = 0.0
    ny = 0.0
    if length > 0.0:
        nx = -dy / length
        ny = dx / length
    reach = m + 0.5 * (abs(nx) + abs(ny))
    for piece in range(npieces):
        u0 = piece / npieces
        u1 = (piece + 1) / npieces
        px0 = ax + u0 * dx
        py0 = ay + u0 * dy
        px1 = ax + u1 * dx
        py1 = ay + u1 * dy
        fx0 = math.ceil(min(px0, px1) - m - 0.5)
        fx1 = math.floor(max(px0, px1) + m + 0.5)
        fy0 = math.ceil(min(py0, py1) - m - 0.5)
        fy1 = math.floor(max(py0, py1) + m + 0.5)
        if fx1 < 0.0 or fy1 < rlo or fx0 > W - 1.0 or fy0 > rhi:
            continue
        ix0 = int(max(fx0, 0.0))
        ix1 = int(min(fx1, W - 1.0))
        iy0 = int(max(fy0, rlo))
        iy1 = int(min(fy1, rhi))
        for iy in range(iy0, iy1 + 1):
            for ix in range(ix0, ix1 + 1):
                if abs(nx * (ix - ax) + ny * (iy - ay)) <= reach:
                    mask[iy - row0, ix] = 1
                    tiles[(iy - row0) // T, ix // T] = 1


@njit(cache=True, error_model="numpy")
def mark_outlines(q, starts, closed, margin, mask, tiles, T):
    r"""Mark the edge pixels of the polylines q[starts[i]:starts[i+1]] in mask (H,W) and
their tiles (of T x T pixels) in tiles (the whole image at once; a render marks band
by band, _render_band_outline)"""
    H, W = mask.shape
    for p in range(starts.shape[0] - 1):
        a0 = starts[p]
        n = starts[p + 1] - a0
        for i in range(n if closed[p] else n - 1):
            j = a0 + i
            k = a0 + i + 1 if i + 1 < n else a0
            _mark_chord(q[j, 0], q[j, 1], q[k, 0], q[k, 1], margin[p], mask, tiles, T, 0, 0,
                        H - 1)


@njit(cache=True, error_model="numpy")
def band_chords(q, starts, closed, margin, T, H, W):
    r"""The chords of the polylines that can mark pixels of each band of T image rows:
(bstart (Nbands+1,), chords (N,3): first point, second point, polyline), band b's at
chords[bstart[b]:bstart[b+1]]"""
    nbands = -(-H // T)
    bstart = np.zeros(nbands + 1, dtype=np.int64)
    chords = np.empty((0, 3), dtype=np.int64)
    for count in range(2):
        fill = bstart[:-1].copy()
        for p in range(starts.shape[0] - 1):
            a0 = starts[p]
            n = starts[p + 1] - a0
            m = margin[p] + 0.5 + BAND_SLACK_PX
            for i in range(n if closed[p] else n - 1):
                j = a0 + i
                k = a0 + i + 1 if i + 1 < n else a0
                if (max(q[j, 0], q[k, 0]) + m < 0.0 or min(q[j, 0], q[k, 0]) - m > W - 1.0
                        or max(q[j, 1], q[k, 1]) + m < 0.0
                        or min(q[j, 1], q[k, 1]) - m > H - 1.0):
                    continue
                b0 = int(max(math.ceil(min(q[j, 1], q[k, 1]) - m), 0.0)) // T
                b1 = int(min(math.floor(max(q[j, 1], q[k, 1]) + m), H - 1.0)) // T
                for b in range(b0, b1 + 1):
                    if count == 0:
                        bstart[b + 1] += 1
                    else:
                        chords[fill[b], 0] = j
                        chords[fill[b], 1] = k
                        chords[fill[b], 2] = p
                        fill[b] += 1
        if count == 0:
            for b in range(nbands):
                bstart[b + 1] += bstart[b]
            chords = np.empty((bstart[nbands], 3), dtype=np.int64)
    return bstart, chords


@njit(cache=True, error_model="numpy")
def _trace_needed(cam, xf, noncentral, r0, x0, x1, nk, need, hx, hy, hok, hu, hchi):
    r"""The board points of the centre rays of the tile's grid points (k, c) marked in need
(band rows 0..nk-1, columns c = 0..x1-x0+1: image x = x0 + c - 1), traced along each
row's runs of marked points (each next ray's Newton started from the previous one's
prediction), into hx, hy, hok [k, c], and the u, chi of their Newton solves (the warm
starts of their pixels' other rays); returns the number of rays"""
    central = cam[_KIND] == KIND_CAHV
    nrays = 0
    for k in range(nk):
        y = r0 + k - 1.0
        warm = (math.nan, 0.0, 0.0, 0.0)
        for c in range(x1 - x0 + 2):
            if not need[k, c]:
                warm = (math.nan, 0.0, 0.0, 0.0)
                continue
            s, vx, vy, vz, u, chi = _ray_warm_chi(cam, x0 + c - 1.0, y, warm, True)
            if not central:
                warm = _warm_coefficients(cam, u, chi)
            ok, x, yb = _hit(xf, s if noncentral else 0.0, vx, vy, vz)
            hok[k, c] = ok
            hx[k, c] = x
            hy[k, c] = yb
            hu[k, c] = u
            hchi[k, c] = chi
            nrays += 1
    return nrays


@njit(cache=True, error_model="numpy")
def _render_band_outline(r0, r1, T, cam, noncentral, xf, K, values, out, filled, stats, pat,
                         qbox, area, tol, outline, scratch):
    r"""_render_band where the edge pixels are known from the outlines: outline = (q,
margin, bstart, chords) (band_chords)

The band's edge pixels are marked first (_mark_chord). A tile without edge pixels is
one region of one material: the board point of one centre ray (none outside qbox)
decides it, and it is filled. In a tile with edge pixels, the centre rays of the edge
pixels and of their 8 neighbours are traced, each edge pixel is rendered as
_render_pixel renders it (area coverage or K x K point samples), and every other pixel
takes the material of its left or upper neighbour when that one is not an edge pixel
either (the union of their squares is connected and no outline meets it: one
material), else of its own centre ray."""
    H, W = out.shape
    nk = r1 - r0 + 2
    (hx, hy, hok, hu, hchi, need, code, _, mask, tiles, counts, offs, stack, jac, cand, hess,
     grid, poly, corners) = scratch
    central = cam[_KIND] == KIND_CAHV
    q, margin, bstart, chords = outline
    b = r0 // T
    mask[:r1 - r0] = 0
    tiles[0] = 0
    for i in range(bstart[b], bstart[b + 1]):
        j = chords[i, 0]
        k = chords[i, 1]
        _mark_chord(q[j, 0], q[j, 1], q[k, 0], q[k, 1], margin[chords[i, 2]], mask, tiles, T,
                    r0, r0, r1 - 1)
    rect = pat[0]
    bg = pat[1][0]
    narea = 0
    nfallback = 0
    nrays = 0
    nsuper = 0
    nboard = 0
    ntiles = 0
    nedge = 0
    nonfinite = 0
    for x0 in range(0, W, T):
        x1 = min(W, x0 + T)
        if not tiles[0, x0 // T]:
            m = bg
            onboard = False
            if not (x1 - 0.5 < qbox[0] or x0 - 0.5 > qbox[1]
                    or r1 - 0.5 < qbox[2] or r0 - 0.5 > qbox[3]):
                s, vx, vy, vz = ray_warm(cam, x0, r0, (math.nan, 0.0, 0.0, 0.0))
                nrays += 1
                ok, bx, by = _hit(xf, s if noncentral else 0.0, vx, vy, vz)
                if ok:
                    m = _material(bx, by, pat)
                    onboard = _on_board(bx, by, rect)
            v = values[m]
            # a tile that already holds v throughout (render_kernel's filled) is not written
            if not (filled[x0 // T] == v):
                # row slices: an element loop compiled to scattered stores
                for iy in range(r0, r1):
                    out[iy, x0:x1] = v
                filled[x0 // T] = v
            if onboard:
                nboard += (r1 - r0) * (x1 - x0)
            continue
        ntiles += 1
        filled[x0 // T] = math.nan
        # the centre rays the edge pixels read: theirs and their neighbours'
        for k in range(nk):
            for c in range(x1 - x0 + 2):
                need[k, c] = 0
        for iy in range(r0, r1):
            for ix in range(x0, x1):
                if mask[iy - r0, ix]:
                    k = iy - r0
                    c = ix - x0
                    for dk in range(3):
                        for dc in range(3):
                            need[k + dk, c + dc] = 1
        nrays += _trace_needed(cam, xf, noncentral, r0, x0, x1, nk, need, hx, hy, hok, hu,
                               hchi)
        if area:
            for j in range(r1 - r0 + 1):
                for i in range(x0, x1 + 1):
                    corners[0, j, i - x0] = math.nan
        for iy in range(r0, r1):
            ix = x0
            while ix < x1:
                k = iy - r0 + 1
                c = ix - x0 + 1
                if mask[iy - r0, ix]:
                    nedge += 1
                    if hok[k, c] and _on_board(hx[k, c], hy[k, c], rect):
                        nboard += 1
                    # the centre ray's Newton solve, traced above, starts the corners'
                    warm0 = (0.0, 0.0, 0.0, 0.0)
                    if not central:
                        warm0 = _warm_coefficients(cam, hu[k, c], hchi[k, c])
                    v, n, how = _render_pixel(cam, xf, ix, iy, k, c, hx, hy, hok, K, offs,
                                              counts, stack, jac, cand, values, pat, area, tol,
                                              hess, grid, poly, corners, warm0)
                    out[iy, ix] = v
                    # the only pixels that can be non-finite: the others are albedos
                    # (compile_pattern: in [0, 1])
                    w = out[iy, ix]
                    nonfinite += not (w - w == 0.0)
                    nrays += n
                    nsuper += how != 0
                    narea += how == 2
                    nfallback += how == 3
                    ix += 1
                    continue
                # a run of pixels that are not edge pixels, up to the next edge pixel: one
                # region, whose 2 m + on board comes from the pixel above the run's first one
                # when that is not an edge pixel either, else from the first one's centre ray
                if iy > r0 and not mask[iy - r0 - 1, ix]:
                    cd = code[iy - r0 - 1, ix - x0]
                else:
                    if need[k, c]:
                        ok = hok[k, c]
                        bx = hx[k, c]
                        by = hy[k, c]
                    else:
                        s, vx, vy, vz = ray_warm(cam, ix, iy, (math.nan, 0.0, 0.0, 0.0))
                        nrays += 1
                        ok, bx, by = _hit(xf, s if noncentral else 0.0, vx, vy, vz)
                    if ok:
                        cd = 2 * _material(bx, by, pat) + _on_board(bx, by, rect)
                    else:
                        cd = 2 * bg
                run = ix + 1
                while run < x1 and not mask[iy - r0, run]:
                    run += 1
                code[iy - r0, ix - x0:run - x0] = cd
                out[iy, ix:run] = values[cd // 2]
                nboard += (run - ix) * (cd % 2)
                ix = run
    _band_stats(stats, nrays, nsuper, nboard, ntiles, nedge, nonfinite, narea, nfallback)


@njit(cache=True, error_model="numpy")
def _count_nonfinite(out, r0, r1):
    r"""The number of non-finite pixels of rows r0..r1-1 (read while the band is in cache)"""
    n = 0
    for iy in range(r0, r1):
        for ix in range(out.shape[1]):
            v = out[iy, ix]
            n += not (v - v == 0.0)
    return n


@njit(cache=True, error_model="numpy")
def _band_stats(stats, nrays, nsuper, nboard, nblocks, ntested, nonfinite, narea, nfallback):
    r"""A band's row of render_kernel's stats (its docstring says what each column is)"""
    stats[0] = nrays
    stats[1] = nsuper
    stats[2] = nboard
    stats[3] = nblocks
    stats[4] = ntested
    stats[5] = nonfinite
    if stats.shape[0] > 6:
        stats[6] = narea
        stats[7] = nfallback


@intrinsic
def _borrowed(typingctx, a):
    r"""The array a without its reference count: the same data, shape and strides, no
meminfo (numba's reference counting skips a null meminfo)

Every array a compiled function receives or unpacks from a tuple is counted up on
entry and down on exit, an atomic operation on the array's shared meminfo, in every
per-pixel callee of the render (_render_pixel, _area_value, _area_pixel, _quad_value,
_clip_box, ...), and two threads counting the same arrays (cam, xf, values, pat)
contend for their cache lines. perf put ~28% of the compiled code's samples on those
atomic operations (area coverage, navcam 15, one thread); without them a render takes
~10% less CPU time. render_kernel hands its callees these borrowed arrays instead; its own
arguments and each thread's scratch arrays, which they alias, outlive them."""
    if not isinstance(a, types.Array):
        return None

    def codegen(context, builder, sig, args):
        src = context.make_array(a)(context, builder, value=args[0])
        dst = context.make_array(a)(context, builder)
        for name in ("nitems", "itemsize", "data", "shape", "strides"):
            setattr(dst, name, getattr(src, name))
        dst.meminfo = cgutils.get_null_value(dst.meminfo.type)
        dst.parent = cgutils.get_null_value(dst.parent.type)
        return dst._getvalue()

    return a(a), codegen


@intrinsic
def _take(typingctx, counter):
    r"""counter[0] += 1 atomically; returns its value before: the next band a thread
renders (render_kernel)"""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64):
        return None

    def codegen(context, builder, sig, args):
        ary = context.make_array(counter)(context, builder, value=args[0])
        ptr = cgutils.get_item_pointer(context, builder, counter, ary,
                                       [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1),
                                  "monotonic")

    return types.int64(counter), codegen


@njit(cache=True, error_model="numpy")
def _borrowed_scratch(scratch):
    r"""_band_scratch's arrays, _borrowed"""
    (hx, hy, hok, hu, hchi, need, code, blocks, bmask, btiles, counts, offs, stack, jac, cand,
     hess, grid, poly, corners) = scratch
    return (_borrowed(hx), _borrowed(hy), _borrowed(hok), _borrowed(hu), _borrowed(hchi),
            _borrowed(need), _borrowed(code), _borrowed(blocks), _borrowed(bmask),
            _borrowed(btiles), _borrowed(counts), _borrowed(offs), _borrowed(stack), _borrowed(jac),
            _borrowed(cand), _borrowed(hess), _borrowed(grid), _borrowed(poly),
            _borrowed(corners))


@njit(cache=True, error_model="numpy")
def _render_bands(taken, T, cam, noncentral, xf, K, adaptive, values, out, filled, stats, pat,
                  qbox, area, tol, outline_known, outline, owned):
    r"""Render the bands not taken yet, one at a time (taken[0]: the next band, _take), from
_borrowed arrays: no reference counting per pixel; the caller holds the arrays they
alias (its arguments and the thread's scratch arrays, owned) until this returns"""
    H = out.shape[0]
    scratch = _borrowed_scratch(owned)
    bcam = _borrowed(cam)
    bxf = _borrowed(xf)
    bvalues = _borrowed(values)
    bout = _borrowed(out)
    bfilled = _borrowed(filled)
    bstats = _borrowed(stats)
    bqbox = _borrowed(qbox)
    bpat = (_borrowed(pat[0]), _borrowed(pat[1]))
    boutline = (_borrowed(outline[0]), _borrowed(outline[1]), _borrowed(outline[2]),
                _borrowed(outline[3]))
    while True:
        b = _take(taken)
        if b >= stats.shape[0]:
            break
        r0 = b * T
        r1 = min(H, r0 + T)
        if r1 <= r0:
            continue
        if outline_known and adaptive:
            _render_band_outline(r0, r1, T, bcam, noncentral, bxf, K, bvalues, bout,
                                 bfilled[b], bstats[b], bpat, bqbox, area, tol, boutline,
                                 scratch)
        else:
            _render_band(r0, r1, T, bcam, noncentral, bxf, K, adaptive, bvalues, bout,
                         bfilled[b], bstats[b], bpat, bqbox, area, tol, scratch)


@njit(parallel=True, cache=True, error_model="numpy")
def render_kernel(cam, noncentral, xf, K, adaptive, T, values, out, filled, stats, pat, qbox,
                  nthreads, area, tol, outline_known, outline):
    r"""Render the image `out` (H,W) float32 in bands of T rows and tiles of T columns

filled (Nbands, Ntiles) float64: the albedo value every pixel of tile (band, column)
of `out` holds on entry, NaN where not known; a tile the render fills with that same
value is not written again (a buffer of an earlier image: renderers.memory.ImagePool),
and on return it says what the tiles hold (NaN for a tile of several values).

stats (Nbands,6) receives per band: rays traced, supersampled pixels, pixels
whose centre ray sees the board, blocks of pixels tested (outline: tiles with
edge pixels), pixels tested (outline: edge pixels),
non-finite pixels (a bug); with 8 columns also: pixels of area coverage, pixels
point sampled in area mode where area coverage was not computed.
area: edge pixels get their exact covered area (to within tol of the pixel's
area; see "Area coverage") instead of K x K point samples (adaptive only).
outline_known (adaptive only): the edge pixels are those of the projected outlines,
outline = (q, margin, bstart, chords) (band_chords): _render_band_outline; else
every tile is tested (_render_band: its ring's centre rays, its interior's when the
ring does not show it uniform, traced in it).
qbox (xmin, xmax, ymin, ymax): the image of the board lies inside (+-inf when
not known); adaptive mode fills the pixels outside with the background.
nthreads: numba's thread count; each thread renders the next band no thread has
taken yet until none is left (the bands cost what their edge pixels cost: a board in
one part of the image is shared out as the bands are done), with work arrays
allocated once. A band's pixels do not depend on which thread renders it."""
    W = out.shape[1]
    nthreads = max(1, min(nthreads, stats.shape[0]))
    taken = np.zeros(1, dtype=np.int64)
    for _ in prange(nthreads):
        # the scratch arrays live until _render_bands returns
        _render_bands(taken, T, cam, noncentral, xf, K, adaptive, values, out, filled, stats,
                      pat, qbox, area, tol, outline_known, outline,
                      _band_scratch(K, values.shape[0], T, W, area,
                                    outline_known and adaptive))


def compiled_entry_points():
    r'''The compiled kernels a ray-cast render calls from Python (numba dispatchers)

SYNOPSIS

    for kernel in compiled_entry_points():
        kernel.signatures     # what numba has compiled (or loaded from its cache)

render_kernel and band_chords: what a warm-up compiles (harness.warmup) and a
cache check looks for.
'''
    return (render_kernel, band_chords)

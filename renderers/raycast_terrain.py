r'''Exact ray casting of terrain height fields, with exact shadow rays (numba)

SYNOPSIS

    from renderers.raycast_terrain import render_terrain, trace_rays, cell_shadows
    from targets.terrain import make_terrain, ground_pose

    terrain = make_terrain(seed=0)
    r = render_terrain(model, terrain, Rt_ref_terrain=ground_pose(0.5), spp=1)
    # or through the registry: renderers.base.get_terrain_renderer("raycast_terrain")
    #     .render_terrain(model, terrain, ground_pose(0.5), RenderSettings(spp=1))
    r.image       # (H,W) float32 in [0,1]: Lambertian shading with the sun
    r.range       # (H,W) float64: distance along each pixel-centre ray to the surface (m); NaN: sky
    r.shadow      # (H,W) uint8: 0 lit, 1 facing away from the sun, 2 in a cast shadow, 255 sky
    r.metadata    # timings, rays, settings

    hit = trace_rays(terrain, origins, directions)   # any rays (...,3) in the terrain frame
    code = cell_shadows(terrain)    # (Ny-1, Nx-1, 2) uint8 per triangle centroid (terrain_shadows)

The surface is the triangle pair of each grid cell described in
targets/terrain.py, and a ray's intersection with it is exact (the nearest
hit, up to float64 rounding): the ray walks a maximum-height pyramid (each
cell of level k holds the highest node of its 2^k x 2^k cells), skipping every
cell the ray passes above, going down a level where it does not and up a
level when it enters a new parent cell, and at level 0 solves the ray against
the two triangle planes of the cell, keeping a hit inside the triangle. The
walk may start at any level without changing the hit; a pixel ray starts at
the level where the previous ray of its run first passed a cell (neighbouring
rays descend alike), instead of descending from the top every time.

A shadow ray needs any hit, not the nearest, and most are lit: it stops as
soon as it is above the sun bound of the cell it is in. The bound of a cell is
the highest cell of the strip it sweeps towards the sun less the rise of the
ray on the way there (_sun_bound), so a ray above it can meet no cell; it is
made once per terrain (and sun), kept with the pyramid, and a pyramid of it
lets the test run at every level. Lit shadow rays end after 1-2 cells instead
of climbing ~8 cells out of the height range.

Shading is Lambertian: radiance = exposure * albedo * (ambient + cos i * lit),
i the angle between the triangle's normal and the sun, lit = 0 when the shadow
ray from the hit point towards the sun meets the terrain (a cast shadow,
computed by the same exact intersection) or when cos i <= 0. Rays that miss
the terrain are sky (value `sky`, range NaN).

Pixel rays come from the camera model's own unproject (any CAHV, CAHVOR,
CAHVORE, including CAHVORE's moving entrance pupil), at K x K subpixel points
per pixel (spp = K); they are computed once per (model, K) and cached (with
the compiled unprojection of renderers._raycast_kernels when available). The
image is the mean over the subpixels; range and shadow are those of the
pixel-centre ray.

Speed (benchmarks/bench_terrain.py): a warm 1024x1024 render with shadows,
MER hazcam over a 21 x 24 m terrain of 5 cm cells, costs ~0.17 CPU s (0.09 s
wall on 2 free cores); a new process pays the pixel rays once per (model, K)
(~0.45 s for CAHVORE) and the pyramid and sun bound once per terrain (~0.07 s);
the kernels load from numba's cache.
'''

import math
import time

import numba
import numpy as np
from numba import njit, prange

from reference_models.errors import CamvalError
from renderers.base import RenderSettings, TerrainRender, merged_options
from renderers.terrain_shadows import ShadowCompareError, sample_points

NAME = "raycast_terrain"
SKY = 255
_RAY_CACHE = {}
_RAY_CACHE_SIZE = 4
_RAY_CACHE_BYTES = 1 << 30
# columns of the sunward strip examined per cell for the sun bound (_sun_bound)
SUN_BOUND_COLUMNS = 48


class TerrainRenderError(CamvalError):
    pass


# ---------------------------------------------------------------------------
# the maximum pyramid
def build_pyramid(heights):
    r'''Max-height pyramid of a (Ny,Nx) node grid, packed flat

RETURNED VALUE: (flat, offsets, nx, ny): level k is
flat[offsets[k]:offsets[k] + nx[k]*ny[k]].reshape(ny[k], nx[k]); level 0 holds
the highest of each cell's 4 nodes.
'''
    h = heights
    lvl = np.maximum(np.maximum(h[:-1, :-1], h[1:, :-1]), np.maximum(h[:-1, 1:], h[1:, 1:]))
    levels = [lvl]
    while lvl.shape[0] > 1 or lvl.shape[1] > 1:
        ny, nx = lvl.shape
        pad = np.full((ny + (ny & 1), nx + (nx & 1)), -np.inf)
        pad[:ny, :nx] = lvl
        lvl = np.maximum(np.maximum(pad[0::2, 0::2], pad[1::2, 0::2]),
                         np.maximum(pad[0::2, 1::2], pad[1::2, 1::2]))
        levels.append(lvl)
    sizes = [lv.size for lv in levels]
    offsets = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int64)
    flat = np.concatenate([lv.ravel() for lv in levels])
    nx = np.array([lv.shape[1] for lv in levels], np.int64)
    ny = np.array([lv.shape[0] for lv in levels], np.int64)
    return flat, offsets, nx, ny


@njit(cache=True, fastmath=False, inline="always")
def _cell_hit(u0, v0, oz, du, dv, dz, h, i, j, tmin, any_hit):
    r"""Nearest t >= tmin where a ray meets the two triangles of cell (i, j); inf if none

The ray is in grid units: x = x0 + (u0 + t du) cell, y = y0 + (v0 + t dv) cell,
z = oz + t dz, so (u0 - i + t du, v0 - j + t dv) are the cell's (u, v). Also
returns the triangle (0: u >= v, 1: u < v). any_hit: the first triangle met.
"""
    h00 = h[j, i]
    h10 = h[j, i + 1]
    h01 = h[j + 1, i]
    h11 = h[j + 1, i + 1]
    u0 = u0 - i
    v0 = v0 - j
    eps = 1e-9
    best = np.inf
    tri = -1
    for k in range(2):
        if k == 0:
            a = h00
            b = h10 - h00
            c = h11 - h10
        else:
            a = h00
            b = h11 - h01
            c = h01 - h00
        # oz + t dz = a + b (u0 + t du) + c (v0 + t dv)
        den = dz - b * du - c * dv
        num = a + b * u0 + c * v0 - oz
        if den == 0.0:
            continue
        t = num / den
        if not (t >= tmin) or t >= best:
            continue
        u = u0 + t * du
        v = v0 + t * dv
        if u < -eps or u > 1 + eps or v < -eps or v > 1 + eps:
            continue
        if k == 0 and u - v < -eps:
            continue
        if k == 1 and v - u < -eps:
            continue
        best = t
        tri = k
        if any_hit:
            break
    return best, tri


def _walk_pyramid(cells, tol):
    r"""A max pyramid of per-cell values laid out for the walk

SYNOPSIS

    flat, offs, width, rows, ncx, ncy = _walk_pyramid(cells, tol)   # cells (Ny-1,Nx-1)

Level 0 is cells + tol (tol: the walk's margin for rounding); each cell of
level k+1 holds the largest of its 2x2 cells of level k. Level k is
flat[offs[k]:offs[k] + width[k]*rows[k]] as rows of width[k]; a level below the
top stores twice the cells of the level above in each direction (padded with
-inf), so children 2i, 2i+1 of any cell exist; ncx[k], ncy[k] count its real
cells.
"""
    lv = np.asarray(cells, np.float64)
    levels, ncx, ncy = [], [], []
    while True:
        ny, nx = lv.shape
        ncx.append(nx)
        ncy.append(ny)
        if ny == 1 and nx == 1:
            levels.append(lv)
            break
        pad = np.full((ny + (ny & 1), nx + (nx & 1)), -np.inf)
        pad[:ny, :nx] = lv
        levels.append(pad)
        lv = np.maximum(np.maximum(pad[0::2, 0::2], pad[1::2, 0::2]),
                        np.maximum(pad[0::2, 1::2], pad[1::2, 1::2]))
    width = np.array([lv.shape[1] for lv in levels], np.int64)
    rows = np.array([lv.shape[0] for lv in levels], np.int64)
    offs = np.concatenate(([0], np.cumsum([lv.size for lv in levels])[:-1])).astype(np.int64)
    flat = np.concatenate([lv.ravel() for lv in levels]) + tol
    return flat, offs, width, rows, np.array(ncx, np.int64), np.array(ncy, np.int64)


def _cell_maxima(heights):
    h = heights
    return np.maximum(np.maximum(h[:-1, :-1], h[1:, :-1]), np.maximum(h[:-1, 1:], h[1:, 1:]))


def _sun_bound(mmax, sx, sy, k, zhi):
    r"""For each cell, a height above which the ray towards the sun from any point of
the cell meets no other cell

SYNOPSIS

    V = _sun_bound(mmax, sx, sy, k, zhi)   # mmax, V (Ny-1,Nx-1): cells' highest nodes

(sx, sy) is the sun's horizontal unit direction, k the rise of the ray per cell
of horizontal travel (tan(elevation) * cell), zhi the highest node. A ray from
a point of cell m stays in the strip that m sweeps towards the sun, and it
reaches a cell m' of the strip only after travelling at least r = p(m') -
pmax(m) cells (p: the coordinate along (sx, sy); p(m'): the lowest p of the
strip within m''s column, or m''s own lowest p), where it has risen k r. So V(m) = max over the
strip's cells of mmax(m') - k max(0, r) bounds what a ray from m can meet.
Beyond SUN_BOUND_COLUMNS columns (a low sun over a large relief) the rest of
the strip counts as the highest node: looser, still a bound, and the cost
stays below ~3 * SUN_BOUND_COLUMNS cells per cell.
"""
    if abs(sx) >= abs(sy):
        return _sun_bound_columns(mmax, sx, sy, k, zhi, SUN_BOUND_COLUMNS)
    # the same with x and y swapped
    return np.ascontiguousarray(
        _sun_bound_columns(np.ascontiguousarray(mmax.T), sy, sx, k, zhi, SUN_BOUND_COLUMNS).T)


@njit(parallel=True, cache=True)
def _sun_bound_columns(mmax, sx, sy, k, zhi, max_columns):
    r"""_sun_bound for |sx| >= |sy|: the strip is walked column by column"""
    ny, nx = mmax.shape
    out = np.empty((ny, nx))
    # extent of a cell along (sx, sy) (p) and across it (l = -x sy + y sx)
    plo = min(0.0, sx) + min(0.0, sy)
    phi = max(0.0, sx) + max(0.0, sy)
    llo = min(0.0, -sy) + min(0.0, sx)
    lhi = max(0.0, -sy) + max(0.0, sx)
    isx = 1.0 / sx
    step = 1 if sx > 0.0 else -1
    marg = 1e-9
    for j in prange(ny):
        for i in range(nx):
            pm1 = i * sx + j * sy + phi
            lm0 = -i * sy + j * sx + llo - marg
            lm1 = -i * sy + j * sx + lhi + marg
            v = mmax[j, i]
            ii = i
            while 0 <= ii < nx:
                # the strip within column ii: x in [ii, ii+1], l in [lm0, lm1];
                # y = (l + x sy) / sx and p = (x + l sy) / sx there
                ya = (lm0 + ii * sy) * isx
                yb = (lm0 + (ii + 1) * sy) * isx
                yc = (lm1 + ii * sy) * isx
                yd = (lm1 + (ii + 1) * sy) * isx
                pa = (ii + lm0 * sy) * isx
                pb = (ii + 1 + lm0 * sy) * isx
                pc = (ii + lm1 * sy) * isx
                pd = (ii + 1 + lm1 * sy) * isx
                reach = max(0.0, min(pa, pb, pc, pd) - marg - pm1)
                if zhi - k * reach <= v:
                    break
                if abs(ii - i) >= max_columns:
                    # the rest of the strip (a long way under a low sun): bounded by
                    # the highest node, risen to from here
                    v = max(v, zhi - k * reach)
                    break
                j0 = max(int(math.floor(min(ya, yb, yc, yd) - marg)), 0)
                j1 = min(int(math.floor(max(ya, yb, yc, yd) + marg)), ny - 1)
                for jj in range(j0, j1 + 1):
                    c = -ii * sy + jj * sx
                    if c + lhi < lm0 or c + llo > lm1:
                        continue
                    # the ray enters m' no nearer than m''s own lowest p either
                    p0 = ii * sx + jj * sy + plo - marg
                    w = mmax[jj, ii] - k * max(reach, p0 - pm1)
                    if w > v:
                        v = w
                ii += step
            out[j, i] = v
    return out


@njit(cache=True, inline="always")
def _child(i, t_next, g, gd, ig, near, s, t_after, n):
    r'''One axis of the step down the pyramid: the child index (of n) that holds the ray
just after t_after and the ray parameter of its next boundary on this axis

g, gd, ig: the ray's start, step and 1/step along the axis (grid units); s: the
child size; near: 0 for a ray going up the axis, 1 going down. The near child
when the ray crosses the middle line later than t_after, else the far one. A
child past the grid's edge (padding) holds the ray only within tol of the edge:
the real child next to it takes the ray instead.'''
    if gd == 0.0:
        return min(2 * i + (1 if g >= (2 * i + 1) * s else 0), n - 1), t_next
    tmid = ((2 * i + 1) * s - g) * ig
    if tmid > t_after:
        i = 2 * i + near
        if i >= n:
            return i - 1, t_next
        return i, tmid
    i = 2 * i + 1 - near
    if i >= n:
        return i - 1, tmid
    return i, t_next


@njit(cache=True, inline="always")
def _trace(ox, oy, oz, dx, dy, dz, tmin, tmax, h, x0, y0, cell,
           pyr, offs, pw, ph, pnx, pny, zlo, zhi, tol, start_level, any_hit, vpyr):
    r"""Nearest hit of one ray with the height field: (t, i, j, triangle, level)

(inf, -1, -1, -1, -1) if the ray misses. level: the level of the first cell
the ray passed over (-1 if none), a good start_level for a neighbouring ray.

The ray walks the pyramid of _walk_pyramid (cell maxima + tol) in grid units.
A cell the ray passes above is skipped; otherwise the walk goes down to the
child that holds the ray just after t (decided by where the ray crosses the
cell's middle lines), and at level 0 the cell's two triangles are solved
exactly (_cell_hit). Entering a new parent cell climbs one level. The walk
starts at level start_level (clipped to the top): the top for rays from afar,
0 for rays leaving the surface (shadow rays), which climb as they rise.
any_hit (shadow rays): the first triangle met in the first cell met, not
necessarily the nearer of the cell's two; and vpyr, if it has values, is the
pyramid (same layout) of _sun_bound: the ray goes towards the sun and misses
once it is above the bound of the cell it is in.
"""
    ny_nodes, nx_nodes = h.shape
    # grid units: cell (i, j) of level k spans [i, i+1] x [j, j+1] times 2^k
    icell = 1.0 / cell
    gx = (ox - x0) * icell
    gy = (oy - y0) * icell
    gdx = dx * icell
    gdy = dy * icell
    igx = 1.0 / gdx if gdx != 0.0 else np.inf
    igy = 1.0 / gdy if gdy != 0.0 else np.inf
    # every bound is widened by tol so rounding never lets a ray slip past a surface
    # that it grazes (a flat floor at the lowest height meets the z bound exactly)
    gtol = tol * icell
    t0 = tmin
    t1 = tmax
    # clip to the grid's box (x, y) and to the height range (z)
    if gdx != 0.0:
        ta = (-gtol - gx) * igx
        tb = (nx_nodes - 1 + gtol - gx) * igx
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    elif gx < -gtol or gx > nx_nodes - 1 + gtol:
        return np.inf, -1, -1, -1, -1
    if gdy != 0.0:
        ta = (-gtol - gy) * igy
        tb = (ny_nodes - 1 + gtol - gy) * igy
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    elif gy < -gtol or gy > ny_nodes - 1 + gtol:
        return np.inf, -1, -1, -1, -1
    if dz != 0.0:
        idz = 1.0 / dz
        ta = (zlo - tol - oz) * idz
        tb = (zhi + tol - oz) * idz
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    elif oz < zlo - tol or oz > zhi + tol:
        return np.inf, -1, -1, -1, -1
    if not (t0 <= t1):
        return np.inf, -1, -1, -1, -1

    if abs(gdx) < 1e-300 and abs(gdy) < 1e-300:
        # a vertical ray: one cell
        i = min(max(int(math.floor(gx)), 0), nx_nodes - 2)
        j = min(max(int(math.floor(gy)), 0), ny_nodes - 2)
        t, tri = _cell_hit(gx, gy, oz, gdx, gdy, dz, h, i, j, tmin, False)
        if t <= t1 + 1e-12:
            return t, i, j, tri, 0
        return np.inf, -1, -1, -1, -1
    # a step that moves the ray at least 1e-9 cells sideways: to leave a cell boundary
    nudge = 1e-9 * min(abs(igx), abs(igy))
    top = offs.size - 1
    level = min(max(start_level, 0), top)
    t = t0
    s = float(1 << level)
    tm = t + nudge
    # floor(g / 2^level) = floor(g) >> level
    ix = min(max(int(math.floor(gx + tm * gdx)) >> level, 0), pnx[level] - 1)
    iy = min(max(int(math.floor(gy + tm * gdy)) >> level, 0), pny[level] - 1)
    # tx, ty: the ray parameters where it crosses the cell's next x and y boundaries;
    # dtx, dty: the parameter across one cell of this level
    stepx = 1 if gdx > 0.0 else -1
    stepy = 1 if gdy > 0.0 else -1
    tx = ty = dtx = dty = np.inf
    if gdx != 0.0:
        tx = ((ix + (1 if gdx > 0.0 else 0)) * s - gx) * igx
        dtx = abs(s * igx)
    if gdy != 0.0:
        ty = ((iy + (1 if gdy > 0.0 else 0)) * s - gy) * igy
        dty = abs(s * igy)
    # which child of a cell the ray meets first along x (along y): 0 or 1
    nearx = 0 if gdx >= 0.0 else 1
    neary = 0 if gdy >= 0.0 else 1
    base = offs[level]
    wl = pw[level]
    hl = ph[level]
    first = -1
    bounded = vpyr.size > 0
    while True:
        if bounded and oz + (t - nudge) * dz > vpyr[base + iy * wl + ix]:
            break
        te = min(tx, ty, t1)
        if te < t:
            te = t
        # lowest point of the ray over [t - nudge, te] (z is linear in t)
        if dz < 0.0:
            zray = oz + te * dz
        else:
            zray = oz + (t - nudge) * dz
        if zray <= pyr[base + iy * wl + ix]:
            if level > 0:
                # down to the child holding the ray just after t: the near child when
                # the ray crosses the middle line later than that, else the far one
                level -= 1
                s *= 0.5
                base = offs[level]
                wl = pw[level]
                hl = ph[level]
                dtx *= 0.5
                dty *= 0.5
                # a child past the grid's edge (padding) holds the ray only within tol
                # of the edge: the real child next to it takes the ray instead
                ix, tx = _child(ix, tx, gx, gdx, igx, nearx, s, t + nudge, pnx[level])
                iy, ty = _child(iy, ty, gy, gdy, igy, neary, s, t + nudge, pny[level])
                continue
            th, tri = _cell_hit(gx, gy, oz, gdx, gdy, dz, h, ix, iy, tmin, any_hit)
            if th <= t1 + 1e-12:
                return th, ix, iy, tri, first
        # the ray passes this cell: on to the next one of the same level
        t = te
        if first < 0:
            first = level
        if t >= t1:
            break
        if tx <= ty:
            ix += stepx
            tx += dtx
            if ix < 0 or ix >= wl:
                break
            # entered a new parent cell (as its child met first along x): climb
            if level < top and (ix & 1) == nearx:
                level += 1
                s *= 2.0
                tx += dtx
                dtx *= 2.0
                if (iy & 1) == neary:
                    ty += dty
                dty *= 2.0
                ix >>= 1
                iy >>= 1
                base = offs[level]
                wl = pw[level]
                hl = ph[level]
        else:
            iy += stepy
            ty += dty
            if iy < 0 or iy >= hl:
                break
            if level < top and (iy & 1) == neary:
                level += 1
                s *= 2.0
                ty += dty
                dty *= 2.0
                if (ix & 1) == nearx:
                    tx += dtx
                dtx *= 2.0
                ix >>= 1
                iy >>= 1
                base = offs[level]
                wl = pw[level]
                hl = ph[level]
    return np.inf, -1, -1, -1, -1


@njit(cache=True, inline="always")
def _normal(h, i, j, tri, icell):
    if tri == 0:
        b = (h[j, i + 1] - h[j, i]) * icell
        c = (h[j + 1, i + 1] - h[j, i + 1]) * icell
    else:
        b = (h[j + 1, i + 1] - h[j + 1, i]) * icell
        c = (h[j + 1, i] - h[j, i]) * icell
    n = 1.0 / math.sqrt(b * b + c * c + 1.0)
    return -b * n, -c * n, n


@njit(cache=True, inline="always")
def _albedo(a, x, y, xmin, ymin, w, hgt):
    ty, tx = a.shape
    fx = min(max((x - xmin) / w * tx - 0.5, 0.0), tx - 1.0)
    fy = min(max((y - ymin) / hgt * ty - 0.5, 0.0), ty - 1.0)
    i = min(int(fx), max(tx - 2, 0))
    j = min(int(fy), max(ty - 2, 0))
    i1 = min(i + 1, tx - 1)
    j1 = min(j + 1, ty - 1)
    u = fx - i
    v = fy - j
    return ((1 - v) * ((1 - u) * a[j, i] + u * a[j, i1])
            + v * ((1 - u) * a[j1, i] + u * a[j1, i1]))


@njit(parallel=True, cache=True)
def _shade_rays(O, D, R, T, h, x0, y0, cell, pyr, offs, pw, ph, pnx, pny, zlo, zhi, tol, vpyr,
                albedo, sun, ambient, exposure, sky, shadows,
                out_value, out_t, out_code):
    N = O.shape[0]
    ny_nodes, nx_nodes = h.shape
    w = (nx_nodes - 1) * cell
    hgt = (ny_nodes - 1) * cell
    # runs of RUN neighbouring rays (they share cache lines of the grid and texture),
    # dealt round-robin to NW workers: neighbouring rays cost alike (sky, far or near
    # ground), so a contiguous split of the image would leave one thread idle
    RUN = 64
    NW = 64
    nruns = (N + RUN - 1) // RUN
    no_bound = vpyr[:0]
    for worker in prange(NW):
        for run in range(worker, nruns, NW):
            start = 1000
            for n in range(run * RUN, min(N, (run + 1) * RUN)):
                # into the terrain frame: p_t = R^T (p_ref - T)
                ax = O[n, 0] - T[0]
                ay = O[n, 1] - T[1]
                az = O[n, 2] - T[2]
                ox = R[0, 0] * ax + R[1, 0] * ay + R[2, 0] * az
                oy = R[0, 1] * ax + R[1, 1] * ay + R[2, 1] * az
                oz = R[0, 2] * ax + R[1, 2] * ay + R[2, 2] * az
                bx, by, bz = D[n, 0], D[n, 1], D[n, 2]
                dx = R[0, 0] * bx + R[1, 0] * by + R[2, 0] * bz
                dy = R[0, 1] * bx + R[1, 1] * by + R[2, 1] * bz
                dz = R[0, 2] * bx + R[1, 2] * by + R[2, 2] * bz
                if not (math.isfinite(ox) and math.isfinite(oy) and math.isfinite(oz)
                        and math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz)):
                    out_value[n] = sky
                    out_t[n] = np.nan
                    out_code[n] = 255
                    continue
                t, i, j, tri, lvl = _trace(ox, oy, oz, dx, dy, dz, 0.0, np.inf, h, x0, y0, cell,
                                           pyr, offs, pw, ph, pnx, pny, zlo, zhi, tol, start,
                                           False, no_bound)
                # the next ray of the run starts where this one first passed a cell
                # (any start level gives the same hit; this one saves the descent)
                start = lvl if lvl >= 0 else 1000
                if i < 0:
                    out_value[n] = sky
                    out_t[n] = np.nan
                    out_code[n] = 255
                    continue
                px = ox + t * dx
                py = oy + t * dy
                pz = oz + t * dz
                nx_, ny_, nz_ = _normal(h, i, j, tri, 1.0 / cell)
                cosi = nx_ * sun[0] + ny_ * sun[1] + nz_ * sun[2]
                code = 0
                if cosi <= 0.0:
                    code = 1
                    cosi = 0.0
                elif shadows:
                    # leave the surface along its normal by a hair: the hit triangle itself
                    # cannot be met again, as the sun is above its plane
                    off = 1e-7 * cell
                    ts, si, sj, stri, _ = _trace(px + off * nx_, py + off * ny_, pz + off * nz_,
                                              sun[0], sun[1], sun[2], 0.0, np.inf, h, x0, y0, cell,
                                              pyr, offs, pw, ph, pnx, pny, zlo, zhi, tol, 0, True,
                                                 vpyr)
                    if si >= 0:
                        code = 2
                        cosi = 0.0
                a = _albedo(albedo, px, py, x0, y0, w, hgt)
                out_value[n] = exposure * a * (ambient + cosi)
                out_t[n] = t
                out_code[n] = code


def _prepared(terrain, shadows=True):
    r"""The walk's pyramid of a terrain and (for shadows) the pyramid of its sun bound

Made once per terrain (kept on the terrain object; the sun bound only once
shadows are asked for): (flat, offs, width, rows, ncx, ncy, zlo, zhi, tol, vpyr),
vpyr empty without shadows.
"""
    cached = getattr(terrain, "_raycast_walk", None)
    if cached is None or cached[0] != id(terrain):
        zlo, zhi = float(terrain.heights.min()), float(terrain.heights.max())
        tol = 1e-9 * max(1.0, zhi - zlo, terrain.cell)
        walk = _walk_pyramid(_cell_maxima(terrain.heights), tol) + (zlo, zhi, tol)
        cached = (id(terrain), walk, {})
        object.__setattr__(terrain, "_raycast_walk", cached)
    _, walk, bound = cached
    if not shadows:
        return walk + (np.empty(0),)
    if "vpyr" not in bound:
        zhi, tol = walk[7], walk[8]
        sun = terrain.sun.direction()
        horizontal = math.hypot(sun[0], sun[1])
        if horizontal < 1e-12:
            bound["vpyr"] = walk[0]     # the sun at the zenith: only the cell itself shades
        else:
            V = _sun_bound(_cell_maxima(terrain.heights), sun[0] / horizontal, sun[1] / horizontal,
                           sun[2] / horizontal * terrain.cell, zhi)
            bound["vpyr"] = _walk_pyramid(V, tol)[0]
    return walk + (bound["vpyr"],)


def trace_rays(terrain, origins, directions, shadows=True, exposure=1.0, sky=0.0,
               Rt_ref_terrain=None):
    r'''Trace rays and shade their hits

SYNOPSIS

    value, t, code = trace_rays(terrain, origins, directions)
    # origins, directions (...,3) (directions need not be unit; t is in units of |d|)
    # value (...) float64 shading; t (...) ray parameter of the hit (NaN: miss)
    # code (...) uint8 0 lit, 1 facing away from the sun, 2 cast shadow, 255 miss

The rays are in the terrain frame, or in a frame "ref" if Rt_ref_terrain (4,3)
is given. Rays with non-finite numbers miss.
'''
    O = np.asarray(origins, np.float64)
    D = np.asarray(directions, np.float64)
    O, D = np.broadcast_arrays(O, D)
    shape = O.shape[:-1]
    O = np.ascontiguousarray(O.reshape(-1, 3))
    D = np.ascontiguousarray(D.reshape(-1, 3))
    Rt = _identity_Rt() if Rt_ref_terrain is None else _check_Rt(Rt_ref_terrain)
    flat, offs, pw, ph, pnx, pny, zlo, zhi, tol, vpyr = _prepared(terrain, bool(shadows))
    N = O.shape[0]
    value = np.empty(N)
    t = np.empty(N)
    code = np.empty(N, np.uint8)
    x0, y0 = terrain.origin
    _shade_rays(O, D, np.ascontiguousarray(Rt[:3]), np.ascontiguousarray(Rt[3]),
                terrain.heights, x0, y0, terrain.cell, flat, offs, pw, ph, pnx, pny, zlo, zhi, tol,
                vpyr,
                terrain.albedo, terrain.sun.direction(), float(terrain.ambient),
                float(exposure), float(sky), bool(shadows), value, t, code)
    return value.reshape(shape), t.reshape(shape), code.reshape(shape)


def _identity_Rt():
    return np.vstack((np.eye(3), np.zeros(3)))


def _check_Rt(Rt):
    Rt = np.asarray(Rt, np.float64)
    if Rt.shape != (4, 3) or not np.all(np.isfinite(Rt)):
        raise TerrainRenderError(
            f"Rt_ref_terrain must be a finite (4,3) array; got shape {Rt.shape}")
    if not np.allclose(Rt[:3].T @ Rt[:3], np.eye(3), atol=1e-9):
        raise TerrainRenderError("Rt_ref_terrain's rotation (its first 3 rows) is not orthonormal")
    return Rt


# ---------------------------------------------------------------------------
# camera rays
def _unproject(model, q):
    r'''model.unproject, by the board ray caster's compiled port when it is there
(renderers._raycast_kernels: the same Newton solves, agreeing to ~1e-15)'''
    try:
        from renderers._raycast_kernels import pack_model, unproject_grid
    except ImportError:
        return model.unproject(q)
    return unproject_grid(pack_model(model), q)


def pixel_rays(model, spp=1):
    r'''Rays of a camera model through K x K subpixel points of every pixel

SYNOPSIS

    origins, v = pixel_rays(model, spp=K)
    # origins, v have shape (H*W, K*K, 3) in the model's frame; |v| = 1

Subpixel points are at offsets (k + 1/2)/K - 1/2 (k = 0..K-1) from the pixel
centre (reference_models.conventions). Cached per (model, K): at most
_RAY_CACHE_SIZE cameras and _RAY_CACHE_BYTES of rays, least recently used
dropped first.
'''
    key = (repr(model), int(spp))
    hit = _RAY_CACHE.pop(key, None)
    if hit is not None:
        _RAY_CACHE[key] = hit           # the most recently used goes last
        return hit
    W, Hh = model.width, model.height
    off = (np.arange(spp) + 0.5) / spp - 0.5
    ox, oy = np.meshgrid(off, off)
    sub = np.stack((ox.ravel(), oy.ravel()), axis=-1)                  # (K*K,2)
    from reference_models.conventions import pixel_centres
    q = pixel_centres(W, Hh).reshape(-1, 1, 2) + sub[None]              # (H*W,K*K,2)
    origins, v = _unproject(model, q)
    origins = np.ascontiguousarray(origins)
    v = np.ascontiguousarray(v)
    # keep at most _RAY_CACHE_SIZE entries and _RAY_CACHE_BYTES (a 1024x1024 camera at
    # K = 4 holds 0.8 GB of rays), dropping the least recently used first
    size = origins.nbytes + v.nbytes
    while _RAY_CACHE and (len(_RAY_CACHE) >= _RAY_CACHE_SIZE or size + sum(
            a.nbytes + b.nbytes for a, b in _RAY_CACHE.values()) > _RAY_CACHE_BYTES):
        _RAY_CACHE.pop(next(iter(_RAY_CACHE)))
    _RAY_CACHE[key] = (origins, v)
    return origins, v


def render_terrain(model, terrain, Rt_ref_terrain=None, spp=1, shadows=True,
                   exposure=1.0, sky=0.0):
    r'''Render a terrain through a camera model

SYNOPSIS

    r = render_terrain(model, terrain, Rt_ref_terrain, spp=1, shadows=True)
    # r.image (H,W) float32 in [0,1]; r.range (H,W) metres along the pixel-centre
    # ray from its origin (NaN: sky); r.shadow (H,W) uint8 (0 lit, 1 self, 2 cast, 255 sky)

Rt_ref_terrain (4,3) places the terrain (z up) in the model's frame
(targets.terrain.ground_pose for a z-down rover frame); identity if None.
spp is K: K x K rays per pixel for the image. exposure scales the radiance;
sky is the value of rays that miss the terrain. Values are clipped to [0,1].
'''
    if isinstance(spp, bool) or not isinstance(spp, int) or spp < 1:
        raise TerrainRenderError(f"supersampling K must be a positive integer; got {spp!r}")
    Rt = _identity_Rt() if Rt_ref_terrain is None else _check_Rt(Rt_ref_terrain)
    W, Hh = model.width, model.height
    t_start = time.perf_counter()
    o, v = pixel_rays(model, spp)
    t_rays = time.perf_counter()
    _prepared(terrain, bool(shadows))
    t_prep = time.perf_counter()
    value, t, code = trace_rays(terrain, o, v, shadows=shadows, exposure=exposure, sky=sky,
                                Rt_ref_terrain=Rt)
    K2 = spp * spp
    image = value.reshape(Hh, W) if spp == 1 else value.reshape(Hh, W, K2).mean(axis=-1)
    image = np.clip(image, 0.0, 1.0, out=image).astype(np.float32)
    if spp == 1:
        rng, shadow = t.reshape(Hh, W), code.reshape(Hh, W)
    elif spp % 2 == 1:
        c = K2 // 2
        rng, shadow = t.reshape(Hh, W, K2)[..., c], code.reshape(Hh, W, K2)[..., c]
    else:
        oc, vc = pixel_rays(model, 1)
        _, tc, cc = trace_rays(terrain, oc, vc, shadows=shadows, Rt_ref_terrain=Rt)
        rng, shadow = tc.reshape(Hh, W), cc.reshape(Hh, W)
    t_end = time.perf_counter()
    return TerrainRender(
        image=image,
        range=np.ascontiguousarray(rng, dtype=np.float64),
        shadow=np.ascontiguousarray(shadow),
        metadata={"renderer": NAME, "version": f"numba {numba.__version__}",
                  "spp": spp, "shadows": bool(shadows), "exposure": exposure,
                  "rays": int(value.size), "threads": numba.get_num_threads(),
                  "seconds": t_end - t_start, "seconds_rays": t_rays - t_start,
                  "seconds_prepare": t_prep - t_rays, "seconds_trace": t_end - t_prep,
                  "surface": "triangle pair per cell",
                  "terrain": terrain.as_dict()})


def cell_shadows(terrain):
    r'''Exact shadow codes at the triangle centroids (renderers.terrain_shadows)

SYNOPSIS

    code = cell_shadows(terrain)    # (Ny-1, Nx-1, 2) uint8: 0 lit, 1 facing away, 2 cast

A vertical ray from above each centroid meets the surface at the centroid;
the exact shadow ray is traced from there.
'''
    x, y = sample_points(terrain)
    top = float(terrain.heights.max()) + 1.0
    origins = np.stack((x, y, np.full_like(x, top)), axis=-1)
    _, t, code = trace_rays(terrain, origins, np.array([0.0, 0.0, -1.0]))
    if np.any(code == 255):
        raise ShadowCompareError("a vertical ray from above a cell centroid missed the terrain "
                                 "(raycast_terrain's intersection failed)")
    return code


class RaycastTerrainRenderer:
    r'''The exact terrain ray caster as a renderer of terrain scenes
(renderers.base.TerrainRenderer)

SYNOPSIS

    r = RaycastTerrainRenderer(shadows=True, exposure=1.0, sky=0.0)
    result = r.render_terrain(model, terrain, Rt_ref_terrain, RenderSettings(spp=2))
    code = r.cell_shadows(terrain)

ARGUMENTS (defaults for every render; RenderSettings.options override them):
render_terrain's shadows, exposure and sky. settings.spp is K (settings None:
K = 1); RenderSettings.adaptive does not apply (every pixel gets K x K rays).
'''

    name = NAME
    scenes = ("terrain",)

    def __init__(self, shadows=True, exposure=1.0, sky=0.0):
        self.defaults = dict(shadows=shadows, exposure=exposure, sky=sky)

    def version(self):
        return f"numba {numba.__version__}"

    def render_terrain(self, model, terrain, Rt_ref_terrain=None, settings=None):
        settings = settings or RenderSettings(spp=1)
        return render_terrain(model, terrain, Rt_ref_terrain, spp=settings.spp,
                              **merged_options(self.name, self.defaults, settings))

    def cell_shadows(self, terrain):
        return cell_shadows(terrain)

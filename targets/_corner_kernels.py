r'''Compiled pixel-area model of targets.corners (numba): the refiner's hot loop

SYNOPSIS

    from targets._corner_kernels import wedge_model

    D, dD_dc, dD_dt, dD_ds = wedge_model(centres, s, c, uu, first, second, widen,
                                         Z, W, dZ, dW)
    # centres (n,P,2) pixel centres of every window; s (m,) the corners to evaluate;
    # c (m,2) their apexes; uu (m,R,2) their unit rays; first, second (n,Nw) ray indices
    # of each wedge (counter-clockwise, below pi); Z (m,M,2) offsets (px) and W (m,M)
    # weights of each corner's blur kernel, dZ, dW their derivatives in the blur's sigma
    # (targets.corners.blur_kernel); D (m,P), dD_dc (m,P,2), dD_dt (m,P,R), dD_ds (m,P)
    JtJ, Jtr = normal_equations(D, dD_dc, dD_dt, b, w, r)   # the fit's normal equations
    A = lm_system(s, JtJ, lam)              # damped, of the corners s
    a, b, S, r = light_levels(s, D, w, v)   # light level, contrast, misfit, residuals
    lm_accept(s, step, S1, c1, t1, g1, D1, ..., JtJ, Jtr, px, wpx)  # accept/damp/converge
    inside, on_image = window_mask(ix, iy, q0, Ainv, half_box, notch, max_px,
                                   lines_box, strip_px, lines_px, H, W)
    finite, lo, hi, img8 = image_range_u8(img, scale)   # targets.detection.working_image

With M > 1 the dark area of each pixel is blurred: D = sum_q W_q A(d + Z_q), the
kernel's expectation of the exact pixel area A; pixels far from every ray take A once
(it is constant over the offsets). Taps at whole-pixel offsets (the "sampled" kind) are
sharp pixels of the window's box: each is clipped once and shared by the taps that land
on it (_grid_wedge_model).

The same arithmetic as targets.corners.wedge_area / _ray_stretch (the numpy reference),
one pixel at a time, in the same order of operations, so the two agree to rounding
(tests/test_corners.py holds them within 1e-12 px on refined corners). A pixel that a ray
misses by far (most of a window) skips that ray's clipping, whose result is then known
exactly (_pixel_wedge). The rays' cos/sin
stay in numpy (the caller passes uu) so that both paths start from identical directions.
'''

import numpy as np
from numba import njit, types
from numba.extending import overload

# the pixel square's corners relative to its centre, counter-clockwise (as corners._SQUARE)
_SX = (-0.5, 0.5, 0.5, -0.5)
_SY = (-0.5, -0.5, 0.5, 0.5)


@njit(cache=True, error_model="numpy", inline="always")
def _stretch(dx, dy, ux, uy, half):
    # corners._ray_stretch for one pixel: Liang-Barsky clipping of the ray s u, s >= 0
    lo = 0.0
    hi = np.inf
    for k in range(2):
        if k == 0:
            uk, dk = ux, dx
        else:
            uk, dk = uy, dy
        a = dk - half
        b = dk + half
        if uk == 0.0:
            if a <= 0.0 and b >= 0.0:
                t0, t1 = -np.inf, np.inf
            else:
                t0, t1 = np.inf, -np.inf
        elif uk > 0.0:
            t0, t1 = a / uk, b / uk
        else:
            t0, t1 = b / uk, a / uk
        lo = max(lo, t0)
        hi = min(hi, t1)
    if not (hi > lo) or not np.isfinite(hi):
        return 0.0, 0.0
    return lo, hi


@njit(cache=True, error_model="numpy", inline="always")
def _area(dx, dy, u1x, u1y, u2x, u2y):
    # corners.wedge_area (the area only) for one pixel centre d relative to the apex
    A = 0.0
    for k in range(4):
        px = dx + _SX[k]
        py = dy + _SY[k]
        qx = dx + _SX[(k + 1) % 4]
        qy = dy + _SY[(k + 1) % 4]
        ex = qx - px
        ey = qy - py
        t0 = 0.0
        t1 = 1.0
        for h in range(2):
            if h == 0:
                vx, vy = u1x, u1y
            else:
                vx, vy = -u2x, -u2y
            f0 = vx * py - vy * px
            g = vx * ey - vy * ex
            if g > 0.0:
                t0 = max(t0, -f0 / g)
            elif g < 0.0:
                t1 = min(t1, -f0 / g)
            elif f0 < 0.0:
                t1 = t0
        frac = max(t1 - t0, 0.0)
        A += frac * (px * qy - py * qx)
    return 0.5 * A


@njit(cache=True, error_model="numpy", inline="always")
def _square_area(dx, dy):
    # _area of a pixel the wedge holds whole: every edge's fraction is exactly 1 there, so
    # this is _area's sum with the clipping left out, the same products in the same order
    A = 0.0
    for k in range(4):
        px = dx + _SX[k]
        py = dy + _SY[k]
        qx = dx + _SX[(k + 1) % 4]
        qy = dy + _SY[(k + 1) % 4]
        A += px * qy - py * qx
    return 0.5 * A


@njit(cache=True, error_model="numpy", inline="always")
def _ray_distance(dx, dy, ux, uy):
    # distance (px) from a pixel centre d (relative to the apex) to the ray s u, s >= 0
    if ux * dx + uy * dy < 0.0:
        return np.sqrt(dx * dx + dy * dy)
    return abs(ux * dy - uy * dx)


# a ray farther than this (px) beyond a square's circumscribed circle misses the square by
# far more than the rounding of the clipping arithmetic (1e-15 px): _area's clipping then
# gives every edge of the square a fraction of exactly 0 or 1, and _stretch (0, 0): what
# _pixel_wedge returns there without clipping is what the clipping gives, bit for bit
_MISS_MARGIN_PX = 1e-6
# the least sin of a wedge's angle for which _pixel_wedge decides a far pixel's side
# without clipping: a centre 0.7 px from both rays is then 7e-10 px or more from each
# line it must be told from, against ~1e-15 px of rounding
_MIN_WEDGE_SIN = 1e-9


@njit(cache=True, error_model="numpy", inline="always")
def _pixel_wedge(dx, dy, u1x, u1y, u2x, u2y, half):
    # (A, s0a, s1a, s0b, s1b): _area of the pixel centred at d (relative to the apex) and
    # _stretch of both rays over its square widened to half. Where a ray is farther than a
    # square's circumscribed circle (plus _MISS_MARGIN_PX) its clipping is known without
    # computing it (most pixels of a window): _stretch gives (0, 0), and a square that
    # both rays miss is wholly inside the wedge (its area: _square_area) or outside (0).
    # The latter only while the rays turn by less than pi from u1 to u2 (sin above
    # _MIN_WEDGE_SIN): the wedge is then the region between the rays (a fit whose rays
    # crossed has the region between their backward extensions), and the centre's side of
    # each ray's line is decided far above rounding
    d1 = _ray_distance(dx, dy, u1x, u1y)
    d2 = _ray_distance(dx, dy, u2x, u2y)
    r_area = np.sqrt(2.0) * 0.5 + _MISS_MARGIN_PX
    r_stretch = np.sqrt(2.0) * half + _MISS_MARGIN_PX
    if d1 > r_area and d2 > r_area and u1x * u2y - u1y * u2x > _MIN_WEDGE_SIN:
        # wholly inside the wedge when its centre is: cross(u1, d) >= 0, cross(d, u2) >= 0
        if u1x * dy - u1y * dx >= 0.0 and dx * u2y - dy * u2x >= 0.0:
            A = _square_area(dx, dy)
        else:
            A = 0.0
    else:
        A = _area(dx, dy, u1x, u1y, u2x, u2y)
    s0a, s1a = _stretch(dx, dy, u1x, u1y, half) if d1 <= r_stretch else (0.0, 0.0)
    s0b, s1b = _stretch(dx, dy, u2x, u2y, half) if d2 <= r_stretch else (0.0, 0.0)
    return A, s0a, s1a, s0b, s1b


@njit(cache=True, error_model="numpy", inline="always")
def _sharp_pixel(j, n, p, dx, dy, uu, first, second, half, D, dD_dc, dD_dt):
    # wedge_model's sharp pixel (no blur offset, weight 1: the same numbers as its general
    # loop); a pixel that neither ray of a wedge crosses adds +-0 to every derivative,
    # which changes no sum: left out
    for k in range(first.shape[1]):
        i1 = first[n, k]
        i2 = second[n, k]
        u1x, u1y = uu[j, i1, 0], uu[j, i1, 1]
        u2x, u2y = uu[j, i2, 0], uu[j, i2, 1]
        A, s0a, s1a, s0b, s1b = _pixel_wedge(dx, dy, u1x, u1y, u2x, u2y, half)
        D[j, p] += A
        la = s1a - s0a
        lb = s1b - s0b
        if la == 0.0 and lb == 0.0:
            continue
        gx = -la * -u1y + lb * -u2y
        gy = -la * u1x + lb * u2x
        dD_dc[j, p, 0] += gx
        dD_dc[j, p, 1] += gy
        dD_dt[j, p, i1] += -0.5 * (s1a ** 2 - s0a ** 2)
        dD_dt[j, p, i2] += 0.5 * (s1b ** 2 - s0b ** 2)


@njit(cache=True, error_model="numpy")
def _on_pixel_grid(Z, dZ):
    # a blur kernel whose taps sit at whole-pixel offsets that sigma does not move (the
    # "sampled" kind: a blur of the pixel image)
    for x in Z.ravel():
        if x != np.floor(x):
            return False
    for x in dZ.ravel():
        if x != 0.0:
            return False
    return True


@njit(cache=True, error_model="numpy")
def _grid_wedge_model(centres, s, c, uu, first, second, widen, Z, W, dW):
    # wedge_model for taps at whole-pixel offsets (_on_pixel_grid): pixel p's tap q is the
    # sharp pixel at p + Z_q, so the sharp area and its derivatives are evaluated once per
    # pixel of the window's box grown by the taps' reach (_sharp_pixel), and each window
    # pixel sums its taps' weights over them: 25 taps at sigma 0.7 px clipped ~1 time per
    # pixel instead of 25 (the same sums to rounding: the offset is added to the integer
    # centre, then the apex subtracted)
    m = len(s)
    P = centres.shape[1]
    R = uu.shape[1]
    M = W.shape[1]
    half = 0.5 + widen
    # each corner's box: the window's pixels grown by the reach of its taps
    box = np.zeros((m, 4), np.int64)
    ncell = 1
    for j in range(m):
        n = s[j]
        reach = 0
        for q in range(M):
            if W[j, q] != 0.0 or dW[j, q] != 0.0:
                reach = max(reach, int(abs(Z[j, q, 0])), int(abs(Z[j, q, 1])))
        x0 = y0 = np.iinfo(np.int64).max
        x1 = y1 = np.iinfo(np.int64).min
        for p in range(P):
            x, y = int(centres[n, p, 0]), int(centres[n, p, 1])
            x0, x1, y0, y1 = min(x0, x), max(x1, x), min(y0, y), max(y1, y)
        box[j, 0], box[j, 1] = x0 - reach, y0 - reach
        box[j, 2], box[j, 3] = x1 - x0 + 2 * reach + 1, y1 - y0 + 2 * reach + 1
        ncell = max(ncell, box[j, 2] * box[j, 3])
    # one corner's cells at a time, only those a window pixel's tap lands on (a chessboard
    # corner's window of strips along its lines has a box mostly of cells no tap needs)
    GA = np.zeros((1, ncell))
    Gc = np.zeros((1, ncell, 2))
    Gt = np.zeros((1, ncell, R))
    need = np.zeros(ncell, np.bool_)
    live = np.zeros(ncell, np.bool_)
    D = np.zeros((m, P))
    dD_dc = np.zeros((m, P, 2))
    dD_dt = np.zeros((m, P, R))
    dD_ds = np.zeros((m, P))
    for j in range(m):
        n = s[j]
        x0, y0, nx, ny = box[j, 0], box[j, 1], box[j, 2], box[j, 3]
        need[:nx * ny] = False
        for p in range(P):
            px = int(centres[n, p, 0]) - x0
            py = int(centres[n, p, 1]) - y0
            for q in range(M):
                if W[j, q] != 0.0 or dW[j, q] != 0.0:
                    need[(py + int(Z[j, q, 1])) * nx + px + int(Z[j, q, 0])] = True
        for k in range(nx * ny):
            if need[k]:
                GA[0, k] = 0.0
                Gc[0, k, 0] = 0.0
                Gc[0, k, 1] = 0.0
                for i in range(R):
                    Gt[0, k, i] = 0.0
                iy, ix = k // nx, k % nx
                _sharp_pixel(0, n, k, (x0 + ix) - c[j, 0], (y0 + iy) - c[j, 1],
                             uu[j:j + 1], first, second, half, GA, Gc, Gt)
                # a cell no ray crosses has +-0 derivatives: adding them changes no sum
                live[k] = Gc[0, k, 0] != 0.0 or Gc[0, k, 1] != 0.0
                for i in range(R):
                    live[k] = live[k] or Gt[0, k, i] != 0.0
        for p in range(P):
            px = int(centres[n, p, 0]) - x0
            py = int(centres[n, p, 1]) - y0
            for q in range(M):
                wq = W[j, q]
                dwq = dW[j, q]
                if wq == 0.0 and dwq == 0.0:
                    continue
                k = (py + int(Z[j, q, 1])) * nx + px + int(Z[j, q, 0])
                D[j, p] += wq * GA[0, k]
                dD_ds[j, p] += dwq * GA[0, k]
                if not live[k]:
                    continue
                dD_dc[j, p, 0] += wq * Gc[0, k, 0]
                dD_dc[j, p, 1] += wq * Gc[0, k, 1]
                for i in range(R):
                    dD_dt[j, p, i] += wq * Gt[0, k, i]
    return D, dD_dc, dD_dt, dD_ds


@njit(cache=True, error_model="numpy")
def wedge_model(centres, s, c, uu, first, second, widen, Z, W, dZ, dW):
    if W.shape[1] > 1 and _on_pixel_grid(Z, dZ):
        return _grid_wedge_model(centres, s, c, uu, first, second, widen, Z, W, dW)
    m = len(s)
    P = centres.shape[1]
    R = uu.shape[1]
    Nw = first.shape[1]
    M = W.shape[1]
    D = np.zeros((m, P))
    dD_dc = np.zeros((m, P, 2))
    dD_dt = np.zeros((m, P, R))
    dD_ds = np.zeros((m, P))
    half = 0.5 + widen
    for j in range(m):
        n = s[j]
        blurred = M > 1
        rmax = 0.0
        for k in range(M):
            rmax = max(rmax, np.sqrt(Z[j, k, 0] ** 2 + Z[j, k, 1] ** 2))
        # a pixel farther than this from every ray (px) sees the same dark area at every
        # offset: one evaluation, no derivatives
        reach = np.sqrt(2.0) * half + rmax
        for p in range(P):
            dx0 = centres[n, p, 0] - c[j, 0]
            dy0 = centres[n, p, 1] - c[j, 1]
            near = not blurred
            if blurred:
                for k in range(Nw):
                    for h in range(2):
                        if h == 0:
                            ux, uy = uu[j, first[n, k], 0], uu[j, first[n, k], 1]
                        else:
                            ux, uy = uu[j, second[n, k], 0], uu[j, second[n, k], 1]
                        t = ux * dx0 + uy * dy0
                        if t < 0.0:
                            dist = np.sqrt(dx0 * dx0 + dy0 * dy0)
                        else:
                            dist = abs(ux * dy0 - uy * dx0)
                        if dist <= reach:
                            near = True
            if blurred and not near:
                # sum W = 1 over the kernel, but the derivatives are 0: A is constant here
                for k in range(Nw):
                    i1 = first[n, k]
                    i2 = second[n, k]
                    D[j, p] += _area(dx0, dy0, uu[j, i1, 0], uu[j, i1, 1],
                                     uu[j, i2, 0], uu[j, i2, 1])
                continue
            if not blurred:
                # sharp: most of a window is a pixel no ray comes near, dark or light whole
                # (D exactly 0 or its square's area, no derivative): _sharp_pixel skips the
                # clipping there, with the same numbers as the general loop below
                _sharp_pixel(j, n, p, dx0, dy0, uu, first, second, half, D, dD_dc, dD_dt)
                continue
            for q in range(M if blurred else 1):
                if blurred and W[j, q] == 0.0 and dW[j, q] == 0.0:
                    continue
                if blurred:
                    zx = Z[j, q, 0]
                    zy = Z[j, q, 1]
                    wq = W[j, q]
                else:
                    zx = 0.0
                    zy = 0.0
                    wq = 1.0
                dx = dx0 + zx
                dy = dy0 + zy
                for k in range(Nw):
                    i1 = first[n, k]
                    i2 = second[n, k]
                    u1x, u1y = uu[j, i1, 0], uu[j, i1, 1]
                    u2x, u2y = uu[j, i2, 0], uu[j, i2, 1]
                    A, s0a, s1a, s0b, s1b = _pixel_wedge(dx, dy, u1x, u1y, u2x, u2y, half)
                    D[j, p] += wq * A
                    la = s1a - s0a
                    lb = s1b - s0b
                    # -la perp(u1) + lb perp(u2), perp(u) = (-u_y, u_x)
                    gx = -la * -u1y + lb * -u2y
                    gy = -la * u1x + lb * u2x
                    dD_dc[j, p, 0] += wq * gx
                    dD_dc[j, p, 1] += wq * gy
                    dD_dt[j, p, i1] += wq * -0.5 * (s1a ** 2 - s0a ** 2)
                    dD_dt[j, p, i2] += wq * 0.5 * (s1b ** 2 - s0b ** 2)
                    if blurred:
                        # sigma moves the offset (dZ: -dA/dc . dZ) and reweighs it (dW)
                        dD_ds[j, p] += dW[j, q] * A - wq * (gx * dZ[j, q, 0]
                                                            + gy * dZ[j, q, 1])
    return D, dD_dc, dD_dt, dD_ds


@njit(cache=True, error_model="numpy", inline="always")
def _corner_sums(JtJ, Jtr, n, D, dD_dc, dD_dt, j, bn, w, r, J):
    # J^T W J and J^T W r of corner n (rows n of JtJ, Jtr, w) from row j of its model D,
    # dD_dc, dD_dt and residuals r, contrast bn; J a scratch (K,)
    P = D.shape[1]
    R = dD_dt.shape[2]
    K = 4 + R
    JtJ[n, :, :] = 0.0
    Jtr[n, :] = 0.0
    for p in range(P):
        wp = w[n, p]
        if wp == 0.0:
            continue
        J[0] = 1.0
        J[1] = D[j, p]
        J[2] = bn * dD_dc[j, p, 0]
        J[3] = bn * dD_dc[j, p, 1]
        for k in range(R):
            J[4 + k] = bn * dD_dt[j, p, k]
        rp = r[j, p]
        # a pixel no ray crosses (most of a sharp window) has no geometric derivative:
        # its +-0 terms leave every sum as it is, so only (1, D) are accumulated
        flat = rp - rp == 0.0
        for k in range(2, K):
            if J[k] != 0.0:
                flat = False
                break
        if flat:
            Jtr[n, 0] += wp * rp
            JtJ[n, 0, 0] += wp
            JtJ[n, 0, 1] += wp * J[1]
            jw = J[1] * wp
            Jtr[n, 1] += jw * rp
            JtJ[n, 1, 1] += jw * J[1]
            continue
        for k in range(K):
            jw = J[k] * wp
            Jtr[n, k] += jw * rp
            for ll in range(k, K):
                JtJ[n, k, ll] += jw * J[ll]
    for k in range(K):
        for ll in range(k):
            JtJ[n, k, ll] = JtJ[n, ll, k]


@njit(cache=True, error_model="numpy")
def normal_equations(D, dD_dc, dD_dt, b, w, r):
    r'''J^T W J (n,K,K) and J^T W r (n,K) of every corner, J = [1, D, b dD_dc, b dD_dt] (the
Jacobian refine_corners builds in numpy; summed pixel by pixel, so equal to numpy's
matmul to rounding, not bit for bit). lm_accept keeps them for the corners whose model
a step changes; lm_system damps them.'''
    n = D.shape[0]
    K = 4 + dD_dt.shape[2]
    JtJ = np.empty((n, K, K))
    Jtr = np.empty((n, K))
    J = np.empty(K)
    for k in range(n):
        _corner_sums(JtJ, Jtr, k, D, dD_dc, dD_dt, k, b[k], w, r, J)
    return JtJ, Jtr


@njit(cache=True, error_model="numpy")
def lm_system(s, JtJ, lam):
    r'''The Levenberg-Marquardt matrices (m,K,K) of the corners s: targets.corners._fit's
numpy expression JtJ + (lam[s, None] * diag)[:, :, None] * eye + 1e-12 * eye (diag:
JtJ[s]'s diagonal, eye: the identity) element by element in its order (the same bits),
without its three temporary (m,K,K) arrays'''
    m = len(s)
    K = JtJ.shape[1]
    A = np.empty((m, K, K))
    dk = np.empty(K)
    for j in range(m):
        n = s[j]
        for k in range(K):
            dk[k] = lam[n] * JtJ[n, k, k]
        for k in range(K):
            for ll in range(K):
                e = 1.0 if k == ll else 0.0
                A[j, k, ll] = (JtJ[n, k, ll] + dk[k] * e) + 1e-12 * e
    return A


@njit(cache=True, error_model="numpy")
def window_mask(ix, iy, q0, Ainv, half_box, notch, max_px, lines_box, strip_px, lines_px, H, W):
    r'''inside, on_image (n,P) of each corner's window (targets.corners._window, whose
numpy arithmetic this repeats pixel by pixel in the same order): pixel (ix, iy) is inside
when every corner of its square maps by Ainv (n,2,2) to board offsets within half_box (n,)
of q0 (n,2) along both axes, not past notch (n,; NaN: no notch) along both at once, and
its centre is within max_px of q0; or, where lines_box (n,) is finite, when its centre
lies within strip_px (px) of one of the board axes' lines through q0 and lines_px of q0
along both image axes (lines_px (n,)), and its square within lines_box board units along
both board axes (strips along a chessboard corner's two lines); on_image when it lies in the (H, W)
image'''
    n, P = ix.shape
    inside = np.zeros((n, P), np.bool_)
    on_image = np.zeros((n, P), np.bool_)
    for j in range(n):
        a00, a01, a10, a11 = Ainv[j, 0, 0], Ainv[j, 0, 1], Ainv[j, 1, 0], Ainv[j, 1, 1]
        hb = half_box[j]
        nt = notch[j]
        lb = lines_box[j]
        strips = not np.isnan(lb)
        # px per board unit across each axis' line: board offset v / |row 1| is the
        # distance from the u axis' line (and u / |row 0| from the v axis')
        n0 = np.sqrt(a00 * a00 + a01 * a01)
        n1 = np.sqrt(a10 * a10 + a11 * a11)
        for p in range(P):
            x = ix[j, p]
            y = iy[j, p]
            on_image[j, p] = x >= 0 and x < W and y >= 0 and y < H
            dx = x - q0[j, 0]
            dy = y - q0[j, 1]
            ok = False
            if abs(dx) <= max_px and abs(dy) <= max_px:
                ok = True
                umax = -np.inf
                vmax = -np.inf
                for k in range(4):
                    rx = dx + _SX[k]
                    ry = dy + _SY[k]
                    bu = a00 * rx + a01 * ry
                    bv = a10 * rx + a11 * ry
                    if not (abs(bu) <= hb and abs(bv) <= hb):
                        ok = False
                        break
                    umax = max(umax, bu)
                    vmax = max(vmax, bv)
                if ok and not np.isnan(nt):
                    ok = not (umax > nt and vmax > nt)
            if not ok and strips and abs(dx) <= lines_px[j] and abs(dy) <= lines_px[j]:
                cu = a00 * dx + a01 * dy
                cv = a10 * dx + a11 * dy
                if abs(cv) <= strip_px * n1 or abs(cu) <= strip_px * n0:
                    ok = True
                    for k in range(4):
                        rx = dx + _SX[k]
                        ry = dy + _SY[k]
                        if not (abs(a00 * rx + a01 * ry) <= lb
                                and abs(a10 * rx + a11 * ry) <= lb):
                            ok = False
                            break
            inside[j, p] = ok
    return inside, on_image


@njit(cache=True, error_model="numpy")
def window_pixels(ix, iy, inside, rows, img):
    r'''v, w (m,P) and centres (m,P,2) of the windows rows (m,) of targets.corners._window's
ix, iy, inside (n,Pall): each row's inside pixels first, then the others, both in their
order (numpy's stable argsort of ~inside), cut to P = the most inside pixels of any of
those rows; v the image's values (float64) at the pixels clipped to the image, w 1.0
inside and 0.0 elsewhere, centres the pixels' (x, y): the numpy expressions of
targets.corners._fit in one pass (the same values)'''
    H, W = img.shape
    m = len(rows)
    Pall = ix.shape[1]
    P = 0
    for j in range(m):
        k = 0
        for p in range(Pall):
            if inside[rows[j], p]:
                k += 1
        P = max(P, k)
    v = np.empty((m, P))
    w = np.empty((m, P))
    centres = np.empty((m, P, 2))
    for j in range(m):
        n = rows[j]
        k = 0
        for sweep in range(2):
            want = sweep == 0
            for p in range(Pall):
                if k == P:
                    break
                if inside[n, p] != want:
                    continue
                x = ix[n, p]
                y = iy[n, p]
                v[j, k] = float(img[min(max(y, 0), H - 1), min(max(x, 0), W - 1)])
                w[j, k] = 1.0 if want else 0.0
                centres[j, k, 0] = float(x)
                centres[j, k, 1] = float(y)
                k += 1
    return v, w, centres


@njit(cache=True, error_model="numpy", inline="always")
def _block_sum(a, lo, n):
    # numpy's pairwise_sum on n <= 128 values: eight lanes, then the rest one by one
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    m = n - n % 8
    while i < m:
        k = lo + i
        r0 += a[k]
        r1 += a[k + 1]
        r2 += a[k + 2]
        r3 += a[k + 3]
        r4 += a[k + 4]
        r5 += a[k + 5]
        r6 += a[k + 6]
        r7 += a[k + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True, error_model="numpy")
def _pairwise_sum(a, n):
    r'''a[:n].sum() in numpy's order (its pairwise summation: halves split at a multiple of
8 down to blocks of at most 128, each summed in 8 lanes), so that light_levels equals the
numpy expressions it replaces bit for bit (_pairwise_walk)'''
    if n <= 128:
        return _block_sum(a, 0, n)
    tlo, tn, tdone, vals = _walk_stacks()
    return _pairwise_walk(a, n, tlo, tn, tdone, vals)


@njit(cache=True, error_model="numpy", inline="always")
def _walk_stacks():
    # _pairwise_walk's task and value stacks: 128 entries hold any length numpy's tree
    # reaches (3 tasks per level, ~log2(n / 128) levels)
    return (np.empty(128, np.int64), np.empty(128, np.int64), np.empty(128, np.bool_),
            np.empty(128))


@njit(cache=True, error_model="numpy")
def _pairwise_walk(a, n, tlo, tn, tdone, vals):
    r'''_pairwise_sum of n > 128 values on the caller's stacks (_walk_stacks: a caller
summing many arrays allocates them once). numpy recurses; this walks the same tree with
its own stacks (numba's cache does not take recursive kernels).'''
    nt = 1
    nv = 0
    tlo[0], tn[0], tdone[0] = 0, n, False
    while nt:
        nt -= 1
        lo, m, done = tlo[nt], tn[nt], tdone[nt]
        if m <= 128:
            vals[nv] = _block_sum(a, lo, m)
            nv += 1
        elif done:
            nv -= 1
            vals[nv - 1] = vals[nv - 1] + vals[nv]
        else:
            m2 = m // 2
            m2 -= m2 % 8
            tlo[nt], tn[nt], tdone[nt] = lo, m, True
            tlo[nt + 1], tn[nt + 1], tdone[nt + 1] = lo + m2, m - m2, False
            tlo[nt + 2], tn[nt + 2], tdone[nt + 2] = lo, m2, False
            nt += 3
    return vals[0]


@njit(cache=True, error_model="numpy", inline="always")
def _sum_on(a, n, tlo, tn, tdone, vals):
    # _pairwise_sum on the caller's stacks
    if n <= 128:
        return _block_sum(a, 0, n)
    return _pairwise_walk(a, n, tlo, tn, tdone, vals)


@njit(cache=True, error_model="numpy")
def light_levels(s, D, w, v):
    r'''The light level a, contrast b, weighted misfit S (m,) and residuals r (m,P) of the
corners s: the weighted least squares of v = a + b D over each window (w its weights,
(n,P); D (m,P) the dark areas of the corners s), the arithmetic of the numpy expressions
in targets.corners._fit in their order, sums in numpy's pairwise order: equal bit for bit'''
    m, P = D.shape
    a = np.empty(m)
    b = np.empty(m)
    S = np.empty(m)
    r = np.empty((m, P))
    t0 = np.empty(P)
    t1 = np.empty(P)
    t2 = np.empty(P)
    t3 = np.empty(P)
    t4 = np.empty(P)
    tlo, tn, tdone, vals = _walk_stacks()
    for j in range(m):
        n = s[j]
        for p in range(P):
            wd = w[n, p] * D[j, p]
            t0[p] = w[n, p]
            t1[p] = wd
            t2[p] = wd * D[j, p]
            t3[p] = w[n, p] * v[n, p]
            t4[p] = wd * v[n, p]
        sw = _sum_on(t0, P, tlo, tn, tdone, vals)
        sd = _sum_on(t1, P, tlo, tn, tdone, vals)
        sdd = _sum_on(t2, P, tlo, tn, tdone, vals)
        sv = _sum_on(t3, P, tlo, tn, tdone, vals)
        sdv = _sum_on(t4, P, tlo, tn, tdone, vals)
        det = sw * sdd - sd * sd
        bj = (sw * sdv - sd * sv) / det
        aj = (sv - bj * sd) / sw
        for p in range(P):
            rp = (v[n, p] - aj) - bj * D[j, p]
            r[j, p] = rp
            t0[p] = (w[n, p] * rp) * rp
        a[j] = aj
        b[j] = bj
        S[j] = _sum_on(t0, P, tlo, tn, tdone, vals)
    return a, b, S, r


def _sortable_bits(img):
    pass


@overload(_sortable_bits)
def _sortable_bits_impl(img):
    # (bits, low, exponent): the image's float bits as signed integers of its width; the
    # mask of all bits below the sign and the mask of the exponent (all ones: inf or NaN)
    if img.dtype == types.float32:
        return lambda img: (img.view(np.int32), np.int32(0x7FFFFFFF), np.int32(0x7F800000))
    return lambda img: (img.view(np.int64), np.int64(0x7FFFFFFFFFFFFFFF),
                        np.int64(0x7FF0000000000000))


@njit(inline="always")
def _ordered(b, low):
    # a float's order as an integer's: negative floats' magnitude bits reversed (its own
    # inverse). A select, and every result cast back to the bits' width: numba widens
    # int32 arithmetic to int64, which halves the lanes of the row's vector loop
    return type(low)(b ^ low) if b < type(low)(0) else b


@njit(cache=True, error_model="numpy")
def _range_u8_row(row, bits, scale, out, kmin, kmax, low, exponent):
    # one row of image_range_u8: every step integer or elementwise, in the pixels' own
    # width (int32 and float32 for a float32 image), so LLVM vectorises it 8 pixels to a
    # 256-bit register (a float min/max reduction it does not: NaN semantics; 2.5x the time)
    zero = np.zeros(1, row.dtype)[0]
    top = np.full(1, 255.0, row.dtype)[0]
    nonfinite = False
    for j in range(row.shape[0]):
        b = bits[j]
        k = _ordered(b, low)
        kmin = min(kmin, k)
        kmax = max(kmax, k)
        nonfinite |= type(low)(b & exponent) == exponent
        out[j] = np.uint8(min(np.rint(max(row[j], zero) * scale), top))
    return kmin, kmax, nonfinite


@njit(cache=True, error_model="numpy")
def image_range_u8(img, scale):
    r'''One pass over a detector's image (targets.detection.working_image): (finite, lo, hi,
img8); finite: no pixel is NaN or infinite; lo, hi: the smallest and largest pixel of a
finite image (of +0 and -0, the first in row order); img8 (H,W) uint8 =
rint(scale * max(img, 0)) saturated at 255, in the image's own float type (scale of that
type): what OpenCV's convertScaleAbs(max(img, 0), alpha=scale) gives (round half to even;
float32 products stay float32) where it does not overflow. The smallest and largest are
taken on the floats' bits as ordered integers (a float min/max does not vectorise), in
the pixels' width: 12.0 ms of CPU on a 5120x3840 float32 image against 15.4 with int64
and float64 steps and 38 with a float min/max (load 8-11, 2 cores); numpy's sum of that
image takes 9.7 (its memory traffic)'''
    H, W = img.shape
    out = np.empty((H, W), np.uint8)
    bits, low, exponent = _sortable_bits(img)
    kmin = _ordered(bits[0, 0], low)
    kmax = kmin
    finite = True
    for i in range(H):
        kmin, kmax, nonfinite = _range_u8_row(img[i], bits[i], scale, out[i], kmin, kmax,
                                              low, exponent)
        finite &= not nonfinite
    ext = np.empty(2, bits.dtype)
    ext[0] = _ordered(kmin, low)
    ext[1] = _ordered(kmax, low)
    lohi = ext.view(img.dtype)
    lo, hi = lohi[0], lohi[1]
    zero = np.zeros(1, img.dtype)[0]
    if lo == zero or hi == zero:
        # +0 and -0 are one value, ordered apart as integers: the first zero in row order
        first = zero
        for i in range(H):
            for j in range(W):
                if img[i, j] == zero:
                    first = img[i, j]
                    break
            else:
                continue
            break
        lo = first if lo == zero else lo
        hi = first if hi == zero else hi
    return finite, float(lo), float(hi), out


@njit(cache=True, error_model="numpy")
def lm_accept(s, step, S1, c1, t1, g1, D1, dD_dc1, dD_dt1, a1, b1, r1, w, c, theta, sig, a,
              b, S, lam, prev, converged, JtJ, Jtr, converged_px, max_window_px):
    r'''The end of one Levenberg-Marquardt iteration of targets.corners._fit, in place: for
each corner n = s[j] whose trial (S1, c1, t1, g1, a1, b1 of row j) lowers its misfit S[n],
take the trial's geometry and light levels; damp the corner (lam) down after a step that
lowered the misfit and was no zig-zag (a step back along the last accepted one, prev),
else up; keep the accepted step in prev; mark it converged on a small accepted step
(corner move < converged_px, ray turn x max_window_px < converged_px) or when its damping
passed 1e6 with a small step. The numpy expressions it replaces, in their order of
operations and numpy's summation order (_block_sum): the same bits.

The trial's model (D1, dD_dc1, dD_dt1, r1 of row j, w of row n) enters only the next
iteration's normal equations: a corner that takes it and still fits gets its JtJ[n],
Jtr[n] (normal_equations' sums) from it here, instead of a copy of those (P,...) rows.'''
    m, K = step.shape
    tmp = np.empty(K)
    J = np.empty(JtJ.shape[1])
    for j in range(m):
        n = s[j]
        better = S1[j] <= S[n]
        # zig-zag: step . prev < -0.5 |step| |prev|, each sum in numpy's order
        for k in range(K):
            tmp[k] = step[j, k] * prev[n, k]
        dot = _block_sum(tmp, 0, K)
        for k in range(K):
            tmp[k] = step[j, k] * step[j, k]
        n1 = np.sqrt(_block_sum(tmp, 0, K))
        for k in range(K):
            tmp[k] = prev[n, k] * prev[n, k]
        n2 = np.sqrt(_block_sum(tmp, 0, K))
        zig = dot < -0.5 * n1 * n2
        if better:
            c[n, 0] = c1[j, 0]
            c[n, 1] = c1[j, 1]
            theta[n, :] = t1[j, :]
            sig[n] = g1[j]
            a[n] = a1[j]
            b[n] = b1[j]
            S[n] = S1[j]
        if better and not zig:
            lam[n] = max(lam[n] * 0.3, 1e-6)
        else:
            lam[n] = lam[n] * 10.0
        if better:
            prev[n, :] = step[j, :]
        # the largest |move| and |turn|: NaN if any is NaN (numpy's max), failing both tests
        x0 = abs(step[j, 2])
        x1 = abs(step[j, 3])
        dc = np.nan if (np.isnan(x0) or np.isnan(x1)) else max(x0, x1)
        turn = -np.inf
        for k in range(4, K):
            x = abs(step[j, k])
            if np.isnan(x) or np.isnan(turn):
                turn = np.nan
            else:
                turn = max(turn, x)
        small = (dc < converged_px) and (turn * max_window_px < converged_px)
        converged[n] = (better and small) or ((lam[n] > 1e6) and (dc < converged_px))
        if better and not converged[n]:
            _corner_sums(JtJ, Jtr, n, D1, dD_dc1, dD_dt1, j, b1[j], w, r1, J)


def compiled_entry_points():
    r'''The compiled kernels of this module that Python calls (numba dispatchers), for a
warm-up's check of numba's cache (harness.warmup)'''
    return (wedge_model, normal_equations, lm_system, window_mask, window_pixels,
            image_range_u8, light_levels, lm_accept, curvature_terms)


@njit(cache=True, error_model="numpy")
def curvature_terms(d, uu, first, second, kk):
    r'''corners.curvature_bias's pixel terms: D (n,P), dD_dc (n,P,2), dD_dt (n,P,R) (the
sharp wedge model, wedge_area with derivatives, widen 0) and dv (n,P), the dark area that
edges bent by kk (n,R) add to each pixel: k (s1^3 - s0^3) / 6 over each ray's stretch
[s0, s1]; d (n,P,2) pixel centres - apex, uu (n,R,2) unit rays, first, second (n,Nw)'''
    n, P = d.shape[0], d.shape[1]
    R = uu.shape[1]
    Nw = first.shape[1]
    D = np.zeros((n, P))
    dD_dc = np.zeros((n, P, 2))
    dD_dt = np.zeros((n, P, R))
    dv = np.zeros((n, P))
    for j in range(n):
        for p in range(P):
            dx = d[j, p, 0]
            dy = d[j, p, 1]
            for k in range(Nw):
                i1 = first[j, k]
                i2 = second[j, k]
                u1x, u1y = uu[j, i1, 0], uu[j, i1, 1]
                u2x, u2y = uu[j, i2, 0], uu[j, i2, 1]
                D[j, p] += _area(dx, dy, u1x, u1y, u2x, u2y)
                s0a, s1a = _stretch(dx, dy, u1x, u1y, 0.5)
                s0b, s1b = _stretch(dx, dy, u2x, u2y, 0.5)
                la = s1a - s0a
                lb = s1b - s0b
                dD_dc[j, p, 0] += -la * -u1y + lb * -u2y
                dD_dc[j, p, 1] += -la * u1x + lb * u2x
                dD_dt[j, p, i1] += -0.5 * (s1a ** 2 - s0a ** 2)
                dD_dt[j, p, i2] += 0.5 * (s1b ** 2 - s0b ** 2)
                # a ray bent outwards adds dark area: outward normal -perp(u1), +perp(u2)
                dv[j, p] += -1.0 * kk[j, i1] * (s1a ** 3 - s0a ** 3) / 6.0
                dv[j, p] += 1.0 * kk[j, i2] * (s1b ** 3 - s0b ** 3) / 6.0
    return D, dD_dc, dD_dt, dv

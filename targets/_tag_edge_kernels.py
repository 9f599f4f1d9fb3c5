r'''Compiled edge-profile fit of targets.tag_edges (numba): the hot loop

SYNOPSIS

    from targets._tag_edge_kernels import edge_normal

    a, b, S, JtJ, Jtr = edge_normal(rows, v, w, tau, s, cubic, j0, fy, d, x0, h, F, dF,
                                    bfix)
    # rows (m,) the edges to evaluate (of n); d (m,4) their curves; v, w, tau, s (n,P):
    # each edge's pixel values, weights (0: padding), positions along the chord (tau) and
    # distances from it (s, px); cubic (n,) 1.0 where d3 is fitted; j0, fy (n,): the angle
    # bin and fraction of each edge's normal; x0, h, F, dF (A,X):
    # targets.tag_edges._edge_table; a, b, S (m,) the light level, contrast and weighted
    # squared misfit at d; JtJ (m,6,6), Jtr (m,6) the normal equations; bfix (n,) the
    # contrast of an edge whose b is given (NaN: fitted)
    # equations in (a, b, d0, d1, d2, d3)

The model of pixel p of edge j: v = a + b F(x), x = s - (d0 + d1 tau + d2 tau^2 + d3 tau^3),
F linear in x and in the angle between the table's entries (targets.tag_edges._lookup is the
numpy reference). a and b solve the weighted least squares for the current curve.
'''

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def edge_normal(rows, v, w, tau, s, cubic, j0, fy, d, x0, h, F, dF, bfix):
    m = len(rows)
    P = v.shape[1]
    X = F.shape[1]
    a = np.zeros(m)
    b = np.zeros(m)
    S = np.zeros(m)
    JtJ = np.zeros((m, 6, 6))
    Jtr = np.zeros((m, 6))
    Fv = np.zeros(P)
    dFv = np.zeros(P)
    J = np.zeros(6)
    for jj in range(m):
        j = rows[jj]
        ja = j0[j]
        fa = fy[j]
        sw = 0.0
        sf = 0.0
        sff = 0.0
        sv = 0.0
        sfv = 0.0
        for p in range(P):
            wp = w[j, p]
            if wp == 0.0:
                continue
            t = tau[j, p]
            x = s[j, p] - (d[jj, 0] + t * (d[jj, 1] + t * (d[jj, 2] + t * d[jj, 3] * cubic[j])))
            fi = (x - x0) / h
            if fi <= 0.0:
                f, df = 0.0, 0.0
            elif fi >= X - 1:
                f, df = 1.0, 0.0
            else:
                i = int(fi)
                fx = fi - i
                f0 = F[ja, i] * (1.0 - fx) + F[ja, i + 1] * fx
                f1 = F[ja + 1, i] * (1.0 - fx) + F[ja + 1, i + 1] * fx
                f = f0 * (1.0 - fa) + f1 * fa
                g0 = dF[ja, i] * (1.0 - fx) + dF[ja, i + 1] * fx
                g1 = dF[ja + 1, i] * (1.0 - fx) + dF[ja + 1, i + 1] * fx
                df = g0 * (1.0 - fa) + g1 * fa
            Fv[p] = f
            dFv[p] = df
            vp = v[j, p]
            sw += wp
            sf += wp * f
            sff += wp * f * f
            sv += wp * vp
            sfv += wp * f * vp
        if np.isnan(bfix[j]):
            det = sw * sff - sf * sf
            bj = (sw * sfv - sf * sv) / det
        else:
            bj = bfix[j]
        aj = (sv - bj * sf) / sw
        a[jj] = aj
        b[jj] = bj
        acc = 0.0
        for p in range(P):
            wp = w[j, p]
            if wp == 0.0:
                continue
            t = tau[j, p]
            r = v[j, p] - aj - bj * Fv[p]
            acc += wp * r * r
            g = -bj * dFv[p]
            J[0] = 1.0
            J[1] = Fv[p] if np.isnan(bfix[j]) else 0.0
            J[2] = g
            J[3] = g * t
            J[4] = g * t * t
            J[5] = g * t * t * t * cubic[j]
            for k in range(6):
                Jtr[jj, k] += wp * J[k] * r
                for l in range(k + 1):
                    JtJ[jj, k, l] += wp * J[k] * J[l]
        S[jj] = acc
        for k in range(6):
            for l in range(k):
                JtJ[jj, l, k] = JtJ[jj, k, l]
    return a, b, S, JtJ, Jtr


@njit(cache=True, error_model="numpy")
def edge_pixels(P0, e, n, L, curve, t_lo, t_hi, out_px, in_px, deep_px, H, bits, offs,
                x0, y0, x1, y1, k, bit_px, Pa, na, Pb, nb):
    r'''The pixels of one tag edge's band (targets.tag_edges._edge_pixels): (ix, iy, t, s)

Pixels with centre at t in [t_lo, t_hi] along the chord and x = s - curve(tau) in
[-out_px, in_px]; those deeper than deep_px must see only dark cells of bits (8,8, True =
light) at the offsets offs (cells) about their position in the tag's cells: along edge k
by the homography H (image -> cells) of the tag's corners, across it by the depth x /
bit_px from the curve (lens distortion bends the edge away from the homography's line by
up to a px on a fisheye's tag). A pixel keeps the clearance t_lo from the lines of the two
adjacent edges too (through Pa, Pb with normals na, nb into the tag): a tag seen obliquely
meets them at an angle off 90 deg.'''
    cap = (x1 - x0 + 1) * (y1 - y0 + 1)
    oix = np.empty(cap, np.int64)
    oiy = np.empty(cap, np.int64)
    ot = np.empty(cap)
    os_ = np.empty(cap)
    c = 0
    no = len(offs)
    for yy in range(y0, y1 + 1):
        for xx in range(x0, x1 + 1):
            rx = xx - P0[0]
            ry = yy - P0[1]
            t = rx * e[0] + ry * e[1]
            if t < t_lo or t > t_hi:
                continue
            s = rx * n[0] + ry * n[1]
            tau = 2.0 * t / L - 1.0
            x = s - (curve[0] + tau * (curve[1] + tau * (curve[2] + tau * curve[3])))
            if x < -out_px or x > in_px:
                continue
            if (xx - Pa[0]) * na[0] + (yy - Pa[1]) * na[1] < t_lo:
                continue
            if (xx - Pb[0]) * nb[0] + (yy - Pb[1]) * nb[1] < t_lo:
                continue
            if x > deep_px:
                w = H[2, 0] * xx + H[2, 1] * yy + H[2, 2]
                u = (H[0, 0] * xx + H[0, 1] * yy + H[0, 2]) / w
                v = (H[1, 0] * xx + H[1, 1] * yy + H[1, 2]) / w
                depth = x / bit_px
                # edges 0..3 of pupil_apriltags' order: bottom (v = 8), right (u = 8),
                # top (v = 0), left (u = 0) of the upright tag
                if k == 0:
                    v = 8.0 - depth
                elif k == 1:
                    u = 8.0 - depth
                elif k == 2:
                    v = depth
                else:
                    u = depth
                ok = True
                for a in range(no):
                    for b in range(no):
                        col = int(np.floor(u + offs[a]))
                        row = int(np.floor(v + offs[b]))
                        if 0 <= col < 8 and 0 <= row < 8 and bits[row, col]:
                            ok = False
                if not ok:
                    continue
            oix[c] = xx
            oiy[c] = yy
            ot[c] = t
            os_[c] = s
            c += 1
    return oix[:c], oiy[:c], ot[:c], os_[:c]

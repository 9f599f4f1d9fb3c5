r'''Compiled edge-profile fit of targets.tag_edges (numba): the hot loops

SYNOPSIS

    from targets._tag_edge_kernels import fit_edges, fit_pixels, meet_curves, tag_edge_pixels

    status, L, e, n, off, ix, iy, t, s = tag_edge_pixels(Q, live, bits, True, H, curves,
                                                         reach, gap_bits, safety, plateau,
                                                         min_pixels, W, H_img)
    # every edge's band of pixels (targets.tag_edges._EDGE_STATUS says why an edge has none)

    off, v, tau, s, dark = fit_pixels(img, ix, iy, t, s, off, fit_off, piece_edge, piece_mode,
                                      piece_reach, P0, e, n, L, d)
    # each fit's pixels (pieces of those edges: its own, its board line's neighbours') in
    # the frame of its chord, as fit_edges takes them

    p, done, mis = fit_edges(off, v, w, tau, s, cubic, j0, fy, d, x0, h, F, dF, bfix, skip,
                             max_iterations, converged_px)
    # the m edges' pixels one after another: edge j's are [off[j], off[j+1]) of v (values),
    # w (weights: the inverse of each pixel's noise variance, to a common scale), tau
    # (positions along the chord, -1..1) and s (distances from it, px); cubic (m,) 1.0
    # where d3 is fitted; j0, fy (m,): the angle bin and fraction of each edge's normal;
    # d (m,4) the start curves; x0, h, F, dF (A,X): targets.tag_edges._edge_table; bfix
    # (m,) the contrast of an edge whose b is given (NaN: fitted); skip (m,) edges left
    # alone (p 0, done False, mis NaN)
    # p (m,6) the fitted (a, b, d0, d1, d2, d3); done (m,) converged; mis (m,) the RMS
    # misfit over the contrast (weighted: that of a pixel of weight 1)
    q = meet_curves(Pa, La, ea, na, da, Pb, Lb, eb, nb, db, iterations)
    # (M,2) where each edge a meets its edge b near a's end and b's start

The model of pixel p of edge j: v = a + b F(x), x = s - (d0 + d1 tau + d2 tau^2 + d3 tau^3),
F linear in x and in the angle between the table's entries (targets.tag_edges._lookup is the
numpy reference). a and b solve the least squares for the current curve; the curve is
fitted by Levenberg-Marquardt, each edge on its own (targets.tag_edges._fit_edges).
'''

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

# the moments _profile sums over an edge's pixels for its normal equations (_normal): with
# g = F'(x) and t the position tau, sum g t^k, sum g F t^k, sum g v t^k (k = 0..3) and
# sum g^2 t^k (k = 0..6): the Jacobian's columns are b g t^k, so the normal equations are
# these times powers of b (one pass over the pixels instead of two). Each pixel's terms
# carry its weight w (g = w F'), summed in scalars in _profile and blur_step, each only to
# the power of t its normal equations read (no cubic term: t^2, g^2 t^4)
_G, _GF, _GV, _GG = 0, 4, 8, 12
_MOMENTS = 19


@njit(cache=True, error_model="numpy", inline="always")
def _lookup_f(x, x0, h, X, Fe, dFe):
    # F and F' at x from one angle's row (Fe, dFe), linear between the table's entries; 0 or 1
    # and flat beyond it
    fi = (x - x0) / h
    if fi <= 0.0:
        return 0.0, 0.0
    if fi >= X - 1:
        return 1.0, 0.0
    i = int(fi)
    fx = fi - i
    return Fe[i] * (1.0 - fx) + Fe[i + 1] * fx, dFe[i] * (1.0 - fx) + dFe[i + 1] * fx


@njit(cache=True, error_model="numpy", inline="always")
def _profile(v, w, tau, s, o0, o1, cubic, d, x0, h, Fe, dFe, bfix, Fv, M):
    # F at every pixel of one edge (into Fv; Fe, dFe: F and F' at the edge's angle, _at_angle),
    # the moments M of its normal equations, and the light level a, contrast b and squared
    # misfit S that fit them; every sum weighted by the pixels' weights w (sw = sum w); the
    # moments to the powers _normal reads (see _G..: a quadratic edge's pass does ~40% less)
    X = Fe.shape[0]
    sw = 0.0
    sf = 0.0
    sff = 0.0
    sv = 0.0
    sfv = 0.0
    g0 = g1 = g2 = g3 = 0.0
    f0 = f1 = f2 = f3 = 0.0
    v0 = v1 = v2 = v3 = 0.0
    q0 = q1 = q2 = q3 = q4 = q5 = q6 = 0.0
    d0, d1, d2, d3 = d[0], d[1], d[2], d[3]
    if cubic != 0.0:
        for p in range(o0, o1):
            t = tau[p]
            x = s[p] - (d0 + t * (d1 + t * (d2 + t * d3 * cubic)))
            f, df = _lookup_f(x, x0, h, X, Fe, dFe)
            vp = v[p]
            wp = w[p]
            if df != 0.0:
                wdf = wp * df
                gg = wdf * df
                t2 = t * t
                t3 = t2 * t
                t4 = t3 * t
                t5 = t4 * t
                t6 = t5 * t
                g0 += wdf
                g1 += wdf * t
                g2 += wdf * t2
                g3 += wdf * t3
                wf = wdf * f
                f0 += wf
                f1 += wf * t
                f2 += wf * t2
                f3 += wf * t3
                wv = wdf * vp
                v0 += wv
                v1 += wv * t
                v2 += wv * t2
                v3 += wv * t3
                q0 += gg
                q1 += gg * t
                q2 += gg * t2
                q3 += gg * t3
                q4 += gg * t4
                q5 += gg * t5
                q6 += gg * t6
            Fv[p - o0] = f
            sw += wp
            wf = wp * f
            sf += wf
            sff += wf * f
            sv += wp * vp
            sfv += wf * vp
    else:
        for p in range(o0, o1):
            t = tau[p]
            x = s[p] - (d0 + t * (d1 + t * (d2 + t * d3 * cubic)))
            f, df = _lookup_f(x, x0, h, X, Fe, dFe)
            vp = v[p]
            wp = w[p]
            if df != 0.0:
                wdf = wp * df
                gg = wdf * df
                t2 = t * t
                t3 = t2 * t
                t4 = t3 * t
                g0 += wdf
                g1 += wdf * t
                g2 += wdf * t2
                wf = wdf * f
                f0 += wf
                f1 += wf * t
                f2 += wf * t2
                wv = wdf * vp
                v0 += wv
                v1 += wv * t
                v2 += wv * t2
                q0 += gg
                q1 += gg * t
                q2 += gg * t2
                q3 += gg * t3
                q4 += gg * t4
            Fv[p - o0] = f
            sw += wp
            wf = wp * f
            sf += wf
            sff += wf * f
            sv += wp * vp
            sfv += wf * vp
    M[_G], M[_G + 1], M[_G + 2], M[_G + 3] = g0, g1, g2, g3
    M[_GF], M[_GF + 1], M[_GF + 2], M[_GF + 3] = f0, f1, f2, f3
    M[_GV], M[_GV + 1], M[_GV + 2], M[_GV + 3] = v0, v1, v2, v3
    M[_GG], M[_GG + 1], M[_GG + 2], M[_GG + 3] = q0, q1, q2, q3
    M[_GG + 4], M[_GG + 5], M[_GG + 6] = q4, q5, q6
    if np.isnan(bfix):
        b = (sw * sfv - sf * sv) / (sw * sff - sf * sf)
    else:
        b = bfix
    a = (sv - b * sf) / sw
    S = 0.0
    for p in range(o0, o1):
        r = v[p] - a - b * Fv[p - o0]
        S += w[p] * r * r
    return a, b, S, sw, sf, sff, sv, sfv


@njit(cache=True, error_model="numpy", inline="always")
def _at_angle(T, ja, fa, out):
    # a table's row at an edge's angle: bins ja and ja + 1 mixed by fa (linear in the angle)
    for i in range(T.shape[1]):
        out[i] = T[ja, i] * (1.0 - fa) + T[ja + 1, i] * fa


@njit(cache=True, error_model="numpy", inline="always")
def _normal(M, sw, sf, sff, sv, sfv, cubic, a, b, bfree, JtJ, Jtr):
    # the normal equations of one edge in (a, b, d0, d1, d2, d3) from _profile's sums: the
    # Jacobian is (1, F, -b g, -b g t, -b g t^2, -b g t^3 [cubic]), the residual
    # v - a - b F
    JtJ[:, :] = 0.0
    Jtr[:] = 0.0
    nk = 4 if cubic != 0.0 else 3
    JtJ[0, 0] = sw
    Jtr[0] = sv - a * sw - b * sf
    if bfree:
        JtJ[1, 0] = sf
        JtJ[1, 1] = sff
        Jtr[1] = sfv - a * sf - b * sff
    for k in range(nk):
        JtJ[2 + k, 0] = -b * M[_G + k]
        if bfree:
            JtJ[2 + k, 1] = -b * M[_GF + k]
        for l in range(k + 1):
            JtJ[2 + k, 2 + l] = b * b * M[_GG + k + l]
        Jtr[2 + k] = -b * (M[_GV + k] - a * M[_G + k] - b * M[_GF + k])
    for k in range(6):
        for l in range(k):
            JtJ[l, k] = JtJ[k, l]


@njit(cache=True, error_model="numpy")
def fit_edges(off, v, w, tau, s, cubic, j0, fy, d, x0, h, F, dF, bfix, skip, max_iterations,
              converged_px):
    m = len(off) - 1
    p_out = np.zeros((m, 6))
    done = np.zeros(m, np.bool_)
    mis = np.zeros(m)
    P = 0
    for j in range(m):
        P = max(P, off[j + 1] - off[j])
    Fv = np.zeros(P)
    X = F.shape[1]
    Fe = np.zeros(X)
    dFe = np.zeros(X)
    M = np.zeros(_MOMENTS)
    M1 = np.zeros(_MOMENTS)
    JtJ = np.zeros((6, 6))
    Jtr = np.zeros(6)
    A = np.zeros((6, 6))
    eye = np.eye(6)
    for j in range(m):
        if skip[j]:
            mis[j] = np.nan
            continue
        o0, o1 = off[j], off[j + 1]
        ja, fa, cj, bj = j0[j], fy[j], cubic[j], bfix[j]
        bfree = np.isnan(bj)
        dj = d[j].copy()
        _at_angle(F, ja, fa, Fe)
        _at_angle(dF, ja, fa, dFe)
        a, b, S, sw, sf, sff, sv, sfv = _profile(v, w, tau, s, o0, o1, cj, dj, x0, h, Fe,
                                                 dFe, bj, Fv, M)
        _normal(M, sw, sf, sff, sv, sfv, cj, a, b, bfree, JtJ, Jtr)
        lam = 1e-3
        ok = False
        # no pixel on the start curve's blurred profile (F' 0 at every pixel: the band past
        # the blur's reach on one side, e.g. a free-contrast edge started from a curve that
        # ran off into its light side; a free b is then 0 / 0): nothing places the curve,
        # the edge is not fitted (done False, mis NaN: targets.tag_edges records why)
        fitted = np.isfinite(a) and np.isfinite(b) and M[_GG] > 0.0
        for _ in range(max_iterations if fitted else 0):
            for k in range(6):
                for l in range(6):
                    A[k, l] = JtJ[k, l] + 1e-12 * eye[k, l]
                A[k, k] += lam * JtJ[k, k]
            step = np.linalg.solve(A, Jtr)
            small = np.abs(step[2:]).max() < converged_px
            if small and lam <= 1.0:
                # a step this small barely damped (lam <= 1: at most halved) is the
                # Gauss-Newton step within 2x: the curve is at its minimum to that. The step
                # is taken without the profile evaluated there (a pass over the pixels, a
                # quarter of the fits' evaluations): the light level and contrast by the same
                # linear step, the squared misfit by its quadratic model |r - J step|^2 (kept
                # where rounding would take it below 0 or above S)
                dj = dj + step[2:]
                a += step[0]
                if bfree:
                    b += step[1]
                S1 = S - 2.0 * (step * Jtr).sum() + (step * (JtJ @ step)).sum()
                if 0.0 <= S1 <= S:
                    S = S1
                ok = True
                break
            d1 = dj + step[2:]
            a1, b1, S1, sw, sf, sff, sv, sfv = _profile(v, w, tau, s, o0, o1, cj, d1, x0, h,
                                                        Fe, dFe, bj, Fv, M1)
            better = S1 <= S
            if better:
                dj, a, b, S = d1, a1, b1, S1
                M, M1 = M1, M
                _normal(M, sw, sf, sff, sv, sfv, cj, a, b, bfree, JtJ, Jtr)
                lam = max(lam * 0.3, 1e-7)
            else:
                lam = lam * 10.0
            if (better and small) or lam > 1e6:
                ok = True
                break
        p_out[j, 0] = a
        p_out[j, 1] = b
        p_out[j, 2:] = dj
        done[j] = ok
        mis[j] = np.sqrt(S / sw) / abs(b) if fitted else np.nan
    return p_out, done, mis


@njit(cache=True, error_model="numpy")
def noise_moments(off, v, tau, s, cubic, j0, fy, p, x0, h, F, use):
    r'''(7,): sums over the pixels of the edges in use (m,) of 1, mu, mu^2, r^2 and mu r^2,
mu = a + b F the fitted value of a pixel and r = v - mu its residual, under the fits p
(m,6) (fit_edges'; the pixels and the rest as its): the normal equations of the noise
variance as a line in the value, E r^2 = c0 + c1 mu (targets.tag_edges._noise_line); then
the least and the largest mu'''
    m = len(off) - 1
    X = F.shape[1]
    out = np.zeros(7)
    out[5] = np.inf
    out[6] = -np.inf
    Fe = np.zeros(X)
    for j in range(m):
        if not use[j]:
            continue
        _at_angle(F, j0[j], fy[j], Fe)
        a, b, cj = p[j, 0], p[j, 1], cubic[j]
        d = p[j, 2:]
        for q in range(off[j], off[j + 1]):
            t = tau[q]
            x = s[q] - (d[0] + t * (d[1] + t * (d[2] + t * d[3] * cj)))
            fi = (x - x0) / h
            if fi <= 0.0:
                f = 0.0
            elif fi >= X - 1:
                f = 1.0
            else:
                i = int(fi)
                fx = fi - i
                f = Fe[i] * (1.0 - fx) + Fe[i + 1] * fx
            mu = a + b * f
            r2 = (v[q] - mu) ** 2
            out[0] += 1.0
            out[1] += mu
            out[2] += mu * mu
            out[3] += r2
            out[4] += mu * r2
            out[5] = min(out[5], mu)
            out[6] = max(out[6], mu)
    return out


@njit(cache=True, error_model="numpy")
def sampled_table(x, proj, W, dW, u, w, F, Fs):
    r'''One angle's row of the sampled kernel's table (targets.tag_edges._edge_table): F[i] =
sum over the taps k of W[k] P(u U1 + w U2 <= x[i] - proj[k]) (U1, U2 uniform on [-1/2, 1/2]:
the pixel's square seen across the edge, u >= w >= 0, u > 0), Fs the same with dW; the taps
summed in their order (as numpy's sum over the first axis)'''
    a = 0.5 * (u + w)
    b = 0.5 * (u - w)
    for i in range(len(x)):
        F[i] = 0.0
        Fs[i] = 0.0
    for k in range(len(proj)):
        for i in range(len(x)):
            y = x[i] - proj[k]
            if y <= -a:
                t = 0.0
            elif y < -b:
                t = (y + a) ** 2 / (2 * u * w) if w > 0 else 0.0
            elif y <= b:
                t = 0.5 + y / u
            elif y < a:
                t = 1.0 - (a - y) ** 2 / (2 * u * w) if w > 0 else 1.0
            else:
                t = 1.0
            F[i] += W[k] * t
            Fs[i] += dW[k] * t


@njit(cache=True, error_model="numpy")
def pixel_weights(v, c0, c1, scale, lo, hi):
    r'''(n,) scale / (c0 + c1 v) of the values v (n,) kept to [lo, hi]: the inverse of the
noise variance line targets.tag_edges._noise_line fitted, in units of scale'''
    out = np.empty(len(v))
    for q in range(len(v)):
        out[q] = scale / (c0 + c1 * min(max(v[q], lo), hi))
    return out


@njit(cache=True, error_model="numpy")
def plateau_counts(off, tau, s, curves, reach):
    r'''(m,) each edge's pixels at least reach px inside its curve (d0..d3 in curves (m,4),
the pixels as fit_edges')'''
    m = len(off) - 1
    out = np.zeros(m, np.int64)
    for j in range(m):
        d = curves[j]
        c = 0
        for q in range(off[j], off[j + 1]):
            t = tau[q]
            if s[q] - (d[0] + t * (d[1] + t * (d[2] + t * d[3]))) >= reach:
                c += 1
        out[j] = c
    return out


@njit(cache=True, error_model="numpy")
def blur_step(off, v, w, tau, s, cubic, j0, fy, p, x0, h, F, dF, Fs, use):
    r'''(H, G): the Gauss-Newton normal equation H dsigma = G of the blur the edges marked
in use (m,) share, each edge's own (a, b, d0..d3) in p (m,6) eliminated (the Schur
complement: their fits follow sigma, to first order). Fs (A,X) is dF/dsigma tabulated as
F; the pixels, their weights w and the rest as fit_edges'. Every edge's b is free, its d3
where cubic.
Sums of moments as fit_edges' (_normal), with those of fs = dF/dsigma: sum fs, fs F,
fs v, fs^2 and fs g t^k.'''
    m = len(off) - 1
    X = F.shape[1]
    Htot = 0.0
    Gtot = 0.0
    A = np.zeros((6, 6))
    r0 = np.zeros(6)
    c = np.zeros(6)
    M = np.zeros(_MOMENTS)
    Ms = np.zeros(4)
    Fe = np.zeros(X)
    dFe = np.zeros(X)
    Fse = np.zeros(X)
    for j in range(m):
        if not use[j]:
            continue
        ja, fa, cj = j0[j], fy[j], cubic[j]
        _at_angle(F, ja, fa, Fe)
        _at_angle(dF, ja, fa, dFe)
        _at_angle(Fs, ja, fa, Fse)
        a, b = p[j, 0], p[j, 1]
        d = p[j, 2:]
        sw = 0.0
        sf = 0.0
        sff = 0.0
        sv = 0.0
        sfv = 0.0
        s1 = 0.0
        sfs = 0.0
        svs = 0.0
        sss = 0.0
        # the moments in scalars, as _profile sums them, and (g fs) t^k beside them; without a
        # cubic term only to t^2 (g^2: t^4)
        g0 = g1 = g2 = g3 = 0.0
        f0 = f1 = f2 = f3 = 0.0
        v0 = v1 = v2 = v3 = 0.0
        q0 = q1 = q2 = q3 = q4 = q5 = q6 = 0.0
        m0 = m1 = m2 = m3 = 0.0
        d0, d1, d2, d3 = d[0], d[1], d[2], d[3]
        for q in range(off[j], off[j + 1]):
            t = tau[q]
            x = s[q] - (d0 + t * (d1 + t * (d2 + t * d3 * cj)))
            fi = (x - x0) / h
            vq = v[q]
            if fi <= 0.0:
                f, df, fs = 0.0, 0.0, 0.0
            elif fi >= X - 1:
                f, df, fs = 1.0, 0.0, 0.0
            else:
                i = int(fi)
                fx = fi - i
                f = Fe[i] * (1.0 - fx) + Fe[i + 1] * fx
                df = dFe[i] * (1.0 - fx) + dFe[i + 1] * fx
                fs = Fse[i] * (1.0 - fx) + Fse[i + 1] * fx
            wq = w[q]
            if df != 0.0:
                wdf = wq * df
                gg = wdf * df
                t2 = t * t
                t3 = t2 * t
                t4 = t3 * t
                g0 += wdf
                g1 += wdf * t
                g2 += wdf * t2
                wf = wdf * f
                f0 += wf
                f1 += wf * t
                f2 += wf * t2
                wv = wdf * vq
                v0 += wv
                v1 += wv * t
                v2 += wv * t2
                ws = wdf * fs
                m0 += ws
                m1 += ws * t
                m2 += ws * t2
                q0 += gg
                q1 += gg * t
                q2 += gg * t2
                q3 += gg * t3
                q4 += gg * t4
                if cj != 0.0:
                    t5 = t4 * t
                    g3 += wdf * t3
                    f3 += wf * t3
                    v3 += wv * t3
                    m3 += ws * t3
                    q5 += gg * t5
                    q6 += gg * (t5 * t)
            sw += wq
            wf = wq * f
            sf += wf
            sff += wf * f
            sv += wq * vq
            sfv += wf * vq
            wfs = wq * fs
            s1 += wfs
            sfs += f * wfs
            svs += vq * wfs
            sss += fs * wfs
        M[_G], M[_G + 1], M[_G + 2], M[_G + 3] = g0, g1, g2, g3
        M[_GF], M[_GF + 1], M[_GF + 2], M[_GF + 3] = f0, f1, f2, f3
        M[_GV], M[_GV + 1], M[_GV + 2], M[_GV + 3] = v0, v1, v2, v3
        M[_GG], M[_GG + 1], M[_GG + 2], M[_GG + 3] = q0, q1, q2, q3
        M[_GG + 4], M[_GG + 5], M[_GG + 6] = q4, q5, q6
        Ms[0], Ms[1], Ms[2], Ms[3] = m0, m1, m2, m3
        _normal(M, sw, sf, sff, sv, sfv, cj, a, b, True, A, r0)
        if cj == 0.0:
            A[5, 5] = 1.0
        # J_sigma = b fs against the columns (1, F, -b g t^k) and the residual
        c[0] = b * s1
        c[1] = b * sfs
        for k in range(4):
            c[2 + k] = -b * b * Ms[k] if (k < 3 or cj != 0.0) else 0.0
        e = b * b * sss
        gs = b * (svs - a * s1 - b * sfs)
        y = np.linalg.solve(A, c)
        z = np.linalg.solve(A, r0)
        Htot += e - (c * y).sum()
        Gtot += gs - (c * z).sum()
    return Htot, Gtot


@njit(cache=True, error_model="numpy", inline="always")
def _columns(slope, base, lo, hi, px, xa, xb):
    # the columns xx in [xa, xb] where lo <= (xx - px) slope + base <= hi may hold, a px of
    # margin each side (all of them where slope is ~0)
    if abs(slope) > 1e-6:
        ua = (lo - base) / slope + px
        ub = (hi - base) / slope + px
        if ua > ub:
            ua, ub = ub, ua
        xa = max(xa, int(np.floor(ua)) - 1)
        xb = min(xb, int(np.ceil(ub)) + 1)
    return xa, xb


@njit(cache=True, error_model="numpy")
def _band(P0, e, n, L, curve, t_lo, t_hi, out_px, in_px, deep_px, H, bits, offs,
          x0, y0, x1, y1, k, bit_px, Pa, na, Pb, nb, oix, oiy, ot, os_, c):
    r'''The pixels of one tag edge's band, written from index c of oix, oiy, ot, os_
(ix, iy, t, s); returns the index after the last

Pixels with centre at t in [t_lo, t_hi] along the chord and x = s - curve(tau) in
[-out_px, in_px]; those deeper than deep_px must see only dark cells of bits (8,8, True =
light) at the offsets offs (cells) about their position in the tag's cells: along edge k
by the homography H (image -> cells) of the tag's corners, across it by the depth x /
bit_px from the curve (lens distortion bends the edge away from the homography's line by
up to a px on a fisheye's tag). A pixel keeps the clearance t_lo from the lines of the two
adjacent edges too (through Pa, Pb with normals na, nb into the tag): a tag seen obliquely
meets them at an angle off 90 deg.'''
    no = len(offs)
    # each row's pixels are scanned only over the columns where t and s = x + curve(tau)
    # (|curve| <= smax) can pass the tests below, a px of margin each side: the tests decide
    smax = abs(curve[0]) + abs(curve[1]) + abs(curve[2]) + abs(curve[3])
    for yy in range(y0, y1 + 1):
        ry = yy - P0[1]
        xa, xb = _columns(e[0], ry * e[1], t_lo, t_hi, P0[0], x0, x1)
        xa, xb = _columns(n[0], ry * n[1], -out_px - smax, in_px + smax, P0[0], xa, xb)
        for xx in range(xa, xb + 1):
            rx = xx - P0[0]
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
    return c


_TAG_CORNERS = np.array([[0.0, 8.0], [8.0, 8.0], [8.0, 0.0], [0.0, 0.0]])


@njit(cache=True, error_model="numpy", inline="always")
def _deep_bit(Qt, k, n):
    # a bit's depth across edge k of the tag Qt (4,2) (n: its unit normal, either sign; the
    # data row's place, the gap's width): the adjacent edges' extent along n, not their
    # length: a sheared tag (a fisheye's rim, corner angles of 45-135 deg on MER hazcam 8)
    # has bits 1/sin(angle) longer than deep, and pixels placed by their length saw the
    # data row (8 CAHVORE, blur only: the rim corners 0.0029 px RMS, outward, against 0.0005)
    P0, P1 = Qt[k], Qt[(k + 1) % 4]
    Pm, Pp = Qt[(k - 1) % 4], Qt[(k + 2) % 4]
    return min(abs((Pm[0] - P0[0]) * n[0] + (Pm[1] - P0[1]) * n[1]),
               abs((Pp[0] - P1[0]) * n[0] + (Pp[1] - P1[1]) * n[1])) / 8.0


@njit(cache=True, error_model="numpy")
def tag_bit_depths(Q):
    r'''(N,) each tag's smallest bit depth (px) over its four edges (_deep_bit, the depth its
edges' pixel bands are placed by: targets.poses plans for it); NaN where a corner is not
finite or an edge has no length. Q (N,4,2) the tags' corners'''
    N = Q.shape[0]
    out = np.full(N, np.nan)
    for i in range(N):
        if not np.all(np.isfinite(Q[i])):
            continue
        m = np.inf
        for k in range(4):
            ex = Q[i, (k + 1) % 4, 0] - Q[i, k, 0]
            ey = Q[i, (k + 1) % 4, 1] - Q[i, k, 1]
            L = np.hypot(ex, ey)
            if not L > 0:
                m = np.nan
                break
            m = min(m, _deep_bit(Q[i], k, np.array([-ey / L, ex / L])))
        out[i] = m
    return out


@njit(cache=True, error_model="numpy")
def _edge_geometry(Qt, k, reach, gap_bits, safety, plateau_px):
    # edge k's frame and band limits (targets.tag_edges._edge_pixels); ok False: too short
    P0 = Qt[k]
    P1 = Qt[(k + 1) % 4]
    ex = P1[0] - P0[0]
    ey = P1[1] - P0[1]
    L = np.hypot(ex, ey)
    e = np.array([ex / L, ey / L]) if L > 0 else np.zeros(2)
    n = np.array([-e[1], e[0]])
    cx = (Qt[0, 0] + Qt[1, 0] + Qt[2, 0] + Qt[3, 0]) / 4.0
    cy = (Qt[0, 1] + Qt[1, 1] + Qt[2, 1] + Qt[3, 1]) / 4.0
    if n[0] * (cx - P0[0]) + n[1] * (cy - P0[1]) < 0:
        n = -n
    deep_bit = _deep_bit(Qt, k, n)
    clear = reach + safety
    out_px = min(gap_bits * deep_bit - clear, clear + plateau_px)
    t_lo = clear
    t_hi = L - clear
    in_px = min(2.0 * deep_bit - clear, clear + plateau_px)
    ok = L > 0 and out_px > 0 and t_hi > t_lo and in_px > -out_px
    return ok, L, e, n, deep_bit, clear, out_px, t_lo, t_hi, in_px


@njit(cache=True, error_model="numpy")
def tag_edge_pixels(Q, live, bits, have_bits, H, curves, reach, gap_bits, safety,
                    plateau_px, min_pixels, width, height):
    r'''The pixels of every edge of every tag (targets.tag_edges._edge_pixels)

Q (N,4,2) the tags' corners, live (N,) those to do; bits (N,8,8) their cells (True = light;
have_bits False: unknown, every data bit may be light); H (N,3,3) each tag's image -> cells
homography; curves (N,4,4) each edge's (d0..d3) in its chord's frame. Returns status (N,4)
(0: pixels found; 1: edge too short for its blur or too few pixels; 2: seen from its light
side only, fewer than min_pixels // 2 on its dark side: its pixels are returned all the same;
3: off the image, or within reach of its border; 4: tag not live), L (N,4), e, n (N,4,2)
each edge's chord length, direction and normal into the tag, off (N*4+1,) and the pixels
(ix, iy, t, s): edge (i, k)'s are [off[4i+k], off[4i+k+1]).'''
    N = Q.shape[0]
    # a pixel sees the image's border through the blur (its value then depends on what the
    # renderer put beyond it: zero padding, a mirror, a wider render) unless its centre keeps
    # reach from it (the border at -1/2 and width - 1/2)
    border = int(np.ceil(reach - 0.5))
    status = np.full((N, 4), 4, np.int64)
    Ls = np.zeros((N, 4))
    es = np.zeros((N, 4, 2))
    ns = np.zeros((N, 4, 2))
    # the bands' bounding boxes first: the output's capacity
    box = np.zeros((N, 4, 4), np.int64)
    cap = 0
    for i in range(N):
        if not live[i]:
            continue
        for k in range(4):
            ok, L, e, n, deep_bit, clear, out_px, t_lo, t_hi, in_px = _edge_geometry(
                Q[i], k, reach, gap_bits, safety, plateau_px)
            if ok and not have_bits:
                in_px = min(in_px, deep_bit - clear)
                ok = in_px > -out_px
            status[i, k] = 0 if ok else 1
            if not ok:
                continue
            smax = 0.0
            for j in range(4):
                smax += abs(curves[i, k, j])
            xlo, ylo, xhi, yhi = np.inf, np.inf, -np.inf, -np.inf
            for t in (t_lo, t_hi):
                for sd in (-out_px - smax, in_px + smax):
                    px = Q[i, k, 0] + t * e[0] + sd * n[0]
                    py = Q[i, k, 1] + t * e[1] + sd * n[1]
                    xlo, ylo = min(xlo, px), min(ylo, py)
                    xhi, yhi = max(xhi, px), max(yhi, py)
            box[i, k, 0] = int(np.floor(xlo))
            box[i, k, 1] = int(np.floor(ylo))
            box[i, k, 2] = int(np.ceil(xhi))
            box[i, k, 3] = int(np.ceil(yhi))
            cap += (box[i, k, 2] - box[i, k, 0] + 1) * (box[i, k, 3] - box[i, k, 1] + 1)
    oix = np.empty(cap, np.int64)
    oiy = np.empty(cap, np.int64)
    ot = np.empty(cap)
    os_ = np.empty(cap)
    off = np.zeros(4 * N + 1, np.int64)
    ones = np.ones((8, 8), np.bool_)
    eye = np.eye(3)
    c = 0
    for i in range(N):
        Qt = Q[i]
        for k in range(4):
            off[4 * i + k] = c
            if status[i, k] != 0:
                continue
            ok, L, e, n, deep_bit, clear, out_px, t_lo, t_hi, in_px = _edge_geometry(
                Qt, k, reach, gap_bits, safety, plateau_px)
            Ls[i, k] = L
            es[i, k] = e
            ns[i, k] = n
            if have_bits:
                Hk = H[i]
                cells = bits[i]
            else:
                Hk = eye
                cells = ones
                in_px = min(in_px, deep_bit - clear)
            # the cells within the reach of a pixel deeper than the border, at steps of at
            # most one cell (numpy's linspace)
            rb = clear / min(L / 8.0, deep_bit)
            no = 2 * int(np.ceil(rb)) + 1
            offs = np.empty(no)
            step = 2.0 * rb / (no - 1)
            for a in range(no):
                offs[a] = a * step + -rb
            offs[no - 1] = rb
            # the adjacent edges' lines, their normals into the tag
            cx = (Qt[0, 0] + Qt[1, 0] + Qt[2, 0] + Qt[3, 0]) / 4.0
            cy = (Qt[0, 1] + Qt[1, 1] + Qt[2, 1] + Qt[3, 1]) / 4.0
            A0, B0 = Qt[(k - 1) % 4], Qt[k]
            A1, B1 = Qt[(k + 1) % 4], Qt[(k + 2) % 4]
            g0 = (B0 - A0) / np.hypot(B0[0] - A0[0], B0[1] - A0[1])
            m0 = np.array([-g0[1], g0[0]])
            if not m0[0] * (cx - A0[0]) + m0[1] * (cy - A0[1]) > 0:
                m0 = -m0
            g1 = (B1 - A1) / np.hypot(B1[0] - A1[0], B1[1] - A1[1])
            m1 = np.array([-g1[1], g1[0]])
            if not m1[0] * (cx - A1[0]) + m1[1] * (cy - A1[1]) > 0:
                m1 = -m1
            c1 = _band(Qt[k], e, n, L, curves[i, k], t_lo, t_hi, out_px, in_px,
                       deep_bit - clear, Hk, cells, offs, box[i, k, 0], box[i, k, 1],
                       box[i, k, 2], box[i, k, 3], k, deep_bit, A0, m0, A1, m1,
                       oix, oiy, ot, os_, c)
            if c1 - c < min_pixels:
                status[i, k] = 1
                continue
            dark = 0
            lo_x, lo_y, hi_x, hi_y = oix[c], oiy[c], oix[c], oiy[c]
            d = curves[i, k]
            for p in range(c, c1):
                tau = 2.0 * ot[p] / L - 1.0
                if os_[p] - (d[0] + tau * (d[1] + tau * (d[2] + tau * d[3]))) >= 0.0:
                    dark += 1
                lo_x, hi_x = min(lo_x, oix[p]), max(hi_x, oix[p])
                lo_y, hi_y = min(lo_y, oiy[p]), max(hi_y, oiy[p])
            if lo_x < border or lo_y < border or hi_x > width - 1 - border or \
                    hi_y > height - 1 - border:
                status[i, k] = 3
                continue
            if dark < min_pixels // 2:
                # its pixels are kept: fitted with its board line's neighbours, which see
                # their dark side, the line may still be placed (targets.tag_edges)
                status[i, k] = 2
            c = c1
    off[4 * N] = c
    return status, Ls, es, ns, off, oix[:c], oiy[:c], ot[:c], os_[:c]


@njit(cache=True, error_model="numpy", inline="always")
def _curve_point(P0, L, e, n, d, t):
    # the point of a curve (d0..d3 in the frame of the chord from P0, length L, direction e,
    # normal n) at t along the chord, and its tangent per unit t
    tau = 2.0 * t / L - 1.0
    s = d[0] + tau * (d[1] + tau * (d[2] + tau * d[3]))
    ds = (d[1] + tau * (2.0 * d[2] + 3.0 * tau * d[3])) * 2.0 / L
    return (P0[0] + t * e[0] + s * n[0], P0[1] + t * e[1] + s * n[1],
            e[0] + ds * n[0], e[1] + ds * n[1])


@njit(cache=True, error_model="numpy")
def meet_curves(Pa, La, ea, na, da, Pb, Lb, eb, nb, db, iterations):
    r'''(M,2) where each curve a (near its end t = La) meets its curve b (near its start
t = 0): Newton, NaN where the tangents are parallel. Curves as _curve_point's, one per row
of Pa (M,2), La (M,), ea, na (M,2), da (M,4) and of the b ones.'''
    M = len(La)
    out = np.full((M, 2), np.nan)
    for j in range(M):
        ta = La[j]
        tb = 0.0
        ok = True
        for _ in range(iterations):
            pax, pay, gax, gay = _curve_point(Pa[j], La[j], ea[j], na[j], da[j], ta)
            pbx, pby, gbx, gby = _curve_point(Pb[j], Lb[j], eb[j], nb[j], db[j], tb)
            # solve [ga, -gb] (dta, dtb) = pb - pa (Cramer's rule)
            rx = pbx - pax
            ry = pby - pay
            det = -gax * gby + gbx * gay
            if not abs(det) > 1e-12:
                ok = False
                break
            dta = (-rx * gby + gbx * ry) / det
            dtb = (gax * ry - gay * rx) / det
            ta, tb = ta + dta, tb + dtb
            if max(abs(dta), abs(dtb)) < 1e-9:
                break
        if ok:
            pax, pay, _, _ = _curve_point(Pa[j], La[j], ea[j], na[j], da[j], ta)
            out[j, 0] = pax
            out[j, 1] = pay
    return out


# the moments edge_moments sums per edge (w the pixel's weight, F, g = F' its profile and
# slope, tau its position): w, w F, w F^2; w g tau^k and w F g tau^k (k <= 5: a quintic
# reference's projection); w g^2 tau^k (k <= 8: a cubic's normal matrix, k <= 6, and its
# projection of the quintic)
SPAN_W, SPAN_G, SPAN_FG, SPAN_GG = 0, 3, 9, 15
SPAN_MOMENTS = 24


@njit(cache=True, error_model="numpy")
def edge_moments(t, s, wt, a, b, d, L, j0, fy, cuts, x0, h, F, dF):
    r'''(m, 3, SPAN_MOMENTS): each edge's moments (SPAN_W..) over its pixels [a[j], b[j]) of
t, s, weighted by wt (fit_edges' w) (its own chord frame, length L[j], curve d[j] =
d0..d2, its normal's angle bin j0[j], fy[j]) in three bins of their position tau = 2 t /
L[j] - 1 along it: below cuts[0], up to cuts[1], beyond; F, g = F' at x = s - d(tau) from
the table (x0, h, F, dF (A,X)): the moments of the normal equations of a curve fitted along
the edge, in units of the contrast and the noise, its light level and contrast free
(targets.tag_edges._span_choice)'''
    m = len(a)
    out = np.zeros((m, 3, SPAN_MOMENTS))
    X = dF.shape[1]
    for j in range(m):
        ja, fa = j0[j], fy[j]
        for q in range(a[j], b[j]):
            tau = 2.0 * t[q] / L[j] - 1.0
            x = s[q] - (d[j, 0] + tau * (d[j, 1] + tau * d[j, 2]))
            fi = (x - x0) / h
            c = 0 if tau < cuts[0] else (1 if tau <= cuts[1] else 2)
            wq = wt[q]
            if fi <= 0.0 or fi >= X - 1:
                f = 0.0 if fi <= 0.0 else 1.0
                out[j, c, SPAN_W] += wq
                out[j, c, SPAN_W + 1] += wq * f
                out[j, c, SPAN_W + 2] += wq * f
                continue
            i = int(fi)
            fx = fi - i
            f = (F[ja, i] * (1.0 - fx) + F[ja, i + 1] * fx) * (1.0 - fa) \
                + (F[ja + 1, i] * (1.0 - fx) + F[ja + 1, i + 1] * fx) * fa
            g = (dF[ja, i] * (1.0 - fx) + dF[ja, i + 1] * fx) * (1.0 - fa) \
                + (dF[ja + 1, i] * (1.0 - fx) + dF[ja + 1, i + 1] * fx) * fa
            wf = wq * f
            out[j, c, SPAN_W] += wq
            out[j, c, SPAN_W + 1] += wf
            out[j, c, SPAN_W + 2] += wf * f
            wg = wq * g
            fg = wf * g
            gg = wg * g
            tk = 1.0
            for k in range(9):
                if k < 6:
                    out[j, c, SPAN_G + k] += wg * tk
                    out[j, c, SPAN_FG + k] += fg * tk
                out[j, c, SPAN_GG + k] += gg * tk
                tk *= tau
    return out


@intrinsic
def _fma(typingctx, a, b, c):
    # a b + c rounded once (LLVM's llvm.fma: the hardware's instruction, else libm's fma)
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)

    return sig, codegen


# how fit_pixels takes a piece of an edge's pixels: all of them in their own chord's frame
# (tag_edge_pixels' t, s); all of them in the fit's frame; those of them at most reach px
# beyond the fit's chord's end (u <= L + reach, u along it from its start); those at least
# reach px before its start (u >= -reach)
PIECE_OWN, PIECE_ALL, PIECE_BEYOND_END, PIECE_BEFORE_START = 0, 1, 2, 3


@njit(cache=True, error_model="numpy")
def fit_pixels(img, ix, iy, t, s, off, fit_off, piece_edge, piece_mode, piece_reach, P0, e, n,
               L, d):
    r'''The pixels of every fit of targets.tag_edges' last pass, one fit after another, as
fit_edges takes them: fit f is the pieces [fit_off[f], fit_off[f+1]) of piece_edge (edges of
tag_edge_pixels: edge c's pixels are [off[c], off[c+1]) of ix, iy, t, s), each taken as
piece_mode says (PIECE_OWN.., piece_reach its px), in the frame of the fit's chord (from
P0[f] (F,2), direction e[f], normal n[f], length L[f]). Returns (out_off (F+1,), v, tau, s,
dark): fit f's pixels are [out_off[f], out_off[f+1]), v their values in img (H,W) as float64,
tau = 2 t / L[f] - 1; dark (F,4) int64: each fit's pixels on the dark side of its curve d[f]
(d0..d3), or on it (s - d(tau) >= 0, d(tau) by Horner as targets.tag_edges._curve_s;
tests/test_tag_edges.py holds the counts to numpy's test), counted where t < 0, t > L,
t < L / 2 and t > L / 2 (tag_edges._sees_dark, _sees_dark_near; counted here, as they are
gathered: the fits' t is not kept).

A pixel's t and s in the fit's frame are r.e and r.n, r its centre less P0, each rounded as
fma(r_x, e_x, r_y e_y): as numpy's r @ e rounds them on this machine (OpenBLAS's dgemv
kernel; 2 or more rows), which this replaced (targets.tag_edges: the corners the same
bits).'''
    F = len(L)
    cap = 0
    for c in range(len(piece_edge)):
        cap += off[piece_edge[c] + 1] - off[piece_edge[c]]
    ov = np.empty(cap)
    otau = np.empty(cap)
    os_ = np.empty(cap)
    out_off = np.zeros(F + 1, np.int64)
    dark = np.zeros((F, 4), np.int64)
    q = 0
    for f in range(F):
        out_off[f] = q
        px, py = P0[f, 0], P0[f, 1]
        ex, ey, nx, ny, Lf = e[f, 0], e[f, 1], n[f, 0], n[f, 1], L[f]
        half = 0.5 * Lf
        d0, d1, d2, d3 = d[f, 0], d[f, 1], d[f, 2], d[f, 3]
        for c in range(fit_off[f], fit_off[f + 1]):
            mode = piece_mode[c]
            hi = Lf + piece_reach[c]
            lo = -piece_reach[c]
            for p in range(off[piece_edge[c]], off[piece_edge[c] + 1]):
                if mode == PIECE_OWN:
                    tp, sp = t[p], s[p]
                else:
                    rx = ix[p] - px
                    ry = iy[p] - py
                    tp = _fma(rx, ex, ry * ey)
                    if (mode == PIECE_BEYOND_END and not tp <= hi) or \
                            (mode == PIECE_BEFORE_START and not tp >= lo):
                        continue
                    sp = _fma(rx, nx, ry * ny)
                ov[q] = np.float64(img[iy[p], ix[p]])
                tau = 2.0 * tp / Lf - 1.0
                otau[q] = tau
                os_[q] = sp
                q += 1
                if sp - (d0 + tau * (d1 + tau * (d2 + tau * d3))) >= 0.0:
                    if tp < 0.0:
                        dark[f, 0] += 1
                    if tp > Lf:
                        dark[f, 1] += 1
                    if tp < half:
                        dark[f, 2] += 1
                    if tp > half:
                        dark[f, 3] += 1
    out_off[F] = q
    return out_off, ov[:q], otau[:q], os_[:q], dark


def compiled_entry_points():
    r'''The compiled kernels of this module that Python calls (numba dispatchers), for a
warm-up's check of numba's cache (harness.warmup; the AprilTag detector calls them on
blurred images, targets.tag_edges)'''
    return (tag_edge_pixels, fit_pixels, fit_edges, meet_curves, blur_step, plateau_counts,
            edge_moments, noise_moments, pixel_weights, sampled_table)

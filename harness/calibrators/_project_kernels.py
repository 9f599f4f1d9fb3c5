r'''Compiled projection of CAHV / CAHVOR / CAHVORE points (numba, float64, fastmath off)

SYNOPSIS

    from harness.calibrators._project_kernels import pack_model, project, project_packed

    q = project(model, p)        # p (...,3) world points -> q (...,2) pixels, = model.project(p)

    cam = pack_model(model)      # (NCAM,) float64, once per model; or
    cam = pack("CAHVOR", C, A, H, V, O, R)
    q = project_packed(cam, p)   # the same, without packing again
    mc = CompiledProjection(model)   # the model, with project() compiled
    r = residuals_packed(cam, p, q, 1e4)   # (project - q).ravel(), 1e4 where not finite
    cam = pack_chart(x, ...)     # the jpl calibrator's trial model (None: build it instead)
    J_T, ok = jacobian_chart(x, h, ...)   # its forward differences, every column in one call

The projection of reference_models.cahvore (the equations of its module
docstring) ported point by point: d = p - C; for CAHVOR the bend about O by
mu = R0 + R1 tau + R2 tau^2 (tau = |lambda|^2 / omega^2); for CAHVORE the
Newton solve of

    zeta sin(theta) - l cos(theta) = (theta - sin(theta)) (E0 + E1 theta^2 + E2 theta^4)

from theta = atan2(l, zeta), chi(theta) by the linearity L and
d' = (l/chi) O + (1 + mu)(d - zeta O); then CAHV on d'. Same pixel convention,
same invalid points: a pixel is NaN (both coordinates) where the reference
gives NaN, i.e. behind the camera (<d',A> not > 0), for CAHVOR with
<d,O> not > 0, for CAHVORE where theta |L| > pi/2 (or theta is not finite).

The only difference from the reference is where the theta Newton iteration
stops: per point here, when all points have converged there (an extra step on
a converged point moves theta by < 1e-15). The projections agree to < 1e-10 px
(tests/test_project_kernels.py); far outside the CAHVORE domain, where that
iteration finds no root or is chaotic, the reference's result depends on
rounding and on the other points of its batch, and so may this one's. One
compiled signature per kernel: float64 arrays, C contiguous.
'''

import math

import numpy as np
from numba import njit

KIND_CAHV = 0
KIND_CAHVOR = 1
KIND_CAHVORE = 2
KINDS = {"CAHV": KIND_CAHV, "CAHVOR": KIND_CAHVOR, "CAHVORE": KIND_CAHVORE}

# layout of the packed model
_C, _A, _H, _V, _O, _R, _E = 0, 3, 6, 9, 12, 15, 18
_L, _KIND = 21, 22
NCAM = 23

# as reference_models.cahvore
NEWTON_MAX_ITERATIONS = 100
NEWTON_TOLERANCE = 1e-15


def pack(family, C, A, H, V, O=None, R=None, E=None, linearity=None):
    r'''The numbers of a CAHV/CAHVOR/CAHVORE model as one float64 array (NCAM,)

O, R are needed for CAHVOR and CAHVORE, E and linearity for CAHVORE; A and O are
used as given (unit vectors, as the model stores them).
'''
    if family not in KINDS:
        raise ValueError(f"cannot project a {family!r} model; known: {', '.join(KINDS)}")
    cam = np.zeros(NCAM, dtype=np.float64)
    cam[_C:_C + 3] = C
    cam[_A:_A + 3] = A
    cam[_H:_H + 3] = H
    cam[_V:_V + 3] = V
    cam[_KIND] = KINDS[family]
    if family != "CAHV":
        cam[_O:_O + 3] = O
        cam[_R:_R + 3] = R
    if family == "CAHVORE":
        cam[_E:_E + 3] = E
        cam[_L] = linearity
    return cam


def pack_model(model):
    r'''pack() of a reference_models.cahvore model'''
    return pack(model.family, model.C, model.A, model.H, model.V, getattr(model, "O", None),
                getattr(model, "R", None), getattr(model, "E", None),
                getattr(model, "linearity", None))


@njit(cache=True, error_model="numpy")
def _solve_theta(zeta, l, e0, e1, e2):
    r'''theta with zeta sin(theta) - l cos(theta) = (theta - sin(theta)) E(theta) (Newton)'''
    theta = math.atan2(l, zeta)
    for _ in range(NEWTON_MAX_ITERATIONS):
        s = math.sin(theta)
        c = math.cos(theta)
        t2 = theta * theta
        e = e0 + t2 * (e1 + t2 * e2)
        de = theta * (2.0 * e1 + 4.0 * e2 * t2)
        f = zeta * s - l * c - (theta - s) * e
        df = zeta * c + l * s - (1.0 - c) * e - (theta - s) * de
        step = f / df
        theta = theta - step
        if not (abs(step) > NEWTON_TOLERANCE):
            break
    return theta


@njit(cache=True, error_model="numpy")
def _project_kernel(cam, p, out):
    kind = int(cam[_KIND])
    Cx, Cy, Cz = cam[_C], cam[_C + 1], cam[_C + 2]
    Ax, Ay, Az = cam[_A], cam[_A + 1], cam[_A + 2]
    Hx, Hy, Hz = cam[_H], cam[_H + 1], cam[_H + 2]
    Vx, Vy, Vz = cam[_V], cam[_V + 1], cam[_V + 2]
    Ox, Oy, Oz = cam[_O], cam[_O + 1], cam[_O + 2]
    R0, R1, R2 = cam[_R], cam[_R + 1], cam[_R + 2]
    E0, E1, E2 = cam[_E], cam[_E + 1], cam[_E + 2]
    L = cam[_L]
    nan = np.nan
    for i in range(p.shape[0]):
        dx = p[i, 0] - Cx
        dy = p[i, 1] - Cy
        dz = p[i, 2] - Cz
        if kind == KIND_CAHVOR:
            omega = dx * Ox + dy * Oy + dz * Oz
            lx = dx - omega * Ox
            ly = dy - omega * Oy
            lz = dz - omega * Oz
            tau = (lx * lx + ly * ly + lz * lz) / (omega * omega)
            mu = R0 + tau * (R1 + tau * R2)
            if omega > 0:
                dx = dx + mu * lx
                dy = dy + mu * ly
                dz = dz + mu * lz
            else:
                dx = nan
                dy = nan
                dz = nan
        elif kind == KIND_CAHVORE:
            zeta = dx * Ox + dy * Oy + dz * Oz
            lx = dx - zeta * Ox
            ly = dy - zeta * Oy
            lz = dz - zeta * Oz
            l = math.sqrt(lx * lx + ly * ly + lz * lz)
            theta = _solve_theta(zeta, l, E0, E1, E2)
            if theta * abs(L) > math.pi / 2:
                dx = nan
                dy = nan
                dz = nan
            else:
                if L > 1e-15:
                    chi = math.tan(L * theta) / L
                elif L < -1e-15:
                    chi = math.sin(L * theta) / L
                else:
                    chi = theta
                if theta <= 1e-8:
                    zetap = zeta
                    mu = 0.0
                else:
                    zetap = l / chi
                    chi2 = chi * chi
                    mu = R0 + chi2 * (R1 + chi2 * R2)
                dx = zetap * Ox + (1.0 + mu) * lx
                dy = zetap * Oy + (1.0 + mu) * ly
                dz = zetap * Oz + (1.0 + mu) * lz
        da = dx * Ax + dy * Ay + dz * Az
        if da > 0:
            out[i, 0] = (dx * Hx + dy * Hy + dz * Hz) / da
            out[i, 1] = (dx * Vx + dy * Vy + dz * Vz) / da
        else:
            out[i, 0] = nan
            out[i, 1] = nan


def project_packed(cam, p):
    r'''Pixels (...,2) of world points p (...,3) by the packed model cam (pack_model)'''
    p = np.asarray(p, dtype=np.float64)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"p must have shape (...,3); got {p.shape}")
    out = np.empty(p.shape[:-1] + (2,), dtype=np.float64)
    _project_kernel(cam, np.ascontiguousarray(p.reshape(-1, 3)), out.reshape(-1, 2))
    return out


def project(model, p):
    r'''model.project(p), compiled: p (...,3) -> (...,2)'''
    return project_packed(pack_model(model), p)


@njit(cache=True, error_model="numpy")
def _residuals_kernel(cam, p, q, unprojectable, out):
    pix = np.empty((p.shape[0], 2), dtype=np.float64)
    _project_kernel(cam, p, pix)
    for i in range(p.shape[0]):
        for k in range(2):
            r = pix[i, k] - q[i, k]
            out[2 * i + k] = r if math.isfinite(r) else unprojectable


def residuals_packed(cam, p, q, unprojectable):
    r'''(project_packed(cam, p) - q).ravel(), with `unprojectable` where not finite

p (N,3) and q (N,2) float64, C contiguous.
'''
    out = np.empty(2 * p.shape[0], dtype=np.float64)
    _residuals_kernel(cam, p, q, float(unprojectable), out)
    return out


@njit(cache=True, error_model="numpy")
def _unit_vector(base, e0, e1, a, b, out):
    r'''out = n / |n| for n = base + a e0 + b e1; False if that is not finite

Then normalised once more if its norm is off 1 by more than 4 eps, as
reference_models.cahvore's _unit treats a vector given to a model.
'''
    for k in range(3):
        out[k] = base[k] + a * e0[k] + b * e1[k]
    for i in range(2):
        n = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
        if not (math.isfinite(n) and n > 0.0):
            return False
        if i == 1 and abs(n - 1.0) <= 4 * 2.220446049250313e-16:
            break
        for k in range(3):
            out[k] = out[k] / n
    return True


@njit(cache=True, error_model="numpy")
def _chart_kernel(x, A0, eA0, eA1, O0, eO0, eO1, R0, kind, linearity, min_hs, max_cos,
                  min_oa, cam):
    for k in range(x.shape[0]):
        if not math.isfinite(x[k]):
            return False
    A = cam[_A:_A + 3]
    if not _unit_vector(A0, eA0, eA1, x[3], x[4], A):
        return False
    for k in range(3):
        cam[_C + k] = x[k]
        cam[_H + k] = x[5 + k]
        cam[_V + k] = x[8 + k]
    H = cam[_H:_H + 3]
    V = cam[_V:_V + 3]
    hc = H[0] * A[0] + H[1] * A[1] + H[2] * A[2]
    vc = V[0] * A[0] + V[1] * A[1] + V[2] * A[2]
    hh = 0.0
    vv = 0.0
    hv = 0.0
    for k in range(3):
        h = H[k] - hc * A[k]
        v = V[k] - vc * A[k]
        hh += h * h
        vv += v * v
        hv += h * v
    Hs = math.sqrt(hh)
    Vs = math.sqrt(vv)
    if not (Hs > min_hs * math.sqrt(H[0] * H[0] + H[1] * H[1] + H[2] * H[2])
            and Vs > min_hs * math.sqrt(V[0] * V[0] + V[1] * V[1] + V[2] * V[2])
            and abs(hv / (Hs * Vs)) < max_cos):
        return False
    cam[_KIND] = kind
    if kind == KIND_CAHV:
        return True
    O = cam[_O:_O + 3]
    if not _unit_vector(O0, eO0, eO1, x[11], x[12], O):
        return False
    if not (O[0] * A[0] + O[1] * A[1] + O[2] * A[2] > min_oa):
        return False
    cam[_R] = R0
    cam[_R + 1] = x[13]
    cam[_R + 2] = x[14]
    if kind == KIND_CAHVORE:
        for k in range(3):
            cam[_E + k] = x[15 + k]
        cam[_L] = linearity
    return True


def pack_chart(x, A0, eA0, eA1, O0, eO0, eO1, R0, family, linearity, min_hs, max_cos, min_oa):
    r'''The packed model of the jpl calibrator's chart (harness.calibrators.jpl_fit._Chart)

SYNOPSIS

    cam = pack_chart(x, A0, eA0, eA1, O0, eO0, eO1, R0, "CAHVORE", L, 2e-6, cos(2e-3), 1e-6)

x: C (3), A (2: A0 + x3 eA0 + x4 eA1, normalised), H (3), V (3) [, O (2, about O0),
R1, R2 [, E (3)]]. None where x is not finite or the model is near or past its
limits: Hs or Vs <= min_hs |H| or |V|, |cos theta| >= max_cos, <O,A> <= min_oa
(the caller then builds the model, which decides). For CAHV, pass O0, eO0, eO1 as A0,
eA0, eA1 (they are not used).
'''
    cam = np.zeros(NCAM, dtype=np.float64)
    ok = _chart_kernel(np.ascontiguousarray(x, dtype=np.float64), A0, eA0, eA1, O0, eO0, eO1,
                       float(R0), KINDS[family], float(linearity or 0.0), float(min_hs),
                       float(max_cos), float(min_oa), cam)
    return cam if ok else None


@njit(cache=True, error_model="numpy")
def _jacobian_kernel(x, h, A0, eA0, eA1, O0, eO0, eO1, R0, kind, linearity, min_hs, max_cos,
                     min_oa, p, q, unprojectable, f0, J_T, ok):
    x1 = x.copy()
    cam = np.empty(NCAM, dtype=np.float64)
    pix = np.empty((p.shape[0], 2), dtype=np.float64)
    for i in range(x.shape[0]):
        x1[i] = x[i] + h[i]
        cam[:] = 0.0
        ok[i] = _chart_kernel(x1, A0, eA0, eA1, O0, eO0, eO1, R0, kind, linearity, min_hs,
                              max_cos, min_oa, cam)
        x1[i] = x[i]
        if not ok[i]:
            continue
        _project_kernel(cam, p, pix)
        dx = (x[i] + h[i]) - x[i]
        for j in range(p.shape[0]):
            for k in range(2):
                r = pix[j, k] - q[j, k]
                if not math.isfinite(r):
                    r = unprojectable
                J_T[i, 2 * j + k] = (r - f0[2 * j + k]) / dx


def jacobian_chart(x, h, A0, eA0, eA1, O0, eO0, eO1, R0, family, linearity, min_hs, max_cos,
                   min_oa, p, q, unprojectable, f0):
    r'''Forward differences of residuals_packed(pack_chart(x, ...), p, q) at x, steps h

SYNOPSIS

    J_T, ok = jacobian_chart(x, h, A0, ..., min_oa, p, q, 1e4, f0)
    # J_T (len(x), 2N): row i = (residuals at x + h_i e_i - f0) / ((x_i + h_i) - x_i)

The jpl calibrator's Jacobian in one call, the same numbers as residuals_packed
and pack_chart column by column. ok[i] is False where pack_chart would give None
for x + h_i e_i (row i is then not computed: the caller builds that model).
'''
    x = np.ascontiguousarray(x, dtype=np.float64)
    J_T = np.empty((x.shape[0], 2 * p.shape[0]), dtype=np.float64)
    ok = np.zeros(x.shape[0], dtype=np.bool_)
    _jacobian_kernel(x, np.ascontiguousarray(h, dtype=np.float64), A0, eA0, eA1, O0, eO0, eO1,
                     float(R0), KINDS[family], float(linearity or 0.0), float(min_hs),
                     float(max_cos), float(min_oa), p, q, float(unprojectable),
                     np.ascontiguousarray(f0, dtype=np.float64), J_T, ok)
    return J_T, ok


@njit(cache=True, error_model="numpy")
def _outline_fits_kernel(outline_cam, Rt, cos_min, R_ref_cam, t_ref_cam, cam, lo_x, hi_x,
                         lo_y, hi_y):
    m = outline_cam.shape[0]
    t = Rt[3]
    n = np.empty(3, dtype=np.float64)
    for k in range(3):
        n[k] = Rt[k, 2]
    p = np.empty((m, 3), dtype=np.float64)
    for i in range(m):
        for k in range(3):
            p[i, k] = outline_cam[i, k] + t[k]
        if not p[i, 2] > 0:
            return False
    for i in range(m):
        r = math.sqrt(p[i, 0] * p[i, 0] + p[i, 1] * p[i, 1] + p[i, 2] * p[i, 2])
        if not ((p[i, 0] / r) * n[0] + (p[i, 1] / r) * n[1] + (p[i, 2] / r) * n[2] >= cos_min):
            return False
    p_ref = np.empty((m, 3), dtype=np.float64)
    for i in range(m):
        for k in range(3):
            p_ref[i, k] = (p[i, 0] * R_ref_cam[k, 0] + p[i, 1] * R_ref_cam[k, 1]
                           + p[i, 2] * R_ref_cam[k, 2]) + t_ref_cam[k]
    q = np.empty((m, 2), dtype=np.float64)
    _project_kernel(cam, p_ref, q)
    for i in range(m):
        if not (q[i, 0] >= lo_x and q[i, 0] <= hi_x and q[i, 1] >= lo_y and q[i, 1] <= hi_y):
            return False
    return True


def outline_fits(outline_cam, Rt, cos_min, R_ref_cam, t_ref_cam, cam, lo, hi):
    r'''Whether a board outline at translation t lies in front, faces the camera and
projects into the image (the pose planner's test, targets.poses._Planner.fits)

SYNOPSIS

    ok = outline_fits(outline_cam, Rt, cos_min, R_ref_cam, t_ref_cam, cam,
                      (x_lo, y_lo), (x_hi, y_hi))

outline_cam (M,3): the outline rotated into the camera frame; Rt (4,3) the board
pose: p = outline_cam + Rt[3], the board normal n = Rt[:3, 2].
True when every p has z > 0, <p/|p|, n> >= cos_min, and the packed model cam
projects p_ref = R_ref_cam p + t_ref_cam within [lo, hi] (NaN: False). All
arrays float64, C contiguous. The sums are in another order than numpy's
matmul (< 1 ulp apart): only a point on a limit to the last bit can decide
differently.
'''
    return _outline_fits_kernel(outline_cam, Rt, float(cos_min), R_ref_cam, t_ref_cam, cam,
                                float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))


class CompiledProjection:
    r'''A model whose project() is the compiled one; every other attribute is the model's

SYNOPSIS

    b, change = bias_step(CompiledProjection(model), target, Rts, p_board)

For code written against the model interface (project, Rt_ref_cam, family, ...).
'''

    def __init__(self, model):
        self.model = model
        self.cam = pack_model(model)

    def __getattr__(self, name):
        return getattr(self.model, name)

    def project(self, p):
        return project_packed(self.cam, p)

r'''Compiled projection of CAHV / CAHVOR / CAHVORE points (numba, float64, fastmath off)

SYNOPSIS

    from harness.calibrators._project_kernels import pack, pack_model, project, project_packed

    q = project(model, p)        # p (N,3) world points -> q (N,2) pixels, = model.project(p)

    cam = pack_model(model)      # (NCAM,) float64, once per model; or
    cam = pack("CAHVOR", C, A, H, V, O, R)
    q = project_packed(cam, p)   # the same, without packing again
    mc = CompiledProjection(model)   # the model, with project() compiled

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

r'''Compiled trial models of the jpl calibrator: its chart and the Jacobian of its residuals

SYNOPSIS

    from harness.calibrators._jpl_kernels import jacobian_chart, pack_chart

    cam = pack_chart(x, A0, eA0, eA1, O0, eO0, eO1, R0, "CAHVORE", L, 2e-6, cos(2e-3), 1e-6)
    # the packed model (reference_models.kernels) of the trial parameters x, or None
    J_T, ok = jacobian_chart(x, h, A0, ..., min_oa, p, q, 1e4, f0)
    # forward differences of its residuals, every column in one call

The parametrisation (the chart) of harness.calibrators.jpl_fit: fit-specific,
so it lives beside the fit; the camera model it packs and projects is
reference_models.kernels' (one packed layout, one projection). float64,
fastmath off, one compiled signature per kernel.
'''

import math

import numpy as np
from numba import njit

from reference_models.kernels import (
    _A,
    _C,
    _E,
    _H,
    _KIND,
    _L,
    _O,
    _R,
    _V,
    KIND_CAHV,
    KIND_CAHVORE,
    KINDS,
    NCAM,
    project_points,
    residual,
    set_pinhole_rays,
)


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
eA0, eA1 (they are not used). The packed model of reference_models.kernels,
every slot filled as its pack() fills them.
'''
    cam = np.zeros(NCAM, dtype=np.float64)
    ok = _chart_kernel(np.ascontiguousarray(x, dtype=np.float64), A0, eA0, eA1, O0, eO0, eO1,
                       float(R0), KINDS[family], float(linearity or 0.0), float(min_hs),
                       float(max_cos), float(min_oa), cam)
    if not ok:
        return None
    set_pinhole_rays(cam)
    return cam


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
        project_points(cam, p, pix)
        dx = (x[i] + h[i]) - x[i]
        for j in range(p.shape[0]):
            for k in range(2):
                r = residual(pix[j, k] - q[j, k], unprojectable)
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


def compiled_entry_points():
    r'''The compiled kernels of this module that Python calls (numba dispatchers), for a
warm-up or reference_models.kernels.drop_stale_caches (they carry its projection)'''
    return (_chart_kernel, _jacobian_kernel)

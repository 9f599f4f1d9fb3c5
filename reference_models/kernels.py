r'''The compiled CAHV / CAHVOR / CAHVORE camera models (numba, float64, fastmath off)

SYNOPSIS

    from reference_models import kernels

    cam = kernels.pack_model(model)             # (NCAM,) float64, once per model
    q = kernels.project_packed(cam, p)          # p (...,3) -> q (...,2), = model.project(p)
    q = kernels.project(model, p)               # the same, packing the model each call
    r = kernels.residuals_packed(cam, p, q, 1e4)   # (project - q).ravel(), 1e4 where not finite
    origin, v = kernels.unproject_grid(cam, q)  # q (...,2) -> (...,3) each, = model.unproject(q)
    s, vx, vy, vz = kernels.ray(cam, x, y)      # one exact ray of pixel q = (x, y), origin C + s O
    warm = kernels.warm_start(cam, ix, iy)      # Newton start near pixel (ix, iy)
    s, vx, vy, vz = kernels.ray_warm(cam, x, y, warm)   # the same ray, unnormalised, faster
    dirs, shift = kernels.build_ray_cache(cam, W, H, noncentral)  # centre rays of pixels -1..W

The one compiled home of the equations of reference_models.cahvore (the numpy
reference, whose module docstring states them). A model is packed once into a
float64 array of NCAM slots (the layout below: C A H V O R E L KIND, then
V x H, V x A, A x H for the unprojection's linear pinhole ray); every kernel
takes that array. The scalar kernels (project_point, ray, warm_start,
ray_warm) are numba functions that other compiled modules call
(renderers._raycast_kernels, harness.calibrators._jpl_kernels,
targets.poses); the batch wrappers take and return numpy arrays.

Projection, point by point as the reference: d = p - C; for CAHVOR the bend
about O by mu = R0 + R1 tau + R2 tau^2 (tau = |lambda|^2 / omega^2); for
CAHVORE the Newton solve of

    zeta sin(theta) - l cos(theta) = (theta - sin(theta)) (E0 + E1 theta^2 + E2 theta^4)

from theta = atan2(l, zeta), chi(theta) by the linearity L and
d' = (l/chi) O + (1 + mu)(d - zeta O); then CAHV on d'. Same pixel convention,
same invalid points: a pixel is NaN (both coordinates) where the reference
gives NaN, i.e. behind the camera (<d',A> not > 0), for CAHVOR with
<d,O> not > 0, for CAHVORE where theta |L| > pi/2 (or theta is not finite).
The only difference from the reference is where the theta Newton iteration
stops: per point here, when all points have converged there (an extra step on
a converged point moves theta by < 1e-15). The projections agree to < 1e-10 px
(tests/test_kernels.py); far outside the CAHVORE domain, where that iteration
finds no root or is chaotic, the reference's result depends on rounding and on
the other points of its batch, and so may this one's.

Unprojection, line by line as the reference: the CAHV ray through the
pinhole, then for CAHVOR the 1-D Newton solve for chi (_newton_chi, the one
Newton loop of every unprojection here: single rays, warm starts and the ray
cache), and for CAHVORE the angle theta = theta(chi) and the entrance-pupil
shift along O. A ray's origin is C + s O (s = 0 for central models), so a ray
is stored as (s, v) and the noncentral part costs one float. The rays agree
with model.unproject to ~1e-15.

One compiled signature per kernel: float64 arrays, C contiguous. numba's
on-disk cache stamps only the source file of the function it compiles
(numba issue 1833): a kernel of another module that calls these
(render_kernel, the jpl chart's Jacobian, the pose planner's outline test)
would be loaded from the cache with the old code of this file after a change
here; drop_stale_caches() forgets those caches (a warm-up calls it first).
'''

import math
import os

import numpy as np
from numba import njit, prange

from .cahvore import NEWTON_MAX_ITERATIONS, NEWTON_TOLERANCE

KIND_CAHV = 0
KIND_CAHVOR = 1
KIND_CAHVORE = 2
KINDS = {"CAHV": KIND_CAHV, "CAHVOR": KIND_CAHVOR, "CAHVORE": KIND_CAHVORE}

# layout of the packed model: C A H V O R E (3 each), L, KIND, then V x H, V x A, A x H
_C, _A, _H, _V, _O, _R, _E = 0, 3, 6, 9, 12, 15, 18
_L, _KIND = 21, 22
_W0, _WX, _WY = 23, 26, 29
NCAM = 32

# subsample rays: Newton from a close start stops after a step below this (relative)
WARM_TOLERANCE = 1e-8


def pack(family, C, A, H, V, O=None, R=None, E=None, linearity=None):
    r'''The numbers of a CAHV/CAHVOR/CAHVORE model as one float64 array (NCAM,)

SYNOPSIS

    cam = pack("CAHVOR", C, A, H, V, O, R)     # (NCAM,) float64

O, R are needed for CAHVOR and CAHVORE, E and linearity for CAHVORE; A and O are
used as given (unit vectors, as the model stores them).
'''
    if family not in KINDS:
        raise ValueError(f"cannot pack a {family!r} model; known: {', '.join(KINDS)}")
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
    set_pinhole_rays(cam)
    return cam


@njit(cache=True, error_model="numpy", inline="always")
def _cross(cam, i, j, k):
    r'''cam[k:k+3] = cam[i:i+3] x cam[j:j+3] (np.cross's products and differences)'''
    cam[k] = cam[i + 1] * cam[j + 2] - cam[i + 2] * cam[j + 1]
    cam[k + 1] = cam[i + 2] * cam[j] - cam[i] * cam[j + 2]
    cam[k + 2] = cam[i] * cam[j + 1] - cam[i + 1] * cam[j]


@njit(cache=True, error_model="numpy")
def set_pinhole_rays(cam):
    r'''Fill the unprojection's slots of a packed model from its A, H, V: V x H, V x A, A x H

(the CAHV ray of pixel (x, y) is V x H - x V x A - y A x H; ray_warm)'''
    _cross(cam, _V, _H, _W0)
    _cross(cam, _V, _A, _WX)
    _cross(cam, _A, _H, _WY)


def pack_model(model):
    r'''pack() of a reference_models.cahvore model'''
    return pack(model.family, model.C, model.A, model.H, model.V, getattr(model, "O", None),
                getattr(model, "R", None), getattr(model, "E", None),
                getattr(model, "linearity", None))


# ---------------------------------------------------------------------------
# Projection

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


@njit(cache=True, error_model="numpy", inline="always")
def project_point(cam, px, py, pz):
    r'''The pixel (x, y) of the world point (px, py, pz) by the packed model cam

NaN, NaN outside the model's domain (see the module docstring).'''
    kind = int(cam[_KIND])
    dx = px - cam[_C]
    dy = py - cam[_C + 1]
    dz = pz - cam[_C + 2]
    if kind == KIND_CAHVOR:
        Ox, Oy, Oz = cam[_O], cam[_O + 1], cam[_O + 2]
        omega = dx * Ox + dy * Oy + dz * Oz
        lx = dx - omega * Ox
        ly = dy - omega * Oy
        lz = dz - omega * Oz
        tau = (lx * lx + ly * ly + lz * lz) / (omega * omega)
        mu = cam[_R] + tau * (cam[_R + 1] + tau * cam[_R + 2])
        if omega > 0:
            dx = dx + mu * lx
            dy = dy + mu * ly
            dz = dz + mu * lz
        else:
            dx = np.nan
            dy = np.nan
            dz = np.nan
    elif kind == KIND_CAHVORE:
        Ox, Oy, Oz = cam[_O], cam[_O + 1], cam[_O + 2]
        L = cam[_L]
        zeta = dx * Ox + dy * Oy + dz * Oz
        lx = dx - zeta * Ox
        ly = dy - zeta * Oy
        lz = dz - zeta * Oz
        l = math.sqrt(lx * lx + ly * ly + lz * lz)
        theta = _solve_theta(zeta, l, cam[_E], cam[_E + 1], cam[_E + 2])
        if theta * abs(L) > math.pi / 2:
            dx = np.nan
            dy = np.nan
            dz = np.nan
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
                mu = cam[_R] + chi2 * (cam[_R + 1] + chi2 * cam[_R + 2])
            dx = zetap * Ox + (1.0 + mu) * lx
            dy = zetap * Oy + (1.0 + mu) * ly
            dz = zetap * Oz + (1.0 + mu) * lz
    da = dx * cam[_A] + dy * cam[_A + 1] + dz * cam[_A + 2]
    if da > 0:
        return ((dx * cam[_H] + dy * cam[_H + 1] + dz * cam[_H + 2]) / da,
                (dx * cam[_V] + dy * cam[_V + 1] + dz * cam[_V + 2]) / da)
    return np.nan, np.nan


@njit(cache=True, error_model="numpy")
def project_points(cam, p, out):
    r'''project_point() of every row of p (N,3) into out (N,2)'''
    for i in range(p.shape[0]):
        out[i, 0], out[i, 1] = project_point(cam, p[i, 0], p[i, 1], p[i, 2])


def project_packed(cam, p):
    r'''Project world points by a packed model

SYNOPSIS

    q = project_packed(pack_model(model), p)
    # p has shape (...,3); q has shape (...,2); = model.project(p) to < 1e-10 px

ARGUMENTS

- cam: the packed model (pack_model), float64 (NCAM,)
- p: world points, (...,3), in the model's frame

RETURNED VALUE

The pixels (...,2) float64; NaN (both coordinates) outside the model's domain.
'''
    p = np.asarray(p, dtype=np.float64)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"p must have shape (...,3); got {p.shape}")
    out = np.empty(p.shape[:-1] + (2,), dtype=np.float64)
    # writable: numba compiles a read-only array (a frozen model's grid) as another type,
    # i.e. a second signature, compiled again by each process that meets it
    project_points(cam, np.require(p.reshape(-1, 3), requirements=("C", "W")),
                   out.reshape(-1, 2))
    return out


def project(model, p):
    r'''model.project(p), compiled: p (...,3) -> (...,2); see project_packed'''
    return project_packed(pack_model(model), p)


@njit(cache=True, error_model="numpy", inline="always")
def residual(r, unprojectable):
    r'''r, or unprojectable where r is not finite'''
    return r if math.isfinite(r) else unprojectable


@njit(cache=True, error_model="numpy")
def _residuals_kernel(cam, p, q, unprojectable, out):
    pix = np.empty((p.shape[0], 2), dtype=np.float64)
    project_points(cam, p, pix)
    for i in range(p.shape[0]):
        for k in range(2):
            out[2 * i + k] = residual(pix[i, k] - q[i, k], unprojectable)


def residuals_packed(cam, p, q, unprojectable):
    r'''The reprojection residuals of points by a packed model

SYNOPSIS

    r = residuals_packed(cam, p, q, 1e4)
    # p has shape (N,3), q (N,2); r has shape (2N,): (project_packed(cam, p) - q).ravel()

ARGUMENTS

- cam: the packed model (pack_model)
- p: world points (N,3), float64, C contiguous
- q: observed pixels (N,2), float64, C contiguous
- unprojectable: the residual given where project - q is not finite

RETURNED VALUE

(2N,) float64.
'''
    out = np.empty(2 * p.shape[0], dtype=np.float64)
    _residuals_kernel(cam, p, q, float(unprojectable), out)
    return out


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


# ---------------------------------------------------------------------------
# Unprojection

@njit(cache=True, error_model="numpy", inline="always")
def _newton_chi(u, chi, r0, r1, r2, tolerance):
    r'''Newton for chi (1 + R0 + R1 chi^2 + R2 chi^4) = u from the start chi; NaN when
it fails (u beyond the maximum of a non-monotonic polynomial)

It stops after a step below tolerance * max(1, chi) where the convergence is
quadratic with a constant <= 1 (|g''| <= 2|g'|): the error left is below
tolerance^2 * max(1, chi)^2. With tolerance 1e-15 it stops at the floating-point
floor, as reference_models.cahvore does.'''
    for _ in range(NEWTON_MAX_ITERATIONS):
        chi2 = chi * chi
        g = chi * (1.0 + r0 + chi2 * (r1 + r2 * chi2)) - u
        dg = 1.0 + r0 + chi2 * (3.0 * r1 + 5.0 * r2 * chi2)
        step = g / dg
        chi = chi - step
        scale = max(1.0, abs(chi))
        if not (abs(step) > tolerance * scale):
            if (not (abs(step) > NEWTON_TOLERANCE * scale)
                    or abs(chi * (6.0 * r1 + 20.0 * r2 * chi2)) <= 2.0 * abs(dg)):
                return chi
    return math.nan


@njit(cache=True, error_model="numpy", inline="always")
def _pinhole_ray(cam, x, y):
    r'''Unit CAHV ray w = (V - y A) x (H - x A), turned to face A'''
    ax, ay, az = cam[_A], cam[_A + 1], cam[_A + 2]
    px = cam[_V] - y * ax
    py = cam[_V + 1] - y * ay
    pz = cam[_V + 2] - y * az
    qx = cam[_H] - x * ax
    qy = cam[_H + 1] - x * ay
    qz = cam[_H + 2] - x * az
    wx = py * qz - pz * qy
    wy = pz * qx - px * qz
    wz = px * qy - py * qx
    if wx * ax + wy * ay + wz * az < 0.0:
        wx, wy, wz = -wx, -wy, -wz
    n = 1.0 / math.sqrt(wx * wx + wy * wy + wz * wz)
    return wx * n, wy * n, wz * n


@njit(cache=True, error_model="numpy", inline="always")
def _split_raw(cam, wx, wy, wz):
    r'''(u, px, py, pz, n): p = w - zeta O (zeta = <w,O>), u = |p| / zeta, n = 1/|p|;
u is NaN for zeta <= 0 (outside the model's domain), n is 0 where |p| is not > 0'''
    ox, oy, oz = cam[_O], cam[_O + 1], cam[_O + 2]
    zeta = wx * ox + wy * oy + wz * oz
    px = wx - zeta * ox
    py = wy - zeta * oy
    pz = wz - zeta * oz
    lp = math.sqrt(px * px + py * py + pz * pz)
    n = 1.0 / lp if lp > 0.0 else 0.0
    u = lp / zeta if zeta > 0.0 else math.nan
    return u, px, py, pz, n


@njit(cache=True, error_model="numpy", inline="always")
def _split(cam, wx, wy, wz):
    r'''u = |w - zeta O| / zeta (zeta = <w,O>) and the unit vector along w - zeta O;
u is NaN for zeta <= 0 (outside the model's domain)'''
    u, px, py, pz, n = _split_raw(cam, wx, wy, wz)
    if n > 0.0:
        return u, px * n, py * n, pz * n
    return u, 0.0, 0.0, 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _ray_from_chi(cam, chi, ux, uy, uz, quick_cos=False):
    r'''(s, v) of a CAHVOR or CAHVORE ray from its solved chi

quick_cos (the ray cache): for theta < 1 rad, cos(theta) is sqrt((1 - s)(1 + s))
of s = sin(theta): within 4e-16 of it (|dc| <= (s/c) |ds| + 2 ulp, s/c < 1.6)'''
    ox, oy, oz = cam[_O], cam[_O + 1], cam[_O + 2]
    if cam[_KIND] == KIND_CAHVOR:
        vx = ox + chi * ux
        vy = oy + chi * uy
        vz = oz + chi * uz
        n = 1.0 / math.sqrt(vx * vx + vy * vy + vz * vz)
        return 0.0, vx * n, vy * n, vz * n
    L = cam[_L]
    if L > 1e-15:
        theta = math.atan(L * chi) / L
    elif L < -1e-15:
        t = L * chi
        theta = math.asin(t) / L if -1.0 <= t <= 1.0 else math.nan
    else:
        theta = chi
    s = math.sin(theta)
    if quick_cos and theta < 1.0:
        c = math.sqrt((1.0 - s) * (1.0 + s))
    else:
        c = math.cos(theta)
    vx = c * ox + s * ux
    vy = c * oy + s * uy
    vz = c * oz + s * uz
    # pupil shift (theta/sin(theta) - 1) E(theta), by its series near the axis
    t2 = theta * theta
    if theta < 1e-4:
        k = t2 / 6.0 + 7.0 * t2 * t2 / 360.0
    else:
        k = theta / s - 1.0
    shift = k * (cam[_E] + t2 * (cam[_E + 1] + t2 * cam[_E + 2]))
    return shift, vx, vy, vz


@njit(cache=True, error_model="numpy")
def ray(cam, x, y):
    r'''The exact ray of the image point (x, y): (s, vx, vy, vz), origin C + s O, |v| = 1

A point outside the model's domain gives NaN.'''
    wx, wy, wz = _pinhole_ray(cam, x, y)
    if cam[_KIND] == KIND_CAHV:
        return 0.0, wx, wy, wz
    u, ux, uy, uz = _split(cam, wx, wy, wz)
    r0 = cam[_R]
    chi = _newton_chi(u, u / (1.0 + r0), r0, cam[_R + 1], cam[_R + 2], NEWTON_TOLERANCE)
    return _ray_from_chi(cam, chi, ux, uy, uz)


@njit(cache=True, error_model="numpy", inline="always")
def _warm_coefficients(cam, u, chi):
    r"""(u, chi, a, b): the Taylor coefficients chi(u + du) = chi + a du + b du^2 + O(du^3)
of the solution chi at u (NaN, 0, 0, 0 when chi or they are not finite)"""
    r0, r1, r2 = cam[_R], cam[_R + 1], cam[_R + 2]
    chi2 = chi * chi
    a = 1.0 / (1.0 + r0 + chi2 * (3.0 * r1 + 5.0 * r2 * chi2))
    b = -0.5 * chi * (6.0 * r1 + 20.0 * r2 * chi2) * a * a * a
    if not (math.isfinite(chi) and math.isfinite(a) and math.isfinite(b)):
        return math.nan, 0.0, 0.0, 0.0
    return u, chi, a, b


@njit(cache=True, error_model="numpy")
def warm_start(cam, x, y):
    r"""(u0, chi0, a, b) at the image point (x, y): chi(u0 + du) = chi0 + a du + b du^2
+ O(du^3), the start of the Newton solves of nearby points (their rays are the
same as from a cold start, only found in fewer steps)"""
    if cam[_KIND] == KIND_CAHV:
        return 0.0, 0.0, 0.0, 0.0
    wx, wy, wz = _pinhole_ray(cam, x, y)
    u, ux, uy, uz = _split(cam, wx, wy, wz)
    r0, r1, r2 = cam[_R], cam[_R + 1], cam[_R + 2]
    chi = _newton_chi(u, u / (1.0 + r0), r0, r1, r2, NEWTON_TOLERANCE)
    return _warm_coefficients(cam, u, chi)


@njit(cache=True, error_model="numpy", inline="always")
def _ray_warm_chi(cam, x, y, warm, quick_cos=False):
    r"""ray_warm(), also returning the u and chi of the ray's Newton solve (0, 0 for CAHV);
quick_cos: see _ray_from_chi"""
    # cam[_W0:] holds V x H, V x A, A x H
    wx = cam[_W0] - x * cam[_WX] - y * cam[_WY]
    wy = cam[_W0 + 1] - x * cam[_WX + 1] - y * cam[_WY + 1]
    wz = cam[_W0 + 2] - x * cam[_WX + 2] - y * cam[_WY + 2]
    if wx * cam[_A] + wy * cam[_A + 1] + wz * cam[_A + 2] < 0.0:
        wx, wy, wz = -wx, -wy, -wz
    if cam[_KIND] == KIND_CAHV:
        return 0.0, wx, wy, wz, 0.0, 0.0
    u, px, py, pz, n = _split_raw(cam, wx, wy, wz)
    r0 = cam[_R]
    u0, chi0, a, b = warm
    if math.isfinite(u0):
        du = u - u0
        start = chi0 + du * (a + du * b)
    else:
        start = u / (1.0 + r0)
    chi = _newton_chi(u, start, r0, cam[_R + 1], cam[_R + 2], WARM_TOLERANCE)
    if cam[_KIND] == KIND_CAHVOR:
        k = chi * n
        return 0.0, cam[_O] + k * px, cam[_O + 1] + k * py, cam[_O + 2] + k * pz, u, chi
    s, vx, vy, vz = _ray_from_chi(cam, chi, px * n, py * n, pz * n, quick_cos)
    return s, vx, vy, vz, u, chi


@njit(cache=True, error_model="numpy", inline="always")
def ray_warm(cam, x, y, warm):
    r"""ray(cam, x, y) with an unnormalised direction, its Newton solve started from
the quadratic prediction of warm_start() (one Newton step, usually)

The CAHV ray (V - y A) x (H - x A) = V x H - x V x A - y A x H is linear in
(x, y); nothing downstream needs |v| = 1 (the board intersection does not), so
the normalisations of ray() are skipped.

Newton stops after a step below WARM_TOLERANCE (relative) where its
convergence is quadratic with a constant <= 1 (_newton_chi): the chi left is
within WARM_TOLERANCE^2 = 1e-16 (relative) of the root, the floating-point
floor."""
    s, vx, vy, vz, _, _ = _ray_warm_chi(cam, x, y, warm)
    return s, vx, vy, vz


@njit(parallel=True, cache=True, error_model="numpy")
def unproject_points(cam, q, origin, v):
    r'''ray() of every row of q (N,2): fills origin (N,3) and v (N,3)'''
    for i in prange(q.shape[0]):
        s, vx, vy, vz = ray(cam, q[i, 0], q[i, 1])
        origin[i, 0] = cam[_C] + s * cam[_O]
        origin[i, 1] = cam[_C + 1] + s * cam[_O + 1]
        origin[i, 2] = cam[_C + 2] + s * cam[_O + 2]
        v[i, 0] = vx
        v[i, 1] = vy
        v[i, 2] = vz


def unproject_grid(cam, q):
    r'''Unproject pixels by a packed model

SYNOPSIS

    origin, v = unproject_grid(pack_model(model), q)
    # q has shape (...,2); origin and v have shape (...,3); |v| = 1

model.unproject(q), compiled (ray() of every pixel, in parallel).

ARGUMENTS

- cam: the packed model (pack_model)
- q: pixels (...,2)

RETURNED VALUE

(origin, v): the rays' origins (C, or C + s O for CAHVORE) and unit
directions, (...,3) each; NaN outside the model's domain.
'''
    q = np.asarray(q, dtype=np.float64)
    flat = np.ascontiguousarray(q.reshape(-1, 2))
    origin = np.empty((flat.shape[0], 3))
    v = np.empty((flat.shape[0], 3))
    unproject_points(cam, flat, origin, v)
    return origin.reshape(q.shape[:-1] + (3,)), v.reshape(q.shape[:-1] + (3,))


@njit(parallel=True, cache=True, error_model="numpy")
def fill_ray_cache(cam, dirs, shift, noncentral):
    r"""ray_warm() for every grid point (with _ray_from_chi's quick cosine), each Newton
solve started from the quadratic prediction of the previous point of its row
(_warm_coefficients)

Rows are independent (each starts cold), so the rays do not depend on the
thread count."""
    central = cam[_KIND] == KIND_CAHV
    for gy in prange(dirs.shape[0]):
        y = gy - 1.0
        warm = (math.nan, 0.0, 0.0, 0.0)
        for gx in range(dirs.shape[1]):
            s, vx, vy, vz, u, chi = _ray_warm_chi(cam, gx - 1.0, y, warm, True)
            if not central:
                warm = _warm_coefficients(cam, u, chi)
            dirs[gy, gx, 0] = vx
            dirs[gy, gx, 1] = vy
            dirs[gy, gx, 2] = vz
            if noncentral:
                shift[gy, gx] = s


def build_ray_cache(cam, width, height, noncentral, out=None):
    r'''The centre rays of every pixel and of a one-pixel ring around the image

SYNOPSIS

    dirs, shift = build_ray_cache(cam, W, H, noncentral)
    # dirs has shape (H+2,W+2,3): dirs[iy+1,ix+1] is the ray of pixel (ix,iy), ix in -1..W
    # shift has shape (H+2,W+2) (noncentral) or (1,1) (central): origin = C + shift O
    dirs, shift = build_ray_cache(cam, W, H, noncentral, out=(dirs0, shift0))
    # the same rays, written over the arrays of an earlier cache of the same shapes

out (optional): (dirs, shift) float64 C-contiguous arrays of the shapes above
(either may be None: a new array), overwritten: the memory of a dropped cache
reused (a fresh 0.5 GB array costs 0.1-0.6 s CPU of page faults on first
touch). Every element is written, so the rays do not depend on what the
arrays held.

The rays are ray_warm()'s: exact to the floating-point level (Newton stopped
by the WARM_TOLERANCE bound; CAHVORE's cos(theta) from sin(theta), within
4e-16) with directions not normalised (|v| != 1 for
CAHV and CAHVOR). The renderer reads them only to intersect the board plane,
which needs no unit direction, and only to decide where to look closer (the
bounds of its adaptive tests, which allow 1e-12 (relative) of slack); a
pixel's value always comes from rays traced in the render.

24 bytes per pixel (32 noncentral): 0.5 GB (0.6 GB) for 5120x3840.
'''
    dshape = (height + 2, width + 2, 3)
    sshape = (height + 2, width + 2) if noncentral else (1, 1)
    dirs, shift = (None, None) if out is None else out
    for a, shape in ((dirs, dshape), (shift, sshape)):
        if a is not None and (a.shape != shape or a.dtype != np.float64
                              or not a.flags.c_contiguous):
            raise ValueError(f"build_ray_cache: out array {a.shape} {a.dtype}; "
                             f"expected C-contiguous float64 {shape}")
    if dirs is None:
        dirs = np.empty(dshape, dtype=np.float64)
    if shift is None:
        shift = np.zeros(sshape, dtype=np.float64)
    elif not noncentral:
        shift[...] = 0.0   # fill_ray_cache writes every element of a noncentral shift
    fill_ray_cache(cam, dirs, shift, noncentral)
    return dirs, shift



def compiled_entry_points():
    r'''The compiled kernels of this module that Python calls directly (numba dispatchers)

SYNOPSIS

    for kernel in compiled_entry_points():
        kernel.signatures     # what numba has compiled (or loaded from its cache)

For a warm-up or a cache check (harness.runner): the kernels numba compiles
when a projection, unprojection or ray cache is first asked for.
'''
    return (project_points, _residuals_kernel, unproject_points, fill_ray_cache)


def drop_stale_caches(dispatchers):
    r'''Forget numba's on-disk cache of kernels compiled before this file last changed

SYNOPSIS

    dropped = drop_stale_caches(renderers._raycast_kernels.compiled_entry_points())
    # ["render_kernel"] after an edit of reference_models/kernels.py, else []

numba checks a cached kernel against its own source file only, so a kernel of
another module that calls the functions here (and carries their compiled code)
is not recompiled when this file changes. This drops the cache index of each
of `dispatchers` older than this file, so that numba compiles them again on
their next call (and caches the new code). Call it in one process before
others load the kernels (as a warm-up does), not while other processes
compile them. A dispatcher without an on-disk cache is passed over.

RETURNED VALUE

The names of the kernels whose cache was dropped.
'''
    dropped = []
    for kernel in dispatchers:
        if stale_cache(kernel):
            kernel._cache.flush()
            dropped.append(kernel.__name__)
    return dropped


def stale_cache(kernel):
    r'''True when numba's on-disk cache index of a kernel that calls the functions here is
older than this file (drop_stale_caches' rule); False without an index or a cache'''
    path = getattr(getattr(getattr(kernel, "_cache", None), "_cache_file", None),
                   "_index_path", None)
    return bool(path) and os.path.exists(path) and \
        os.path.getmtime(path) < os.path.getmtime(__file__)

r'''The JPL camera models CAHV, CAHVOR and CAHVORE, exactly, in float64

SYNOPSIS

    from reference_models.cahvore import CAHVOR

    m = CAHVOR(C=..., A=..., H=..., V=..., O=..., R=..., width=1024, height=1024)

    q = m.project(p)            # p has shape (...,3); q has shape (...,2)
    origin, v = m.unproject(q)  # origin, v have shape (...,3); |v| = 1
    m.photogrammetric().theta_deg

A point p (in the model's world frame) maps to the pixel q = (x, y), in the
pixel convention of reference_models.conventions:

CAHV (Yakimovsky & Cunningham 1978), d = p - C:

    x = <d,H> / <d,A>        y = <d,V> / <d,A>

CAHVOR (Gennery): the ray bends at the pinhole about the optical axis O by a
polynomial in tau = tan^2 of its angle to O:

    omega = <d,O>;  lambda = d - omega O;  tau = |lambda|^2 / omega^2
    mu = R0 + R1 tau + R2 tau^2;  d' = d + mu lambda;  then CAHV on d'

CAHVORE (Gennery 2006): additionally the entrance pupil moves along O with the
ray's angle theta to O, by (theta/sin(theta) - 1)(E0 + E1 theta^2 + E2 theta^4);
the model is noncentral. The angle theta solves

    zeta sin(theta) - l cos(theta) = (theta - sin(theta)) (E0 + E1 theta^2 + E2 theta^4)

(zeta = <d,O>, l = |d - zeta O|), and with linearity L (type 1: L = 1,
perspective; type 2: L = 0, fisheye; type 3: L given)

    chi = tan(L theta)/L  (L > 0),  sin(L theta)/L  (L < 0),  theta  (L = 0)
    mu = R0 + R1 chi^2 + R2 chi^4;  d' = (l/chi) O + (1 + mu)(d - zeta O)

and CAHV on d'. With E = 0 and L = 1, CAHVORE is CAHVOR.

A and O are unit vectors: they are normalised on construction (files round
them to a few digits), and a vector whose norm is far from 1 is an error.
'''

import contextlib
import dataclasses
import math
import threading
from dataclasses import dataclass

import numpy as np

from .errors import ModelError
from .poseutils import cross3

# |A| and |O| in a model file are rounded; beyond this they are not unit vectors.
UNIT_TOLERANCE = 1e-3
NEWTON_MAX_ITERATIONS = 100
NEWTON_TOLERANCE = 1e-15

CAHVORE_TYPES = {1: "perspective", 2: "fisheye", 3: "general"}
# the JPL model families, each a truncation of the next
FAMILIES = ("CAHV", "CAHVOR", "CAHVORE")


def _norm3(v):
    r'''np.linalg.norm(v) of a float64 3-vector, bit for bit (numpy takes sqrt(v . v)), as a
float, without its dispatch: models are built by the thousand (the verdict's finite
differences, harness.verdict.Linearisation.model_jacobians)'''
    return math.sqrt(v.dot(v))


def _vec3(name, value):
    v = np.array(value, dtype=np.float64)
    if v.shape != (3,):
        raise ModelError(f"{name} must be a 3-vector; got shape {v.shape}")
    if not np.isfinite(v).all():
        raise ModelError(f"{name} = {v.tolist()} is not finite")
    return v


def _unit(name, value):
    v = _vec3(name, value)
    n = _norm3(v)
    if abs(n - 1.0) > UNIT_TOLERANCE:
        raise ModelError(f"{name} = {v.tolist()} must be a unit vector; its norm is {n:.9g}")
    # a vector normalised already stays bit-identical, so write -> read is exact
    if abs(n - 1.0) <= 4 * np.finfo(np.float64).eps:
        return v
    return v / n


# checked_once(): set in a thread while it builds the small steps of a model checked already
_STEPS = threading.local()


@contextlib.contextmanager
def checked_once():
    r'''Models built inside (this thread) skip the checks of their geometry: the focal
lengths against A (_check_linear) and O facing forward. Their fields are still converted,
normalised and frozen as always: the same model, bit for bit, when it passes the checks.

For the finite-difference steps of a model that passed them (harness.verdict's
Jacobians: steps of 1e-6 of each parameter's size): the checks are continuous in the
parameters and hold at the model with margins of order one (an angle of 1e-3 rad from
the limits, a focal length of 1e-6 |H|, O . A > 0), which such a step does not cross;
they cost as much as the function of the stepped model they feed.'''
    prev = getattr(_STEPS, "on", False)
    _STEPS.on = True
    try:
        yield
    finally:
        _STEPS.on = prev


def _freeze(obj, name, v):
    v.setflags(write=False)
    object.__setattr__(obj, name, v)


@dataclass(frozen=True)
class Photogrammetric:
    r'''The photogrammetric decomposition of the linear (CAHV) part of a model

Hc, Vc: image coordinates of the point where A pierces the image plane (px)
Hs, Vs: horizontal and vertical focal lengths (px)
Hp, Vp: unit horizontal and vertical image-plane axes H', V' (perpendicular to A)
theta:  the angle between H' and V' (radians; pi/2 for a perfect sensor)
'''

    Hc: float
    Vc: float
    Hs: float
    Vs: float
    Hp: np.ndarray
    Vp: np.ndarray

    @property
    def theta(self):
        return math.acos(max(-1.0, min(1.0, float(np.dot(self.Hp, self.Vp)))))

    @property
    def theta_deg(self):
        return math.degrees(self.theta)


@dataclass(frozen=True, eq=False)
class _Linear:
    C: np.ndarray
    A: np.ndarray
    H: np.ndarray
    V: np.ndarray
    width: int
    height: int

    family = None

    def __post_init__(self):
        _freeze(self, "C", _vec3("C", self.C))
        _freeze(self, "A", _unit("A", self.A))
        _freeze(self, "H", _vec3("H", self.H))
        _freeze(self, "V", _vec3("V", self.V))
        for name in ("width", "height"):
            n = getattr(self, name)
            if isinstance(n, bool) or not float(n).is_integer() or n <= 0:
                raise ModelError(f"image {name} must be a positive integer; got {n!r}")
            object.__setattr__(self, name, int(n))
        if not getattr(_STEPS, "on", False):
            self._check_linear()

    def _check_linear(self):
        ph = self.photogrammetric()
        for axis, s in (("H", ph.Hs), ("V", ph.Vs)):
            # A nearly parallel to H or V leaves no focal length
            if s < 1e-6 * np.linalg.norm(getattr(self, axis)) or s <= 0:
                raise ModelError(
                    f"A is parallel to {axis}: the focal length {axis}s = {s:.3g} px; "
                    f"expected {axis} to have a component perpendicular to A")
        if not (1e-3 < ph.theta < math.pi - 1e-3):
            raise ModelError(f"H' and V' are parallel (theta = {ph.theta_deg:.6g} deg)")

    # --- decomposition -------------------------------------------------------
    def photogrammetric(self):
        r'''Decompose H and V into Hc, Vc, Hs, Vs, H', V' (and theta)'''
        Hc = float(self.H @ self.A)
        Vc = float(self.V @ self.A)
        h = self.H - Hc * self.A
        v = self.V - Vc * self.A
        Hs = _norm3(h)
        Vs = _norm3(v)
        return Photogrammetric(Hc=Hc, Vc=Vc, Hs=Hs, Vs=Vs, Hp=h / Hs, Vp=v / Vs)

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)

    def with_photogrammetric(self, ph):
        r'''The same model with H and V composed from a Photogrammetric'''
        if not (ph.Hs > 0 and ph.Vs > 0):
            raise ModelError(f"negative focal length: Hs = {ph.Hs!r}, Vs = {ph.Vs!r}; "
                             "expected both > 0")
        return self.replace(H=ph.Hs * np.asarray(ph.Hp) + ph.Hc * self.A,
                            V=ph.Vs * np.asarray(ph.Vp) + ph.Vc * self.A)

    def with_theta_90(self):
        r'''The model with V' made perpendicular to H' (theta = 90 deg), as mrcal and
OpenGL represent it; Hc, Vc, Hs, Vs, H' and the handedness are kept

V' becomes A x H', or -(A x H') for a mirrored model: the nearest theta = 90
model, not an upside-down one.
'''
        ph = self.photogrammetric()
        Vp = cross3(self.A, ph.Hp)
        if self.mirrored:
            Vp = -Vp
        return self.with_photogrammetric(dataclasses.replace(ph, Vp=Vp))

    def to_cahv(self):
        return CAHV(C=self.C, A=self.A, H=self.H, V=self.V,
                    width=self.width, height=self.height)

    def Rt_ref_cam(self):
        r'''The camera frame of this model as mrcal defines it

SYNOPSIS

    Rt = model.Rt_ref_cam()   # shape (4,3): R (3,3) on top, t (3,) last
    p_ref = p_cam @ Rt[:3].T + Rt[3]

Origin C; axes x = H', y = A x H' (V' made perpendicular), z = A. Board poses
Rt_cam_board are given in this frame; with theta != 90 the model's own V'
differs from the frame's y axis, which changes nothing about projection.
'''
        ph = self.photogrammetric()
        R = np.stack((ph.Hp, cross3(self.A, ph.Hp), self.A), axis=1)
        return np.vstack((R, self.C))

    @property
    def mirrored(self):
        r'''True when H' x V' points against A: a left-handed (mirror-imaged) camera,
such as a telescope behind a fold mirror'''
        ph = self.photogrammetric()
        return bool(np.dot(cross3(ph.Hp, ph.Vp), self.A) < 0)

    @property
    def imagersize(self):
        return (self.width, self.height)

    @property
    def is_central(self):
        return True

    # --- geometry ------------------------------------------------------------
    def _pinhole(self, d):
        da = d @ self.A
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.stack((d @ self.H / da, d @ self.V / da), axis=-1)

    def _pinhole_ray(self, q):
        r'''Unit ray direction w (in the world frame) with CAHV(w) = q'''
        q = np.asarray(q, dtype=np.float64)
        x = q[..., 0:1]
        y = q[..., 1:2]
        w = np.cross(self.V - y * self.A, self.H - x * self.A)
        # pick the direction in front of the camera
        w *= np.sign(w @ self.A)[..., None]
        return w / np.linalg.norm(w, axis=-1, keepdims=True)

    def project(self, p):
        r'''Project points to pixels

SYNOPSIS

    q = model.project(p)
    # p has shape (...,3) in the model's frame; q has shape (...,2)

Points behind the camera or outside the model's domain give NaN.
'''
        d = np.asarray(p, dtype=np.float64) - self.C
        dd = self._distort(d)
        q = self._pinhole(dd)
        q[~((dd @ self.A) > 0)] = np.nan
        return q

    def unproject(self, q):
        r'''Unproject pixels to rays

SYNOPSIS

    origin, v = model.unproject(q)
    # q has shape (...,2); origin and v have shape (...,3); |v| = 1

The ray origin is C for central models and moves along O for CAHVORE.
'''
        w = self._pinhole_ray(q)
        return self._undistort(w)

    def _distort(self, d):
        return d

    def _undistort(self, w):
        return np.broadcast_to(self.C, w.shape).copy(), w

    def range(self, p):
        r'''Distance of points along A (metres), as JPL's cmod reports it'''
        return (np.asarray(p, dtype=np.float64) - self.C) @ self.A


@dataclass(frozen=True, eq=False)
class CAHV(_Linear):
    r'''The CAHV (pinhole) camera model: C (m), A (unit), H and V (px), image size'''

    family = "CAHV"

    def __repr__(self):
        return _repr(self)


def _solve_chi(u, r):
    r'''Solve chi (1 + R0 + R1 chi^2 + R2 chi^4) = u for chi >= 0, u >= 0'''
    r0, r1, r2 = r
    chi = u / (1.0 + r0)
    for _ in range(NEWTON_MAX_ITERATIONS):
        chi2 = chi * chi
        g = chi * (1.0 + r0 + chi2 * (r1 + r2 * chi2)) - u
        dg = 1.0 + r0 + chi2 * (3.0 * r1 + 5.0 * r2 * chi2)
        step = g / dg
        chi = chi - step
        if np.all(~(np.abs(step) > NEWTON_TOLERANCE * np.maximum(1.0, np.abs(chi)))):
            break
    return chi


@dataclass(frozen=True, eq=False)
class CAHVOR(_Linear):
    r'''CAHVOR: CAHV plus the optical axis O (unit) and radial terms R'''

    O: np.ndarray = None
    R: np.ndarray = None

    family = "CAHVOR"

    def __post_init__(self):
        if self.O is None or self.R is None:
            raise ModelError(f"{self.family} needs O and R")
        _freeze(self, "O", _unit("O", self.O))
        _freeze(self, "R", _vec3("R", self.R))
        super().__post_init__()
        if self.O @ self.A <= 0.0 and not getattr(_STEPS, "on", False):
            raise ModelError("O points away from A (expected the optical axis to face forward)")

    def __repr__(self):
        return _repr(self)

    def to_cahvor(self):
        return CAHVOR(C=self.C, A=self.A, H=self.H, V=self.V, O=self.O, R=self.R,
                      width=self.width, height=self.height)

    def _distort(self, d):
        omega = d @ self.O
        lam = d - omega[..., None] * self.O
        with np.errstate(divide="ignore", invalid="ignore"):
            tau = (lam * lam).sum(axis=-1) / (omega * omega)
        mu = self.R[0] + tau * (self.R[1] + tau * self.R[2])
        out = d + mu[..., None] * lam
        out[~(omega > 0)] = np.nan
        return out

    def _split(self, w):
        zeta = w @ self.O
        perp = w - zeta[..., None] * self.O
        lp = np.linalg.norm(perp, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            unit_perp = np.where(lp[..., None] > 0, perp / lp[..., None], 0.0)
        return zeta, lp, unit_perp

    def _undistort(self, w):
        zeta, lp, unit_perp = self._split(w)
        chi = _solve_chi(lp / zeta, self.R)
        v = self.O + chi[..., None] * unit_perp
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        return np.broadcast_to(self.C, w.shape).copy(), v


def _theta_step(theta, zeta, l, e0, e1, e2):
    r'''The Newton step of the CAHVORE angle equation zeta sin(t) - l cos(t) = (t - sin(t))
e(t), e = e0 + e1 t^2 + e2 t^4, at theta (arrays)'''
    s, c = np.sin(theta), np.cos(theta)
    t2 = theta * theta
    e = e0 + t2 * (e1 + t2 * e2)
    de = theta * (2.0 * e1 + 4.0 * e2 * t2)
    f = zeta * s - l * c - (theta - s) * e
    df = zeta * c + l * s - (1.0 - c) * e - (theta - s) * de
    return f / df


def solve_theta_each(zeta, l, E):
    r'''CAHVORE's angle for arrays (zeta, l) as reference_models.kernels._solve_theta gives it
point by point: Newton from atan2(l, zeta), each point stopped at its own first step below
NEWTON_TOLERANCE (CAHVORE._solve_theta stops them all together: the same to ~1e-16 rad)'''
    th = np.arctan2(l, zeta)
    act = np.ones(th.shape, dtype=bool)
    e0, e1, e2 = (float(v) for v in E)
    with np.errstate(all="ignore"):
        for _ in range(NEWTON_MAX_ITERATIONS):
            step = _theta_step(th[act], zeta[act], l[act], e0, e1, e2)
            th[act] = th[act] - step
            idx = np.flatnonzero(act)
            act[idx[~(np.abs(step) > NEWTON_TOLERANCE)]] = False
            if not act.any():
                break
    return th


@dataclass(frozen=True, eq=False)
class CAHVORE(CAHVOR):
    r'''CAHVORE: CAHVOR plus the entrance-pupil terms E, JPL type 1/2/3 and linearity'''

    E: np.ndarray = None
    model_type: int = 3
    linearity: float = None

    family = "CAHVORE"

    def __post_init__(self):
        if self.E is None:
            raise ModelError("CAHVORE needs E")
        _freeze(self, "E", _vec3("E", self.E))
        if self.model_type not in CAHVORE_TYPES:
            raise ModelError(f"CAHVORE type {self.model_type!r} is unknown; "
                             f"known types are 1 (perspective), 2 (fisheye), 3 (general)")
        implied = {1: 1.0, 2: 0.0}.get(self.model_type)
        if implied is not None:
            if self.linearity is not None and float(self.linearity) != implied:
                raise ModelError(f"CAHVORE type {self.model_type} has linearity {implied:g}; "
                                 f"got {self.linearity!r}")
            object.__setattr__(self, "linearity", implied)
        else:
            if self.linearity is None or not math.isfinite(float(self.linearity)):
                raise ModelError("CAHVORE type 3 needs a finite linearity")
            object.__setattr__(self, "linearity", float(self.linearity))
        super().__post_init__()

    def __repr__(self):
        return _repr(self)

    @property
    def is_central(self):
        return not np.any(self.E != 0.0)

    @property
    def mrcal_lensmodel(self):
        return f"LENSMODEL_CAHVORE_linearity={self.linearity!r}"

    def _chi_from_theta(self, theta):
        L = self.linearity
        if L > 1e-15:
            return np.tan(L * theta) / L
        if L < -1e-15:
            return np.sin(L * theta) / L
        return theta

    def _theta_from_chi(self, chi):
        L = self.linearity
        if L > 1e-15:
            return np.arctan(L * chi) / L
        if L < -1e-15:
            with np.errstate(invalid="ignore"):
                return np.arcsin(L * chi) / L
        return chi

    def _e_poly(self, theta):
        t2 = theta * theta
        return self.E[0] + t2 * (self.E[1] + t2 * self.E[2])

    def _solve_theta(self, zeta, l):
        e0, e1, e2 = self.E
        theta = np.arctan2(l, zeta)
        for _ in range(NEWTON_MAX_ITERATIONS):
            step = _theta_step(theta, zeta, l, e0, e1, e2)
            theta = theta - step
            if np.all(~(np.abs(step) > NEWTON_TOLERANCE)):
                break
        return theta

    def _distort(self, d):
        zeta = d @ self.O
        ll = d - zeta[..., None] * self.O
        l = np.linalg.norm(ll, axis=-1)
        theta = self._solve_theta(zeta, l)
        bad = theta * abs(self.linearity) > math.pi / 2
        small = theta <= 1e-8
        chi = self._chi_from_theta(theta)
        with np.errstate(divide="ignore", invalid="ignore"):
            zetap = np.where(small, zeta, l / chi)
        chi2 = chi * chi
        mu = np.where(small, 0.0, self.R[0] + chi2 * (self.R[1] + chi2 * self.R[2]))
        out = zetap[..., None] * self.O + (1.0 + mu)[..., None] * ll
        out[bad] = np.nan
        return out

    def _undistort(self, w):
        zeta, lp, unit_perp = self._split(w)
        chi = _solve_chi(lp / zeta, self.R)
        theta = self._theta_from_chi(chi)
        s = np.sin(theta)
        v = np.cos(theta)[..., None] * self.O + s[..., None] * unit_perp
        # pupil shift (theta/sin(theta) - 1) E(theta), by its series near the axis
        t2 = theta * theta
        with np.errstate(divide="ignore", invalid="ignore"):
            k = np.where(theta < 1e-4, t2 / 6.0 + 7.0 * t2 * t2 / 360.0, theta / s - 1.0)
        origin = self.C + (k * self._e_poly(theta))[..., None] * self.O
        return origin, v


def _repr(m):
    parts = [f"{f.name}={_fmt(getattr(m, f.name))}" for f in dataclasses.fields(m)]
    return f"{type(m).__name__}({', '.join(parts)})"


def _fmt(v):
    if isinstance(v, np.ndarray):
        return "[" + ", ".join(f"{x:.17g}" for x in v) + "]"
    return repr(v)


def family_of(model):
    return model.family


def truncate(model, family):
    r'''The model truncated as the paper did: CAHVORE -> CAHVOR drops E;
-> CAHV drops O and R. Asking for a richer family than the model has is an error.'''
    order = FAMILIES
    if family not in order:
        raise ModelError(f"unknown model family {family!r}; known: {', '.join(order)}")
    if order.index(family) > order.index(model.family):
        raise ModelError(f"cannot make a {family} from a {model.family}: it lacks "
                         f"{'O, R' if model.family == 'CAHV' else 'E'}")
    if family == "CAHV":
        return model.to_cahv()
    if family == "CAHVOR":
        return model.to_cahvor()
    return model


def with_R0(model, R0=0.0):
    r'''The exactly equivalent CAHVOR/CAHVORE model with radial term R0 set to `R0`

SYNOPSIS

    m0 = with_R0(m)            # projects every point as m does; m0.R[0] == 0

With k = (1 + R0_old)/(1 + R0) and T = k I - (k - 1) O O^T:
A' = T A / |T A|, H' = T H / |T A|, V' = T V / |T A|,
R' = (R0, R1 (1+R0)/(1+R0_old), R2 (1+R0)/(1+R0_old)); C, O, E unchanged.
'''
    if model.family not in ("CAHVOR", "CAHVORE"):
        return model
    k = (1.0 + model.R[0]) / (1.0 + R0)
    T = k * np.eye(3) - (k - 1.0) * np.outer(model.O, model.O)
    TA = T @ model.A
    n = np.linalg.norm(TA)
    s = (1.0 + R0) / (1.0 + model.R[0])
    return model.replace(A=TA / n, H=T @ model.H / n, V=T @ model.V / n,
                         R=np.array([R0, model.R[1] * s, model.R[2] * s]))

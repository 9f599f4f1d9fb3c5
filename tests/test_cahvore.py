'''The exact CAHV/CAHVOR/CAHVORE models, table-driven over all 33 catalogue models'''

import math

import mrcal
import numpy as np
import pytest

from reference_models.cahvore import CAHV, CAHVOR, CAHVORE, truncate
from reference_models.conventions import image_bounds, pixel_centres
from reference_models.errors import ModelError
from reference_models.mrcal_convert import to_mrcal

RANGES = (0.5, 2.0, 50.0)  # metres along each unprojected ray


def image_grid(m, nx=65, ny=49):
    r'''A grid over the whole image area, edges and corners included: (N,2)'''
    x0, x1, y0, y1 = image_bounds(m.width, m.height)
    xs = np.linspace(x0, x1, nx)
    ys = np.linspace(y0, y1, ny)
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


# --- round trip and mrcal ----------------------------------------------------

def test_project_unproject_round_trip(catalogue_entry):
    m = catalogue_entry.model
    q = image_grid(m)
    origin, v = m.unproject(q)
    assert np.all(np.isfinite(origin)) and np.all(np.isfinite(v))
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-15)
    for k in RANGES:
        q2 = m.project(origin + k * v)
        err = np.max(np.abs(q2 - q))
        assert err < 1e-9, f"range {k} m: max error {err:.3g} px"


def test_agrees_with_mrcal_on_theta_90_version(catalogue_entry):
    m = catalogue_entry.model.with_theta_90()
    assert abs(m.photogrammetric().theta_deg - 90.0) < 1e-12
    cm = to_mrcal(m)
    q = image_grid(m, 33, 25)
    origin, v = m.unproject(q)
    for k in RANGES:
        p = origin + k * v
        qm = mrcal.project(mrcal.transform_point_Rt(cm.Rt_cam_ref(), p), *cm.intrinsics())
        err = np.max(np.abs(qm - q))
        assert err < 1e-9, f"range {k} m: mrcal differs by {err:.3g} px"
        np.testing.assert_allclose(m.project(p), qm, rtol=0, atol=1e-9)


# --- theta != 90 against a direct scalar evaluation of the JPL formulas --------

def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _lin(a, x, b, y):
    return [a * x[i] + b * y[i] for i in range(3)]


def _cahvore_theta(zeta, l, E):
    r'''Solve zeta sin(t) - l cos(t) = (t - sin(t)) (E0 + E1 t^2 + E2 t^4) by bisection'''
    def f(t):
        return zeta * math.sin(t) - l * math.cos(t) - (t - math.sin(t)) * (
            E[0] + E[1] * t * t + E[2] * t ** 4)
    t0 = math.atan2(l, zeta)
    lo, hi = max(0.0, t0 - 0.3), min(math.pi, t0 + 0.3)
    assert f(lo) <= 0.0 <= f(hi), "no sign change around the CAHVOR angle"
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if f(mid) <= 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def direct_project(family, C, A, H, V, O=None, R=None, E=None, L=None, p=None):
    r'''One point through the JPL formulas as the cahvore.py docstring writes them'''
    d = [p[i] - C[i] for i in range(3)]
    if family == "CAHVOR":
        omega = _dot(d, O)
        lam = _lin(1.0, d, -omega, O)
        tau = _dot(lam, lam) / (omega * omega)
        mu = R[0] + R[1] * tau + R[2] * tau * tau
        d = _lin(1.0, d, mu, lam)
    elif family == "CAHVORE":
        zeta = _dot(d, O)
        lam = _lin(1.0, d, -zeta, O)
        l = math.sqrt(_dot(lam, lam))
        theta = _cahvore_theta(zeta, l, E)
        if L > 0:
            chi = math.tan(L * theta) / L
        elif L < 0:
            chi = math.sin(L * theta) / L
        else:
            chi = theta
        mu = R[0] + R[1] * chi ** 2 + R[2] * chi ** 4
        d = _lin(l / chi, O, 1.0 + mu, lam)
    da = _dot(d, A)
    return (_dot(d, H) / da, _dot(d, V) / da)


def _direct_args(m):
    kw = dict(family=m.family, C=m.C.tolist(), A=m.A.tolist(), H=m.H.tolist(),
              V=m.V.tolist())
    if m.family != "CAHV":
        kw.update(O=m.O.tolist(), R=m.R.tolist())
    if m.family == "CAHVORE":
        kw.update(E=m.E.tolist(), L=m.linearity)
    return kw


def test_theta_not_90_against_direct_formulas(catalogue_entry):
    m = catalogue_entry.model
    q = image_grid(m, 7, 6)
    origin, v = m.unproject(q)
    p = origin + 3.0 * v
    kw = _direct_args(m)
    q_direct = np.array([direct_project(**kw, p=pi.tolist()) for pi in p])
    np.testing.assert_allclose(m.project(p), q_direct, rtol=0, atol=1e-9)
    # the direct evaluation is sharp enough to tell theta from 90 deg
    dtheta = abs(m.photogrammetric().theta_deg - 90.0)
    if dtheta > 1e-3:
        q90 = m.with_theta_90().project(p)
        assert np.max(np.abs(q90 - q_direct)) > 1e-3


# --- unprojection ---------------------------------------------------------------

def test_cahvore_unprojection_is_noncentral_along_O(catalogue):
    noncentral = [e for e in catalogue if e.model.family == "CAHVORE" and not e.model.is_central]
    assert len(noncentral) >= 15
    for e in noncentral:
        m = e.model
        q = image_grid(m, 9, 7)
        origin, v = m.unproject(q)
        shift = origin - m.C
        # the entrance pupil moves along O only, and differently per pixel
        np.testing.assert_allclose(np.cross(shift, m.O), 0.0, atol=1e-15)
        assert np.ptp(shift @ m.O) > 1e-6
        # and the rays agree with the forward model: residual of the theta equation
        for k in (1.0, 10.0):
            np.testing.assert_allclose(m.project(origin + k * v), q, rtol=0, atol=1e-9)


def test_cahvore_with_zero_E_is_central(catalogue):
    m = catalogue.get(17).model
    assert m.family == "CAHVORE" and m.is_central
    origin, _ = m.unproject(image_grid(m, 5, 4))
    np.testing.assert_array_equal(origin, np.broadcast_to(m.C, origin.shape))


def test_cahvore_perspective_with_zero_E_is_cahvor(catalogue):
    m = catalogue.get(15).model
    e = CAHVORE(C=m.C, A=m.A, H=m.H, V=m.V, O=m.O, R=m.R, E=[0, 0, 0], model_type=1,
                width=m.width, height=m.height)
    assert e.linearity == 1.0
    q = image_grid(m, 9, 9)
    origin, v = m.unproject(q)
    p = origin + 2.0 * v
    np.testing.assert_allclose(e.project(p), m.project(p), rtol=0, atol=1e-9)


# --- decomposition -------------------------------------------------------------

def test_decompose_compose_identity(catalogue_entry):
    m = catalogue_entry.model
    m2 = m.with_photogrammetric(m.photogrammetric())
    for name in ("H", "V"):
        a, b = getattr(m, name), getattr(m2, name)
        assert np.linalg.norm(a - b) <= 1e-12 * np.linalg.norm(a), name
    ph, ph2 = m.photogrammetric(), m2.photogrammetric()
    for name in ("Hc", "Vc", "Hs", "Vs"):
        assert abs(getattr(ph, name) - getattr(ph2, name)) <= 1e-12 * abs(getattr(ph, name))
    assert abs(ph.theta - ph2.theta) < 1e-12


def test_decomposition_of_a_known_camera():
    # Hs, Vs, Hc, Vc and theta built in; the decomposition must give them back
    Hp = np.array([1.0, 0.0, 0.0])
    A = np.array([0.0, 0.0, 1.0])
    th = math.radians(89.9)
    Vp = np.array([math.cos(th), math.sin(th), 0.0])
    m = CAHV(C=[1, 2, 3], A=A, H=1200.0 * Hp + 511.5 * A, V=1210.0 * Vp + 383.5 * A,
             width=1024, height=768)
    ph = m.photogrammetric()
    assert (ph.Hs, ph.Vs, ph.Hc, ph.Vc) == pytest.approx((1200.0, 1210.0, 511.5, 383.5),
                                                         abs=1e-12)
    assert ph.theta_deg == pytest.approx(89.9, abs=1e-12)
    assert not m.mirrored
    # a point on the axis lands on (Hc, Vc)
    np.testing.assert_allclose(m.project(m.C + 5.0 * A), [511.5, 383.5], atol=1e-12)


def test_with_theta_90_keeps_the_rest(catalogue_entry):
    m = catalogue_entry.model
    m90 = m.with_theta_90()
    ph, ph90 = m.photogrammetric(), m90.photogrammetric()
    assert ph90.theta_deg == pytest.approx(90.0, abs=1e-12)
    for name in ("Hc", "Vc", "Hs", "Vs"):
        assert getattr(ph90, name) == pytest.approx(getattr(ph, name), rel=1e-14)
    np.testing.assert_allclose(ph90.Hp, ph.Hp, atol=1e-15)
    assert m90.mirrored == m.mirrored
    # V' turns by |theta - 90 deg| only
    turn = math.degrees(math.acos(min(1.0, float(ph.Vp @ ph90.Vp))))
    assert turn == pytest.approx(abs(ph.theta_deg - 90.0), abs=1e-6)


def test_supercam_is_mirrored(catalogue):
    m = catalogue.get("SuperCam").model
    assert m.family == "CAHV"
    assert m.mirrored
    assert m.photogrammetric().theta_deg == pytest.approx(75.288, abs=1e-3)


# --- truncation ----------------------------------------------------------------

def test_truncations(catalogue):
    m = catalogue.get(12).model
    assert m.family == "CAHVORE"
    r = truncate(m, "CAHVOR")
    assert type(r) is CAHVOR
    for name in ("C", "A", "H", "V", "O", "R"):
        np.testing.assert_array_equal(getattr(r, name), getattr(m, name))
    assert not hasattr(r, "E")
    c = truncate(m, "CAHV")
    assert type(c) is CAHV
    for name in ("C", "A", "H", "V"):
        np.testing.assert_array_equal(getattr(c, name), getattr(m, name))
    assert truncate(m, "CAHVORE") is m
    assert (c.width, c.height) == (m.width, m.height)
    # the truncated models differ from the full one away from the axis
    q = np.array([[5.0, 5.0]])
    o, v = m.unproject(q)
    assert np.max(np.abs(r.project(o + 2 * v) - q)) > 1.0
    with pytest.raises(ModelError, match="cannot make a CAHVORE from a CAHV"):
        truncate(c, "CAHVORE")
    with pytest.raises(ModelError, match="unknown model family"):
        truncate(m, "OPENCV")


# --- pixel convention ----------------------------------------------------------

def test_pixel_convention():
    q = pixel_centres(4, 3)
    assert q.shape == (3, 4, 2)
    assert tuple(q[0, 0]) == (0.0, 0.0)
    assert tuple(q[2, 3]) == (3.0, 2.0)  # q[iy, ix] = (ix, iy)
    assert image_bounds(4, 3) == (-0.5, 3.5, -0.5, 2.5)
    # mrcal agrees: a pinhole's principal point is pixel (cx, cy) exactly
    m = CAHV(C=[0, 0, 0], A=[0, 0, 1], H=[100, 0, 1.5], V=[0, 100, 1.0], width=4, height=3)
    cm = to_mrcal(m)
    p = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(mrcal.project(p, *cm.intrinsics()), [1.5, 1.0], atol=1e-15)
    np.testing.assert_allclose(m.project(p), [1.5, 1.0], atol=1e-15)

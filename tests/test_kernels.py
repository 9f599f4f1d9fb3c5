'''The compiled camera models of reference_models.kernels against model.project'''

import math
import zlib

import numpy as np
import pytest

from harness import least_squares as lsq
from harness.calibrators import _jpl_kernels as jk
from reference_models import kernels
from reference_models.cahvore import CAHVORE, truncate
from reference_models.catalogue import load_catalogue

# measured: 4.7e-11 px (test_max_difference_over_the_catalogue)
TOLERANCE_PX = 1e-9


def _models():
    cat = load_catalogue()
    out = []
    for e in list(cat.slots()) + list(cat.extras()):
        for fam in ("CAHV", "CAHVOR", "CAHVORE"):
            if ("CAHV", "CAHVOR", "CAHVORE").index(fam) <= \
                    ("CAHV", "CAHVOR", "CAHVORE").index(e.model.family):
                out.append((f"{e.key}-{fam}", truncate(e.model, fam)))
    return out


MODELS = _models()


def _variants(m):
    r'''The CAHVORE m under other linearities (fisheye, general > 0 and < 0)'''
    kw = dict(C=m.C, A=m.A, H=m.H, V=m.V, O=m.O, R=m.R, E=m.E, width=m.width, height=m.height)
    return [CAHVORE(model_type=2, **kw), CAHVORE(model_type=3, linearity=0.5, **kw),
            CAHVORE(model_type=3, linearity=-0.4, **kw)]


def _points(m, rng, n=4000):
    r'''World points of every kind: in and beyond the image, wide angles, behind, on axes'''
    ph = m.photogrammetric()
    Rt = m.Rt_ref_cam()
    # directions in the camera frame up to 170 deg off the axis, all azimuths
    ang = np.radians(rng.uniform(0.0, 170.0, n))
    az = rng.uniform(0.0, 2 * math.pi, n)
    v = np.stack((np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)), axis=-1)
    rng_m = 10.0 ** rng.uniform(-2.0, 3.0, n)
    p = (v * rng_m[:, None]) @ Rt[:3].T + Rt[3]
    # the rays of pixels over and beyond the image (the domain edge of wide cameras)
    x = rng.uniform(-0.5 * m.width, 1.5 * m.width, n)
    y = rng.uniform(-0.5 * m.height, 1.5 * m.height, n)
    with np.errstate(all="ignore"):
        origin, w = m.unproject(np.stack((x, y), axis=-1))
    ok = np.all(np.isfinite(w), axis=-1)
    p_img = origin[ok] + w[ok] * 10.0 ** rng.uniform(-1.0, 2.0, ok.sum())[:, None]
    # (not points in the plane through C perpendicular to A: there <d,A> is rounding
    # noise, and its sign decides whether a pixel is valid)
    special = [m.C, m.C + m.A, m.C - m.A, m.C + 1e-12 * m.A, m.C + ph.Hp + 1e-3 * m.A,
               m.C + 5.0 * getattr(m, "O", m.A), m.C - getattr(m, "O", m.A)]
    return np.concatenate((p, p_img, np.array(special)))


def _well_posed(m, p):
    r'''False where a CAHVORE projection is decided by rounding

Where the theta Newton iteration does not settle within 30 steps (far outside
the domain: no root, or several) it is chaotic: the reference's theta depends on
rounding and on the other points of the batch (it iterates until all have
converged), so no implementation can match it. Points more than 120 deg off O
(theta near pi: l/chi is ill-conditioned, 1e-4 px apart for a fisheye) and
points within 1e-9 of the domain edge theta |L| = pi/2 are left out too.
'''
    if m.family != "CAHVORE":
        return np.ones(len(p), dtype=bool)
    d = p - m.C
    zeta = d @ m.O
    l = np.linalg.norm(d - zeta[:, None] * m.O, axis=-1)
    e0, e1, e2 = m.E
    theta = np.arctan2(l, zeta)
    last_big = np.full(len(p), -1)
    with np.errstate(all="ignore"):
        for k in range(100):
            s, c = np.sin(theta), np.cos(theta)
            t2 = theta * theta
            e = e0 + t2 * (e1 + t2 * e2)
            de = theta * (2.0 * e1 + 4.0 * e2 * t2)
            step = (zeta * s - l * c - (theta - s) * e) / (
                zeta * c + l * s - (1.0 - c) * e - (theta - s) * de)
            theta = theta - step
            last_big[np.abs(step) > 1e-15] = k
    return (last_big < 30) & (np.arctan2(l, zeta) <= np.radians(120.0)) & \
        ~(np.abs(theta * abs(m.linearity) - math.pi / 2) < 1e-9)


def _compare(m, p):
    p = p[_well_posed(m, p)]
    with np.errstate(all="ignore"):
        q_ref = m.project(p)
    q = kernels.project(m, p)
    assert q.shape == q_ref.shape
    # the same invalid points, NaN in both coordinates
    np.testing.assert_array_equal(np.isnan(q), np.isnan(q_ref))
    assert np.all(np.isnan(q[:, 0]) == np.isnan(q[:, 1]))
    ok = np.isfinite(q_ref[:, 0])
    # pixels far out (points near the plane through C perpendicular to A, or behind
    # it for a fisheye) agree relatively
    near = ok & (np.abs(q_ref[:, 0] - 0.5 * m.width) < 1.5 * m.width) & \
        (np.abs(q_ref[:, 1] - 0.5 * m.height) < 1.5 * m.height)
    assert near.sum() > 100
    far = ok & ~near
    np.testing.assert_allclose(q[far], q_ref[far], rtol=1e-9, atol=0)
    return float(np.abs(q[near] - q_ref[near]).max())


@pytest.mark.parametrize("key,model", MODELS, ids=[k for k, _ in MODELS])
def test_projection_matches_the_reference(key, model):
    rng = np.random.default_rng(zlib.crc32(key.encode()))
    models = [model] + (_variants(model) if model.family == "CAHVORE" else [])
    for m in models:
        d = _compare(m, _points(m, rng))
        assert d <= TOLERANCE_PX, (m.family, getattr(m, "linearity", None), d)


def test_max_difference_over_the_catalogue():
    rng = np.random.default_rng(1)
    worst = 0.0
    n_invalid = 0
    for _, model in MODELS:
        for m in [model] + (_variants(model) if model.family == "CAHVORE" else []):
            p = _points(m, rng, n=1000)
            worst = max(worst, _compare(m, p))
            n_invalid += int(np.isnan(kernels.project(m, p)[:, 0]).sum())
    print(f"max |q - q_ref| over the catalogue: {worst:.3g} px; {n_invalid} invalid points")
    assert worst <= TOLERANCE_PX
    assert n_invalid > 0   # the points reached beyond every domain


def test_invalid_points_are_nan():
    m = next(m for k, m in MODELS if m.family == "CAHVORE")
    behind = m.C - 3.0 * m.A
    q = kernels.project(m, np.array([behind, m.C + 2.0 * m.A]))
    assert np.all(np.isnan(q[0]))
    assert np.all(np.isfinite(q[1]))
    np.testing.assert_allclose(q[1], m.project(m.C + 2.0 * m.A), rtol=0, atol=1e-9)


def test_cahv_is_the_pinhole():
    m = next(m for k, m in MODELS if m.family == "CAHV")
    p = m.C + np.array([[0.3, -0.2, 4.0], [1.0, 2.0, 3.0]]) @ m.Rt_ref_cam()[:3].T
    d = p - m.C
    expected = np.stack((d @ m.H / (d @ m.A), d @ m.V / (d @ m.A)), axis=-1)
    np.testing.assert_allclose(kernels.project(m, p), expected, rtol=0, atol=1e-10)


def test_bad_input_is_refused():
    m = MODELS[0][1]
    with pytest.raises(ValueError, match="shape"):
        kernels.project(m, np.zeros((4, 2)))


def test_any_leading_shape_and_the_compiled_model():
    m = next(m for k, m in MODELS if m.family == "CAHVORE")
    p = m.C + 3.0 * m.A + np.random.default_rng(2).uniform(-1, 1, (4, 5, 3))
    q = kernels.project(m, p)
    assert q.shape == (4, 5, 2)
    np.testing.assert_allclose(q, m.project(p), rtol=0, atol=1e-9)
    mc = kernels.CompiledProjection(m)
    assert mc.family == "CAHVORE"
    np.testing.assert_array_equal(mc.Rt_ref_cam(), m.Rt_ref_cam())
    np.testing.assert_array_equal(mc.project(p), q)


@pytest.mark.parametrize("family", ["CAHV", "CAHVOR", "CAHVORE"])
def test_jpl_chart_packs_exactly_what_its_model_packs(family):
    from harness.calibrators import jpl_fit
    from reference_models.errors import ModelError
    m = next(m for k, m in MODELS if m.family == family)
    chart = jpl_fit._Chart(family, m, getattr(m, "model_type", None),
                           getattr(m, "linearity", None), R0=0.0)
    rng = np.random.default_rng(3)
    x0 = chart.x0()
    for _ in range(50):
        x = x0 + rng.normal(0.0, 1e-3, x0.shape) * np.maximum(1.0, np.abs(x0))
        # A and O may be an ulp off the model's (their norm is summed in another order)
        np.testing.assert_allclose(chart.packed(x), kernels.pack_model(chart.model(x)),
                                   rtol=1e-13, atol=1e-13)  # a few ulps of sums in another order
    # a trial outside the model's limits (V along H: theta = 0) is refused as model() is
    x = x0.copy()
    x[8:11] = x[5:8]
    with pytest.raises(ModelError):
        chart.model(x)
    assert chart.packed(x) is None
    x[0] = np.nan
    assert chart.packed(x) is None


def test_residuals_replace_unprojectable_points():
    m = next(m for k, m in MODELS if m.family == "CAHVORE")
    p = np.array([m.C + 2.0 * m.A, m.C - 3.0 * m.A, m.C + 4.0 * m.A + 0.1 * m.O])
    q = np.array([[1.0, 2.0], [3.0, 4.0], [np.inf, 5.0]])
    r = kernels.residuals_packed(kernels.pack_model(m), p, q, 1e4)
    expected = (m.project(p) - q).ravel()
    np.testing.assert_allclose(r[[0, 1, 5]], expected[[0, 1, 5]], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(r[[2, 3, 4]], [1e4, 1e4, 1e4])


@pytest.mark.parametrize("family", ["CAHV", "CAHVOR", "CAHVORE"])
def test_jacobian_chart_is_the_forward_difference_bit_for_bit(family):
    from harness.calibrators import jpl_fit
    m = next(m for k, m in MODELS if m.family == family)
    chart = jpl_fit._Chart(family, m, getattr(m, "model_type", None),
                           getattr(m, "linearity", None), R0=0.0)
    p = np.ascontiguousarray(_points(m, np.random.default_rng(5), n=200))
    with np.errstate(all="ignore"):
        p = p[np.isfinite(m.project(p)).all(axis=-1)]
    q = np.ascontiguousarray(m.project(p) + 0.01)

    def residuals(x):
        cam = chart.packed(x)
        return np.full(2 * len(p), 1e4) if cam is None else kernels.residuals_packed(cam, p, q, 1e4)
    x = chart.x0() + 1e-4
    expected = lsq.forward_difference(residuals, x, residuals(x))
    got = chart.forward_difference(residuals, x, residuals(x), p, q)
    assert got.shape == (2 * len(p), len(x)) and np.array_equal(got, expected)
    assert np.abs(expected).max() > 1.0
    # a column whose trial is at the model's limits goes through residuals()
    x[8:11] = x[5:8] + 1e-9
    J_T, ok = jk.jacobian_chart(x, jpl_fit.forward_steps(x), *chart._chart_args(), p, q,
                                1e4, residuals(x))
    assert not ok.all()
    assert np.array_equal(chart.forward_difference(residuals, x, residuals(x), p, q),
                          lsq.forward_difference(residuals, x, residuals(x)))

r'''Exact projected points and dot centroids'''

import math

import mrcal
import numpy as np
import pytest
from targets_render import pinhole

from reference_models.catalogue import load_catalogue
from targets.boards import TargetError, load_target, target_from_dict
from targets.centroids import (
    CENTROID_TOLERANCE_PX,
    board_to_ref,
    centroid_bias,
    expected_centroids,
    outline_centroid,
    polygon_centroid,
    projected_points,
)
from targets.poses import plan_poses


def _Rt(rx_deg, ry_deg, t):
    R = mrcal.R_from_r(np.radians([rx_deg, ry_deg, 0.0]))
    return np.vstack((R, t))


def test_polygon_centroid_known_shapes():
    sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float) + [1000.0, 3000.0]
    assert np.allclose(polygon_centroid(sq), [1001, 3001], atol=1e-12)
    # orientation does not matter
    assert np.allclose(polygon_centroid(sq[::-1]), [1001, 3001], atol=1e-12)
    tri = np.array([[0, 0], [3, 0], [0, 3]], float)
    assert np.allclose(polygon_centroid(tri), [1, 1])
    # broadcasting and degenerate input
    both = polygon_centroid(np.stack((sq, sq + 5)))
    assert both.shape == (2, 2) and np.allclose(both[1], [1006, 3006])
    assert np.all(np.isnan(polygon_centroid(np.zeros((4, 2)))))
    bad = sq.copy()
    bad[2, 0] = np.nan
    assert np.all(np.isnan(polygon_centroid(bad)))


def test_projected_points_match_mrcal_transforms():
    m = load_catalogue().get(15).model
    t = load_target("dots")
    Rt = _Rt(20, -10, [-0.45, -0.4, 2.0])
    Rt_ref_board = mrcal.compose_Rt(m.Rt_ref_cam(), Rt)
    q_ref = m.project(mrcal.transform_point_Rt(Rt_ref_board, t.points()))
    assert np.allclose(projected_points(m, t, Rt), q_ref, atol=1e-9, rtol=0)


def test_centroid_is_the_conic_centre_for_a_pinhole():
    # the image of a circle through a pinhole is an ellipse; its centre is exact algebra
    m = pinhole(640, 480, 500.0, cx=300.0, cy=250.0)
    r = 0.05
    t = target_from_dict({"kind": "dots", "nx": 1, "ny": 1, "spacing": 0.1,
                          "dot_diameter": 2 * r})
    Rt = _Rt(35, 25, [0.15, -0.1, 0.6])
    q = expected_centroids(m, t, Rt)[0]
    # homography board (x, y, 1) -> image, then the image conic of x^2 + y^2 = r^2
    K = np.array([[500.0, 0, 300.0], [0, 500.0, 250.0], [0, 0, 1]])
    Hb = K @ np.column_stack((Rt[:3, 0], Rt[:3, 1], Rt[3]))
    Hi = np.linalg.inv(Hb)
    C = Hi.T @ np.diag([1.0, 1.0, -r * r]) @ Hi
    centre = -np.linalg.solve(C[:2, :2], C[:2, 2])
    # the default's error bound (a 42 px dot seen 40 deg off-axis), and 1e-8 px at 1440 points
    assert np.allclose(q, centre, atol=CENTROID_TOLERANCE_PX, rtol=0)
    assert np.allclose(expected_centroids(m, t, Rt, Noutline=1440)[0], centre, atol=1e-8,
                       rtol=0)
    # ... and it is not the projection of the dot's centre
    assert np.linalg.norm(q - projected_points(m, t, Rt)[0]) > 0.05


def _polygon_reference(m, t, Rt, n=5760):
    # independent of outline_centroid: the inscribed polygon's centroid (error c/n^2)
    # Richardson-extrapolated with every other vertex (error c/n^4: ~1e-13 px at 5760)
    q = m.project(board_to_ref(m, Rt, t.dot_outlines(n)))
    c = polygon_centroid(q)
    return c + (c - polygon_centroid(q[..., ::2, :])) / 3.0


def test_centroid_converges_exponentially_with_outline_points():
    # the sampled outline's Green's-theorem centroid converges exponentially: on the fisheye
    # hazcam, at its poses and at half their distance (dots twice as large and more
    # distorted), 8 points err by 1e-8..1e-4 px and 16 are at the reference's own precision
    # (1e-13 px; 1e-10 leaves room for another machine's rounding of 1000 px coordinates)
    m = load_catalogue().get(8).model     # a CAHVORE fisheye hazcam
    t = load_target("dots")
    worst8 = 0.0
    for Rt in plan_poses(m, t)[:3]:
        for scale in (1.0, 0.5):
            Rt_near = np.vstack((Rt[:3], Rt[3] * scale))
            ref = _polygon_reference(m, t, Rt_near)
            ok = np.all(np.isfinite(ref), axis=-1)
            assert ok.sum() > 50
            err = {n: np.abs(expected_centroids(m, t, Rt_near, Noutline=n) - ref)[ok].max()
                   for n in (8, 16, 32)}
            assert err[16] < 1e-10 and err[32] < 1e-10
            worst8 = max(worst8, err[8])
    # ... where a polygon of 8 points would err by pixels: the convergence is the method's
    assert 1e-7 < worst8 < 1e-3


@pytest.mark.parametrize("tolerance", [CENTROID_TOLERANCE_PX, 1e-9])
def test_outline_points_follow_the_error_bound(tolerance):
    # the default picks its outline points from an error estimate: every dot within the
    # bound of a 5760-point outline (itself ~1e-13 px from the limit: error ~ 1/N^4),
    # on the fisheye hazcam and on that camera's poses moved to half their distance
    # (dots twice as large and more distorted: c/N^4 grows)
    m = load_catalogue().get(8).model     # a CAHVORE fisheye hazcam
    t = load_target("dots")
    for Rt in plan_poses(m, t)[:3]:
        for scale in (1.0, 0.5):
            Rt_near = np.vstack((Rt[:3], Rt[3] * scale))
            q = expected_centroids(m, t, Rt_near, tolerance=tolerance)
            q5760 = expected_centroids(m, t, Rt_near, Noutline=5760)
            ok = np.all(np.isfinite(q5760), axis=-1)
            assert ok.sum() > 50
            assert np.array_equal(np.isfinite(q[:, 0]), ok)
            assert np.abs(q[ok] - q5760[ok]).max() < tolerance


def test_symmetric_view_has_no_bias():
    m = pinhole(256, 256, 200.0)
    t = target_from_dict({"kind": "dots", "nx": 1, "ny": 1, "spacing": 0.1,
                          "dot_diameter": 0.05})
    Rt = _Rt(0, 0, [0.0, 0.0, 1.0])
    assert np.allclose(centroid_bias(m, t, Rt), 0, atol=1e-9)
    assert np.allclose(expected_centroids(m, t, Rt), [[127.5, 127.5]], atol=1e-9)


def test_navcam_bias_is_as_measured():
    # FINDINGS: centroid - projected centre 0.10 px mean, 0.31 px max (navcam-like CAHVOR,
    # 6 poses at 1.2-2.3 m tilted up to 45 deg). Our planner's poses for the MER navcam:
    m = load_catalogue().get(15).model
    t = load_target("dots")
    b = np.concatenate([np.linalg.norm(centroid_bias(m, t, Rt), axis=-1)
                        for Rt in plan_poses(m, t)])
    assert b.shape == (600,) and np.all(np.isfinite(b))
    assert 0.05 < b.mean() < 0.2
    assert 0.15 < b.max() < 0.6


def test_bad_input():
    m = pinhole(256, 256, 200.0)
    t = load_target("dots")
    behind = _Rt(0, 0, [-0.45, -0.45, -1.0])
    assert np.all(np.isnan(expected_centroids(m, t, behind)))
    assert np.all(np.isnan(projected_points(m, t, behind)))
    # a board crossing the camera plane: the dots behind are NaN, the others finite
    crossing = _Rt(0, 80, [-0.45, -0.45, 0.3])
    q = expected_centroids(m, t, crossing)
    assert np.isnan(q).any() and np.isfinite(q).any()
    with pytest.raises(TargetError, match="dot targets"):
        expected_centroids(m, load_target("chessboard"), behind)
    with pytest.raises(TargetError, match=r"\(4,3\)"):
        projected_points(m, t, np.eye(3))
    with pytest.raises(TargetError, match="rotation"):
        projected_points(m, t, np.vstack((2 * np.eye(3), [0, 0, 1])))
    assert math.isfinite(float(projected_points(m, t, _Rt(0, 0, [0, 0, 2]))[0, 0]))


def test_calibrator_bias_of_an_opencv_model():
    # harness.calibrators.bias takes every model's bias from expected_centroids (its default
    # error bound); for a distorting OpenCV model it agrees with a plain polygon of 11520
    # outline points (error ~1/N^2: ~1e-8 px there) to well below 1e-6 px
    from harness.calibrators.bias import centroid_bias as calibrator_bias
    from harness.calibrators.bias import dot_radii, outline_centroids
    from harness.calibrators.opencv_fit import OpenCVModel
    phi = np.arange(11520) * (2 * np.pi / 11520)
    ring = np.stack((np.cos(phi), np.sin(phi), np.zeros_like(phi)), axis=-1)
    K = np.array([[900.0, 0.0, 640.5], [0.0, 905.0, 480.25], [0.0, 0.0, 1.0]])
    m = OpenCVModel("OPENCV5", K, np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02]), 1280, 960)
    t = load_target("dots")
    p = np.asarray(t.points(), dtype=np.float64)
    for Rt in (_Rt(30, -20, [0.05, -0.1, 1.2]), _Rt(-10, 35, [-0.2, 0.1, 1.6])):
        b = calibrator_bias(m, t, Rt)
        q = m.project(Rt[3] + (p[:, None, :] + dot_radii(t, p)[:, None, None] * ring) @ Rt[:3].T)
        fine = polygon_centroid(q)
        assert np.abs(outline_centroids(m, p, dot_radii(t, p), Rt) - fine).max() < 1e-6
        ref = fine - m.project(Rt[3] + p @ Rt[:3].T)
        assert b.shape == (100, 2) and np.all(np.isfinite(b))
        assert 0.01 < np.abs(b).max() < 2.0
        assert np.abs(b - ref).max() < 1e-6


@pytest.mark.parametrize("n", [8, 16, 64])
def test_outline_centroid_of_an_ellipse_is_exact(n):
    r'''A rotated ellipse far from the origin, sampled at n equal steps of a parameter
that is not its angle (so the samples crowd on one side, as a projected circle's do):
its centroid is its centre, to rounding of 5000 px coordinates (1e-9 px) once the
series has converged, either way round; a non-finite sample or no area gives NaN'''
    t = np.arange(n) * (2 * np.pi / n)
    s = t + 0.3 * np.sin(t)            # a smooth reparametrisation (ds/dt > 0)
    a, b, th = 37.0, 11.0, 0.7
    centre = np.array([4321.25, 3017.5])
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    q = centre + np.stack((a * np.cos(s), b * np.sin(s)), axis=-1) @ R.T
    # the reparametrised samples carry every harmonic, decaying geometrically: 64 samples
    # reach rounding, 8 a hundredth of a pixel
    tol = 1e-9 if n >= 64 else 1e-2
    assert np.abs(outline_centroid(q) - centre).max() < tol
    assert np.abs(outline_centroid(q[::-1]) - centre).max() < tol
    qe = centre + np.stack((a * np.cos(t), b * np.sin(t)), axis=-1) @ R.T
    assert np.abs(outline_centroid(qe) - centre).max() < 1e-9    # first harmonics only
    both = outline_centroid(np.stack((qe, qe + 5)))
    assert np.abs(both - np.stack((centre, centre + 5))).max() < 1e-9
    bad = np.stack((qe, qe, np.full_like(qe, 7.0)))
    bad[0, 1, 0] = np.nan
    bad[1, 2, 1] = np.inf
    assert np.all(np.isnan(outline_centroid(bad)))
    with pytest.raises(TargetError):
        outline_centroid(qe[:2])


@pytest.mark.parametrize("n", [8, 9, 16, 33])
def test_fourier_derivative_is_exact_on_trigonometric_polynomials(n):
    # v @ D differentiates the samples' trigonometric interpolant: exact (to rounding of
    # sums of n terms of size ~n, 1e-12) on every harmonic below n/2, either parity of n
    from targets.centroids import _fourier_derivative
    t = np.arange(n) * (2 * np.pi / n)
    kmax = (n - 1) // 2
    v = np.stack([np.cos(k * t + 0.3 * k) for k in range(kmax + 1)]
                 + [np.sin(k * t) for k in range(1, kmax + 1)])
    dv = np.stack([-k * np.sin(k * t + 0.3 * k) for k in range(kmax + 1)]
                  + [k * np.cos(k * t) for k in range(1, kmax + 1)])
    assert np.abs(v @ _fourier_derivative(n) - dv).max() < 1e-12 * n

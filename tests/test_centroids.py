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
    centroid_bias,
    expected_centroids,
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


def test_centroid_converges_with_outline_points():
    m = load_catalogue().get(8).model     # a CAHVORE fisheye hazcam
    t = load_target("dots")
    Rt = plan_poses(m, t)[1]
    q360 = expected_centroids(m, t, Rt, Noutline=360)
    q1440 = expected_centroids(m, t, Rt, Noutline=1440)
    q5760 = expected_centroids(m, t, Rt, Noutline=5760)
    e1440 = np.abs(q1440 - q5760).max()
    e360 = np.abs(q360 - q5760).max()
    assert e1440 < 1e-8
    # fourth-order convergence after the Richardson step: 4x the points, ~256x smaller error
    assert e360 / e1440 > 100


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
    # harness.calibrators.bias takes every model's bias from expected_centroids (192 outline
    # points, Richardson-extrapolated); for a distorting OpenCV model it agrees with a plain
    # polygon of 11520 outline points (error ~1/N^2: ~1e-8 px there) to well below 1e-6 px
    from harness.calibrators.bias import centroid_bias as calibrator_bias
    from harness.calibrators.bias import dot_radii, outline_centroids
    from harness.calibrators.opencv_fit import OpenCVModel
    K = np.array([[900.0, 0.0, 640.5], [0.0, 905.0, 480.25], [0.0, 0.0, 1.0]])
    m = OpenCVModel("OPENCV5", K, np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02]), 1280, 960)
    t = load_target("dots")
    p = np.asarray(t.points(), dtype=np.float64)
    for Rt in (_Rt(30, -20, [0.05, -0.1, 1.2]), _Rt(-10, 35, [-0.2, 0.1, 1.6])):
        b = calibrator_bias(m, t, Rt)
        fine = outline_centroids(m, p, dot_radii(t, p), Rt, noutline=11520)
        ref = fine - m.project(Rt[3] + p @ Rt[:3].T)
        assert b.shape == (100, 2) and np.all(np.isfinite(b))
        assert 0.01 < np.abs(b).max() < 2.0
        assert np.abs(b - ref).max() < 1e-6


def _polygon_centroid_numpy(q):
    r'''The former polygon_centroid, all numpy: the reference of the compiled terms'''
    q0 = q[..., :1, :]
    d = q - q0
    x, y = d[..., 0], d[..., 1]
    xn, yn = np.roll(x, -1, axis=-1), np.roll(y, -1, axis=-1)
    cross = x * yn - xn * y
    area2 = cross.sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cx = ((x + xn) * cross).sum(axis=-1) / (3.0 * area2)
        cy = ((y + yn) * cross).sum(axis=-1) / (3.0 * area2)
    c = np.stack((cx, cy), axis=-1) + q0[..., 0, :]
    c[~(np.abs(area2) > 0) | ~np.all(np.isfinite(q), axis=(-1, -2))] = np.nan
    return c


@pytest.mark.parametrize("n", [8, 12, 20, 128, 192, 264, 1024])
def test_polygon_centroid_is_the_numpy_computation_bit_for_bit(n):
    r'''polygon_centroid (its terms compiled, targets._dot_kernels.polygon_terms; numpy's
sums) against the all-numpy computation, bit for bit, on every vertex, every other and
every fourth: the calibrators' bias takes these centroids and mrcal's fits are chaotic in
their last bits. Projected-circle-like polygons far from the origin, some with a
non-finite vertex or no area.'''
    rng = np.random.default_rng(n)
    t = np.arange(n) * (2 * np.pi / n)
    ndots = 40
    r = rng.uniform(0.5, 60, (ndots, 1))
    squeeze = rng.uniform(0.3, 1, (ndots, 1))
    q = np.stack((rng.uniform(0, 5000, (ndots, 1)) + r * np.cos(t) * squeeze
                  + rng.normal(0, 1e-3, (ndots, n)),
                  rng.uniform(0, 4000, (ndots, 1)) + r * np.sin(t)
                  + rng.normal(0, 1e-3, (ndots, n))), axis=-1)
    q[3, 5] = np.nan
    q[4, 2, 1] = np.inf
    q[5] = q[5, :1]                      # no area
    for step in (1, 2, 4):
        with np.errstate(invalid="ignore"):   # the inf vertex: inf - inf in the sums
            ref = _polygon_centroid_numpy(q[:, ::step])
        c = polygon_centroid(q[:, ::step])
        assert np.array_equal(c, ref, equal_nan=True)
        if n // step >= 3:   # (every 4th of 8 vertices: a segment, no area)
            assert np.isfinite(np.delete(c, [3, 4, 5], 0)).all()
    assert np.isnan(polygon_centroid(q[[3, 4, 5]])).all()
    assert np.array_equal(polygon_centroid(q[7]), _polygon_centroid_numpy(q[7]))

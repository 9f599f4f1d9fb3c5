r'''The joint renderer test (harness.verdict.joint_statistic) of jpl fits whose unit vectors
lie along a world axis, and of CAHVORE fits, under the noise model's own noise

No rendering: the "images" are the exact dot centroids plus seeded isotropic Gaussian
noise, the noise model exactly, so the joint chi2 must be chi-square with its dof.
'''

import math

import numpy as np
import pytest
from scipy import stats

from harness import stages, verdict
from reference_models.poseutils import R_from_r


@pytest.fixture(autouse=True)
def _fresh_exact_fit_memo():
    verdict._EXACT_FITS.clear()
    yield
    verdict._EXACT_FITS.clear()


def _turned(m, R):
    r'''m with its world frame turned by R (p -> R p): the same camera, C, A, H, V, O turned'''
    kw = {k: R @ getattr(m, k) for k in ("C", "A", "H", "V", "O") if hasattr(m, k)}
    return m.replace(**kw)


def _looking_along(m, axis):
    r'''m turned so that its A is the world axis `axis` exactly (a unit vector)'''
    a = np.asarray(m.A, dtype=np.float64)
    r = np.cross(a, axis)
    ang = math.atan2(np.linalg.norm(r), a @ axis)
    R = R_from_r(r / np.linalg.norm(r) * ang)
    out = _turned(m, R)
    # the turn leaves A within an ulp or so of the axis: put it there, the case at stake
    return out.replace(A=np.asarray(axis, dtype=np.float64))


def test_unit_vector_moves_are_their_two_tangent_components():
    # a move of 1e-3 deg of a unit vector along a world axis: two components whose norm is
    # the move (the normal component, -|du|^2 / 2 = 1.5e-10 rad, is not reported)
    u0 = np.array([0.0, 0.0, 1.0])
    w = np.radians(1e-3) * np.array([0.6, 0.8, 0.0])
    u = R_from_r(w) @ u0
    c = verdict._unit_components(u0, u)
    assert len(c) == 2
    # |u - u0| = 2 sin(|w| / 2): equal to |w| to 1e-11 relative at this size
    assert math.hypot(*c) == pytest.approx(1e-3, rel=1e-9)


def _joint_draws(truth, family, seeds, sigma_px=0.002):
    r'''verdict.renderer.joint of jpl fits of the exact centroids of truth at 6 poses (pose
seed 0) plus Gaussian noise of sigma_px RMS per point, one per noise seed'''
    from targets.centroids import expected_centroids
    target = stages.cached_target("dots")
    poses = stages.poses_stage(truth, target, 6, 0)
    q = [expected_centroids(truth, target, Rt) for Rt in poses]
    obs = stages.observations_from(truth, target, poses, q)
    out = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        img = obs.replace(q=obs.q + rng.normal(0, sigma_px / math.sqrt(2), obs.q.shape))
        verdict._EXACT_FITS.clear()
        res = stages.calibrate_stage("jpl", img, target, family, truth, {})
        exact, noise, _ = verdict.exact_fit("jpl", family, {}, img, target, truth, {},
                                            start=res)
        params, proj, _ = stages.compare_stage(truth, res)
        v = verdict.assess(truth, res, exact, noise, params, proj, obs=img)
        out.append(v["renderer"]["joint"])
    return out


def test_a_camera_looking_along_a_world_axis_is_chi_square():
    r'''Hazcam 12 (CAHVORE, linearity 0.37, 1024 x 1024) turned to look down the world z
axis, 0.002 px of Gaussian noise: chi2 within the two-sided 1e-4 band of chi-square(18)
for each of 6 draws (dof: C 3, A 2, O 2, Hc, Vc, Hs, Vs, theta, roll, R1, R2, E 3; a false
failure has probability 6 x 2e-4). With A's world components, A_deg[2] (second order in
the move, its sigma the Jacobian's rounding) put the first of these draws at chi2 68.8,
mean chi2/dof 1.54 over 10 draws (1.03 with the tangent components); on camera 17 (A =
z) 1.7 over 40.'''
    _, truth = stages.camera_truth("12", "CAHVORE")
    truth = _looking_along(truth, np.array([0.0, 0.0, 1.0]))
    lo, hi = stats.chi2.isf(1 - 1e-4, 18), stats.chi2.isf(1e-4, 18)
    for j in _joint_draws(truth, "CAHVORE", seeds=range(6)):
        assert j["dof"] == 18
        assert lo < j["chi2"] < hi


def test_a_one_percent_change_of_E_is_seen_by_the_joint_test_alone():
    r'''Hazcam 12 CAHVORE, 0.002 px of Gaussian noise, the "images" drawn by the camera with
E x 1.01 (a renderer's CAHVORE pupil term 1% off: exact centroids moved by 0.0076 px at
most): no marginal z reaches 6 (E's sigmas are ~1-2% of E: a move along E is mostly
absorbed by R, C and the focal lengths), but E scaled moves the differences along a
direction whose sigma given the others is ~60x smaller (rendered camera 12: 9e-5 of E
against 0.006 for the best marginal), so the joint test flags it. Noise seeds 5, 6, 7:
marginal z at most 1.2 / 2.0 / 1.4, joint z 31 / 31 / 32 (without the fault 0.1 / 0.9 /
2.2).'''
    from targets.centroids import expected_centroids
    _, truth = stages.camera_truth("12", "CAHVORE")
    faulty = truth.replace(E=1.01 * truth.E)
    target = stages.cached_target("dots")
    poses = stages.poses_stage(truth, target, 6, 0)
    q = np.stack([expected_centroids(faulty, target, Rt) for Rt in poses])
    rng = np.random.default_rng(5)
    q = q + rng.normal(0, 0.002 / math.sqrt(2), q.shape)
    img = stages.observations_from(truth, target, poses, list(q))
    res = stages.calibrate_stage("jpl", img, target, "CAHVORE", truth, {})
    exact, noise, _ = verdict.exact_fit("jpl", "CAHVORE", {}, img, target, truth, {},
                                        start=res)
    params, proj, _ = stages.compare_stage(truth, res)
    r = verdict.assess(truth, res, exact, noise, params, proj, obs=img)["renderer"]
    assert max(r["z"].values()) < 6
    assert r["joint"]["dof"] == 18 and r["joint"]["z"] > 6

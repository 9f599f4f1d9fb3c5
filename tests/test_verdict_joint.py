r'''The joint test of the renderer differences (harness.verdict.joint_statistic) on
covariances constructed here: its chi2, dof and equivalent z'''

import math

import numpy as np
import pytest
from scipy import stats
from synthetic import centroid_observations

from harness.verdict import (
    DETECTION_RESOLUTION_PX,
    JOINT_RESOLUTION_Z,
    joint_direction,
    joint_fault_sigma,
    joint_limit,
    joint_resolution_cov,
    joint_statistic,
    joint_z,
)


def test_independent_quantities_sum_their_squared_z():
    s = np.array([1e-3, 2e-7, 5.0])
    d = np.array([2e-3, -2e-7, 15.0])
    j = joint_statistic(d, np.diag(s ** 2))
    # float64 arithmetic on numbers of order 1 after scaling: 1e-12 is rounding
    assert j["dof"] == 3 and j["n"] == 3
    assert j["chi2"] == pytest.approx(4 + 1 + 9, rel=1e-12)


def test_a_move_against_the_correlation_is_seen_by_its_conditional_sigma():
    # two quantities 99.9% correlated (R1 with the focal length): each alone at z 0.1,
    # their difference at (0.1 + 0.1) / sqrt(2 (1 - r)) = 4.5 sigma: chi2 = 2 x^2 / (1 - r)
    r, x = 0.999, 0.1
    S = np.array([[1.0, r], [r, 1.0]])
    j = joint_statistic(np.array([x, -x]), S)
    assert j["dof"] == 2
    assert j["chi2"] == pytest.approx(2 * x * x / (1 - r), rel=1e-9)
    # along the correlation the same marginal z-scores are nothing unusual
    assert joint_statistic(np.array([x, x]), S)["chi2"] == pytest.approx(
        2 * x * x / (1 + r), rel=1e-9)
    # a unit move of the first alone: sigma given the second is sqrt(1 - r^2)
    assert joint_fault_sigma(np.array([1.0, 0.0]), S) == pytest.approx(
        math.sqrt(1 - r * r), rel=1e-9)


def test_the_direction_carrying_chi2_is_named():
    # R1 and the focal length 99.9999% correlated, Hc alone: a difference against the
    # correlation (each at z 0.5) is a 707-sigma move along the weak direction, whose
    # eigenvalue is (1 - r) / (1 + r) of the strong one's; the direction is named by its
    # loadings, signed as the difference moved
    r = 0.999999
    S = np.sqrt(np.array([4.0, 1e-6, 1.0]))[:, None] * np.array(
        [[1.0, r, 0.0], [r, 1.0, 0.0], [0.0, 0.0, 1.0]]) * np.sqrt(np.array([4.0, 1e-6, 1.0]))
    d = np.array([0.5 * 2.0, -0.5 * 1e-3, 1.0])
    names = ["R1", "Hs", "Hc"]
    j = joint_statistic(d, S)
    top = joint_direction(names, d, S)
    # the weak direction: (0.5 + 0.5)^2 / (2 (1 - r)) of chi2 = 5e5 of 5e5 + 1
    assert top["chi2"] == pytest.approx(1.0 / (2 * (1 - r)), rel=1e-6)
    assert top["share"] == pytest.approx(top["chi2"] / j["chi2"], rel=1e-12)
    assert top["share"] > 0.99999
    assert top["relative_eigenvalue"] == pytest.approx((1 - r) / (1 + r), rel=1e-6)
    assert list(top["loading"])[:2] in (["R1", "Hs"], ["Hs", "R1"])
    assert top["loading"]["R1"] == pytest.approx(math.sqrt(0.5), rel=1e-6)
    assert top["loading"]["Hs"] == pytest.approx(-math.sqrt(0.5), rel=1e-6)
    assert abs(top["loading"]["Hc"]) < 1e-9
    assert joint_direction(names, np.zeros(3), S) is None


def test_units_and_exact_redundancies_drop_out():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(4, 4))
    S = A @ A.T
    d = rng.normal(size=4)
    ref = joint_statistic(d, S)
    # a quantity in other units (fractional vs absolute): the same statistic
    k = np.array([1.0, 1e-6, 1e3, 1.0])
    assert joint_statistic(d * k, S * np.outer(k, k))["chi2"] == pytest.approx(ref["chi2"],
                                                                               rel=1e-9)
    # a redundant copy (R1_frac = R1 / |R1|) and a held quantity (R0: zero variance, any
    # difference): neither adds a degree of freedom nor changes chi2
    T = np.vstack((np.eye(4), [0, 0, 2.5, 0]))
    S5 = T @ S @ T.T
    S6 = np.zeros((6, 6))
    S6[:5, :5] = S5
    d6 = np.concatenate((T @ d, [0.3]))
    j = joint_statistic(d6, S6)
    assert (j["dof"], j["n"]) == (4, 5)
    assert j["chi2"] == pytest.approx(ref["chi2"], rel=1e-7)


def test_clean_draws_are_chi_square_with_the_rank_as_dof():
    # 15 quantities from 12 parameters (a rank-12 covariance, as a jpl fit's quantities
    # from its chart): chi2 of N(0, S) draws is chi-square(12)
    rng = np.random.default_rng(7)
    G = rng.normal(size=(15, 12)) * np.logspace(-6, 2, 15)[:, None]
    C = np.diag(np.logspace(-4, 0, 12))
    S = G @ C @ G.T
    L = G @ np.sqrt(C)
    N = 4000
    chi2 = [joint_statistic(L @ rng.normal(size=12), S)["chi2"] for _ in range(N)]
    assert joint_statistic(np.zeros(15), S)["dof"] == 12
    # mean 12 with a standard error sqrt(2 x 12 / N) = 0.077: within 5 of them
    assert np.mean(chi2) == pytest.approx(12, abs=5 * math.sqrt(24 / N))
    # the 1% tail: 40 of 4000 expected, binomial sigma 6.3
    over = np.sum(np.array(chi2) > stats.chi2.isf(0.01, 12))
    assert abs(over - 40) < 5 * math.sqrt(N * 0.01 * 0.99)


def test_equivalent_z_matches_the_per_quantity_gate():
    # one degree of freedom: chi2 = z^2 exactly, and the limit at z = 6 is 36
    for z in (0.5, 3.0, 6.0, 9.0):
        assert joint_z(z * z, 1) == pytest.approx(z, rel=1e-9)
    assert joint_limit(6, 1) == pytest.approx(36.0, rel=1e-9)
    # the limit is where the equivalent z reaches 6, at any dof
    for k in (2, 14, 20):
        assert joint_z(joint_limit(6, k), k) == pytest.approx(6.0, rel=1e-9)
    # where scipy's log tail underflows (a gross fault) the asymptotic tail takes over:
    # at chi2 1000 both exist; the asymptotic form's relative error (a-1)/x = 1.2% in p
    # is 1.2e-2 / z^2 ~ 1e-5 in z
    a, x = 7.0, 500.0
    z_asym = -stats.norm.ppf(math.exp((a - 1) * math.log(x) - x - math.lgamma(a)) / 2)
    assert joint_z(1000.0, 14) == pytest.approx(z_asym, rel=1e-4)
    big = joint_z(1e6, 14)
    assert math.isfinite(big) and big == pytest.approx(1e3, rel=0.01)
    assert joint_z(None, 3) is None and joint_z(5.0, 0) is None


@pytest.fixture(scope="module")
def navcam():
    from harness import stages
    _, truth = stages.camera_truth("15", "CAHVOR")
    target = stages.cached_target("dots")
    poses = stages.poses_stage(truth, target, 6, 0)
    return truth, target, centroid_observations(truth, target, poses)


def _verdict(navcam, shift, seed):
    from harness import stages, verdict
    truth, target, obs = navcam
    rng = np.random.default_rng(seed)
    img = obs.replace(q=obs.q + rng.normal(0, 0.001 / np.sqrt(2), obs.q.shape)
                      + np.array([shift, 0.0]))
    verdict._EXACT_FITS.clear()
    exact, noise, _ = verdict.exact_fit("jpl", "CAHVOR", {}, img, target, truth, {})
    res = stages.calibrate_stage("jpl", img, target, "CAHVOR", truth, {})
    params, proj, _ = stages.compare_stage(truth, res)
    return verdict.assess(truth, res, exact, noise, params, proj, obs=img)["renderer"]


def test_joint_test_of_a_jpl_fit_under_seeded_noise_and_a_shift(navcam):
    r'''navcam 15, jpl CAHVOR, 6 poses, 0.001 px of isotropic Gaussian detection noise (the
noise model exactly): chi2 is of order its dof (15: C 3, A 2, O 2, Hc, Vc, Hs, Vs,
theta, the roll of H' about A, R1, R2). A shift of every detection by 0.003 px (a
renderer drawing the image 0.003 px to the right: Hc moves, A does not) is at marginal
z ~3 on Hc (sigma ~0.001 px), under the per-quantity limit; the noise moves Hc only
together with A (the rotation valley of a 45 deg lens), so the joint test sees the shift
alone by a sigma more than 10x smaller (41x on its rendered images: 1.4e-5 px against
5.6e-4) and flags it.'''
    from scipy import stats
    clean = [_verdict(navcam, 0.0, seed) for seed in (3, 4)]
    for r in clean:
        assert r["joint"]["dof"] == 15
        # two-sided 1e-4 band of chi-square(15)
        assert stats.chi2.isf(1 - 1e-4, 15) < r["joint"]["chi2"] < stats.chi2.isf(1e-4, 15)
        assert r["joint"]["fault_sigma"]["Hc"] < r["sigma"]["Hc"] / 10
    r = _verdict(navcam, 0.003, 3)
    assert r["z"]["Hc"] < 6
    assert r["joint"]["z"] > 6


def test_resolution_term_charges_a_move_by_its_rms_over_the_points_in_units_of_r():
    rng = np.random.default_rng(3)
    n_points, n = 300, 6
    J = rng.normal(size=(2 * n_points, n)) * np.logspace(-3, 3, n)   # badly scaled columns
    s_col = np.linalg.norm(J, axis=0)
    Js = J / s_col
    w, V = np.linalg.eigh(Js.T @ Js)
    F = joint_resolution_cov((V / w) @ V.T, s_col, n_points)
    dx = rng.normal(size=n) / s_col
    rms = math.sqrt(np.sum((J @ dx) ** 2) / n_points)       # RMS of |dq| over the points
    r = DETECTION_RESOLUTION_PX / JOINT_RESOLUTION_Z
    assert joint_statistic(dx, F)["chi2"] == pytest.approx((rms / r) ** 2, rel=1e-8)

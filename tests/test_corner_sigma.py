r'''Each corner's predicted error, exported from the detector (targets.tag_edges'
info["corner_sigma_px"] -> Detection.corner_sigma_px -> Observations.corner_sigma_px), and
the verdict's scatter that distributes each pose's measured noise over its corners by it'''

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from targets_render import pinhole

from targets.boards import load_target
from targets.detect import detect
from targets.poses import plan_poses


@pytest.fixture(scope="module")
def blurred_apriltag():
    # a constructed 1024x1024 pinhole with a little barrel, the board at its first planned
    # pose, blurred as the realistic profile's PSF (sigma 0.7 px)
    from renderers.base import RenderSettings, get_renderer
    t = load_target("apriltag")
    m = pinhole(1024, 1024, 800.0, R=[0.0, -0.08, 0.01])
    Rt = plan_poses(m, t, seed=0)[0]
    img = get_renderer("raycast").render(m, t.pattern(), Rt, RenderSettings(spp=16)).image
    img = gaussian_filter(np.asarray(img, dtype=np.float64), 0.7, mode="nearest")
    return t, m, Rt, img


def test_predicted_corner_error_matches_the_noise_scatter(blurred_apriltag):
    # under white noise (3% of the image's range per pixel) each detection carries each
    # corner's predicted error; over 8 noise draws the corners scatter as predicted. The
    # prediction takes the first pass's misfit as the noise, which holds the single edges'
    # model error too: a floor (here ~0.003 px; at 1% noise the measured scatter is 0.78 of
    # the predicted, at 4% 1.00; the pupil job's realistic draws, 120 of them: per corner
    # 0.99 median, 0.93-1.06 for 80% of them)
    t, m, Rt, img = blurred_apriltag
    rng = np.random.default_rng(3)
    noise = 0.03 * (img.max() - img.min())
    n = 8
    dets = [detect(img + noise * rng.standard_normal(img.shape), t, psf_sigma_px=0.7)
            for _ in range(n)]
    for d in dets:
        assert d.status == "ok"
        s = d.corner_sigma_px
        assert s.shape == (144,) and np.isfinite(s[d.found]).all()
        assert np.isnan(s[~d.found]).all()
    q = np.stack([d.q for d in dets])
    ok = np.isfinite(q).all(-1).all(0)
    assert ok.sum() > 130
    sd = np.sqrt(np.mean(np.sum((q - q.mean(0)) ** 2, -1), 0) * n / (n - 1))   # 2-d RMS
    pred = np.sqrt(np.mean(np.stack([d.corner_sigma_px for d in dets]) ** 2, 0))
    sd, pred = sd[ok], pred[ok]
    # the board's RMS within 15% (~1100 2-d samples: ~3% standard error; the floor above
    # ~5%)
    ratio = np.sqrt(np.mean(sd ** 2) / np.mean(pred ** 2))
    assert 0.85 < ratio < 1.15
    # the corners differ, and the prediction follows them (correlation of the variances:
    # the measured one has 8 draws' noise, ~50% per corner)
    assert np.corrcoef(sd ** 2, pred ** 2)[0, 1] > 0.5


def test_predicted_error_reaches_the_observations(blurred_apriltag):
    from harness.stages import observations_from
    t, m, Rt, img = blurred_apriltag
    det = detect(img, t, psf_sigma_px=0.7)
    import dataclasses
    sharp = dataclasses.replace(det, corner_sigma_px=None)
    obs = observations_from(m, t, [Rt, Rt], [det, sharp])
    s = obs.corner_sigma_px
    assert s.shape == (2, 144)
    assert np.array_equal(s[0], det.corner_sigma_px, equal_nan=True)
    assert np.isnan(s[1]).all()
    # a noise-free render's prediction is its fits' model error as noise: small, > 0
    assert np.all((s[0][det.found] > 0) & (s[0][det.found] < 0.01))
    # without any prediction (dots, chessboards): None
    assert observations_from(m, t, [Rt], [sharp]).corner_sigma_px is None


class _Obs:
    r'''What corner_shares and corner_correlation read of Observations'''

    def __init__(self, found, sigma, spans=None, q=None, p_board=None):
        self.found, self.corner_sigma_px, self.corner_spans = found, sigma, spans
        self.q, self.p_board, self.Nposes = q, p_board, found.shape[0]


def test_each_pose_s_noise_is_spread_over_its_corners_by_their_predicted_variance():
    from harness.verdict import corner_shares
    found = np.array([[True, True, True, False], [True, True, True, True]])
    sigma = np.array([[1.0, 2.0, np.nan, 5.0], [3.0, 3.0, 3.0, 3.0]])
    pose = np.nonzero(found)[0]
    s = corner_shares(_Obs(found, sigma), pose)
    # pose 0: variances 1 and 4 (mean 2.5), the third point without a prediction keeps 1
    assert s == pytest.approx([0.4, 1.6, 1.0, 1.0, 1.0, 1.0, 1.0], abs=1e-15)
    # a pose the fit left out (a posed fit's NaN board pose) is not among the rows
    s = corner_shares(_Obs(found, sigma), pose[pose == 1])
    assert s == pytest.approx([1.0] * 4, abs=1e-15)
    # no prediction at all: the scatter's rows as before
    assert corner_shares(_Obs(found, None), pose) is None


def test_gram_factor_of_correlated_rows_is_the_hand_computed_covariance():
    from harness.verdict import _gram_factor
    rng = np.random.default_rng(0)
    F = rng.normal(size=(6, 3))
    var = np.array([1.0, 1.0, 4.0, 4.0, 0.25, 0.25])
    C = np.eye(4)
    C[0, 2] = C[2, 0] = 0.6           # rows 0 and 2 (two corners' x) correlated
    C[1, 3] = C[3, 1] = -0.3
    R = _gram_factor(F, var, [(np.arange(4), C)])
    S = np.sqrt(var)
    D = np.diag(var)
    D[:4, :4] = S[:4, None] * C * S[None, :4]
    assert R.T @ R == pytest.approx(F.T @ D @ F, rel=1e-12, abs=1e-12)
    # without blocks: diag(var)
    R0 = _gram_factor(F, var)
    assert R0.T @ R0 == pytest.approx(F.T @ np.diag(var) @ F, rel=1e-12, abs=1e-12)


def test_line_correlation_of_least_squares_ends():
    from harness.verdict import line_correlation
    # one edge u in [0, 1], a straight line fitted over it: its two ends' estimates
    # phi(t) = 1/2 -+ 3t/2 (t = 2u - 1) have variance 2 and covariance -1 (per unit
    # information of t): correlation -1/2; a constant fitted: both ends the mean, 1
    ends = [(0.0, 1.0, -1.0, 1, 0.0, 1.0), (0.0, 1.0, 1.0, 1, 0.0, 1.0)]
    assert line_correlation(ends, [(0.0, 1.0)])[0, 1] == pytest.approx(-0.5, abs=1e-12)
    ends = [(0.0, 1.0, -1.0, 0, 0.0, 1.0), (0.0, 1.0, 1.0, 0, 0.0, 1.0)]
    assert line_correlation(ends, [(0.0, 1.0)])[0, 1] == pytest.approx(1.0, abs=1e-12)
    # two tags' edges [0, 1] and [1.3, 2.3], each end alone on its edge: nothing shared
    ends = [(0.0, 1.0, 1.0, 3, 0.0, 1.0), (1.3, 2.3, -1.0, 3, 1.3, 2.3)]
    R = line_correlation(ends, [(0.0, 1.0), (1.3, 2.3)])
    assert R == pytest.approx(np.eye(2), abs=1e-12)
    # both on the cubic over the two edges (the gap without pixels): the same estimate of
    # the line at two points 0.3 apart, strongly correlated; against dense sampling
    ends = [(0.0, 1.0, 1.0, 3, 0.0, 2.3), (1.3, 2.3, -1.0, 3, 0.0, 2.3)]
    r = line_correlation(ends, [(0.0, 1.0), (1.3, 2.3)])[0, 1]
    u = np.concatenate((np.linspace(0, 1, 20001), np.linspace(1.3, 2.3, 20001)))
    V = np.vander(u, 4, increasing=True)
    P = V @ np.linalg.inv(V.T @ V)
    a, b = P @ (1.0 ** np.arange(4)), P @ (1.3 ** np.arange(4))
    assert r == pytest.approx(a @ b / np.sqrt((a @ a) * (b @ b)), abs=1e-4)
    assert r > 0.5


def test_chessboard_and_dots_carry_no_prediction(blurred_apriltag):
    # the scatter of targets without a prediction takes the code path it took before
    # (corner_shares and corner_correlation None: the same numbers, bit for bit)
    from harness.stages import observations_from
    from harness.verdict import corner_correlation, corner_shares
    from renderers.base import RenderSettings, get_renderer
    _, m, _, _ = blurred_apriltag
    for name in ("chessboard", "dots"):
        t = load_target(name)
        Rt = plan_poses(m, t, seed=0)[0]
        img = get_renderer("raycast").render(m, t.pattern(), Rt, RenderSettings(spp=4)).image
        img = gaussian_filter(np.asarray(img, dtype=np.float64), 0.7, mode="nearest")
        det = detect(img, t)
        assert det.status == "ok"
        assert getattr(det, "corner_sigma_px", None) is None
        obs = observations_from(m, t, [Rt], [det])
        assert obs.corner_sigma_px is None
        pose = np.nonzero(obs.found)[0]
        assert corner_shares(obs, pose) is None and corner_correlation(obs, pose) is None


def test_mrcal_s_pose_subset_keeps_the_predictions_in_step():
    # mrcal leaves out a pose with too few points (harness.calibrators.mrcal_fit): its
    # subset of the observations takes the predictions' rows with the rest (a full-size
    # corner_sigma_px beside the subset's q would be refused by Observations)
    from test_mrcal_fit import MODELS, TARGET, exact_observations, synthetic_poses

    from harness.calibrators import calibrate
    truth = dict(MODELS)["15"]
    obs = exact_observations(truth, TARGET, synthetic_poses(truth, TARGET))
    q = obs.q.copy()
    q[2] = np.nan
    q[4, 3:] = np.nan
    sigma = np.where(np.isfinite(q[..., 0]), 0.002, np.nan)
    r = calibrate("mrcal", obs.replace(q=q, corner_sigma_px=sigma), TARGET, truth.family,
                  truth=truth, bias_correction=False)
    assert r.status == "ok", r.reason
    assert [(d["pose"], d["found"]) for d in r.info["poses_dropped"]] == [(2, 0), (4, 3)]

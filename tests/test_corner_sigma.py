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

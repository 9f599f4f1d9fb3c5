'''The jpl fit weighted by the detector's predicted corner errors (jpl_fit.point_weights)'''

import types
from pathlib import Path

import numpy as np
import pytest
from synthetic import default_target, exact_observations, synthetic_poses

from harness.calibrators import calibrate, jpl_fit
from harness.compare import projection_difference
from reference_models.catalogue import load_model_file

TARGET = default_target()
BARREL = Path(__file__).resolve().parents[1] / "campaigns" / "cameras" / "barrel-1024x768.cahvor"


def _with_sigma(obs, sigma):
    r'''obs with corner_sigma_px = sigma (Nposes,Npoints), NaN where no prediction'''
    if "corner_sigma_px" in getattr(obs, "__dataclass_fields__", {}):
        return obs.replace(corner_sigma_px=sigma)
    # before the Observations field exists: the attribute point_weights reads, on a copy
    obs = obs.replace(q=obs.q)
    object.__setattr__(obs, "corner_sigma_px", sigma)
    return obs


def _barrel_case(seed):
    r'''(truth, exact obs, predicted sigma, noisy obs): a constructed CAHVOR barrel (R1 -0.2),
6 poses of the 10x10 board; the 12% of points farthest from the image centre (the rim,
where the distortion is fitted) have a predicted error of 0.03 px, the others 0.002 px,
and each point's error is drawn with its predicted sigma (the RMS of the 2-d error)'''
    truth = load_model_file(BARREL)
    obs = exact_observations(truth, TARGET, synthetic_poses(truth, TARGET))
    found = obs.found
    c = np.array([truth.width, truth.height]) / 2.0
    r = np.linalg.norm(obs.q - c, axis=-1)
    rim = found & (r > np.quantile(r[found], 0.88))
    sigma = np.where(rim, 0.03, 0.002)
    sigma[~found] = np.nan
    rng = np.random.default_rng(seed)
    e = rng.normal(size=obs.q.shape) * (sigma / np.sqrt(2))[..., None]
    noisy = obs.replace(q=obs.q + np.nan_to_num(e))
    return truth, obs, sigma, noisy


def _projection_rms(truth, obs):
    r = calibrate("jpl", obs, TARGET, "CAHVOR", truth=truth, bias_correction=False)
    assert r.status == "ok", r.reason
    return projection_difference(truth, r.model, mode="rotation", step=32)["rms"], r


def test_weighting_by_the_predicted_error_recovers_the_truth_better():
    unweighted, weighted = [], []
    for seed in range(4):
        truth, _, sigma, noisy = _barrel_case(seed)
        d0, r0 = _projection_rms(truth, noisy)
        d1, r1 = _projection_rms(truth, _with_sigma(noisy, sigma))
        assert r0.info["weights"] is None
        w = r1.info["weights"]
        # relative weights, 1 / the floored prediction, RMS 1 over the found points
        f = noisy.found
        assert np.sqrt(np.mean(w[f] ** 2)) == pytest.approx(1.0, rel=1e-12)
        s = np.sqrt(sigma ** 2 + jpl_fit.WEIGHT_FLOOR_PX ** 2)
        np.testing.assert_allclose(w[f] * s[f], (w[f] * s[f])[0], rtol=1e-12)
        unweighted.append(d0)
        weighted.append(d1)
    u = float(np.sqrt(np.mean(np.square(unweighted))))
    v = float(np.sqrt(np.mean(np.square(weighted))))
    # measured: unweighted 0.048, weighted 0.013 px (pooled over the 4 draws; per draw 0.058
    # -> 0.005, 0.061 -> 0.0035, 0.024 -> 0.025, 0.041 -> 0.0038: the image's rim beyond the
    # points is extrapolated, so one draw may come out a little worse)
    assert v < 0.5 * u, (u, v)


def test_without_a_prediction_the_fit_is_the_unweighted_one_bit_for_bit():
    truth, _, sigma, noisy = _barrel_case(0)
    _, r0 = _projection_rms(truth, noisy)
    # no prediction anywhere: the same fit
    _, r1 = _projection_rms(truth, _with_sigma(noisy, np.full(sigma.shape, np.nan)))
    assert r1.info["weights"] is None
    for name in ("C", "A", "H", "V", "O", "R"):
        assert np.array_equal(getattr(r0.model, name), getattr(r1.model, name)), name
    assert jpl_fit.point_weights(noisy) is None


def test_a_noise_free_images_predictions_weigh_alike():
    # predictions ~0 (a noise-free image): floored, the weights are 1 to rounding and the fit
    # is the unweighted one to well below the renderer's resolution
    truth, exact, sigma, _ = _barrel_case(0)
    tiny = np.where(np.isfinite(sigma), 1e-9 * np.arange(sigma.size).reshape(sigma.shape),
                    np.nan)
    w = jpl_fit.point_weights(_with_sigma(exact, tiny))
    f = exact.found
    assert np.all(np.abs(w[f] - 1.0) < 1e-4)
    assert np.all(np.isnan(w[~f]))


def test_points_without_a_prediction_take_their_poses_median():
    found = np.ones((3, 4), dtype=bool)
    found[2, 3] = False
    s = np.array([[0.001, 0.002, 0.004, np.nan],
                  [np.nan, np.nan, np.nan, np.nan],
                  [0.003, np.nan, 0.005, np.nan]])
    w = jpl_fit.point_weights(types.SimpleNamespace(found=found, corner_sigma_px=s))
    sig = 1.0 / w
    floored = np.sqrt(s ** 2 + jpl_fit.WEIGHT_FLOOR_PX ** 2)
    k = sig[0, 0] / floored[0, 0]              # the common scale of the relative weights
    np.testing.assert_allclose(sig[0, :3] / k, floored[0, :3], rtol=1e-12)
    # pose 0's median for its point without a prediction
    assert sig[0, 3] / k == pytest.approx(floored[0, 1], rel=1e-12)
    # pose 1 has none: the median over every pose
    all_med = np.median(floored[np.isfinite(floored)])
    np.testing.assert_allclose(sig[1] / k, all_med, rtol=1e-12)
    assert sig[2, 1] / k == pytest.approx(np.median(floored[2, [0, 2]]), rel=1e-12)
    assert np.isnan(w[2, 3])
    assert np.sqrt(np.mean(w[found] ** 2)) == pytest.approx(1.0, rel=1e-12)


def test_a_warm_start_holds_its_weights():
    truth, _, sigma, noisy = _barrel_case(1)
    _, r1 = _projection_rms(truth, _with_sigma(noisy, sigma))
    # other observations without predictions (the verdict's exact fit): the start's weights
    w = jpl_fit.point_weights(noisy, r1)
    np.testing.assert_allclose(w, r1.info["weights"], rtol=1e-12)
    # an unweighted start stays unweighted, whatever the observations predict
    _, r0 = _projection_rms(truth, noisy)
    assert jpl_fit.point_weights(_with_sigma(noisy, sigma), r0) is None

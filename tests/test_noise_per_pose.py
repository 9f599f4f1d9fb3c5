r'''The verdict's noise per image: read from each image's residual degrees of freedom (the
fit's leverage over its rows), and from its detected - exact RMS where its residuals cannot
say it (an image whose points its own board pose absorbs: tiny-320x240 AprilTag seed 1, a
view of two corners read 2e-4 px where they erred by 0.0064, joint chi2 2598 on 15)'''

import math
from types import SimpleNamespace

import numpy as np
import pytest

from harness.verdict import DETECTION_RESOLUTION_PX, fit_leverage, noise_per_pose


def _fits(d):
    r'''An image fit and an exact fit whose residuals differ by d (Nposes,Npoints,2)'''
    return SimpleNamespace(residuals=d), SimpleNamespace(residuals=np.zeros_like(d))


def test_the_even_spread_is_the_old_scaling_sqrt_2N_over_2N_minus_n():
    rng = np.random.default_rng(1)
    d = rng.normal(0, 0.01, (3, 40, 2))
    d[2, 30:] = np.nan
    res, ex = _fits(d)
    n_params = 30
    out = noise_per_pose(res, ex, 3, n_params)
    N = 40 + 40 + 30
    scale = math.sqrt(2 * N / (2 * N - n_params))
    for i, n in enumerate((40, 40, 30)):
        own = math.sqrt(np.mean(np.sum(d[i, :n] ** 2, axis=-1)))
        assert out[i] == pytest.approx(scale * own, rel=1e-12)   # same arithmetic, same process


def test_an_image_its_fit_absorbed_takes_its_detected_minus_exact_rms():
    rng = np.random.default_rng(2)
    d = np.full((2, 30, 2), np.nan)
    d[0] = rng.normal(0, 0.004, (30, 2))
    d[1, :2] = 1e-5          # two corners, their residuals taken by their pose
    res, ex = _fits(d)
    # the hat matrix's trace over each image's rows: its pose's six and a share of the model
    absorbed = np.array([6.0 + 9.5, 3.9])
    out = noise_per_pose(res, ex, 2, 16, absorbed=absorbed, direct=[0.0057, 0.0064])
    # image 0 keeps 60 - 15.5 dof: its own reading
    assert out[0] == pytest.approx(math.sqrt(2 * np.sum(d[0] ** 2) / (60 - 15.5)), rel=1e-12)
    assert 0.0045 < out[0] < 0.0070           # the 0.004-per-axis noise, 2-d RMS 0.0057
    # image 1 keeps 4 - 3.9 = 0.1 dof: E[k / chi2_k] is unbounded there; the direct reading
    assert out[1] == 0.0064
    # without a direct reading it stays its own (the even spread's dof), never below the floor
    out = noise_per_pose(res, ex, 2, 16, absorbed=absorbed)
    assert out[1] == pytest.approx(max(math.sqrt(2 * np.sum(d[1, :2] ** 2) /
                                                  (4 - 16 * 2 / 32)), DETECTION_RESOLUTION_PX))
    assert out[1] < 1e-3


def test_the_leverage_of_each_image_sums_to_the_fitted_numbers():
    r'''The hat matrix's trace is its rank: the fitted numbers the residuals lost. An image's
own pose takes six of its rows' degrees of freedom, the shared model the rest by its share'''
    rng = np.random.default_rng(3)
    n_model, Nposes = 8, 3
    npts = [20, 20, 3]
    rows = []
    pose = np.repeat(np.arange(Nposes), npts)
    for i, n in enumerate(npts):
        block = np.zeros((2 * n, n_model + 6 * Nposes))
        block[:, :n_model] = rng.normal(size=(2 * n, n_model))
        block[:, n_model + 6 * i:n_model + 6 * i + 6] = rng.normal(size=(2 * n, 6))
        rows.append(block)
    J = np.vstack(rows)
    t = fit_leverage(J, pose, Nposes)
    assert t.sum() == pytest.approx(n_model + 6 * Nposes, rel=1e-9)
    # the three-point image: six rows, six of its own pose's numbers: all absorbed
    assert t[2] == pytest.approx(6.0, rel=1e-9)
    assert np.all(t[:2] > 6.0) and np.all(t[:2] < 6.0 + n_model)

'''The COLMAP calibrator: bundle adjustment with constant 3D target points; failures'''

import numpy as np
from synthetic import (
    catalogue_models,
    default_target,
    exact_observations,
    synthetic_poses,
)

from harness.calibrators import calibrate, opencv_fit
from harness.calibrators.colmap_fit import ColmapModel
from harness.compare import compare

TARGET = default_target()
MODELS = dict(catalogue_models())


def _obs(key, centroids=False):
    m = MODELS[key]
    return m, exact_observations(m, TARGET, synthetic_poses(m, TARGET), centroids=centroids)


def test_pixel_convention_is_converted():
    # COLMAP puts the top-left pixel's centre at (0.5, 0.5): the principal point maps to
    # (cx, cy) in ours
    m = ColmapModel("OPENCV", [1000.0, 1000.0, 512.5, 300.5, 0, 0, 0, 0], 1024, 768)
    assert (m.cx, m.cy) == (512.0, 300.0)
    np.testing.assert_allclose(m.project(np.array([0.0, 0.0, 2.0])), [512.0, 300.0],
                               atol=1e-12)


def test_opencv_model_agrees_with_opencv_calibrator():
    truth, obs = _obs("15")
    rc = calibrate("colmap", obs, TARGET, "OPENCV", bias_correction=False)
    assert rc.ok, rc.reason
    assert rc.model.family == "OPENCV"
    ro = calibrate("opencv", obs, TARGET, "OPENCV5", bias_correction=False)
    # both fit the same kind of polynomial to the same data: same centre within 0.05 px
    assert abs(rc.model.cx - ro.model.cx) < 0.05 and abs(rc.model.cy - ro.model.cy) < 0.05
    assert rc.residual_stats()["rms"] < 0.05
    s = compare(rc, truth)
    assert s["parameters"]["theta_deg"] is None and s["parameters"]["C_mm"] is None
    assert abs(s["parameters"]["Hs"]) < 0.01


def test_fisheye_with_bias_correction():
    truth, obs = _obs("8", centroids=True)
    r = calibrate("colmap", obs, TARGET, "OPENCV_FISHEYE")
    assert r.ok, r.reason
    assert r.info["bias_corrected"]
    # COLMAP's OPENCV_FISHEYE is OpenCV's fisheye model: the same fit
    ro = calibrate("opencv", obs, TARGET, "FISHEYE")
    np.testing.assert_allclose(r.model.params[4:], ro.model.dist, atol=1e-4)
    assert isinstance(ro.model, opencv_fit.OpenCVModel)


def test_full_opencv_runs():
    truth, obs = _obs("15")
    r = calibrate("colmap", obs, TARGET, "FULL_OPENCV", bias_correction=False)
    assert r.ok, r.reason
    assert len(r.model.params) == 12


def test_failures():
    truth, obs = _obs("15")
    q = np.full_like(obs.q, np.nan)
    q[0] = obs.q[0]
    r = calibrate("colmap", obs.replace(q=q), TARGET, "OPENCV")
    assert r.status == "failed" and r.reason.startswith("too few points")
    r = calibrate("colmap", obs, TARGET, "CAHVOR")
    assert r.status == "not-applicable"
    r = calibrate("colmap", obs, TARGET, "OPENCV", known_poses=True)
    assert r.status == "not-applicable"
    rng = np.random.default_rng(2)
    bad = obs.q + rng.normal(scale=40.0, size=obs.q.shape)
    r = calibrate("colmap", obs.replace(q=bad), TARGET, "OPENCV", bias_correction=False)
    assert r.status == "failed"
    assert r.reason.startswith(("diverged", "degenerate poses", "exception inside pycolmap"))


def test_parallel_boards_are_degenerate_poses():
    # boards translated in their own plane: the focal length trades against the range
    truth = dict(catalogue_models())["15"]
    Rts = [np.vstack((np.eye(3), [-0.45 + 0.05 * i, -0.45, 2.0])) for i in range(6)]
    obs = exact_observations(truth, TARGET, Rts)
    r = calibrate("colmap", obs, TARGET, "OPENCV", bias_correction=False)
    assert r.status == "failed"
    assert r.reason.startswith("degenerate poses: the board views leave the focal length")
    same = exact_observations(truth, TARGET, [synthetic_poses(truth, TARGET)[1]] * 6)
    r = calibrate("colmap", same, TARGET, "OPENCV", bias_correction=False)
    assert r.status == "failed" and r.reason.startswith("degenerate poses")


def test_opencv_on_a_pinhole_truth():
    truth = MODELS["15"].to_cahv()
    obs = exact_observations(truth, TARGET, synthetic_poses(truth, TARGET))
    r = calibrate("colmap", obs, TARGET, "OPENCV", bias_correction=False)
    assert r.ok, r.reason
    assert r.residual_stats()["rms"] < 0.05

'''harness.model_benchmark: each calibrator's floor under its own constraints (own_floor)

Cameras constructed here (not catalogue slots): a CAHV with theta = 90.05 deg, a CAHVOR
whose distortion axis O is tilted 3 deg from A, and the Rocky8 rear hazcam's fisheye
CAHVORE (640x480). The calibrator's choice is made on own_floor(): its own fit of exact
observations of whole-image poses, compared with the truth as the verdict compares a
record's exact-observation fit. These tests hold it against
  - the direct fit (what the model can do at all: a lower bound up to the weighting), and
  - the verdict's exact-observation fit on the campaign's pose set (slow).
'''

import dataclasses
import math

import numpy as np
import pytest

from harness import model_benchmark as mb
from reference_models.catalogue import load_catalogue

CAT = load_catalogue()
# exactness of a fit of exact data: far above rounding (1e-12 px), far below any misfit
EXACT = 1e-6


def with_theta(m, theta_deg):
    r'''m with V' turned about A so that the angle between H' and V' is theta_deg'''
    ph = m.photogrammetric()
    n = np.cross(m.A, ph.Hp)
    if m.mirrored:
        n = -n
    t = math.radians(theta_deg)
    return m.with_photogrammetric(dataclasses.replace(ph, Vp=math.cos(t) * ph.Hp
                                                      + math.sin(t) * n))


def tilted_O(m, deg):
    r'''m with O tilted deg from A towards H\''''
    ph = m.photogrammetric()
    O = math.cos(math.radians(deg)) * m.A + math.sin(math.radians(deg)) * ph.Hp
    return m.replace(O=O / np.linalg.norm(O))


@pytest.fixture(scope="module")
def skewed_cahv():
    return with_theta(CAT.get(15).model.to_cahv(), 90.05)


@pytest.fixture(scope="module")
def tilted_cahvor():
    return tilted_O(CAT.get(15).model.with_theta_90(), 3.0)


@pytest.fixture(scope="module")
def fisheye():
    return CAT.get(17).model


def _direct(truth, name):
    b = mb.benchmark(truth, candidates=[name], own_fits=())
    return b["rows"][0]


def test_skew_is_out_of_opencvs_reach_and_within_mrcals_cahvor(skewed_cahv):
    assert abs(skewed_cahv.photogrammetric().theta_deg - 90.05) < 1e-9
    # OpenCV's K has no skew: 0.05 deg of skew moves a pixel 500 px from the centre by
    # 500 * 0.05 deg in rad = 0.44 px, of which a fitted rotation and focal lengths take
    # part; the floor stays a sizeable fraction of it (0.22 px RMS measured)
    cv = mb.own_floor(skewed_cahv, "opencv", "OPENCV5")
    assert cv["status"] == "ok" and cv["rms"] > 0.05, cv
    # mrcal's LENSMODEL_CAHVOR holds a skewed pinhole exactly (R0 and O make a linear
    # shear), and its solver gets there
    mr = mb.own_floor(skewed_cahv, "mrcal", "CAHVOR")
    assert mr["status"] == "ok" and mr["max"] < EXACT, mr
    # jpl holds theta free
    jp = mb.own_floor(skewed_cahv, "jpl", "CAHV")
    assert jp["status"] == "ok" and jp["max"] < EXACT, jp
    # so best picks OpenCV's lowest floor with the reason, mrcal's CAHVOR and jpl's CAHV
    with_tmp_cache = mb.own_fit_choice(skewed_cahv, "mrcal")[0]
    assert with_tmp_cache["model"] == "CAHVOR", with_tmp_cache
    c = mb.own_fit_choice(skewed_cahv, "opencv")[0]
    assert c["why"].startswith("no opencv model within"), c


@pytest.mark.parametrize("camera, model, name", [
    ("skewed_cahv", "OPENCV5", "cv2 5 (OPENCV5)"),
    ("tilted_cahvor", "OPENCV5", "cv2 5 (OPENCV5)"),
    ("fisheye", "FISHEYE", "cv2 fisheye (FISHEYE, COLMAP OPENCV_FISHEYE)"),
])
def test_opencv_own_floor_against_the_direct_fit(request, camera, model, name):
    truth = request.getfixturevalue(camera)
    direct = _direct(truth, name)
    own = mb.own_floor(truth, "opencv", model)
    assert own["status"] == "ok", own
    # The same model and constraints (K without skew, the camera frame's rotation free):
    # the direct fit minimises the RMS over the whole image, so the calibrator's fit, which
    # weighs the image by where its boards are, cannot have a lower RMS there (1e-3:
    # the direct fit stops at STOP_GAIN of its cost) ...
    assert own["rms"] >= direct["rms"] * (1 - 1e-3), (own, direct)
    # ... and with boards in every corner and on every edge it is not far off: measured
    # 1.17x (skew), 1.75x (tilted O), 1.52x (fisheye); 2.5x would mean boards missing a
    # whole region of the image, which FLOOR_POSES's "corners" cover is meant to prevent
    assert own["rms"] < 2.5 * direct["rms"], (own, direct)


def test_tilted_o_cahvor_is_exact_for_jpl_and_mrcal(tilted_cahvor):
    for cal in ("jpl", "mrcal"):
        r = mb.own_floor(tilted_cahvor, cal, "CAHVOR")
        assert r["status"] == "ok" and r["max"] < EXACT, (cal, r)


def test_a_failing_own_fit_is_a_row_with_its_reason(monkeypatch, skewed_cahv):
    from harness import stages
    from harness.calibrators.base import CalibrationResult

    def failed(name, obs, target, model, truth, options):
        return CalibrationResult(calibrator=name, model_name=model, status="failed",
                                 reason="diverged: no convergence")
    monkeypatch.setattr(stages, "calibrate_stage", failed)
    choice, rows = mb.own_fit_choice(skewed_cahv, "opencv")
    assert rows and all(r["status"] == "failed" for r in rows)
    assert "no convergence" in rows[0]["reason"]
    assert choice["model"] is None and "could be fitted" in choice["why"]


def test_best_model_choices_are_kept_on_disk(monkeypatch, tmp_path, skewed_cahv):
    monkeypatch.setenv(mb.CACHE_ENV, str(tmp_path))
    monkeypatch.setattr(mb, "_MEMO", {})
    a = mb.best_model(skewed_cahv, "jpl")
    assert a[0] == "CAHV"
    assert mb.cached_choice(skewed_cahv, "CAHV", "jpl")
    files = list((tmp_path / "best-models").glob("*.json"))
    assert len(files) == 1

    def boom(*args, **kw):
        raise AssertionError("refitted although the choice is on disk")
    monkeypatch.setattr(mb, "_MEMO", {})
    monkeypatch.setattr(mb, "own_fit_choice", boom)
    assert mb.best_model(skewed_cahv, "jpl") == a
    # another camera is not that choice
    assert not mb.cached_choice(with_theta(skewed_cahv, 90.1), "CAHV", "jpl")


@pytest.mark.slow
@pytest.mark.parametrize("camera, cal, model", [
    ("skewed_cahv", "opencv", "OPENCV5"),
    ("skewed_cahv", "mrcal", "CAHVOR"),
    ("tilted_cahvor", "mrcal", "CAHVOR"),
    ("fisheye", "opencv", "FISHEYE"),
    ("fisheye", "mrcal", "CAHVORE"),
])
def test_own_floor_agrees_with_the_verdicts_exact_fit(request, camera, cal, model):
    r'''The choice's floor vs the floor the verdict gives a record: the calibrator's fit of
the exact dot centroids of the campaign's poses (30, cover "corners", bias correction on)'''
    from harness import stages, verdict
    from targets.centroids import expected_centroids
    truth = request.getfixturevalue(camera)
    target = stages.cached_target("dots")
    poses = stages.poses_stage(truth, target, 30, 0, "corners")
    obs = stages.observations_from(truth, target, poses,
                                   [expected_centroids(truth, target, Rt)
                                    for Rt in poses])
    exact, _, _ = verdict.exact_fit(cal, model, {}, obs, target, truth, {})
    assert exact.status == "ok", exact.reason
    v = verdict.floor_comparison(truth, exact)["projection"]
    own = mb.own_floor(truth, cal, model)
    if own["max"] < EXACT:
        # an exact model: the verdict's fit converges as far as its solver's stopping rule
        # and the centroid bias correction (1e-5 px tolerance) allow
        assert v["max"] < 1e-4, (own, v)
    else:
        # a misfit model: both fits are least squares of the same misfit over boards
        # covering the image; the pose sets differ (14 vs 30), so the weighting does
        within = 0.5 * own["rms"] < v["rms"] < 2.0 * own["rms"]
        assert within, (own, v)


def test_none_within_tolerance_picks_the_simplest_alike_to_the_lowest():
    def row(model, n, floor):
        return {"name": model, "nparams": n, "status": "ok", "max": floor,
                "calibrators": {"opencv": model}}
    # FISHEYE 0.255 and OPENCV5 0.250 are alike at 0.01 px; RATIONAL 0.247 too: the simplest
    rows = [row("FISHEYE", 8, 0.255), row("OPENCV5", 9, 0.250), row("RATIONAL", 12, 0.247)]
    c = mb._choose_rows(rows, "opencv", 0.01, "max")
    assert c["model"] == "FISHEYE" and "lowest max floor is 0.247 px (RATIONAL)" in c["why"]
    assert "simplest within 0.01 px of it: FISHEYE" in c["why"]
    # a gain larger than the tolerance is worth the parameters
    rows = [row("FISHEYE", 8, 0.30), row("OPENCV5", 9, 0.25), row("RATIONAL", 12, 0.10)]
    c = mb._choose_rows(rows, "opencv", 0.01, "max")
    assert c["model"] == "RATIONAL" and "simplest within" not in c["why"]

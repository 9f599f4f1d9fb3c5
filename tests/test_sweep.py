'''Stability sweeps: level configurations, forced poses and dot sizes, breakdown bookkeeping,
and noise, tilt and dot-size sweeps on the 640x480 Rocky8 hazcam'''

import json

import numpy as np
import pytest

from harness.studies.sweep import (
    DIFFICULTIES,
    LevelNotApplicable,
    SweepError,
    breakdowns,
    dot_diameters_px,
    horizontal_fov_deg,
    order_by_fov,
    plan_sweep_poses,
    response_for,
    run_sweep,
    scaled_dots,
)
from reference_models.cahvore import truncate
from reference_models.catalogue import load_catalogue
from renderers.response import ResponseChain
from targets.boards import load_target
from targets.poses import plan_poses, pose_summary


@pytest.fixture(scope="module")
def cam17():
    return truncate(load_catalogue().get(17).model, "CAHVOR")


def test_levels_are_valid_response_configurations():
    for d in ("noise", "blur", "motion"):
        for lv in DIFFICULTIES[d]["levels"]:
            chain = ResponseChain.from_config(response_for(d, lv))
            assert (len(chain.stages) == 0) == (lv == 0)
    assert response_for("noise", 50)["read_noise"] == {"sigma_e": 50.0}


def test_breakdown_is_the_first_broken_level():
    recs = [{"level": lv, "calibrator": "a", "model": "M", "status": "ok",
             "detection_rate": 1.0, "projection_rms_px": rms, "broken": rms > 0.05}
            for lv, rms in ((0, 0.01), (1, 0.02), (2, 0.09), (3, 0.04))]
    recs += [{"level": lv, "calibrator": "b", "model": "M", "status": "ok",
              "detection_rate": 1.0, "projection_rms_px": 0.01, "broken": False}
             for lv in range(4)]
    b = breakdowns(recs, [0, 1, 2, 3])
    assert b["a/M"]["level"] == 2 and "0.09 px" in b["a/M"]["reason"]
    assert b["b/M"] == {"level": None, "reason": None}


def test_unknown_difficulty_names_the_choices():
    with pytest.raises(SweepError,
                       match="known: noise, blur, motion, spp, poses, tilt, range, dots, fov"):
        run_sweep(17, difficulty="fog")
    with pytest.raises(SweepError, match="'chessboard' is 'chessboard'"):
        run_sweep(17, target="chessboard", difficulty="dots")


@pytest.mark.slow
def test_noise_sweep_degrades_monotonically_and_breaks(tmp_path):
    sw = run_sweep(17, "CAHVOR", "dots", "noise", levels=[0, 1000, 4000, 10000], spp=2,
                   n_poses=4, calibrators=(("jpl", "CAHVOR"),))
    recs = [r for r in sw["records"] if r["calibrator"] == "jpl"]
    assert [r["level"] for r in recs] == [0, 1000, 4000, 10000]
    ok = [r for r in recs if r["status"] == "ok"]
    assert len(ok) >= 3
    rms = np.array([r["projection_rms_px"] for r in ok])
    assert np.all(np.diff(rms) > 0), rms
    assert rms[0] < 0.03
    assert recs[-1]["detection_rate"] < 1.0 or recs[-1]["status"] != "ok"
    b = sw["breakdown"]["jpl/CAHVOR"]
    assert b["level"] in (4000, 10000)
    json.dumps(sw, allow_nan=False)


def test_tilt_and_range_poses_are_forced(cam17):
    target = load_target("dots")
    for tilt in (0.0, 60.0, 80.0):
        poses = plan_sweep_poses(cam17, target, 6, tilt_deg=tilt)
        s = [pose_summary(cam17, target, Rt, margin_px=0.0) for Rt in poses]
        assert all(x["in_view"] and x["in_front"] for x in s)
        np.testing.assert_allclose([x["tilt_deg"] for x in s], tilt, atol=1e-5)
    near = plan_sweep_poses(cam17, target, 6, range_factor=1.0)
    far = plan_sweep_poses(cam17, target, 6, range_factor=3.0)
    r_near = np.array([pose_summary(cam17, target, Rt)["range_m"] for Rt in near])
    r_far = np.array([pose_summary(cam17, target, Rt)["range_m"] for Rt in far])
    # the Rocky8 hazcam is noncentral (CAHVORE) only by millimetres
    np.testing.assert_allclose(r_far / r_near, 3.0, rtol=0.01)
    with pytest.raises(LevelNotApplicable, match="no placement of the board fits"):
        plan_sweep_poses(cam17, target, 1, range_factor=0.3)


def test_dot_size_in_pixels_scales_with_the_dots(cam17):
    target = load_target("dots")
    poses = plan_poses(cam17, target, n=4, seed=0)
    d0 = dot_diameters_px(cam17, target, poses)
    assert d0.shape == (4, 100)
    half = dot_diameters_px(cam17, scaled_dots(target, 0.5), poses)
    # perspective foreshortening of a smaller circle is the same shape: exactly half
    np.testing.assert_allclose(half / d0, 0.5, rtol=2e-3)
    assert 5 < np.median(d0) < 40
    with pytest.raises(LevelNotApplicable, match="orientation_mark dot_diameter"):
        scaled_dots(target, 1.5)       # 0.105 m marks on a 0.1 m grid would overlap


def test_fov_levels_are_ordered_by_field_of_view():
    out = order_by_fov(["17", "13", "no-such-camera", "15"])
    assert [c for c, _ in out] == ["13", "15", "17", "no-such-camera"]
    np.testing.assert_allclose([f for _, f in out[:3]], [16.1, 45.4, 125.6], atol=0.1)
    assert horizontal_fov_deg(load_catalogue().get(15).model) == pytest.approx(45.4, abs=0.1)


@pytest.mark.slow
def test_tilt_sweep_degrades_and_breaks():
    sw = run_sweep(17, "CAHVOR", "dots", "tilt", levels=[0, 30, 75], spp=2, n_poses=4,
                   calibrators=(("jpl", "CAHVOR"),))
    recs = {r["level"]: r for r in sw["records"]}
    assert list(recs) == [0.0, 30.0, 75.0]
    for lv in (0.0, 30.0):
        assert recs[lv]["status"] == "ok" and recs[lv]["detection_rate"] == 1.0
        assert recs[lv]["scene"]["tilt_deg"] == pytest.approx(lv, abs=1e-5)
    # a tilted board foreshortens the dots: less accurate, still within the bar
    assert recs[0.0]["projection_rms_px"] < recs[30.0]["projection_rms_px"] < 0.05
    assert recs[75.0]["detection_rate"] < 0.5
    assert sw["breakdown"]["jpl/CAHVOR"]["level"] == 75.0
    assert "detection rate" in sw["breakdown"]["jpl/CAHVOR"]["reason"]


@pytest.mark.slow
def test_cli_dot_size_sweep_writes_its_report(tmp_path, capsys):
    from camval.cli import main
    assert main(["sweep", "--camera", "17", "--difficulty", "dots", "--levels", "12,2",
                 "--calibrators", "jpl:CAHVOR", "--spp", "2", "--poses", "4",
                 "-o", str(tmp_path)]) == 0
    sw = json.loads((tmp_path / "sweep_dots.json").read_text())
    big, small = sw["records"]
    assert big["scene"]["dot_px"] == pytest.approx(12.0, rel=0.02)
    assert small["scene"]["dot_px"] == pytest.approx(2.0, rel=0.02)
    assert big["status"] == "ok" and big["detection_rate"] == 1.0
    assert big["projection_rms_px"] < 0.05
    # 2 px dots are below the detector's 6 px minimum blob area
    assert small["detection_rate"] < 0.5
    assert sw["breakdown"]["jpl/CAHVOR"]["level"] == 2
    html = (tmp_path / "sweep_report.html").read_text()
    assert html.count('src="data:image/png;base64,') == 1
    assert (tmp_path / "sweep_dots.png").read_bytes()[:4] == b"\x89PNG"
    assert "breaks at 2" in capsys.readouterr().out
    assert main(["sweep", "--difficulty", "dots", "-o", str(tmp_path)]) == 2   # exists
    assert main(["sweep", "--difficulty", "fog", "-o", str(tmp_path / "x")]) == 2

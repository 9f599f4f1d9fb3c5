'''The stereo range check: model scaling, scene placement, statistics, and one pair end to end'''

import argparse
import json
import math

import numpy as np
import pytest

from harness.stereo import (
    StereoError,
    StereoSetup,
    _error_stats,
    rectifiable,
    scale_model,
    terrain_pose_for,
)


def test_scale_model_maps_pixels_in_the_centre_convention(catalogue):
    m = catalogue.get(21).model
    s = scale_model(m, 0.25)
    assert (s.width, s.height) == (1280, 960)
    rng = np.random.default_rng(0)
    p = m.C + np.column_stack((rng.uniform(3, 8, 20), rng.uniform(-2, 2, 20),
                               rng.uniform(-1, 2, 20)))
    q, qs = m.project(p), s.project(p)
    assert np.allclose(qs, 0.25 * (q + 0.5) - 0.5, atol=1e-9)
    # the top-left corner of the image stays the top-left corner
    assert np.allclose(0.25 * (np.array([-0.5, -0.5]) + 0.5) - 0.5, [-0.5, -0.5])


@pytest.mark.parametrize("slot, height", [(21, 1.9), (12, 0.52)])
def test_terrain_pose_puts_the_camera_above_the_ground(catalogue, slot, height):
    m = catalogue.get(slot).model
    Rt, pitch = terrain_pose_for(m, height, 5.0)
    c_t = (m.C - Rt[3]) @ Rt[:3]
    assert c_t[2] == pytest.approx(height, abs=1e-12)
    a_t = m.A @ Rt[:3]
    if slot == 21:
        # the navcam looks level: the mast is pitched so its axis meets the ground at 5 m
        assert pitch > 15
        t = -c_t[2] / a_t[2]
        hit = c_t + t * a_t
        assert math.hypot(hit[0] - c_t[0], hit[1] - c_t[1]) == pytest.approx(5.0, rel=0.01)
    else:
        assert pitch == 0 and a_t[2] < -0.6     # the hazcam already looks 45 deg down


def test_pairs_must_share_a_frame(catalogue):
    with pytest.raises(StereoError, match="do not share a frame"):
        StereoSetup.from_catalogue(15, 16, catalogue=catalogue)
    with pytest.raises(StereoError, match="two cameras"):
        StereoSetup.from_catalogue(12, "12", catalogue=catalogue)


def test_rectifiable_models_are_what_mrcal_can_rectify(catalogue):
    m = catalogue.get(12).model
    r = rectifiable(m)
    assert abs(m.photogrammetric().theta_deg - 90) > 0.01
    assert r.photogrammetric().theta_deg == pytest.approx(90, abs=1e-9)
    assert np.all(r.E == 0) and np.array_equal(r.R, m.R)


def test_error_statistics():
    truth = np.array([[5.0, 5.0, 5.0, 5.0], [2.0, 2.0, np.nan, 9.0]])
    rng = np.array([[5.05, 4.9, np.nan, 5.0], [2.02, 2.0, 3.0, np.nan]])
    s = _error_stats(rng, truth, 5.0)
    assert s["pixels_with_truth"] == 7
    assert s["valid_fraction"] == pytest.approx(5 / 7)
    assert s["band"]["n"] == 3 and s["band"]["valid_fraction"] == pytest.approx(3 / 4)
    assert s["band"]["median_rel_error"] == pytest.approx(0.0)
    assert s["band"]["median_abs_rel_error"] == pytest.approx(0.01)
    assert s["all"]["median_abs_error_m"] == pytest.approx(0.02)


def test_unknown_variant_is_refused(tmp_path):
    from harness.commands import stereo as cmd
    p = argparse.ArgumentParser()
    cmd.add_arguments(p)
    with pytest.raises(StereoError, match="known: clean, noise"):
        cmd.run(p.parse_args(["12", "11", "-o", str(tmp_path), "--variants", "fog"]))


@pytest.mark.slow
def test_hazcam_pair_range_error(tmp_path):
    r'''MER B front hazcams (slots 12, 11) at half resolution: the whole check and its outputs'''
    from harness.commands import stereo as cmd
    p = argparse.ArgumentParser()
    cmd.add_arguments(p)
    args = p.parse_args(["12", "11", "-o", str(tmp_path), "--scale", "0.5", "--spp", "2",
                         "--variants", "clean,noise"])
    assert cmd.run(args) == 0
    doc = json.loads((tmp_path / "stereo_12_11.json").read_text())
    assert (tmp_path / "stereo_12_11.png").stat().st_size > 50_000
    clean = doc["variants"]["clean"]["stats"]
    noise = doc["variants"]["noise"]["stats"]
    assert clean["valid_fraction"] > 0.85
    assert abs(clean["all"]["median_rel_error"]) < 0.005
    assert clean["all"]["median_abs_rel_error"] < 0.01
    # near 5 m the disparity is ~4.5 px at this scale
    assert clean["band"]["n"] > 1000
    assert abs(clean["band"]["median_rel_error"]) < 0.02
    assert clean["band"]["median_abs_rel_error"] < 0.04
    assert noise["all"]["median_abs_rel_error"] > clean["all"]["median_abs_rel_error"]
    assert doc["meta"]["rectified_size"][0] > 400

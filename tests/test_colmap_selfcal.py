'''COLMAP self-calibration from rendered terrain sequences'''

import numpy as np
import pytest

from harness.studies.colmap_selfcal import _pose_sequence, closest_colmap_model


def test_closest_colmap_model(catalogue):
    assert closest_colmap_model(catalogue.get(15).model) == "OPENCV"      # CAHVOR navcam
    assert closest_colmap_model(catalogue.get(12).model) == "OPENCV_FISHEYE"  # wide CAHVORE


def test_pose_sequence_drives_forward_at_constant_height(catalogue):
    m = catalogue.get(15).model
    poses = _pose_sequence(m, 5, 0.25, 1.5, 5.0, 10.0, 3.0)
    c = np.array([(m.C - Rt[3]) @ Rt[:3] for Rt in poses])   # camera in the terrain frame
    assert np.allclose(c[:, 2], 1.5)
    # forward 0.25 m per image, give or take the mast head swinging with the yaw
    assert np.all(np.abs(np.diff(c[:, 0]) - 0.25) < 0.1)


@pytest.mark.slow
def test_selfcal_recovers_the_focal_length(tmp_path):
    from harness.studies.colmap_selfcal import run_selfcal
    r = run_selfcal(15, n_images=8, scale=0.5, workdir=tmp_path, with_target=False)
    sc = r["selfcal"]
    assert sc["status"] == "ok", sc.get("reason")
    assert sc["registered_images"] >= 6
    # the truth is 512x512 with Hs ~ 612 px: COLMAP gets within 2% without a target
    assert abs(sc["fx_error_px"]) < 0.02 * sc["fx"]
    assert sc["projection_rms_px"] < 5.0

r'''A blurred image's AprilTag corners from the coarse quad search

detect_apriltags searches an image's quads decimated TRIAL_DECIMATION_FACTOR times
coarser first (a 1024x1024 image's by 2); on a blurred image the tag edges
(targets.tag_edges) start from that search's corners, their search grown with the
decimation, instead of searching the quads again finer.
'''

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from targets_render import pinhole

from targets.boards import load_target
from targets.centroids import projected_points
from targets.detect import detect
from targets.poses import plan_poses


@pytest.mark.parametrize("size, f, decimated", [(2048, 1600.0, 4), (1024, 800.0, 2)])
def test_blurred_image_keeps_the_coarse_search(size, f, decimated):
    # a blurred image is searched decimated TRIAL_DECIMATION_FACTOR times coarser first
    # (2048x2048: by 4; 1024x1024, decimate_for 1: by 2, where the near pose's tags, bits of
    # ~10 px, all decode): the tag edges started from that search's corners end where the
    # finer search's start takes them, to well under their error
    from renderers.base import RenderSettings, get_renderer
    from targets.detect_apriltag import TRIAL_DECIMATION_FACTOR, decimate_for
    t = load_target("apriltag")
    m = pinhole(size, size, f, R=[0.0, -0.08, 0.01])
    Rt = plan_poses(m, t, seed=0)[0]
    img = get_renderer("raycast").render(m, t.pattern(), Rt, RenderSettings(spp=16)).image
    # sigma 0.7 px, as the realistic response profile's PSF: the blur estimate finds it
    img = gaussian_filter(np.asarray(img, dtype=np.float64), 0.7, mode="nearest")
    det = detect(img, t)
    assert det.info["psf_sigma_px"] > 0.5                  # the blurred path
    assert det.info["quad_decimate"] == TRIAL_DECIMATION_FACTOR * decimate_for(img.shape) \
        == decimated
    truth = projected_points(m, t, Rt)
    e = np.linalg.norm(det.q - truth, axis=-1)[det.found]
    assert det.status == "ok" and det.n_found == 144
    # a blurred pinhole render's tag-edge corners (measured 0.0005 px RMS, max 0.0022-0.0031)
    assert np.sqrt(np.mean(e ** 2)) < 0.002 and e.max() < 0.01
    # the finer search's start gives the same corners to well under their error
    # (measured 0.0005-0.0006 px apart)
    fine = detect(img, t, quad_decimate=decimate_for(img.shape))
    assert fine.info["quad_decimate"] == decimate_for(img.shape) == decimated // 2
    assert np.array_equal(det.found, fine.found)
    assert np.max(np.abs(det.q - fine.q)[det.found]) < 0.002


def test_given_blur_on_a_large_image_starts_from_its_search_decimation():
    # a given blur skips the trial search: the quads are searched at decimate_for's 3, and
    # the tag edges' start error is that decimation's (left at 1, corners whose pupil quads
    # erred more than MAX_CORNER_SHIFT_PX were dropped, "edges meet far from the corner")
    from reference_models.cahvore import CAHVORE
    from renderers.base import RenderSettings, get_renderer
    t = load_target("apriltag")
    # a 5120x3840 CAHVORE fisheye (test_corner_model_bias's, 6.4 times the pixels): its
    # curved tag edges put pupil_apriltags' quads, decimated by 3, px off the corners
    A, O = np.array([0.0, 0.0, 1.0]), np.array([0.008, -0.003, 1.0])
    m = CAHVORE(C=[0, 0, 0], A=A, H=[1920.0, 0, 0] + 2559.5 * A, V=[0, 1920.0, 0] + 1919.5 * A,
                O=O / np.linalg.norm(O), R=[0.0, 0.006, -0.002], E=[0.0, 0.004, -0.001],
                model_type=3, linearity=0.6, width=5120, height=3840)
    Rt = plan_poses(m, t, seed=0)[0]
    img = get_renderer("raycast").render(m, t.pattern(), Rt, RenderSettings(spp=4)).image
    img = gaussian_filter(np.asarray(img, dtype=np.float64), 0.7, mode="nearest")
    det = detect(img, t, psf_sigma_px=0.7)
    assert det.info["quad_decimate"] == 3 and det.info["psf_sigma_px"] == 0.7
    truth = projected_points(m, t, Rt)
    e = np.linalg.norm(det.q - truth, axis=-1)[det.found]
    assert det.status == "ok" and det.n_found == 144
    assert np.sqrt(np.mean(e ** 2)) < 0.005            # measured 0.0031 (spp 4)

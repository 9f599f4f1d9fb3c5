r'''targets.corners' quick blur look: its sigma fits end at LOOK_SHARP_SIGMA_PX on sharp
images without changing what the look decides, and never on blurred ones'''

import numpy as np
import pytest
from targets_render import pinhole, render

import targets.corners as corners
from renderers.response import ResponseChain
from targets.boards import load_target
from targets.corners import (
    BLUR_NEGLIGIBLE_PX,
    LOOK_SHARP_SIGMA_PX,
    refine_tag_corners,
    tag_window,
)


def _tags(psf_sigma_px=0.0):
    r'''(image, exact corners, coarse corners 0.3 px off) of the AprilTag grid on a 320 x 320
pinhole, rolled and tilted (no edge along the pixel grid), K = 16 samples a pixel side;
blurred by the response stage's PSF (a pixel-integrated Gaussian) when psf_sigma_px > 0'''
    from targets.centroids import projected_points
    t = load_target("apriltag")
    m = pinhole(320, 320, 260.0)
    r, a = np.radians(-23.0), np.radians(20.0)
    Rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Rt = np.vstack((Rz @ Rx, [-0.5, -0.45, 1.45]))
    img = render(m, t.pattern(), Rt, K=16)
    if psf_sigma_px > 0.0:
        img = ResponseChain.from_config({"psf": {"kind": "gaussian", "sigma_px": psf_sigma_px}}) \
            .apply(img).image.astype(np.float64)
    truth = projected_points(m, t, Rt)
    rng = np.random.default_rng(1)
    ang = rng.uniform(0, 2 * np.pi, len(truth))
    q0 = truth + 0.3 * np.stack((np.cos(ang), np.sin(ang)), -1)
    return t, img, truth, q0.reshape(-1, 4, 2)


def test_sharp_look_ends_early_and_decides_as_the_full_fits(monkeypatch):
    r'''A sharp render: the look's corners end below LOOK_SHARP_SIGMA_PX (their full fits
crawl on towards ~1e-5 px), the image is found sharp either way and every corner is the
same (the second pass fits the sharp model in both); the look's median lies within
LOOK_SHARP_SIGMA_PX of the full fits' (each ended sigma and its full fit's both in [0, it))'''
    t, img, truth, q0 = _tags()
    fit = refine_tag_corners(img, q0, stop_if_blurred=True, **tag_window(t))
    assert fit.info["psf_sigma_px"] == 0.0
    assert fit.info["psf_sharp_stops"] > 0
    assert fit.info["psf_sigma_estimated_px"] < LOOK_SHARP_SIGMA_PX
    monkeypatch.setattr(corners, "LOOK_SHARP_SIGMA_PX", 0.0)
    full = refine_tag_corners(img, q0, stop_if_blurred=True, **tag_window(t))
    assert "psf_sharp_stops" not in full.info
    assert full.info["psf_sigma_px"] == 0.0
    np.testing.assert_array_equal(fit.q, full.q)
    assert abs(fit.info["psf_sigma_estimated_px"]
               - full.info["psf_sigma_estimated_px"]) < LOOK_SHARP_SIGMA_PX


@pytest.mark.parametrize("psf_sigma_px", [0.3, 0.7])
def test_blurred_look_is_never_ended(psf_sigma_px, monkeypatch):
    r'''A blurred render (the response stage's PSF; 0.7 px is the `realistic` profile's):
the look's sigma fits come down to the blur from above and never pass below
LOOK_SHARP_SIGMA_PX, so the look stops the window fit with the same estimate as without
the stop'''
    t, img, truth, q0 = _tags(psf_sigma_px)
    fit = refine_tag_corners(img, q0, stop_if_blurred=True, **tag_window(t))
    assert fit.info["stopped"]
    assert fit.info["psf_sharp_stops"] == 0
    assert fit.info["psf_sigma_px"] > BLUR_NEGLIGIBLE_PX
    monkeypatch.setattr(corners, "LOOK_SHARP_SIGMA_PX", 0.0)
    full = refine_tag_corners(img, q0, stop_if_blurred=True, **tag_window(t))
    assert full.info["psf_sigma_px"] == fit.info["psf_sigma_px"]
    np.testing.assert_array_equal(fit.q, full.q)



def test_a_given_sharp_image_skips_the_look():
    r'''detect_apriltags(psf_sigma_px=0): the image is taken as sharp (given, no look) and
the corners are the ones the look's sharp verdict gives (both fit the sharp model from the
same first pass on a clean render)'''
    from targets.detect_apriltag import detect_apriltags
    t = load_target("apriltag")
    m = pinhole(640, 640, 600.0)
    r, a = np.radians(-23.0), np.radians(20.0)
    Rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    img = render(m, t.pattern(), np.vstack((Rz @ Rx, [-0.5, -0.45, 1.6])), K=16)
    looked = detect_apriltags(img, t)
    given = detect_apriltags(img, t, psf_sigma_px=0.0)
    assert looked.info["psf_source"] == "estimated" and looked.info["psf_sigma_px"] == 0.0
    assert given.info["psf_source"] == "given" and given.info["psf_sigma_px"] == 0.0
    assert np.isfinite(given.q).any()
    np.testing.assert_array_equal(given.q, looked.q)

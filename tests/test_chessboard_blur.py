r'''targets.detect_chessboard on blurred images: the X junctions fitted with the sampled
kernel at the estimated blur's variance (x_junction_blur)'''

import numpy as np
import pytest
from targets_render import pinhole, render
from test_corners_blur import _as_grid, _chessboard_corner_image
from test_detect import WIDE

from renderers.response import ResponseChain
from targets.boards import load_target
from targets.centroids import projected_points
from targets.corners import added_blur_px, refine_chessboard_corners
from targets.detect import detect
from targets.detect_chessboard import X_BLUR_TOLERANCE_PX, x_junction_blur
from targets.poses import plan_poses


@pytest.mark.parametrize("sigma,kind", [(0.05, "gaussian"), (0.3, "gaussian"),
                                        (0.7, "gaussian"), (1.5, "gaussian"),
                                        (0.7, "sampled")])
def test_x_junction_blur_adds_the_estimates_blur(sigma, kind):
    r'''The sampled kernel's taps add the blur (standard deviation beyond the pixel's own
area) of the estimate, whatever its kind: to the secant's tolerance; a sampled estimate
comes back as itself'''
    s = x_junction_blur(sigma, kind)
    assert abs(added_blur_px(s, "sampled") - added_blur_px(sigma, kind)) < X_BLUR_TOLERANCE_PX
    if kind == "sampled":
        assert abs(s - sigma) < 1e-5


@pytest.mark.parametrize("c,tilt", [((23.37, 24.81), 11.0), ((23.81, 24.13), 37.0)])
def test_x_junction_corner_barely_moves_with_the_kernel_kind(c, tilt):
    r'''A point-symmetric X junction under a point-symmetric blur: a model of the other kind
at the same variance misfits the pixels at c + u and c - u alike, and the corner moves
only by what the pixel grid's asymmetry about it leaves (0 at half-pixel corners).
Noise-free corners of constructed images:
- the response's (sampled) blur fitted with the sampled kernel of the Gaussian-kind
  estimate's variance: the exact model, at 1e-5 px (x_junction_blur's round trip);
- fitted with the Gaussian kind at that variance: measured 0.9e-3 - 1.1e-3 px, held to
  2e-3 (half the realistic profile's noise-limited 0.004 px RMS on navcam 15);
- an optics (Gaussian-kind) blur fitted with the sampled kernel of its variance: within
  1.5e-3 px of the Gaussian kind's own fit, itself off by 2-5e-3 px (its 5 x 5 quadrature:
  tests/test_corners_blur.py)'''
    img, q, dirs, steps = _chessboard_corner_image(0.7, "sampled", seed=None, c=c, tilt=tilt)
    G = _as_grid(q + 0.2, dirs, steps)
    sg = x_junction_blur(0.7, "sampled")
    same = refine_chessboard_corners(img, G, psf_sigma_px=x_junction_blur(
        np.sqrt(0.7 ** 2 + 1.0 / 12.0), "gaussian"), psf_kind="sampled")
    assert np.linalg.norm(same.q[4] - q[0]) < 1e-4
    other = refine_chessboard_corners(img, G, psf_sigma_px=np.sqrt(sg ** 2 + 1.0 / 12.0),
                                      psf_kind="gaussian")
    assert np.linalg.norm(other.q[4] - q[0]) < 2e-3

    img, q, dirs, steps = _chessboard_corner_image(0.7, "gaussian", seed=None, c=c, tilt=tilt)
    G = _as_grid(q + 0.2, dirs, steps)
    own = refine_chessboard_corners(img, G, psf_sigma_px=0.7, psf_kind="gaussian")
    sampled = refine_chessboard_corners(img, G, psf_sigma_px=x_junction_blur(0.7, "gaussian"),
                                        psf_kind="sampled")
    e_own = np.linalg.norm(own.q[4] - q[0])
    e_sampled = np.linalg.norm(sampled.q[4] - q[0])
    assert e_own < 6e-3 and e_sampled < e_own + 1.5e-3, (e_own, e_sampled)


def test_blurred_chessboard_is_fitted_with_the_sampled_kernel():
    r'''The realistic profile (the response's PSF of sigma 0.7 px, shot and read noise, 12
bits) on the distorted camera's first planned poses: the windows' quick look estimates the
blur, the corners are fitted with the sampled kernel of its variance (sigma within 2% of
the response's 0.7: the look's 8 corners scatter ~1%), and the corners are as close to the
projections as those of the sharp image (its K = 4 render's sampling error, 0.05-0.09 px
RMS, dominates both: the blur averages it, measured 0.024-0.051 px)'''
    t = load_target("chessboard")
    m = pinhole(480, 360, 300.0, R=WIDE["R"])
    chain = ResponseChain.from_config({"full_well_e": 20000,
                                       "psf": {"kind": "gaussian", "sigma_px": 0.7},
                                       "shot_noise": {}, "read_noise": {"sigma_e": 12.0},
                                       "quantise": {"bits": 12}})
    for i, Rt in enumerate(plan_poses(m, t, seed=0)[:2]):
        sharp = render(m, t.pattern(), Rt, K=4)
        truth = projected_points(m, t, Rt)
        det = detect(chain.apply(sharp, seed=i).image, t)
        assert det.status == "ok", det.reason
        assert "as the sampled kernel" in det.info["psf_source"]
        assert det.info["psf_kind"] == "sampled"
        assert abs(det.info["psf_sigma_px"] - 0.7) < 0.02 * 0.7, det.info
        e = np.linalg.norm(det.q - truth, axis=-1)
        e0 = np.linalg.norm(detect(sharp, t).q - truth, axis=-1)
        assert np.sqrt(np.nanmean(e ** 2)) <= np.sqrt(np.nanmean(e0 ** 2))

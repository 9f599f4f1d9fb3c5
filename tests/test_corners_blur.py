r'''targets.corners under blur: the blurred pixel model, the blur estimate, and corners of
blurred images (issue 16: the `realistic` response profile's PSF)'''

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from renderers.response import ResponseChain
from targets._corner_kernels import wedge_model
from targets.corners import (
    _blur_rule,
    blur_kernel,
    blurred_half_box,
    refine_chessboard_corners,
    refine_tag_corners,
    wedge_area,
)


def _unit(a):
    return np.array([np.cos(a), np.sin(a)])


def _model(centres, c, angles, wedges, sigma, kind, order=None):
    r'''D (P,) of one corner: the compiled model with the given blur'''
    uu = np.stack([_unit(a) for a in angles])[None]
    first = np.array([[i for i, _ in wedges]])
    second = np.array([[j for _, j in wedges]])
    if sigma == 0:
        Z, dZ = np.zeros((1, 1, 2)), np.zeros((1, 1, 2))
        W, dW = np.ones((1, 1)), np.zeros((1, 1))
    elif order is not None:
        nodes, w = _blur_rule(order)
        Z, W = sigma * nodes[None], w[None]
        dZ, dW = nodes[None], np.zeros(W.shape)
    else:
        Z, W, dZ, dW = blur_kernel([sigma], kind)
    return wedge_model(centres[None], np.array([0]), np.asarray(c, float)[None], uu, first,
                       second, 0.0, Z, W, dZ, dW)


def _grid(r):
    p = np.arange(-r, r + 1, dtype=np.float64)
    X, Y = np.meshgrid(p, p)
    return np.stack((X.ravel(), Y.ravel()), -1)


# a wedge from 20 to 115 deg (an L-shaped corner seen obliquely), apex off the pixel grid
C0, ANGLES = (0.3, -0.2), np.radians([20.0, 115.0])


def test_gaussian_kernel_is_the_optics_blur_of_the_pixel_area():
    r'''Against a brute force: the wedge at 40 x 40 points per px, blurred by sigma 0.7 px
(scipy, continuous to 1/40 px) and integrated over each pixel. Pixels within 4 px of the
apex (the field is 16 px: its zero padding reaches in 3 sigma). The product Gauss-Hermite
rule of 5 nodes a side is within 0.5% of the contrast RMS (order 3: 1%, so 3 fails it)'''
    S, sig = 40, 0.7
    xs = (np.arange(-8 * S, 8 * S) + 0.5) / S - 0.5
    XX, YY = np.meshgrid(xs, xs)
    dx, dy = XX - C0[0], YY - C0[1]
    u1, u2 = _unit(ANGLES[0]), _unit(ANGLES[1])
    inside = ((u1[0] * dy - u1[1] * dx) >= 0) & ((dx * u2[1] - dy * u2[0]) >= 0)
    ref = gaussian_filter(inside.astype(float), sig * S, mode="constant")
    ref = ref.reshape(16, S, 16, S).mean(axis=(1, 3))[4:13, 4:13].ravel()   # centres -4..4
    centres = _grid(4)
    D = _model(centres, C0, ANGLES, [(0, 1)], sig, "gaussian")[0][0]
    rms = np.sqrt(np.mean((D - ref) ** 2))
    assert rms < 0.005, rms
    D3 = _model(centres, C0, ANGLES, [(0, 1)], sig, None, order=3)[0][0]
    assert np.sqrt(np.mean((D3 - ref) ** 2)) > 0.008


def test_sampled_kernel_is_the_response_stage_psf():
    r'''The "sampled" kernel on the exact area image equals renderers.response's psf stage
applied to that image (both convolve the pixel image with the pixel-integrated Gaussian;
the model's taps stop at 3 sigma beyond the pixel's half, the stage's at 5 sigma: the
weight left out is < 0.1%)'''
    r = 12
    centres = _grid(r)
    sharp = _model(centres, C0, ANGLES, [(0, 1)], 0.0, None)[0][0].reshape(2 * r + 1, -1)
    stage = ResponseChain.from_config({"psf": {"kind": "gaussian", "sigma_px": 0.7}})
    blurred = stage.apply(sharp).image.astype(np.float64)
    D = _model(centres, C0, ANGLES, [(0, 1)], 0.7, "sampled")[0][0].reshape(2 * r + 1, -1)
    inner = slice(4, -4)   # clear of the zero padding at the field's edge
    assert np.abs(D - blurred)[inner, inner].max() < 1e-3


@pytest.mark.parametrize("kind", ["gaussian", "sampled"])
def test_blur_derivative_is_the_models_slope(kind):
    r'''dD/dsigma against central differences of the model (smooth in sigma: the pixel area
is C1 in the offsets, the sampled weights are smooth in sigma)'''
    centres = _grid(5)
    D, _, _, dD_ds = _model(centres, C0, ANGLES, [(0, 1)], 0.7, kind)
    h = 1e-5
    Dp = _model(centres, C0, ANGLES, [(0, 1)], 0.7 + h, kind)[0]
    Dm = _model(centres, C0, ANGLES, [(0, 1)], 0.7 - h, kind)[0]
    num = (Dp - Dm) / (2 * h)
    assert np.abs(dD_ds - num).max() < 1e-5 * max(1.0, np.abs(num).max())


@pytest.mark.parametrize("widen", [0.0, 0.1])
def test_sampled_taps_share_the_sharp_pixels(widen):
    r'''The sampled kernel's taps sit at whole-pixel offsets: the compiled model takes each
tap's sharp pixel from one grid over the window's box (_grid_wedge_model). It equals the
numpy reference's sum over the taps of wedge_area and its derivatives (an X junction: two
wedges) to rounding (1e-12: ~25 taps of terms of order 1, added in another order)'''
    centres = _grid(6) + np.array([3.0, -2.0])
    c = np.array([3.3, -2.2])
    angles = np.radians([20.0, 115.0, 200.0, 295.0])
    uu = np.stack([_unit(a) for a in angles])
    first, second = np.array([[0, 2]]), np.array([[1, 3]])
    Z, W, dZ, dW = blur_kernel([0.7], "sampled")
    D, dD_dc, dD_dt, dD_ds = wedge_model(centres[None], np.array([0]), c[None], uu[None],
                                         first, second, widen, Z, W, dZ, dW)
    ref = [np.zeros(D.shape[1:]), np.zeros(dD_dc.shape[1:]), np.zeros(dD_dt.shape[1:]),
           np.zeros(D.shape[1:])]
    for z, wq, dwq in zip(Z[0], W[0], dW[0], strict=True):
        d = centres + z - c
        for i1, i2 in ((0, 1), (2, 3)):
            A, dA_dc, dA_dt1, dA_dt2 = wedge_area(
                d, np.broadcast_to(uu[i1], d.shape), np.broadcast_to(uu[i2], d.shape), True,
                widen)
            ref[0] += wq * A
            ref[1] += wq * dA_dc
            ref[2][:, i1] += wq * dA_dt1
            ref[2][:, i2] += wq * dA_dt2
            ref[3] += dwq * A
    for got, want in zip((D[0], dD_dc[0], dD_dt[0], dD_ds[0]), ref, strict=True):
        assert np.abs(got - want).max() < 1e-12


def test_blurred_model_numpy_reference_equals_compiled():
    from targets.corners import _fit
    img, q, dirs, steps = _chessboard_corner_image(0.7, "sampled", seed=None)
    fits = [_fit(img, q + 0.15, dirs, [(0, 1), (2, 3)], steps, 0.45, sigma=0.7,
                 psf_kind="sampled", lines=[(0, 2), (1, 3)], kernel=k)
            for k in ("numba", "numpy")]
    assert np.abs(fits[0].q - fits[1].q).max() < 1e-9


def _chessboard_corner_image(sigma, kind, seed=0, size=48, c=(23.37, 24.81), tilt=11.0):
    r'''A chessboard corner (two opposite dark wedges, squares ~19 px, edges at 11 deg and
98 deg), exact area image blurred with the response stage (sampled) or by the gaussian
model, with the realistic profile's noise when seed is not None'''
    a0, a1 = np.radians(tilt), np.radians(tilt + 87.0)
    angles = [a0, a1, a0 + np.pi, a1 + np.pi]
    P = np.stack(np.meshgrid(np.arange(size), np.arange(size)), -1).reshape(-1, 2) \
        .astype(np.float64)
    if kind == "sampled" or sigma == 0:
        D = _model(P - np.asarray(c), (0.0, 0.0), angles, [(0, 1), (2, 3)], 0.0, None)[0][0]
        img = 0.85 - 0.75 * D.reshape(size, size)
        cfg = {"psf": {"kind": "gaussian", "sigma_px": sigma}} if sigma > 0 else {}
    else:
        D = _model(P - np.asarray(c), (0.0, 0.0), angles, [(0, 1), (2, 3)], sigma, None,
                   order=9)[0][0]
        img = 0.85 - 0.75 * D.reshape(size, size)
        cfg = {}
    if seed is not None:
        cfg.update({"shot_noise": {}, "read_noise": {"sigma_e": 12.0}, "quantise": {"bits": 12}})
    if cfg:
        img = ResponseChain.from_config({"full_well_e": 20000, **cfg}) \
            .apply(img, seed=seed).image.astype(np.float64)
    dirs = np.stack([_unit(a) for a in angles])[None]
    steps = (19.0 * np.stack((_unit(a0), _unit(a1)), -1))[None]
    return img, np.asarray(c, float)[None], dirs, steps


@pytest.mark.parametrize("sigma,kind", [(0.4, "sampled"), (0.7, "sampled"), (1.0, "sampled"),
                                        (0.7, "gaussian")])
def test_blur_is_estimated_and_the_corner_found(sigma, kind):
    r'''Noise-free: the blur estimate finds the kind and sigma (to 0.5%: the model is
exact for the sampled kernel; to 2% for the gaussian one, whose image here is made with 9
Gauss-Hermite nodes a side against the model's 5, 0.26% of the contrast apart), and the
corner is where it is to 2e-3 px with the sampled kernel, to 6e-3 px with the gaussian
one (its 5 x 5 quadrature's error: measured 0.0049 px here; a sharp-edged fit of these
images is off by 0.07-0.25 px: the kinked-X failure)'''
    img, q, dirs, steps = _chessboard_corner_image(sigma, kind, seed=None)
    fit = refine_chessboard_corners(img, _as_grid(q + 0.2, dirs, steps))
    k = 4   # the middle corner of the 3 x 3 grid
    assert fit.info["psf_kind"] == kind
    tol = 0.005 if kind == "sampled" else 0.02
    assert abs(fit.info["psf_sigma_px"] - sigma) < tol * sigma, fit.info
    assert np.linalg.norm(fit.q[k] - q[0]) < (2e-3 if kind == "sampled" else 6e-3), \
        fit.q[k] - q[0]


def _as_grid(q, dirs, steps):
    r'''A 3 x 3 grid around one corner (its neighbours one square away: off the image
here, so only the middle one is fitted; they give the grid steps)'''
    ex, ey = steps[0, :, 0], steps[0, :, 1]
    G = np.empty((3, 3, 2))
    for i in range(3):
        for j in range(3):
            G[i, j] = q[0] + (j - 1) * ex + (i - 1) * ey
    return G


def test_noisy_blurred_corner_to_its_noise_floor():
    r'''The realistic profile (sigma 0.7 px, 12-bit, shot + read noise) on 20 noise seeds:
the corner's RMS error is the noise's (a few thousandths of a px at a contrast of 15000
e-), not the 0.07-0.25 px of a sharp model; mean error within 3 standard errors of 0'''
    errs = []
    for seed in range(20):
        img, q, dirs, steps = _chessboard_corner_image(0.7, "sampled", seed=seed)
        fit = refine_chessboard_corners(img, _as_grid(q + 0.2, dirs, steps))
        errs.append(fit.q[4] - q[0])
    e = np.array(errs)
    assert np.isfinite(e).all()
    rms = np.sqrt(np.mean(e ** 2))
    assert rms < 0.01, rms
    assert (np.abs(e.mean(0)) < 3 * e.std(0) / np.sqrt(len(e)) + 1e-3).all(), e.mean(0)


def test_sharp_images_keep_the_sharp_model():
    r'''An exact area render has no blur: the estimate is below BLUR_NEGLIGIBLE_PX and the
corner is where the sharp fit puts it (1e-6 px)'''
    img, q, dirs, steps = _chessboard_corner_image(0.0, "sampled", seed=None)
    fit = refine_chessboard_corners(img, _as_grid(q + 0.2, dirs, steps))
    assert fit.info["psf_sigma_px"] < 0.02
    assert np.linalg.norm(fit.q[4] - q[0]) < 1e-5


def test_given_blur_and_tag_corners():
    r'''A known PSF handed in (psf_sigma_px) is used as given; an L-shaped corner (an
AprilTag's) is found under it to 2e-3 px; the sharp model puts it 0.025 px off (into
the dark wedge)'''
    size, c = 40, np.array([17.31, 16.77])
    a0, a1 = np.radians(8.0), np.radians(101.0)
    P = np.stack(np.meshgrid(np.arange(size), np.arange(size)), -1).reshape(-1, 2) \
        .astype(np.float64)
    D = _model(P - c, (0.0, 0.0), [a0, a1], [(0, 1)], 0.0, None)[0][0]
    img = 0.9 - 0.8 * D.reshape(size, size)
    img = ResponseChain.from_config({"psf": {"kind": "gaussian", "sigma_px": 0.7}}) \
        .apply(img).image.astype(np.float64)
    # a tag of side 8 bits = 80 px with this corner first: next corner along a0, previous
    # along a1
    Q = np.stack((c, c + 80 * _unit(a0), c + 80 * (_unit(a0) + _unit(a1)), c + 80 * _unit(a1)))
    given = refine_tag_corners(img, Q[None], psf_sigma_px=0.7, psf_kind="sampled",
                               max_window_px=8)
    assert given.info == {"psf_sigma_px": 0.7, "psf_source": "given", "psf_kind": "sampled"}
    assert np.linalg.norm(given.q[0] - c) < 2e-3, given.q[0] - c
    sharp = refine_tag_corners(img, Q[None], psf_sigma_px=0.0, max_misfit=1.0)
    assert np.linalg.norm(sharp.q[0] - c) > 0.01


def test_window_shrinks_by_the_psf_reach():
    r'''3 sigma of blur in px, over the smallest image step of a board unit'''
    steps = np.array([[[10.0, 0.0], [0.0, 5.0]]])
    assert blurred_half_box(steps, 0.8, 1.0, 0.0)[0] == 0.8
    assert blurred_half_box(steps, 0.8, 1.0, 0.5)[0] == pytest.approx(1.0 - 1.5 / 5.0)
    assert np.isfinite(wedge_area(np.zeros(2), _unit(0.0), _unit(1.0)))


@pytest.mark.parametrize("sigma, spread, n, blurred", [
    (0.023, 0.033, 8, False),   # a sharp 5120x3840 fisheye render's quick look (camera 22)
    (0.023, 0.001, 8, True),    # the same median, its 8 estimates agreeing: a real blur
    (0.70, 0.02, 8, True),      # the realistic profile's sigma 0.7 px
    (1e-5, 1e-5, 8, False),     # a sharp render's usual look
    (0.05, float("nan"), 0, True),   # no spread to judge by: the median decides
    (0.2347, 0.0, 1, False),    # one corner's estimate, spread 0 by construction (a sharp
                                # render of constructed offaxis-640x480): the full estimate
])
def test_quick_look_stops_only_on_a_blur_beyond_its_own_scatter(sigma, spread, n, blurred):
    r'''refine_corners(stop_if_blurred) leaves the window fit for the tag edges only when
the quick look's blur exceeds BLUR_NEGLIGIBLE_PX by 3 standard errors of its median
(1.2533 spread / sqrt(n)); a look within its scatter of that is checked by the full
estimate (a sharp render of camera 22, 5120x3840 CAHVORE, read 0.023 +- 0.033 px on 8
corners and its corners went to the tag edges: 100x the residual)'''
    from targets.corners import _clearly_blurred
    look = {"psf_sigma_px": sigma, "psf_sigma_spread_px": spread, "psf_estimates": n,
            "psf_kind": "gaussian"}
    assert _clearly_blurred(look) is blurred

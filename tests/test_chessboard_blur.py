r'''targets.detect_chessboard on blurred images: the X junctions fitted with the sampled
kernel at the estimated blur's variance (x_junction_blur)'''

import numpy as np
import pytest
from targets_render import pinhole, render
from test_corners_blur import _as_grid, _chessboard_corner_image, _unit
from test_detect import WIDE

from harness.stages import observations_from
from renderers.response import ResponseChain
from targets.boards import load_target
from targets.centroids import projected_points
from targets.corners import added_blur_px, refine_chessboard_corners
from targets.detect import detect
from targets.detect_chessboard import X_BLUR_TOLERANCE_PX, x_junction_blur
from targets.detection import CORNER_LINES
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
    poses = plan_poses(m, t, seed=0)[:2]
    dets = []
    for i, Rt in enumerate(poses):
        sharp = render(m, t.pattern(), Rt, K=4)
        truth = projected_points(m, t, Rt)
        det = detect(chain.apply(sharp, seed=i).image, t)
        assert det.status == "ok", det.reason
        assert "as the sampled kernel" in det.info["psf_source"]
        assert det.info["psf_kind"] == "sampled"
        assert abs(det.info["psf_sigma_px"] - 0.7) < 0.02 * 0.7, det.info
        # the kernel the lines were fitted with, for their bias (corner_bias(blur_px))
        assert det.corner_blur_px == det.info["psf_sigma_px"]
        assert set(det.corner_model[det.found]) == {CORNER_LINES}
        e = np.linalg.norm(det.q - truth, axis=-1)
        det0 = detect(sharp, t)
        assert det0.corner_blur_px == 0.0 and det0.corner_model is None
        e0 = np.linalg.norm(det0.q - truth, axis=-1)
        assert np.sqrt(np.nanmean(e ** 2)) <= np.sqrt(np.nanmean(e0 ** 2))
        dets.append(det)
    # the blur travels with the observations to the calibrators' bias step
    obs = observations_from(m, t, poses, dets)
    assert np.array_equal(obs.corner_blur_px, [d.corner_blur_px for d in dets])


def _bent_x(c, a0, k1, k2, size=48, S=32):
    r'''A chessboard corner at c whose two board lines are bent (curvatures k1, k2 1/px, the
parabola s t + (k s^2 / 2) perp(t) through c along each), area-sampled at S x S points a
pixel; (image, u1, u2) the lines' unit tangents'''
    u1, u2 = _unit(a0), _unit(a0 + np.radians(87.0))
    sub = (np.arange(S) + 0.5) / S - 0.5
    img = np.zeros((size, size))
    ys, xs = np.mgrid[0:size, 0:size].astype(float)
    for sy in sub:
        for sx in sub:
            dx, dy = xs + sx - c[0], ys + sy - c[1]
            f1 = (u1[0] * dy - u1[1] * dx) - 0.5 * k1 * (u1[0] * dx + u1[1] * dy) ** 2
            f2 = (u2[0] * dy - u2[1] * dx) - 0.5 * k2 * (u2[0] * dx + u2[1] * dy) ** 2
            img += (f1 > 0) ^ (f2 > 0)
    return 0.85 - 0.75 * img / S ** 2, u1, u2


@pytest.mark.parametrize("clearance", [1.0, 0.5])
@pytest.mark.parametrize("k1,k2", [(2e-3, 0.0), (2e-3, -1.5e-3), (0.0, 3e-3)])
def test_blurred_x_junction_moves_by_its_lines_curvature_bias(k1, k2, clearance):
    r'''Bent board lines through a corner: the sharp fit (four free rays) moves the corner by
curvature_bias (measured within 0.9-1.7% of it), the blurred fit (each line's two rays tied
into one: CORNER_LINES) by curvature_bias with the lines tied, the blur's taps and the blurred
fit's window (a neighbour 0.5 square away
shrinks it from 0.45 to 0.39 square), about -1.9x the other: measured within 1.0-3.2% of
it, held to 5% (first order in the curvature: k w ~ 0.03 here); the lines' bias with the
sharp pixel terms in the sharp window, which leave the blur out, is 6.5-10.4% off (19-24%
with the shrunk window), at least twice as far'''
    from targets.corners import CHESSBOARD_LINES, curvature_bias
    c = np.array([23.37, 24.81])
    img, u1, u2 = _bent_x(c, np.radians(11.0), k1, k2)
    blurred = ResponseChain.from_config({"psf": {"kind": "gaussian", "sigma_px": 0.7}}) \
        .apply(img).image.astype(np.float64)
    tangents = np.stack((u1, u2, -u1, -u2))[None]
    # ray i + 2 runs the other way along line i: its curvature is -k
    curv = np.array([[k1, k2, -k1, -k2]])
    steps = (19.0 * np.stack((u1, u2), -1))[None]
    G = _as_grid(c[None] + 0.2, tangents, steps)
    for im, sigma, lines, tol in ((img, 0.0, (), 0.02),
                                  (blurred, 0.7, CHESSBOARD_LINES, 0.05)):
        fit = refine_chessboard_corners(im, G, psf_sigma_px=sigma, psf_kind="sampled",
                                        clearance=clearance)
        b = curvature_bias(c[None], tangents, curv, [(0, 1), (2, 3)], steps, 0.45,
                           lines=lines, sigma=sigma, clearance=clearance)[0]
        shift = fit.q[4] - c
        assert np.linalg.norm(shift - b) < tol * np.linalg.norm(b), (sigma, shift, b)
    sharp_terms = curvature_bias(c[None], tangents, curv, [(0, 1), (2, 3)], steps, 0.45,
                                 lines=CHESSBOARD_LINES)[0]
    assert np.linalg.norm(shift - sharp_terms) > 2.0 * np.linalg.norm(shift - b)


@pytest.mark.parametrize("blur", [None, [0.7, 0.7, 0.7]])
def test_bias_step_gives_lines_corners_the_lines_bias(blur):
    r'''The calibrators' bias step: a view whose corners are CORNER_LINES' gets
corner_bias(lines=True) under the view's corner_blur_px (None: sharp terms), a window view
corner_bias (no blur whatever the view's), a tag-edge view none (a constructed 800x600
CAHVORE fisheye, tests/test_corner_model_bias.py; exact observations)'''
    from synthetic import exact_observations, synthetic_poses
    from test_corner_model_bias import _fisheye

    from harness.calibrators.bias import bias_step, corner_bias
    from targets.detection import CORNER_WINDOW, TAG_EDGES
    truth, t = _fisheye(), load_target("chessboard")
    Rts = synthetic_poses(truth, t)[:3]
    obs = exact_observations(truth, t, Rts)
    model = np.array([np.where(obs.found[i], m, "") for i, m in
                      enumerate((CORNER_LINES, CORNER_WINDOW, TAG_EDGES))])
    b, _ = bias_step(truth, t, Rts, obs.p_board, corner_model=model, corner_blur_px=blur)
    want = [corner_bias(truth, t, Rts[0], obs.p_board[0], lines=True,
                        blur_px=0.0 if blur is None else blur[0]),
            corner_bias(truth, t, Rts[1], obs.p_board[1])]
    if blur is not None:
        # the blur's taps and window move the lines' bias by 12% RMS of it here (measured)
        sharp = corner_bias(truth, t, Rts[0], obs.p_board[0], lines=True)
        f = obs.found[0]
        assert np.sqrt(np.mean((want[0][f] - sharp[f]) ** 2)) > \
            0.05 * np.sqrt(np.mean(sharp[f] ** 2))
    for i in range(2):
        f = obs.found[i]
        assert np.allclose(b[i][f], want[i][f], rtol=0, atol=1e-15)
        assert np.sqrt(np.mean(want[i][f] ** 2)) > 1e-3   # the fisheye bends its lines
    assert (b[2] == 0).all()
    # the two biases differ in sign (lines fitted straight through the corner)
    f = obs.found[0]
    free = corner_bias(truth, t, Rts[0], obs.p_board[0])[f]
    assert (want[0][f] * free).sum() < 0


def test_only_the_marked_squares_corners_keep_the_dots_clearance():
    r'''chessboard_clearance per corner: the four corners of each marked square are 0.5 - r /
sqrt(2) squares from its dot along the box's axes (r the dot's radius in squares), every
other corner a square from the next one; corner_rays hands the same to the bias model'''
    from targets.corners import CHESSBOARD_CLEARANCE, chessboard_clearance, corner_rays
    t = load_target("chessboard")
    nx, ny = t.grid_shape
    c = chessboard_clearance(t)
    assert c.shape == (nx * ny,)
    r = 0.5 * t.spec["orientation_mark"]["dot_diameter"] / t.spec["square"]
    near = np.zeros((ny, nx), bool)
    for sx, sy in t.spec["orientation_mark"]["squares"]:
        near[sy - 1:sy + 1, sx - 1:sx + 1] = True       # corners (sx-1..sx, sy-1..sy)
    near = near.ravel()
    assert np.allclose(c[near], 0.5 - r / np.sqrt(2.0), rtol=0, atol=1e-15)
    assert (c[~near] == CHESSBOARD_CLEARANCE).all()
    assert near.sum() == 4 * len(t.spec["orientation_mark"]["squares"])
    # the corners' board positions: each near corner is a corner of a marked square
    p = t.points()[near, :2] / t.spec["square"]
    centres = np.array(t.spec["orientation_mark"]["squares"], dtype=float) - 0.5
    assert np.isclose(np.abs(p[:, None] - centres[None]).max(-1), 0.5).any(-1).all()
    assert np.array_equal(corner_rays(t)[3]["clearance"], c)


def test_line_strips_follow_the_blur_and_the_squares():
    r'''The strips a blurred X junction's window adds along its lines: as long as the
sharp window's MAX_WINDOW_PX in edge information (x sigma_e / sqrt(1/12): 22 px at the
realistic 0.7 px, whose sampled kernel adds 0.755 px: a pixel-integrated Gaussian),
STRIP_SIGMAS edge-profile sigmas wide, and a square less the next line's blur reach and
LINES_SLACK long in board units; a bent line's strips end where a straight line's mean
offset over them, kappa L^2 / 6, reaches LINES_BIAS_PX, none where that is in the box'''
    from targets.corners import (
        LINES_BIAS_PX,
        LINES_SLACK,
        MAX_WINDOW_PX,
        STRIP_SIGMAS,
        line_strips,
    )
    steps = np.array([[[44.0, 3.0], [-2.0, 40.0]]])
    box, strip, reach = line_strips(steps, 1.0, 0.7, 0.0)
    se = np.sqrt(added_blur_px(0.7, "sampled") ** 2 + 1.0 / 12.0)
    assert 0.75 < added_blur_px(0.7, "sampled") < 0.76
    assert reach == pytest.approx(MAX_WINDOW_PX * se * np.sqrt(12.0), rel=1e-12)
    assert 22.0 < reach < 22.8
    assert strip == pytest.approx(STRIP_SIGMAS * se, rel=1e-12)
    smin = np.linalg.svd(steps[0], compute_uv=False)[-1]
    assert box[0] == pytest.approx(1.0 - 3.0 * 0.7 / smin - LINES_SLACK, rel=1e-12)
    # a bent line's strips end where the next order of their bias, kappa^2 L^3, reaches
    # LINES_BIAS_PX: not by the curvature below that
    steps4 = np.repeat(steps, 4, axis=0)
    box, _, reach = line_strips(steps4, 1.0, 0.7, [2e-5, 2e-4, 1e-3, np.nan])
    assert reach[0] == pytest.approx(MAX_WINDOW_PX * se * np.sqrt(12.0), rel=1e-12)
    assert (2e-4) ** 2 * reach[1] ** 3 == pytest.approx(LINES_BIAS_PX)    # 17.1 px
    assert reach[2] == 0.0 and np.isnan(box[2])     # 5.8 px: within the box
    assert reach[3] == 0.0 and np.isnan(box[3])


def test_bent_lines_strips_are_predicted_by_the_lines_bias():
    r'''A blurred X junction on lines bent by 2e-4 / px (a 5120x3840 CAHVORE's, camera 1)
on squares of 60 px: its window holds strips of ~17 px (line_strips' cap) past the box,
where a straight line fitted over them moves by ~kappa L^2 / 6 ~ 0.01 px, and
curvature_bias with the same strips predicts the corner's shift to LINES_BIAS_PX (its
next order, kappa^2 L^3) plus the render's own error (S = 32 subsamples: ~1e-4 px on
the box, tests above)'''
    from targets.corners import (
        CHESSBOARD_HALF_BOX,
        CHESSBOARD_LINES,
        LINES_BIAS_PX,
        curvature_bias,
        refine_corners,
    )
    k = 2e-4
    c = np.array([55.37, 56.81])
    img, u1, u2 = _bent_x(c, np.radians(11.0), k, -k, size=112)
    blurred = ResponseChain.from_config({"psf": {"kind": "gaussian", "sigma_px": 0.7}}) \
        .apply(img).image.astype(np.float64)
    tangents = np.stack((u1, u2, -u1, -u2))[None]
    curv = np.array([[k, -k, -k, k]])
    steps = (60.0 * np.stack((u1, u2), -1))[None]
    sigma = x_junction_blur(0.7, "gaussian")
    fit = refine_corners(blurred, c[None] + 0.2, tangents, [(0, 1), (2, 3)], steps,
                         CHESSBOARD_HALF_BOX, clearance=1.0, lines=CHESSBOARD_LINES,
                         psf_sigma_px=sigma, psf_kind="sampled",
                         line_curvature=lambda q: np.full(len(q), k))
    assert fit.npixels[0] > 289 + 4 * 8 * 2, fit.npixels[0]       # the box and the strips
    b = curvature_bias(c[None], tangents, curv, [(0, 1), (2, 3)], steps, CHESSBOARD_HALF_BOX,
                       lines=CHESSBOARD_LINES, sigma=sigma, clearance=1.0)[0]
    shift = fit.q[0] - c
    assert 0.005 < np.linalg.norm(b) < 0.03, b
    assert np.linalg.norm(shift - b) < LINES_BIAS_PX + 2e-4, (shift, b)


def test_grid_curvature_at_the_lines_ends_is_extrapolated():
    r'''The curvature of a grid line at its end corners (no neighbour beyond them) is the
next two corners' extrapolated: on a line whose curvature changes along it (a parabola
y = a x^2 sampled every 50 px, its curvature falling 6x along it), within 3% of the curve's
own (measured 1.3% and 2.6%) where the next corner's copy is 7% and 16% off'''
    from targets.corners import _grid_curvature
    a = 1e-3
    x = 50.0 * np.arange(10) + 100.0
    G = np.stack((x, a * x * x), -1)[None]                      # (1, 10, 2): one line
    k = _grid_curvature(G, axis=1)[0]
    exact = 2 * a / (1 + (2 * a * x) ** 2) ** 1.5
    assert np.all(np.abs(k[1:-1] / exact[1:-1] - 1) < 0.02)
    assert np.all(np.abs(k[[0, -1]] / exact[[0, -1]] - 1) < 0.03), k / exact - 1
    assert np.all(np.abs(k[[1, -2]] / exact[[0, -1]] - 1) > 0.05)


def test_blurred_corner_window_holds_its_line_strips():
    r'''On squares of 44 px (a navcam's) the blurred fit's window reaches along straight
lines past the MAX_WINDOW_PX box ((2 x 8 + 1)^2 = 289 pixels at most): the box's pixels
plus four strips of ~14 px (22 - 8) by ~3 px; noise-free, the corner is where it is (the
model is exact for the sampled kernel: 2e-3 px, as on 19 px squares). Without the lines'
curvature (refine_chessboard_corners takes it from the first pass's grid, NaN where a
neighbour is missing, as here) the box alone'''
    from targets.corners import CHESSBOARD_HALF_BOX, CHESSBOARD_LINES, refine_corners
    img, q, dirs, steps = _chessboard_corner_image(0.7, "sampled", seed=None, size=100,
                                                   c=(49.37, 50.81))
    steps = steps * (44.0 / 19.0)
    args = (img, q + 0.2, dirs, [(0, 1), (2, 3)], steps, CHESSBOARD_HALF_BOX)
    opts = dict(clearance=1.0, lines=CHESSBOARD_LINES, psf_sigma_px=0.7, psf_kind="sampled")
    fit = refine_corners(*args, line_curvature=lambda q: np.zeros(len(q)), **opts)
    assert 289 + 4 * 13 * 2 < fit.npixels[0] < 289 + 4 * 15 * 5, fit.npixels[0]
    assert np.linalg.norm(fit.q[0] - q[0]) < 2e-3
    box = refine_corners(*args, **opts)
    assert box.npixels[0] <= 289
    assert np.linalg.norm(box.q[0] - q[0]) < 2e-3


def test_blurred_board_lost_to_the_equalisation_is_found_without_it():
    r'''The constructed fisheye campaigns/cameras/eye-1024x768.cahvore (CAHVORE), the second
planned pose (a foreshortened board near the image's top-left rim, 78% of the pixels dark
background) under the realistic profile's PSF alone (Gaussian sigma 0.7 px, no noise: the
image is the same on every machine): OpenCV's quad-based search with its histogram
equalisation (CLASSIC_FLAGS) finds no board, the same search on the image as it is does
(CLASSIC_PLAIN_FLAGS); every corner is kept and refined, as close to the exact
projections as the first pose's (measured 0.023 px RMS both: the K = 4 numpy render's
sampling error and the fisheye's curvature bias, which the calibrators correct)'''
    import cv2
    from targets_render import render

    from harness.stages import camera_truth
    from targets.detect_chessboard import CLASSIC_FLAGS, CLASSIC_PLAIN, CLASSIC_PLAIN_FLAGS
    from targets.detection import working_image

    _, m = camera_truth("campaigns/cameras/eye-1024x768.cahvore", "CAHVORE")
    t = load_target("chessboard")
    blur = ResponseChain.from_config({"psf": {"kind": "gaussian", "sigma_px": 0.7}})
    poses = plan_poses(m, t, n=6, seed=0)[:2]
    rms = []
    for i, Rt in enumerate(poses):
        img = blur.apply(render(m, t.pattern(), Rt, K=4)).image
        img8 = working_image(img)[1]
        nx, ny = t.grid_shape
        if i == 1:
            assert not cv2.findChessboardCorners(img8, (nx, ny), flags=CLASSIC_FLAGS)[0]
            assert cv2.findChessboardCorners(img8, (nx, ny), flags=CLASSIC_PLAIN_FLAGS)[0]
        det = detect(img, t)
        assert det.status == "ok", det.reason
        assert det.info["method"] == ("findChessboardCorners", CLASSIC_PLAIN)[i]
        assert det.found.all() and det.info["corners_dropped"] == {}
        e = np.linalg.norm(det.q - projected_points(m, t, Rt), axis=-1)
        rms.append(np.sqrt(np.mean(e ** 2)))
    assert rms[1] < 0.03 and rms[1] < 1.5 * rms[0], rms

r'''Detectors on rendered targets: exact dot centroids, numbering, tags, chessboards, bad input

The fast tests render with tests/targets_render.py (plain numpy supersampling,
independent of renderers/); the slow one renders every planned pose of the
1024x1024 catalogue cameras with the ray-cast renderer.
'''

import math

import numpy as np
import pytest
from targets_render import pinhole, render

from reference_models.cahvore import CAHV
from targets.boards import load_target, target_from_dict
from targets.centroids import expected_centroids, projected_points
from targets.detect import detect
from targets.detection import DetectionInputError
from targets.poses import plan_poses

# a distorted wide-ish camera small enough to render in numpy
WIDE = dict(width=320, height=240, f=220.0, R=[0.0, -0.08, 0.01])


def _Rt(rx_deg, ry_deg, t):
    ax, ay = math.radians(rx_deg), math.radians(ry_deg)
    Rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    Ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    return np.vstack((Ry @ Rx, t))


@pytest.fixture(scope="module")
def dots():
    return load_target("dots")


def _single_dot(d=0.04):
    # the board covers the whole image, so the dot sits on a uniform board
    return target_from_dict({"kind": "dots", "nx": 1, "ny": 1, "spacing": 0.1,
                             "dot_diameter": d, "margin": 2.0})


@pytest.mark.parametrize("R", [None, [0.0, -0.1, 0.02]], ids=["CAHV", "CAHVOR"])
def test_single_dot_centroid_is_exact(R):
    r'''Proves the pixel convention: a tilted dot, off-centre, 20 px in radius, 32x32
supersampled: the detected centroid is the exact expected centroid to 1e-3 px, and that
differs from the projected centre by far more'''
    m = pinhole(96, 96, 200.0, R=R)
    t = _single_dot()
    Rt = _Rt(30, 0, [0.013, -0.007, 0.2])
    det = detect(render(m, t.pattern(), Rt, K=32), t)
    assert det.status == "ok" and det.n_found == 1 and det.n_expected == 1
    q = expected_centroids(m, t, Rt)
    assert np.abs(det.q - q).max() < 1e-3
    assert np.linalg.norm(q - projected_points(m, t, Rt)) > 0.3
    # a half-pixel convention slip is 500 times the tolerance
    assert np.all(np.abs(det.q - (q + 0.5)) > 0.4)


def _check_dots(m, t, Rt, K=8, tol=0.03):
    img = render(m, t.pattern(), Rt, K=K)
    det = detect(img, t)
    assert det.status == "ok", det.reason
    assert det.n_found == det.n_expected == 100
    err = np.linalg.norm(det.q - expected_centroids(m, t, Rt), axis=-1)
    # a wrong numbering would put dots 0.1 m (many pixels) off
    assert err.max() < tol, err.max()
    return det


def test_dots_on_planned_poses(dots):
    m = pinhole(WIDE["width"], WIDE["height"], WIDE["f"], R=WIDE["R"])
    for Rt in plan_poses(m, dots, seed=0):
        _check_dots(m, dots, Rt)


def test_dots_through_a_mirrored_camera(dots):
    r'''H -> -H mirrors the image: only the orientation mark can number the grid right'''
    m = _mirrored_camera(320, 240, 220.0)
    assert m.mirrored
    poses = plan_poses(m, dots, seed=2)
    for Rt in poses[:3]:
        det = _check_dots(m, dots, Rt)
        assert det.info["transform"] is not None


def test_dots_rotated_in_plane(dots):
    m = pinhole(320, 320, 250.0)
    c = dots.centre()
    for angle in (90.0, 180.0, 270.0):
        a = math.radians(angle + 3.0)
        R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
        Rt = np.vstack((R, [0, 0, 2.0] - R @ c))
        _check_dots(m, dots, Rt)


def test_dots_partly_out_of_view(dots):
    r'''Part of the grid outside the image: the dots seen are numbered right (the mark is
in view), the result says how many'''
    m = pinhole(320, 240, 220.0)
    Rt = np.vstack((np.eye(3), [-0.4, -0.26, 0.8]))
    det = detect(render(m, dots.pattern(), Rt, K=4), dots)
    assert det.status == "failed" and "found" in det.reason
    assert 40 < det.n_found < 100
    exp = expected_centroids(m, dots, Rt)
    assert np.nanmax(np.linalg.norm(det.q - exp, axis=-1)) < 0.05
    ok = detect(render(m, dots.pattern(), Rt, K=4), dots, min_found=40)
    assert ok.status == "ok" and ok.n_found == det.n_found


def test_apriltags_decoded_with_the_right_ids():
    t = load_target("apriltag")
    m = pinhole(480, 360, 300.0, R=WIDE["R"])
    for Rt in plan_poses(m, t, seed=0):
        # tag bits of 3-4 px: too small a window for the corner model (targets.corners),
        # which drops such corners; the decoding and numbering are checked on the tags' own
        det = detect(render(m, t.pattern(), Rt, K=4), t, refine=False)
        assert det.status == "ok", det.reason
        assert det.n_expected == 144
        # every tag whole in the image (the board overflows it where the planner keeps a
        # central sub-grid in view: targets.poses.tag_bit_need_px), and only tags in it
        q = projected_points(m, t, Rt).reshape(-1, 4, 2)
        inside = np.all((q >= 0.5) & (q <= np.array([m.width, m.height]) - 1.5), axis=(1, 2))
        touching = np.any((q >= -0.5) & (q <= np.array([m.width, m.height]) - 0.5), axis=(1, 2))
        found = np.isfinite(det.q).all(axis=1).reshape(-1, 4).all(axis=1)
        assert np.all(found[inside]) and not np.any(found[~touching])
        assert det.info["Ntags_decoded"] == found.sum() >= 16
        err = np.linalg.norm(det.q - projected_points(m, t, Rt), axis=-1)
        # right ids and corner order (a wrong one is a tag or more away), convention shifted
        assert np.nanmax(err) < 0.6 and np.sqrt(np.nanmean(err ** 2)) < 0.25


def _mirrored_camera(W, H, f):
    A = np.array([0.0, 0.0, 1.0])
    return CAHV(C=np.zeros(3), A=A, H=np.array([-f, 0, 0]) + (W - 1) / 2 * A,
                V=np.array([0, f, 0]) + (H - 1) / 2 * A, width=W, height=H)


def test_apriltags_through_a_mirrored_camera():
    t = load_target("apriltag")
    m = _mirrored_camera(480, 360, 300.0)
    Rt = plan_poses(m, t, seed=0)[0]
    det = detect(render(m, t.pattern(), Rt, K=4), t)
    assert det.status == "ok" and det.info["mirrored"]
    # corners of tags with bits under ~5 px are dropped by the corner model, with a reason
    assert det.n_found + sum(det.info["corners_dropped"].values()) == 144
    assert det.n_found > 100
    assert np.nanmax(np.linalg.norm(det.q - projected_points(m, t, Rt), axis=-1)) < 0.6


def test_chessboard_on_planned_poses():
    r'''Every planned pose's 100 corners found on a distorted pinhole's renders of K = 16.
(K = 4 until session 19: since then the poses are planned by the corners, nearer, and the
windows reach 0.8 square, and on pose 5 one corner's aliasing misfit at K = 4 puts its
predicted error at 3.05 x the image's median: targets.corners drops it, "predicted error
too large", its cut for a noisy image; the mirrored camera's pose 5 drops 2 at K = 4, 1 at
K = 8)'''
    t = load_target("chessboard")
    m = pinhole(480, 360, 300.0, R=WIDE["R"])
    for Rt in plan_poses(m, t, seed=0):
        det = detect(render(m, t.pattern(), Rt, K=16), t)
        assert det.status == "ok", det.reason
        assert det.n_found == det.n_expected == 100
        err = np.linalg.norm(det.q - projected_points(m, t, Rt), axis=-1)
        assert err.max() < 0.35 and np.sqrt(np.mean(err ** 2)) < 0.15


@pytest.mark.slow
def test_chessboard_on_a_large_image():
    r'''Large images: OpenCV's quad-based search finds the board first; without it the
sector-based search runs at reduced size (here 1/3); both are polished at full size'''
    from targets.detect_chessboard import detect_chessboard
    t = load_target("chessboard")
    m = pinhole(1600, 1200, 1000.0)
    Rt = plan_poses(m, t, seed=0)[2]
    img = render(m, t.pattern(), Rt, K=2)
    for det, method in ((detect(img, t), "findChessboardCorners"),
                        (detect_chessboard(img, t, classic_first=False),
                         "findChessboardCornersSB at 1/3 size")):
        assert det.status == "ok" and det.n_found == 100
        assert det.info["method"] == method
        err = np.linalg.norm(det.q - projected_points(m, t, Rt), axis=-1)
        # K = 2 only (a numpy render of 2 Mpx): coarser than the K = 4 tests
        assert err.max() < 0.5 and np.sqrt(np.mean(err ** 2)) < 0.15


def test_chessboard_corner_off_its_saddle_is_caught():
    r'''A corner moved onto a plain square fails the saddle check (the reduced-size search
produced one, 7.9 px off, on a fisheye; the detector then searches at full size)'''
    from targets.detect_chessboard import _is_saddle
    t = load_target("chessboard")
    m = pinhole(480, 360, 300.0)
    Rt = plan_poses(m, t, seed=0)[0]
    img = render(m, t.pattern(), Rt, K=4)
    G = projected_points(m, t, Rt).reshape(10, 10, 2)
    assert _is_saddle(img, G).all()
    step = np.linalg.norm(G[4, 5] - G[4, 4])
    G[4, 4] += 0.35 * step * (G[5, 5] - G[4, 4]) / np.linalg.norm(G[5, 5] - G[4, 4])
    ok = _is_saddle(img, G)
    assert not ok[4, 4] and ok.sum() == 99


def test_chessboard_keeps_the_corners_it_could_refine():
    r'''A corner blurred out (a smudge on the lens) is dropped with its reason; the other 99
stay, as exact as on the clean image, and the detection is ok'''
    from scipy.ndimage import gaussian_filter
    t = load_target("chessboard")
    m = pinhole(480, 360, 300.0, R=WIDE["R"])
    Rt = plan_poses(m, t, seed=0)[0]
    img = render(m, t.pattern(), Rt, K=4)
    truth = projected_points(m, t, Rt)
    x, y = np.round(truth[44]).astype(int)
    blurred = img.copy()
    # sigma 3 px over a 9 px box: the corner model's edges cannot fit it (misfit), while
    # OpenCV still finds the board
    blurred[y - 4:y + 5, x - 4:x + 5] = gaussian_filter(img, 3.0)[y - 4:y + 5, x - 4:x + 5]
    det = detect(blurred, t)
    assert det.status == "ok", det.reason
    assert not det.found[44] and det.n_found == 99
    assert sum(det.info["corners_dropped"].values()) == 1
    clean = detect(img, t)
    assert clean.n_found == 100 and clean.info["corners_dropped"] == {}
    # the kept corners are the clean image's (their windows, <= 8 px, miss the smudge
    # except the 8 neighbours, which sit a full square (~20 px) away)
    keep = det.found
    np.testing.assert_allclose(det.q[keep], clean.q[keep], atol=0.02)


def test_chessboard_found_but_every_corner_dropped_says_so(monkeypatch):
    r'''A board OpenCV finds whose corners the refiner cannot refine (squares of ~8 px on a
160x120 image, every window made too small by asking 100 pixels per unknown of its fit:
the windows of 0.45 square, 9-16 pixels, determine their 8 unknowns and are kept
otherwise) fails with a reason that says the board was found and why its corners went,
not only "found 0 of 100 points" (a campaign record keeps one image's reason, which read
as a board not found)'''
    import targets.corners
    monkeypatch.setattr(targets.corners, "WINDOW_PIXELS_PER_UNKNOWN", 100)
    t = load_target("chessboard")
    m = pinhole(160, 120, 135.0)
    det = detect(render(m, t.pattern(), plan_poses(m, t, seed=0)[0], K=4), t)
    assert det.status == "failed" and det.n_found == 0
    assert "chessboard was found" in det.reason
    assert "100 window too small" in det.reason
    assert det.info["corners_dropped"] == {"window too small": 100}


def test_chessboard_corners_on_one_line_give_no_view():
    r'''What a view's pose needs (targets.detection.MIN_POINTS_FOR_POSE): 4 corners, not on
one line of the board'''
    from targets.detection import result
    t = load_target("chessboard")
    q = projected_points(pinhole(480, 360, 300.0), t, plan_poses(pinhole(480, 360, 300.0),
                                                                   t, seed=0)[0])
    row = np.full_like(q, np.nan)
    row[:10] = q[:10]             # the first row of corners only
    d = result(t, row, "chessboard", min_found=4)
    assert d.status == "failed" and "one line" in d.reason
    row[15] = q[15]
    assert result(t, row, "chessboard", min_found=4).status == "ok"
    three = np.full_like(q, np.nan)
    three[[0, 1, 10]] = q[[0, 1, 10]]
    assert "need 4" in result(t, three, "chessboard", min_found=4).reason


def test_chessboard_mirrored_is_numbered_by_the_mark():
    t = load_target("chessboard")
    m = _mirrored_camera(480, 360, 300.0)
    Rt = plan_poses(m, t, seed=0)[5]
    # K = 16: at K = 4 (8) the aliasing drops 2 (1) corners (test_chessboard_on_planned_poses)
    det = detect(render(m, t.pattern(), Rt, K=16), t)
    assert det.status == "ok" and det.n_found == 100
    err = np.linalg.norm(det.q - projected_points(m, t, Rt), axis=-1)
    assert err.max() < 0.35


def test_dots_with_noise_and_vignetting(dots):
    r'''2 DN of noise and a 50 % vignette: every dot found; the local board plane keeps
the shading from biasing the centroids (plain board-level weights: 0.025 px RMS)'''
    m = pinhole(WIDE["width"], WIDE["height"], WIDE["f"], R=WIDE["R"])
    Rt = plan_poses(m, dots)[0]
    img = render(m, dots.pattern(), Rt, K=8)
    H, W = img.shape
    yy, xx = np.mgrid[0:H, 0:W]
    vignette = 1 - 0.5 * ((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / ((W / 2) ** 2 + (H / 2) ** 2)
    exp = expected_centroids(m, dots, Rt)
    clean = np.linalg.norm(detect(img, dots).q - exp, axis=-1)
    det = detect(img * vignette, dots)
    assert det.status == "ok" and det.n_found == 100
    shaded = np.linalg.norm(det.q - exp, axis=-1)
    assert np.sqrt(np.mean(shaded ** 2)) < 1.2 * np.sqrt(np.mean(clean ** 2)) + 1e-4
    noisy = img * vignette + np.random.default_rng(1).normal(0, 2 / 255, img.shape)
    det = detect(np.clip(noisy, 0, 1), dots)
    assert det.status == "ok" and det.n_found == 100
    assert np.sqrt(np.mean(np.sum((det.q - exp) ** 2, axis=-1))) < 0.015


def test_uint8_input(dots):
    m = pinhole(WIDE["width"], WIDE["height"], WIDE["f"], R=WIDE["R"])
    Rt = plan_poses(m, dots)[0]
    img = render(m, dots.pattern(), Rt, K=8)
    det = detect(np.round(img * 255).astype(np.uint8), dots)
    assert det.status == "ok" and det.n_found == 100
    assert np.abs(det.q - expected_centroids(m, dots, Rt)).max() < 0.05


@pytest.mark.parametrize("name", ["dots", "apriltag", "chessboard"])
def test_not_found_is_a_result(name):
    t = load_target(name)
    m = pinhole(160, 120, 120.0)
    blank = np.full((120, 160), 0.5)
    behind = render(m, t.pattern(), _Rt(0, 0, [-0.5, -0.5, -1.0]), K=1)
    noise = np.random.default_rng(0).uniform(size=(120, 160))
    nan = blank.copy()
    nan[3, 4] = np.nan
    for img in (blank, behind, noise, nan):
        det = detect(img, t)
        assert det.status == "failed" and det.reason and det.n_found == 0
        assert det.q.shape == (t.Npoints, 2) and np.all(np.isnan(det.q))
        assert det.n_expected == t.Npoints
        det.as_dict()


def test_chessboard_not_found_names_the_searches():
    r'''A view without a board fails with each OpenCV search it tried in its reason (a
campaign record keeps it): the quad-based one with and without equalisation, then the
sector-based one (its reduced-size first try only on images 800 px or more)'''
    from targets.detect_chessboard import CLASSIC_PLAIN
    t = load_target("chessboard")
    for H, W in ((120, 160), (800, 1000)):
        noise = np.random.default_rng(0).uniform(size=(H, W))
        det = detect(noise, t)
        assert det.status == "failed"
        tried = ["findChessboardCorners", CLASSIC_PLAIN] + \
            ["findChessboardCornersSB at 1/2 size"] * (H >= 800) + ["findChessboardCornersSB"]
        assert det.info["searches"] == tried
        assert det.reason == f"OpenCV found no 10x10 chessboard ({', '.join(tried)})"


def test_wrong_target_in_the_image():
    m = pinhole(320, 240, 220.0)
    chess = load_target("chessboard")
    img = render(m, chess.pattern(), plan_poses(m, chess)[0], K=2)
    det = detect(img, load_target("dots"))
    assert det.status == "failed" and det.reason


def test_target_too_large_for_the_image(dots):
    # the board overflows the image on every side: no dot grid with its mark
    m = pinhole(160, 120, 400.0)
    det = detect(render(m, dots.pattern(), _Rt(0, 0, [-0.45, -0.45, 1.0]), K=2), dots)
    assert det.status == "failed" and det.n_found < 100


def test_not_an_image():
    t = load_target("dots")
    for bad in (np.zeros(10), np.zeros((2, 3, 5)), np.zeros((10, 10), np.int32)):
        with pytest.raises(DetectionInputError):
            detect(bad, t)
    with pytest.raises(DetectionInputError, match="no detector"):
        detect(np.zeros((10, 10)), object())


@pytest.mark.slow
@pytest.mark.parametrize("name", ["dots", "apriltag", "chessboard"])
def test_every_planned_pose_of_the_1024_cameras(catalogue, name):
    r'''Ray-cast renders (K=4, adaptive) of every planned pose of every 1024x1024 catalogue
camera: every target found with all its points, dots at their exact centroids'''
    from renderers.base import RenderSettings, get_renderer

    renderer = get_renderer("raycast")
    t = load_target(name)
    for entry in catalogue.entries():
        m = entry.model
        if (m.width, m.height) != (1024, 1024):
            continue
        for i, Rt in enumerate(plan_poses(m, t)):
            img = renderer.render(m, t.pattern(), Rt, RenderSettings(spp=4)).image
            det = detect(img, t)
            where = f"{entry.key} pose {i}: {det.reason}"
            dropped = sum(det.info.get("corners_dropped", {}).values())
            assert det.status == "ok" and det.n_found + dropped == det.n_expected, where
            assert dropped <= det.n_expected // 20, where
            truth = (expected_centroids(m, t, Rt) if name == "dots"
                     else projected_points(m, t, Rt))
            err = np.linalg.norm(det.q - truth, axis=-1)
            assert np.nanmax(err) < {"dots": 0.05, "apriltag": 1.0, "chessboard": 0.5}[name], where


@pytest.mark.parametrize("reduction", [2, 4])
@pytest.mark.parametrize("dtype", ["float32", "uint8"])
def test_large_image_path_gives_the_full_labelling(dots, monkeypatch, dtype, reduction):
    r'''Above LARGE_IMAGE_PIXELS the blobs are located in a reduced image and labelled in
their boxes: the dots, their centroids and the numbering are bit for bit those of the full
labelling. The threshold is lowered here so that a 320x240 render takes that path (a
reduction of 4, the compiled reduction targets._dot_kernels.reduce4_and_subsample: 640x480,
whose dots keep the reduced image's size of those of 320x240 reduced twice).'''
    from targets import detect_dots as dd
    k = reduction // 2
    m = pinhole(k * WIDE["width"], k * WIDE["height"], k * WIDE["f"], R=WIDE["R"])
    Rt = plan_poses(m, dots, seed=0)[0]
    img = render(m, dots.pattern(), Rt, K=4).astype(np.float32)
    if dtype == "uint8":
        img = np.round(img * 255).astype(np.uint8)
    full = detect(img, dots)
    monkeypatch.setattr(dd, "LARGE_IMAGE_PIXELS", 1000)
    monkeypatch.setattr(dd, "REDUCTION", reduction)
    calls = []
    real = dd._blobs_from_reduced
    monkeypatch.setattr(dd, "_blobs_from_reduced",
                        lambda *a: calls.append(real(*a)) or calls[-1])
    fast = detect(img, dots)
    assert calls and calls[0] is not None        # the reduced path ran and was used
    assert full.status == fast.status == "ok"
    assert fast.n_found == full.n_found == 100
    assert np.array_equal(fast.q, full.q)


def test_large_image_path_falls_back_when_the_reduction_hides_the_dots(monkeypatch, dots):
    r'''Dots too small for the reduction: the full image is labelled, nothing is lost'''
    from targets import detect_dots as dd
    m = pinhole(WIDE["width"], WIDE["height"], WIDE["f"], R=WIDE["R"])
    Rt = plan_poses(m, dots, seed=0)[0]
    img = render(m, dots.pattern(), Rt, K=4)
    monkeypatch.setattr(dd, "LARGE_IMAGE_PIXELS", 1000)
    monkeypatch.setattr(dd, "REDUCTION", 64)
    assert dd._blobs_from_reduced(img.astype(np.float32), 0.5, 64) is None
    det = detect(img, dots)
    assert det.status == "ok" and det.n_found == 100


def test_apriltag_quad_decimation_keeps_a_1024_px_image():
    r'''The quad search is decimated only as far as a 1024 px image (the size at which the
catalogue's 1024x1024 cameras decode every tag of their planned poses undecimated)'''
    from targets.detect_apriltag import DECIMATED_MIN_SIDE_PX, decimate_for
    for shape, k in (((480, 640), 1), ((1024, 1024), 1), ((1200, 1648), 1),
                     ((2048, 2048), 2), ((3840, 5120), 3)):
        assert decimate_for(shape) == k
        assert min(shape) // k >= DECIMATED_MIN_SIDE_PX or k == 1


def _large_tag_image(pose, distance_scale):
    r'''(image, target): the ray caster's render of the AprilTag grid through a 2048x2048
camera (decimate_for 2) at planned pose `pose` moved distance_scale times as far'''
    from renderers.base import RenderSettings, get_renderer
    t = load_target("apriltag")
    m = pinhole(2048, 2048, 1600.0, R=WIDE["R"])
    Rt = plan_poses(m, t, seed=0)[pose].copy()
    Rt[3] *= distance_scale
    return get_renderer("raycast").render(m, t.pattern(), Rt, RenderSettings(spp=16)).image, t


def test_apriltag_quads_of_a_large_image_searched_coarser_when_no_tag_is_missed():
    r'''A 2048x2048 image whose 36 tags (bits of 22 px and more) all decode in the quad
search decimated by 4: that search is kept, and the refined corners are those of the
search decimated by 2 (the corner fit starts from the coarse corners and stops at a step
below CONVERGED_PX, 1e-4 px: the two starts end within that; measured 5e-7 px)'''
    from targets.detect_apriltag import TRIAL_DECIMATION_FACTOR, decimate_for
    img, t = _large_tag_image(0, 1.0)
    det = detect(img, t)
    fine = detect(img, t, quad_decimate=decimate_for(img.shape))
    assert det.info["quad_decimate"] == TRIAL_DECIMATION_FACTOR * decimate_for(img.shape) == 4
    assert det.status == fine.status == "ok" and det.n_found == fine.n_found == 144
    assert np.array_equal(det.found, fine.found)
    assert np.max(np.abs(det.q - fine.q)[det.found]) < 1e-4


def test_apriltag_quads_of_a_large_image_searched_again_when_tags_are_missed():
    r'''A tilted board far away (tag bits down to 3.7 px): the search decimated by 4 decodes
a few of its tags only, so the search decimated by decimate_for's 2 gives the detection,
the one that decimation gives when asked for'''
    img, t = _large_tag_image(3, 3.0)
    coarse = detect(img, t, quad_decimate=4, refine=False)
    assert coarse.info["Ntags_decoded"] < 36
    det = detect(img, t)
    fine = detect(img, t, quad_decimate=2)
    assert det.info["quad_decimate"] == 2 and det.info["Ntags_decoded"] == 36
    assert det.n_found == fine.n_found and np.array_equal(det.q, fine.q, equal_nan=True)


def test_search_complete_needs_every_tag_or_tags_twice_the_smallest_searchable():
    from targets.detect_apriltag import MIN_DECIMATED_BIT_PX, Tag, _search_complete
    index = {4 * i + k: 4 * i + k for i in range(4) for k in range(4)}

    def tag(i, side, hamming=0):
        return Tag(i, hamming, np.array([[0, 0], [side, 0], [side, side], [0, side]], float))
    # every tag of the board, however small
    assert _search_complete([tag(i, 8.0) for i in range(4)], index, 4, 1)
    # one missing: the decoded ones must keep 2 x MIN_DECIMATED_BIT_PX decimated px a bit
    big = 8 * 2 * MIN_DECIMATED_BIT_PX * 4
    assert _search_complete([tag(i, big) for i in range(3)], index, 4, 1)
    assert not _search_complete([tag(i, 0.99 * big) for i in range(3)], index, 4, 1)
    # a tag beyond max_hamming or off the board does not count
    assert not _search_complete([tag(0, 8.0), tag(1, 8.0), tag(2, 8.0), tag(3, 8.0, 2)],
                                index, 4, 1)
    assert not _search_complete([tag(9, big)], index, 4, 1)


def test_mark_flags_follow_perspective_on_the_lattice_edge():
    # a board seen obliquely through a wide lens: blob areas fall 1.41x a row (measured
    # on a hazcam render whose detection failed), marks 1.96x their row (the dot target's
    # 0.07 m mark over 0.05 m dots, squared). The median of an edge dot's inward
    # neighbours put the whole front row above the 1.4 threshold; the log-area plane
    # over the neighbourhood extrapolates it.
    from targets.detect_dots import mark_flags
    marks = {(2, 2), (6, 2), (2, 5)}
    nodes, area = {}, []
    for ia in range(10):
        for ib in range(10):
            nodes[(ib, ia)] = len(area)
            area.append(1100.0 / 1.41 ** ia * (1.96 if (ib, ia) in marks else 1.0)
                        * (1 + 0.01 * np.sin(7 * ia + 3 * ib)))   # +-1 % blob noise
    flags = mark_flags(nodes, np.array(area), 0.07 / 0.05)
    assert {k for k, j in nodes.items() if flags[j]} == marks


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_working_image_is_the_rounded_clipped_image(dtype):
    # the detectors' uint8 copy is round-half-to-even(255 * clip(img, 0, 1)) computed in the
    # image's own float type (numpy's round of the same product): exact integers, so equal,
    # including pixels exactly half-way between two levels, below 0 and above 1
    from targets.detection import working_image
    rng = np.random.default_rng(3)
    img = rng.uniform(-0.3, 1.3, (37, 53)).astype(dtype)
    levels = (np.repeat(np.arange(256), 3) + np.tile([-0.5, 0.0, 0.5], 256)) / 255.0
    img.flat[:len(levels)] = levels.astype(dtype)
    work, img8, (lo, hi) = working_image(img)
    assert work.dtype == dtype
    want = np.round(dtype(255.0) * np.clip(img, dtype(0.0), dtype(1.0)))
    assert np.array_equal(img8, want.astype(np.uint8))
    assert (lo, hi) == (float(img.min()), float(img.max()))
    for bad in (np.nan, np.inf, -np.inf):
        img[20, 30] = bad
        assert working_image(img) is None


def test_a_float32_render_is_detected_as_its_float64_copy(dots):
    r'''A small float32 image (what the renderers give) is read as float64 where the
detector computes, not converted as a whole: the same dots, numbering and centroids as
its float64 copy, bit for bit (the float64 copy holds the same values), noisy too'''
    m = pinhole(WIDE["width"], WIDE["height"], WIDE["f"], R=WIDE["R"])
    Rt = plan_poses(m, dots)[0]
    img = render(m, dots.pattern(), Rt, K=4)
    noisy = np.clip(img + np.random.default_rng(2).normal(0, 2 / 255, img.shape), 0, 1)
    for im in (img.astype(np.float32), noisy.astype(np.float32)):
        a, b = detect(im, dots), detect(im.astype(np.float64), dots)
        assert a.status == b.status == "ok" and a.n_found == 100
        assert a.info == b.info and np.array_equal(a.q, b.q)

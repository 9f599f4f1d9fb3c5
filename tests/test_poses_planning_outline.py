r'''targets.poses plans a board by what its detector needs in the image
(targets.boards.Target.planning_extent): a chessboard's corners and outer squares, not its
light margin; a dot board and an AprilGrid by the printed board'''

from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from targets_render import pinhole

from reference_models.jpl_files import read_model
from renderers.base import RenderSettings, get_renderer
from targets.boards import load_target, target_from_dict
from targets.centroids import board_to_ref
from targets.detect import detect
from targets.poses import _margin_px, plan_poses, pose_summary

CAMERAS = Path(__file__).resolve().parents[1] / "campaigns" / "cameras"


def test_planning_extent_is_the_corners_and_outer_squares_of_a_chessboard():
    chess = load_target("chessboard")
    sq = chess.spec["square"]
    nx, ny = chess.grid_shape
    assert np.allclose(chess.planning_extent(), (-sq, nx * sq, -sq, ny * sq), rtol=0,
                       atol=1e-15)
    # inside the printed board, which keeps its light margin
    x0, x1, y0, y1 = chess.extent
    assert x0 < -sq and x1 > nx * sq and y0 < -sq and y1 > ny * sq
    o = chess.planning_outline(8)
    assert o.shape == (32, 3) and np.all(o[:, 2] == 0)
    assert np.allclose(o.min(axis=0)[:2], (-sq, -sq)) and np.allclose(o.max(axis=0)[:2],
                                                                      (nx * sq, ny * sq))
    # the printed board for the others, and for a chessboard a plug-in detector finds
    for name in ("dots", "apriltag"):
        t = load_target(name)
        assert t.planning_extent() == t.extent
        assert np.array_equal(t.planning_outline(16), t.outline(16))
    spec = dict(chess.spec)
    spec["detector"] = "dots"     # any registered name other than the kind's
    assert target_from_dict(spec).planning_extent() == chess.extent


def _corner_span(model, target, Rt):
    q = model.project(board_to_ref(model, Rt, target.points()))
    return q.max(axis=0) - q.min(axis=0)


@pytest.mark.parametrize("camera", ["barrel-1024x768.cahvor", "eye-1024x768.cahvore",
                                    "tiny-320x240.cahvor"])
def test_chessboard_corners_span_what_the_dots_span(camera):
    # both boards have 10x10 points 0.1 m apart; planned by the printed board the
    # chessboard's light margin kept it ~8% farther and its corners spanned ~10% less of
    # the image (camera 8: 667x635 px against the dots' 742x703 on the near pose)
    model = read_model(CAMERAS / camera)
    chess, dots = load_target("chessboard"), load_target("dots")
    for seed in (0, 1):
        pc, pd = plan_poses(model, chess, n=6, seed=seed), plan_poses(model, dots, n=6, seed=seed)
        for Rc, Rd in zip(pc, pd, strict=True):
            sc, sd = _corner_span(model, chess, Rc), _corner_span(model, dots, Rd)
            assert np.all(sc >= sd * (1 - 1e-9)), (camera, seed, sc, sd)
            assert pose_summary(model, chess, Rc)["in_view"]


def _frontal(target, s_px, d_px):
    r'''(model, Rt): a pinhole seeing the board frontally, squares of s_px, the image's edge
d_px past the outermost corners on all four sides'''
    p = target.points()[:, :2]
    lo, hi = p.min(axis=0), p.max(axis=0)
    sq = target.spec["square"]
    f = 1000.0
    Z = f * sq / s_px
    W, H = (np.round((hi - lo) / sq * s_px + 2 * d_px)).astype(int)
    c = d_px - 0.5 - f * lo / Z
    return pinhole(int(W), int(H), f, cx=c[0], cy=c[1]), np.vstack((np.eye(3), [0, 0, Z]))


@pytest.mark.parametrize("s_px", [12, 20, 40])
@pytest.mark.parametrize("blur", [0.0, 1.0])
def test_the_planning_outline_holds_what_the_detector_needs(s_px, blur):
    # the image's edge where the planner may put it at the least: the planning outline
    # (the outer squares' edges) at the smallest margin, 4 px; the detector finds the
    # corners it finds with the whole printed board in view, sharp (all of them) and under
    # a 1 px blur (whose line strips reach 0.6-0.7 square past the outermost corners on
    # 40 px squares; on 12 px squares 12 corners by the mark dots are dropped either way,
    # "window too small")
    target = load_target("chessboard")

    def found(d_px):
        model, Rt = _frontal(target, s_px, d_px)
        img = get_renderer("raycast").render(model, target.pattern(), Rt,
                                             RenderSettings(spp=4)).image
        if blur:
            img = gaussian_filter(np.asarray(img, dtype=np.float64), blur)
        det = detect(img, target)
        assert det.status == "ok", det.reason
        return np.isfinite(det.q).all(axis=1), det.info.get("corners_dropped")
    at_edge, dropped = found(s_px + 4.0)
    whole, _ = found(3.0 * s_px)
    assert np.array_equal(at_edge, whole), dropped
    assert at_edge.sum() >= (88 if blur and s_px < 20 else 100)


def test_the_outer_squares_are_needed():
    # the detector's need is real: with the image's edge 8 px past the outermost corners
    # (most of the outer squares cut off) OpenCV finds no board
    target = load_target("chessboard")
    model, Rt = _frontal(target, 30, 8.0)
    img = get_renderer("raycast").render(model, target.pattern(), Rt,
                                         RenderSettings(spp=4)).image
    assert detect(img, target).status == "failed"


@pytest.mark.parametrize("camera", ["eye-1024x768.cahvore", "fish-1280.cahvore",
                                    "tiny-320x240.cahvor", "small-240x180.cahvor",
                                    "blur-wide-1024.cahvor"])
def test_detection_finds_the_board_on_every_planned_pose(camera):
    # every corner on the planned poses, on fisheyes and small sensors; on the 240x180
    # sensor squares of 6-10 px lose corners to windows too small for their fit, never to
    # the image's edge
    model = read_model(CAMERAS / camera)
    target = load_target("chessboard")
    renderer = get_renderer("raycast")
    small = min(model.width, model.height) < 200
    for Rt in plan_poses(model, target, n=6, seed=0):
        img = renderer.render(model, target.pattern(), Rt, RenderSettings(spp=4)).image
        det = detect(img, target)
        assert det.status == "ok", (camera, det.reason)
        dropped = det.info.get("corners_dropped", {})
        assert "window off the image" not in dropped, (camera, dropped)
        if not small:
            assert np.isfinite(det.q).all(), (camera, dropped)
    assert _margin_px(model) >= 4.0

r'''targets.poses keeps an AprilGrid's tags resolvable on a small sensor (tag_bit_need_px)'''

from pathlib import Path

import numpy as np
import pytest

import targets.poses as poses
from reference_models.cahvore import CAHV, truncate
from reference_models.catalogue import load_catalogue
from reference_models.jpl_files import read_model
from targets.boards import load_target, target_from_dict
from targets.poses import (
    NotVisibleError,
    TagsTooSmallError,
    _margin_px,
    _Planner,
    plan_poses,
    pose_summary,
    tag_bit_depths,
    tag_bit_need_px,
    tag_subgrid_extents,
)

ROOT = Path(__file__).resolve().parents[1]
CAMERAS = ROOT / "campaigns" / "cameras"


def _medians(model, target, plan):
    planner = _Planner(model, target, _margin_px(model), 100.0)
    return [float(np.median(tag_bit_depths(model, planner.tag_quads, Rt))) for Rt in plan]


def _in_image(model, target, Rt):
    r'''(N,) the tags whose four corners project inside the image'''
    quads = target.points().reshape(-1, 4, 3)
    Rr = model.Rt_ref_cam()
    q = model.project((quads.reshape(-1, 3) @ Rt[:3].T + Rt[3]) @ Rr[:3].T + Rr[3])
    q = q.reshape(-1, 4, 2)
    ok = np.isfinite(q).all(axis=-1)
    ok &= (q[..., 0] >= 0) & (q[..., 0] <= model.width - 1)
    ok &= (q[..., 1] >= 0) & (q[..., 1] <= model.height - 1)
    return ok.all(axis=1)


def test_the_need_comes_from_the_detectors_limits():
    # the blurred edges' clearance at sigma 0.7: 3 sigma + sqrt(1/2) + SAFETY_PX 0.3
    assert tag_bit_need_px((240, 320)) == pytest.approx(3.1071, abs=1e-3)
    # sharp: the quad search's 2 px (the edges' clearance 1.01 px)
    assert tag_bit_need_px((240, 320), psf_sigma_px=0.0) == pytest.approx(2.0, abs=1e-12)
    # a 5120x3840 image's quad search is decimated by 3: 6 px
    assert tag_bit_need_px((3840, 5120)) == pytest.approx(6.0, abs=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_small_sensors_tags_stay_above_the_detectors_need(seed):
    # tiny-320x240: the whole board at the templates' ranges put the median tag bit of the
    # corner views at 1.6-2.3 px (main: 1.76, 2.09, 1.63, 2.32, 2.07 CAHVOR seed 0), under the
    # 3.11 px the blurred edges need; a central sub-grid planned in view brings every pose
    # to it, the rest of the board beyond the image
    model = read_model(CAMERAS / "tiny-320x240.cahvor")
    target = load_target("apriltag")
    plan = plan_poses(model, target, n=6, seed=seed)
    need = tag_bit_need_px((model.height, model.width))
    for Rt, median in zip(plan, _medians(model, target, plan), strict=True):
        inside = _in_image(model, target, Rt)
        # the tags whole in the image, not the board's, are what the detector has
        bits = tag_bit_depths(model, target.points().reshape(-1, 4, 3)[inside], Rt)
        assert np.median(bits) >= 0.9 * need, (median, bits)
        assert inside.sum() >= 9
    # the corner views overflow the image (the centred one too where the whole board's
    # median bit, ~3.1 px, misses the need)
    assert not any(pose_summary(model, target, Rt)["in_view"] for Rt in plan[1:5])


@pytest.mark.parametrize("key", [15, 8, 1])
def test_the_rule_does_not_bind_on_the_catalogue(monkeypatch, key):
    # where every pose's median tag bit meets the need the plan is the one without the rule,
    # bit for bit
    target = load_target("apriltag")
    entry = load_catalogue().get(key)
    for family in ("CAHV", "CAHVOR", "CAHVORE"):
        if family == "CAHVORE" and entry.model.family != "CAHVORE":
            continue
        model = truncate(entry.model, family)
        plan = plan_poses(model, target, n=6, seed=0)
        need = tag_bit_need_px((model.height, model.width))
        assert min(_medians(model, target, plan)) >= need
        with monkeypatch.context() as m:
            m.setattr(poses, "tag_bit_need_px", lambda shape: 0.0)
            free = plan_poses(model, target, n=6, seed=0)
        assert all(np.array_equal(a, b) for a, b in zip(plan, free, strict=True))


def test_only_the_poses_whose_tags_are_too_small_change(monkeypatch):
    # MER hazcam 17 (640x480 fisheye): pose 3 of seed 0 (the bottom-right corner, 45 deg)
    # has a median tag bit of 2.63 px with the whole board (CAHVOR), under the 3.11 px;
    # it alone is planned with a sub-grid, the other five are the plan without the rule
    model = truncate(load_catalogue().get(17).model, "CAHVOR")
    target = load_target("apriltag")
    plan = plan_poses(model, target, n=6, seed=0)
    with monkeypatch.context() as m:
        m.setattr(poses, "tag_bit_need_px", lambda shape: 0.0)
        free = plan_poses(model, target, n=6, seed=0)
    same = [np.array_equal(a, b) for a, b in zip(plan, free, strict=True)]
    assert same == [True, True, True, False, True, True]
    need = tag_bit_need_px((model.height, model.width))
    before, after = _medians(model, target, free[3:4])[0], _medians(model, target, plan[3:4])[0]
    assert before == pytest.approx(2.63, abs=0.01) and before < need
    assert after > before


def test_other_targets_are_unchanged_on_a_small_sensor(monkeypatch):
    model = read_model(CAMERAS / "tiny-320x240.cahvor")
    for name in ("dots", "chessboard"):
        target = load_target(name)
        plan = plan_poses(model, target, n=6, seed=0)
        with monkeypatch.context() as m:
            m.setattr(poses, "tag_bit_need_px", lambda shape: np.inf)
            other = plan_poses(model, target, n=6, seed=0)
        assert all(np.array_equal(a, b) for a, b in zip(plan, other, strict=True))


def test_a_camera_that_cannot_resolve_one_tag_is_not_applicable():
    # a 48x36 pinhole of ~60 deg: one tag filling the image at the corner views' range and
    # tilt has bits under 3.11 px
    model = CAHV(C=[0, 0, 0], A=[0, 0, 1], H=[42.0, 0, 23.5], V=[0, 42.0, 17.5],
                 width=48, height=36)
    with pytest.raises(TagsTooSmallError) as e:
        plan_poses(model, load_target("apriltag"), n=6, seed=0)
    assert isinstance(e.value, NotVisibleError) and e.value.not_applicable
    assert "too small for its detector" in str(e.value) and "px it needs" in str(e.value)


def test_a_users_own_grid_is_planned_by_the_same_rule():
    # a 4x3 grid of 0.1 m tags with a wider gap, from a target definition of the user's
    spec = {"name": "mygrid", "kind": "apriltag", "nx": 4, "ny": 3, "tag_size": 0.1,
            "tag_spacing": 0.5, "margin": 0.03}
    target = target_from_dict(spec)
    ext = tag_subgrid_extents(target)
    # one tag fewer a side each step, down to one tag; each extent holds its tags' borders
    # and half the gap
    assert [(mx, my) for mx, my, _ in ext] == [(3, 2), (2, 1), (1, 1)]
    x0, x1, y0, y1 = ext[-1][2]
    assert (x1 - x0, y1 - y0) == pytest.approx((0.15, 0.15), abs=1e-12)
    model = read_model(CAMERAS / "tiny-320x240.cahvor")
    plan = plan_poses(model, target, n=6, seed=0)
    need = tag_bit_need_px((model.height, model.width))
    for Rt in plan:
        inside = _in_image(model, target, Rt)
        bits = tag_bit_depths(model, target.points().reshape(-1, 4, 3)[inside], Rt)
        assert inside.sum() >= 2 and np.median(bits) >= 0.9 * need, bits


def test_the_detector_finds_the_planned_sub_grid():
    # tiny-320x240, sharp render: every view's tags whole in the image are found (the board
    # overflowing the image in the corner views), each tag's four corners within 0.05 px
    from renderers.base import RenderSettings, get_renderer
    from targets.detect import detect
    model = read_model(CAMERAS / "tiny-320x240.cahvor")
    target = load_target("apriltag")
    renderer = get_renderer("raycast")
    Rr = model.Rt_ref_cam()
    P = target.points()
    for Rt in plan_poses(model, target, n=6, seed=0):
        img = renderer.render(model, target.pattern(), Rt, RenderSettings(spp=4)).image
        det = detect(img, target, psf_sigma_px=0.0)
        assert det.status == "ok", det.reason
        inside = _in_image(model, target, Rt)
        found = np.isfinite(det.q).all(axis=1).reshape(-1, 4)
        # the tags whole in the image give their corners (a few corners of the tags at the
        # image's edge lose their window: "window off the image")
        assert found[inside].sum() >= 0.9 * 4 * inside.sum(), det.info
        q = model.project((P @ Rt[:3].T + Rt[3]) @ Rr[:3].T + Rr[3])
        err = np.linalg.norm(det.q - q, axis=1)
        assert np.nanmax(err) < 0.05, np.nanmax(err)

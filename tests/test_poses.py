r'''The pose planner: six board poses for every catalogue camera'''

import numpy as np
import pytest
from conftest import CATALOGUE_KEYS

from reference_models.catalogue import load_catalogue
from reference_models.errors import CamvalError
from targets.boards import load_target, target_from_dict
from targets.centroids import board_to_ref
from targets.poses import NotVisibleError, plan_poses, pose_summary

PLANNABLE = [k for k in CATALOGUE_KEYS if k != "SuperCam"]


def _board_grid(target, n=30):
    xmin, xmax, ymin, ymax = target.extent
    g = np.stack(np.meshgrid(np.linspace(xmin, xmax, n), np.linspace(ymin, ymax, n)), -1)
    g = g.reshape(-1, 2)
    return np.column_stack((g, np.zeros(len(g))))


@pytest.mark.parametrize("key", PLANNABLE)
def test_six_poses_for_every_camera(catalogue, key):
    m = catalogue.get(key).model
    t = load_target("dots")
    poses = plan_poses(m, t, n=6, seed=0)
    assert len(poses) == 6
    W, H = m.width, m.height
    summaries = []
    for Rt in poses:
        assert Rt.shape == (4, 3) and Rt.dtype == np.float64
        R = Rt[:3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.linalg.det(R) > 0
        s = pose_summary(m, t, Rt)
        assert s["in_view"] and s["in_front"], (key, s)
        assert s["tilt_deg"] <= 50.0
        summaries.append(s)
    tilts = [s["tilt_deg"] for s in summaries]
    ranges = [s["range_m"] for s in summaries]
    assert min(tilts) < 15.0 and max(tilts) > 35.0
    assert max(ranges) / min(ranges) > 1.3
    # every dot is imaged, in every pose
    for Rt in poses:
        assert np.all(np.isfinite(m.project(board_to_ref(m, Rt, t.points()))))
    # the union of the board images reaches the outer third of each image quadrant
    q = np.concatenate([m.project(board_to_ref(m, Rt, _board_grid(t))) for Rt in poses])
    for left in (True, False):
        for top in (True, False):
            inx = q[:, 0] < W / 6 if left else q[:, 0] > W - 1 - W / 6
            iny = q[:, 1] < H / 6 if top else q[:, 1] > H - 1 - H / 6
            assert np.any(inx & iny), (key, "corner", left, top)


def test_deterministic_for_a_seed():
    m = load_catalogue().get(15).model
    t = load_target("dots")
    a = plan_poses(m, t, seed=3)
    b = plan_poses(m, t, seed=3)
    c = plan_poses(m, t, seed=4)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not all(np.allclose(x, y) for x, y in zip(a, c, strict=True))


@pytest.mark.parametrize("name", ["apriltag", "chessboard"])
def test_other_targets(name):
    m = load_catalogue().get(17).model    # 640x480 wide-angle CAHVORE
    t = load_target(name)
    poses = plan_poses(m, t, n=8, seed=1)
    assert len(poses) == 8
    for Rt in poses:
        s = pose_summary(m, t, Rt)
        assert s["in_view"] and s["in_front"] and s["tilt_deg"] <= 50.0


def test_supercam_is_refused_with_the_reason():
    m = load_catalogue().get("SuperCam").model
    t = load_target("dots")
    with pytest.raises(NotVisibleError, match=r"optical centre \(-37389, 35777\) px lies far "
                                              r"outside the 2048x2048 image"):
        plan_poses(m, t)
    # asked to, the planner finds poses at long range
    poses = plan_poses(m, t, allow_offaxis=True, max_range=1000.0)
    for Rt in poses:
        s = pose_summary(m, t, Rt)
        assert s["in_view"] and s["in_front"] and 50.0 < s["range_m"] < 200.0
    with pytest.raises(NotVisibleError, match="max_range = 100 m"):
        plan_poses(m, t, allow_offaxis=True)


def test_bad_input():
    m = load_catalogue().get(15).model
    t = load_target("dots")
    for n in (0, -1, 2.5, True):
        with pytest.raises(CamvalError, match="positive integer"):
            plan_poses(m, t, n=n)
    # a board too large to fit at any range up to max_range
    huge = target_from_dict({"kind": "dots", "nx": 3, "ny": 3, "spacing": 500.0,
                             "dot_diameter": 100.0})
    with pytest.raises(NotVisibleError, match="does not fit the 1024x1024 image"):
        plan_poses(m, huge)

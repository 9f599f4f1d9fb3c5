r'''The pose planner: six board poses for every catalogue camera'''

import math

import numpy as np
import pytest
from conftest import CATALOGUE_KEYS

from reference_models.cahvore import truncate
from reference_models.catalogue import load_catalogue
from reference_models.errors import CamvalError
from targets.boards import load_target, target_from_dict
from targets.centroids import board_to_ref
from targets.poses import NotVisibleError, _Planner, plan_poses, pose_summary

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
    in_view = []
    for Rt in poses:
        s = pose_summary(m, t, Rt)
        assert s["in_front"] and s["tilt_deg"] <= 50.0
        in_view.append(s["in_view"])
    # the AprilGrid's pose 3 keeps a central sub-grid in view, the whole board's median tag
    # bit there under the detector's need (targets.poses.tag_bit_need_px;
    # tests/test_small_sensor_tags.py)
    assert in_view == ([True] * 3 + [False] + [True] * 4 if name == "apriltag" else [True] * 8)


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


# poses 0, 3 and 5 (translation, board normal) as planned when the planner's rays became
# reference_models.kernels' compiled ones (re-pinned then: they moved by <= 2e-15 m from
# those of commit cf58840); it must keep planning the same poses
PINNED = {
    (15, "CAHVOR"): {
        0: ([-0.45903611607305794, -0.4141746248267948, 1.5009234533611144],
            [-0.07232073298949972, 0.14223256616212795, 0.9871877271840432]),
        3: ([-0.055078529023886325, 0.0007053524113306286, 2.4808676050331355],
            [-0.5312220205357955, 0.4354655152018823, 0.7267550825194319]),
        5: ([-0.3287477005105835, -0.425543685683394, 2.3054183227156884],
            [-0.5780256921793241, -0.09435977531330557, 0.8105445897564397])},
    (8, "CAHVORE"): {
        0: ([-0.4751947470099854, -0.4248966072401997, 0.35786179699273185],
            [-0.055569395922182276, 0.15021211475055968, 0.9870908584416169]),
        3: ([-0.05469779935162572, 0.4174951481695791, 1.0423396864230785],
            [-0.6169623268421778, -0.18372797121283876, 0.7652460518365969]),
        5: ([-0.3570270753824564, -0.44202888063413803, 0.9641598165302946],
            [-0.5640866344723539, -0.08800272882078808, 0.821012660395531])},
    (3, "CAHV"): {
        0: ([-0.4739283177610476, -0.42714702478100397, 0.7370477635706076],
            [-0.06166190391449159, 0.15290209232151225, 0.9863157505430722]),
        3: ([0.023308445472247585, -0.016683636117040768, 1.4284075017979887],
            [-0.682310619778488, 0.2818173082163373, 0.6745600217380169]),
        5: ([-0.35238416069854156, -0.4464407945474578, 1.4478161204134141],
            [-0.5690482009797658, -0.08471181868615438, 0.8179291245190966])},
}


@pytest.mark.parametrize("key,family", list(PINNED))
def test_poses_are_pinned(key, family):
    m = truncate(load_catalogue().get(key).model, family)
    poses = plan_poses(m, load_target("dots"), n=6, seed=0)
    for i, (t, normal) in PINNED[(key, family)].items():
        # bit for bit on the machine they were recorded on; 1e-9 (m, and unit-vector
        # components) leaves room for another CPU's or BLAS's rounding carried through the
        # search's refinements, while a search that went another way moves a pose by
        # millimetres at least
        np.testing.assert_allclose(poses[i][3], t, rtol=0, atol=1e-9)
        np.testing.assert_allclose(poses[i][2], normal, rtol=0, atol=1e-9)


def _rotation_plain(axis, angle):
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)


def test_pose_is_the_plain_formula_bit_for_bit():
    m = load_catalogue().get(8).model      # CAHVORE fisheye: rays far off the axis
    t = load_target("dots")
    planner = _Planner(m, t, 20.0, 100.0)
    for q in ([511.5, 511.5], [3.25, 1000.0], [1020.0, 7.5], [700.0, 200.0]):
        for tilt, azimuth, roll in ((8.0, 30.0, 0.0), (44.5, 137.0, -2.5), (30.0, -80.0, 3.0)):
            for d in (0.3, 1.7):
                o, v = planner.ray_cam(np.array(q))
                ex = np.array([1.0, 0.0, 0.0])
                x = ex - (ex @ v) * v
                x /= np.linalg.norm(x)
                y = np.cross(v, x)
                R = np.stack((x, y, v), axis=1)
                a = math.radians(azimuth)
                axis = math.cos(a) * x + math.sin(a) * y
                R = (_rotation_plain(v, math.radians(roll))
                     @ _rotation_plain(axis, math.radians(tilt)) @ R)
                expected = np.vstack((R, o + d * v - R @ t.centre()))
                assert np.array_equal(planner.pose(np.array(q), d, tilt, azimuth, roll),
                                      expected)


@pytest.mark.parametrize("key,family", [(8, "CAHVORE"), (17, "CAHVORE"), (15, "CAHVOR"),
                                        (3, "CAHV")])
def test_compiled_test_plans_the_same_poses(monkeypatch, key, family):
    import targets.poses
    m = truncate(load_catalogue().get(key).model, family)
    t = load_target("dots")
    compiled = plan_poses(m, t, n=7, seed=3)
    # the planner on the model's own project() and unproject()
    monkeypatch.setattr(targets.poses, "_packed", lambda model: None)
    reference = plan_poses(m, t, n=7, seed=3)
    # the compiled rays are the model's to ~1e-16 (not bit for bit: other roundings of the
    # same operations), which the search carries into the poses (measured: <= 2e-15 m over
    # every plannable paper job); a search that went another way moves a pose by millimetres
    for a, b in zip(compiled, reference, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    # and the compiled test decides as the numpy one, also off the planner's path
    planner = _Planner(m, t, 20.0, 100.0)
    monkeypatch.undo()
    fast = _Planner(m, t, 20.0, 100.0)
    assert fast._cam is not None and planner._cam is None
    q_c = np.array([(m.width - 1) / 2, (m.height - 1) / 2])
    decisions = []
    for d in np.geomspace(0.05, 20.0, 40):
        for tilt in (0.0, 50.0, 80.0):
            Rt = planner.pose(q_c, d, tilt, 30.0, 0.0)
            decisions.append(planner.fits(Rt))
            assert fast.fits(Rt) == decisions[-1]
    assert any(decisions) and not all(decisions)


@pytest.mark.parametrize("key", CATALOGUE_KEYS)
def test_planner_rays_are_the_models_unproject(key):
    rng = np.random.default_rng(7)
    t = load_target("dots")
    for family in ("CAHV", "CAHVOR", "CAHVORE"):
        try:
            m = truncate(load_catalogue().get(key).model, family)
        except CamvalError:
            continue
        planner = _Planner(m, t, 20.0, 100.0)
        assert planner._cam is not None
        W, H = m.width, m.height
        qs = np.vstack((np.column_stack((rng.uniform(-0.5, W - 0.5, 40),
                                         rng.uniform(-0.5, H - 0.5, 40))),
                        [[(W - 1) / 2, (H - 1) / 2], [-0.5, -0.5], [W - 0.5, H - 0.5]]))
        Rt = m.Rt_ref_cam()
        for q in qs:
            o, v = m.unproject(q)
            o_cam, v_cam = planner.ray_cam(q)
            # the compiled ray: the model's to a few ulps (origins in metres, unit directions)
            np.testing.assert_allclose(o_cam, (o - Rt[3]) @ Rt[:3], rtol=0, atol=1e-13)
            np.testing.assert_allclose(v_cam, v @ Rt[:3], rtol=0, atol=1e-14)

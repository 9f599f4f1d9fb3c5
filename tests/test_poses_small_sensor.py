r'''targets.poses keeps a dot board's dots detectable on a small sensor (DOT_AREA_FACTOR)'''

from pathlib import Path

import pytest

from reference_models.jpl_files import read_model
from targets.boards import load_target
from targets.poses import DOT_AREA_FACTOR, _margin_px, _Planner, plan_poses

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "campaigns" / "cameras" / "mini-160x120.cahvor"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_small_sensor_dots_stay_above_the_detector_minimum(seed):
    # a 160x120 camera: the template ranges (1.3-1.55 x the closest fit) and 30-45 deg tilts
    # put dots of 3.1-5.9 px^2 on the image, under detect_dots' min_area_px = 6 (whole poses
    # lost); nearer, the smallest dot of each seed's plan is 5.7-6.1 px^2 (the closest fit
    # bounds how near: a board tilted 45 deg at that range keeps only about that much)
    model = read_model(MINI)
    target = load_target("dots")
    planner = _Planner(model, target, _margin_px(model), 100.0)
    areas = [planner.smallest_dot_area(Rt) for Rt in plan_poses(model, target, n=6, seed=seed)]
    assert min(areas) >= 0.9 * planner.min_dot_area / DOT_AREA_FACTOR, areas


'''reference_models.poseutils: helpers that must keep the operations of what they replace'''

import numpy as np

from reference_models.poseutils import cross3


def test_cross3_is_np_cross_bit_for_bit():
    # the camera frame (Rt_ref_cam), theta and the jpl chart's tangent basis took np.cross;
    # cross3 keeps its products and differences in its order, so every figure built on them
    # stays the same bits (a comparison in one process: the same CPU, the same rounding)
    rng = np.random.default_rng(0)
    for _ in range(20000):
        a = rng.normal(size=3) * 10.0 ** rng.uniform(-8, 8)
        b = rng.normal(size=3) * 10.0 ** rng.uniform(-8, 8)
        assert np.array_equal(cross3(a, b), np.cross(a, b))
    # lists and integer vectors as np.cross takes them
    assert np.array_equal(cross3([1, 0, 0], [0, 1, 0]), [0.0, 0.0, 1.0])

r'''targets.corners on small features: windows judged by what their fit determines, not by a
count of pixels'''

import numpy as np
from targets_render import pinhole, render

from targets.boards import load_target
from targets.centroids import projected_points
from targets.corners import chessboard_half_box, refine_chessboard_corners
from targets.poses import plan_poses


def test_small_chessboard_squares_keep_their_corners():
    r'''Squares of ~8 px on a 160x120 image: windows of 0.45 square hold 9-16 pixels, which
the fixed floor of 30 pixels dropped every one of; 2 pixels per unknown (8 unknowns) and
the predicted error keep the corners, at the render's sampling error'''
    t = load_target("chessboard")
    m = pinhole(160, 120, 135.0)
    Rt = plan_poses(m, t, seed=0)[0]
    img = render(m, t.pattern(), Rt, K=32)
    truth = projected_points(m, t, Rt)
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 2 * np.pi, len(truth))
    q0 = truth + 0.3 * np.stack((np.cos(a), np.sin(a)), axis=-1)
    fit = refine_chessboard_corners(img, q0.reshape(10, 10, 2), chessboard_half_box(t),
                                    psf_sigma_px=0.0)
    kept = np.all(np.isfinite(fit.q), axis=-1)
    e = np.linalg.norm(fit.q[kept] - truth[kept], axis=-1)
    # every drop says why in words
    assert all(r for r in fit.reasons[~kept])
    assert kept.sum() >= 50, fit.dropped()
    assert np.sqrt(np.mean(e ** 2)) < 0.01 and e.max() < 0.05, (np.sqrt(np.mean(e ** 2)),
                                                                e.max(), kept.sum())

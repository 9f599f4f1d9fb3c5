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


def test_tag_corners_need_a_whole_pixel_in_each_edge_strip():
    r'''Tag bits of ~1.7 px (a 320x320 pinhole, the board 2.3 m away, tilted 20 deg): the
L-shaped window's strip along each edge inside the tag (0.8 bit) is narrower than a pixel
across the edge for about half the corners, which show no pixel of the full dark level;
those are dropped with that reason, by geometry alone (no pixel floor), and the rest are
refined to the K=32 render's sampling error'''
    from targets.corners import refine_tag_corners, tag_window
    t = load_target("apriltag")
    m = pinhole(320, 320, 260.0)
    r, a = np.radians(-23.0), np.radians(20.0)
    Rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Rt = np.vstack((Rz @ Rx, [-0.5, -0.45, 2.3]))
    img = render(m, t.pattern(), Rt, K=32)
    truth = projected_points(m, t, Rt)
    rng = np.random.default_rng(1)
    ang = rng.uniform(0, 2 * np.pi, len(truth))
    q0 = truth + 0.3 * np.stack((np.cos(ang), np.sin(ang)), axis=-1)
    fit = refine_tag_corners(img, q0.reshape(-1, 4, 2), psf_sigma_px=0.0, min_window_pixels=0,
                             **tag_window(t))
    kept = np.all(np.isfinite(fit.q), axis=-1)
    e = np.linalg.norm(fit.q[kept] - truth[kept], axis=-1)
    # measured: 77 of 144 kept, 0.0021 px RMS, 0.011 max; 67 "edge strip narrower than a pixel"
    assert fit.dropped() == {"edge strip narrower than a pixel": len(truth) - kept.sum()}
    assert kept.sum() >= 60, kept.sum()
    assert np.sqrt(np.mean(e ** 2)) < 0.004 and e.max() < 0.02, (np.sqrt(np.mean(e ** 2)), e.max())

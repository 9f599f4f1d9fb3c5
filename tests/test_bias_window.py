r'''The corner bias's window is laid where the refiner laid it, about the detected corner, so
that the bias is a smooth function of the model (harness.calibrators.bias.corner_bias's
q_window, targets.corners.curvature_bias's window_at)

Laid about the model's projected corner, the window gained or lost an edge pixel wherever a
pass of the calibrators' bias correction moved that corner across a pixel square's reach, and
the bias jumped (~1.4e-3 px on catalogue slot 17 CAHVORE's realistic chessboard): the
pass-to-pass change of the bias then need not fall below the 1e-5 px tolerance ("the corner
bias correction did not settle").'''

import numpy as np
import pytest
from synthetic import exact_observations, synthetic_poses
from test_corner_model_bias import _fisheye

from harness.calibrators.bias import bias_step, corner_bias
from targets.boards import load_target
from targets.detection import CORNER_LINES

# the corners move by this much (px) per step of the scan, 50 steps
STEP_PX = 2e-4
NSTEPS = 50


def _scan(truth, target, Rt, q_window, **kw):
    r'''(NSTEPS-1, Npoints) |change of the bias| between steps of the board moved along the
camera's x by STEP_PX px at a time'''
    ph = truth.photogrammetric()
    dt = STEP_PX * Rt[3, 2] / ph.Hs
    bs = []
    for k in range(NSTEPS):
        R = Rt.copy()
        R[3, 0] += k * dt
        bs.append(corner_bias(truth, target, R, target.points(), q_window=q_window, **kw))
    return np.linalg.norm(np.diff(np.array(bs), axis=0), axis=-1)


@pytest.mark.parametrize("kw", [{}, {"lines": True, "blur_px": 0.7}], ids=["sharp", "lines"])
def test_the_bias_moves_smoothly_with_the_model(kw):
    r'''A constructed 800x600 CAHVORE fisheye (edges bent by ~1e-3 / px: a bias of 4e-3 -
8e-3 px RMS), a chessboard pose, the board moved 2e-4 px at a time over 50 steps (0.01 px):
with the windows about the detections (here the projections at the scan's start) the bias
changes by at most 5.7e-6 px a step (measured; its smooth slope: the largest step is the
99.9% quantile's); about the moving projections one corner's window took in a pixel and its
bias jumped 2.2e-4 / 1.6e-4 px (sharp / lines, measured), which the second assertion checks
the scan can see.'''
    truth, t = _fisheye(), load_target("chessboard")
    Rt = synthetic_poses(truth, t)[0]
    obs = exact_observations(truth, t, [Rt])
    f = obs.found[0]
    fixed = _scan(truth, t, Rt, obs.q[0], **kw)[:, f]
    moving = _scan(truth, t, Rt, None, **kw)[:, f]
    assert fixed.max() < 2e-5, fixed.max()
    assert moving.max() > 1e-4, moving.max()


def test_bias_step_lays_the_windows_about_the_detections():
    r'''bias_step's corner_q (Observations.q) reaches corner_bias as q_window, pose by pose,
for the window model's corners and the lines' alike'''
    truth, t = _fisheye(), load_target("chessboard")
    Rts = synthetic_poses(truth, t)[:2]
    obs = exact_observations(truth, t, Rts)
    q = obs.q + 0.3          # detections 0.3 px off the projections: other windows
    model = np.array([np.where(obs.found[0], CORNER_LINES, ""), np.where(obs.found[1], "", "")])
    b, _ = bias_step(truth, t, Rts, obs.p_board, corner_model=model,
                     corner_blur_px=[0.7, 0.0], corner_q=q)
    want = corner_bias(truth, t, Rts[0], obs.p_board[0], lines=True, blur_px=0.7, q_window=q[0])
    about_projection = corner_bias(truth, t, Rts[0], obs.p_board[0], lines=True, blur_px=0.7)
    f = obs.found[0]
    assert np.array_equal(b[0][f], want[f])
    # the windows 0.3 px over hold other pixels: other biases (measured up to 1.1e-3 px)
    assert np.abs(want[f] - about_projection[f]).max() > 1e-4
    assert (b[1] == 0).all()


@pytest.mark.parametrize("pose", [1, 3])
def test_sharp_tag_corners_lose_their_bias_in_the_refiners_window(pose):
    r'''The window's steps are the refiner's (its fitted rays, as long as each tag's mean bit:
targets.corners.corner_steps, window_steps), not the model's derivative at the corner, which
differs from a tag's mean bit where the board recedes or the lens compresses it: the
constructed 800x600 CAHVORE fisheye's sharp tags (area render, exact corners as the coarse
ones), error after the bias under the truth, about the detections: 8.2e-5 / 6.4e-5 px RMS,
3.6e-4 / 3.7e-4 max (poses 1 / 3, measured); with the derivative's steps about the
projections (before) 3.0e-4 / 5.3e-4 RMS, 1.6e-3 / 2.4e-3 max, of 5.6e-3 / 4.2e-3 before
any bias is taken off.'''
    from renderers.base import RenderSettings
    from renderers.raycast import RaycastRenderer
    from targets.centroids import projected_points
    from targets.corners import refine_tag_corners, tag_window
    truth, t = _fisheye(), load_target("apriltag")
    Rt = synthetic_poses(truth, t)[pose]
    img = np.array(RaycastRenderer().render(truth, t, Rt, RenderSettings(spp=16)).image,
                   dtype=np.float64)
    exact = projected_points(truth, t, Rt)
    fit = refine_tag_corners(img, exact.reshape(-1, 4, 2), psf_sigma_px=0.0, **tag_window(t))
    assert np.isfinite(fit.q).all()
    b = corner_bias(truth, t, Rt, t.points(), q_window=fit.q)
    e = np.linalg.norm(fit.q - b - exact, axis=-1)
    raw = np.linalg.norm(fit.q - exact, axis=-1)
    assert np.sqrt(np.mean(raw ** 2)) > 3e-3            # the fisheye bends the tags' edges
    assert np.sqrt(np.mean(e ** 2)) < 1.5e-4 and e.max() < 8e-4, (np.sqrt(np.mean(e ** 2)),
                                                                  e.max())

r'''Shared helpers of the renderer adapter tests: small models, boards, exact centroids

Not a test module (no test_ prefix). The expected centroid of a projected dot
is computed here independently of targets.centroids: the area centroid of the
projected outline polygon (4096 outline points).
'''

import numpy as np

from reference_models.cahvore import CAHV, CAHVOR, CAHVORE
from targets.pattern import Pattern


def small_model(family="CAHVOR", W=256, H=192, f=250.0, hc=None, vc=None, theta_deg=90.0):
    r'''A small camera looking along +z from the origin (camera frame = world frame
when theta = 90)'''
    hc = W / 2 - 0.3 if hc is None else hc
    vc = H / 2 + 0.2 if vc is None else vc
    A = np.array([0.0, 0.0, 1.0])
    t = np.radians(theta_deg)
    Hp = np.array([1.0, 0.0, 0.0])
    Vp = np.array([np.cos(t), np.sin(t), 0.0])
    Hv = f * Hp + hc * A
    Vv = f * Vp + vc * A
    if family == "CAHV":
        return CAHV(C=[0, 0, 0], A=A, H=Hv, V=Vv, width=W, height=H)
    O = np.array([0.003, -0.002, 1.0])
    O /= np.linalg.norm(O)
    if family == "CAHVOR":
        return CAHVOR(C=[0, 0, 0], A=A, H=Hv, V=Vv, O=O, R=[0, -0.1, 0.02], width=W, height=H)
    return CAHVORE(C=[0, 0, 0], A=A, H=Hv, V=Vv, O=O, R=[0, -0.1, 0.02],
                   E=[0.002, 0.004, -0.001], model_type=3, linearity=0.6, width=W, height=H)


def board_pose(tilt_deg=20.0, distance=1.0, offset=(0.0, 0.0)):
    r'''Rt_cam_board of a board whose frame origin is near the image centre, tilted about y'''
    t = np.radians(tilt_deg)
    R = np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])
    return np.vstack((R, [offset[0], offset[1], distance]))


def dot_board(centres, r, extent=(-0.4, 0.4, -0.3, 0.3)):
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    circles = np.column_stack((c, np.full(len(c), r)))
    return Pattern(extent=extent, board_value=1.0, background_value=0.0,
                   circles=circles, circle_value=0.0)


def grid_board(n=5, spacing=0.08, r=0.02):
    xs = (np.arange(n) - (n - 1) / 2) * spacing
    centres = np.stack(np.meshgrid(xs, xs), -1).reshape(-1, 2)
    half = n * spacing / 2 + 0.05
    return dot_board(centres, r, extent=(-half, half, -half, half)), centres


def expected_centroid(model, Rt_cam_board, centre, r, n=4096):
    r'''Exact image centroid of a projected disc (area centroid of its outline)'''
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    p_board = np.column_stack((centre[0] + r * np.cos(a), centre[1] + r * np.sin(a),
                               np.zeros(n)))
    Rt = np.asarray(Rt_cam_board)
    p_cam = p_board @ Rt[:3].T + Rt[3]
    Rr = model.Rt_ref_cam()
    p_ref = p_cam @ Rr[:3].T + Rr[3]
    q = model.project(p_ref)
    x, y = q[:, 0], q[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cross = x * y1 - x1 * y
    area = cross.sum() / 2
    return np.array([((x + x1) * cross).sum() / (6 * area), ((y + y1) * cross).sum() / (6 * area)])


def measured_centroid(image, q0, radius_px, dark=True):
    r'''Intensity centroid of a dark (or bright) blob near q0 within radius_px'''
    img = np.asarray(image, dtype=np.float64)
    H, W = img.shape
    ys, xs = np.mgrid[0:H, 0:W]
    win = (xs - q0[0]) ** 2 + (ys - q0[1]) ** 2 <= radius_px ** 2
    w = (1.0 - img) if dark else img
    w = np.where(win, w, 0.0)
    s = w.sum()
    return np.array([(w * xs).sum() / s, (w * ys).sum() / s])

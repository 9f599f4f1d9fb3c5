r'''A slow, plain-numpy reference render of a target, for the targets tests

SYNOPSIS

    from targets_render import pinhole, render

    model = pinhole(256, 256, f=200.0)
    image = render(model, target.pattern(), Rt_cam_board, K=8)  # (256,256) float64

Each pixel is the mean of the Pattern's albedo over K x K subpixels, centred
at x = ix - 0.5 + (k + 0.5)/K (reference_models.conventions: the centre of
pixel (ix, iy) is (ix, iy)), each unprojected through the model and
intersected with the board plane. Adaptive: a pixel whose centre and four
corners see the same albedo, and whose 8 neighbours do too, is taken as
uniform; the rest are supersampled (exact for pattern features at least a
pixel wide; measured identical to the ray-cast renderer's full supersampling
to 3e-8 on AprilGrid, chessboard and dot boards through slots 5, 9, 15, 17).
Independent of renderers/ on purpose: the detector tests must not depend on
the renderer they are used to check.
'''

import numpy as np
from scipy.ndimage import binary_dilation
from scipy.spatial import cKDTree

from reference_models.cahvore import CAHV, CAHVOR
from targets.pattern import Pattern


def pinhole(width, height, f, cx=None, cy=None, R=None):
    r'''A CAHV (or CAHVOR with radial terms R) looking along +z from the origin'''
    cx = (width - 1) / 2 if cx is None else cx
    cy = (height - 1) / 2 if cy is None else cy
    A = np.array([0.0, 0.0, 1.0])
    H = np.array([f, 0.0, 0.0]) + cx * A
    V = np.array([0.0, f, 0.0]) + cy * A
    if R is None:
        return CAHV(C=np.zeros(3), A=A, H=H, V=V, width=width, height=height)
    return CAHVOR(C=np.zeros(3), A=A, H=H, V=V, O=A, R=np.asarray(R, float),
                  width=width, height=height)


class _FastAlbedo:
    r'''Pattern.albedo with the circles looked up in a k-d tree (the circles of a target
never overlap and are further apart than twice their radius)'''

    def __init__(self, pattern):
        self.pattern = pattern
        self.base = Pattern(extent=pattern.extent, board_value=pattern.board_value,
                            background_value=pattern.background_value, cells=pattern.cells,
                            cell_origin=pattern.cell_origin, cell_size=pattern.cell_size)
        c = pattern.circles
        self.tree = cKDTree(c[:, :2]) if c is not None and len(c) else None

    def __call__(self, x, y):
        a = self.base.albedo(x, y)
        if self.tree is None:
            return a
        xmin, xmax, ymin, ymax = self.pattern.extent
        inside = (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax)
        xy = np.stack((x, y), axis=-1)
        _, i = self.tree.query(xy)
        r = self.pattern.circles[i, 2]
        # compare squared distances, as Pattern.albedo does
        c = self.pattern.circles[i, :2]
        d2 = (x - c[..., 0]) ** 2 + (y - c[..., 1]) ** 2
        hit = inside & (d2 <= r * r)
        return np.where(hit, self.pattern.circle_value, a)


def _albedo_at(model, albedo, Rt_ref_board, q):
    o, v = model.unproject(q)
    R, t = Rt_ref_board[:3], Rt_ref_board[3]
    o_b = (o - t) @ R
    v_b = v @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -o_b[..., 2] / v_b[..., 2]
    p = o_b + s[..., None] * v_b
    ok = (s > 0) & np.isfinite(s) & np.all(np.isfinite(p), axis=-1)
    a = np.full(ok.shape, float(albedo.pattern.background_value))
    a[ok] = albedo(p[ok][:, 0], p[ok][:, 1])
    return a


def render(model, pattern, Rt_cam_board, K=8, adaptive=True):
    r'''Area-average render of a Pattern (float64 (H,W) in [0,1])'''
    W, H = model.width, model.height
    Rt_ref_cam = model.Rt_ref_cam()
    Rt = np.asarray(Rt_cam_board, float)
    Rt_ref_board = np.vstack((Rt_ref_cam[:3] @ Rt[:3], Rt_ref_cam[:3] @ Rt[3] + Rt_ref_cam[3]))
    albedo = _FastAlbedo(pattern)
    xs, ys = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    centre = _albedo_at(model, albedo, Rt_ref_board, np.stack((xs, ys), -1))
    if adaptive:
        cx, cy = np.meshgrid(np.arange(W + 1) - 0.5, np.arange(H + 1) - 0.5)
        corner = _albedo_at(model, albedo, Rt_ref_board, np.stack((cx, cy), -1))
        same = ((corner[:-1, :-1] == centre) & (corner[1:, :-1] == centre)
                & (corner[:-1, 1:] == centre) & (corner[1:, 1:] == centre))
        # a feature's corner can poke into a pixel between its 5 samples; features at
        # least a pixel wide then hit a neighbour's samples: supersample the neighbours too
        todo = np.argwhere(binary_dilation(~same, structure=np.ones((3, 3), bool)))
    else:
        todo = np.argwhere(np.ones((H, W), bool))
    image = centre.copy()
    off = (np.arange(K) + 0.5) / K - 0.5
    ox, oy = np.meshgrid(off, off)
    ox, oy = ox.ravel(), oy.ravel()
    chunk = max(1, 200000 // (K * K))
    for i in range(0, len(todo), chunk):
        iy, ix = todo[i:i + chunk, 0], todo[i:i + chunk, 1]
        q = np.stack((ix[:, None] + ox, iy[:, None] + oy), -1)
        image[iy, ix] = _albedo_at(model, albedo, Rt_ref_board, q).mean(axis=-1)
    return image

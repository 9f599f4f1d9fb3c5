r'''The shared pinhole-to-model warp of the POV-Ray and OSMesa renderers

SYNOPSIS

    from renderers.warp import PinholeWarp

    warp = PinholeWarp.for_model(model)          # cached per camera model
    pin = warp.pinhole                           # the oversized pinhole to render
    fine = pin.scaled(K)                         # the same view, K times finer
    # ... render the board through `fine` (shape (fine.height, fine.width)) ...
    image_pinhole = box_downsample(image_fine, K)
    image = warp.apply(image_pinhole, interpolation="bilinear", Rt_cam_board=Rt_cam_board)
    # image has shape (model.height, model.width), float32

The paper's path for a distorted camera (ROAMS, Dspace): render a perfect
pinhole view with a fast rasteriser or ray tracer, then fill every pixel of
the target model by looking up the pinhole pixel that sees the same ray
(bilinear or bicubic interpolation).

The pinhole shares the model's centre C and its camera frame
(model.Rt_ref_cam(): x = H', y = A x H', z = A), so board poses Rt_cam_board
mean the same for both. Its focal length is chosen so that the pinhole is at
least as fine as the model everywhere (the smallest singular value of the
map's Jacobian, model px -> pinhole px, is >= `scale`, default 1), and its size
and principal point so that every ray of every model pixel, plus the
footprint of the model's border pixels, lands inside it with `margin` pinhole
pixels to spare (interpolation support included).

Noncentral CAHVORE (E != 0): a pinhole at C cannot reproduce rays that leave
the entrance pupil elsewhere, so the map depends on the depth of the scene.
For a board pose the map is built exactly for the board plane: each model
pixel's true ray (origin, direction) is intersected with the plane of the
board and that point is projected through the pinhole. Rays that miss the
plane (they only see the uniform background) use the point at
`noncentral_range` metres along the ray. Without a pose the whole map uses
that range. Central models have one map per camera, independent of the pose.

Maps are cached per (model, scale, margin, samples): PinholeWarp.for_model
returns the same object for the same camera, and the per-pixel rays are
computed once.

Area sampling: a remap samples the pinhole image at one point per model pixel
(the pixel centre), a point sample of the pinhole image blurred by its own
pixels and the interpolation kernel. With `samples` = n > 1 the warp averages
n x n remaps at the sub-pixel centres of each model pixel, which approximates
the model pixel's area average; use it with a finer pinhole (scale = n):
a finer pinhole sampled at one point per model pixel aliases.

cv2.remap samples with 1/32-px fixed-point weights (INTER_BITS = 5); that
quantisation is part of the warp's measured cost, as in the paper's ROAMS.
'''

import math
import threading
from dataclasses import dataclass

import numpy as np

from reference_models.conventions import pixel_centres

from .base import RendererError, RendererNotApplicable

DEFAULT_MARGIN = 4.0
MAX_PINHOLE_SIDE = 32768
NONCENTRAL_RANGE = 2.0
INTERPOLATIONS = ("bilinear", "bicubic")


class WarpError(RendererError):
    '''A model that the pinhole warp cannot represent (field of view >= 180 deg, ...)'''


class FieldOfViewError(WarpError, RendererNotApplicable):
    '''The model's field of view is too wide for a pinhole warp (not-applicable, by design).'''



@dataclass(frozen=True)
class Pinhole:
    r'''An ideal pinhole camera in a model's camera frame

q = (fx x/z + cx, fy y/z + cy) for a point (x, y, z) in the camera frame
(x = H', y = A x H', z = A), in camval's pixel convention (centre of the
top-left pixel at (0,0)).
'''

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def project(self, p_cam):
        p = np.asarray(p_cam, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.stack((self.fx * p[..., 0] / p[..., 2] + self.cx,
                             self.fy * p[..., 1] / p[..., 2] + self.cy), axis=-1)

    def scaled(self, K):
        r'''The same view rendered K times finer: pixel (i, j) of the coarse camera
covers exactly the K x K block of fine pixels (K i + a, K j + b), a, b in [0, K)'''
        K = int(K)
        return Pinhole(fx=K * self.fx, fy=K * self.fy,
                       cx=K * (self.cx + 0.5) - 0.5, cy=K * (self.cy + 0.5) - 0.5,
                       width=K * self.width, height=K * self.height)

    def shifted(self, ox, oy, width, height):
        r'''The tile of this camera whose top-left pixel is this camera's pixel (ox, oy)'''
        return Pinhole(fx=self.fx, fy=self.fy, cx=self.cx - ox, cy=self.cy - oy,
                       width=int(width), height=int(height))

    def as_dict(self):
        return dict(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy,
                    width=self.width, height=self.height)


def box_downsample(image, K):
    r'''Average K x K blocks: (K H, K W) -> (H, W), float64'''
    K = int(K)
    if K == 1:
        return np.asarray(image, dtype=np.float64)
    H, W = image.shape[0] // K, image.shape[1] // K
    img = np.asarray(image, dtype=np.float64)[:H * K, :W * K]
    return img.reshape(H, K, W, K).mean(axis=(1, 3))


def _rays_cam(model, q):
    r'''Origins and unit directions of model pixels q, in the model's camera frame'''
    Rt = model.Rt_ref_cam()
    origin, v = model.unproject(q)
    # ref -> cam: p_cam = R^T (p_ref - C)
    return (origin - Rt[3]) @ Rt[:3], v @ Rt[:3]


class PinholeWarp:
    r'''The oversized pinhole of a camera model and the map from model pixels to it'''

    _cache = {}
    _lock = threading.Lock()

    def __init__(self, model, scale=1.0, margin=DEFAULT_MARGIN,
                 noncentral_range=NONCENTRAL_RANGE, samples=1):
        if not (scale > 0 and math.isfinite(scale)):
            raise WarpError(f"warp scale must be a positive number; got {scale!r}")
        if not (margin >= 0 and math.isfinite(margin)):
            raise WarpError(f"warp margin must be >= 0 px; got {margin!r}")
        if not (noncentral_range > 0):
            raise WarpError(f"noncentral_range must be > 0 m; got {noncentral_range!r}")
        if isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= 8:
            raise WarpError(f"warp samples must be an integer in [1, 8]; got {samples!r}")
        self.model = model
        self.samples = samples
        self.scale = float(scale)
        self.margin = float(margin)
        self.noncentral_range = float(noncentral_range)
        self.is_central = bool(model.is_central)
        W, H = model.width, model.height
        q = pixel_centres(W, H)
        self._origin, self._v = _rays_cam(model, q)
        # sub-pixel sample offsets of the warp (samples x samples per model pixel)
        d = (np.arange(samples) + 0.5) / samples - 0.5
        self.offsets = [(float(dx), float(dy)) for dy in d for dx in d]
        self._sub_rays = {}
        # the outline of the image (pixel edges) bounds the pinhole
        edge = np.concatenate((
            np.stack((np.linspace(-0.5, W - 0.5, 4 * W + 1), np.full(4 * W + 1, -0.5)), -1),
            np.stack((np.linspace(-0.5, W - 0.5, 4 * W + 1), np.full(4 * W + 1, H - 0.5)), -1),
            np.stack((np.full(4 * H + 1, -0.5), np.linspace(-0.5, H - 0.5, 4 * H + 1)), -1),
            np.stack((np.full(4 * H + 1, W - 0.5), np.linspace(-0.5, H - 0.5, 4 * H + 1)), -1)))
        _, v_edge = _rays_cam(model, edge)
        v_all = np.concatenate((self._v.reshape(-1, 3), v_edge))
        if not np.all(np.isfinite(v_all)):
            raise WarpError(f"{model.family} model: some pixels have no ray (unprojection "
                            "failed); the pinhole warp needs a ray for every pixel")
        cos_max = float(np.min(v_all[:, 2]))
        if cos_max < 0.02:
            raise FieldOfViewError(
                f"the field of view reaches {math.degrees(math.acos(max(-1, cos_max))):.1f} deg "
                "from the optical axis; a pinhole cannot cover it (pinhole warps need < 88.8 deg; "
                "use the raycast renderer or povray with camera='mesh')")
        # normalised pinhole coordinates m = (x/z, y/z) of every pixel ray
        m = self._v[..., :2] / self._v[..., 2:3]
        # local resolution: Jacobian of m w.r.t. model pixels (finite differences)
        dmx = np.gradient(m, axis=1)
        dmy = np.gradient(m, axis=0)
        # singular values of the 2x2 Jacobian [dm/dx, dm/dy] (per pixel)
        a, b = dmx[..., 0], dmy[..., 0]
        c, d = dmx[..., 1], dmy[..., 1]
        s1 = a * a + b * b + c * c + d * d
        det = np.abs(a * d - b * c)
        smin = np.sqrt(np.maximum(0.5 * (s1 - np.sqrt(np.maximum(s1 * s1 - 4 * det * det, 0))),
                                  0))
        f = self.scale / float(np.min(smin))
        m_edge = v_edge[:, :2] / v_edge[:, 2:3]
        lo = np.minimum(m.reshape(-1, 2).min(0), m_edge.min(0)) * f
        hi = np.maximum(m.reshape(-1, 2).max(0), m_edge.max(0)) * f
        pad = self.margin + 2.0
        cx, cy = pad - lo[0], pad - lo[1]
        width = int(math.ceil(hi[0] - lo[0] + 2 * pad)) + 1
        height = int(math.ceil(hi[1] - lo[1] + 2 * pad)) + 1
        if max(width, height) > MAX_PINHOLE_SIDE:
            raise FieldOfViewError(
                f"the pinhole covering this {model.family} model would be {width}x{height} px "
                f"(limit {MAX_PINHOLE_SIDE}); its field of view is too wide for a pinhole warp")
        self.pinhole = Pinhole(fx=f, fy=f, cx=float(cx), cy=float(cy),
                               width=width, height=height)
        self._central_maps = {}

    @classmethod
    def for_model(cls, model, scale=1.0, margin=DEFAULT_MARGIN,
                  noncentral_range=NONCENTRAL_RANGE, samples=1):
        r'''The cached warp of a camera model (one per model, scale, margin, samples)'''
        key = (repr(model), float(scale), float(margin), float(noncentral_range), int(samples))
        with cls._lock:
            w = cls._cache.get(key)
        if w is None:
            w = cls(model, scale=scale, margin=margin, noncentral_range=noncentral_range,
                    samples=samples)
            with cls._lock:
                if len(cls._cache) > 16:
                    cls._cache.clear()
                cls._cache[key] = w
        return w

    def _rays(self, isample):
        dx, dy = self.offsets[isample]
        if dx == 0.0 and dy == 0.0:
            return self._origin, self._v
        r = self._sub_rays.get(isample)
        if r is None:
            q = pixel_centres(self.model.width, self.model.height) + (dx, dy)
            r = self._sub_rays[isample] = _rays_cam(self.model, q)
        return r

    def map(self, Rt_cam_board=None, isample=None):
        r'''Pinhole coordinates of every model pixel centre (or of sub-pixel sample isample)

SYNOPSIS

    map_x, map_y = warp.map(Rt_cam_board)   # each (model.height, model.width) float32

For central models the map is the same for every pose (and cached); for
noncentral CAHVORE it is exact on the board plane (see the module docstring).
isample indexes warp.offsets (default: the pixel centre when samples is odd,
else sample 0).
'''
        if isample is None:
            isample = len(self.offsets) // 2
        if self.is_central:
            m = self._central_maps.get(isample)
            if m is None:
                q = self.pinhole.project(self._rays(isample)[1])
                m = self._central_maps[isample] = (q[..., 0].astype(np.float32),
                                                   q[..., 1].astype(np.float32))
            return m
        o, v = self._rays(isample)
        s = np.full(v.shape[:-1], self.noncentral_range)
        if Rt_cam_board is not None:
            Rt = np.asarray(Rt_cam_board, dtype=np.float64)
            n = Rt[:3, 2]           # board normal (board z axis) in the camera frame
            p0 = Rt[3]
            den = v @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((p0 - o) @ n) / den
            ok = np.isfinite(t) & (t > 0)
            s = np.where(ok, t, s)
        p = o + s[..., None] * v
        q = self.pinhole.project(p)
        return q[..., 0].astype(np.float32), q[..., 1].astype(np.float32)

    def apply(self, image_pinhole, interpolation="bilinear", Rt_cam_board=None):
        r'''Warp a pinhole image (pinhole.height, pinhole.width) to the model

Returns a float32 image of shape (model.height, model.width).
'''
        import cv2

        if interpolation not in INTERPOLATIONS:
            raise WarpError(f"unknown warp interpolation {interpolation!r}; "
                            f"known: {', '.join(INTERPOLATIONS)}")
        img = np.asarray(image_pinhole, dtype=np.float32)
        if img.shape != (self.pinhole.height, self.pinhole.width):
            raise WarpError(f"pinhole image has shape {img.shape}; expected "
                            f"{(self.pinhole.height, self.pinhole.width)}")
        flag = cv2.INTER_LINEAR if interpolation == "bilinear" else cv2.INTER_CUBIC
        acc = None
        for i in range(len(self.offsets)):
            map_x, map_y = self.map(Rt_cam_board, i)
            out = cv2.remap(img, map_x, map_y, flag, borderMode=cv2.BORDER_REPLICATE)
            acc = out.astype(np.float64) if acc is None else acc + out
        return np.clip(acc / len(self.offsets), 0.0, 1.0).astype(np.float32)

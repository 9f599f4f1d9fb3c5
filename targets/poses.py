r'''Board poses for calibrating a camera: the six target positions of the JPL procedure

SYNOPSIS

    from targets.poses import plan_poses, pose_summary, NotVisibleError

    Rt_cam_board_all = plan_poses(model, target, n=6, seed=0)   # list of (4,3) arrays
    pose_summary(model, target, Rt_cam_board_all[0])            # range, tilt, image bounds, ...

The JPL calibration procedure images the dot board in six positions. The
planner places the board so that together the six images constrain focal
length, image centre and distortion:

- pose 0: in the middle of the image, nearly facing the camera, as close as
  the board fits (it fills most of the image);
- poses 1-4: pushed into each corner of the image (top-left, top-right,
  bottom-right, bottom-left) until the board touches both image edges, at a
  larger range and tilted 30-45 deg about varying axes (the corners of the
  1024x1024 fisheye hazcams look more than 90 deg off axis: a board in front
  of the camera reaches into, not onto, them);
- pose 5: in the middle again, tilted about 40 deg, at a middle range.

More poses cycle through these with other tilts. A seed jitters tilt angle,
tilt axis, roll and range (deterministically). Every pose keeps the board's
planning outline (target.planning_outline(), sampled densely: what its detector
needs in the image, the whole printed board for dots and AprilGrids, the corners
and outer squares of a chessboard) inside the image with a margin
(2 % of the smaller image side, at least 4 px), in front of the camera
(camera-frame z > 0 for every board point) and facing it; the board's
tilt (angle between its normal and the line of sight to its centre) is at
most MAX_TILT_DEG. On a small sensor an AprilGrid's pose keeps a central sub-grid of its
tags in the image instead of the whole board, where the whole board would leave the
median tag bit under what the detector needs (tag_bit_need_px; the rest of the board
overflows the image: pose_summary's in_view is False there), and a camera that cannot
resolve even one tag is refused as not-applicable (TagsTooSmallError). Viewing
directions come from model.unproject() and every check uses model.project(), so this
works for any CAHV/CAHVOR/CAHVORE model, central or not, mirrored or not. (For speed
the planner uses the compiled equivalents of the two, reference_models.kernels (_packed):
the poses are within 1e-12 m of those planned with the model's own methods.)

Poses are Rt_cam_board (4,3) in the camera frame of model.Rt_ref_cam().

When the planner refuses (NotVisibleError): a camera whose optical centre
(Hc, Vc) lies more than one image size outside its image (the SuperCam
remote micro-imager: its 2048x2048 image looks about 40 deg off its axis A
through a 1.7 deg window). Such a camera can see a board (the 1.1 m dot board
at 70-110 m), but the JPL procedure - a board facing the camera across its field,
observing focal length and centre - does not apply: a pinhole fit cannot
separate the far-off centre from the focal length. Pass
allow_offaxis=True to plan anyway. It also refuses when the board does not fit
at any range up to max_range (default 100 m), or when the image centre does
not unproject. With allow_offaxis=True and max_range=1000 the planner gives
SuperCam six poses at 74-107 m.
'''

import math

import numpy as np
from numba import njit

from reference_models import kernels
from reference_models.errors import CamvalError
from reference_models.poseutils import R_from_axis_angle

MAX_TILT_DEG = 45.0
MAX_VIEW_ANGLE_DEG = 78.0      # largest angle between the board normal and a ray to the board
DEFAULT_MAX_RANGE = 100.0      # metres
NOUTLINE_PER_EDGE = 32
# A dot board's dots must stay detectable: targets.detect_dots drops dark blobs under its
# min_area_px (6 px); a dot's blob (its pixels darker than the dark/light threshold, about
# those more than half covered) can lose up to half its projected area on a small dot, so
# a pose keeps its smallest projected dot at DOT_AREA_FACTOR x min_area_px where the range
# allows (_Planner.dot_area_range). It binds on small sensors only (a 160x120 camera's far,
# tilted poses put dots of 3-6 px^2 on the image: 0-97 of 100 found, whole poses lost);
# where every pose's smallest dot is above it (the catalogue, the other constructed
# cameras) the plans are unchanged bit for bit.
DOT_AREA_FACTOR = 2.0
NDOT_OUTLINE = 32
# An AprilGrid's tags must stay resolvable: most tags of a view whose bits project under what
# the detector needs give no corner (targets.detect_apriltag, targets.tag_edges) and one
# view carries the fit. A pose keeps the median bit depth of the tags it plans in view (the
# tag_edges measure: the adjacent edges' extent across an edge / 8) at tag_bit_need_px()
# (the detector's own limits); where the whole board at the template's range leaves it
# smaller, the planner keeps a central sub-grid of the tags in the image instead
# (tag_subgrid_extents: one tag fewer a side each step), planned as the board would be (its
# closest fit, the template's range factor, pushed into the corner), and the rest of the
# board overflows the image (the detector keeps the tags whole in it). Where a pose's median
# bit meets the need the pose is unchanged bit for bit: every pose of catalogue cameras 15,
# 8, 1 (and every dot board and chessboard); it binds on the small sensors and on the
# steepest corner views of 640 px cameras (hazcam 17's pose 3: median 2.63 px).
# The blur the tags are planned for: a well-focused lens's PSF, sigma 0.7 px (the
# `realistic` response profile, campaigns/response.toml); the detector's edge fit needs
# deeper bits under more blur (tag_bit_need_px). The plan cannot depend on a campaign's
# response profile: a camera's sharp and realistic records share their poses
PLAN_PSF_SIGMA_PX = 0.7

# (anchor, tilt deg, tilt axis azimuth deg in the board plane, roll deg, range factor)
# anchor: None = image centre, else (sx, sy) signs of the image corner to push towards.
# range factor: times the range at which the board just fits in the middle of the image.
_TEMPLATES = (
    (None, 8.0, 30.0, 0.0, 1.0),
    ((-1, -1), 40.0, 135.0, 3.0, 1.45),
    ((1, -1), 35.0, 0.0, -3.0, 1.3),
    ((1, 1), 45.0, 45.0, 2.0, 1.55),
    ((-1, 1), 30.0, 90.0, -2.0, 1.35),
    (None, 40.0, 110.0, 0.0, 1.15),
)


# plan_poses(cover=...): "paper" cycles the templates; "corners" adds poses that reach
# the image's corners and edges (plan_poses says how)
COVERS = ("paper", "corners")
# the anchors of cover="corners" poses: the four corners, then the four edge midpoints
COVER_ANCHORS = ((-1, -1), (1, -1), (1, 1), (-1, 1), (0, -1), (1, 0), (0, 1), (-1, 0))
# their range factors, one round of COVER_ANCHORS each: a board at f times the range at
# which it fills the middle spans ~1/f of the image, so it can reach f times deeper into
# a corner; 3 keeps 10x10 dots ~1/30 of the image apart (detectable at 640 px)
COVER_FACTORS = (1.6, 2.2, 3.0)


class NotVisibleError(CamvalError):
    '''A camera that cannot see the target in a usable calibration pose (the message says why).'''


class OffAxisError(NotVisibleError):
    r'''The optical centre lies far outside the image: the JPL procedure does not apply

A property of the camera, not a failure: a campaign records it as
not-applicable (not_applicable = True), with this reason.'''

    not_applicable = True


def _packed(model):
    r'''The packed model (reference_models.kernels.pack_model) of a JPL model

SYNOPSIS

    cam = _packed(model)       # None for any other model

With it the planner unprojects by the compiled ray (reference_models.kernels.ray,
~1e-15 from model.unproject) and _Planner.fits() tests the board outline by one
compiled call (_outline_fits: in front, facing the camera, in the image): the
planner unprojects ~240 pixels and tests ~350 outlines per plan, and numpy's
projection of a CAHVORE costs ~80 us per call on 128 points. The compiled
projection agrees with model.project to < 1e-10 px and its sums are in another
order than numpy's matmul, which could only matter for a point on a limit to
the last bit. Any other model is planned with its own unproject() and project().
'''
    if getattr(model, "family", None) not in kernels.KINDS:
        return None
    return kernels.pack_model(model)


@njit(cache=True, error_model="numpy")
def _outline_fits(outline_cam, Rt, cos_min, R_ref_cam, t_ref_cam, cam, lo_x, hi_x, lo_y, hi_y):
    r'''Whether a board outline at translation t lies in front, faces the camera and
projects into the image (the compiled _Planner.fits)

SYNOPSIS

    ok = _outline_fits(outline_cam, Rt, cos_min, R_ref_cam, t_ref_cam, cam,
                       x_lo, x_hi, y_lo, y_hi)

outline_cam (M,3): the outline rotated into the camera frame; Rt (4,3) the board
pose: p = outline_cam + Rt[3], the board normal n = Rt[:3, 2].
True when every p has z > 0, <p/|p|, n> >= cos_min, and the packed model cam
projects p_ref = R_ref_cam p + t_ref_cam within [lo, hi] (NaN: False). All
arrays float64, C contiguous. The sums are in another order than numpy's
matmul (< 1 ulp apart): only a point on a limit to the last bit can decide
differently.
'''
    m = outline_cam.shape[0]
    t = Rt[3]
    n = np.empty(3, dtype=np.float64)
    for k in range(3):
        n[k] = Rt[k, 2]
    p = np.empty((m, 3), dtype=np.float64)
    for i in range(m):
        for k in range(3):
            p[i, k] = outline_cam[i, k] + t[k]
        if not p[i, 2] > 0:
            return False
    for i in range(m):
        r = math.sqrt(p[i, 0] * p[i, 0] + p[i, 1] * p[i, 1] + p[i, 2] * p[i, 2])
        if not ((p[i, 0] / r) * n[0] + (p[i, 1] / r) * n[1] + (p[i, 2] / r) * n[2] >= cos_min):
            return False
    p_ref = np.empty((m, 3), dtype=np.float64)
    for i in range(m):
        for k in range(3):
            p_ref[i, k] = (p[i, 0] * R_ref_cam[k, 0] + p[i, 1] * R_ref_cam[k, 1]
                           + p[i, 2] * R_ref_cam[k, 2]) + t_ref_cam[k]
    q = np.empty((m, 2), dtype=np.float64)
    kernels.project_points(cam, p_ref, q)
    for i in range(m):
        if not (q[i, 0] >= lo_x and q[i, 0] <= hi_x and q[i, 1] >= lo_y and q[i, 1] <= hi_y):
            return False
    return True


def compiled_entry_points():
    r'''The planner's compiled kernels (numba dispatchers), for a warm-up or
reference_models.kernels.drop_stale_caches (they carry its projection)'''
    return (_outline_fits,)


_EX = np.array([1.0, 0.0, 0.0])


class _Planner:
    def __init__(self, model, target, margin_px, max_range, extent=None):
        self.model = model
        self.target = target
        self.W, self.H = model.width, model.height
        self.margin = float(margin_px)
        self.max_range = float(max_range)
        Rt = model.Rt_ref_cam()
        self.R_ref_cam = Rt[:3]
        self.t_ref_cam = Rt[3]
        # what the detector needs in the image (targets.boards: Target.planning_extent), not
        # the printed board: a chessboard's light margin may leave the image; extent: a part
        # of the board instead (an AprilGrid's central sub-grid, tag_subgrid_extents)
        if extent is None:
            extent = target.planning_extent()
            self.outline = target.planning_outline(NOUTLINE_PER_EDGE)
        else:
            from targets.boards import _rectangle_outline
            self.outline = _rectangle_outline(extent, NOUTLINE_PER_EDGE)
        self.extent = tuple(float(v) for v in extent)
        self.centre_board = target.centre(extent)
        self.size = math.hypot(*target.size(extent))
        self.cos_view_max = math.cos(math.radians(MAX_VIEW_ANGLE_DEG))
        self._rays = {}
        self.dot_outlines = None
        if getattr(target, "kind", None) == "dots":
            import inspect

            from targets.detect_dots import _detect_dots
            min_area = inspect.signature(_detect_dots).parameters["min_area_px"].default
            self.min_dot_area = DOT_AREA_FACTOR * float(min_area)
            self.dot_outlines = target.dot_outlines(NDOT_OUTLINE)
        self.tag_quads = None
        if getattr(target, "kind", None) == "apriltag":
            # the tags whose four corners lie in the planned extent (all of them: the board)
            quads = target.points().reshape(-1, 4, 3)
            x0, x1, y0, y1 = self.extent
            inside = np.all((quads[..., 0] >= x0) & (quads[..., 0] <= x1)
                            & (quads[..., 1] >= y0) & (quads[..., 1] <= y1), axis=1)
            self.tag_quads = quads[inside]
            self.tag_need_px = tag_bit_need_px((self.H, self.W))
        self._cam = _packed(model)
        if self._cam is not None:
            self._R_ref_cam = np.ascontiguousarray(self.R_ref_cam)
            self._t_ref_cam = np.ascontiguousarray(self.t_ref_cam)
            self._C = self._cam[kernels._C:kernels._C + 3]
            self._O = self._cam[kernels._O:kernels._O + 3]

    def ray_cam(self, q):
        key = (float(q[0]), float(q[1]))
        ray = self._rays.get(key)
        if ray is None:
            if self._cam is None:
                o, v = self.model.unproject(np.asarray(key, dtype=np.float64))
            else:
                # kernels.unproject_grid's ray of one pixel, without its per-call overhead
                s, vx, vy, vz = kernels.ray(self._cam, *key)
                o, v = self._C + s * self._O, np.array([vx, vy, vz])
            ray = ((o - self.t_ref_cam) @ self.R_ref_cam, v @ self.R_ref_cam)
            self._rays[key] = ray
        return ray

    def orientation(self, q_anchor, tilt, azimuth, roll):
        r'''(o, v, R, R @ centre_board): the board facing the ray (o, v) of q_anchor

None when the ray is not finite. The range along the ray plays no part: a
range search computes this once and moves the board with place().
'''
        o, v = self.ray_cam(q_anchor)
        if not (np.isfinite(o).all() and np.isfinite(v).all()):
            return None
        # board axes facing the ray: z along the ray, x as close to the camera's x as possible
        x = _EX - (_EX @ v) * v
        # |x| as np.linalg.norm computes it (sqrt of the dot product), bit for bit
        if math.sqrt(x.dot(x)) < 1e-6:
            x = np.array([0.0, 1.0, 0.0]) - v[1] * v
        x /= math.sqrt(x.dot(x))
        # y = np.cross(v, x), bit for bit (the same products and differences)
        v0, v1, v2 = v.tolist()
        x0, x1, x2 = x.tolist()
        y = np.array([v1 * x2 - v2 * x1, v2 * x0 - v0 * x2, v0 * x1 - v1 * x0])
        R = np.empty((3, 3))
        R[:, 0], R[:, 1], R[:, 2] = x, y, v
        a = math.radians(azimuth)
        axis = math.cos(a) * x + math.sin(a) * y
        R = (R_from_axis_angle(v, math.radians(roll))
             @ R_from_axis_angle(axis, math.radians(tilt)) @ R)
        return o, v, R, R @ self.centre_board

    def smallest_dot_area(self, Rt):
        r'''Projected area (px^2, of an NDOT_OUTLINE-gon) of the smallest dot at pose Rt'''
        o = self.dot_outlines
        p = (o.reshape(-1, 3) @ Rt[:3].T + Rt[3]) @ self.R_ref_cam.T + self.t_ref_cam
        if self._cam is not None:
            q = np.empty((len(p), 2))
            kernels.project_points(self._cam, np.ascontiguousarray(p), q)
        else:
            q = self.model.project(p)
        q = q.reshape(o.shape[0], o.shape[1], 2)
        x, y = q[..., 0], q[..., 1]
        a = 0.5 * np.abs((x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y).sum(axis=1))
        return float(np.min(a)) if np.all(np.isfinite(a)) else 0.0

    def median_tag_bit(self, Rt):
        r'''The median over the planned tags (tag_quads) of each tag's smallest bit depth,
px, at pose Rt (tag_bit_depths); 0 when a tag does not project'''
        b = tag_bit_depths(self.model, self.tag_quads, Rt, self._cam)
        return float(np.median(b)) if len(b) and np.all(np.isfinite(b)) else 0.0

    def dot_area_range(self, Rt, d, d_fit):
        r'''The range (d_fit <= range <= d) at which the smallest dot of the board at Rt
(range d) keeps min_dot_area px^2: d itself when it does or the target has no dots. A
dot's area falls as 1/range^2: d is scaled by sqrt(area / min_dot_area), never below
d_fit (where the board just fits the middle of the image: its dots can be no larger).'''
        if self.dot_outlines is None or d <= d_fit:
            return d
        a = self.smallest_dot_area(Rt)
        if a >= self.min_dot_area:
            return d
        return max(d_fit, d * math.sqrt(a / self.min_dot_area))

    def place(self, orientation, d):
        r'''Rt_cam_board of an orientation() with the board centre at range d along its ray'''
        o, v, R, Rc = orientation
        return np.vstack((R, o + d * v - Rc))

    def pose(self, q_anchor, d, tilt, azimuth, roll):
        r'''Rt_cam_board placing the board centre at range d along the ray of q_anchor'''
        orientation = self.orientation(q_anchor, tilt, azimuth, roll)
        return None if orientation is None else self.place(orientation, d)

    def fits(self, Rt, outline_cam=None):
        r'''Whether the board at Rt lies in front of the camera, faces it and is in the image

outline_cam: self.outline @ Rt[:3].T, when the caller has it already.
'''
        if Rt is None:
            return False
        if outline_cam is None:
            outline_cam = self.outline @ Rt[:3].T
        if self._cam is not None:
            m = self.margin
            return _outline_fits(outline_cam, Rt, self.cos_view_max, self._R_ref_cam,
                                 self._t_ref_cam, self._cam, m - 0.5, self.W - 0.5 - m,
                                 m - 0.5, self.H - 0.5 - m)
        p_cam = outline_cam + Rt[3]
        if not (p_cam[:, 2] > 0).all():
            return False
        n = Rt[:3, 2]
        # rays from the camera centre: the board must face the camera, not too obliquely
        u = p_cam / np.linalg.norm(p_cam, axis=-1, keepdims=True)
        if not (u @ n).min() >= self.cos_view_max:
            return False
        q = self.model.project(p_cam @ self.R_ref_cam.T + self.t_ref_cam)
        # the bounds are NaN when any q is (min and max propagate NaN): the board does not fit
        (xmin, ymin), (xmax, ymax) = q.min(axis=0).tolist(), q.max(axis=0).tolist()
        m = self.margin
        return (xmin >= m - 0.5 and xmax <= self.W - 0.5 - m
                and ymin >= m - 0.5 and ymax <= self.H - 0.5 - m)

    def closest_fit_range(self, q_anchor, tilt, azimuth, roll):
        r'''Smallest range at which the board fits with its centre on the ray of q_anchor'''
        orientation = self.orientation(q_anchor, tilt, azimuth, roll)
        if orientation is None:
            return None
        outline_cam = self.outline @ orientation[2].T

        def ok(d):
            return self.fits(self.place(orientation, d), outline_cam)
        hi = self.size
        while not ok(hi):
            hi *= 2.0
            if hi > self.max_range:
                return None
        lo = hi / 2.0
        while ok(lo) and lo > 1e-3 * self.size:
            hi, lo = lo, lo / 2.0
        for _ in range(18):
            mid = math.sqrt(lo * hi)
            if ok(mid):
                hi = mid
            else:
                lo = mid
        return hi if hi <= self.max_range else None

    def push(self, q_centre, corner, d, tilt, azimuth, roll):
        r'''Move the board's anchor from the image centre towards an image corner as far as
it still fits: x, y, x or y, x, y, whichever gets further towards the corner (which
order a fisheye's bulging edges allow depends on the image's shape); the board ends
touching both edges'''
        span = np.asarray(corner, dtype=np.float64) - q_centre

        def ok(s):
            return self.fits(self.pose(q_centre + s * span, d, tilt, azimuth, roll))

        def bisect(s, direction):
            lo, hi = 0.0, float(np.min((1.0 - s)[direction > 0] / direction[direction > 0]))
            for _ in range(10):
                mid = 0.5 * (lo + hi)
                if ok(s + mid * direction):
                    lo = mid
                else:
                    hi = mid
            return s + lo * direction

        ex, ey = np.array([1.0, 0.0]), np.array([0.0, 1.0])
        best = None
        for order in ((ex, ey, ex), (ey, ex, ey)):
            s = np.zeros(2)
            for direction in order:
                s = bisect(s, direction)
            if best is None or s.sum() > best.sum():
                best = s
        s = best
        return q_centre + s * span


def _margin_px(model):
    return max(4.0, 0.02 * min(model.width, model.height))


def tag_bit_need_px(shape, psf_sigma_px=PLAN_PSF_SIGMA_PX):
    r'''The bit depth (px) an AprilGrid's tag needs for the detector to give its corners

SYNOPSIS

    tag_bit_need_px((480, 640))       # 3.11 px at the planning blur of 0.7 px

From the detector's own limits, the larger of:

- the quad search (targets.detect_apriltag): a tag whose bit spans fewer than
  MIN_DECIMATED_BIT_PX decimated px may be missed, the image decimated by
  decimate_for(shape) (1 up to 2047 px): 2 px;
- the blurred tag edges (targets.tag_edges): an edge's band keeps its pixels clear of every
  other feature by c = BLUR_REACH_SIGMAS sigma + sqrt(1/2) (a pixel's half-diagonal) +
  SAFETY_PX, 3.11 px at sigma 0.7. Where a light data bit lines the border, the dark side
  of the edge is the 1-bit border alone: its band has dark pixels only where the bit is
  deeper than c ("edge seen from its light side only (tag bits too small for the blur)"
  below). So b = c: every edge of a tag sees its dark side.

Measured (bench_corner_campaign.py --response realistic --seeds 0-3, docs/corners.md): the
weaker need of an edge lined by dark data bits (2 bits of dark, MIN_EDGE_PIXELS / 2 of
them: (8 b - 2 c)(2 b - c) = 20, b = 2.35 px) kept 64-129 of 864 corners on
tiny-320x240 (most dropped "seen from its light side only"), c kept 312-407.

The sharp corner window (targets.corners: TAG_MIN_WINDOW_PIXELS in an L-shaped window of
~15 bits^2) needs less (1.4 px).
'''
    from targets.corners import BLUR_REACH_SIGMAS
    from targets.detect_apriltag import MIN_DECIMATED_BIT_PX, decimate_for
    from targets.tag_edges import SAFETY_PX
    quad = MIN_DECIMATED_BIT_PX * decimate_for(shape)
    c = BLUR_REACH_SIGMAS * float(psf_sigma_px) + math.sqrt(0.5) + SAFETY_PX
    edges = c
    return max(quad, edges)


def tag_bit_depths(model, tag_quads, Rt, cam=None):
    r'''(N,) each tag's smallest bit depth (px) at pose Rt: over its four edges, the
adjacent edges' extent across the edge / 8 (targets._tag_edge_kernels.tag_bit_depths, the
depth the detector's edge bands are placed by: a sheared tag's bits are less deep than
long); NaN where a corner does not project

tag_quads (N,4,3): the tags' outer corners on the board; cam: the packed model (_packed)
or None (model.project).
'''
    p = tag_quads.reshape(-1, 3) @ Rt[:3].T + Rt[3]
    Rt_ref_cam = model.Rt_ref_cam()
    p = p @ Rt_ref_cam[:3].T + Rt_ref_cam[3]
    if cam is not None:
        q = np.empty((len(p), 2))
        kernels.project_points(cam, np.ascontiguousarray(p), q)
    else:
        q = model.project(p)
    from targets._tag_edge_kernels import tag_bit_depths as depths
    return depths(np.ascontiguousarray(q.reshape(-1, 4, 2)))


def tag_subgrid_extents(target):
    r'''[(nx', ny', extent)]: an AprilGrid's central sub-grids, one tag fewer a side each
step down to one tag; each extent its tags' black borders and half the gap between tags
beyond them (a light ring for the quad search and the edges' bands: the tags beyond may
leave the image)'''
    spec = target.spec
    nx, ny = target.grid_shape
    s = float(spec["tag_size"])
    gap = float(spec.get("tag_spacing", 0.3)) * s
    pitch = s + gap
    out = []
    for k in range(1, max(nx, ny)):
        mx, my = max(1, nx - k), max(1, ny - k)
        i0, j0 = (nx - mx) // 2, (ny - my) // 2
        out.append((mx, my, (i0 * pitch - gap / 2, (i0 + mx) * pitch - gap / 2,
                             j0 * pitch - gap / 2, (j0 + my) * pitch - gap / 2)))
    return out


class TagsTooSmallError(NotVisibleError):
    r'''An AprilGrid whose tags this camera cannot resolve in a calibration pose

A property of the camera and the board, not a failure: a campaign records it as
not-applicable (not_applicable = True), with this reason.'''

    not_applicable = True


def plan_poses(model, target, n=6, seed=0, *, allow_offaxis=False, max_range=DEFAULT_MAX_RANGE,
               cover="paper"):
    r'''Plan n board poses that calibrate `model`

SYNOPSIS

    Rt_cam_board_all = plan_poses(model, target, n=6, seed=0)
    # list of n arrays of shape (4,3), in the camera frame of model.Rt_ref_cam()
    Rt_cam_board_all = plan_poses(model, target, n=30, seed=0, cover="corners")

See the module docstring for what the poses are. Deterministic for a seed.
The first poses do not depend on n: plan_poses(n=30)[:6] == plan_poses(n=6),
bit for bit, for either cover.

cover: what poses beyond the six templates do. "paper": cycle through the
templates with other tilt axes and ranges (the boards stay as large, so on a
fisheye they reach no further into the corners). "corners": smaller boards
(COVER_FACTORS times the range at which the board fills the middle) pushed into
the four image corners and onto the four edge midpoints (COVER_ANCHORS), with
tilts of 15-45 deg about varying axes from their own random stream (seed, 1):
the detected points reach the corners and edges, which is what constrains the
rich models (mrcal's documentation: observations near the corners constrain
the distortion there; a splined model is undetermined where nothing was seen).

Raises NotVisibleError (with the reason) when the camera cannot see the
target in a usable calibration pose, CamvalError for a bad n or cover.
'''
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise CamvalError(f"number of poses must be a positive integer; got {n!r}")
    if cover not in COVERS:
        raise CamvalError(f"cover must be one of {', '.join(COVERS)}; got {cover!r}")
    W, H = model.width, model.height
    ph = model.photogrammetric()
    if not allow_offaxis and (abs(ph.Hc - (W - 1) / 2) > W or abs(ph.Vc - (H - 1) / 2) > H):
        off = float(np.degrees(np.arccos(np.clip(
            model.unproject(np.array([(W - 1) / 2, (H - 1) / 2]))[1] @ model.A, -1, 1))))
        raise OffAxisError(
            f"the optical centre ({ph.Hc:.0f}, {ph.Vc:.0f}) px lies far outside the {W}x{H} "
            f"image: the camera looks {off:.1f} deg off its axis A, so a board facing it cannot "
            "constrain focal length and centre (pass allow_offaxis=True to plan anyway)")
    planner = _Planner(model, target, _margin_px(model), max_range)
    q_centre = np.array([(W - 1) / 2, (H - 1) / 2])
    o, v = planner.ray_cam(q_centre)
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(v))):
        raise NotVisibleError(f"the image centre {q_centre.tolist()} does not unproject "
                              "through this camera model")
    rng = np.random.default_rng(seed)
    rng_cover = np.random.default_rng([seed, 1])
    corners = {(sx, sy): ((W - 1) / 2 + sx * W / 2, (H - 1) / 2 + sy * H / 2)
               for sx in (-1, 0, 1) for sy in (-1, 0, 1) if (sx, sy) != (0, 0)}
    poses = []
    for i in range(n):
        anchor, tilt, azimuth, roll, factor = _TEMPLATES[i % len(_TEMPLATES)]
        if i >= len(_TEMPLATES) and cover == "corners":
            k = i - len(_TEMPLATES)
            anchor = COVER_ANCHORS[k % len(COVER_ANCHORS)]
            factor = COVER_FACTORS[(k // len(COVER_ANCHORS)) % len(COVER_FACTORS)]
            tilt = rng_cover.uniform(15.0, MAX_TILT_DEG)
            azimuth = rng_cover.uniform(0.0, 360.0)
            roll = rng_cover.uniform(-10.0, 10.0)
            factor *= rng_cover.uniform(0.95, 1.05)
        elif i >= len(_TEMPLATES):
            # later rounds: other tilt axes and ranges
            azimuth += 60.0 * (i // len(_TEMPLATES))
            factor *= 1.0 + 0.15 * (i // len(_TEMPLATES))
        if not (i >= len(_TEMPLATES) and cover == "corners"):
            tilt = min(MAX_TILT_DEG, max(0.0, tilt + rng.uniform(-5.0, 5.0)))
            azimuth += rng.uniform(-15.0, 15.0)
            roll += rng.uniform(-3.0, 3.0)
            factor *= rng.uniform(0.95, 1.05)
        d_fit = planner.closest_fit_range(q_centre, tilt, azimuth, roll)
        if d_fit is None:
            w, h = target.size(target.planning_extent())
            raise NotVisibleError(
                f"the {target.name!r} board ({w:.3g} x {h:.3g} m) "
                f"does not fit the {W}x{H} image at any range up to {max_range:g} m "
                f"(margin {planner.margin:.0f} px, tilt {tilt:.0f} deg)")
        d = max(1.0, factor) * d_fit
        if d > max_range:
            raise NotVisibleError(
                f"pose {i}: the {target.name!r} board needs a range of {d:.3g} m (it fits the "
                f"{W}x{H} image from {d_fit:.3g} m); more than max_range = {max_range:g} m")
        q_anchor = q_centre if anchor is None else planner.push(
            q_centre, corners[anchor], d, tilt, azimuth, roll)
        Rt = planner.pose(q_anchor, d, tilt, azimuth, roll)
        # a small sensor: nearer, so that the smallest dot stays detectable (DOT_AREA_FACTOR)
        d_dots = d if Rt is None else planner.dot_area_range(Rt, d, d_fit)
        if d_dots < d:
            d = d_dots
            q_anchor = q_centre if anchor is None else planner.push(
                q_centre, corners[anchor], d, tilt, azimuth, roll)
            Rt = planner.pose(q_anchor, d, tilt, azimuth, roll)
        if not planner.fits(Rt):
            raise NotVisibleError(f"pose {i}: no placement of the board fits the {W}x{H} image "
                                  f"at {d:.3g} m with tilt {tilt:.0f} deg")
        if planner.tag_quads is not None and planner.median_tag_bit(Rt) < planner.tag_need_px:
            # a small sensor: a central sub-grid of the tags planned in view, the rest of the
            # board beyond the image (PLAN_PSF_SIGMA_PX, tag_bit_need_px)
            Rt = _subgrid_pose(model, target, planner, i, q_centre, corners, anchor, tilt,
                               azimuth, roll, factor, max_range)
        poses.append(Rt)
    return poses


def _subgrid_pose(model, target, planner, i, q_centre, corners, anchor, tilt, azimuth, roll,
                  factor, max_range):
    r'''Pose i planned with the largest central sub-grid of an AprilGrid
(tag_subgrid_extents) whose median tag bit meets planner.tag_need_px, as the board is
planned (its closest fit, the range factor, pushed into the corner);
TagsTooSmallError when not even one tag does'''
    W, H = model.width, model.height
    best = None
    for mx, my, extent in tag_subgrid_extents(target):
        sub = _Planner(model, target, planner.margin, max_range, extent=extent)
        d_fit = sub.closest_fit_range(q_centre, tilt, azimuth, roll)
        if d_fit is None:
            continue
        d = max(1.0, factor) * d_fit
        q_anchor = q_centre if anchor is None else sub.push(
            q_centre, corners[anchor], d, tilt, azimuth, roll)
        Rt = sub.pose(q_anchor, d, tilt, azimuth, roll)
        if not sub.fits(Rt):
            continue
        bit = sub.median_tag_bit(Rt)
        if bit >= planner.tag_need_px:
            return Rt
        best = (bit, mx, my)
    seen = "no sub-grid fits" if best is None else \
        f"a median tag bit of {best[0]:.2g} px with {best[1]}x{best[2]} tags planned in view"
    raise TagsTooSmallError(
        f"pose {i}: the {target.name!r} board's tags project too small for its detector on "
        f"the {W}x{H} image: {seen} (tilt {tilt:.0f} deg, {max(1.0, factor):.2f} x the "
        f"closest fit), under the {planner.tag_need_px:.2f} px it needs (tag_bit_need_px)")


def image_coverage(q_all, width, height, cells=10):
    r'''Fraction of the image's cells x cells grid that holds at least one point

SYNOPSIS

    image_coverage([det.q for det in detections], W, H)     # 0.64

q_all: arrays (...,2) of pixels (NaN: not detected); the union over all of
them counts. Cells split [-0.5, W-0.5] x [-0.5, H-0.5] evenly.
'''
    hit = np.zeros((cells, cells), dtype=bool)
    for q in q_all:
        q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
        q = q[np.all(np.isfinite(q), axis=1)]
        ix = np.floor((q[:, 0] + 0.5) / width * cells).astype(int)
        iy = np.floor((q[:, 1] + 0.5) / height * cells).astype(int)
        ok = (ix >= 0) & (ix < cells) & (iy >= 0) & (iy < cells)
        hit[iy[ok], ix[ok]] = True
    return float(hit.mean())


def pose_summary(model, target, Rt_cam_board, margin_px=None):
    r'''What a board pose looks like through a camera

SYNOPSIS

    s = pose_summary(model, target, Rt_cam_board)
    s["range_m"], s["tilt_deg"], s["in_view"], s["in_front"], s["q_min"], s["q_max"]

range_m: distance from the camera centre to the board centre (the centre of its
planning outline, target.planning_outline(): what the planner keeps in the image);
tilt_deg: angle between the board normal and that line of sight; in_front: every
planning outline point has camera-frame z > 0 and the board faces the camera;
in_view: that outline projects inside the image with margin_px (default: the
planner's margin); q_min, q_max: the bounding box of the projected outline.
'''
    Rt = np.asarray(Rt_cam_board, dtype=np.float64)
    margin = _margin_px(model) if margin_px is None else float(margin_px)
    outline = target.planning_outline(NOUTLINE_PER_EDGE)
    p_cam = outline @ Rt[:3].T + Rt[3]
    c = target.centre(target.planning_extent()) @ Rt[:3].T + Rt[3]
    n = Rt[:3, 2]
    rng = float(np.linalg.norm(c))
    tilt = float(np.degrees(np.arccos(np.clip(c @ n / rng, -1, 1))))
    Rt_ref_cam = model.Rt_ref_cam()
    q = model.project(p_cam @ Rt_ref_cam[:3].T + Rt_ref_cam[3])
    W, H = model.width, model.height
    finite = bool(np.all(np.isfinite(q)))
    in_view = finite and bool(
        np.all(q[:, 0] >= margin - 0.5) and np.all(q[:, 0] <= W - 0.5 - margin)
        and np.all(q[:, 1] >= margin - 0.5) and np.all(q[:, 1] <= H - 0.5 - margin))
    in_front = bool(np.all(p_cam[:, 2] > 0) and c @ n > 0)
    return {"range_m": rng, "tilt_deg": tilt, "in_view": in_view, "in_front": in_front,
            "q_min": np.nanmin(q, axis=0) if finite else None,
            "q_max": np.nanmax(q, axis=0) if finite else None}

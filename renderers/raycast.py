r'''The exact ray-cast renderer: planar targets through CAHV, CAHVOR and CAHVORE

SYNOPSIS

    from renderers.raycast import RaycastRenderer
    from renderers.base import RenderSettings

    r = RaycastRenderer()
    result = r.render(model, pattern, Rt_cam_board, RenderSettings(spp=16))
    # result.image has shape (model.height, model.width), float32 in [0,1], read-only
    # result.metadata: renderer, version, settings, seconds, coverage, samples, ...
    point = r.render(model, pattern, Rt_cam_board,
                     RenderSettings(spp=16, options={"coverage": "point"}))

A pixel is the mean albedo over its area [ix-0.5, ix+0.5) x [iy-0.5, iy+0.5)
(reference_models.conventions). By default (coverage "area", see "Area
coverage" below) a pixel that sees an edge gets that mean exactly, integrated
over the pixel's preimage on the board; K (RenderSettings.spp) then sets only
the K x K point sampling of the few pixels where the exact integral is not
used (a corner ray that misses the plane, a preimage too curved, overlapping
circles: metadata area_point_sampled_fraction). With coverage "point" (kept
for comparison) every pixel is the average of K x K subsamples at
(ix + (i+0.5)/K - 0.5, iy + (j+0.5)/K - 0.5), i, j = 0..K-1.

Every sample is an exact ray of the camera model: the unprojection of
reference_models.cahvore compiled with numba (float64, no fastmath), including
the moving entrance pupil of a noncentral CAHVORE (E != 0). The ray meets the
board plane z = 0 (board frame: Rt_board_ref = inverse of
compose(model.Rt_ref_cam(), Rt_cam_board)) and the albedo of the
targets.pattern.Pattern there is the sample.

Edge pixels from the projected outlines (the default path of adaptive
rendering, renderers.raycast_outlines): every boundary of the pattern (board
rectangle, cell edges between different albedos, circles) is projected through
the camera model, sampled finely enough that its chords stay within a stated
margin of the curve, and every pixel whose square comes within that margin of
a chord is an edge pixel (renderers._raycast_kernels._mark_chord, band by band in
the render kernel from the chords band_chords lists for each band; the
proof-style argument why that is all of them is raycast_outlines' docstring).
A tile of 32 x 32 pixels without an edge pixel is one ray and a fill; in the
other tiles, the pixels that are not edge pixels take the material of a
neighbour of the same region (or of their centre ray), and the edge pixels are
rendered as in step 3 below, area coverage or K x K point samples, from the
board points of their own and their 8 neighbours' centre rays (traced, not
cached). Where the board is not known to lie wholly in front of the camera (a
corner behind it, an outline point beyond a fisheye's field:
board_image_box, project_outlines), or with RaycastRenderer(outlines=False),
the edge pixels are found by testing pixels:

Adaptive mode gives the same image as full supersampling, bit for bit. A pixel
is the area average computed from integer counts of the materials its
subsamples hit (a pixel that hits one material is that material's albedo
exactly), so a block of subsamples known to hit one material is counted
without tracing it. Whether a region is uniform is decided conservatively:
its board points must all lie farther than the region's footprint radius
from every edge of the pattern (board rectangle, cell edges between
different albedos, circle outlines; circles are found through a bucket grid):

1. tiles of 32x32 pixels outside the projected outline of the board are
   background; other tiles (then 16x16, 8x8, 4x4, 2x2 blocks) are uniform
   when the board point of their centre ray is farther from every edge than
   the largest distance to the board points of the ring of pixel centres
   around them (the image of the block lies inside that ring's image). The
   board points of a tile's interior are computed only when its ring says
   that it is not uniform;
2. a pixel of a non-uniform block is uniform when its centre's board point is
   farther from every edge than its footprint radius (from the Jacobian of
   the neighbouring pixels' board points, plus a bound on the quadratic term,
   plus 1%);
3. an edge pixel's subsamples are split into quadrants; the board point of a
   block's centre is predicted from the pixel's exact centre point and
   Jacobian (to within the quadratic bound + 1% of the footprint); a block
   whose predicted disc has no edge counts towards the material there, and
   only the subsamples within that tolerance of an edge are traced, as exact
   rays (Newton started from the pixel centre's solution). Pixels whose
   footprint is far from affine (near the board plane's horizon) or whose
   neighbours miss the plane are traced in full.

Area coverage (the default; RenderSettings.options "coverage" = "area"): the
pixels that the steps above find uniform are filled as before (their value is
exact either way, so adaptive = False changes nothing under area coverage);
every other pixel gets the albedo integrated exactly over its preimage on
the board, the polygon through the board points of exact rays at
its corners (an (n+1) x (n+1) grid where n = 2, 4, 8 is needed), weighted by
the pixel-to-board density (linear in each quadrilateral). The board
rectangle and the cells are clipped out of it, the circles integrated along
their arcs (renderers._raycast_kernels, "Area coverage"). The error of a
pixel's value is bounded by options["area_tolerance"] (default 1e-4 of its
area, AREA_TOLERANCE) from the curvature of the preimage across the pixel;
where the bound needs n > 8, where a ray misses the plane, or where circles
overlap near the pixel, the pixel is K x K point sampled instead
(metadata area_point_sampled_fraction). tests/test_raycast_area.py checks
edge pixels against an exact line-by-line integral.

The coverage names the records (renderers.base.DEFAULT_OPTIONS: a fullname
says "coverage=area" whether the settings give it or not), so records of
point sampling, the default before, never join those of area coverage.

tests/test_raycast.py checks point sampling's adaptive == full bit for bit on several cameras,
targets and poses (including noncentral CAHVOREs at K = 16).

No ray is cached between renders (RAYCAST_VERSION 3.0): a render traces the
rays it reads. The image's memory is: a render writes every pixel, into a
buffer of an earlier image that its caller has dropped where there is one
(renderers.memory.ImagePool; fresh memory costs page faults, and the first
79 MB arrays of a process cost about as much CPU again as their render),
except a tile of one value that the buffer already holds throughout (the
background around the board: writing a 5120x3840 image costs ~9 ms). The
image is handed out read-only, so that nobody changes what the buffer holds.
'''

import math
import time
from dataclasses import dataclass, field

import numpy as np

from reference_models.errors import CamvalError
from renderers.base import DEFAULT_OPTIONS, RendererError, RenderResult, RenderSettings
from renderers.memory import ImagePool

# 2.0: area coverage is the default; 3.0: edge pixels from the projected outlines, no ray
# cache
RAYCAST_VERSION = "3.0"
COVERAGES = ("area", "point")
DEFAULT_COVERAGE = DEFAULT_OPTIONS["raycast"]["coverage"]
# the image is rendered in tiles of TILE x TILE pixels; a tile far from every edge is
# filled without looking at its pixels
TILE = 32
# the image of the board is taken to lie within this many pixels of its projected outline
BOX_MARGIN_PX = 2.0
MAX_OUTLINE_STEP_PX = 4.0
MAX_BUCKETS = 1 << 22
# a renderer keeps the compiled patterns of this many patterns, the last drawn: a campaign's
# worker alternates targets between jobs, and an AprilTag grid's compile_pattern and
# board features cost ~15 ms
KEEP_PATTERNS = 4
# coverage = "area": the bound on the error of an edge pixel's covered area, as a
# fraction of the pixel's area (renderers._raycast_kernels, "Area coverage"); 1e-4 is
# 1/300 of the K = 16 grid's resolution of one edge pixel (1/32)
AREA_TOLERANCE = 1e-4


class PatternError(CamvalError):
    '''A Pattern the renderer cannot draw (bad extent, albedo, cells or circles).'''


class PoseError(CamvalError):
    '''A board pose that is not a rigid transform (4,3).'''


@dataclass(frozen=True, eq=False)
class CompiledPattern:
    r'''A Pattern as the kernels read it: the albedo of each material and two flat
arrays (layout in renderers._raycast_kernels); derived: what is computed from them
once for every render of the pattern ({name: value}, e.g. raycast_outlines'
board features)'''

    values: np.ndarray   # (Nmaterials,) albedo of each material
    f: np.ndarray        # float64: rectangle, cell grid, bucket grid, circles
    ii: np.ndarray       # int64: material ids, cell materials and masks, buckets
    derived: dict = field(default_factory=dict, repr=False)

    def kernel_args(self):
        return (self.f, self.ii)


def _finite_albedo(name, v):
    v = float(v)
    if not (0.0 <= v <= 1.0):
        raise PatternError(f"pattern {name} = {v!r}; expected an albedo in [0, 1]")
    return v


def compile_pattern(pattern):
    r'''Check a targets.pattern.Pattern and build the lookup tables of the kernels

SYNOPSIS

    cp = compile_pattern(pattern)   # CompiledPattern

Raises PatternError (a CamvalError) naming what is wrong: an empty or
non-finite extent, an albedo outside [0, 1], cells without a positive
cell_size, a circle with a radius that is not > 0.

Materials are the distinct albedo values (background, board, circle, cells);
a cell records which of its 8 neighbours has another material, so that edges
between cells of one albedo are not edges.
'''
    try:
        extent = np.array(pattern.extent, dtype=np.float64).reshape(4)
    except (TypeError, ValueError):
        raise PatternError(f"pattern extent {pattern.extent!r}; expected "
                           "(xmin, xmax, ymin, ymax)") from None
    if not np.all(np.isfinite(extent)) or not (extent[0] < extent[1] and extent[2] < extent[3]):
        raise PatternError(f"pattern extent {extent.tolist()}; expected finite "
                           "(xmin, xmax, ymin, ymax) with xmin < xmax and ymin < ymax")
    background = _finite_albedo("background_value", pattern.background_value)
    board = _finite_albedo("board_value", pattern.board_value)
    circle = _finite_albedo("circle_value", pattern.circle_value)

    values = []

    def material(v):
        if v not in values:
            values.append(v)
        return values.index(v)

    ids = [material(background), material(board), material(circle)]

    # cells, with a ring of board cells so that every cell has 8 neighbours
    cells = pattern.cells
    cell_geometry = [0.0, 0.0, 0.0, 0.0, 0.0]
    cmat = cmask = np.zeros(0, dtype=np.int64)
    if cells is not None:
        cells = np.asarray(cells, dtype=np.float64)
        if cells.ndim != 2 or cells.size == 0:
            raise PatternError(f"pattern cells have shape {cells.shape}; expected (ny, nx)")
        cs = float(pattern.cell_size)
        if not (math.isfinite(cs) and cs > 0.0):
            raise PatternError(f"pattern cell_size = {pattern.cell_size!r}; expected > 0")
        origin = np.array(pattern.cell_origin, dtype=np.float64).reshape(2)
        if not np.all(np.isfinite(origin)):
            raise PatternError(f"pattern cell_origin {origin.tolist()} is not finite")
        finite = cells[np.isfinite(cells)]
        if finite.size and not (finite.min() >= 0.0 and finite.max() <= 1.0):
            raise PatternError(f"pattern cells hold albedo {finite.min()!r}..{finite.max()!r}; "
                               "expected values in [0, 1] (or NaN for transparent)")
        ny, nx = cells.shape
        inner = np.full(cells.shape, ids[1], dtype=np.int64)
        uniq, inverse = np.unique(finite, return_inverse=True)
        if uniq.size:
            uid = np.array([material(float(v)) for v in uniq], dtype=np.int64)
            inner[np.isfinite(cells)] = uid[inverse]
        padded = np.full((ny + 4, nx + 4), ids[1], dtype=np.int64)
        padded[2:-2, 2:-2] = inner
        cmat2 = padded[1:-1, 1:-1]
        cmask2 = np.zeros_like(cmat2)
        for bit, (dx, dy) in enumerate(((-1, 0), (1, 0), (0, -1), (0, 1),
                                        (-1, -1), (1, -1), (-1, 1), (1, 1))):
            neighbour = padded[1 + dy:ny + 3 + dy, 1 + dx:nx + 3 + dx]
            cmask2 |= (neighbour != cmat2).astype(np.int64) << bit
        cmat = cmat2.ravel()
        cmask = cmask2.ravel()
        cell_geometry = [origin[0], origin[1], cs, float(nx), float(ny)]

    circ = pattern.circles
    if circ is None or len(circ) == 0:
        circ = np.zeros((0, 3))
        bucket_geometry = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0]
        bstart = np.zeros(1, dtype=np.int64)
        bitems = np.zeros(0, dtype=np.int64)
    else:
        circ = np.asarray(circ, dtype=np.float64)
        if circ.ndim != 2 or circ.shape[1] != 3:
            raise PatternError(f"pattern circles have shape {circ.shape}; "
                               "expected (N,3): cx, cy, r")
        if not np.all(np.isfinite(circ)):
            raise PatternError("pattern circles hold non-finite numbers")
        bad = np.flatnonzero(~(circ[:, 2] > 0.0))
        if bad.size:
            raise PatternError(f"pattern circle {bad[0]} has radius {float(circ[bad[0], 2])!r}; "
                               "expected a radius > 0 (a zero-size dot cannot be drawn)")
        bucket_geometry, bstart, bitems = _buckets(circ)

    f = np.concatenate((extent, cell_geometry, bucket_geometry, circ.ravel()))
    header = np.array(ids + [0, 0, 0, 0], dtype=np.int64)
    offsets = np.cumsum([len(header), len(cmat), len(cmask), len(bstart)])
    header[3:7] = offsets
    ii = np.concatenate((header, cmat, cmask, bstart, bitems)).astype(np.int64)
    return CompiledPattern(values=np.array(values, dtype=np.float64), f=f, ii=ii)


def _buckets(circ):
    r'''A uniform grid of buckets over the circles: each circle is listed in every
bucket its bounding box touches'''
    lo = (circ[:, :2] - circ[:, 2:3]).min(axis=0)
    hi = (circ[:, :2] + circ[:, 2:3]).max(axis=0)
    size = 2.0 * float(circ[:, 2].max())
    while True:
        nb = np.floor((hi - lo) / size).astype(np.int64) + 1
        if nb[0] * nb[1] <= MAX_BUCKETS:
            break
        size *= 2.0
    b0 = np.clip(np.floor((circ[:, :2] - circ[:, 2:3] - lo) / size).astype(np.int64), 0, nb - 1)
    b1 = np.clip(np.floor((circ[:, :2] + circ[:, 2:3] - lo) / size).astype(np.int64), 0, nb - 1)
    lists = [[] for _ in range(int(nb[0] * nb[1]))]
    for k in range(circ.shape[0]):
        for by in range(b0[k, 1], b1[k, 1] + 1):
            for bx in range(b0[k, 0], b1[k, 0] + 1):
                lists[by * nb[0] + bx].append(k)
    bstart = np.zeros(len(lists) + 1, dtype=np.int64)
    bstart[1:] = np.cumsum([len(x) for x in lists])
    bitems = np.array([k for x in lists for k in x], dtype=np.int64)
    geometry = [lo[0], lo[1], size, 1.0 / size, float(nb[0]), float(nb[1])]
    return geometry, bstart, bitems


def _check_model(model):
    family = getattr(model, "family", None)
    if family not in ("CAHV", "CAHVOR", "CAHVORE"):
        raise CamvalError(f"the ray-cast renderer draws through a CAHV, CAHVOR or CAHVORE "
                          f"model; got {type(model).__name__}")


def _check_pose(Rt_cam_board):
    try:
        Rt = np.array(Rt_cam_board, dtype=np.float64)
    except (TypeError, ValueError):
        raise PoseError("Rt_cam_board is not numeric; expected a (4,3) array") from None
    if Rt.shape != (4, 3):
        raise PoseError(f"Rt_cam_board has shape {Rt.shape}; expected (4,3): R on top, t last")
    if not np.all(np.isfinite(Rt)):
        raise PoseError("Rt_cam_board holds non-finite numbers")
    R = Rt[:3]
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > 1e-6 or np.linalg.det(R) < 0:
        raise PoseError(f"Rt_cam_board's rotation is not a rotation (|R'R - I| = {err:.3g}, "
                        f"det = {np.linalg.det(R):.6g}); expected an orthonormal R, det +1")
    return Rt


def Rt_board_ref(model, Rt_cam_board):
    r'''The transform from the model's reference frame to the board frame

SYNOPSIS

    Rt = Rt_board_ref(model, Rt_cam_board)   # (4,3)
    p_board = p_ref @ Rt[:3].T + Rt[3]
'''
    import mrcal
    return mrcal.invert_Rt(_Rt_ref_board(model, Rt_cam_board))


def _Rt_ref_board(model, Rt_cam_board):
    r'''compose(model.Rt_ref_cam(), Rt_cam_board), the pose checked (_check_pose)'''
    import mrcal
    return mrcal.compose_Rt(model.Rt_ref_cam(), _check_pose(Rt_cam_board))


def board_image_box(model, Rt_cam_board, rect, margin_px=BOX_MARGIN_PX, *, Rt_ref_board=None,
                    cam=None):
    r'''A box (xmin, xmax, ymin, ymax) in the image that holds the image of the board

SYNOPSIS

    qbox = board_image_box(model, Rt_cam_board, (xmin, xmax, ymin, ymax))   # (4,)

Rt_ref_board (compose(model.Rt_ref_cam(), Rt_cam_board)) and cam (the packed model)
may be passed by a caller that has them (RaycastRenderer.render: model.Rt_ref_cam()
costs ~0.25 ms, computed once per render).

When the whole board lies in front of the camera (every corner at a positive
range along A), projection maps it one to one into the image, and its image
is the region bounded by the image of its outline. The outline is projected
densely enough that neighbouring projected points lie within 4 px (the
outline's image curves far less than margin_px between them), so the image of
the board lies in the bounding box of those points grown by margin_px; a
16 x 16 grid of board points is checked to lie inside too. When part of the
board is behind the camera (a wide-angle CAHVORE sees behind its own plane,
and the image of such a board need not be bounded by its outline), when a
point does not project, or when the check fails, the box is the whole
plane (+-inf): nothing is known.
'''
    import mrcal

    from reference_models import kernels
    unknown = np.array([-np.inf, np.inf, -np.inf, np.inf])
    if Rt_ref_board is None:
        Rt_ref_board = mrcal.compose_Rt(model.Rt_ref_cam(), np.asarray(Rt_cam_board, float))
    # the compiled projection (within 1e-10 px of model.project: far inside margin_px)
    if cam is None:
        cam = kernels.pack_model(model)
    xmin, xmax, ymin, ymax = (float(v) for v in rect)
    corners = np.array([[xmin, ymin, 0.0], [xmax, ymin, 0.0], [xmax, ymax, 0.0],
                        [xmin, ymax, 0.0]])
    if not np.all(model.range(mrcal.transform_point_Rt(Rt_ref_board, corners)) > 0.0):
        return unknown
    n = 64
    while True:
        s = np.arange(n) / n
        xy = np.concatenate((
            np.stack((xmin + s * (xmax - xmin), np.full(n, ymin)), -1),
            np.stack((np.full(n, xmax), ymin + s * (ymax - ymin)), -1),
            np.stack((xmax - s * (xmax - xmin), np.full(n, ymax)), -1),
            np.stack((np.full(n, xmin), ymax - s * (ymax - ymin)), -1)))
        p = np.concatenate((xy, np.zeros((len(xy), 1))), -1)
        q = kernels.project_packed(cam, mrcal.transform_point_Rt(Rt_ref_board, p))
        if not np.all(np.isfinite(q)):
            return unknown
        step = np.linalg.norm(np.diff(np.concatenate((q, q[:1])), axis=0), axis=-1).max()
        if step <= MAX_OUTLINE_STEP_PX:
            break
        if n >= 1 << 14:
            return unknown
        n = min(1 << 14, int(n * 1.25 * step / MAX_OUTLINE_STEP_PX) + 1)
    lo = q.min(axis=0) - margin_px
    hi = q.max(axis=0) + margin_px
    gx, gy = np.meshgrid(np.linspace(xmin, xmax, 16), np.linspace(ymin, ymax, 16))
    grid = np.stack((gx.ravel(), gy.ravel(), np.zeros(gx.size)), axis=-1)
    qg = kernels.project_packed(cam, mrcal.transform_point_Rt(Rt_ref_board, grid))
    if not (np.all(np.isfinite(qg)) and np.all(qg >= lo) and np.all(qg <= hi)):
        return unknown
    return np.array([lo[0], hi[0], lo[1], hi[1]])


class RaycastRenderer:
    r"""The embedded exact ray-cast renderer (see the module docstring)

SYNOPSIS

    r = RaycastRenderer(threads=None, outlines=True)
    result = r.render(model, pattern, Rt_cam_board, RenderSettings(spp=16))

threads sets numba's thread count (default: all). outlines=False finds the edge
pixels by testing every pixel (the path a board not wholly in front of the
camera takes) instead of from the projected outlines: for comparison; the
images agree to rounding (tests/test_raycast.py).
"""

    name = "raycast"
    # renders in the camera frame, exactly: cameras that image every camera-frame point
    # alike get the same images (campaigns render them once: harness.runner.group_twins)
    camera_frame_exact = True

    def __init__(self, threads=None, outlines=True):
        if threads is not None and not (isinstance(threads, int) and threads >= 1):
            raise CamvalError(f"threads = {threads!r}; expected a positive integer")
        self.threads = threads
        self.outlines = bool(outlines)
        self._patterns = []     # (pattern, CompiledPattern), the last drawn last
        # every pixel of an image is written: a render takes a buffer its caller has
        # dropped instead of faulting in fresh memory (renderers.memory.ImagePool)
        self._images = ImagePool()

    def version(self):
        import numba
        return f"raycast {RAYCAST_VERSION} (numba {numba.__version__})"

    def _compiled(self, pattern):
        # the list is replaced, never changed in place: a worker's threads may share the
        # renderer (its ImagePool's lock), and a reader then walks a whole list
        kept = self._patterns
        hit = next((cp for p, cp in kept if p is pattern), None)
        cp = compile_pattern(pattern) if hit is None else hit
        others = [x for x in kept if x[0] is not pattern]
        self._patterns = others[len(others) - (KEEP_PATTERNS - 1):] + [(pattern, cp)]
        return cp

    # --- rendering -----------------------------------------------------------
    def render(self, model, scene, Rt_cam_board, settings=None):
        r'''Render a planar target

SYNOPSIS

    result = renderer.render(model, pattern, Rt_cam_board, RenderSettings(spp=16))
    # result.image: (model.height, model.width) float32 in [0,1], read-only (its buffer
    # is rendered into again once dropped: renderers.memory.ImagePool)

ARGUMENTS

- model: a CAHV, CAHVOR or CAHVORE of reference_models.cahvore
- scene: a targets.pattern.Pattern (or anything with a .pattern() method
  returning one, such as a target)
- Rt_cam_board: (4,3) the board in the camera frame model.Rt_ref_cam()
- settings: RenderSettings (spp = K, adaptive, options "coverage": "area" (the
  default) or "point", "area_tolerance"); default K = 16, adaptive, area

RETURNED VALUE

RenderResult(image, metadata). metadata: renderer, version, settings, seconds,
coverage, samples (rays traced in this render: pixel-centre, corner and subsample
rays and the rays that start their Newton solves),
adaptive_fraction (pixels supersampled / pixels), board_fraction (pixels whose
centre ray sees the board; 0 for a board behind the camera, which renders as
blank background), edges ("outlines": edge pixels from the projected outlines,
"tested": pixels tested), blocks_tested and pixels_tested (outlines: tiles with
edge pixels and edge pixels; tested: blocks and pixels tested), outline_seconds
(projecting the outlines and listing their chords by band), threads; under area coverage
also area_tolerance, area_fraction (pixels integrated exactly / pixels) and
area_point_sampled_fraction (edge pixels K x K point sampled instead / pixels).
'''
        import numba

        from reference_models import kernels
        from renderers import _raycast_kernels as kern

        t0 = time.perf_counter()
        if settings is None:
            settings = RenderSettings()
        if not isinstance(settings, RenderSettings):
            raise CamvalError(f"settings must be a RenderSettings; got {type(settings).__name__}")
        K = settings.spp
        if isinstance(K, bool) or not isinstance(K, int) or K < 1:
            raise CamvalError(f"supersampling K must be a positive integer; got {K!r}")
        _check_model(model)
        from targets.pattern import Pattern
        if not isinstance(scene, Pattern) and callable(getattr(scene, "pattern", None)):
            scene = scene.pattern()
        if not isinstance(scene, Pattern):
            raise CamvalError(f"the ray-cast renderer draws a targets.pattern.Pattern; "
                              f"got {type(scene).__name__}")
        area, tol = _coverage(settings)
        cp = self._compiled(scene)
        import mrcal
        # Rt_board_ref(model, Rt_cam_board), its inverse and the packed model once
        Rt_ref_board = _Rt_ref_board(model, Rt_cam_board)
        Rt = mrcal.invert_Rt(Rt_ref_board)
        cam, noncentral = kernels.pack_model(model), not model.is_central
        if self.threads is not None:
            numba.set_num_threads(self.threads)

        adaptive = area or bool(settings.adaptive)
        qbox = board_image_box(model, Rt_cam_board, cp.f[:4], Rt_ref_board=Rt_ref_board,
                               cam=cam)
        H, W = model.height, model.width
        t1 = time.perf_counter()
        outlines = None
        if adaptive and self.outlines and np.all(np.isfinite(qbox)):
            from renderers.raycast_outlines import project_outlines
            outlines = project_outlines(model, Rt_cam_board, cp, Rt_ref_board=Rt_ref_board,
                                        cam=cam)
        if outlines is not None:
            bstart, chords = kern.band_chords(outlines.q, outlines.starts, outlines.closed,
                                              outlines.margin, TILE, H, W)
            outline = (outlines.q, outlines.margin, bstart, chords)
        else:
            outline = (np.zeros((0, 2)), np.zeros(0), np.zeros(1, dtype=np.int64),
                       np.zeros((0, 3), dtype=np.int64))
        t_outlines = time.perf_counter() - t1

        R = Rt[:3]
        t = Rt[3]
        O = cam[12:15]
        xf = np.concatenate((R.ravel(), R @ model.C + t, R @ O))
        nbands = -(-H // TILE)
        out, filled = self._images.take((H, W), np.float32, (nbands, -(-W // TILE)))
        stats = np.zeros((nbands, 8 if area else 6), dtype=np.int64)
        try:
            kern.render_kernel(cam, noncentral, xf, K, adaptive, TILE, cp.values, out, filled,
                               stats, cp.kernel_args(), qbox, numba.get_num_threads(), area,
                               tol, outlines is not None, outline)
        except BaseException:
            filled[:] = np.nan
            raise
        # the buffer's tiles are known (filled) only while nobody else writes into it
        out.flags.writeable = False
        total = stats.sum(axis=0)
        if total[5] != 0:
            raise RendererError(f"the ray-cast renderer produced {int(total[5])} non-finite "
                                "pixels (a bug)")
        seconds = time.perf_counter() - t0
        metadata = {
            "renderer": self.name,
            "version": self.version(),
            "settings": settings.as_dict(),
            "seconds": seconds,
            "samples": int(total[0]),
            "adaptive_fraction": float(total[1]) / (W * H),
            "board_fraction": float(total[2]) / (W * H),
            "blocks_tested": int(total[3]),
            "pixels_tested": int(total[4]),
            "edges": "outlines" if outlines is not None else "tested",
            "outline_seconds": t_outlines,
            "threads": numba.get_num_threads(),
            "coverage": "area" if area else "point",
        }
        if area:
            metadata["area_tolerance"] = tol
            metadata["area_fraction"] = float(total[6]) / (W * H)
            metadata["area_point_sampled_fraction"] = float(total[7]) / (W * H)
        return RenderResult(image=out, metadata=metadata)


def _coverage(settings):
    r'''(area, tolerance) from settings.options: coverage "area" (DEFAULT_COVERAGE: exact
covered area of edge pixels, within area_tolerance of a pixel's area; default
AREA_TOLERANCE) or "point" (K x K point samples)'''
    options = settings.options or {}
    coverage = options.get("coverage", DEFAULT_COVERAGE)
    if coverage not in COVERAGES:
        raise CamvalError(f"coverage = {coverage!r}; expected \"area\" (exact covered area of "
                          "edge pixels, the default) or \"point\" (K x K point samples)")
    tol = options.get("area_tolerance", AREA_TOLERANCE)
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not (0.0 < tol < 1.0):
        raise CamvalError(f"area_tolerance = {tol!r}; expected a fraction of a pixel's area "
                          "in (0, 1)")
    return coverage == "area", float(tol)

r'''Find the dots of a dot-grid target: subpixel centroids, numbered with the orientation mark

SYNOPSIS

    from targets.detect_dots import detect_dots

    det = detect_dots(image, target)    # targets.detection.Detection
    det.q                               # (nx*ny,2): centroid of dot iy*nx + ix, NaN if not found

Steps:

1. Dark blobs: pixels darker than an Otsu threshold, grouped into 8-connected
   components; components touching the image border, smaller than min_area_px
   or larger than a quarter of the image are dropped.
2. Lattice: from a seed blob (the largest few first) the grid is grown
   breadth-first: each neighbour is predicted from the dots found so far
   (parallelogram or linear extrapolation, so perspective and lens distortion
   do not lead it astray) and accepted if a blob of similar size lies within
   0.3 spacings of the prediction.
3. Numbering: blobs larger than the local median by the mark's size ratio are
   the orientation mark; of the 8 rotations/flips of the lattice (and its
   offsets, if part of the grid is missing) exactly one must put the mark
   where the target has it. This also numbers the grid correctly through a
   mirrored camera. A target without a mark is numbered with board x along
   image +x (ambiguous by design; the info says so).
4. Subpixel centre: the darkness-weighted centroid over the blob mask
   dilated by window_dilation_px (default 2; wider on a blurred image, by the blur its
   dots' edges show: blur_window) - not a bounding box, which
   picks up grey board-edge pixels - with weights 1 - intensity/(board
   level), clipped at 0. The board level is a plane fitted to a ring around
   the window (ring_px wide), so it follows shading across the board: with a
   uniform board the weights are (board level - intensity) up to a constant;
   under multiplicative shading (vignetting) they stay proportional to the
   dot area each pixel covers (a 50 % vignette biased the plain weights by
   0.03 px RMS on 320x240 test renders).

Step 1's labelling, 3's mark test and 4 (and the Otsu histogram) run as compiled
kernels (targets._dot_kernels, numba: one call a dot instead of ~40 numpy/OpenCV calls);
mark_flags' and _dot_centroid's numpy code here is their reference (the tests
compare) and _dot_centroid the fallback for a degenerate plane fit.

For a uniformly dark dot on a uniform board imaged as an area average, this
centroid is the area centroid of the dot's projected outline:
targets.centroids.expected_centroids() gives it exactly.
'''

import math
import sys
import threading

import numpy as np

from . import _dot_kernels as _kernels
from .boards import apply_grid_transform, grid_transforms
from .detection import as_float_image, failed, median, result

DETECTOR = "dots"
NEIGHBOUR_TOLERANCE = 0.3      # of the local spacing
AREA_RATIO_MAX = 4.0           # between neighbouring blobs
NSEEDS = 6
OTSU_PIXELS = 1_000_000        # the threshold is computed on about this many pixels
# above this many pixels the blobs are located in an image reduced REDUCTION times, and
# labelled at full resolution in their boxes only (5120x3840: 0.1 s instead of 1 s)
LARGE_IMAGE_PIXELS = 4_500_000
REDUCTION = 4
MIN_REDUCED_AREA_PX = 4        # smaller reduced blobs are not located this way
MIN_REDUCED_BLOBS = 4          # fewer: the full image is labelled instead
MIN_RING_FOR_PLANE = 12
MIN_CONTRAST = 0.02            # an image whose range (max - min) is not above this is refused
_NO_FREE = np.zeros((1, 1), bool)     # dot_centroid's free mask when no other blob is near
ALL_TRANSFORMS = [(swap, fa, fb) for swap in (False, True) for fa in (False, True)
                  for fb in (False, True)]


def _otsu(img):
    v = img.ravel()     # contiguous (a copy of a subsample): 10x faster passes below
    h, edges = _histogram(v, 1024, float(v.min()), float(v.max()))
    centres = 0.5 * (edges[:-1] + edges[1:])
    w0 = np.cumsum(h)
    w1 = w0[-1] - w0
    m0 = np.cumsum(h * centres)
    with np.errstate(divide="ignore", invalid="ignore"):
        mu0 = m0 / w0
        mu1 = (m0[-1] - m0) / w1
        between = w0 * w1 * (mu0 - mu1) ** 2
    between[~np.isfinite(between)] = -1
    return float(edges[int(np.argmax(between)) + 1])


def _histogram(v, bins, lo, hi):
    r'''np.histogram(v, bins, range=(lo, hi)) of a 1-D float v within [lo, hi]: the same
counts and edges, in one pass over v instead of np.histogram's twenty

SYNOPSIS

    h, edges = _histogram(v, 1024, float(v.min()), float(v.max()))

np.histogram estimates each value's bin in double precision from v - lo (in v's
precision) and then corrects it by one bin either way against its edges (in v's
precision), so that a value counts in the bin [edges[i], edges[i+1]) that holds it, the
last bin closed. Here the estimate is made in v's precision: it is a small fraction of a
bin off at most (the edges are far wider apart than v's resolution; otherwise
np.histogram itself is called), and the same correction makes it that bin: one pass of
targets._dot_kernels.histogram_counts.'''
    edges = np.linspace(lo, hi, bins + 1, dtype=np.result_type(lo, hi, v))
    if v.dtype not in (np.float32, np.float64) or not hi - lo > 1e-3 * max(abs(lo), abs(hi)):
        return np.histogram(v, bins=bins, range=(lo, hi))
    lo, scale = edges.dtype.type(lo), edges.dtype.type(bins / (hi - lo))
    n = _kernels.histogram_counts(np.ascontiguousarray(v), edges, lo, scale)
    return n, edges


def _is_large(image):
    shape = np.shape(image)
    return len(shape) >= 2 and shape[0] * shape[1] > LARGE_IMAGE_PIXELS


def _reduce(img, s):
    r'''img reduced s times by area averaging (cv2.INTER_AREA), as _blobs_from_reduced()
takes it'''
    import cv2
    H, W = img.shape
    return cv2.resize(img, (W // s, H // s), interpolation=cv2.INTER_AREA)


def _range(img, small=None):
    r'''(img.min(), img.max()), the same values and type: NaN or +-inf if a pixel is

With the reduced image (_reduce) of img, in one pass (cv2.minMaxLoc) instead of two when
the reduced image is finite: each of its pixels sums pixels of img with positive
weights, so a NaN or infinite pixel of img makes one NaN or infinite (cv2.minMaxLoc
would skip a NaN); where img sums to an overflow it is computed the numpy way.'''
    import cv2
    if small is not None and np.isfinite(small.min()) and np.isfinite(small.max()):
        lo, hi = cv2.minMaxLoc(img)[:2]
        return img.dtype.type(lo), img.dtype.type(hi)
    return img.min(), img.max()


def _scan(img, s, step):
    r'''(small, sub): the reduced image _reduce(img, s) and the subsample img[::step, ::step]
(a contiguous copy, raveled), in one pass over img

SYNOPSIS

    small, sub = _scan(img, 4, 4)
    reason = _image_problem(img, small)     # the range, only where small leaves it open

For s = 4 (REDUCTION) and an image of whole 4x4 blocks, one compiled pass
(targets._dot_kernels.reduce4_and_subsample: cv2's area average of whole blocks, bit for
bit): 5120x3840 float32 in 8 ms of CPU where cv2.resize and the subsample's copy took 12
(load 10, 2 cores), into arrays reused from call to call (_scan_buffers): 7.1 ms where
fresh ones made it 9.3-10.4 (load 12). Otherwise cv2 reduces the image and the subsample
is copied after.'''
    H, W = img.shape
    if s != 4 or H % s or W % s or img.dtype not in (np.float32, np.float64):
        return _reduce(img, s), img[::step, ::step].ravel()
    small, sub = _scan_buffers(((H // s, W // s), (-(-H // step), -(-W // step))), img.dtype)
    _kernels.reduce4_and_subsample(img, small, sub, step)
    return small, sub.ravel()


# this thread's last _scan arrays: ((shapes, dtype), arrays)
_SCAN_BUFFERS = threading.local()
# the references to an array of _scan_buffers' tuple that nothing else holds: the tuple,
# sys.getrefcount's argument and the loop's name
_IDLE_REFERENCES = 3


def _scan_buffers(shapes, dtype):
    r'''Uninitialised C-contiguous arrays of these shapes and dtype for _scan: this thread's
from its previous call when they have the same shapes and nothing else holds them (or a view
of them), else new ones (kept for the next call)

Fresh arrays are fresh memory: _scan's two of a 5120x3840 image (4.9 MB each) faulted in
about 1100 pages per detection, half of its page faults.'''
    key = (shapes, np.dtype(dtype))
    held = getattr(_SCAN_BUFFERS, "arrays", None)
    if held is not None and held[0] == key and all(
            sys.getrefcount(a) <= _IDLE_REFERENCES for a in held[1]):
        return held[1]
    arrays = tuple(np.empty(shape, dtype) for shape in shapes)
    _SCAN_BUFFERS.arrays = (key, arrays)
    return arrays


def _shows_contrast(small):
    r'''True when the reduced image small (_reduce) of an image proves that the image
is finite and its range hi - lo exceeds MIN_CONTRAST, as _image_problem() tests them,
without a pass over the image

A NaN or infinite pixel makes small non-finite (_range). Each pixel of small is a
float32 average of a block, within 16 u B of the block's exact average (u = 2^-24: 15
roundings of the sum, one of the product; B the largest pixel magnitude), and the exact
average lies within the image's range. Were that range at most MIN_CONTRAST, every
pixel would be within MIN_CONTRAST of every block's average, so B <= (m + MIN_CONTRAST)
/ (1 - 16 u) with m = min(|small.min()|, |small.max()|), and small's range at most
MIN_CONTRAST + 32 u B: a range of small beyond MIN_CONTRAST + 1e-5 (m + 1) (32 u =
1.9e-6) shows the contrast, with room for the float32 rounding of the test's hi - lo.'''
    s_lo, s_hi = float(small.min()), float(small.max())
    if not (math.isfinite(s_lo) and math.isfinite(s_hi)):
        return False
    m = min(abs(s_lo), abs(s_hi))      # at least small's smallest magnitude
    return s_hi - s_lo > MIN_CONTRAST + 1e-5 * (m + 1.0)


def _image_problem(img, small=None, dtype=None):
    r'''Why img holds no target for any threshold: "the image has non-finite pixels" or
"no contrast in the image (range lo..hi)"; None when it may hold one

With its reduced image small (_reduce), no pass over img when small shows the contrast
(_shows_contrast); else the range of img (_range), taken as dtype (a wider float type:
the range of img converted to it) when given.'''
    if small is not None and _shows_contrast(small):
        return None
    lo, hi = _range(img, small)
    if dtype is not None:
        lo, hi = dtype(lo), dtype(hi)
    # min and max propagate NaN and reach +-inf: finite both iff every pixel is finite
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "the image has non-finite pixels"
    if not hi - lo > MIN_CONTRAST:
        return f"no contrast in the image (range {lo:.3g}..{hi:.3g})"
    return None


def _blobs_from_reduced(img, thr, s, small=None):
    r'''(masks, stats, centroids) of the components of img < thr, found through its image
small reduced s times (_reduce(img, s), made if not given): None when the reduced image
shows too few blobs of a size that survives the reduction (the caller then labels the
full image)

stats and centroids are those cv2.connectedComponentsWithStats gives the components
(numbered box by box); masks[k] is component k's pixels (bool) over its box stats[k, :4]
(masks[0] is None). They replace a label image of the full size (78 MB on 5120x3840,
whose pages cost 10 ms to fault in): _label_image() makes any crop of it.

The reduced image (area average) locates the dark blobs; each is then labelled at full
resolution inside its box widened by 2 s pixels, and a full-resolution component is kept
when it lies wholly inside that box. So every dot that the reduction shows gets exactly
the pixels, statistics and centroid of the full labelling; the label image is zero
elsewhere (background, or dark specks too small to show in the reduced image).'''
    H, W = img.shape
    small = _reduce(img, s) if small is None else small
    st = _reduced_blobs(small, thr)
    if len(st) < MIN_REDUCED_BLOBS:
        return None
    margin = 2 * s
    boxes = [(max(0, bx * s - margin), max(0, by * s - margin),
              min(W, (bx + bw) * s + margin), min(H, (by + bh) * s + margin))
             for bx, by, bw, bh in st]
    stats = [[0, 0, 0, 0, 0]]
    centroids = [np.zeros(2)]
    masks = [None]
    _label_stack(img, thr, boxes, stats, centroids, masks)
    return masks, np.array(stats, np.int64), np.array(centroids)


def _label_image(masks, stats, xa, ya, xb, yb):
    r'''The label image (int32) over [ya:yb, xa:xb] of components given by masks and stats
(as _blobs_from_reduced returns them): 0 where no component is'''
    x, y, w, h = (stats[:, k] for k in range(4))
    near = np.flatnonzero((x < xb) & (x + w > xa) & (y < yb) & (y + h > ya))
    lab = np.zeros((yb - ya, xb - xa), np.int32)
    for k in near.tolist():
        if masks[k] is None:
            continue
        kx, ky, kw, kh = stats[k, :4].tolist()
        x0, y0, x1, y1 = max(kx, xa), max(ky, ya), min(kx + kw, xb), min(ky + kh, yb)
        mine = masks[k][y0 - ky:y1 - ky, x0 - kx:x1 - kx]
        lab[y0 - ya:y1 - ya, x0 - xa:x1 - xa][mine] = k
    return lab


def _label_whole(img, thr):
    r'''(masks, stats, centroids) of every component of img < thr, as _blobs_from_reduced()
gives them and cv2.connectedComponentsWithStats numbers them: the whole image as one
box (_label_stack)'''
    H, W = img.shape
    stats, centroids, masks = [[0, 0, 0, 0, 0]], [np.zeros(2)], [None]
    _label_stack(img, thr, [(0, 0, W, H)], stats, centroids, masks)
    return masks, np.array(stats, np.int64), np.array(centroids)


def _reduced_blobs(small, thr):
    r'''Boxes (x, y, w, h) of the components of the reduced image's dark pixels (small <
thr) that detect_dots would keep: not touching the border, of MIN_REDUCED_AREA_PX to a
quarter of the image; in label order'''
    H, W = small.shape
    comps, _ = _kernels.label_boxes(small, small.dtype.type(thr),
                                    np.array([[0, 0, W, H]], np.int64))
    return [(x, y, w, h) for _, x, y, w, h, area, _, _ in comps.tolist()
            if x > 0 and y > 0 and x + w < W and y + h < H
            and MIN_REDUCED_AREA_PX <= area <= 0.25 * small.size]


def _label_stack(img, thr, boxes, stats, centroids, masks):
    r'''Label img < thr in each box as if alone: one compiled call for all boxes

A component lying wholly inside its box and not yet labelled (through a neighbouring
box) gets the next label: its row of stats, centroids and masks (appended to these
lists), as cv2.connectedComponentsWithStats gives them for the box alone, in its label
order (targets._dot_kernels.label_boxes: row runs joined 8-connected, ordered by each
component's first 2x2 block, as cv2 numbers them). The centroid is the mean of the
pixels' box-relative coordinates (exact integer sums over the area) plus the box's
corner: cv2's centroid of the box labelled alone, bit for bit.

A component wholly inside its box is a component of the whole image, so one labelled
through another box has the same box and pixels, and components of the image are
disjoint: a component is taken iff one of the same box shares a pixel with it.'''
    # numpy's img < thr: a float threshold in img's type, a numpy scalar in the wider type
    comps, pixels = _kernels.label_boxes(img, np.result_type(img, thr).type(thr),
                                         np.array(boxes, np.int64).reshape(-1, 4))
    taken = {}
    for k, st in enumerate(stats[1:], 1):
        taken.setdefault(tuple(st[:4]), []).append(k)
    end = 0
    for i, x, y, w, h, area, sx, sy in comps.tolist():
        start, end = end, end + w * h
        mine = pixels[start:end].reshape(h, w)
        key = (x, y, w, h)
        if any(masks[j].any(where=mine) for j in taken.get(key, ())):
            continue                    # already taken through a neighbouring box
        taken.setdefault(key, []).append(len(stats))
        stats.append([*key, area])
        centroids.append(np.array([sx / area, sy / area]) + boxes[i][:2])
        masks.append(mine)


def _disk(r):
    import cv2
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def _grow(c, area, seed, tree, max_extent):
    r'''Grow a lattice from blob `seed`; returns {(a, b): blob index} or None'''
    k = min(9, len(c))
    if k < 2:
        return {(0, 0): seed}
    _, nb = tree.query(c[seed], k=k)
    nb = [j for j in np.atleast_1d(nb)[1:] if j < len(c)
          and 1 / AREA_RATIO_MAX < area[j] / area[seed] < AREA_RATIO_MAX]
    if not nb:
        return {(0, 0): seed}
    u = c[nb[0]] - c[seed]
    v = None
    for j in nb[1:]:
        w = c[j] - c[seed]
        if abs(w @ u) / (np.linalg.norm(w) * np.linalg.norm(u)) < 0.6:
            v = w
            break
    if v is None:
        # a single row of dots: any perpendicular will do for the second axis
        v = np.array([-u[1], u[0]])
    # the walk itself: _kernels.grow_lattice (one compiled call; its doc says how)
    ka, kb, idx, n = _kernels.grow_lattice(
        np.ascontiguousarray(c, np.float64), np.ascontiguousarray(area, np.float64),
        int(seed), np.asarray(u, np.float64), np.asarray(v, np.float64),
        max_extent ** 2 + 4 * max_extent, NEIGHBOUR_TOLERANCE, AREA_RATIO_MAX)
    if n < 0:
        return None
    return dict(zip(zip(ka.tolist(), kb.tolist(), strict=True), idx.tolist(), strict=True))


# the neighbourhood (lattice steps each way) whose areas predict a dot's own
MARK_NEIGHBOURHOOD = 2


def mark_flags(nodes, area, ratio_threshold):
    r'''(len(area),) bool: the lattice's dots larger than their neighbourhood predicts

A dot is a mark when its blob area exceeds the area its lattice neighbours (within
MARK_NEIGHBOURHOOD steps) predict by more than ratio_threshold (the mark's diameter
over the small dots': half the mark's area ratio in log). The prediction is a plane in
log area over the lattice offsets, so it follows perspective: a dot on the lattice's
edge is predicted by extrapolation from the rows inward, not by their median (on a
board seen obliquely through a wide lens, areas fall 1.4x a row: an edge row then
sat 1.41x above its inward neighbours' median and read as marks). Neighbours that are
themselves far above the plane (other marks) are left out and the plane refitted.
With fewer than 3 neighbours off one line the median of the 8 adjacent ones decides.
'''
    if not nodes:
        return np.zeros(len(area), bool)
    return _kernels.mark_flags(np.array(list(nodes.keys()), np.int64),
                               np.array(list(nodes.values()), np.int64),
                               np.asarray(area, np.float64), float(ratio_threshold),
                               MARK_NEIGHBOURHOOD)


def _mark_flags_numpy(nodes, area, ratio_threshold):
    r'''mark_flags() the numpy way: the reference of targets._dot_kernels.mark_flags'''
    is_mark = np.zeros(len(area), bool)
    log_thr = np.log(ratio_threshold)
    la = np.log(np.maximum(area, 1e-300))
    R = MARK_NEIGHBOURHOOD
    for (ka, kb), j in nodes.items():
        offs, vals = [], []
        for da in range(-R, R + 1):
            for db in range(-R, R + 1):
                k = nodes.get((ka + da, kb + db))
                if (da or db) and k is not None:
                    offs.append((1.0, da, db))
                    vals.append(la[k])
        if not offs:
            continue
        A, y = np.array(offs), np.array(vals)
        keep = np.ones(len(y), bool)
        pred = None
        for _ in range(3):
            Ak = A[keep]
            N = Ak.T @ Ak
            # fewer than 3 neighbours off one line: no plane (offsets are small integers,
            # so a collinear set makes N exactly singular)
            if keep.sum() < 3 or abs(np.linalg.det(N)) < 0.5:
                pred = None
                break
            coef = np.linalg.solve(N, Ak.T @ y[keep])
            pred = coef[0]
            high = (y - A @ coef) > 0.5 * log_thr
            if not np.any(high & keep):
                break
            keep &= ~high
        if pred is None:
            neigh = [nodes[(ka + da, kb + db)] for da in (-1, 0, 1) for db in (-1, 0, 1)
                     if (da or db) and (ka + da, kb + db) in nodes]
            if neigh:
                is_mark[j] = area[j] / median(area[neigh]) > ratio_threshold
            continue
        is_mark[j] = la[j] - pred > log_thr
    return is_mark


def _number(nodes, is_mark, target):
    r'''Number lattice (a, b) as grid (ix, iy) by the mark: -> (ix, iy, info) or a reason'''
    nx, ny = target.grid_shape
    ab = np.array(list(nodes.keys()))
    a = ab[:, 0] - ab[:, 0].min()
    b = ab[:, 1] - ab[:, 1].min()
    na, nb = a.max() + 1, b.max() + 1
    mark_spec = target.spec.get("orientation_mark")
    marks = set() if mark_spec is None else {tuple(p) for p in mark_spec["dots"]}
    observed = np.array([is_mark[nodes[tuple(k)]] for k in ab])
    matches = []
    for t in ALL_TRANSFORMS:
        i, j = apply_grid_transform(t, a, b, na, nb)
        ex, ey = (nb, na) if t[0] else (na, nb)
        for ox in range(0, nx - ex + 1):
            for oy in range(0, ny - ey + 1):
                mapped = {(int(x) + ox, int(y) + oy) for x, y in zip(i, j, strict=True)}
                got = {(int(x) + ox, int(y) + oy)
                       for x, y, m in zip(i, j, observed, strict=True) if m}
                expected = marks & mapped
                if marks and got == expected and expected:
                    matches.append((t, ox, oy))
                elif not marks:
                    matches.append((t, ox, oy))
    matches = list(dict.fromkeys(matches))
    if not matches:
        return f"the orientation mark was not found where the target has it " \
               f"({int(observed.sum())} large dots seen in a {na}x{nb} lattice)"
    if marks and len(matches) > 1:
        return f"the orientation mark leaves {len(matches)} ways to number the " \
               f"{na}x{nb} lattice of dots found"
    t, ox, oy = matches[0]
    i, j = apply_grid_transform(t, a, b, na, nb)
    return np.asarray(i) + ox, np.asarray(j) + oy, {"transform": list(t)}


def _unmarked_choice(nodes, c, target):
    r'''Without a mark: the numbering with board x along image +x and y along image +y'''
    nx, ny = target.grid_shape
    ab = np.array(list(nodes.keys()))
    a = ab[:, 0] - ab[:, 0].min()
    b = ab[:, 1] - ab[:, 1].min()
    na, nb = a.max() + 1, b.max() + 1
    q = np.array([c[nodes[tuple(k)]] for k in ab])
    best = None
    for t in grid_transforms(na, nb, nx, ny):
        i, j = apply_grid_transform(t, a, b, na, nb)
        score = 0.0
        if np.ptp(i) > 0:
            score += np.corrcoef(i, q[:, 0])[0, 1]
        if np.ptp(j) > 0:
            score += np.corrcoef(j, q[:, 1])[0, 1]
        if best is None or score > best[0]:
            best = (score, np.asarray(i), np.asarray(j), t)
    if best is None:
        return f"found a {na}x{nb} lattice of dots; expected {nx}x{ny}"
    return best[1], best[2], {"transform": list(best[3]),
                              "note": "target has no orientation mark: numbering assumed"}


def _plane(A, v):
    r'''Least squares a, b, c of v = A (a, b, c) by the normal equations: 3 well-scaled
unknowns (centred coordinates), 10x cheaper than lstsq for these few dozen points'''
    try:
        return np.linalg.solve(A.T @ A, A.T @ v)
    except np.linalg.LinAlgError:   # the ring's kept pixels are collinear
        return np.linalg.lstsq(A, v, rcond=None)[0]


def _board_level(crop, ring, window, xx, yy):
    r'''The board's intensity around a dot: a plane a + b x + c y fitted (with one round of
outlier rejection) to the ring pixels, so that a shading gradient does not bias the
centroid; the ring's median when it is too small for a plane

xx, yy: the pixel coordinates of the crop's columns (1,w) and rows (h,1), whole numbers.
The plane is returned as an array of the crop's shape, the median as a scalar.

The ring's pixels in raster order, their coordinates' means from the exact integer sums
(np.mean's values bit for bit) and the columns of A written in place: the values of
crop[ring], np.nonzero(ring), rx.mean() and np.column_stack((1, x, y)).'''
    i = np.flatnonzero(ring)
    v = crop.ravel().take(i)
    if len(v) < MIN_RING_FOR_PLANE:
        return float(median(v)) if len(v) else float(crop[window].max())
    ry, rx = np.divmod(i, ring.shape[1])
    rx += int(xx[0, 0])
    ry += int(yy[0, 0])
    xm, ym = rx.sum() / len(i), ry.sum() / len(i)
    A = np.empty((len(i), 3))
    A[:, 0] = 1.0
    np.subtract(rx, xm, out=A[:, 1])
    np.subtract(ry, ym, out=A[:, 2])
    # fit all, then again without the pixels beyond 5 sigma (MAD) of that fit
    r = np.abs(v - A @ _plane(A, v))
    keep = np.flatnonzero(r < 5 * 1.4826 * (median(r) + 1e-12) + 1e-9)
    coef = _plane(A.take(keep, axis=0), v.take(keep))
    return coef[0] + coef[1] * (xx - xm) + coef[2] * (yy - ym)


def _crowded(stats, labels, xa, ya, xb, yb, chunk=1_000_000):
    r'''(len(labels),) bool: whether another component's box (stats, row 0 not one) reaches
the crop [ya:yb, xa:xb] of each component of labels (arrays of the crops' corners), in
pieces of about chunk box tests'''
    sx, sy, sw, sh = (stats[:, k] for k in range(4))
    out = np.zeros(len(labels), bool)
    step = max(1, chunk // max(1, len(stats)))
    for i in range(0, len(labels), step):
        j = slice(i, i + step)
        near = ((sx < xb[j, None]) & (sx + sw > xa[j, None]) & (sy < yb[j, None])
                & (sy + sh > ya[j, None]))
        near[:, 0] = False
        near[np.arange(len(near)), labels[j]] = False
        out[j] = near.any(axis=1)
    return out


def _dot_masks(masks, stats, label, xa, ya, xb, yb, crowded):
    r'''(mask, free) over the crop [ya:yb, xa:xb] of blob `label`: its pixels (uint8) and
the pixels of no blob (_dot_free), as the numpy centroid (_dot_centroid) takes them

masks, stats: as _blobs_from_reduced() gives them: the blob's mask is copied into the
crop (the compiled centroid reads masks[label] where it lies instead).'''
    x, y, w, h = stats[label, :4].tolist()
    mask = np.zeros((yb - ya, xb - xa), np.uint8)
    mask[y - ya:y - ya + h, x - xa:x - xa + w] = masks[label]
    return mask, _dot_free(masks, stats, xa, ya, xb, yb, crowded)


def _dot_free(masks, stats, xa, ya, xb, yb, crowded):
    r'''The pixels of no blob (bool) over the crop [ya:yb, xa:xb], or None when no other blob
comes into it: the label image (_label_image) is made only when another blob's box
reaches the crop (crowded: _crowded()'s value for this crop)'''
    if not crowded:
        return None
    return _label_image(masks, stats, xa, ya, xb, yb) == 0


def _clear_of_others(free, blob, bx, by, kernel):
    r'''free (bool, a dot's crop: the pixels of no blob) without the pixels within the kernel
(a disk of BLUR_NEIGHBOUR_SIGMAS edge-blur sigmas, rounded up) of another blob's pixels;
blob: the dot's own mask (uint8) over its box, whose corner is pixel (bx, by) of the crop.

The board level under a dot's window is a plane fitted to the ring beyond it (free pixels
only). Under blur a neighbour's darkness reaches past its blob, the pixels below the
threshold: where dots crowd, dot_windows can leave no room between the ring and that edge
(its windows stop at the sharp one), and the ring took in the neighbour's blurred edge,
tilting the plane down on that side and moving the centroid away from the neighbour. On a
506x506 wide pinhole (dots of radius 2-4 px, 3-5 px apart; docs/corners.md, h-dotgate),
detected - exact centroid RMS 0.010-0.013 px per crowded view under the 0.7 px PSF alone,
0.005-0.008 with the ring kept clear (0.004-0.005 on the sharp render); the renderer gate's
joint chi2 on its dots 36-90 on 11 dof -> 4-14. Sharp renders (no blur read) are not
touched.'''
    import cv2
    other = ~free
    h, w = blob.shape
    other[by:by + h, bx:bx + w] &= blob == 0
    return free & (cv2.dilate(other.view(np.uint8), kernel) == 0)


def _dot_centroid(crop, mask, free, win_kernel, ring_kernel, xa, ya):
    r'''The darkness-weighted centroid (x, y) of a blob in a crop (float64, a copy: it is
overwritten) whose pixel crop[0,0] is (xa, ya); None if it has no weight

The numpy reference of targets._dot_kernels.dot_centroid, which the detector calls; used
where that kernel declines (a zero pivot in its plane fit: numpy's solve and lstsq).

mask, free: the blob's pixels (uint8) and the pixels of no blob (bool; None: all but the
blob's), over the crop (_dot_masks). Window, ring, board level and weights as the module
docstring says. The weights are computed in place in the crop; their non-finite values
(a board level of 0) are zeroed only when the sum shows one.'''
    import cv2
    window = cv2.dilate(mask, win_kernel).view(bool)
    ring = np.greater(cv2.dilate(mask, ring_kernel).view(bool), window)
    if free is not None:        # (the ring holds none of the blob's pixels)
        ring &= free
    h, w = crop.shape
    xx = np.arange(xa, xa + w, dtype=np.float64)[np.newaxis, :]    # (exact integers)
    yy = np.arange(ya, ya + h, dtype=np.float64)[:, np.newaxis]
    board = _board_level(crop, ring, window, xx, yy)
    # darkness relative to the local board level: 1 - I/B is proportional to the dot
    # area a pixel covers even when shading (vignetting) tilts the board level
    with np.errstate(divide="ignore", invalid="ignore"):
        wgt = np.divide(crop, board, out=crop)  # then in place: max(1 - wgt, 0) * window
        np.subtract(1.0, wgt, out=wgt)
        np.maximum(wgt, 0.0, out=wgt)
        wgt *= window
    s = wgt.sum()
    if not np.isfinite(s):      # NaN or +inf weights: the sum is finite iff there are none
        wgt[~np.isfinite(wgt)] = 0.0
        s = wgt.sum()
    if not s > 0:
        return None
    wx = np.multiply(wgt, xx, out=board if np.ndim(board) else None)
    sx = wx.sum()
    return sx / s, np.multiply(wgt, yy, out=wx).sum() / s


# The centroid window under blur (edge_blur_and_noise, blur_window). A lens's PSF spreads each dot's
# darkness past the sharp window (the blob mask dilated by 2 px) into the ring that sets the
# board level: the darkness cut off there biased the centroids, navcam 15 (2 poses, detected
# - exact RMS, px) clean 0.00037, PSF sigma 0.7 / 1.0 / 1.5 px 0.00078 / 0.0041 / 0.0126;
# with the window dilated by 3 / 4 / 5 px they are 0.00037 / 0.00036 / 0.00032, the clean
# render's. The blur is read from the dots' edges: the band of pixels between 5 % and 95 %
# of the way from board to dot, per boundary pixel of the blob, is 0.74-0.79 on sharp renders
# (15, 17) and 2.15-2.28 / 2.86-3.10 / 4.10-4.51 / 5.40-5.70 under a Gaussian PSF of sigma
# 0.7 / 1 / 1.5 / 2 px (and 2.15-2.29 through the realistic profile with 8-bit noise): sigma
# = (ratio - BLUR_BAND_SHARP) / BLUR_BAND_PER_SIGMA. The window then reaches
# BLUR_WINDOW_SIGMAS sigma past the blob's edge (half a pixel more), never less than the
# sharp window: on a sharp render (sigma <= 0.43 px) it is that window, bit for bit. Where
# dots crowd (a mark dot's neighbours, a fisheye's small distant dots) each window stops
# short of the ring's reaching the neighbour's blurred edge (dot_windows): 6 poses, PSF sigma
# 1.0 / 1.5 px, detected - exact RMS px, sharp window -> these: navcam 15 0.0049 / 0.0147 ->
# 0.00051 / 0.00052 (clean 0.0005); MER hazcam 8 0.0056 / 0.0161 -> 0.00075 / 0.0033;
# barrel CAHVOR 0.0062 / 0.0183 -> 0.0012 / 0.0055; hazcam 17 (640x480, dots 8-19 px
# apart) 0.0094 / 0.0271 -> 0.0066 / 0.0210.
BLUR_BAND_SHARP = 0.4
BLUR_BAND_PER_SIGMA = 2.55
BLUR_WINDOW_SIGMAS = 3.5
BLUR_SAMPLE_DOTS = 12
BLUR_SIGMA_NOTED_PX = 0.43
# the quick look: every third sampled dot, all of them read sharper than this sigma (px; a
# sharp render's dots 0.13-0.15, the blurred window starts past 0.43), and the others are not
# read (clean renders: 4 dots of 12, the paper campaign's detection ~3 s CPU less; the
# sigma and the windows of a blurred image are those of all 12: the median and the quartile
# do not depend on the order the dots are read in)
BLUR_QUICK_LOOK = 0.3
BLUR_NEIGHBOUR_SIGMAS = 2.0


def _surrounded(mask, xx, yy):
    r'''Whether the board's light pixels (columns xx, rows yy of a dot's crop) surround the
dot (its blob mask, uint8): the centre of its mask inside their convex hull, so that the
board plane through them (edge_blur_and_noise) is read at the dot, not extrapolated to it.
Where dots crowd (gaps under the 14 px that keep a pixel 7 px from any dark one), only the
dots at the board's margin keep light pixels, a strip on one side: a 320x240 camera's dots
(radius 2.7 px, 4.4 px apart; docs/corners.md, h-dotgate) put the plane at 1.4-2.1 over the
dot where the image's lightest pixel is 0.9, the band of its edge 6x too wide, sigma read
3-6 px under a 0.7 px PSF, and shading_blur_shift ((sigma^2 + 1/12) grad ln(board level))
moved the centroids by up to 0.15 px. Such a dot is not read; a board read from none is
sharp (no blur measured: the sharp window, no shift).'''
    import cv2
    my, mx = np.nonzero(mask)
    hull = cv2.convexHull(np.column_stack((xx, yy)).astype(np.float32))
    return cv2.pointPolygonTest(hull, (float(mx.mean()), float(my.mean())), False) > 0


def edge_blur_and_noise(img, masks, stats, labels):
    '''(sigma, noise) of the dots labels (up to BLUR_SAMPLE_DOTS of them, spread over the
list): the edge blur sigma (px; see BLUR_* above), the median over them, and the board's
pixel noise relative to the dots' contrast (the robust RMS of the board's light pixels about
their plane over board - dot; the lower quartile over them); each None when none could be
measured. A sharp image is read from every third of them (BLUR_QUICK_LOOK)'''
    import cv2
    H, W = img.shape
    pad = 10
    ratios, noises = [], []
    pick = labels[np.linspace(0, len(labels) - 1, min(BLUR_SAMPLE_DOTS, len(labels))).astype(int)]
    quick = np.arange(len(pick)) % 3 == 0
    order = np.concatenate((pick[quick], pick[~quick])).tolist()
    for n, k in enumerate(order):
        if n == np.count_nonzero(quick) and len(ratios) == n and n > 0 and \
                max(ratios) < BLUR_BAND_SHARP + BLUR_QUICK_LOOK * BLUR_BAND_PER_SIGMA:
            break   # every dot of the quick look sharp: the window is the sharp one
        x, y, w, h = stats[k, :4].tolist()
        if masks[k] is None:
            continue
        xa, ya, xb, yb = max(0, x - pad), max(0, y - pad), min(W, x + w + pad), min(H, y + h + pad)
        crop = np.asarray(img[ya:yb, xa:xb], dtype=np.float64)
        mask = np.zeros(crop.shape, np.uint8)
        mask[y - ya:y - ya + h, x - xa:x - xa + w] = masks[k]
        dot = np.percentile(crop[mask > 0], 5)
        mid = 0.5 * (dot + crop.max())
        # the board 7 px from this dot's and any other's dark pixels: the blur's darkness
        # there (2e-4 of the dots' at sigma 2) is neither board level nor noise
        far = cv2.dilate(mask | (crop < mid).view(np.uint8), np.ones((15, 15), np.uint8)) == 0
        light = far & (crop > mid)
        if np.count_nonzero(light) < MIN_RING_FOR_PLANE:
            continue
        # the board as a plane through its light pixels: a shading gradient across the crop
        # (vignetting) is no blur
        yy, xx = np.nonzero(light)
        if not _surrounded(mask, xx, yy):
            continue
        A = np.column_stack((np.ones(len(xx)), xx, yy)).astype(np.float64)
        coef = np.linalg.lstsq(A, crop[light], rcond=None)[0]
        gy, gx = np.mgrid[0:crop.shape[0], 0:crop.shape[1]]
        board = coef[0] + coef[1] * gx + coef[2] * gy
        if not np.all(board - dot > 0):
            continue
        res = np.abs(crop[light] - A @ coef)
        noises.append(1.4826 * float(median(res)) / float(np.median(board[mask > 0]) - dot))
        darkness = (board - crop) / (board - dot)
        near = cv2.dilate(mask, np.ones((13, 13), np.uint8)) > 0
        band = np.count_nonzero(near & (darkness > 0.05) & (darkness < 0.95))
        edge = np.count_nonzero(mask & (cv2.erode(mask, np.ones((3, 3), np.uint8)) == 0))
        if edge:
            ratios.append(band / edge)
    # the noise: the lower quartile over the dots (a board crowded with dots, or the
    # board's own edge, leaves a dot too few clean board pixels and reads high)
    noise = float(np.percentile(noises, 25)) if noises else None
    if not ratios:
        return None, noise
    return (max(0.0, (float(np.median(ratios)) - BLUR_BAND_SHARP) / BLUR_BAND_PER_SIGMA),
            noise)


def dot_windows(sigma, sharp_px, ring_px, centres, areas, lattice, tree, noise=None):
    r'''(len(lattice),) int: the window dilation of each lattice dot (lattice: indices into
the blobs' centres and areas; tree: their cKDTree) under the edge blur sigma: blur_window's,
or on a noisy image the narrower noise_window's, but no wider than leaves the ring
(ring_px) and another blob's blurred edge (BLUR_NEIGHBOUR_SIGMAS sigma: 2.3 % of its
darkness lies beyond) apart: gap - ring_px - that reach, gap the distance between the two
blobs' edges (their centres' distance less their radii as discs of their areas); never
below sharp_px. noise: the board's pixel noise relative to the dots' contrast
(edge_blur_and_noise; None: none measured, blur_window's)'''
    wide = blur_window(sigma, sharp_px)
    out = np.full(len(lattice), sharp_px, np.int64)
    if wide <= sharp_px:
        return out
    radius = np.sqrt(np.asarray(areas, np.float64) / math.pi)
    if noise is not None and noise > 0:
        wide = noise_window(sigma, sharp_px, wide, noise, radius[lattice])
    reach = BLUR_NEIGHBOUR_SIGMAS * sigma
    k = min(9, len(centres))
    dist, near = tree.query(centres[lattice], k=k)
    dist, near = np.atleast_2d(dist)[:, 1:], np.atleast_2d(near)[:, 1:]
    gap = (dist - radius[lattice][:, None] - radius[np.minimum(near, len(radius) - 1)])
    gap = np.where(near < len(radius), gap, np.inf).min(axis=1) if gap.size else \
        np.full(len(lattice), np.inf)
    room = np.floor(gap - ring_px - reach)
    return np.maximum(sharp_px, np.minimum(wide, room)).astype(np.int64)


# Shading under blur. Where the board's light falls off (vignetting), a blur moves each dot's
# darkness-weighted centroid: the weights divide the blurred image by the board's own level
# at each pixel, which undoes the shading only where the blur did not mix light from
# brighter and dimmer sides. For a shading f = exp(g . x) and a Gaussian blur (variance s2)
# the divided image is the dot's coverage convolved with the blur kernel tilted by
# exp(-g . u), a Gaussian centred at -s2 g: the centroid moves by -s2 grad ln f, towards
# the dimmer side. Measured (PSF sigma 1.0 / 1.5 px after a lens vignetting 1 -> 0.4 over
# 700 px, 3 poses, with the blurred windows): detected - exact regressed on -(sigma^2 +
# 1/12) grad ln f has a slope of 1.08-1.17 on navcam 15, MER hazcam 8 and the barrel CAHVOR
# (1/12: the PSF's kernel integrated over a pixel). shading_blur_shift puts it back, with
# grad ln f of the board level (local_board_level) fitted as a plane over SHADING_FIT_DOTS
# dot diameters about each dot, sigma the dots' own edge blur.
SHADING_FIT_DOTS = 1.0
# the plane takes the pixels whose level is at least this fraction of the dot's own: the
# board, not its blurred outer edge or the background beyond it
SHADING_FIT_LEVEL = 0.8


def shading_blur_shift(img, q, sigma, dot_area_px):
    r'''(N,2) px to add to the centroids q (N,2; NaN: not found) of a blurred image (edge
blur sigma px): (sigma^2 + 1/12) grad ln(board level) at each (see above); None when the
board level cannot be read'''
    level = local_board_level(img, dot_area_px)
    top = float(level.max())
    if not top > 0 or not dot_area_px:
        return None
    H, W = level.shape
    d = 2.0 * math.sqrt(dot_area_px / math.pi)
    R = max(8, int(math.ceil(SHADING_FIT_DOTS * d)))
    step = max(1, R // 8)
    out = np.zeros_like(q)
    for i, (x, y) in enumerate(q):
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        xi, yi = int(round(x)), int(round(y))
        if not (0 <= xi < W and 0 <= yi < H):
            continue
        ys, xs = np.mgrid[max(0, yi - R):min(H, yi + R + 1):step,
                          max(0, xi - R):min(W, xi + R + 1):step]
        v = level[ys, xs].astype(np.float64)
        ok = v > SHADING_FIT_LEVEL * level[yi, xi]
        if ok.sum() < 6:
            continue
        L = np.log(v[ok])
        A = np.column_stack((np.ones(ok.sum()), xs[ok] - x, ys[ok] - y))
        coef = np.linalg.lstsq(A, L, rcond=None)[0]
        out[i] = (sigma * sigma + 1.0 / 12.0) * coef[1:]
    return out


# The window under blur AND noise (noise_window). Each ring of pixels a window takes in holds
# the blur's tail of the dot's darkness (leaving it out biases the centroid) and the pixels'
# noise (taking it in scatters the centroid by the noise times the ring's lever arm). The
# bias of a window dilated d px past the blob's edge is about TRUNCATION_BIAS sigma
# Phi(-(d - 1/2) / sigma): the darkness at the window's edge (the blob's edge lies half a
# pixel inside its boundary pixels) times the share of it a pixel-quantised window leaves
# on one side more than the other. Measured (detected - sharp-render RMS, px, Gaussian PSF,
# no noise; 6 poses) on navcam 15, the constructed tele-2048 and blur-wide-1024: sigma 0.7
# d 2: 0.0011 / 0.0007 / 0.0012; sigma 1.0 d 2 / 3: 0.0052 / 0.0007, 0.0038 / 0.0005,
# 0.0061 / 0.0008; sigma 1.5 d 2 / 3 / 4: 0.015 / 0.006 / 0.0013, 0.011 / 0.004 / 0.0008,
# 0.016 / 0.007 / 0.0014; sigma 2 d 2-5 on 15: 0.022 / 0.013 / 0.0054 / 0.0025: 0.05-0.11
# sigma Phi (0.1 taken). The noise of a dot of radius R (a disc of its blob's area) under a
# window of radius W = R + d + 1/2 px: pixels of noise n (relative to the dots' contrast)
# scatter its darkness-weighted centroid by n W^2 / (2 sqrt(pi) R^2) along each axis (the
# window's second moment over the dot's darkness; the dot's darker, quieter pixels and the
# clipped weights of the light ones roughly cancel): on navcam 15 (R ~12.6 px; no blur, shot
# and read noise, 12 bits) 0.41 / 0.58 n predicted at d 2 / 5, 0.35 / 0.59 n measured; the
# measured growth with d is alike on tele-2048, blur-wide, barrel and portrait. The window grows
# past the sharp one only while the bias it removes exceeds half that noise: the bias it
# leaves adds at most 12 % to the centroid's error. On a noiseless render it is
# blur_window's; under the realistic profile (PSF 0.7 px, 12-bit shot and read noise)
# the sharp window, which measured 8-14 % below blur_window's 3 px on 15, 8, blur-wide,
# barrel and portrait (detected - sharp-render RMS 0.0040 against 0.0044-0.0047 on 15).
TRUNCATION_BIAS = 0.1
NOISE_BIAS_SHARE = 0.5


def noise_window(sigma, sharp_px, wide_px, noise, radius):
    r'''(len(radius),) int: the narrowest dilation d in [sharp_px, wide_px] whose truncation
bias (TRUNCATION_BIAS sigma Phi(-(d - 1/2)/sigma)) is at most NOISE_BIAS_SHARE of the
centroid noise its window takes in (noise (W / R)^2 / (2 sqrt(pi)), W = R + d + 1/2), per
dot of radius radius (px); wide_px where none is'''
    d = np.arange(sharp_px, wide_px + 1, dtype=np.float64)
    bias = TRUNCATION_BIAS * sigma * 0.5 * np.array(
        [math.erfc((x - 0.5) / sigma / math.sqrt(2.0)) for x in d.tolist()])
    r = np.maximum(np.asarray(radius, np.float64), 0.5)[:, None]
    scatter = noise * (r + d + 0.5) ** 2 / (2.0 * math.sqrt(math.pi) * r * r)
    ok = bias <= NOISE_BIAS_SHARE * scatter
    first = np.where(ok.any(axis=1), ok.argmax(axis=1), len(d) - 1)
    return (sharp_px + first).astype(np.int64)


def blur_window(sigma, sharp_px):
    '''The window's dilation (px) that holds a dot's darkness under an edge blur sigma: at least
sharp_px (the sharp window), BLUR_WINDOW_SIGMAS sigma + 0.5 px when that is wider'''
    if sigma is None:
        return sharp_px
    return max(sharp_px, int(math.ceil(BLUR_WINDOW_SIGMAS * sigma + 0.5)))


# The shading pass (_shading_pass): the board's own level at each pixel is the grey
# closing of the image (a dilation, then an erosion: it fills the dark features narrower
# than its window and follows any wider shading, never rising above a light neighbour's
# level on both sides), on the image reduced SHADING_REDUCTION times at most (area
# averages: a hot pixel counts a sixteenth); its square window is SHADING_WINDOW times the
# largest dot of the first pass's lattice (the mark dots are 1.4 times a small one's
# diameter) plus SHADING_MARGIN_PX for a blurred edge.
SHADING_REDUCTION = 4
SHADING_WINDOW = 1.5
SHADING_MARGIN_PX = 8
# where the board level is below this fraction of its brightest, the image is divided by
# that fraction instead: the background beyond the board (albedo 0) stays dark, and a
# board lit below 2 % of its brightest (a cos^4 falloff past 68 deg off the axis) is not
# sought (its dots' contrast is a few levels of an 8-bit converter)
SHADING_FLOOR = 0.02
# the image relative to the board level is clipped here: what is brighter than twice the
# board around it (a hot pixel) is light whatever its value, and the threshold's
# histogram keeps its resolution between the dots (~0.1) and the board (1)
SHADING_CLIP = 2.0


def local_board_level(img, dot_area_px=None):
    '''The board's light level at each pixel of img (H,W), float32: the grey closing of
img reduced (area average), with a window wider than the dots (the largest dot's area
dot_area_px; None: a twentieth of the image's larger side as its diameter), resized back
bilinearly. See SHADING_* above.'''
    import cv2
    H, W = img.shape
    d = 2.0 * math.sqrt(dot_area_px / math.pi) if dot_area_px else max(H, W) / 20.0
    s = max(1, min(SHADING_REDUCTION, int(d // 4)))
    f = np.asarray(img, dtype=np.float32)
    small = _reduce(f, s) if s > 1 else f
    k = int(math.ceil((SHADING_WINDOW * d + SHADING_MARGIN_PX) / s)) | 1
    level = cv2.morphologyEx(small, cv2.MORPH_CLOSE, np.ones((k, k), np.uint8))
    if s > 1:
        level = cv2.resize(level, (W, H), interpolation=cv2.INTER_LINEAR)
    return level


def _shading_pass(image, target, src, img, det, dot_area, step, **options):
    '''The first pass's Detection det (a global threshold, which left dots out) or a second
one whose threshold is relative to the local board level, whichever found more dots

Under shading (vignetting: a multiplicative falloff across the image) one threshold
cannot split dots from board everywhere: where the board is lit at a third of its
brightest it is darker than the dots at the centre. Divided by the board's own level
(local_board_level), every dot is ~dot/board albedo (0.11 for the JPL target) and the
board ~1, whatever the light: Otsu's threshold on that ratio splits them everywhere. Only
the blobs (masks, lattice, numbering) come from the ratio; the centroids are measured in
img as in the first pass (their weights take the board level from a plane fitted around
each dot). An image the global threshold already serves is never looked at again, so its
dots are those of the first pass, bit for bit.'''
    level = local_board_level(img, dot_area)
    floor = SHADING_FLOOR * float(level.max())
    if not floor > 0:
        return det
    lab = np.clip(img / np.maximum(level, floor), 0.0, SHADING_CLIP).astype(np.float32)
    H, W = img.shape
    small = _reduce(lab, REDUCTION) if H * W > LARGE_IMAGE_PIXELS else None
    thr = _otsu(lab[::step, ::step])
    det2, _ = _measure(image, target, src, img, lab, thr, small, False, **options)
    if det2.n_found <= det.n_found and not det2.status == "ok":
        return det
    det2.info["threshold_relative_to"] = "the local board level (shading)"
    return det2


def detect_dots(image, target, **options):
    r'''Detect a dot grid; see the module docstring and _detect_dots() for the options

SYNOPSIS

    det = detect_dots(image, target)   # Detection; det.q (nx*ny,2)

OpenCV runs on one thread meanwhile (its previous thread count is restored after):
its thread pool costs CPU time in these calls on small images and boxes (5120x3840:
about 10 ms of 130 ms per image) and gains no wall time when the campaign's workers
already use every core. The labels, statistics and pixels are those of the threaded
calls (benchmarks/bench_stages.py detect --check).'''
    import cv2
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        return _detect_dots(image, target, **options)
    finally:
        cv2.setNumThreads(threads)


def _detect_dots(image, target, *, window_dilation_px=2, ring_px=3, min_area_px=6,
                 min_found=None, threshold=None, shading=True):
    r'''Detect a dot grid; see the module docstring

SYNOPSIS

    det = detect_dots(image, target)   # Detection; det.q (nx*ny,2)

ARGUMENTS

- image: (H,W) float in [0,1], or uint8/uint16
- target: a "dots" targets.boards.Target
- window_dilation_px: centroid window = blob mask dilated by this many px (at least: a
  blurred image's window is widened to hold the blur, blur_window)
- ring_px: width of the ring outside the window where the board level is measured
- min_area_px: smaller dark blobs are ignored
- min_found: fewest dots for status "ok" (default: all of them)
- threshold: dark/light threshold (default: Otsu)
- shading: when the global threshold does not give every dot, look again with the
  threshold relative to the local board level (_shading_pass); False: the global
  threshold only
'''

    large = _is_large(image)
    src = np.asarray(image)
    # a small float32 image (a render) is not converted as a whole: its pixels are read
    # as float64 where they are used (the subsample, the range, the threshold test and
    # the centroids), the values a float64 copy would hold
    exact64 = not large and src.ndim == 2 and src.dtype == np.float32
    img = as_float_image(image, dtype=np.float32 if large or exact64 else np.float64)
    if target.kind != "dots":
        return failed(target, f"detect_dots() needs a dots target; got {target.kind!r}",
                      DETECTOR)
    H, W = img.shape
    # the threshold only splits dark from light: about a million pixels give it
    step = max(2, math.isqrt(H * W // OTSU_PIXELS))
    if H * W > LARGE_IMAGE_PIXELS:
        small, sub = _scan(img, REDUCTION, step)
    else:
        small, sub = None, img[::step, ::step].astype(np.float64 if exact64 else img.dtype)
    problem = _image_problem(img, small, np.float64 if exact64 else None)
    if problem is not None:
        return failed(target, problem, DETECTOR)
    thr = _otsu(sub) if threshold is None else float(threshold)
    options = dict(window_dilation_px=window_dilation_px, ring_px=ring_px,
                   min_area_px=min_area_px, min_found=min_found)
    det, dot_area = _measure(image, target, src, img, img, thr, small, exact64, **options)
    if det.status == "ok" or threshold is not None or not shading:
        return det
    return _shading_pass(image, target, src, img, det, dot_area, step, **options)


def _measure(image, target, src, img, lab, thr, small, exact64, *, window_dilation_px,
             ring_px, min_area_px, min_found):
    '''(Detection, the largest lattice blob's area px or None): the blobs of lab < thr
(the labelled image: img itself, or _shading_pass's image relative to the board level;
small: its reduction for a large image), their lattice and numbering, and the centroids
of the blobs measured in img (module docstring, steps 1-4)'''
    from scipy.spatial import cKDTree

    nx, ny = target.grid_shape
    H, W = img.shape
    found = None
    if H * W > LARGE_IMAGE_PIXELS:
        found = _blobs_from_reduced(lab, thr, REDUCTION, small)
    whole = found is None   # every dark pixel lies in a labelled component
    if whole:   # (a float64 threshold: the float32 pixels compared as float64)
        found = _label_whole(lab, np.float64(thr) if exact64 else thr)
    masks, stats, centroids = found
    n = len(stats)
    x0, y0, w, h, area = (stats[:, k] for k in range(5))
    keep = ((np.arange(n) > 0) & (x0 > 0) & (y0 > 0) & (x0 + w < W) & (y0 + h < H)
            & (area >= min_area_px) & (area <= 0.25 * W * H))
    blobs = np.flatnonzero(keep)
    info = {"threshold": thr, "Nblobs": int(len(blobs))}
    if len(blobs) == 0:
        return failed(target, "no dark blobs in the image", DETECTOR, info), None
    c = centroids[blobs]
    a = area[blobs].astype(np.float64)
    tree = cKDTree(c)

    best = None
    seeds = list(np.argsort(-a)[:NSEEDS]) + list(np.argsort(np.abs(a - np.median(a)))[:NSEEDS])
    for seed in dict.fromkeys(seeds):
        nodes = _grow(c, a, seed, tree, max(nx, ny))
        if nodes is None:
            continue
        ab = np.array(list(nodes.keys()))
        ext = tuple(np.ptp(ab, axis=0) + 1)
        fits = ext in ((nx, ny), (ny, nx)) or (max(ext) <= max(nx, ny)
                                                and min(ext) <= min(nx, ny))
        if fits and (best is None or len(nodes) > len(best)):
            best = nodes
        if best is not None and len(best) == nx * ny:
            break
    if best is None or len(best) < 2 and nx * ny > 1:
        return failed(target, f"no grid of dots among {len(blobs)} dark blobs", DETECTOR,
                      info), float(np.median(a))
    info["Nlattice"] = len(best)
    dot_area = float(a[np.array(list(best.values()), np.int64)].max())

    # the orientation mark: blobs larger than their lattice neighbours
    mark_spec = target.spec.get("orientation_mark")
    radii = target.dot_radii()
    is_mark = np.zeros(len(c), bool)
    if mark_spec is not None:
        ratio_threshold = float(mark_spec["dot_diameter"]) / (2 * float(radii.min()))
        is_mark = mark_flags(best, a, ratio_threshold)
        numbered = _number(best, is_mark, target)
    else:
        numbered = _unmarked_choice(best, c, target)
    if isinstance(numbered, str):
        return failed(target, numbered, DETECTOR, info), dot_area
    ix, iy, tinfo = numbered
    info.update(tinfo)

    # subpixel centroids
    q = np.full((nx * ny, 2), np.nan)
    lattice = np.array(list(best.values()), np.int64)
    dots = blobs[lattice]
    # a blurred image's dots reach past the sharp window: widen it to hold the blur, each
    # dot's as far as its neighbours leave room (dot_windows)
    sigma, noise = edge_blur_and_noise(img, masks, stats, dots)
    windows = dot_windows(sigma, window_dilation_px, ring_px, c, a, lattice, tree, noise)
    if sigma is not None and sigma > BLUR_SIGMA_NOTED_PX:
        info["edge_blur_sigma_px"] = round(sigma, 3)
        info["window_dilation_px"] = [int(windows.min()), int(windows.max())]
        if noise is not None:
            info["board_noise_rel"] = float(f"{noise:.3g}")
    # the ring keeps off the other blobs' blurred edges (_clear_of_others)
    clear_px = 0 if sigma is None or sigma <= BLUR_SIGMA_NOTED_PX else \
        int(math.ceil(BLUR_NEIGHBOUR_SIGMAS * sigma))
    clear_kernel = _disk(clear_px) if clear_px else None
    kernels = {}
    for wd in sorted(set(windows.tolist())):
        win_kernel, ring_kernel = _disk(wd), _disk(wd + ring_px)
        rows = _kernels.element_rows(win_kernel), _kernels.element_rows(ring_kernel)
        kernels[wd] = (win_kernel, ring_kernel, None if None in rows else rows[0] + rows[1])
    pad = int(windows.max()) + ring_px + 1
    # img has the source's pixel values when it is float64 (converted from the source as
    # float64) or when it is the source itself (a 2-D float32 image, not copied)
    img_is_source = img.dtype == np.float64 or (src.ndim == 2 and src.dtype == img.dtype)
    crops = (np.maximum(0, x0[dots] - pad), np.maximum(0, y0[dots] - pad),
             np.minimum(W, x0[dots] + w[dots] + pad), np.minimum(H, y0[dots] + h[dots] + pad))
    crowded = _crowded(stats, dots, *crops)
    # the threshold as _label_stack compared the pixels with it
    thr_labelled = np.result_type(lab, thr).type(np.float64(thr) if exact64 else thr)
    for label, bx, by, xa, ya, xb, yb, near, gx, gy, wd in zip(
            dots.tolist(), x0[dots].tolist(), y0[dots].tolist(), *(c.tolist() for c in crops),
            crowded.tolist(), ix, iy, windows.tolist(), strict=True):
        win_kernel, ring_kernel, rows = kernels[wd]
        # the source pixels (their float64 values), whatever precision the labelling used:
        # a view of img when img holds them (the kernel reads float32 as float64)
        crop = img[ya:yb, xa:xb] if img_is_source else \
            as_float_image(np.asarray(image)[ya:yb, xa:xb])
        free = _dot_free(masks, stats, xa, ya, xb, yb, near and not whole)
        if near and whole:   # the pixels of no blob: the light ones, as labelled
            free = ~(lab[ya:yb, xa:xb] < thr_labelled)
        if free is not None and clear_kernel is not None:
            free = _clear_of_others(free, masks[label], bx - xa, by - ya, clear_kernel)
        status = -1
        if rows is not None:    # (the blob's mask over its box, where it lies in the crop)
            status, cx, cy = _kernels.dot_centroid(
                crop, masks[label], bx - xa, by - ya, _NO_FREE if free is None else free,
                free is not None, *rows, xa, ya, MIN_RING_FOR_PLANE)
        if status < 0:      # a degenerate plane fit (numpy's solve or lstsq), or no kernel
            crop = np.array(crop, dtype=np.float64)     # a copy: _dot_centroid writes it
            mask = _dot_masks(masks, stats, label, xa, ya, xb, yb, False)[0]
            c = _dot_centroid(crop, mask, free, win_kernel, ring_kernel, xa, ya)
            status, (cx, cy) = (0, (0, 0)) if c is None else (1, c)
        if status:
            q[gy * nx + gx] = cx, cy
    if sigma is not None and sigma > BLUR_SIGMA_NOTED_PX:
        shift = shading_blur_shift(img, q, sigma, dot_area)
        if shift is not None:
            q += shift
            info["shading_blur_shift_px"] = round(float(np.nanmax(np.hypot(*shift.T))), 6)
    return result(target, q, DETECTOR, min_found=min_found, info=info), dot_area

r'''The dot detector's shortcuts give bit for bit what the plain computations give

_label_stack labels many boxes in one call: each box's components, their order, stats
and centroids must be those of the box labelled alone (as the detector did before, one
connectedComponentsWithStats call per box), and _label_image the label image they made.
The other shortcuts (targets.detection.median, _histogram, _label_whole, _dot_centroid,
...) are compared with the numpy/OpenCV computations they replace.
'''

import cv2
import numpy as np
import pytest

from targets import detect_dots as dd
from targets.detection import median


def _label_boxes_one_by_one(img, thr, boxes):
    r'''The reference: each box labelled alone (the former per-box loop)'''
    H, W = img.shape
    labels = np.zeros((H, W), np.int32)
    stats, centroids = [[0, 0, 0, 0, 0]], [np.zeros(2)]
    for xa, ya, xb, yb in boxes:
        dark = (img[ya:yb, xa:xb] < thr).astype(np.uint8)
        m, lab, cst, cc = cv2.connectedComponentsWithStats(dark, connectivity=8)
        for k in range(1, m):
            cx, cy, cw, ch, ca = cst[k].tolist()
            if not ((cx > 0 or xa == 0) and (cy > 0 or ya == 0) and
                    (cx + cw < xb - xa or xb == W) and (cy + ch < yb - ya or yb == H)):
                continue
            region = labels[ya + cy:ya + cy + ch, xa + cx:xa + cx + cw]
            mine = lab[cy:cy + ch, cx:cx + cw] == k
            if region[mine].any():
                continue
            region[mine] = len(stats)
            stats.append([cx + xa, cy + ya, cw, ch, ca])
            centroids.append(cc[k] + (xa, ya))
    return labels, np.array(stats, np.int64), np.array(centroids)


def _speckled(seed, H=300, W=420):
    r'''Dark blobs of many shapes (ellipses, rings, specks, blobs touching each other and
the border) on a noisy board, float32 like the renders'''
    rng = np.random.default_rng(seed)
    img = np.full((H, W), 0.8, np.float32) + rng.normal(0, 0.02, (H, W)).astype(np.float32)
    yy, xx = np.mgrid[:H, :W]
    for _ in range(60):
        cx, cy = rng.uniform(-5, W + 5), rng.uniform(-5, H + 5)
        a, b, th = rng.uniform(1, 25), rng.uniform(1, 25), rng.uniform(0, np.pi)
        u = ((xx - cx) * np.cos(th) + (yy - cy) * np.sin(th)) / a
        v = (-(xx - cx) * np.sin(th) + (yy - cy) * np.cos(th)) / b
        r2 = u * u + v * v
        img[(r2 < 1) & ((r2 > 0.3) if rng.uniform() < 0.3 else True)] = 0.1
    img[rng.uniform(size=(H, W)) < 0.01] = 0.2       # isolated dark specks
    return img


@pytest.mark.parametrize("seed", range(6))
def test_label_stack_is_each_box_labelled_alone(seed):
    img = _speckled(seed)
    H, W = img.shape
    rng = np.random.default_rng(100 + seed)
    # overlapping boxes of odd and even sizes, some at the image border, one huge
    boxes = []
    for _ in range(40):
        xa, ya = int(rng.integers(0, W - 10)), int(rng.integers(0, H - 10))
        boxes.append((xa, ya, min(W, xa + int(rng.integers(5, 90))),
                      min(H, ya + int(rng.integers(5, 90)))))
    boxes.insert(20, (0, 3, W, H - 1))
    boxes.insert(30, (0, 150, W, 157))
    ref = _label_boxes_one_by_one(img, 0.5, boxes)
    stats, centroids, masks = [[0, 0, 0, 0, 0]], [np.zeros(2)], [None]
    dd._label_stack(img, 0.5, boxes, stats, centroids, masks)
    assert len(stats) == len(ref[1]) == len(masks) > 40
    labels = dd._label_image(masks, np.array(stats), 0, 0, W, H)
    assert np.array_equal(labels, ref[0])
    # each blob's crop as detect_dots takes it: its mask, and the pixels of no blob
    nfree = 0
    st = np.array(stats)
    labels = np.arange(1, len(st))
    corners = (np.maximum(0, st[1:, 0] - 6), np.maximum(0, st[1:, 1] - 6),
               np.minimum(W, st[1:, 0] + st[1:, 2] + 6), np.minimum(H, st[1:, 1] + st[1:, 3] + 6))
    crowded = dd._crowded(st, labels, *corners, chunk=50)     # (in pieces of a few crops)
    for k, (x, y, w, h, _) in enumerate(stats[1:], 1):
        xa, ya, xb, yb = max(0, x - 6), max(0, y - 6), min(W, x + w + 6), min(H, y + h + 6)
        mask, free = dd._dot_masks(masks, st, k, xa, ya, xb, yb, crowded[k - 1])
        lab = ref[0][ya:yb, xa:xb]
        assert mask.dtype == np.uint8 and np.array_equal(mask, lab == k)
        if free is None:
            assert np.all((lab == 0) | (lab == k))
        else:
            assert np.array_equal(free, lab == 0)
            nfree += 1
    assert 0 < nfree < len(stats) - 1
    assert np.array_equal(dd._label_image(masks, np.array(stats), 30, 20, 200, 150),
                          ref[0][20:150, 30:200])
    assert np.array_equal(np.array(stats, np.int64), ref[1])
    assert np.array_equal(np.array(centroids), ref[2])     # bit for bit, not just close


@pytest.mark.parametrize("density", [0.2, 0.45, 0.6])
def test_label_stack_on_noise_is_each_box_labelled_alone(density):
    r'''Speckle noise: many small components touching only diagonally, nested in each
other's boxes, whose label order (cv2's first 2x2 block, from the box's own corner at
odd and even rows and columns) decides the stats' order'''
    rng = np.random.default_rng(int(density * 100))
    H, W = 97, 131
    img = np.where(rng.uniform(size=(H, W)) < density, 0.1, 0.9).astype(np.float32)
    boxes = [(int(xa), int(ya), int(min(W, xa + dx)), int(min(H, ya + dy)))
             for xa, ya, dx, dy in zip(rng.integers(0, W - 4, 30), rng.integers(0, H - 4, 30),
                                       rng.integers(3, 40, 30), rng.integers(3, 40, 30),
                                       strict=True)] + [(0, 0, W, H)]
    ref = _label_boxes_one_by_one(img, 0.5, boxes)
    stats, centroids, masks = [[0, 0, 0, 0, 0]], [np.zeros(2)], [None]
    dd._label_stack(img, 0.5, boxes, stats, centroids, masks)
    assert len(stats) > 5      # (0.6 percolates: one big component and a few specks)
    assert np.array_equal(np.array(stats, np.int64), ref[1])
    assert np.array_equal(np.array(centroids), ref[2])
    assert np.array_equal(dd._label_image(masks, np.array(stats), 0, 0, W, H), ref[0])


@pytest.mark.parametrize("n", [1, 2, 3, 10, 11, 64, 65])
def test_median_is_np_median(n):
    rng = np.random.default_rng(n)
    for v in (rng.normal(size=n), np.round(rng.normal(size=n), 1), np.full(n, 0.3)):
        m = median(v.copy())
        assert m == np.median(v) and type(m) is type(np.median(v))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_one_non_finite_pixel_is_refused(bad, dtype):
    from targets.boards import load_target
    img = _speckled(0).astype(dtype)
    img[100, 200] = bad
    det = dd.detect_dots(img, load_target("dots"))
    assert det.status == "failed" and det.reason == "the image has non-finite pixels"


def _edge_heavy(rng, dtype, lo, hi, n=200_000):
    r'''Values in [lo, hi] many of them exactly on np.histogram's bin edges or one ulp
either side of them, where the bin of a value is decided by the edge comparisons'''
    edges = np.linspace(lo, hi, 1025, dtype=np.result_type(lo, hi, np.zeros(1, dtype)))
    e = edges[rng.integers(0, 1025, n // 2)].astype(dtype)
    e = np.where(rng.uniform(size=e.size) < 0.3, np.nextafter(e, dtype(np.inf)), e)
    e = np.where(rng.uniform(size=e.size) < 0.3, np.nextafter(e, dtype(-np.inf)), e)
    v = np.concatenate((e, rng.uniform(lo, hi, n - e.size).astype(dtype), [lo, hi]))
    return np.clip(v, dtype(lo), dtype(hi))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("lo,hi", [(0.0, 1.0), (0.0123, 0.8731), (-3.5, 250.25),
                                   (0.5, 0.5004), (0.3, 0.3)])
def test_histogram_is_np_histogram(dtype, lo, hi):
    rng = np.random.default_rng(int(1000 * hi))
    v = _edge_heavy(rng, dtype, lo, hi)
    lo, hi = float(v.min()), float(v.max())
    h, edges = dd._histogram(v, 1024, lo, hi)
    h0, edges0 = np.histogram(v, bins=1024, range=(lo, hi))
    assert h.sum() == v.size
    assert np.array_equal(h, h0) and h.dtype == h0.dtype
    assert np.array_equal(edges, edges0) and edges.dtype == edges0.dtype


def test_otsu_threshold_of_a_render_is_that_of_np_histogram():
    img = _speckled(3)
    sub = img[::2, ::2]
    h0, edges0 = np.histogram(sub, bins=1024, range=(float(sub.min()), float(sub.max())))
    h, edges = dd._histogram(sub.ravel(), 1024, float(sub.min()), float(sub.max()))
    assert np.array_equal(h, h0) and np.array_equal(edges, edges0)
    assert 0.1 < dd._otsu(sub) < 0.8


def _reference_centroid(crop, lab, label, win_kernel, ring_kernel, xa, ya):
    r'''The former per-dot computation of detect_dots, verbatim: the window, ring, board
plane (np.nonzero, np.mean, np.column_stack, np.linalg.solve) and weights'''
    mask = (lab == label).view(np.uint8)
    window = cv2.dilate(mask, win_kernel).view(bool)
    ring = cv2.dilate(mask, ring_kernel).view(bool) & ~window & (lab == 0)
    v = crop[ring]
    if len(v) < dd.MIN_RING_FOR_PLANE:
        board = float(np.median(v)) if len(v) else float(crop[window].max())
    else:
        ry, rx = np.nonzero(ring)
        rx += xa
        ry += ya
        xm, ym = rx.mean(), ry.mean()
        x, y = rx - xm, ry - ym
        A = np.column_stack((np.ones_like(x), x, y))
        r = np.abs(v - A @ np.linalg.solve(A.T @ A, A.T @ v))
        keep = r < 5 * 1.4826 * (np.median(r) + 1e-12) + 1e-9
        coef = np.linalg.solve(A[keep].T @ A[keep], A[keep].T @ v[keep])
        h, w = crop.shape
        xx = np.arange(xa, xa + w)[np.newaxis, :]
        yy = np.arange(ya, ya + h)[:, np.newaxis]
        board = coef[0] + coef[1] * (xx - xm) + coef[2] * (yy - ym)
    with np.errstate(divide="ignore", invalid="ignore"):
        wgt = np.maximum(1.0 - crop / board, 0.0) * window
    wgt[~np.isfinite(wgt)] = 0.0
    s = wgt.sum()
    if not s > 0:
        return None
    xx = np.arange(xa, xa + crop.shape[1])[np.newaxis, :]
    yy = np.arange(ya, ya + crop.shape[0])[:, np.newaxis]
    return (wgt * xx).sum() / s, (wgt * yy).sum() / s


def _dot_field(seed, H=240, W=320, K=4):
    r'''Area-averaged dark dots of many sizes on a vignetted, noisy board (float64)'''
    rng = np.random.default_rng(seed)
    yy, xx = (np.mgrid[:H * K, :W * K] + 0.5) / K
    dark = np.zeros((H * K, W * K), bool)
    for _ in range(25):
        cx, cy, r = rng.uniform(8, W - 8), rng.uniform(8, H - 8), rng.uniform(1.5, 9)
        dark |= (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
    cover = dark.reshape(H, K, W, K).mean(axis=(1, 3))
    y, x = np.mgrid[:H, :W]
    board = 0.9 * (1 - 0.5 * ((x - W / 2) ** 2 + (y - H / 2) ** 2) / (W * W / 4 + H * H / 4))
    return board * (1 - 0.85 * cover) + rng.normal(0, 0.01, (H, W))


@pytest.mark.parametrize("seed", range(4))
def test_dot_centroid_is_the_former_computation(seed):
    img = _dot_field(seed)
    H, W = img.shape
    n, labels, stats, _ = cv2.connectedComponentsWithStats((img < 0.4).astype(np.uint8),
                                                           connectivity=8)
    win, ring = dd._disk(2), dd._disk(5)
    checked = 0
    for label in range(1, n):
        x0, y0, w, h, _ = stats[label]
        xa, ya, xb, yb = max(0, x0 - 6), max(0, y0 - 6), min(W, x0 + w + 6), min(H, y0 + h + 6)
        crop, lab = img[ya:yb, xa:xb], labels[ya:yb, xa:xb]
        ref = _reference_centroid(crop, lab, label, win, ring, xa, ya)
        got = dd._dot_centroid(crop.copy(), (lab == label).view(np.uint8), lab == 0, win,
                               ring, xa, ya)
        assert got == ref            # bit for bit (tuples of floats, or both None)
        checked += ref is not None
    assert checked > 10


def test_dot_centroid_with_a_zero_board_level():
    r'''A ring of fewer than MIN_RING_FOR_PLANE pixels, all 0: the board level is 0, every
weight 0/0 or x/0, none of them finite: no centroid'''
    crop = np.full((20, 20), 0.5)
    crop[8:12, 8:12] = 0.0
    lab = np.full((20, 20), 2, np.int32)
    lab[8:12, 8:12] = 1
    lab[5, 8:13] = 0            # 5 ring pixels, 0 on the board
    crop[5, 8:13] = 0.0
    args = (dd._disk(2), dd._disk(5), 10, 20)
    assert _reference_centroid(crop, lab, 1, *args) is None
    masks = (lab == 1).view(np.uint8), lab == 0
    assert dd._dot_centroid(crop.copy(), *masks, *args) is None
    crop[5, 8:13] = 0.8         # a board level again: the same centroid as before
    ref = _reference_centroid(crop, lab, 1, *args)
    assert ref is not None and dd._dot_centroid(crop.copy(), *masks, *args) == ref


def _masks():
    r'''Dark masks with components of every kind: specks, rings with components in their
holes, diagonal contacts, components on the border, one over a quarter of the image'''
    for seed in range(12):
        rng = np.random.default_rng(seed)
        if seed % 3 == 0:
            shape = (int(rng.integers(1, 90)), int(rng.integers(1, 90)))
            yield (rng.uniform(size=shape) < rng.uniform(0.2, 0.7)).astype(np.uint8)
        else:
            m = (_speckled(seed) < 0.5).astype(np.uint8)
            yield np.ascontiguousarray(m[5:-7, 3:]) if seed % 3 == 2 else m
    big = np.zeros((40, 50), np.uint8)
    big[2:35, 3:45] = 1
    big[10:20, 10:20] = 0
    big[14:16, 14:16] = 1
    big[25, 47] = 1
    yield big


def _as_image(mask):
    r'''A float32 image whose pixels below 0.5 are the mask'''
    return np.where(mask != 0, np.float32(0.1), np.float32(0.9))


def test_reduced_blobs_are_the_stats_filter():
    r'''The former filter on cv2's statistics'''
    for mask in _masks():
        H, W = mask.shape
        st = cv2.connectedComponentsWithStats(mask, connectivity=8)[2][1:]
        st = st[(st[:, 4] >= dd.MIN_REDUCED_AREA_PX) & (st[:, 4] <= 0.25 * mask.size)
                & (st[:, 0] > 0) & (st[:, 1] > 0) & (st[:, 0] + st[:, 2] < W)
                & (st[:, 1] + st[:, 3] < H)]
        assert dd._reduced_blobs(_as_image(mask), 0.5) == [tuple(r) for r in st[:, :4].tolist()]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_label_whole_is_cv2_labels_stats_and_centroids(dtype):
    for mask in _masks():
        n, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
        masks, st, c = dd._label_whole(_as_image(mask).astype(dtype), 0.5)
        assert np.array_equal(st[1:], stats[1:]) and np.array_equal(c[1:], centroids[1:])
        H, W = mask.shape
        assert np.array_equal(dd._label_image(masks, st, 0, 0, W, H), labels)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_one_non_finite_pixel_of_a_large_image_is_refused(bad):
    r'''Through the reduced image (a size not a multiple of REDUCTION: its last rows and
columns are averaged with fractional weights), anywhere in the image'''
    from targets.boards import load_target
    H, W = 1903, 2403
    assert H * W > dd.LARGE_IMAGE_PIXELS and H % dd.REDUCTION and W % dd.REDUCTION
    img = np.tile(_speckled(1), (7, 6))[:H, :W].copy()
    assert dd._range(img, dd._reduce(img, dd.REDUCTION)) == (img.min(), img.max())
    for y, x in ((0, 0), (H - 1, W - 1), (H - 1, 5), (7, W - 2), (950, 1201)):
        img[y, x] = bad
        det = dd.detect_dots(img, load_target("dots"))
        assert det.status == "failed" and det.reason == "the image has non-finite pixels"
        img[y, x] = 0.5


def test_range_is_numpy_min_max():
    img = _speckled(2)
    for small in (None, dd._reduce(img, 4)):
        lo, hi = dd._range(img, small)
        assert (lo, hi) == (img.min(), img.max()) and type(lo) is np.float32
    img[8:12, 8:12] = np.float32(3e38)      # finite, but the reduced image overflows
    small = dd._reduce(img, 4)
    assert not np.isfinite(small.max())
    assert dd._range(img, small) == (img.min(), img.max())


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape,s,step", [((300, 420), 4, 4), ((300, 420), 4, 3),
                                          ((300, 420), 4, 5), ((302, 420), 4, 4),
                                          ((300, 418), 2, 5)])
def test_scan_is_reduce_and_subsample(dtype, shape, s, step):
    img = np.tile(_speckled(4), (2, 2))[:shape[0], :shape[1]].astype(dtype)
    small, sub = dd._scan(img, s, step)
    ref = dd._reduce(img, s)
    assert np.array_equal(small, ref) and small.dtype == ref.dtype
    assert np.array_equal(sub, img[::step, ::step].ravel()) and sub.dtype == img.dtype
    img[shape[0] - 1, 7] = np.nan
    small, sub = dd._scan(img, s, step)
    assert np.isnan(small).any()


def test_scan_reuses_its_arrays_only_when_nothing_holds_them():
    r'''_scan's arrays come back to the next call once dropped (no fresh pages per
detection), but a result still held (or a view of it) is never written again'''
    a = np.tile(_speckled(4), (2, 2))[:300, :420].astype(np.float32)
    b = a[::-1].copy()
    small_a, sub_a = dd._scan(a, 4, 4)
    kept = small_a.copy(), sub_a.copy()
    small_b, sub_b = dd._scan(b, 4, 4)
    assert np.array_equal(small_a, kept[0]) and np.array_equal(sub_a, kept[1])
    assert np.array_equal(small_b, dd._reduce(b, 4)) and small_b is not small_a
    del small_a, sub_a, kept
    memory = small_b.ctypes.data, sub_b.ctypes.data
    del small_b, sub_b
    small_c, sub_c = dd._scan(a, 4, 4)
    assert (small_c.ctypes.data, sub_c.ctypes.data) == memory
    assert np.array_equal(small_c, dd._reduce(a, 4))
    assert np.array_equal(sub_c, a[::4, ::4].ravel())


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_reduce4_kernel_is_cv2_area_average(dtype):
    r'''The compiled 4x4 average is cv2's, bit for bit, where the order of the 16 additions
shows: values of every magnitude and sign (the rounding of each partial sum differs with
the order), infinities and overflow to them'''
    rng = np.random.default_rng(5)
    img = (rng.standard_normal((96, 128)) * 10.0 ** rng.integers(-8, 8, (96, 128))).astype(dtype)
    img[3, 5], img[40, 41], img[60:64, 8:12] = np.inf, -np.inf, np.finfo(dtype).max
    small, sub = dd._scan(img, 4, 4)
    ref = dd._reduce(img, 4)
    assert np.array_equal(small, ref, equal_nan=True)
    assert np.array_equal(sub, img[::4, ::4].ravel())


def _problem_from_range(img):
    r'''The image test as the detector made it before _image_problem: from the full range'''
    lo, hi = img.min(), img.max()
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "the image has non-finite pixels"
    if not hi - lo > dd.MIN_CONTRAST:
        return f"no contrast in the image (range {lo:.3g}..{hi:.3g})"
    return None


@pytest.mark.parametrize("level", [0.0, 0.5, -3.0, 1e4])
def test_image_problem_is_the_full_range_test(level):
    r'''Through the reduced image or not, the same verdict as the full range gives: ranges
just above and below MIN_CONTRAST (float32 steps of the level), a contrast that only
single pixels show (averaged away in the reduced image), non-finite pixels'''
    rng = np.random.default_rng(7)
    base = np.float32(level) + rng.uniform(0, 1, (64, 96)).astype(np.float32) * np.float32(0.01)
    ulp = np.spacing(np.float32(level + 0.03))
    for extra in (0.0, 0.0101, 0.02, 0.025, 0.5):
        for kind in ("block", "pixel"):
            for nudge in (-2, 0, 2):
                img = base.copy()
                if kind == "block":
                    img[8:16, 12:20] += np.float32(extra)
                else:
                    img[9, 13] += np.float32(extra)
                img[9, 13] += nudge * ulp
                want = _problem_from_range(img)
                for small in (None, dd._reduce(img, 4)):
                    assert dd._image_problem(img, small) == want
                    if small is not None and dd._shows_contrast(small):
                        assert want is None
    img = base.copy()
    img[5, 6] = np.nan
    assert dd._image_problem(img, dd._reduce(img, 4)) == "the image has non-finite pixels"


def test_reduced_contrast_decides_the_paper_like_image():
    # a board with dark dots: the reduced image shows the contrast, so no full range pass
    img = np.tile(_speckled(1), (2, 2))
    assert dd._shows_contrast(dd._reduce(img, 4)) and dd._image_problem(img) is None


@pytest.mark.parametrize("seed", range(3))
def test_small_float32_image_is_read_as_its_float64_copy(seed):
    r'''A small float32 image is not converted as a whole: the same threshold, blobs,
centroids and verdicts as its float64 copy (whose values it holds exactly), also at a
range just above and below the contrast bar (float32 and float64 differences differ)'''
    from targets.boards import load_target
    from targets.detect import detect
    t = load_target("dots")
    img = _dot_field(seed).astype(np.float32)
    for im in (img, np.float32(0.5) + (img - img.min()) * np.float32(0.02 / np.ptp(img)),
               np.float32(0.5) + (img - img.min()) * np.float32(0.0201 / np.ptp(img))):
        a, b = detect(im, t), detect(im.astype(np.float64), t)
        assert (a.status, a.reason, a.info) == (b.status, b.reason, b.info)
        assert np.array_equal(a.q, b.q, equal_nan=True)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_pixels_of_no_blob_of_a_whole_labelling_are_the_light_ones(seed, dtype):
    r'''The detector takes a crowded crop's pixels of no blob as the light pixels (not
img < thr) when the whole image was labelled: every dark pixel then lies in a labelled
component, so this is the label image's zeros (_label_image), NaN pixels included'''
    img = _speckled(seed).astype(dtype)
    img[np.random.default_rng(seed).uniform(size=img.shape) < 0.002] = np.nan
    thr = np.float64(0.45)
    masks, stats, _ = dd._label_whole(img, thr)
    t = np.result_type(img, thr).type(thr)
    rng = np.random.default_rng(100 + seed)
    for _ in range(40):
        xa, ya = rng.integers(0, 380), rng.integers(0, 260)
        xb, yb = xa + rng.integers(1, 40), ya + rng.integers(1, 40)
        assert np.array_equal(dd._label_image(masks, stats, xa, ya, xb, yb) == 0,
                              ~(img[ya:yb, xa:xb] < t))


def _lattice_blobs(seed):
    r'''Blob centroids of a 9 x 7 dot lattice under perspective and a barrel warp (rows
bend by ~half a spacing), two dots missing, one far too large (area ratio > 4 with its
neighbours: never a lattice node), two stray blobs in the middle of cells; -> (c, area, ij)
with ij the lattice position of each blob ((-1, -1) for the strays)'''
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(9), np.arange(7), indexing="ij")
    ij = np.column_stack((i.ravel(), j.ravel()))
    x, y = ij[:, 0] - 4.0, ij[:, 1] - 3.0
    w = 1.0 + 0.04 * x + 0.02 * y                              # perspective
    px, py = 30 * x / w, 30 * y / w
    r2 = (px * px + py * py) / 150.0 ** 2
    c = np.column_stack((px, py)) * (1 - 0.1 * r2)[:, None] + rng.normal(0, 0.3, (63, 2))
    area = 40.0 * (1 + rng.uniform(-0.2, 0.2, 63))
    # strays in the middle of two cells away from the seed (index 30 after the holes)
    strays = np.array([c[[0, 1, 7, 8]].mean(axis=0), c[[53, 54, 60, 61]].mean(axis=0)])
    keep = np.ones(63, bool)
    keep[[10, 40]] = False
    area[25] *= 6.0
    c, area, ij = c[keep], area[keep], ij[keep]
    return (np.vstack((c, strays)), np.concatenate((area, [40.0, 40.0])),
            np.vstack((ij, [[-1, -1], [-1, -1]])))


@pytest.mark.parametrize("seed", range(5))
def test_grow_finds_the_lattice_around_holes_strays_and_an_outsized_dot(seed):
    r'''_grow (the compiled walk) maps the lattice offsets to exactly the blobs at those
lattice positions: one integer frame for all, the strays and the outsized dot left out,
the walk going round the holes; a max_extent the lattice exceeds gives None'''
    from scipy.spatial import cKDTree
    c, area, ij = _lattice_blobs(seed)
    seed_blob = 30
    nodes = dd._grow(c, area, seed_blob, cKDTree(c), 9)
    assert nodes is not None
    big = int(np.flatnonzero(area > 100)[0])
    members = set(range(len(c))) - {big} - set(np.flatnonzero(ij[:, 0] < 0).tolist())
    assert set(nodes.values()) == members and len(nodes) == len(members)
    ab = np.array(list(nodes.keys()), float)
    d_ij = (ij[list(nodes.values())] - ij[seed_blob]).astype(float)
    # the lattice frame: d_ij = ab @ F with F a signed permutation (integer, |det| 1)
    F, *_ = np.linalg.lstsq(ab, d_ij, rcond=None)
    assert np.array_equal(np.rint(F), F.round(9)) and abs(round(np.linalg.det(F))) == 1
    assert np.array_equal(ab @ np.rint(F), d_ij)
    assert dd._grow(c, area, seed_blob, cKDTree(c), 4) is None

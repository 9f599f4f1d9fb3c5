r'''The dot detector's compiled kernels (targets._dot_kernels) against its numpy path

dilations() must give cv2.dilate's pixels exactly (the window and ring decide which
pixels weigh); dot_centroid() the numpy centroid (detect_dots._dot_centroid) to
rounding: the same pixels and weights summed in another order, so a difference of
1e-9 px is already 10^4 times what the sums' rounding makes (the bar the detector
keeps is 1e-5 px, far below the ~1e-3 px sampling error of a rendered dot);
mark_flags() the same marks as the numpy fits (a discrete decision: equal flags).
'''

import cv2
import numpy as np
import pytest
from test_detect_dots_exact import _dot_field

from targets import _dot_kernels as K
from targets import detect_dots as dd

NO_FREE = np.zeros((1, 1), bool)


@pytest.mark.parametrize("seed", range(8))
def test_dilations_are_cv2s(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(3, 60, 2)
    mask = np.zeros((h, w), np.uint8)
    # blobs, holes, single pixels, and pixels on the crop's border (clipped stamps)
    for _ in range(4):
        cx, cy, r = rng.uniform(-3, w + 3), rng.uniform(-3, h + 3), rng.uniform(0.5, 12)
        yy, xx = np.mgrid[:h, :w]
        mask[(xx - cx) ** 2 + (yy - cy) ** 2 < r * r] ^= 1
    mask[rng.uniform(size=(h, w)) < 0.03] = 1
    for r1, r2 in ((2, 5), (1, 4), (0, 3), (3, 9)):
        k1, k2 = dd._disk(r1), dd._disk(r2)
        window, outer = K.dilations(mask, *K.element_rows(k1), *K.element_rows(k2))
        assert np.array_equal(window, cv2.dilate(mask, k1).view(bool))
        assert np.array_equal(outer, cv2.dilate(mask, k2).view(bool))


def test_an_element_with_a_gap_in_a_row_is_refused():
    # dilations() takes an element row by row as intervals: a ring-shaped one is refused
    # (the detector then takes the numpy path)
    ring = np.ones((5, 5), np.uint8)
    ring[2, 2] = 0
    assert K.element_rows(ring) is None
    lo, hi = K.element_rows(dd._disk(2))
    assert lo.tolist() == [0, -2, -2, -2, 0] and hi.tolist() == [0, 2, 2, 2, 0]


def _kernel_centroid(crop, mask, free, xa, ya, mx=0, my=0):
    rows = K.element_rows(dd._disk(2)) + K.element_rows(dd._disk(5))
    status, cx, cy = K.dot_centroid(np.ascontiguousarray(crop), mask, mx, my,
                                    NO_FREE if free is None else free, free is not None,
                                    *rows, xa, ya, dd.MIN_RING_FOR_PLANE)
    assert status in (0, 1)
    return (cx, cy) if status else None


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("offset", [(0, 0), (5000, 3700)])
def test_dot_centroid_is_the_numpy_one(seed, offset):
    r'''Vignetted noisy dots of radius 1.5-9 px, some touching (free pixels), some with a
ring too small for a plane; offset moves the crops to the far corner of a 5120x3840
image, where numpy's sums of x w round the most'''
    img = _dot_field(seed)
    H, W = img.shape
    n, labels, stats, _ = cv2.connectedComponentsWithStats((img < 0.4).astype(np.uint8),
                                                           connectivity=8)
    win, ring = dd._disk(2), dd._disk(5)
    checked = shared = 0
    for label in range(1, n):
        x0, y0, w, h, _ = stats[label]
        p = 14                  # wider than the detector's 6: neighbours come in
        xa, ya, xb, yb = max(0, x0 - p), max(0, y0 - p), min(W, x0 + w + p), min(H, y0 + h + p)
        crop, lab = img[ya:yb, xa:xb], labels[ya:yb, xa:xb]
        mask = (lab == label).view(np.uint8)
        for free in (lab == 0, None):
            if free is None and ((lab != 0) & (lab != label)).any():
                continue    # None means no other blob in the crop
            ref = dd._dot_centroid(crop.copy(), mask, free, win, ring, xa + offset[0],
                                   ya + offset[1])
            got = _kernel_centroid(crop, mask, free, xa + offset[0], ya + offset[1])
            assert (got is None) == (ref is None)
            # the blob's mask over its box only, placed in the crop: the same pixels read
            box = (labels[y0:y0 + h, x0:x0 + w] == label)
            assert _kernel_centroid(crop, box, free, xa + offset[0], ya + offset[1],
                                    x0 - xa, y0 - ya) == got
            if ref is not None:
                assert np.max(np.abs(np.subtract(got, ref))) < 1e-9
                checked += 1
                shared += free is not None and ((lab != 0) & (lab != label)).any()
    assert checked > 10 and shared > 0


def test_dot_centroid_with_few_or_no_ring_pixels():
    r'''Rings below MIN_RING_FOR_PLANE pixels: their median (0 here: every weight x/0 or
0/0, none finite, no centroid; 0.8: a centroid), or none at all (the window's maximum)'''
    crop = np.full((20, 20), 0.5)
    crop[8:12, 8:12] = 0.0
    lab = np.full((20, 20), 2, np.int32)
    lab[8:12, 8:12] = 1
    lab[5, 8:13] = 0
    crop[5, 8:13] = 0.0
    mask, free = (lab == 1).view(np.uint8), lab == 0
    win, ring = dd._disk(2), dd._disk(5)
    assert dd._dot_centroid(crop.copy(), mask, free, win, ring, 10, 20) is None
    assert _kernel_centroid(crop, mask, free, 10, 20) is None
    crop[5, 8:13] = 0.8
    ref = dd._dot_centroid(crop.copy(), mask, free, win, ring, 10, 20)
    assert ref is not None
    assert np.max(np.abs(np.subtract(_kernel_centroid(crop, mask, free, 10, 20), ref))) < 1e-12
    nothing = np.zeros_like(free)
    crop[9, 9] = 0.6            # the window's maximum is the board level
    ref = dd._dot_centroid(crop.copy(), mask, nothing, win, ring, 10, 20)
    assert ref is not None
    assert np.max(np.abs(np.subtract(_kernel_centroid(crop, mask, nothing, 10, 20), ref))) \
        < 1e-12


@pytest.mark.parametrize("seed", range(20))
def test_mark_flags_are_the_numpy_ones(seed):
    r'''Lattices of 2-12 x 2-12 dots with perspective in the areas, holes (missing dots:
neighbourhoods with too few or collinear neighbours take the median), marks, noise'''
    rng = np.random.default_rng(seed)
    na, nb = rng.integers(2, 13, 2)
    ga, gb = rng.uniform(-0.4, 0.4, 2)
    nodes, area = {}, []
    for a in range(na):
        for b in range(nb):
            if rng.uniform() < 0.2:
                continue
            nodes[(a - 3, b + 7)] = len(area)
            mark = rng.uniform() < 0.05
            area.append(900 * np.exp(ga * a + gb * b) * (1.96 if mark else 1.0)
                        * rng.uniform(0.97, 1.03))
    area.append(50.0)           # a blob outside the lattice
    area = np.array(area)
    ref = dd._mark_flags_numpy(nodes, area, 1.4)
    assert np.array_equal(dd.mark_flags(nodes, area, 1.4), ref)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 8, 9, 31, 100, 901])
def test_median_is_np_median(n):
    # the quickselect median, on ties and on continuous values
    rng = np.random.default_rng(n)
    for v in (rng.normal(size=n), rng.integers(0, 4, n).astype(float), np.ones(n)):
        assert K._median(v.copy(), n) == np.median(v)

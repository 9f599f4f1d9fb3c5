r'''Compiled per-dot centroid of targets.detect_dots (numba): window, ring, board plane, weights

SYNOPSIS

    from targets import _dot_kernels as K

    rows = K.element_rows(win_kernel) + K.element_rows(ring_kernel)   # (lo, hi) twice
    status, cx, cy = K.dot_centroid(crop, mask, mx, my, free, has_free, *rows, xa, ya,
                                    min_ring)
    # status 1: centroid (cx, cy); 0: no weight (no centroid); -1: a degenerate plane fit
    # (a zero pivot): the caller computes this dot the numpy way (detect_dots._dot_centroid)
    is_mark = K.mark_flags(ab, node, area, ratio_threshold, R)     # detect_dots.mark_flags
    counts = K.histogram_counts(v, edges, lo, scale)               # detect_dots._histogram
    comps, pixels = K.label_boxes(img, thr, boxes)                 # detect_dots._label_stack
    K.reduce4_and_subsample(img, small, sub, step)                 # detect_dots._scan

One call per dot instead of about forty numpy and OpenCV calls (their overhead was most
of the detector's time: ~250 us a dot). The arithmetic is detect_dots._dot_centroid's
(the numpy reference, kept as the fallback and the tests' oracle), pixel by pixel:

- window = the mask dilated by win_kernel, ring = dilated by ring_kernel, minus the
  window, minus pixels of other blobs (free; has_free False: none come near). The
  dilations (dilations()) are those of cv2.dilate for a symmetric element whose rows are
  intervals (cv2's MORPH_ELLIPSE; element_rows() returns None for another element, and
  the detector then takes the numpy path), crop borders clipped as cv2's border does.
- board level: the plane a + b x + c y fitted by normal equations to the ring's pixels
  (raster order, centred coordinates), refitted without pixels beyond 5 x 1.4826 x the
  median residual; the ring's median if it has fewer than min_ring pixels, the window's
  maximum if it has none. The 3x3 systems are solved by Gaussian elimination with
  partial pivoting (LAPACK's gesv for one right-hand side); a zero pivot returns -1.
- weights max(1 - I/B, 0) over the window, a non-finite weight counted 0; the centroid
  is (sum w x, sum w y) / sum w.

Sums run in raster order (numpy sums pairwise), the weighted coordinates in the crop's
frame (numpy's in the image's: its rounding grows with the coordinates, ~1e-9 px on
5120x3840): the centroids agree with the numpy path to rounding, well below the 1e-5 px
that matters (tests/test_detect_dots_kernels.py).

Compilation: few small functions without np.sort or array expressions, as their
compile time (paid once per source change, cache=True) grows with the code numba
generates; a process loads the cached kernels in ~0.4 s CPU.
'''

import math

import numpy as np
from llvmlite import binding as _llvm
from llvmlite import ir as _ir
from numba import njit
from numba.core import cgutils as _cgutils
from numba.core import types as _types
from numba.extending import intrinsic

# rows of a crop of a large image lie a page or more apart, where the hardware prefetcher
# does not follow: the kernels that walk a crop row by row request the cache lines of the
# row this many rows ahead (label_boxes 7.2 -> 4.5 ms, dot_centroid 15.6 -> 12.3 ms of CPU
# per 5120x3840 paper render, load 14; 4 and 8 rows ahead gain the same)
PREFETCH_ROWS = 4
_LINE_BYTES = 64



@intrinsic
def _prefetch(typingctx, a, y, x):
    r'''A hint to load a[y, x]'s cache line (llvm.prefetch: a read, kept in every cache
level): no effect on any result; an address off the array does not fault'''
    name = "llvm.prefetch.p0" if _llvm.llvm_version_info >= (15,) else "llvm.prefetch.p0i8"

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = _cgutils.get_item_pointer(context, builder, signature.args[0], ary,
                                        [args[1], args[2]], wraparound=False)
        i8p, i32 = _ir.IntType(8).as_pointer(), _ir.IntType(32)
        fn = _cgutils.get_or_insert_function(
            builder.module, _ir.FunctionType(_ir.VoidType(), [i8p, i32, i32, i32]), name)
        builder.call(fn, [builder.bitcast(ptr, i8p), _ir.Constant(i32, 0),
                          _ir.Constant(i32, 3), _ir.Constant(i32, 1)])
        return context.get_dummy_value()
    return _types.void(a, y, x), codegen


@njit(cache=True, error_model="numpy", inline="always")
def _prefetch_row(a, y, x0, x1):
    r"""A hint to load the cache lines of a[y, x0:x1] (PREFETCH_ROWS)"""
    if x1 > x0:
        for x in range(x0, x1, max(1, _LINE_BYTES // a.itemsize)):
            _prefetch(a, y, x)
        _prefetch(a, y, x1 - 1)


def element_rows(kernel):
    r"""(lo, hi): the columns lo..hi of each row of a structuring element (uint8, odd
square) relative to its centre, lo > hi for an empty row, as dilations() takes them;
None unless every row's elements are one interval (cv2's MORPH_ELLIPSE elements are)"""
    k = np.asarray(kernel) != 0
    r = k.shape[1] // 2
    lo = np.ones(len(k), np.int64)
    hi = np.zeros(len(k), np.int64)
    for i, row in enumerate(k):
        cols = np.flatnonzero(row)
        if len(cols):
            if cols[-1] - cols[0] + 1 != len(cols):
                return None
            lo[i], hi[i] = cols[0] - r, cols[-1] - r
    return lo, hi


@njit(cache=True, error_model="numpy")
def _dilation_steps(mask, lo_w, hi_w, lo_r, hi_r):
    r"""d (2,h,w+1) int32: the difference arrays along the rows of mask (uint8, 0/1)
dilated by two symmetric structuring elements given by their rows (element_rows()):
d[0] the window's, d[1] the outer one's; a pixel is in dilation j iff the prefix sum
of d[j, y, :x + 1] is positive (dilations())

Run by run: a run of mask pixels [s, e) of row y covers, in row y + dy, the columns
[s + lo, e + hi) of the element's row dy (lo..hi); crop borders clip the intervals, as
cv2's constant border adds nothing."""
    h, w = mask.shape
    d = np.zeros((2, h, w + 1), np.int32)
    for y in range(h):
        x = 0
        while x < w:
            if not mask[y, x]:
                x += 1
                continue
            s = x
            while x < w and mask[y, x]:
                x += 1
            for which in range(2):
                lo, hi = (lo_w, hi_w) if which == 0 else (lo_r, hi_r)
                r = len(lo) // 2
                for i in range(len(lo)):
                    Y = y + i - r
                    if lo[i] > hi[i] or Y < 0 or Y >= h:
                        continue
                    a, b = max(s + lo[i], 0), min(x + hi[i], w)
                    if a < b:
                        d[which, Y, a] += 1
                        d[which, Y, b] -= 1
    return d


@njit(cache=True, error_model="numpy")
def dilations(mask, lo_w, hi_w, lo_r, hi_r):
    r"""(window, outer): mask (uint8, 0/1) dilated by two symmetric structuring elements
given by their rows (element_rows()), as cv2.dilate gives them (bool): the prefix sums
of _dilation_steps(), the form dot_centroid() reads them in"""
    h, w = mask.shape
    d = _dilation_steps(mask, lo_w, hi_w, lo_r, hi_r)
    window = np.zeros((h, w), np.bool_)
    outer = np.zeros((h, w), np.bool_)
    for y in range(h):
        cw = cr = 0
        for x in range(w):
            cw += d[0, y, x]
            cr += d[1, y, x]
            window[y, x] = cw > 0
            outer[y, x] = cr > 0
    return window, outer


@njit(cache=True, error_model="numpy")
def _solve3(N, b):
    r'''N^-1 b by Gaussian elimination with partial pivoting (N and b overwritten);
ok False at a zero pivot'''
    for k in range(3):
        p = k
        for i in range(k + 1, 3):
            if abs(N[i, k]) > abs(N[p, k]):
                p = i
        if N[p, k] == 0.0:
            return False
        if p != k:
            for j in range(3):
                N[k, j], N[p, j] = N[p, j], N[k, j]
            b[k], b[p] = b[p], b[k]
        for i in range(k + 1, 3):
            f = N[i, k] / N[k, k]
            for j in range(k + 1, 3):
                N[i, j] -= f * N[k, j]
            b[i] -= f * b[k]
    for k in range(2, -1, -1):
        s = b[k]
        for j in range(k + 1, 3):
            s -= N[k, j] * b[j]
        b[k] = s / N[k, k]
    return True


@njit(cache=True, error_model="numpy")
def _add_plane_point(N, b, x, y, v):
    r"""One point's share of the normal equations of the plane v = a + b x + c y: the upper
triangle of N (3,3) and b (3,)"""
    N[0, 0] += 1.0
    N[0, 1] += x
    N[0, 2] += y
    N[1, 1] += x * x
    N[1, 2] += x * y
    N[2, 2] += y * y
    b[0] += v
    b[1] += x * v
    b[2] += y * v


@njit(cache=True, error_model="numpy")
def _median(v, n):
    r"""The median of v[:n] (n > 0) as np.median takes it: the middle order statistic, or
the mean of the two middle ones; v[:n] is reordered (a quickselect: compiles in a
fraction of np.sort's time)"""
    k = n // 2
    lo, hi = 0, n - 1
    while lo < hi:
        pivot = v[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while v[i] < pivot:
                i += 1
            while v[j] > pivot:
                j -= 1
            if i <= j:
                v[i], v[j] = v[j], v[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    m = v[k]
    if n % 2:
        return m
    below = v[0]    # v[:k] holds the k smallest: the largest of them is the (k-1)th
    for i in range(1, k):
        if v[i] > below:
            below = v[i]
    return (below + m) / 2


@njit(cache=True, error_model="numpy")
def _row_runs(mask, mx, my, h, w):
    r"""The runs of each row of an (h, w) crop whose only set pixels are those of mask (0/1,
uint8 or bool) placed with its pixel [0, 0] at the crop's (mx, my): (rs, re, row0), crop
row y's runs [rs[k], re[k]) for k in row0[y]..row0[y + 1] - 1, left to right, in crop
columns; only mask's pixels are read"""
    mh, mw = mask.shape
    rs = np.empty(mh * ((mw + 1) // 2) + 1, np.int64)
    re = np.empty(len(rs), np.int64)
    row0 = np.zeros(h + 1, np.int64)
    n = 0
    for y in range(h):
        row0[y] = n
        my_ = y - my
        if my_ < 0 or my_ >= mh:
            continue
        x = 0
        while x < mw:
            if not mask[my_, x]:
                x += 1
                continue
            rs[n] = x + mx
            while x < mw and mask[my_, x]:
                x += 1
            re[n] = x + mx
            n += 1
    row0[h] = n
    return rs, re, row0


@njit(cache=True, error_model="numpy", inline="always")
def _dilated_row(Y, h, w, rs, re, row0, lo, hi, a, b):
    r"""Row Y of the mask whose runs are (rs, re, row0) (_row_runs) dilated by the element
of rows (lo, hi) (element_rows()), as sorted disjoint intervals [a[k], b[k]) (written to
a, b; their count returned): each run [s, e) of row Y - i + r gives [s + lo[i], e + hi[i])
clipped to the crop (_dilation_steps' intervals), and their union is taken"""
    r = len(lo) // 2
    m = 0
    for i in range(len(lo)):
        y = Y - i + r
        if lo[i] > hi[i] or y < 0 or y >= h:
            continue
        for k in range(row0[y], row0[y + 1]):
            s, e = max(rs[k] + lo[i], 0), min(re[k] + hi[i], w)
            if not s < e:
                continue
            # the union so far: sorted, disjoint, not touching (one interval a row of a
            # dot, mostly): the new one merges with those from the first that reaches it
            # (b >= s) to the last that it reaches (a <= e)
            t = 0
            while t < m and b[t] < s:
                t += 1
            u = t
            while u < m and a[u] <= e:
                s, e = min(s, a[u]), max(e, b[u])
                u += 1
            if u == t:      # touches none: inserted before a[t]
                for q in range(m, t, -1):
                    a[q], b[q] = a[q - 1], b[q - 1]
                m += 1
            elif u > t + 1:     # it joins t..u-1: the rest moves down
                for q in range(u, m):
                    a[q - u + t + 1], b[q - u + t + 1] = a[q], b[q]
                m -= u - t - 1
            a[t], b[t] = s, e
    return m


@njit(cache=True, error_model="numpy")
def dot_centroid(crop, mask, mx, my, free, has_free, lo_w, hi_w, lo_r, hi_r, xa, ya,
                 min_ring):
    r"""(status, x, y): the centroid of the blob mask (uint8 or bool, over the blob's box,
whose pixel [0, 0] is the crop's (mx, my); the crop's other pixels are not the blob's) in
crop (float64 or float32, any strides: a view of the image; not written), crop[0, 0]
being pixel (xa, ya); free (bool, over the crop, read only if has_free) the pixels of no
blob; the elements' rows from element_rows(); see the module docstring

The window and the outer dilation are taken row by row as intervals from the mask's
runs (_dilated_row: the pixels dilations() gives), so that only the ring's and the
window's pixels are read, in raster order, in one pass over the crop's rows: the ring's
collected (the plane's points) and the window's copied; then the weights of each window
interval are computed elementwise (vectorised; a weight that is not finite or not
positive is 0, which adds nothing to the sums: they are non-negative, so s + 0 = s) and
summed in raster order. A float32 pixel is taken as its float64 value, as numpy's
astype gives it. 17.3 -> 15.4 ms of CPU per 100 dots of 5120x3840 renders (the union of
a row's intervals, the plane's sums in scalars and the weights), the same bits (load 19)."""
    h, w = crop.shape
    rs, re, row0 = _row_runs(mask, mx, my, h, w)
    runs = 1
    for y in range(h):
        runs = max(runs, row0[y + 1] - row0[y])
    cap = len(lo_r) * runs + 1
    # the window's intervals of every row: row y's are wa[wrow[y]:wrow[y + 1]]
    wa = np.empty(h * len(lo_w) * runs + 1, np.int64)
    wb = np.empty(len(wa), np.int64)
    wrow = np.empty(h + 1, np.int64)
    oa = np.empty(cap, np.int64)
    ob = np.empty(cap, np.int64)
    nwin = 0
    v = np.empty(h * w)
    wv = np.empty(h * w)
    nv = 0
    rx = np.empty(h * w, np.int64)
    ry = np.empty(h * w, np.int64)
    n = 0
    sx, sy = 0, 0
    for y in range(h):
        wrow[y] = nwin
        if y + PREFETCH_ROWS < h:
            _prefetch_row(crop, y + PREFETCH_ROWS, 0, w)
        nw = _dilated_row(y, h, w, rs, re, row0, lo_w, hi_w, wa[nwin:], wb[nwin:])
        no = _dilated_row(y, h, w, rs, re, row0, lo_r, hi_r, oa, ob)
        # the ring: the outer intervals' pixels outside the window's, left to right
        k = nwin
        for t in range(no):
            x = oa[t]
            while x < ob[t]:
                while k < nwin + nw and wb[k] <= x:
                    k += 1
                if k < nwin + nw and wa[k] <= x:
                    x = wb[k]           # inside the window: skip it
                    continue
                end = ob[t] if k == nwin + nw else min(ob[t], wa[k])
                for xx in range(x, end):
                    if not has_free or free[y, xx]:
                        v[n] = crop[y, xx]
                        rx[n] = xx + xa
                        ry[n] = y + ya
                        sx += xx + xa
                        sy += y + ya
                        n += 1
                x = end
        for k in range(nwin, nwin + nw):   # the window's pixels, for the weights
            for x in range(wa[k], wb[k]):
                wv[nv] = crop[y, x]
                nv += 1
        nwin += nw
    wrow[h] = nwin
    plane = n >= min_ring
    level = 0.0
    coef = np.zeros(3)
    xm = ym = 0.0
    if plane:
        xm, ym = sx / n, sy / n
        dx = np.empty(n)
        dy = np.empty(n)
        for k in range(n):
            dx[k] = rx[k] - xm
            dy[k] = ry[k] - ym
        use = np.ones(n, np.bool_)
        N = np.empty((3, 3))
        for fit in range(2):
            # least squares v = a + b dx + c dy over the used pixels: normal equations
            # (_add_plane_point's sums, in scalars: the same order of additions)
            n00 = n01 = n02 = n11 = n12 = n22 = b0 = b1 = b2 = 0.0
            for k in range(n):
                if not use[k]:
                    continue
                x, y, vk = dx[k], dy[k], v[k]
                n00 += 1.0
                n01 += x
                n02 += y
                n11 += x * x
                n12 += x * y
                n22 += y * y
                b0 += vk
                b1 += x * vk
                b2 += y * vk
            N[0, 0], N[0, 1], N[0, 2] = n00, n01, n02
            N[1, 0], N[1, 1], N[1, 2] = n01, n11, n12
            N[2, 0], N[2, 1], N[2, 2] = n02, n12, n22
            coef[0], coef[1], coef[2] = b0, b1, b2
            if not _solve3(N, coef):
                return -1, 0.0, 0.0
            if fit == 0:
                # again without the pixels beyond 5 sigma (MAD) of the first fit
                r = np.empty(n)
                for k in range(n):
                    r[k] = abs(v[k] - (coef[0] + dx[k] * coef[1] + dy[k] * coef[2]))
                limit = 5 * 1.4826 * (_median(r, n) + 1e-12) + 1e-9
                for k in range(n):
                    use[k] = abs(v[k] - (coef[0] + dx[k] * coef[1] + dy[k] * coef[2])) < limit
    elif n:
        level = _median(v[:n].copy(), n)
    else:
        level = -np.inf
        for y in range(h):
            for k in range(wrow[y], wrow[y + 1]):
                for x in range(wa[k], wb[k]):
                    if crop[y, x] > level:
                        level = crop[y, x]
    s = sxw = syw = 0.0
    c0, c1 = coef[0], coef[1]
    if not plane:       # the level as a plane of slope 0: the same b at every pixel
        c0, c1, xm = level, 0.0, 0.0
    wt = np.empty(w)
    j = 0
    for y in range(h):
        # the plane's y term of the row: the same value and sum order as per pixel
        yterm = coef[2] * (float(y + ya) - ym) if plane else 0.0
        for k in range(wrow[y], wrow[y + 1]):
            a0, L = wa[k], wb[k] - wa[k]
            for t in range(L):
                b = c0 + c1 * (float(a0 + t + xa) - xm) + yterm
                wgt = 1.0 - wv[j + t] / b
                wt[t] = wgt if math.isfinite(wgt) and wgt > 0.0 else 0.0
            for t in range(L):
                s += wt[t]
                sxw += wt[t] * (a0 + t)   # crop coordinates: smaller terms, less rounding
                syw += wt[t] * y
            j += L
    if not s > 0:
        return 0, 0.0, 0.0
    return 1, xa + sxw / s, ya + syw / s


@njit(cache=True, error_model="numpy")
def mark_flags(ab, node, area, ratio_threshold, R):
    r'''detect_dots.mark_flags on arrays: ab (n,2) lattice coordinates of the nodes, node
(n,) their blob indices into area; R the neighbourhood (lattice steps each way)

The same fits in the same order: per node, its neighbours' log areas (da outer, db
inner) and a plane by normal equations, up to three rounds leaving out neighbours far
above it; the 8 adjacent neighbours' median when the plane is singular (its normal
matrix has small integer entries: its determinant is exact here, numpy's by LU).'''
    n = len(node)
    is_mark = np.zeros(len(area), np.bool_)
    log_thr = math.log(ratio_threshold)
    la = np.empty(len(area))
    for k in range(len(area)):
        la[k] = math.log(max(area[k], 1e-300))
    a0, b0, a1, b1 = ab[0, 0], ab[0, 1], ab[0, 0], ab[0, 1]
    for i in range(n):
        a0, a1 = min(a0, ab[i, 0]), max(a1, ab[i, 0])
        b0, b1 = min(b0, ab[i, 1]), max(b1, ab[i, 1])
    na, nb = a1 - a0 + 1, b1 - b0 + 1
    grid = np.zeros((na + 2 * R, nb + 2 * R), np.int64) - 1
    for i in range(n):
        grid[ab[i, 0] - a0 + R, ab[i, 1] - b0 + R] = node[i]
    m = (2 * R + 1) ** 2 - 1
    offa = np.empty(m)
    offb = np.empty(m)
    y = np.empty(m)
    keep = np.empty(m, np.bool_)
    neigh = np.empty(8)
    N = np.empty((3, 3))
    c = np.empty(3)
    for i in range(n):
        j = node[i]
        ga, gb = ab[i, 0] - a0 + R, ab[i, 1] - b0 + R
        cnt = 0
        for da in range(-R, R + 1):
            for db in range(-R, R + 1):
                k = grid[ga + da, gb + db]
                if (da or db) and k >= 0:
                    offa[cnt] = da
                    offb[cnt] = db
                    y[cnt] = la[k]
                    keep[cnt] = True
                    cnt += 1
        if cnt == 0:
            continue
        have = False
        pred = 0.0
        for _ in range(3):
            nk = 0
            for u in range(3):
                c[u] = 0.0
                for t in range(3):
                    N[u, t] = 0.0
            for k in range(cnt):
                if keep[k]:
                    nk += 1
                    _add_plane_point(N, c, offa[k], offb[k], y[k])
            N[1, 0], N[2, 0], N[2, 1] = N[0, 1], N[0, 2], N[1, 2]
            det = (N[0, 0] * (N[1, 1] * N[2, 2] - N[1, 2] * N[2, 1])
                   - N[0, 1] * (N[1, 0] * N[2, 2] - N[1, 2] * N[2, 0])
                   + N[0, 2] * (N[1, 0] * N[2, 1] - N[1, 1] * N[2, 0]))
            if nk < 3 or abs(det) < 0.5 or not _solve3(N, c):
                have = False
                break
            have = True
            pred = c[0]
            any_high = False
            for k in range(cnt):
                high = (y[k] - (c[0] + offa[k] * c[1] + offb[k] * c[2])) > 0.5 * log_thr
                if high and keep[k]:
                    any_high = True
                if high:
                    keep[k] = False
            if not any_high:
                break
        if not have:
            nn = 0
            for da in range(-1, 2):
                for db in range(-1, 2):
                    k = grid[ga + da, gb + db]
                    if (da or db) and k >= 0:
                        neigh[nn] = area[k]
                        nn += 1
            if nn:
                is_mark[j] = area[j] / _median(neigh, nn) > ratio_threshold
            continue
        is_mark[j] = la[j] - pred > log_thr
    return is_mark


@njit(cache=True, error_model="numpy")
def _slot(keys, key):
    # the slot of key in the open-addressed table keys (-1: empty), linear probing
    mask = len(keys) - 1
    i = key & mask
    while keys[i] != -1 and keys[i] != key:
        i = (i + 1) & mask
    return i


@njit(cache=True, error_model="numpy")
def grow_lattice(c, area, seed, u, v, max_nodes, tolerance, ratio_max):
    r"""detect_dots._grow's breadth-first walk from blob `seed`, compiled: the lattice
offsets (ka, kb) and blob indices idx of its nodes in the order the walk adds them,
and their count n (-1: the walk passed max_nodes nodes)

u, v: (2,) the seed's lattice steps. Each node's four neighbours are predicted (the
parallelogram of a neighbouring row or column, else the step back, else the node's
steps) and taken when the blob nearest the prediction (brute force: the nearest of
all, the first of equals) lies within tolerance x the step and not yet in the
lattice, and its area is within ratio_max of the node's either way. The arithmetic
and the order are _grow's own, so the lattice is the one a k-d tree's nearest
neighbours give (they differ only where two blobs are equally near a prediction)."""
    N = len(c)
    M = max_nodes + 2                    # |a|, |b| <= nodes so far
    size = 1
    while size < 4 * M:
        size *= 2
    hkeys = np.full(size, -1, np.int64)
    hvals = np.empty(size, np.int64)
    width = 2 * M + 1
    ka = np.empty(M, np.int64)
    kb = np.empty(M, np.int64)
    idx = np.empty(M, np.int64)
    lu = np.empty((M, 2))
    lv = np.empty((M, 2))
    taken = np.zeros(N, np.bool_)
    ka[0], kb[0], idx[0] = 0, 0, seed
    lu[0, 0], lu[0, 1], lv[0, 0], lv[0, 1] = u[0], u[1], v[0], v[1]
    taken[seed] = True
    i = _slot(hkeys, M * width + M)
    hkeys[i], hvals[i] = M * width + M, 0
    n = 1
    head = 0
    pred = np.empty(2)
    while head < n:
        a, b = ka[head], kb[head]
        j0 = idx[head]
        p0, p1 = c[j0, 0], c[j0, 1]
        for d in range(4):
            da = 1 if d == 0 else (-1 if d == 1 else 0)
            db = 0 if d < 2 else (1 if d == 2 else -1)
            t = _slot(hkeys, (a + da + M) * width + (b + db + M))
            if hkeys[t] != -1:
                continue                 # already a node
            have = False
            for s in range(2):
                sa = 0 if da != 0 else (1 if s == 0 else -1)
                sb = (1 if s == 0 else -1) if da != 0 else 0
                s1 = _slot(hkeys, (a + sa + M) * width + (b + sb + M))
                s2 = _slot(hkeys, (a + da + sa + M) * width + (b + db + sb + M))
                if hkeys[s1] != -1 and hkeys[s2] != -1:
                    q1 = idx[hvals[s1]]
                    q2 = idx[hvals[s2]]
                    pred[0] = p0 + (c[q2, 0] - c[q1, 0])
                    pred[1] = p1 + (c[q2, 1] - c[q1, 1])
                    have = True
                    break
            if not have:
                sbk = _slot(hkeys, (a - da + M) * width + (b - db + M))
                if hkeys[sbk] != -1:
                    jb = idx[hvals[sbk]]
                    pred[0] = p0 + (p0 - c[jb, 0])
                    pred[1] = p1 + (p1 - c[jb, 1])
                else:
                    pred[0] = p0 + (da * lu[head, 0] + db * lv[head, 0])
                    pred[1] = p1 + (da * lu[head, 1] + db * lv[head, 1])
            e0, e1 = pred[0] - p0, pred[1] - p1
            step_len = math.sqrt(e0 * e0 + e1 * e1)
            best, jn = np.inf, -1
            for k in range(N):
                x0, x1 = c[k, 0] - pred[0], c[k, 1] - pred[1]
                dd = x0 * x0 + x1 * x1
                if dd < best:
                    best, jn = dd, k
            if not (math.sqrt(best) < tolerance * step_len) or taken[jn]:
                continue
            r = area[jn] / area[j0]
            if not (1.0 / ratio_max < r < ratio_max):
                continue
            if n == M:
                return ka, kb, idx, -1
            ka[n], kb[n], idx[n] = a + da, b + db, jn
            hkeys[t], hvals[t] = (a + da + M) * width + (b + db + M), n
            taken[jn] = True
            if da != 0:
                lu[n, 0], lu[n, 1] = (c[jn, 0] - p0) * da, (c[jn, 1] - p1) * da
                lv[n, 0], lv[n, 1] = lv[head, 0], lv[head, 1]
            else:
                lu[n, 0], lu[n, 1] = lu[head, 0], lu[head, 1]
                lv[n, 0], lv[n, 1] = (c[jn, 0] - p0) * db, (c[jn, 1] - p1) * db
            n += 1
            if n > max_nodes:
                return ka, kb, idx, -1
        head += 1
    return ka[:n], kb[:n], idx[:n], n


@njit(cache=True, error_model="numpy")
def histogram_counts(v, edges, lo, scale):
    r'''The counts of detect_dots._histogram (np.histogram's) in one pass over v: each
value's bin estimated as min((v - lo) scale, bins - 1) in v's precision (lo and scale
of the edges' type), then moved one bin down or up against its edges, so that it counts
in the bin [edges[i], edges[i+1]) that holds it, the last bin closed

A run of equal values (==) counts once, by its length: they fall in one bin (the bin
is found from comparisons and differences of equal values), and a render's subsample
is mostly runs (99% of a 5120x3840 dot render's values equal the one before): 3.4 ->
1.6 ms on its 1.2 M values, where adding 1 to one bin per value waited for the last
addition to the same bin.'''
    bins = len(edges) - 1
    n = np.zeros(bins, np.intp)
    N = len(v)
    k = 0
    while k < N:
        b = v[k]
        j = k + 1
        while j < N and v[j] == b:
            j += 1
        f = (b - lo) * scale
        if f > bins - 1:
            f = bins - 1
        i = int(f)
        if b < edges[i]:
            i -= 1
        elif i < bins - 1 and b >= edges[i + 1]:
            i += 1
        n[i] += j - k
        k = j
    return n


@njit(cache=True, error_model="numpy")
def reduce4_and_subsample(img, small, sub, step):
    r"""small[Y, X] = the average of img's 4x4 block (Y, X) as cv2.resize(img, (W // 4, H // 4),
interpolation=cv2.INTER_AREA) computes it for whole blocks, and sub = img[::step, ::step],
in one pass over img (H and W multiples of 4; img float32 or float64, small of img's type)

cv2 takes an integer scale of 4 through its scalar area loop (its vector loop is for a
scale of 2): the block's 16 pixels summed in the image's type in raster order, four at a
time, sum += ((a + b) + c) + d, one group of four a row here, then times 1/16 (exact).
Row by row (a running sum of each block row) so that img is read in order, once. With
step 4 (a 5120x3840 image's) the subsample is each block's first pixel, stored as the
block's first row is summed (a strided copy of the row after it cost ~1 ms an image)."""
    H, W = img.shape
    w = W // 4
    acc = np.empty(w, img.dtype)
    sixteenth = img.dtype.type(0.0625)
    for Y in range(H // 4):
        for r in range(4):
            y = 4 * Y + r
            row = img[y]
            if r == 0 and step == 4:
                out = sub[Y]
                for X in range(w):
                    x = 4 * X
                    a = row[x]
                    acc[X] = ((a + row[x + 1]) + row[x + 2]) + row[x + 3]
                    out[X] = a
                continue
            if r == 0:
                for X in range(w):
                    x = 4 * X
                    acc[X] = ((row[x] + row[x + 1]) + row[x + 2]) + row[x + 3]
            else:
                for X in range(w):
                    x = 4 * X
                    acc[X] += ((row[x] + row[x + 1]) + row[x + 2]) + row[x + 3]
            if y % step == 0:
                out = sub[y // step]
                for j in range(len(out)):
                    out[j] = row[j * step]
        for X in range(w):
            small[Y, X] = acc[X] * sixteenth


@njit(cache=True, error_model="numpy")
def _root(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True, error_model="numpy")
def label_boxes(img, thr, boxes):
    r"""The 8-connected components of img < thr in each box, as the box labelled alone by
cv2.connectedComponents gives them, those wholly inside their box (a box side on the
image border counts as inside): (comps, pixels)

comps (m,8) int64, box by box, in cv2's label order within the box: box index, x, y,
w, h (the component's bounding box in the image), area, and the sums of the pixels'
x and y relative to the box's corner (exact integers); pixels (bool, flat): each
component's pixels over its bounding box, row by row, one after the other.

thr is of img's type (numpy compares a float32 image with a float threshold in
float32). Row runs of dark pixels are joined (union-find) where they touch across
rows, 8-connected. cv2 labels 2x2 blocks in raster order from the box's corner (the
blocks of a component are 8-connected, so each block belongs to one component) and
numbers components in the order of their first block: here each component's first
block (y // 2, x // 2 in the box) orders them."""
    H, W = img.shape
    nb = len(boxes)
    comps = np.zeros((0, 8), np.int64)
    out = []
    npix = 0
    # the runs [rs, re) of row ry, row by row: at most (w + 1) // 2 a row
    cap = 1
    for ib in range(nb):
        cap = max(cap, (boxes[ib, 3] - boxes[ib, 1]) * ((boxes[ib, 2] - boxes[ib, 0] + 1) // 2))
    rs = np.empty(cap, np.int64)
    re = np.empty(cap, np.int64)
    ry = np.empty(cap, np.int64)
    for ib in range(nb):
        xa, ya, xb, yb = boxes[ib, 0], boxes[ib, 1], boxes[ib, 2], boxes[ib, 3]
        h, w = yb - ya, xb - xa
        row0 = np.empty(h + 1, np.int64)
        n = 0
        for y in range(h):
            row0[y] = n
            if y + PREFETCH_ROWS < h:
                _prefetch_row(img, ya + y + PREFETCH_ROWS, xa, xb)
            x = 0
            while x < w:
                if not img[ya + y, xa + x] < thr:
                    x += 1
                    continue
                rs[n] = x
                while x < w and img[ya + y, xa + x] < thr:
                    x += 1
                re[n], ry[n] = x, y
                n += 1
        row0[h] = n
        parent = np.arange(n)
        for y in range(1, h):
            i, j = row0[y - 1], row0[y]
            while i < row0[y] and j < row0[y + 1]:
                # 8-connected: [rs_i - 1, re_i + 1) meets [rs_j, re_j)
                if rs[i] <= re[j] and rs[j] <= re[i]:
                    a, b = _root(parent, i), _root(parent, j)
                    if a < b:
                        parent[b] = a
                    elif b < a:
                        parent[a] = b
                if re[i] < re[j]:
                    i += 1
                else:
                    j += 1
        # per root: first block, box, area, sums
        nbx = w // 2 + 1
        first = np.full(n, np.iinfo(np.int64).max)
        x0 = np.full(n, w)
        y0 = np.full(n, h)
        x1 = np.full(n, -1)
        y1 = np.full(n, -1)
        area = np.zeros(n, np.int64)
        sx = np.zeros(n, np.int64)
        sy = np.zeros(n, np.int64)
        for k in range(n):
            r = _root(parent, k)
            parent[k] = r
            first[r] = min(first[r], (ry[k] // 2) * nbx + rs[k] // 2)
            x0[r] = min(x0[r], rs[k])
            x1[r] = max(x1[r], re[k])
            y0[r] = min(y0[r], ry[k])
            y1[r] = max(y1[r], ry[k] + 1)
            L = re[k] - rs[k]
            area[r] += L
            sx[r] += (rs[k] + re[k] - 1) * L // 2
            sy[r] += ry[k] * L
        roots = np.empty(n, np.int64)
        m = 0
        for k in range(n):
            if parent[k] == k:
                # insertion by first block (few components a box)
                t = m
                while t > 0 and first[roots[t - 1]] > first[k]:
                    roots[t] = roots[t - 1]
                    t -= 1
                roots[t] = k
                m += 1
        slot = np.full(n, -1)
        kept = []
        for t in range(m):
            r = roots[t]
            if not ((x0[r] > 0 or xa == 0) and (y0[r] > 0 or ya == 0)
                    and (x1[r] < w or xb == W) and (y1[r] < h or yb == H)):
                continue
            slot[r] = len(out)
            out.append(np.zeros((y1[r] - y0[r], x1[r] - x0[r]), np.bool_))
            kept.append(r)
        for k in range(n):
            r = parent[k]
            if slot[r] >= 0:
                out[slot[r]][ry[k] - y0[r], rs[k] - x0[r]:re[k] - x0[r]] = True
        rows = np.empty((len(kept), 8), np.int64)
        for t in range(len(kept)):
            r = kept[t]
            cw, ch = x1[r] - x0[r], y1[r] - y0[r]
            npix += ch * cw
            rows[t, 0], rows[t, 1], rows[t, 2], rows[t, 3] = ib, xa + x0[r], ya + y0[r], cw
            rows[t, 4], rows[t, 5], rows[t, 6], rows[t, 7] = ch, area[r], sx[r], sy[r]
        comps = np.concatenate((comps, rows))
    pixels = np.empty(npix, np.bool_)
    k = 0
    for mask in out:
        pixels[k:k + mask.size] = mask.ravel()
        k += mask.size
    return comps, pixels


def compiled_entry_points():
    r'''The compiled kernels of this module that Python calls (numba dispatchers), for a
warm-up's check of numba's cache (harness.warmup). Not dilations(): the detector no
longer calls it (dot_centroid takes the dilations row by row from the mask's runs); it
stays as the tests' statement of the dilations cv2.dilate gives, and a kernel listed here
that no job calls would never be cached, so every warm-up would render again. Nor
reduce4_and_subsample(): only images above detect_dots.LARGE_IMAGE_PIXELS call it, so a
campaign of smaller cameras never caches it; a change of this file makes the listed
kernels' caches stale too (numba stamps a cache with its source file), and the warm-up
detects the largest image of each target (harness.warmup._render_kinds), which compiles it.'''
    return (dot_centroid, mark_flags, histogram_counts, label_boxes, grow_lattice)

r'''Clipped pixels and column bleed (CCD blooming) of a detected image

SYNOPSIS

    from targets.saturation import measure, summarise, sentence

    m = measure(image)        # one image (targets.detect stores it in det.info["saturation"])
    m["fraction"]             # of the light pixels, those at full scale (0.0: none)
    m["bleed_px"]             # the longest isolated jump of a column's clipped run's end, px
    s = summarise([m, ...])   # a job's images: the record's detections["saturation"]
    s["blooming"]             # True: the clipped charge runs along the columns
    sentence(s)               # "the images are saturated (...): the detector's positions ..."

A CCD whose wells overflow (renderers.response Saturation, blooming = true) spills the
excess charge along its columns into the nearest pixels with room: the clipped runs of a
column grow at both ends, each by about half its run's excess. Dots next to long runs
lose their edge pixels to it and move along the columns (0.3-0.6 px for a 15%
overexposed board, benchmarks/bench_photometric.py), as on a real sensor: a true bias of
the images, not a renderer geometry fault. A plain clip (blooming = false) moves nothing
that matters (the dots keep their dark pixels) and must not be read as blooming.

Everything is read from the image:

- full scale: 1.0 of targets.detection.as_float_image's range (the top code of an integer
  image, a float image's 1.0), or the image's maximum where a float image exceeds 1. A
  pixel is clipped when it lies within FULL_SCALE_TOL of it. An image whose maximum is
  below full scale has none (a clean render's white board at 0.9 is not "saturated").
- the light pixels: above the midpoint of the image's minimum and maximum (the board);
  fraction = clipped / light.
- the feature size: the median length of the columns' dark runs that lie between light
  pixels (a dot's height, a tag's cell); the ends of clipped runs in neighbouring columns
  are paired within it.
- bleed: the end of a column's clipped run (either end) that jumps by JUMP_MIN px or more
  from the paired end of the next column, where the jumps on either side do not continue
  it (not a steep edge's staircase, not a curve's turn: a lone step or a finger). A
  boundary sampled on pixels ends within a pixel of its edge in every column, so a smooth
  boundary gives lone jumps of at most 2 px: none of 3 px or more in the clipped renders
  of tests/test_saturation.py (the barrel CAHVOR, a 640x480 pinhole). Not none everywhere:
  MER hazcam 8's 6 clipped fisheye renders (bench_photometric `saturation`) have 4 along
  the columns and 24 along the rows, so the same count along the rows is the image's own
  control: blooming moves charge along the columns only. A lone jump pairs only ends
  joined by clipped pixels (the longer run covers the step).

summarise() sums a job's counts: blooming when the column jumps exceed the row jumps by
more than BLEED_Z x the standard deviation of that difference (sqrt(columns + rows), both
counts Poisson under the null of no direction), with some pixels at full scale.
'''

import math

import numpy as np

# a pixel within this of full scale is clipped (float32 rounding of 1.0 is 6e-8)
FULL_SCALE_TOL = 1e-6
# a lone jump of a clipped run's end this long or longer is not pixel sampling of an edge
JUMP_MIN = 3
# column jumps beyond the rows' by this many standard deviations: bleed along columns
BLEED_Z = 3.0


def _dark_run_median(D, L):
    r'''Median length of the column runs of D that have L pixels at both ends (0: none)'''
    H = D.shape[0]
    P = np.zeros((D.shape[1], H + 2), np.int8)     # column-major, padded: runs pair up
    P[:, 1:-1] = D.T
    d = np.diff(P, axis=1)
    x, y = np.nonzero(d)
    first = d[x, y] == 1
    sx, sy = x[first], y[first]         # first dark row of each run
    ey = y[~first]                      # one past its last
    inside = (sy > 0) & (ey < H)
    sx, sy, ey = sx[inside], sy[inside], ey[inside]
    bounded = L[sy - 1, sx] & L[ey, sx]
    lengths = (ey - sy)[bounded]
    return int(np.median(lengths)) if len(lengths) else 0


def _runs(A):
    r'''The runs of True along each line (row) of A: (line, first, last) int arrays, in
order along each line'''
    n, m = A.shape
    P = np.zeros((n, m + 2), np.int8)
    P[:, 1:-1] = A
    d = np.diff(P, axis=1)
    line, pos = np.nonzero(d)           # a run's first pixel (+1), one past its last (-1)
    first = d[line, pos] == 1
    return line[first], pos[first], pos[~first] - 1


def _lone(line, y, other, length, window, bottom):
    r'''The lone jumps of the run ends (line, y) (bottom ends: y the last pixel of each run,
other its first; top ends: y the first, other the last), each paired with the nearest
end of the next line within window, joined by the runs'''
    none = np.iinfo(np.int64).min
    keep = (y < length - 1) if bottom else (y > 0)     # the image's edge is no end
    line, y, other = line[keep], y[keep], other[keep]
    n = len(y)
    if n == 0:
        return np.zeros(0, np.int64)
    order = np.lexsort((y, line))
    line, y, other = line[order], y[order], other[order]
    key = line.astype(np.int64) * length + y

    def pair(side):
        c = line + side
        k = np.searchsorted(key, c.astype(np.int64) * length + y)
        best = np.full(n, -1, np.int64)
        dist = np.full(n, window + 1, np.int64)
        for kk in (k - 1, k):
            kc = np.clip(kk, 0, n - 1)
            d = np.abs(y[kc] - y)
            take = (kk >= 0) & (kk < n) & (line[kc] == c) & (d < dist)
            best = np.where(take, kc, best)
            dist = np.where(take, d, dist)
        b = np.maximum(best, 0)
        # joined: the run of the end that reaches further covers the other end's row
        deeper = (y[b] > y) if bottom else (y[b] < y)
        joined = np.where(deeper, (other[b] <= y) if bottom else (other[b] >= y),
                          (other <= y[b]) if bottom else (other >= y[b]))
        return np.where((best >= 0) & joined, best, -1)

    nxt, prv = pair(1), pair(-1)
    has = nxt >= 0
    safe = np.maximum(nxt, 0)
    J = np.where(has, y[safe] - y, 0)
    before = np.where(prv >= 0, y - y[np.maximum(prv, 0)], none)
    after = np.where(has & (nxt[safe] >= 0), y[np.maximum(nxt[safe], 0)] - y[safe], none)

    def quiet(o):       # a neighbouring jump that does not carry J's step on
        return (o != none) & ~((np.sign(o) == np.sign(J)) & (2 * np.abs(o) > np.abs(J)))
    lone = has & (np.abs(J) >= JUMP_MIN) & quiet(before) & quiet(after)
    return np.abs(J[lone])


def lone_jumps(lines, window):
    r'''(N,) int: the lone jumps (px, >= JUMP_MIN) of the ends of the runs along the rows
of `lines` (bool; S.T for the columns of the clipped pixels S)

Each run's last pixel (and its first) is paired with the nearest end of the same kind on
the next line within `window`, where the runs join them (the longer run covers the
step). A jump J between the two is lone where neither the jump into the first end nor
the one out of the second is of J's sign and more than half its size.'''
    line, first, last = _runs(lines)
    n = lines.shape[1]
    return np.concatenate([_lone(line, last, first, n, window, True),
                           _lone(line, first, last, n, window, False)])


def measure(image):
    r'''{"full_scale", "fraction", "clipped", "light", and where any pixel is clipped
"feature_px", "column_jumps", "row_jumps", "bleed_px"} of one image (JSON-able)

image: (H,W) as the detectors take it (targets.detection.as_float_image).'''
    from .detection import as_float_image
    a = np.asarray(image)
    img = as_float_image(a, dtype=np.float64 if a.dtype == np.float64 else np.float32)
    hi = float(np.max(img))     # one pass: most images end here (nothing at full scale)
    fs = 1.0 if hi <= 1.0 + FULL_SCALE_TOL else hi
    out = {"full_scale": fs, "fraction": 0.0, "clipped": 0, "light": 0}
    if not math.isfinite(hi) or hi < fs - FULL_SCALE_TOL:
        return out
    lo = float(np.min(img))
    if not math.isfinite(lo) or hi <= lo:
        return out
    L = img > 0.5 * (lo + hi)
    # the light pixels' box and a pixel around it: all the ends lie in it
    rows, cols = np.nonzero(L.any(axis=1))[0], np.nonzero(L.any(axis=0))[0]
    r0, r1 = max(rows[0] - 1, 0), min(rows[-1] + 2, L.shape[0])
    c0, c1 = max(cols[0] - 1, 0), min(cols[-1] + 2, L.shape[1])
    img, L = img[r0:r1, c0:c1], L[r0:r1, c0:c1]
    S = img >= fs - FULL_SCALE_TOL
    n_light, n_clipped = int(L.sum()), int(S.sum())
    out.update(clipped=n_clipped, light=n_light,
               fraction=n_clipped / n_light if n_light else 0.0)
    St = np.ascontiguousarray(S.T)
    feature = _dark_run_median(~L, L)
    window = max(feature, JUMP_MIN)
    cols = lone_jumps(St, window)
    rows = lone_jumps(S, window)
    out.update(feature_px=feature, column_jumps=int(len(cols)), row_jumps=int(len(rows)),
               bleed_px=int(cols.max()) if len(cols) else 0)
    return out


def summarise(per_image):
    r'''A job's images' measures (each measure()'s, or None) -> the record's summary

{"fraction", "bleed_px", "column_jumps", "row_jumps", "blooming", "per_pose"}: the
clipped fraction of all the light pixels, the longest bleed, the summed counts;
blooming: column jumps beyond the rows' by more than BLEED_Z sigma, some pixels clipped.
None when no image has a pixel at full scale.'''
    ms = [m or {} for m in per_image]
    if not any(m.get("clipped") for m in ms):
        return None
    clipped = sum(m.get("clipped", 0) for m in ms)
    light = sum(m.get("light", 0) for m in ms)
    c = sum(m.get("column_jumps", 0) for m in ms)
    r = sum(m.get("row_jumps", 0) for m in ms)
    return {"fraction": clipped / light if light else 0.0,
            "bleed_px": max((m.get("bleed_px", 0) for m in ms), default=0),
            "column_jumps": c, "row_jumps": r,
            "blooming": bool(c - r > BLEED_Z * math.sqrt(c + r)),
            "per_pose": [{k: m[k] for k in ("fraction", "clipped", "light", "column_jumps",
                                            "row_jumps", "bleed_px") if k in m} for m in ms]}


def subset(summary, n):
    r'''The summary of the first n images (a calibrator fitting the first n poses)'''
    if not summary or n is None or n >= len(summary.get("per_pose", ())):
        return summary
    return summarise(summary["per_pose"][:n])


def sentence(summary):
    r'''Why a blooming job's records move, in words; "" when the summary is not blooming'''
    if not summary or not summary.get("blooming"):
        return ""
    return (f"the images are saturated ({100 * summary['fraction']:.0f}% of the board at full "
            f"scale, bleed along columns up to {summary['bleed_px']} px): the detector's "
            f"positions move with the blooming, not the renderer's geometry")

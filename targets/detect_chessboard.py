r'''Find the inner corners of a chessboard with OpenCV, numbered with the orientation mark

SYNOPSIS

    from targets.detect_chessboard import detect_chessboard

    det = detect_chessboard(image, target)   # targets.detection.Detection
    det.q                                    # (nx*ny,2): corner iy*nx + ix

OpenCV's findChessboardCorners (quad-based, a few ms) finds the nx x ny inner
corners (if it fails, findChessboardCornersSB, sector-based: ten times slower,
searched at reduced size on large images); cornerSubPix then polishes them
(about 0.2 px RMS -> 0.1 px on distorted, tilted boards), and
targets.corners.refine_chessboard_corners fits the exact area-sampled image of
the four square edges at each corner (0.06-0.1 px -> 0.002-0.01 px RMS on exact
K=16 ray-cast renders, whose own sampling error that is; see
benchmarks/bench_corners.py). A corner the fit cannot refine, or whose
image is no chessboard saddle, is dropped (info["corners_dropped"]: {reason:
count}), never kept at OpenCV's position; the detection keeps the others and
is "ok" with at least MIN_POINTS_FOR_POSE corners not all on one line (what
a view's pose needs; min_found). OpenCV numbers the
corners in one of the 8 rotations/flips of the grid (any of them for a square
grid). The numbering is fixed by the squares: for
each candidate numbering, every interior square's centre (the crossing of its
corners' diagonals) is sampled in the image and compared with what the target
has there - dark, light, or a dark square with a light orientation dot. The
numbering that explains all squares wins; it must beat the next best by at
least two squares, else the result is "failed" (ambiguous).

Blurred images (a response profile's PSF): the corner windows' quick look at the blur
(targets.corners.refine_corners, stop_if_blurred: one kernel kind on 8 corners) stops
the window fit, and the corners are fitted with the sampled kernel at the look's
variance (x_junction_blur: an X junction's corner hardly depends on the kernel's kind),
a blurred first pass with the exact Jacobian, then the second: 0.06 s CPU per 1024x1024
image against 0.18 s with the two-kind estimate on 32 corners after a sharp first pass
of every corner (docs/corners.md, "Blurred chessboard detection time").

OpenCV's pixel convention is camval's (pixel centres at integers).
'''

import dataclasses

import numpy as np

from .detection import (
    CORNER_LINES,
    MIN_POINTS_FOR_POSE,
    failed,
    result,
    working_image,
)

DETECTOR = "chessboard"
# images larger than twice this (smaller side) are searched at a reduced size first
SEARCH_SIZE_PX = 400
# OpenCV's quad-based search (findChessboardCorners)
CLASSIC_FLAGS = 3     # cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE (1 | 2)
# the quad-based search again without CALIB_CB_NORMALIZE_IMAGE, where it found no board:
# cv2.CALIB_CB_ADAPTIVE_THRESH only. The equalisation maps each grey level to its rank among
# the pixels: on a board that covers a minority of the image (a foreshortened board near a
# fisheye's rim, the rest dark background) it lifts the dark squares (26 -> 81 of 255 on
# the view below) and spreads the blurred edges' and the noise's few grey levels over tens,
# and the adaptive threshold no longer separates the small squares. Constructed
# eye-1024x768.cahvore (CAHVORE), pose seed 0's second pose under the realistic profile's
# PSF (sigma 0.7 px): lost with the PSF alone, and with 6 of 8 noise draws; found by every
# one of them on the image as it is (tests/test_chessboard_blur.py). 2-15 ms, only where
# the first search failed; what it finds is checked as the first search's (squares, saddles).
CLASSIC_PLAIN_FLAGS = 1   # cv2.CALIB_CB_ADAPTIVE_THRESH
CLASSIC_PLAIN = "findChessboardCorners without equalisation"
CLASSIC_METHODS = ("findChessboardCorners", CLASSIC_PLAIN)
# the sector-based search (findChessboardCornersSB, each size) again without
# CALIB_CB_NORMALIZE_IMAGE where it found no board, for the same reason: a foreshortened board
# at the edge of a wide rectilinear view (the CAHV of random camera rnd22-6-506x506, a 151 deg
# fisheye: 121 deg as a pinhole), squares 8-36 px on a dark image, is found by neither
# quad-based search nor by the sector-based one with equalisation, and by the sector-based
# one without it (campaigns/cameras/wide-cahv-506x506.cahv; tests/test_chessboard_wide.py).
# Only where every other search failed; a failed search's name in the reason stays
# "findChessboardCornersSB" (it covers both).
SB_PLAIN_SUFFIX = " without equalisation"
# the reason of a corner dropped because the image around it is no chessboard saddle
NOT_SADDLE = "not a saddle"
# how far along the diagonals (in grid steps) a corner's saddle is checked
SADDLE_PROBE = 0.15
# x_junction_blur's match of the sampled kernel's added blur to an estimate's (px): far
# below the estimate's own scatter (~1e-3 px), and at most this many secant steps
X_BLUR_TOLERANCE_PX = 1e-6
X_BLUR_SECANT_STEPS = 20
ALL_TRANSFORMS = [(swap, fa, fb) for swap in (False, True) for fa in (False, True)
                  for fb in (False, True)]


def _bilinear(img, q):
    H, W = img.shape
    x = np.clip(q[..., 0], 0, W - 1.001)
    y = np.clip(q[..., 1], 0, H - 1.001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    return ((1 - fx) * (1 - fy) * img[y0, x0] + fx * (1 - fy) * img[y0, x0 + 1]
            + (1 - fx) * fy * img[y0 + 1, x0] + fx * fy * img[y0 + 1, x0 + 1])


def _square_centres(G):
    r'''G (ny,nx,2) corner grid -> (ny-1,nx-1,2) centres of the squares between corners'''
    p00, p11 = G[:-1, :-1], G[1:, 1:]
    p10, p01 = G[:-1, 1:], G[1:, :-1]
    # crossing of the diagonals p00-p11 and p10-p01 (the perspective centre)
    d1, d2 = p11 - p00, p01 - p10
    r = p10 - p00
    den = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (r[..., 0] * d2[..., 1] - r[..., 1] * d2[..., 0]) / den
    c = p00 + s[..., None] * d1
    bad = ~np.isfinite(c).all(axis=-1)
    c[bad] = (0.25 * (p00 + p11 + p10 + p01))[bad]
    return c


def _is_saddle(img, G, contrast=None):
    r'''(ny,nx) bool: the image around each corner is a chessboard saddle

Four samples at SADDLE_PROBE of the local grid steps along the diagonals: the two on one
diagonal must be alike, and differ from the two on the other by at least a
third of the image's contrast. A corner that a detector misplaced onto a plain
square (or an edge) fails.'''
    u = np.gradient(G, axis=1)
    v = np.gradient(G, axis=0)
    r = SADDLE_PROBE
    a = _bilinear(img, G + r * (u + v)) + _bilinear(img, G - r * (u + v))
    b = _bilinear(img, G + r * (u - v)) + _bilinear(img, G - r * (u - v))
    if contrast is None:
        contrast = float(img.max() - img.min())
    return np.abs(a - b) / 2 > contrast / 3


def x_junction_blur(sigma, kind):
    r'''The sigma of the "sampled" blur kernel (targets.corners.blur_kernel) that adds the
variance of (sigma, kind) to the pixel's own area

Why. A chessboard corner is an X junction: two straight edges crossing, its dark region
point-symmetric about the corner, and so is its image under any point-symmetric blur. A
model blurred by a point-symmetric kernel of another shape or width misfits every pixel
pair (c + u, c - u) alike, where the corner's derivative is opposite: to first order the
fitted corner does not move (tests/test_chessboard_blur.py measures it), unlike an
AprilTag's L-shaped corner, which a wrong kernel moves into its dark wedge. So the X
junctions need no choice of kernel kind (two blurred fits of 32 corners, ~0.04 s per
1024x1024 image) and take the kind whose taps at whole-pixel offsets share the sharp
pixels (targets._corner_kernels, ~2.5x cheaper than the Gaussian kind's 25 offsets) at
the blur's variance: added_blur_px of the taps matched by secant steps (the taps' variance
is sigma^2 + 1/12 above sigma ~0.5 px, less below, where the pixel's own width dominates).
'''
    from .corners import added_blur_px
    want = added_blur_px(sigma, kind)
    # secant steps on the taps' added blur, monotone in sigma, from the large-sigma formula
    s0 = float(np.sqrt(max(want * want - 1.0 / 12.0, 0.0))) + 0.05
    s1 = s0 + 0.05
    f0, f1 = added_blur_px(s0, "sampled") - want, added_blur_px(s1, "sampled") - want
    for _ in range(X_BLUR_SECANT_STEPS):
        if abs(f1) < X_BLUR_TOLERANCE_PX or f1 == f0:
            break
        s0, s1 = s1, max(s1 - f1 * (s1 - s0) / (f1 - f0), 1e-3)
        f0, f1 = f1, added_blur_px(s1, "sampled") - want
    return s1


def _expected_squares(target):
    r'''(ny-1, nx-1) expected brightness class of interior squares: 0 dark, 1 light'''
    nx, ny = target.grid_shape
    sy, sx = np.mgrid[1:ny, 1:nx]
    light = ((sx + sy) % 2 == 1).astype(int)
    mark = target.spec.get("orientation_mark")
    if mark is not None:
        for px, py in mark["squares"]:
            light[py - 1, px - 1] = 1
    return light


def _find_sb(cv2, img8, size, flags_sb, fast=True):
    r'''findChessboardCornersSB without CALIB_CB_ACCURACY first (4x faster: 0.04-0.06 s
instead of 0.16-0.22 s on 512x512, benchmarks/bench_corners.py images; its sub-pixel
polish is redone below by cornerSubPix and the corner model), then with it where that
finds no board (1 of 18 images of MER hazcam 8, camera 17, navcam 15). fast=False (the
corners are used as OpenCV finds them, refine=False): with it only. Where neither finds a
board, the same again without CALIB_CB_NORMALIZE_IMAGE (SB_PLAIN): the equalisation defeats
the sector-based search as it does the quad-based one (CLASSIC_PLAIN_FLAGS). -> (found,
corners, the search's name suffix: "" or SB_PLAIN_SUFFIX)'''
    for flags, suffix in ((flags_sb, ""),
                          (flags_sb & ~cv2.CALIB_CB_NORMALIZE_IMAGE, SB_PLAIN_SUFFIX)):
        if suffix and flags == flags_sb:
            break
        ok = False
        if fast:
            ok, corners = cv2.findChessboardCornersSB(img8, size,
                                                      flags=flags & ~cv2.CALIB_CB_ACCURACY)
        if not ok:
            ok, corners = cv2.findChessboardCornersSB(img8, size, flags=flags)
        if ok:
            return ok, corners, suffix
    return False, None, ""


def detect_chessboard(image, target, *, min_found=MIN_POINTS_FOR_POSE, refine=True,
                      reduced_search=True, classic_first=True, psf_sigma_px=None):
    r'''Detect a chessboard; see the module docstring

SYNOPSIS

    det = detect_chessboard(image, target)

ARGUMENTS

- image: (H,W) float in [0,1], or uint8/uint16 (OpenCV gets 8 bits)
- target: a "chessboard" targets.boards.Target
- min_found: fewest corners for status "ok" (default: what a view's pose needs,
  targets.detection.MIN_POINTS_FOR_POSE; the corners kept must not lie on one line)
- refine: True: polish the corners with cv2.cornerSubPix, then fit the corner model
  (targets.corners); "subpix": cornerSubPix only; False: OpenCV's corners as found
- psf_sigma_px: the image's Gaussian blur (px) for the corner model when known (e.g. a
  campaign's response profile; fitted as the sampled kernel of its variance,
  x_junction_blur); None (default): estimated from the image
  (targets.corners.estimate_blur); info["psf_sigma_px"] has the sampled kernel's sigma
  used, as det.corner_blur_px (the blurred corners' bias depends on it)
- reduced_search: on large images, search at reduced size first (falls back to full
  size when a corner wanders off its refinement window)
- classic_first: with refine, try OpenCV's findChessboardCorners (quad-based) before the
  sector-based search: 1.5-5 ms of CPU against 25-70 ms on 1024x1024 renders, and it found
  every board of the 18 images of benchmarks/bench_corners.py (cameras 15, 17, 8) where
  the reduced-size sector search missed 1; a board it misses, whose squares it cannot
  number, or whose corners fail the saddle check, goes to the sector-based search
'''
    import cv2

    if target.kind != "chessboard":
        return failed(target, f"detect_chessboard() needs a chessboard target; got "
                      f"{target.kind!r}", DETECTOR)
    work = working_image(image)
    if work is None:
        return failed(target, "the image has non-finite pixels", DETECTOR)
    img, img8, (lo, hi) = work
    nx, ny = target.grid_shape
    info = {}
    flags_sb = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    ok, corners = False, None
    tried = []   # the searches that found no board, for the failure's reason
    if refine and classic_first:
        ok, corners = cv2.findChessboardCorners(img8, (nx, ny), flags=CLASSIC_FLAGS)
        info["method"] = "findChessboardCorners"
        if not ok:
            # without the histogram equalisation (CLASSIC_PLAIN_FLAGS)
            tried.append(info["method"])
            ok, corners = cv2.findChessboardCorners(img8, (nx, ny), flags=CLASSIC_PLAIN_FLAGS)
            info["method"] = CLASSIC_PLAIN
            tried += [] if ok else [CLASSIC_PLAIN]
    # the sector-based detector costs ~1.3 s on 1024x1024 (0.2 s without its ACCURACY
    # polish, _find_sb): find the board on a reduced
    # image first (the corners are polished at full resolution below)
    shrink = int(min(img8.shape) // SEARCH_SIZE_PX)
    if not ok and shrink >= 2 and refine and reduced_search:
        small = cv2.resize(img8, (img8.shape[1] // shrink, img8.shape[0] // shrink),
                           interpolation=cv2.INTER_AREA)
        ok, corners, suffix = _find_sb(cv2, small, (nx, ny), flags_sb)
        if ok:
            # INTER_AREA: small pixel i covers full pixels [i*s, (i+1)*s)
            corners = (np.asarray(corners, dtype=np.float64) + 0.5) * shrink - 0.5
            info["method"] = f"findChessboardCornersSB at 1/{shrink} size{suffix}"
        else:
            tried.append(f"findChessboardCornersSB at 1/{shrink} size")
    if not ok:
        ok, corners, suffix = _find_sb(cv2, img8, (nx, ny), flags_sb, fast=bool(refine))
        info["method"] = "findChessboardCornersSB" + suffix
        tried += [] if ok else ["findChessboardCornersSB"]
    if not ok and not (refine and classic_first):
        ok, corners = cv2.findChessboardCorners(img8, (nx, ny), flags=CLASSIC_FLAGS)
        info["method"] = "findChessboardCorners"
        tried += [] if ok else [info["method"]]
    if not ok or corners is None:
        info["searches"] = tried
        return failed(target, f"OpenCV found no {nx}x{ny} chessboard ({', '.join(tried)})",
                      DETECTOR, info)
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    # OpenCV's order: rows of nx; lattice a along a row, b across rows
    G_cv = c.reshape(ny, nx, 2)
    expected = _expected_squares(target)
    mid = 0.5 * (hi + lo)
    scores = []
    for t in ALL_TRANSFORMS:
        swap, fa, fb = t
        G = G_cv
        if fa:
            G = G[:, ::-1]
        if fb:
            G = G[::-1]
        if swap:
            G = G.transpose(1, 0, 2)
        if G.shape[:2] != (ny, nx):
            continue
        seen = (_bilinear(img, _square_centres(G)) > mid).astype(int)
        scores.append((int((seen != expected).sum()), t, G))
    scores.sort(key=lambda s: s[0])
    info["square_mismatches"] = [s[0] for s in scores]
    best = scores[0]
    ambiguous = len(scores) > 1 and scores[1][0] - best[0] < 2
    if (ambiguous or best[0] > max(2, expected.size // 20)) and \
            info["method"] in CLASSIC_METHODS and refine and classic_first:
        # the quad-based search's grid does not explain the squares: the sector-based one
        return detect_chessboard(image, target, min_found=min_found, refine=refine,
                                 reduced_search=reduced_search, classic_first=False,
                                 psf_sigma_px=psf_sigma_px)
    if ambiguous:
        return failed(target, f"the chessboard's orientation is ambiguous (square mismatches "
                      f"{[s[0] for s in scores]}); is the orientation mark visible?",
                      DETECTOR, info)
    if best[0] > max(2, expected.size // 20):
        return failed(target, f"the chessboard's squares do not match the target "
                      f"({best[0]} of {expected.size} interior squares differ)", DETECTOR, info)
    info["transform"] = list(best[1])
    G = best[2]
    if refine:
        # the corners found at reduced size can be several px off at full size: polish
        # coarse to fine, the first window wide (a quarter square: clear of the mark dots)
        # and the last one well inside the smallest square (~0.1 px on distorted boards)
        step = min(np.linalg.norm(np.diff(G, axis=0), axis=-1).min(),
                   np.linalg.norm(np.diff(G, axis=1), axis=-1).min())
        wins = [int(np.clip(0.25 * step, 2, 40)), int(np.clip(0.2 * step, 2, 10))]
        info["subpix_windows_px"] = wins
        img32 = img if img.dtype == np.float32 else img.astype(np.float32)
        G = G.reshape(-1, 1, 2).astype(np.float32)
        wandered = np.zeros(len(G), bool)
        for win in wins:
            G1 = cv2.cornerSubPix(
                img32, G.copy(), (win, win), (-1, -1),
                (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5))
            # a corner that left its window was pulled off by another edge (a mark dot
            # close to the corner on a foreshortened board): keep where it was
            bad = np.linalg.norm((G1 - G).reshape(-1, 2), axis=-1) > win
            wandered |= bad
            G = np.where(bad[:, None, None], G, G1)
        if wandered.any():
            info["unrefined_corners"] = int(wandered.sum())
    G = np.asarray(G, dtype=np.float64).reshape(ny, nx, 2)
    not_saddle = ~_is_saddle(img, G, hi - lo)
    if not_saddle.any():
        if info["method"] in CLASSIC_METHODS and refine and classic_first:
            # the quad-based search misplaced a corner: the sector-based search
            return detect_chessboard(image, target, min_found=min_found, refine=refine,
                                     reduced_search=reduced_search, classic_first=False,
                                 psf_sigma_px=psf_sigma_px)
        if info["method"].endswith("size"):
            # the reduced-size search was too coarse here: search at full size
            return detect_chessboard(image, target, min_found=min_found, refine=refine,
                                     reduced_search=False, classic_first=False,
                                     psf_sigma_px=psf_sigma_px)
        info["rejected_corners"] = int(not_saddle.sum())
        G[not_saddle] = np.nan
    dropped = {NOT_SADDLE: int(not_saddle.sum())} if not_saddle.any() else {}
    if refine is True:
        from .corners import chessboard_clearance, chessboard_half_box, refine_chessboard_corners
        window = dict(half_box=chessboard_half_box(target),
                      clearance=chessboard_clearance(target), value_range=hi - lo)
        given = {"psf_sigma_px": psf_sigma_px}
        if psf_sigma_px is not None and float(psf_sigma_px) > 0.0:
            # a given Gaussian blur: the X junctions take the sampled kernel of its variance
            # too, the one kernel their lines' bias knows (corner_blur_px)
            given = {"psf_sigma_px": x_junction_blur(float(psf_sigma_px), "gaussian"),
                     "psf_kind": "sampled"}
        fit = refine_chessboard_corners(img, G, stop_if_blurred=psf_sigma_px is None,
                                        **given, **window)
        if fit.info.get("stopped"):
            # blurred: the corner windows' look at the blur (or their full estimate) stopped
            # the fit; the X junctions are fitted with the sampled kernel of its variance
            look = fit.info
            sigma = x_junction_blur(look["psf_sigma_px"], look.get("psf_kind", "gaussian"))
            fit = refine_chessboard_corners(img, G, psf_sigma_px=sigma, psf_kind="sampled",
                                            **window)
            fit.info.update({"psf_source": f"{look.get('psf_source', 'estimated')} "
                             f"({look.get('psf_kind', 'gaussian')} "
                             f"{look['psf_sigma_px']:.4f} px), as the sampled kernel of its "
                             f"variance"})
            fit.info.update({k: v for k, v in look.items()
                             if k.startswith("psf_") and k not in fit.info})
        info.update({k: v for k, v in fit.info.items() if k.startswith("psf_")})
        # the refiner calls the corners rejected above "not detected"
        dropped.update({k: v for k, v in fit.dropped().items() if k != "not detected"})
        G = fit.q.reshape(ny, nx, 2)
    info["corners_dropped"] = dropped
    # blurred, the fit tied each pair of opposite rays into one line: its curvature bias is
    # the lines' under the sampled kernel it was fitted with
    # (harness.calibrators.bias.corner_bias(lines=True, blur_px)); sharp, None: the
    # window's (as every corner target's before CORNER_LINES)
    corner_model, blur = None, 0.0
    if refine is True and float(info.get("psf_sigma_px") or 0.0) > 0.0:
        corner_model, blur = CORNER_LINES, float(info["psf_sigma_px"])
    det = result(target, G.reshape(-1, 2), DETECTOR, min_found=min_found, info=info,
                 corner_model=corner_model, corner_blur_px=blur)
    if det.status != "ok" and dropped:
        # the board was found: say so, and why its corners went (a campaign record keeps
        # one image's reason; "found 0 of 100 points" alone reads as a board not found)
        det = dataclasses.replace(det, reason=(
            f"{det.reason}: the {nx}x{ny} chessboard was found ({info['method']}), but "
            f"{sum(dropped.values())} of its corners were dropped ({_counts(dropped)})"))
    return det


def _counts(dropped):
    r'''{reason: count} -> "count reason, ..." (largest first)'''
    return ", ".join(f"{n} {why}" for why, n in sorted(dropped.items(), key=lambda kv: -kv[1]))

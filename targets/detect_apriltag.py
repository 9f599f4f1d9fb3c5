r'''Find the tag corners of an AprilTag grid with pupil_apriltags

SYNOPSIS

    from targets.detect_apriltag import detect_apriltags

    det = detect_apriltags(image, target)   # targets.detection.Detection
    det.q                                   # (4*Ntags,2): point 4*tag_id + corner

Each decoded tag of the target's family whose id is on the board gives its 4
outer black-border corners, in pupil_apriltags' order (bottom-left,
bottom-right, top-right, top-left of the upright tag), which is the order of
the target's points. Tags with a Hamming distance above max_hamming, ids not
on the board, and ids seen twice are ignored (a duplicate id drops both).

A mirror-imaged camera (model.mirrored, e.g. behind a fold mirror) shows every
tag mirrored, which decodes as no tag at all; when no tag of the board decodes,
the flipped image is tried and the corners are flipped back (info["mirrored"]).

The quad search runs on the image decimated (decimate_for); with refine=True (camval
fits the corners on the full image) it is tried first TRIAL_DECIMATION_FACTOR times
coarser and kept when it missed no tag of the board (_search_complete: every tag decoded,
or tags big enough that one half their size would still be found): on 5120x3840 renders
0.013 s of CPU for pupil_apriltags instead of 0.030, the refined corners within 1.4e-6 px
of the finer search's (benchmarks/bench_corners.py --compare-q, cameras 1 and 21). A
1024x1024 image's trial is decimated by 2: on the realistic renders of cameras 15 and 8
every tag decoded there (tag bits 3.7-12 px), pupil_apriltags' CPU 9 ms instead of 39-50
on the near pose 0 (big tags: the undecimated quad search follows their long, noisy
borders) and 5-8 instead of 14-25 on the others, its corners as far from the truth (per
pose max 0.17-1.79 px decimated, 0.17-1.77 undecimated); where the trial misses a tag
(hazcam 17's 640x480 images, 3 of 6 poses) the finer search costs ~2 ms more. The refined
corners start from the trial's and move by noise only: on 18 realistic images each of
cameras 15, 8, blur-wide-1024, eye-1024x768 and fish-1280 (6 poses, 3 noise seeds) their
raw error RMS changed by at most 3e-5 px, no max grew (0.0140 -> 0.0138 and 0.0347 ->
0.0343 px, the rest equal); on the bench's own seeds one corner of eye-1024x768 pose 2
went 0.005 -> 0.025 px, its camera's mean squared error changing by less than its
standard error (benchmarks/bench_corners.py --compare-q; on the sharp area renders of
those cameras and 17 the RMS and max errors are unchanged to 1e-5 px, no corner moved
more than 0.0034 px). A blurred image's tag edges
start from the coarse search's corners too, their search grown with the decimation
(_refine_blurred's start error): a second, finer quad search cost a noisy realistic
5120x3840 image 0.035-0.089 s of pupil_apriltags' CPU; without it cameras 1, 2 and 21
(18 images) took 0.24-0.26 s median, 0.38-0.41 max instead of 0.31-0.32, 0.48, every
corner found as before, within 0.008 px of its place, the RMS errors within 1e-5 px.

Pixel convention: the AprilTag library puts the centre of pixel (0,0) at
(0.5, 0.5) (its corners came out +0.50 px in x and y against exact projections,
measured in tests/test_detect.py), camval at (0,0): corners are shifted by
APRILTAG_PIXEL_OFFSET.

refine=True (default) fits each corner with targets.corners.refine_tag_corners:
the exact area-sampled image of the two border edges meeting there, in a
window of 0.8 tag bit (0.06-1.06 px RMS -> 0.004-0.017 px on exact K=16
ray-cast renders of MER navcam and hazcam fisheyes, the renders' own sampling
error; 0.000013-0.004 px on the ray caster's exact area-coverage renders, where
what is left is the hazcams' edge curvature that corner_bias removes;
benchmarks/bench_corners.py). A corner the fit cannot refine (a tag bit
of a few px gives too small a window) is dropped, never kept at the coarse
position (info["corners_dropped"]: {reason: count}). On a blurred image (the blur
estimate of targets.corners finds one, e.g. the `realistic` response profile) the corners
come instead from the tags' whole border edges, each fitted with the edges of its board
line's neighbours, where two edges meet (targets.tag_edges: 0.003-0.008 px RMS against
0.014-0.03 for the corner windows on the quick cameras' realistic renders,
benchmarks/bench_corners.py --response realistic); det.corner_model says which model
gave each corner (targets.detection: CORNER_WINDOW or TAG_EDGES).
refine="subpix" is the older polish described next, kept for comparison.

The AprilTag corners come from straight-line fits to each tag edge
(refine_edges): under strong lens distortion the edges are curved and the
corners are biased by a fraction of a pixel; they are not subpixel-exact like
the dot centroids. cornerSubPix in a window inside the black border and its
light margin (refine, default; tags with bits of 8 px or more) removes most
of that: on a 1024x1024 fisheye hazcam (slot 5, pose 5, numpy reference
render) the corner errors went from 1.47 px max / 0.54 px RMS to 0.44 / 0.20.
'''

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np

from .detection import CORNER_WINDOW, failed, result, working_image

DETECTOR = "apriltag"
# AprilTag pixel coordinates minus camval's for the same point
APRILTAG_PIXEL_OFFSET = 0.5
# cornerSubPix helps big tags only: with tag bits under 8 px it made corners worse
# (0.09 -> 0.29 px RMS on 20-40 px tags), above it better (0.54 -> 0.2 px on 60-90 px tags)
MIN_REFINE_WINDOW = 4


def _destroy(detector):
    r'''Free a pupil_apriltags Detector's C objects: the detector first, then its families

pupil_apriltags' own Detector.__del__ (1.0.4.post11) frees the families first, and
apriltag_detector_destroy() then runs quick_decode_uninit() on each family, which
reads and zeroes fam->impl (offset 64 of the freed 72-byte apriltag_family_t): a write
after free (valgrind: "Invalid write of size 8 ... 64 bytes inside a block of size 72
free'd", tag36h11_destroy then quick_decode_uninit). Offset 64 of that block is the
next heap chunk's prev_size, so when the freed block is in a bin when the zero is
written (its tcache bin full, and any malloc of 1 KB or more in between, Python's own
in __del__ included, consolidating the fastbins), the heap is corrupt: a later free()
beside it aborts with glibc's "corrupted size vs. prev_size" (and when the block was
taken again in between, the stale fam->impl read segfaults instead). The cached
detectors are collected when the interpreter shuts down, so that later free() was one
run by exit() (llvmlite's LLVMContext destructor): the whole test suite aborted,
status 134, after every test had passed, in about 2 of 7 runs. Destroying the
detector first uninitialises live families; freeing them after is what the AprilTag
library expects (apriltag_detector_destroy frees neither).
Upstream: pupil-labs/apriltags pull request 65 (open) makes the same reordering, the
duckietown fork has it (lib-dt-apriltags pull request 26); pupil's issues 34 (a
segfault at exit in quick_decode_uninit) and 39 ("corrupted size vs. prev_size") are
this bug.'''
    ptr, detector.tag_detector_ptr = detector.tag_detector_ptr, None
    if ptr is None:
        return
    lib = detector.libc
    lib.apriltag_detector_destroy.restype = None
    lib.apriltag_detector_destroy(ptr)
    families, detector.tag_families = detector.tag_families, {}
    for name, family in families.items():
        destroy = getattr(lib, f"{name}_destroy")
        destroy.restype = None
        destroy(family)


@functools.cache
def _detector_class():
    r'''pupil_apriltags' Detector, freed in the right order (see _destroy)'''
    import ctypes

    from pupil_apriltags import Detector
    from pupil_apriltags.bindings import _ApriltagDetection, _ImageU8, _ZArray, zarray_get

    class OrderedDetector(Detector):
        # bound now: at interpreter shutdown this module's globals may be gone already
        def __del__(self, _destroy=_destroy):
            _destroy(self)

        def detect(self, img, quad_decimate=None):
            r'''[Tag]: pupil_apriltags' Detector.detect without its copy of the image, its
quad search decimated by quad_decimate (None: the detector's current decimation)

The decimation is the C detector's field, read by each search (apriltag_detector_detect):
setting it per call lets one detector, one tag family and one quick-decode table serve
every decimation; a Detector built per decimation cost 0.024 s of CPU each, once per
process (0.048 for the first, with pupil_apriltags' import), on the first image of each
new decimation (an image has a trial and a finer one, detect_apriltags).

The library's detect copies the uint8 image into a buffer of its own (image_u8_create:
a zeroed allocation, rows padded to 96 bytes), 0.011 s of CPU per 5120x3840 image of the
0.05 its search takes (load 9-13, 2 cores); the AprilTag library reads its input image
through the image's stride and never writes it, so it is handed the array's own rows
(the tags and corners are the same bit for bit, benchmarks/bench_corners.py
--compare-q). Only what detect_apriltags uses is kept of each detection.'''
            img = np.ascontiguousarray(img, dtype=np.uint8)
            if img.ndim != 2:
                raise ValueError(f"detect() needs a (H,W) uint8 image; got shape {img.shape}")
            c_img = _ImageU8(width=img.shape[1], height=img.shape[0], stride=img.shape[1],
                             buf=img.ctypes.data_as(ctypes.POINTER(ctypes.c_uint8)))
            if quad_decimate is not None:
                self.tag_detector_ptr.contents.quad_decimate = float(quad_decimate)
            lib = self.libc
            lib.apriltag_detector_detect.restype = ctypes.POINTER(_ZArray)
            found = lib.apriltag_detector_detect(self.tag_detector_ptr, ctypes.byref(c_img))
            tags = []
            try:
                det = ctypes.POINTER(_ApriltagDetection)()
                for i in range(found.contents.size):
                    zarray_get(found, i, ctypes.byref(det))
                    d = det.contents
                    tags.append(Tag(d.id, d.hamming,
                                    np.ctypeslib.as_array(d.p, shape=(4, 2)).copy()))
            finally:
                lib.apriltag_detections_destroy.restype = None
                lib.apriltag_detections_destroy(found)
            return tags

    return OrderedDetector


@dataclass(frozen=True, eq=False)
class Tag:
    r'''One decoded tag: its id, the bits corrected, its 4 corners (4,2) in the AprilTag
library's pixel convention (APRILTAG_PIXEL_OFFSET) and order'''
    tag_id: int
    hamming: int
    corners: np.ndarray


# the quad search runs on an image decimated by an integer while its smaller side stays at
# least this (px): a 1024x1024 camera decodes every tag of its planned poses undecimated, so
# a decimated image no smaller has tag bits no smaller than those
DECIMATED_MIN_SIDE_PX = 1024


def decimate_for(shape):
    r'''pupil_apriltags' quad_decimate for an image of this (H, W): the largest integer
keeping the smaller side >= DECIMATED_MIN_SIDE_PX (1 up to 2047 px). On 5120x3840
renders (camera 21, 3 poses) 3 found every corner, 0.11 s CPU per image instead of 0.31,
the refined corners within 8e-6 px of the undecimated search's.'''
    return max(1, int(min(shape[:2]) // DECIMATED_MIN_SIDE_PX))


# a tag whose bit spans fewer decimated px than this may be missed by the quad search:
# every tag decoded at >= 1.95 decimated px a bit, some lost at 1.1-1.47 (renders of the
# 1024x1024 camera 5 and the 640x480 hazcam 17, 6 poses each, decimations 1-6)
MIN_DECIMATED_BIT_PX = 2.0
# the quad search is tried first this many times coarser than decimate_for's
# (pupil_apriltags decodes and refines the edges at full resolution either way): on
# 5120x3840 renders (cameras 1 and 21, tag bits 17-40 px) decimation 6 found every tag,
# 27 ms of CPU against 44 at 3, the refined corners within 1.4e-6 px of decimation 3's;
# on 1024x1024 ones (cameras 15 and 8, realistic) 2 found every tag, 5-9 ms against 14-50
TRIAL_DECIMATION_FACTOR = 2


def _search_complete(tags, index, quad_decimate, max_hamming):
    r'''Whether a quad search decimated by quad_decimate missed no tag of the board: every
tag of the board decoded, or the smallest decoded tag of the board so large that a tag
half its size keeps MIN_DECIMATED_BIT_PX decimated px a bit (a tilted board's far tags,
a board partly out of view)'''
    board = {t.tag_id for t in tags if t.hamming <= max_hamming and 4 * t.tag_id in index}
    if len(board) * 4 == len(index):
        return True
    sides = [np.linalg.norm(t.corners - np.roll(t.corners, 1, axis=0), axis=-1).min()
             for t in tags if t.tag_id in board]
    return bool(sides) and min(sides) / 8.0 / quad_decimate >= 2.0 * MIN_DECIMATED_BIT_PX


# detectors live as long as the process: the option sets are few; the decimation is set
# per search (OrderedDetector.detect), so one detector serves them all
@functools.cache
def _detector(quad_sigma, refine_edges, decode_sharpening):
    return _detector_class()(families="tag36h11", nthreads=1, quad_sigma=quad_sigma,
                             refine_edges=refine_edges, decode_sharpening=decode_sharpening)


def _refine(img32, corners):
    r'''cornerSubPix on the 4 outer corners of one tag, each in a window of half a tag bit
(inside the black border, which is 1 bit wide, and the light margin outside it); a
corner whose half bit is under MIN_REFINE_WINDOW px, or that would move by more than
its window, keeps pupil_apriltags' position'''
    import cv2
    edge = np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=-1)
    # corner k joins the edges (k-1, k) and (k, k+1)
    side = np.minimum(edge, np.roll(edge, -1))
    out = corners.copy()
    for k in range(4):
        win = int(min(0.5 * side[k] / 8.0, 12))
        if win < MIN_REFINE_WINDOW:
            continue
        c = cv2.cornerSubPix(
            img32, corners[k].reshape(1, 1, 2).astype(np.float32), (win, win), (-1, -1),
            (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5)).reshape(2)
        if np.linalg.norm(c - corners[k]) < win:
            out[k] = c
    return out


def _refine_blurred(img, used, refined, blur, target, value_range, quad_decimate=1,
                    line_reference=None, defer_span_bias=True):
    r'''The corners of a blurred image from the tags' whole border edges
(targets.tag_edges), started from the window fit's corners where it kept them (the blur's
quick look's few) and from pupil_apriltags' elsewhere; the CornerFit, its info the blur's
and the edge model's'''
    from .boards import tag36h11_bits
    from .tag_edges import MAX_CORNER_SHIFT_PX, refine_tag_edges
    coarse = np.array([c for _, c in used])
    start = coarse if refined is None else np.where(np.isfinite(refined), refined, coarse)
    bits = np.array([tag36h11_bits(tag_id) for tag_id, _ in used])
    spec = target.spec
    bit = float(spec["tag_size"]) / 8.0
    gap_bits = min(8.0 * float(spec.get("tag_spacing", 0.3)),
                   float(spec.get("margin", np.inf)) / bit)
    # each tag's (column, row) on the board: its edges share board lines with its neighbours
    nx = int(spec["nx"])
    first = int(spec.get("first_id", 0))
    grid = np.array([((t - first) % nx, (t - first) // nx) for t, _ in used])
    # an estimated blur's kind is chosen again on the whole edges (tag_edges._choose_kind)
    # pupil_apriltags fits its quads on the image decimated by quad_decimate: its corners
    # err by up to ~1.5 decimated px (4.6 px on 5120x3840 fisheyes, decimated by 3)
    fit = refine_tag_edges(img, start, blur["psf_sigma_px"], blur.get("psf_kind", "gaussian"),
                           bits=bits, grid=grid, gap_bits=gap_bits, value_range=value_range,
                           choose_kind=blur.get("psf_source") == "estimated",
                           start_error_px=MAX_CORNER_SHIFT_PX * max(1.0, float(quad_decimate)),
                           line_reference=line_reference, defer_span_bias=defer_span_bias)
    fit.info.update({k: v for k, v in blur.items() if k.startswith("psf_") and k not in fit.info})
    return fit


def _search(img8, index, quad_decimate, quad_sigma, refine_edges, decode_sharpening):
    r'''(tags, mirrored): pupil_apriltags' tags of the 8-bit image, or of its mirror image
when no tag of the board (index: {point id: row}) decodes in it but some do there'''
    detector = _detector(float(quad_sigma), int(refine_edges), float(decode_sharpening))
    tags = detector.detect(img8, quad_decimate)
    if not any(4 * t.tag_id in index for t in tags):
        # a mirror-imaged camera shows every tag mirrored, which decodes as nothing: try
        # the flipped image (pixel x there is W-1-x here)
        flipped = detector.detect(np.ascontiguousarray(img8[:, ::-1]), quad_decimate)
        if any(4 * t.tag_id in index for t in flipped):
            return flipped, True
    return tags, False


def _board_tags(tags, mirrored, index, img, max_hamming, refine):
    r'''(used, rejected): [(tag id, its 4 corners (4,2) in camval's pixel convention)] of
the decoded tags of the board (cornerSubPix-polished with refine "subpix"), and the
counts of the tags left out by reason'''
    W = img.shape[1]
    seen = {}
    img32 = img if img.dtype == np.float32 or refine != "subpix" else img.astype(np.float32)
    rejected = {"hamming": 0, "not_on_board": 0, "duplicate": 0}
    for tag in tags:
        if tag.hamming > max_hamming:
            rejected["hamming"] += 1
            continue
        if 4 * tag.tag_id not in index:
            rejected["not_on_board"] += 1
            continue
        c = np.asarray(tag.corners, dtype=np.float64) - APRILTAG_PIXEL_OFFSET
        if mirrored:
            c[:, 0] = W - 1 - c[:, 0]
        seen.setdefault(tag.tag_id, []).append(c)
    used = []
    for tag_id, corners in seen.items():
        if len(corners) > 1:
            rejected["duplicate"] += len(corners)
            continue
        c = corners[0]
        if refine == "subpix":
            c = _refine(img32, c)
        used.append((tag_id, c))
    return used, rejected


def detect_apriltags(image, target, *, max_hamming=1, min_found=4, quad_decimate=None,
                     quad_sigma=0.0, refine_edges=1, decode_sharpening=0.25, refine=True,
                     psf_sigma_px=None, line_reference=None, defer_span_bias=True):
    r'''Detect an AprilTag grid; see the module docstring

SYNOPSIS

    det = detect_apriltags(image, target)

ARGUMENTS

- image: (H,W) float in [0,1], or uint8/uint16 (converted to 8 bits for the detector)
- target: an "apriltag" targets.boards.Target
- max_hamming: largest number of corrected bit errors accepted
- min_found: fewest corners for status "ok" (default 4: one tag)
- quad_decimate, quad_sigma, refine_edges, decode_sharpening: pupil_apriltags' options;
  quad_decimate None: with refine=True and no psf_sigma_px, TRIAL_DECIMATION_FACTOR x
  decimate_for(image shape), kept when that search missed no tag (_search_complete), else
  decimate_for's; otherwise decimate_for's
  (the quads only: decoding and the corners use the full image; info["quad_decimate"]
  has the one used)
- refine: True: fit the corner model (targets.corners); "subpix": polish each corner with
  cv2.cornerSubPix in a window of half a tag bit; False: pupil_apriltags' corners
- psf_sigma_px: the image's Gaussian blur (px) for the corner model when known (e.g. a
  campaign's response profile); 0: a sharp image (no blur look: ~6 ms of CPU less per
  image, the same corners as the look's on a sharp image); None (default): estimated from
  the image (targets.corners.estimate_blur); info["psf_sigma_px"] has the value used
- line_reference: the board lines' shape for a blurred image's tag edges
  (targets.tag_edges.refine_tag_edges; targets.tag_edges.camera_line_reference(model,
  Rt_cam_board, tag bit in metres) from a camera model and the board's pose, e.g. a
  calibration's): each corner's span judged by, and its model error taken off with, that
  shape instead of the image's own first pass; None (default): the image's alone
- defer_span_bias: without a line_reference, True (default): each corner's span is chosen
  as if its model error were taken off (refine_tag_edges' defer_span_bias), as the
  calibrators' bias step does (harness.calibrators.bias.tag_edges_bias, from the record
  det.corner_spans, under the current model and pose): the corners themselves then carry
  that error (the long spans' bend bias and the blur's shift of a bent edge), as the
  corner window's carry theirs; False: the span of least expected error as corners alone
'''
    if target.kind != "apriltag":
        return failed(target, f"detect_apriltags() needs an apriltag target; got "
                      f"{target.kind!r}", DETECTOR)
    work = working_image(image)
    if work is None:
        return failed(target, "the image has non-finite pixels", DETECTOR)
    img, img8, (lo, hi) = work
    ids = target.point_ids()
    index = {int(pid): k for k, pid in enumerate(ids)}
    # the quads are searched coarser first, kept when that search missed no
    # tag (_search_complete), else searched again at decimate_for's decimation; a blurred
    # image's tag edges start from the kept search's corners (tag_edges' search grown
    # with their error, which grows with the decimation: _refine_blurred)
    fine = decimate_for(img8.shape)
    trials = [quad_decimate] if quad_decimate is not None else \
        [TRIAL_DECIMATION_FACTOR * fine, fine] if refine is True and not psf_sigma_px \
        else [fine]
    for k, quad_decimate in enumerate(trials):
        last = k == len(trials) - 1
        tags, mirrored = _search(img8, index, quad_decimate, quad_sigma, refine_edges,
                                 decode_sharpening)
        if not last and not _search_complete(tags, index, quad_decimate, max_hamming):
            continue
        used, rejected = _board_tags(tags, mirrored, index, img, max_hamming, refine)
        if refine is True and used:
            from .corners import refine_tag_corners, tag_window
            if psf_sigma_px:
                # the search's decimation sets the tag edges' start error, as below (it was
                # left at 1: a given blur on 5120x3840 camera 1 dropped 104 of 864 corners,
                # "edges meet far from the corner", from the corners decimated by 3)
                fit = _refine_blurred(img, used, None, {"psf_sigma_px": float(psf_sigma_px),
                                                        "psf_source": "given"}, target,
                                      hi - lo, quad_decimate, line_reference=line_reference,
                                      defer_span_bias=defer_span_bias)
            else:
                fit = refine_tag_corners(img, np.array([c for _, c in used]),
                                         value_range=hi - lo, psf_sigma_px=psf_sigma_px,
                                         stop_if_blurred=True, **tag_window(target))
                if fit.info.get("stopped"):
                    fit = _refine_blurred(img, used, fit.q.reshape(-1, 4, 2), fit.info,
                                          target, hi - lo, quad_decimate, line_reference,
                                          defer_span_bias)
            refined = fit.q.reshape(-1, 4, 2)
            used = [(tag_id, refined[i]) for i, (tag_id, _) in enumerate(used)]
        break
    q = np.full((len(ids), 2), np.nan)
    for tag_id, c in used:
        for k in range(4):
            q[index[4 * tag_id + k]] = c[k]
    info = {"Ntags_decoded": len(tags), "Ntags_used": int(np.isfinite(q[:, 0]).sum() // 4),
            "rejected": rejected, "mirrored": mirrored, "quad_decimate": quad_decimate}
    if refine is True and used:
        info["corners_dropped"] = fit.dropped()
        info.update({k: v for k, v in fit.info.items() if k.startswith("psf_")})
    # which corner model gave the corners: the calibrators correct the window's bias only
    corner_model = (fit.info.get("corner_model", CORNER_WINDOW) if refine is True and used
                    else "cornerSubPix" if refine == "subpix" else "pupil_apriltags")
    if not np.isfinite(q).any():
        if used:
            return failed(target, f"every corner of the {len(used)} tags of the board decoded was "
                          f"dropped by the corner refinement: {info.get('corners_dropped')}",
                          DETECTOR, info)
        return failed(target, f"no tag of the board decoded ({len(tags)} tags decoded in all)",
                      DETECTOR, info)
    det = result(target, q, DETECTOR, min_found=min_found, info=info,
                 corner_model=corner_model)
    spans = fit.info.get("edge_spans") if refine is True and used else None
    if spans is not None:
        # for the calibrators' bias step (harness.calibrators.bias.corner_bias: where the
        # tag edges' spans place each corner under the current model): each point's two
        # edges' records, the row of each edge's other corner appended (NaN: none)
        rec = np.full((len(ids), 2, spans.shape[-1] + 1), np.nan)
        for i, (tag_id, _) in enumerate(used):
            for k in range(4):
                row = index[4 * tag_id + k]
                rec[row, :, :-1] = spans[4 * i + k]
                rec[row, 0, -1] = index[4 * tag_id + (k - 1) % 4]
                rec[row, 1, -1] = index[4 * tag_id + (k + 1) % 4]
        det = dataclasses.replace(det, corner_spans=rec)
    sigma = fit.info.get("corner_sigma_px") if refine is True and used else None
    if sigma is not None:
        # each point's predicted error (refine_tag_edges' info["corner_sigma_px"]; NaN: none)
        out = np.full(len(ids), np.nan)
        for i, (tag_id, _) in enumerate(used):
            out[[index[4 * tag_id + k] for k in range(4)]] = sigma[4 * i:4 * i + 4]
        out[~det.found] = np.nan
        det = dataclasses.replace(det, corner_sigma_px=out)
    return det

r'''Find the tag corners of an AprilTag grid with pupil_apriltags

SYNOPSIS

    from targets.detect_apriltag import detect_apriltags

    det = detect_apriltags(image, target)   # targets.detect.Detection
    det.q                                   # (4*Ntags,2): point 4*tag_id + corner

Each decoded tag of the target's family whose id is on the board gives its 4
outer black-border corners, in pupil_apriltags' order (bottom-left,
bottom-right, top-right, top-left of the upright tag), which is the order of
the target's points. Tags with a Hamming distance above max_hamming, ids not
on the board, and ids seen twice are ignored (a duplicate id drops both).

Pixel convention: the AprilTag library puts the centre of pixel (0,0) at
(0.5, 0.5) (its corners came out +0.50 px in x and y against exact projections,
measured in tests/test_detect.py), camval at (0,0): corners are shifted by
APRILTAG_PIXEL_OFFSET.

The AprilTag corners come from straight-line fits to each tag edge
(refine_edges): under strong lens distortion the edges are curved and the
corners are biased by a fraction of a pixel; they are not subpixel-exact like
the dot centroids.
'''

import functools

import numpy as np

from .detect import as_float_image, failed, result

DETECTOR = "apriltag"
# AprilTag pixel coordinates minus camval's for the same point
APRILTAG_PIXEL_OFFSET = 0.5


@functools.lru_cache(maxsize=4)
def _detector(quad_decimate, quad_sigma, refine_edges, decode_sharpening):
    from pupil_apriltags import Detector
    return Detector(families="tag36h11", nthreads=1, quad_decimate=quad_decimate,
                    quad_sigma=quad_sigma, refine_edges=refine_edges,
                    decode_sharpening=decode_sharpening)


def detect_apriltags(image, target, *, max_hamming=1, min_found=4, quad_decimate=1.0,
                     quad_sigma=0.0, refine_edges=1, decode_sharpening=0.25):
    r'''Detect an AprilTag grid; see the module docstring

SYNOPSIS

    det = detect_apriltags(image, target)

ARGUMENTS

- image: (H,W) float in [0,1], or uint8/uint16 (converted to 8 bits for the detector)
- target: an "apriltag" targets.boards.Target
- max_hamming: largest number of corrected bit errors accepted
- min_found: fewest corners for status "ok" (default 4: one tag)
- quad_decimate, quad_sigma, refine_edges, decode_sharpening: pupil_apriltags' options
'''
    img = as_float_image(image)
    if target.kind != "apriltag":
        return failed(target, f"detect_apriltags() needs an apriltag target; got "
                      f"{target.kind!r}", DETECTOR)
    if not np.all(np.isfinite(img)):
        return failed(target, "the image has non-finite pixels", DETECTOR)
    img8 = np.ascontiguousarray(np.round(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8))
    tags = _detector(float(quad_decimate), float(quad_sigma), int(refine_edges),
                     float(decode_sharpening)).detect(img8)
    ids = target.point_ids()
    index = {int(pid): k for k, pid in enumerate(ids)}
    q = np.full((len(ids), 2), np.nan)
    seen = {}
    rejected = {"hamming": 0, "not_on_board": 0, "duplicate": 0}
    for tag in tags:
        if tag.hamming > max_hamming:
            rejected["hamming"] += 1
            continue
        if 4 * tag.tag_id not in index:
            rejected["not_on_board"] += 1
            continue
        seen.setdefault(tag.tag_id, []).append(
            np.asarray(tag.corners, dtype=np.float64) - APRILTAG_PIXEL_OFFSET)
    for tag_id, corners in seen.items():
        if len(corners) > 1:
            rejected["duplicate"] += len(corners)
            continue
        for k in range(4):
            q[index[4 * tag_id + k]] = corners[0][k]
    info = {"Ntags_decoded": len(tags), "Ntags_used": int(np.isfinite(q[:, 0]).sum() // 4),
            "rejected": rejected}
    if not np.isfinite(q).any():
        return failed(target, f"no tag of the board decoded ({len(tags)} tags decoded in all)",
                      DETECTOR, info)
    return result(target, q, DETECTOR, min_found=min_found, info=info)

r'''Find a target's points in an image: the detector registry

SYNOPSIS

    from targets.detect import detect, get_detector, known_detectors

    det = detect(image, target)     # image (H,W) float in [0,1] (or uint8/uint16)
    det = detect(image, target, window_dilation_px=3)   # options of the kind's detector
    det.info["saturation"]          # the image's clipped pixels (targets.saturation.measure)
    det.status                      # "ok" | "failed"
    det.q[det.found]                # (Nfound,2) pixel positions, camval's pixel convention
    det.n_found, det.n_expected, det.reason

    detector = get_detector("dots")            # the detector of a target kind
    known_detectors()               # {kind: source}: built-in ones and entry-point plugins

One built-in detector per target kind: targets.detect_dots
(intensity-weighted dot centroids, ordered with the orientation mark),
targets.detect_apriltag (pupil_apriltags), targets.detect_chessboard
(OpenCV). The result is a targets.detection.Detection; q[i] belongs to
target.point_ids()[i], NaN where a point was not found.

A detector is anything with this shape (typing.Protocol `Detector`:
detector(image, target, **options) -> Detection); a plain function is one.
The registry is a dict of lazy specs "module:function": a detector's module
(OpenCV, pupil_apriltags) is imported only when its kind is detected. Python
packages add detectors under the entry-point group "camval.detectors": a
target file names one with its key `detector` (targets.boards; e.g. kind =
"chessboard", detector = "my_chessboard"), and a target whose kind is the
plug-in's name gets it; a built-in name keeps its built-in detector.

A detector never raises because the target was not found: it returns status
"failed" with the reason. Only input that is not an image at all (wrong
dimensions, a target kind without a detector) raises a DetectionInputError.
'''

import importlib
from typing import Protocol, runtime_checkable

from .detection import Detection, DetectionInputError

ENTRY_POINT_GROUP = "camval.detectors"

# target kind -> "module:function"
BUILTIN_DETECTORS = {
    "dots": "targets.detect_dots:detect_dots",
    "apriltag": "targets.detect_apriltag:detect_apriltags",
    "chessboard": "targets.detect_chessboard:detect_chessboard",
}


class UnknownDetectorError(DetectionInputError):
    '''A target kind that no built-in or plugin detector finds.'''


@runtime_checkable
class Detector(Protocol):
    def __call__(self, image, target, **options) -> Detection: ...


def _entry_point_detectors():
    from importlib.metadata import entry_points
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def known_detectors():
    r'''{target kind: source} of every detector: built-in ones, then entry-point plugins'''
    out = {kind: f"built-in ({spec})" for kind, spec in BUILTIN_DETECTORS.items()}
    for kind, ep in _entry_point_detectors().items():
        out.setdefault(kind, f"plugin ({ep.value}, package {ep.dist.name if ep.dist else '?'})")
    return out


def get_detector(kind):
    r'''The detector of target kind `kind` (UnknownDetectorError naming the known kinds)'''
    if kind in BUILTIN_DETECTORS:
        modname, funcname = BUILTIN_DETECTORS[kind].split(":")
        return getattr(importlib.import_module(modname), funcname)
    plugins = _entry_point_detectors()
    if isinstance(kind, str) and kind in plugins:
        return plugins[kind].load()
    raise UnknownDetectorError(f"no detector for target kind {kind!r}; "
                               f"known kinds: {', '.join(known_detectors())}")


def detect(image, target, **options):
    r'''Find the target's points in an image

SYNOPSIS

    det = detect(image, target)          # Detection
    det = detect(image, target, window_dilation_px=3)   # options of the kind's detector

Calls the detector the target names (target.detector: a target file's key
"detector", targets.boards), else the one registered for target.kind
(get_detector).

The Detection's info["saturation"] is the image's clipped pixels and column bleed
(targets.saturation.measure: measured once here for every detector; a CCD's blooming
moves the positions any detector finds), unless the detector gave its own.
'''
    name = getattr(target, "detector", None) or getattr(target, "kind", None)
    det = get_detector(name)(image, target, **options)
    if isinstance(det, Detection) and isinstance(det.info, dict) \
            and "saturation" not in det.info:
        import dataclasses

        from .saturation import measure
        det = dataclasses.replace(det, info={**det.info, "saturation": measure(image)})
    return det

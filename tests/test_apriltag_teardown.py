r'''The AprilTag detector's C objects are freed detector first, then its families

pupil_apriltags' own Detector.__del__ frees the tag families first; the detector's
destroy then writes into a freed family (targets.detect_apriltag._destroy says how this
corrupted the heap and aborted the test process at exit). These tests record the C
calls a real detector's teardown makes.
'''

import gc

import numpy as np

from targets.detect_apriltag import _destroy, _detector, _detector_class


class _Recorder:
    r'''The detector's C library, recording the names of the *_destroy functions called'''

    def __init__(self, lib):
        self.lib = lib
        self.calls = []

    def __getattr__(self, name):
        fn = getattr(self.lib, name)
        if not name.endswith("_destroy"):
            return fn
        calls = self.calls

        class Call:
            def __call__(self, *args):
                calls.append(name)
                return fn(*args)

            def __setattr__(self, attr, value):
                setattr(fn, attr, value)     # restype

        return Call()


def _new_detector():
    return _detector_class()(families="tag36h11", nthreads=1)


def test_collected_detector_frees_the_detector_before_its_family():
    det = _new_detector()
    rec = det.libc = _Recorder(det.libc)
    del det
    gc.collect()
    # the other order (pupil_apriltags' own) is the write after free
    assert rec.calls == ["apriltag_detector_destroy", "tag36h11_destroy"]


def test_destroy_is_done_once():
    det = _new_detector()
    rec = det.libc = _Recorder(det.libc)
    _destroy(det)
    _destroy(det)
    assert det.tag_detector_ptr is None and det.tag_families == {}
    del det
    gc.collect()
    # neither a second explicit call nor __del__ frees the C objects again
    assert rec.calls == ["apriltag_detector_destroy", "tag36h11_destroy"]


def test_cached_detector_is_the_ordered_one_and_detects():
    det = _detector(1.0, 0.0, 1, 0.25)
    assert isinstance(det, _detector_class())
    # a blank image decodes no tag (a detector whose C side were freed would crash here)
    assert det.detect(np.full((64, 64), 128, np.uint8)) == []

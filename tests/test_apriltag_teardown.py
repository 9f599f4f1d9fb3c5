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
    det = _detector(0.0, 1, 0.25)
    assert isinstance(det, _detector_class())
    # a blank image decodes no tag (a detector whose C side were freed would crash here)
    assert det.detect(np.full((64, 64), 128, np.uint8)) == []


def test_detect_reads_the_callers_image_as_pupil_apriltags_does():
    # the ordered detector hands the AprilTag library the caller's own rows (stride = width,
    # no copy); the library's own detect copies them into rows padded to 96 bytes. Both
    # run the same C search on the same pixel values, so the tags and corners are the same
    # (an odd width included). A second pupil_apriltags Detector is not made here: its own
    # teardown corrupts the heap
    from pupil_apriltags import Detector
    from targets_render import pinhole, render

    from targets.boards import load_target
    t = load_target("apriltag")
    r, a = np.radians(-23.0), np.radians(20.0)
    Rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    img = render(pinhole(640, 640, 600.0), t.pattern(), np.vstack((Rz @ Rx, [-0.5, -0.45, 1.6])),
                 K=4)
    img8 = np.round(255 * np.clip(img, 0, 1)).astype(np.uint8)
    det = _detector(0.0, 1, 0.25)
    det.detect(img8, 1.0)
    for im in (img8, img8[:, :333]):
        # pupil_apriltags' own detect, on the same (ordered: see above) detector
        got, want = det.detect(im), Detector.detect(det, np.ascontiguousarray(im))
        assert len(want) >= 4
        assert [(g.tag_id, g.hamming) for g in got] == [(w.tag_id, w.hamming) for w in want]
        assert all(np.array_equal(g.corners, w.corners) for g, w in zip(got, want, strict=True))


def test_one_detector_serves_every_decimation():
    # the cached detector takes the decimation per search (the C detector's field): its
    # tags at each decimation, in any order, are those of a detector built with that one
    from targets_render import pinhole, render

    from targets.boards import load_target
    t = load_target("apriltag")
    a = np.radians(25.0)
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    img = render(pinhole(900, 700, 800.0), t.pattern(), np.vstack((Rx, [-0.45, -0.4, 1.5])),
                 K=4)
    img8 = np.round(255 * np.clip(img, 0, 1)).astype(np.uint8)
    shared = _detector(0.0, 1, 0.25)
    got = {d: shared.detect(img8, d) for d in (3.0, 1.0, 2.0)}
    got[3.5] = shared.detect(img8, 3.0)          # set back: the same as the first search
    for d, tags in got.items():
        own = _detector_class()(families="tag36h11", nthreads=1, quad_decimate=min(d, 3.0))
        want = own.detect(img8)
        assert len(want) >= 4
        assert [(g.tag_id, g.hamming) for g in tags] == [(w.tag_id, w.hamming) for w in want]
        assert all(np.array_equal(g.corners, w.corners) for g, w in zip(tags, want, strict=True))
    # the decimations differ: pupil_apriltags' quads (its corners) are not the same
    fine, coarse = ({g.tag_id: g.corners for g in got[d]} for d in (1.0, 3.0))
    assert any(not np.array_equal(fine[i], coarse[i]) for i in fine.keys() & coarse.keys())

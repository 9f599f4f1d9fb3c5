r'''Keep C-library messages off the terminal, and keep them for the record

SYNOPSIS

    from harness.quiet import capture, diagnostics_of

    with capture() as cap:
        mrcal.optimize(**problem)     # libdogleg, mrcal, OpenCV, COLMAP write to fds 1/2
    cap.lines                         # ["libdogleg at dogleg.c:1651: CHOLMOD warning: ...", ...]
    cap.summary()                     # {"n": 41, "kinds": {"CHOLMOD warning": 40, ...},
                                      #  "first": [first MAX_FIRST lines]}

mrcal, libdogleg, OpenCV and COLMAP (glog) print straight to the file
descriptors 1 and 2, below Python: sys.stdout cannot catch them. capture()
points fds 1 and 2 at a temporary file for the duration of the block and reads
what the libraries wrote there afterwards. Python's own sys.stdout/sys.stderr
keep writing to the terminal meanwhile (they are pointed at duplicates of the
original descriptors while the block runs), so progress lines printed by
another thread are not swallowed.

The redirection is process-wide. Nested blocks and blocks running at the same
time in several threads (the Dask threaded executor) share one redirection: the
first block in sets it up, the last one out restores the descriptors, and each
block gets the lines written between its entry and its exit, so a line written
while two blocks overlap is counted by both (nothing is lost; a count may be
high by the overlap). Processes (the local process pool) each have their own
descriptors.

diagnostics_of(fit, library) wraps a calibrator's fit(): its library calls
run inside capture() and the result's info["diagnostics"] holds the summary
(a failed fit too: it is returned as a failed CalibrationResult with the
reason calibrate() would give it).
'''

import contextlib
import ctypes
import functools
import io
import os
import re
import sys
import tempfile
import threading

# lines kept verbatim per block (the counts cover all of them)
MAX_FIRST = 5
# message kinds: (name, regular expression); the first that matches names a line
KINDS = (
    ("CHOLMOD warning", re.compile(r"CHOLMOD warning")),
    ("CAHVORE projection failed", re.compile(r"CAHVORE PROJECTION .*FAILED")),
    ("libdogleg", re.compile(r"libdogleg")),
    ("mrcal", re.compile(r"mrcal[\w.]*\(\d+\)|\bmrcal\b|^_project_\w+\(\)")),
    ("OpenCV", re.compile(r"OpenCV|cv::|\[ WARN:|\[ERROR:")),
    ("COLMAP", re.compile(r"^[IWEF]\d{4} |colmap|ceres", re.IGNORECASE)),
)

_lock = threading.RLock()
_state = {"depth": 0, "file": None, "saved": None, "streams": None}
_retired = []   # the previous capture's Python stream wrappers (see _exit)


def kind_of(line):
    r'''The kind of a captured line ("CHOLMOD warning", "mrcal", ..., "other")'''
    for name, rx in KINDS:
        if rx.search(line):
            return name
    return "other"


class Captured:
    r'''The lines written to fds 1/2 during one capture() block'''

    def __init__(self):
        self.lines = []

    def counts(self):
        out = {}
        for line in self.lines:
            k = kind_of(line)
            out[k] = out.get(k, 0) + 1
        return out

    def summary(self, max_first=MAX_FIRST):
        r'''{"n": lines, "kinds": {kind: count}, "first": the first max_first lines}'''
        return {"n": len(self.lines), "kinds": self.counts(),
                "first": list(self.lines[:max_first])}

    def __bool__(self):
        return bool(self.lines)


def _flush_c():
    # C stdio buffers of the libraries (OpenCV prints through printf) go out before the
    # descriptors change
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


def _flush_python():
    for s in (sys.stdout, sys.stderr):
        try:
            s.flush()
        except (AttributeError, ValueError, OSError):
            pass


def _fd_of(stream):
    try:
        return stream.fileno()
    except (AttributeError, ValueError, OSError, io.UnsupportedOperation):
        return None


def _enter():
    with _lock:
        if _state["depth"] == 0:
            while _retired:
                try:
                    _retired.pop().close()
                except (ValueError, OSError):
                    pass
            _flush_python()
            _flush_c()
            f = tempfile.TemporaryFile(mode="w+b")
            saved = {fd: os.dup(fd) for fd in (1, 2)}
            streams = {}
            # Python's streams that write to fd 1/2 keep going to the terminal
            for name in ("stdout", "stderr"):
                s = getattr(sys, name)
                fd = _fd_of(s)
                if fd in saved:
                    streams[name] = s
                    setattr(sys, name, io.TextIOWrapper(
                        os.fdopen(os.dup(saved[fd]), "wb"), encoding=getattr(
                            s, "encoding", None) or "utf-8", errors="backslashreplace",
                        line_buffering=True))
            for fd in (1, 2):
                os.dup2(f.fileno(), fd)
            _state.update(file=f, saved=saved, streams=streams)
        _state["depth"] += 1
        return _state["file"].seek(0, os.SEEK_END)


def _read_from(offset):
    f = _state["file"]
    f.seek(offset)
    return f.read()


def _exit(offset):
    with _lock:
        _flush_c()
        data = _read_from(offset)
        _state["depth"] -= 1
        if _state["depth"] == 0:
            _flush_python()
            for fd, dup in _state["saved"].items():
                os.dup2(dup, fd)
                os.close(dup)
            for name, s in _state["streams"].items():
                wrapper = getattr(sys, name)
                setattr(sys, name, s)
                # flushed, not closed: another thread may be inside its write(); closed at
                # the next capture's start
                try:
                    wrapper.flush()
                except (ValueError, OSError):
                    pass
                _retired.append(wrapper)
            _state["file"].close()
            _state.update(file=None, saved=None, streams=None)
        return data


@contextlib.contextmanager
def capture():
    r'''Redirect fds 1 and 2 to a temporary file inside the block; yields a Captured

The lines are in the Captured object once the block has ended (also when it
raised).
'''
    cap = Captured()
    offset = _enter()
    try:
        yield cap
    finally:
        data = _exit(offset)
        text = data.decode("utf-8", errors="backslashreplace")
        cap.lines.extend(line.rstrip() for line in text.splitlines() if line.strip())


def diagnostics_of(library):
    r'''Decorator of a calibrator's fit(): run it inside capture(), keep the summary

SYNOPSIS

    @diagnostics_of("mrcal")
    def fit(obs, target, model_name, ...): ...

    r = fit(...)               # a CalibrationResult, also when the fit failed
    r.info["diagnostics"]      # {"n": ..., "kinds": {...}, "first": [...]}

A CalibrationFailed or a library exception inside the fit becomes a failed
CalibrationResult with the reason harness.calibrators.calibrate() would give;
a CalibratorError (bad input) is raised as before.
'''
    def wrap(fit):
        @functools.wraps(fit)
        def wrapped(obs, target, model_name, *args, **kwargs):
            from harness.calibrators.base import (
                CalibrationFailed,
                CalibrationResult,
                CalibratorError,
            )
            error = result = None
            with capture() as cap:
                try:
                    result = fit(obs, target, model_name, *args, **kwargs)
                except CalibratorError:
                    raise
                except CalibrationFailed as e:
                    error = str(e)
                except Exception as e:  # a library that throws: a failed method
                    error = f"exception inside {library}: {type(e).__name__}: {e}".splitlines()[0]
            diag = cap.summary()
            if error is not None:
                mod = sys.modules.get(fit.__module__)
                try:
                    version = mod.library_version()
                except Exception as e:
                    version = f"unknown ({type(e).__name__})"
                return CalibrationResult(calibrator=getattr(mod, "NAME", library),
                                         model_name=str(model_name), status="failed",
                                         reason=error, library=library, library_version=version,
                                         info={"diagnostics": diag})
            return result.replace(info={**result.info, "diagnostics": diag})
        return wrapped
    return wrap

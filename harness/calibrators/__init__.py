r'''Reference calibrators: a registry and the calibrate() dispatcher

SYNOPSIS

    from harness.calibrators import calibrate, known_calibrators

    result = calibrate("jpl", observations, target, "CAHVOR", truth=truth_model)
    # result: harness.calibrators.base.CalibrationResult

The registry is a plain dict of lazy specs, name -> "module" (or
"module:attribute"): the library behind a calibrator is imported only when it
is chosen. Python packages add calibrators under the entry-point group
"camval.calibrators" (an entry point names a module or an object). A
calibrator is anything with the shape of base.Calibrator (a typing.Protocol:
NAME, LIBRARY, MODELS (the model names it can fit), library_version() and
fit(observations, target, model_name, truth=None, **options) returning a
CalibrationResult; optionally canonical_model(name) and
uses_world_frame(**options)); fit() may raise base.CalibrationFailed to end
with a failed result.

calibrate() never raises for a failure of the method: a model the calibrator
cannot fit gives status "not-applicable", a failure or an exception inside
the library gives status "failed" with the reason. Bad input (an unknown
calibrator, inconsistent observations) raises a CalibratorError.
'''

import importlib
import time

from .base import (
    CalibrationFailed,
    CalibrationResult,
    Calibrator,
    CalibratorError,
    Observations,
    UnknownCalibratorError,
)

__all__ = ["calibrate", "known_calibrators", "calibrator_module", "models_of",
           "uses_world_frame", "ENTRY_POINT_GROUP", "BUILTIN_CALIBRATORS",
           "Calibrator", "CalibrationResult", "Observations", "CalibratorError"]

ENTRY_POINT_GROUP = "camval.calibrators"

# name -> "module" (or "module:attribute")
BUILTIN_CALIBRATORS = {
    "jpl": "harness.calibrators.jpl_fit",
    "mrcal": "harness.calibrators.mrcal_fit",
    "opencv": "harness.calibrators.opencv_fit",
    "colmap": "harness.calibrators.colmap_fit",
}


def _entry_point_calibrators():
    from importlib.metadata import entry_points
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def known_calibrators():
    r'''{name: source} of every calibrator: the built-in ones, then entry-point plugins

SYNOPSIS

    known_calibrators()["jpl"]   # "built-in (harness.calibrators.jpl_fit)"
    "jpl" in known_calibrators() # nothing is imported to answer this
'''
    out = {name: f"built-in ({spec})" for name, spec in BUILTIN_CALIBRATORS.items()}
    for name, ep in _entry_point_calibrators().items():
        out.setdefault(name, f"plugin ({ep.value}, package {ep.dist.name if ep.dist else '?'})")
    return out


def calibrator_module(name):
    r'''The calibrator called `name`: its module, or the object a plugin names

Raises UnknownCalibratorError (listing the known calibrators) for an unknown
name, CalibratorError for a plugin that is not a Calibrator, and ImportError
when the calibrator's library is missing here.
'''
    if name in BUILTIN_CALIBRATORS:
        modname, _, attr = BUILTIN_CALIBRATORS[name].partition(":")
        mod = importlib.import_module(modname)
        return getattr(mod, attr) if attr else mod
    plugins = _entry_point_calibrators()
    if name not in plugins:
        raise UnknownCalibratorError(
            f"unknown calibrator {name!r}; known calibrators: "
            f"{', '.join(sorted(known_calibrators()))}")
    cal = plugins[name].load()
    if not isinstance(cal, Calibrator):
        missing = [a for a in ("NAME", "LIBRARY", "MODELS", "library_version", "fit")
                   if not hasattr(cal, a)]
        raise CalibratorError(f"calibrator {name!r} ({plugins[name].value}) is not a "
                              f"calibrator: it has no {', '.join(missing)}")
    return cal


def uses_world_frame(name, options):
    r'''Whether calibrator `name` with these options reads the world frame

SYNOPSIS

    uses_world_frame("jpl", {})                        # True: surveyed world points
    uses_world_frame("mrcal", {"known_poses": True})   # True
    uses_world_frame("mrcal", {})                      # False: board poses estimated

A calibrator that does not (it estimates the board poses and fits the camera
in its own frame) gives the same result for two cameras that see the same
images, wherever they are: a campaign computes it once for both
(harness.jobs.group_twins). A calibrator module that does not say is taken
to read it.
'''
    f = getattr(calibrator_module(name), "uses_world_frame", None)
    return True if f is None else bool(f(**dict(options or {})))


def models_of(name):
    r'''The model names calibrator `name` can fit'''
    return tuple(calibrator_module(name).MODELS)


def calibrate(name, observations, target, model_family, truth=None, **options):
    r'''Calibrate with calibrator `name`; failures are returned, not raised

SYNOPSIS

    result = calibrate("mrcal", obs, target, "CAHVORE", truth=truth, known_poses=False)

ARGUMENTS

- name: a name from known_calibrators(): "jpl" | "mrcal" | "opencv" | "colmap" or a plugin
- observations: base.Observations
- target: targets.boards.Target (or anything with points() and pattern()), or
  None (no dot-centroid bias correction then)
- model_family: a name from models_of(name), e.g. "CAHVOR", "OPENCV5"
- truth: the true model; only its CAHVORE type and linearity are used
- options: calibrator-specific (see each module's fit())

RETURNED VALUE

A CalibrationResult; status "ok", "failed" or "not-applicable".
'''
    mod = calibrator_module(name)
    if not isinstance(observations, Observations):
        raise CalibratorError(f"observations must be a harness.calibrators.base.Observations; "
                              f"got {type(observations).__name__}")
    version = _version(mod)
    common = dict(calibrator=name, model_name=str(model_family), library=mod.LIBRARY,
                  library_version=version)
    canonical = mod.canonical_model(model_family) if hasattr(mod, "canonical_model") \
        else model_family
    if canonical not in mod.MODELS:
        return CalibrationResult(
            status="not-applicable",
            reason=f"{name} cannot fit a {model_family!r} model; it fits {', '.join(mod.MODELS)}",
            **common)
    t0 = time.perf_counter()
    try:
        result = mod.fit(observations, target, canonical, truth=truth, **options)
    except CalibrationFailed as e:
        return CalibrationResult(status="failed", reason=str(e),
                                 seconds=time.perf_counter() - t0, **common)
    except CalibratorError:
        raise
    except Exception as e:  # a library that throws is a failed method, not a crash
        return CalibrationResult(
            status="failed",
            reason=f"exception inside {mod.LIBRARY}: {type(e).__name__}: {e}".splitlines()[0],
            seconds=time.perf_counter() - t0, **common)
    if not result.seconds:
        result = result.replace(seconds=time.perf_counter() - t0)
    return result


def _version(mod):
    try:
        return mod.library_version()
    except Exception as e:
        return f"unknown ({type(e).__name__})"

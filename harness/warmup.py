r'''Warm numba up once before the worker processes start

SYNOPSIS

    from harness.warmup import kernels_cached, warm_up

    kernels_cached("raycast")   # numba's disk cache holds the kernels for their source
    info = warm_up(jobs)        # {"seconds", "renders", "cached", "failed"}

Before local worker processes start (harness.executors.run_jobs), warm_up()
compiles (or loads) the renderer's numba kernels once in this process, so the
workers load the cached kernels instead of each compiling them.
'''

import time

from .stages import cached_target, camera_stage, failure_reason, poses_stage

# --- what names kernels: the only place here that knows them --------------------------
# renderers whose kernels numba compiles (and caches on disk) on first use -> the module
# whose compiled_entry_points() are the kernels a render calls from Python
NUMBA_RENDERERS = {"raycast": "renderers._raycast_kernels"}
# every module with @njit(cache=True) kernels that call reference_models.kernels: numba
# checks a cached kernel against its own source file only (reference_models.kernels.
# drop_stale_caches says why), so a warm-up drops their stale caches first
COMPILED_MODULES = ("reference_models.kernels", "renderers._raycast_kernels",
                    "renderers.raycast_outlines", "targets.poses",
                    "harness.calibrators._jpl_kernels")


def _entry_points(modname):
    import importlib
    return importlib.import_module(modname).compiled_entry_points()


def _numba_cache_index(kernel):
    r'''The index of numba's on-disk cache of a @njit(cache=True) kernel (numba's private
API: empty when no entry matches the kernel's current source)'''
    return kernel._cache._cache_file._load_index()


def drop_stale_caches():
    r'''Drop numba's cached kernels compiled before reference_models/kernels.py last changed

Run in one process before workers start (warm_up does); returns the dropped names.
'''
    from reference_models.kernels import drop_stale_caches as drop
    dropped = []
    for modname in COMPILED_MODULES:
        dropped += drop(_entry_points(modname))
    return dropped


def kernels_cached(renderer):
    r'''True when numba's on-disk cache holds the renderer's kernels for their current source

Reads only numba's cache index (its stamp of the source file), loads no code:
False after a kernel change (of the renderer's module or of reference_models.kernels,
whose stale caches it drops), for a new cache directory, or when numba's internals
cannot be read (then warming is the safe choice).
'''
    if renderer not in NUMBA_RENDERERS:
        return True
    try:
        if drop_stale_caches():
            return False
        return all(bool(_numba_cache_index(k)) for k in _entry_points(NUMBA_RENDERERS[renderer]))
    except Exception:
        return False


def warm_up(jobs, force=False):
    r'''Compile (or load from numba's cache) the kernels the jobs need, in this process

SYNOPSIS

    info = warm_up(jobs)   # {"seconds", "renders": ["raycast/CAHV", ...], "cached", "failed"}
    # force=True: warm even when numba's cache is up to date

Renders one image per model family used by the jobs' numba renderers (the
job's own camera and first planned pose, K=1), and runs the blooming kernel if a
job's response uses it.
numba writes what it compiles to its cache directory, so worker processes
started afterwards load the kernels instead of each compiling them (after a
kernel change that is minutes per worker on a loaded machine). A renderer
whose kernels are already cached for their source (kernels_cached) is not
warmed: loading them here too would only add the loading time (seconds under
load) before the workers start. Never raises: a job that cannot be warmed
fails later, in its own record.
'''
    t0 = time.perf_counter()
    done, failed, cached = [], [], []
    seen = set()
    if force and any(j.renderer in NUMBA_RENDERERS for j in jobs):
        try:
            drop_stale_caches()
        except Exception:  # numba's internals changed: compile anyway
            pass
    for name in sorted({j.renderer for j in jobs if j.renderer in NUMBA_RENDERERS}):
        if not force and kernels_cached(name):
            cached.append(name)
    for job in jobs:
        key = (job.renderer, job.family)
        if job.renderer not in NUMBA_RENDERERS or job.renderer in cached or key in seen:
            continue
        try:
            from renderers.base import RenderSettings, get_renderer
            _, truth = camera_stage(job)
            target = cached_target(job.target)
            Rt = poses_stage(truth, target, 1, job.poses_seed)[0]
            renderer = get_renderer(job.renderer)
            renderer.render(truth, target.pattern(), Rt, RenderSettings(spp=1, adaptive=True))
            seen.add(key)
            done.append(f"{job.renderer}/{job.family}")
        except Exception as e:  # not-applicable family, invisible target: try the next job
            failed.append(f"{job.key}: {failure_reason(e)}")
    if any((j.response or {}).get("saturation", {}).get("blooming") for j in jobs):
        try:
            import numpy as np

            from renderers.response import ResponseChain
            ResponseChain.from_config({"saturation": {"blooming": True}}).apply(
                np.full((4, 4), 2.0))
            done.append("response/blooming")
        except Exception as e:
            failed.append(f"response/blooming: {failure_reason(e)}")
    return {"seconds": time.perf_counter() - t0, "renders": done, "cached": cached,
            "failed": sorted(set(failed))[:10]}

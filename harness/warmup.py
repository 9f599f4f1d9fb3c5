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
# LEAD (issue 13): the compiled kernels move to reference_models/kernels.py; point this
# table (and, if numba's cache layout differs there, _numba_cache_index) at their new home.
# renderers whose kernels numba compiles (and caches on disk) on first use, and the
# kernels a render calls from Python (module, names)
NUMBA_RENDERERS = {"raycast": ("renderers._raycast_kernels", ("render_kernel",
                                                               "_fill_ray_cache"))}


def _numba_cache_index(kernel):
    r'''The index of numba's on-disk cache of a @njit(cache=True) kernel (numba's private
API: empty when no entry matches the kernel's current source)'''
    return kernel._cache._cache_file._load_index()


def kernels_cached(renderer):
    r'''True when numba's on-disk cache holds the renderer's kernels for their current source

Reads only numba's cache index (its stamp of the source file), loads no code:
False after a kernel change, for a new cache directory, or when numba's
internals cannot be read (then warming is the safe choice).
'''
    import importlib
    if renderer not in NUMBA_RENDERERS:
        return True
    modname, names = NUMBA_RENDERERS[renderer]
    try:
        mod = importlib.import_module(modname)
        return all(bool(_numba_cache_index(getattr(mod, n))) for n in names)
    except Exception:
        return False


def warm_up(jobs, force=False):
    r'''Compile (or load from numba's cache) the kernels the jobs need, in this process

SYNOPSIS

    info = warm_up(jobs)   # {"seconds", "renders": ["raycast/CAHV", ...], "cached", "failed"}
    # force=True: warm even when numba's cache is up to date

Renders one image per model family used by the jobs' numba renderers (the
job's own camera and first planned pose, K=1, with a private ray cache that is
dropped afterwards), and runs the blooming kernel if a job's response uses it.
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
            renderer = get_renderer(job.renderer, shared_cache=False)
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

r'''Compile numba's kernels once, on both cores, before the worker processes start

SYNOPSIS

    from harness.warmup import kernels_cached, warm_up

    kernels_cached("raycast")   # numba's disk cache holds the kernels for their source
    info = warm_up(jobs)        # {"seconds", "renders", "fits", "cached", "failed"}

    uv run --frozen camval warm-up campaigns/paper.toml   # the same, as an install step

Before local worker processes start (harness.executors.run_jobs), warm_up()
compiles every numba kernel a job calls, so that the workers load them from
numba's on-disk cache instead of each compiling them. The kernels fall into two
disjoint sets, compiled at the same time in two processes: the render set
(the renderer's kernels, the camera response, the detector's: one real image of
each job kind rendered, responded and detected) and the fit set (the pose
planner's and the calibrators' kernels: each numba calibrator fitted once on the
exact observations of the job's poses, and the corner targets' bias step). The
render set is most of the time (~48 of ~60 CPU s on this machine kind, nearly all of it
the ray caster's render_kernel), so two cores take ~48 s where one took ~60.

Two processes may write numba's cache at once: each index file is written by
rename (atomic), and two writers of one kernel with the same signature write
the same thing. The one unsafe case, two processes adding different
signatures of one kernel at the same moment (both pick data file 1), does not
arise: the kernels both sets call (reference_models.kernels) are compiled with
one signature each (project_packed hands them writable C arrays).

scripts/setup.sh runs the warm-up of the paper and quick campaigns as an
install step (as uv's --compile-bytecode does for .pyc files), so a fresh
clone's first campaign loads the kernels instead of compiling them.
'''

import time

from .stages import cached_target, camera_stage, failure_reason, poses_stage

# --- what names kernels: the only place here that knows them --------------------------
# renderers whose kernels numba compiles (and caches on disk) on first use -> the modules
# whose compiled_entry_points() are the kernels a render calls from Python
NUMBA_RENDERERS = {"raycast": ("renderers._raycast_kernels", "renderers.raycast_outlines")}
# target kinds whose detector calls numba kernels -> their module
NUMBA_DETECTORS = {"dots": "targets._dot_kernels", "apriltag": "targets._corner_kernels",
                   "chessboard": "targets._corner_kernels"}
# the AprilTag detector's blurred path (targets.tag_edges: it takes it when the image's
# measured blur says so) -> its module; warmed by a job whose camera response blurs
# (BLURRING_STAGES) on its own kind (_render_kinds): the sharp kinds never call it
BLURRED_DETECTORS = {"apriltag": "targets._tag_edge_kernels"}
BLURRING_STAGES = ("psf", "motion_blur")
# calibrators whose fit calls numba kernels -> their module
NUMBA_CALIBRATORS = {"jpl": "harness.calibrators._jpl_kernels",
                     "opencv": "harness.calibrators.opencv_fit"}
# target kinds whose points the calibrators' bias step corrects with numba kernels (the
# corner windows' curvature bias, harness.calibrators.bias.corner_bias) -> their module
BIAS_KERNELS = {"apriltag": "targets._corner_kernels", "chessboard": "targets._corner_kernels"}
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


def _modules_cached(modnames):
    try:
        return all(bool(_numba_cache_index(k)) for m in modnames for k in _entry_points(m))
    except Exception:   # numba's internals changed: warming is the safe choice
        return False


def _kernel_modules():
    return sorted(set(COMPILED_MODULES)
                  | {m for mods in NUMBA_RENDERERS.values() for m in mods}
                  | set(NUMBA_DETECTORS.values()) | set(BLURRED_DETECTORS.values())
                  | set(NUMBA_CALIBRATORS.values()) | set(BIAS_KERNELS.values()))


def load_cached_kernels():
    r'''Load every serial kernel numba's on-disk cache holds for its current source; compile
nothing -> the number of kernel signatures loaded

The fork server of local workers calls it once (harness.executors.local_context's preload),
so that each worker forks with numba's compiler context set up and the kernels in memory
instead of loading them itself on its first job: numba's typing and target registries alone
took 0.45 s of the first job's pose planning in each worker, the detectors' kernels 0.3-0.5 s
of its first detection (paper campaign, idle). Only what is certainly current loads: a
signature in its kernel's cache index (numba's stamp of the kernel's own source), an index
no older than reference_models/kernels.py for the COMPILED_MODULES that carry that file's
code (reference_models.kernels.stale_cache, drop_stale_caches' rule; the warm-up drops the
stale ones later, in the campaign's process; the other modules' caches do not depend on
that file, so its mtime says nothing about them). A kernel missing or stale here is
loaded or compiled by the worker on first call, as without this. Parallel kernels (the ray
caster's bands) are left to the workers: loading one starts numba's thread pool, which a fork does
not carry over. Never raises: numba's private cache API changing costs only the time.'''
    from reference_models.kernels import stale_cache
    n = 0
    try:
        from numba.core.registry import cpu_target
        cpu_target.typing_context.refresh()
        cpu_target.target_context.refresh()
        for modname in _kernel_modules():
            for kernel in _entry_points(modname):
                if kernel.targetoptions.get("parallel") or (
                        modname in COMPILED_MODULES and stale_cache(kernel)):
                    continue
                for key in _numba_cache_index(kernel):
                    sig = key[0]    # (signature, target machine, ...)
                    if sig in kernel.overloads:
                        continue
                    cres = kernel._cache.load_overload(sig, kernel.targetctx)
                    if cres is None:
                        continue
                    # what numba's Dispatcher.compile does with a cache hit
                    kernel._cache_hits[sig] += 1
                    if not cres.objectmode:
                        kernel.targetctx.insert_user_function(cres.entry_point, cres.fndesc,
                                                              [cres.library])
                    kernel.add_overload(cres)
                    n += 1
    except Exception:
        pass
    return n


def kernels_cached(name):
    r'''True when numba's on-disk cache holds the kernels of a renderer or calibrator

name: a renderer ("raycast") or a calibrator ("jpl"); any other name has no kernels.
Reads only numba's cache index (its stamp of the source file), loads no code:
False after a kernel change (of its module or of reference_models.kernels,
whose stale caches it drops), for a new cache directory, or when numba's internals
cannot be read (then warming is the safe choice).
'''
    mods = NUMBA_RENDERERS.get(name) or ((NUMBA_CALIBRATORS[name],)
                                         if name in NUMBA_CALIBRATORS else ())
    if not mods:
        return True
    try:
        if drop_stale_caches():
            return False
    except Exception:
        return False
    return _modules_cached(mods)


def _numba_calibrators(job):
    return [c for c in job.calibrators if c[0] in NUMBA_CALIBRATORS]


def _kind(target_name):
    try:
        return cached_target(target_name).kind
    except Exception:
        return None


def _blurred(job):
    r'''The job's target kind whose blurred detection path its camera response calls
(BLURRED_DETECTORS), or None'''
    kind = _kind(job.target)
    if kind in BLURRED_DETECTORS and any(k in BLURRING_STAGES for k in (job.response or {})):
        return kind
    return None


def _render_kinds(jobs):
    r'''(kind, job) in the order _warm_renders tries them: each (renderer, family, target)
with its jobs from the smallest image up (by job.cost: the cheapest render), then each
(renderer, target) with its largest image first: a detector may take another path, with
other types, for a large image (targets.detect_dots reads one above 4.5 Mpx as float32)'''
    ordered = sorted(jobs, key=lambda j: j.cost)
    # a job whose response blurs an AprilTag grid is its own kind (_blurred): the sharp
    # job of its renderer, family and target does not call the blurred path's kernels
    return ([((j.renderer, j.family, j.target) + (("blurred",) if _blurred(j) else ()), j)
             for j in ordered]
            + [((j.renderer, j.target, "largest"), j) for j in reversed(ordered)])


def _warm_renders(jobs):
    r'''Render, respond and detect one image of each kind of job (_render_kinds; the job's own
settings and first pose) -> (done, failed)'''
    import dataclasses

    from .stages import render_detect_stage
    done, failed, seen = [], {}, set()
    for key, job in _render_kinds(jobs):
        if key in seen:
            continue
        try:
            _, truth = camera_stage(job)
            target = cached_target(job.target)
            Rt = poses_stage(truth, target, 1, job.poses_seed)[0]
            out = render_detect_stage(dataclasses.replace(job, keep_images=False),
                                      truth, target, [Rt])
            seen.add(key)
            done.append("/".join(key))
            failed[key] = []    # the other jobs' failures to warm it no longer matter
            if out.failure is not None:
                failed[key].append(f"{job.key}: {out.failure.stage}: {out.failure.reason}")
        except Exception as e:  # not-applicable family, invisible target: try the next job
            failed.setdefault(key, []).append(f"{job.key}: {failure_reason(e)}")
    if any(j.renderer == "raycast" for j in jobs):
        try:
            from renderers.raycast_outlines import warm_fold_check
            warm_fold_check()   # the renders above may not have needed it
        except Exception as e:
            failed[("raycast", "fold check")] = [f"raycast fold check: {failure_reason(e)}"]
    if any((j.response or {}).get("saturation", {}).get("blooming") for j in jobs):
        try:
            import numpy as np

            from renderers.response import ResponseChain
            ResponseChain.from_config({"saturation": {"blooming": True}}).apply(
                np.full((4, 4), 2.0))
            done.append("response/blooming")
        except Exception as e:
            failed[("response",)] = [f"response/blooming: {failure_reason(e)}"]
    return done, [f for fs in failed.values() for f in fs]


def _warm_fits(jobs):
    r'''Plan each job's poses and fit its numba calibrators, once per (calibrator, family),
to the exact image positions of the target's points in those poses (no image
needed) -> (done, failed)'''
    from targets.centroids import expected_centroids, projected_points

    from .campaign import MODEL_CHOICE, POSE_COUNT
    from .stages import calibrate_stage, observations_from
    done, failed, seen = [], {}, set()
    for job in jobs:
        todo = [c for c in _numba_calibrators(job) if (c[0], job.family) not in seen]
        bias = _bias_kind(job)
        bias = bias if bias and ("bias", bias) not in seen else None
        if not todo and not bias:
            continue
        try:
            _, truth = camera_stage(job)
            target = cached_target(job.target)
            poses = poses_stage(truth, target, job.poses_n, job.poses_seed, job.poses_cover)
            exact = expected_centroids if target.kind == "dots" else projected_points
            obs = observations_from(truth, target, poses,
                                    [exact(truth, target, Rt) for Rt in poses])
        except Exception as e:
            for cal, _, _ in todo:
                failed.setdefault((cal, job.family), []).append(
                    f"{job.key}: {failure_reason(e)}")
            continue
        for cal, model, options in todo:
            options = {k: v for k, v in options.items() if k not in (MODEL_CHOICE, POSE_COUNT)}
            res = calibrate_stage(cal, obs, target, model, truth, options)
            if res.status == "ok":
                seen.add((cal, job.family))
                done.append(f"{cal}/{job.family}")
                failed[(cal, job.family)] = []
            elif res.status == "failed":
                failed.setdefault((cal, job.family), []).append(f"{job.key}/{cal}: {res.reason}")
        if bias:
            from .calibrators.bias import corner_bias
            try:
                corner_bias(truth, target, poses[0], target.points())
                seen.add(("bias", bias))
                done.append(f"bias/{bias}")
            except Exception as e:
                failed.setdefault(("bias", bias), []).append(f"{job.key}: {failure_reason(e)}")
    return done, [f for fs in failed.values() for f in fs]


def _bias_kind(job):
    r'''The job's target kind when a calibrator of the job corrects its points with numba
kernels (BIAS_KERNELS), else None'''
    kind = _kind(job.target)
    return kind if job.calibrators and kind in BIAS_KERNELS else None


def _timed(fn, jobs):
    r'''fn(jobs) -> (done, failed, {"seconds": wall, "cpu": CPU seconds of this process})'''
    t0, c0 = time.perf_counter(), time.process_time()
    done, failed = fn(jobs)
    return done, failed, {"seconds": time.perf_counter() - t0, "cpu": time.process_time() - c0}


def _run_parts(parts, workers):
    r'''Run the (function, jobs) parts, in up to `workers` processes
-> [(done, failed, {"seconds", "cpu"}), ...]'''
    if workers <= 1 or len(parts) <= 1:
        return [_timed(fn, jobs) for fn, jobs in parts]
    from .executors import local_pool
    with local_pool(min(workers, len(parts))) as ex:
        futs = [ex.submit(_timed, fn, jobs) for fn, jobs in parts]
        out = []
        for (fn, _), f in zip(parts, futs, strict=True):
            try:
                out.append(f.result())
            except Exception as e:   # a warm-up process died: the jobs compile for themselves
                out.append(([], [f"{fn.__name__}: {failure_reason(e)}"], None))
        return out


def warm_up(jobs, force=False, workers=2):
    r'''Compile (or load from numba's cache) every kernel the jobs call, in `workers` processes

SYNOPSIS

    info = warm_up(jobs)
    # {"seconds", "renders": ["raycast/CAHV/dots", ...], "fits": ["jpl/CAHV", ...],
    #  "cached": ["raycast", "jpl"], "failed": [...],
    #  "parts": {"renders": {"seconds", "cpu"}, "fits": {...}}}   (the warmed sets' times)
    # force=True: warm even when numba's cache is up to date

The render set (per renderer, model family and target of the jobs, and per
renderer and target the largest image: one image of the job's own settings and
first pose rendered, put through the job's camera response and detected) and
the fit set (per numba calibrator and family: the job's poses planned and the
calibrator fitted to their exact observations; per corner target kind a calibrator
corrects, its bias step once: BIAS_KERNELS) run in two processes at once
(workers=1: one after the other, in this process). numba writes what it compiles
to its cache directory, so worker processes started afterwards load the kernels
instead of each compiling them (after a kernel change that is minutes per worker on a loaded
machine). A set whose kernels are all cached for their source
(kernels_cached; for the render set also the detectors' kernels) is not
warmed: loading them here too would only add the loading time (seconds under
load) before the workers start. Never raises: a job that cannot be warmed
fails later, in its own record.
'''
    t0 = time.perf_counter()
    renderers = sorted({j.renderer for j in jobs if j.renderer in NUMBA_RENDERERS})
    calibrators = sorted({c[0] for j in jobs for c in _numba_calibrators(j)})
    if force and (renderers or calibrators):
        try:
            drop_stale_caches()
        except Exception:  # numba's internals changed: compile anyway
            pass
    cached = [] if force else [n for n in renderers + calibrators if kernels_cached(n)]
    detectors = sorted({NUMBA_DETECTORS[k] for k in map(_kind, {j.target for j in jobs})
                        if k in NUMBA_DETECTORS}
                       | {BLURRED_DETECTORS[k] for k in map(_blurred, jobs) if k})
    if not _modules_cached(detectors):   # the render set runs the detectors
        cached = [c for c in cached if c not in renderers]
    render_jobs = [j for j in jobs if j.renderer in renderers and j.renderer not in cached]
    bias = sorted({BIAS_KERNELS[k] for k in map(_bias_kind, jobs) if k})
    bias_cached = not force and _modules_cached(bias)
    fit_jobs = [j for j in jobs if any(c[0] not in cached for c in _numba_calibrators(j))
                or (_bias_kind(j) and not bias_cached)]
    parts = [(fn, js) for fn, js in ((_warm_renders, render_jobs), (_warm_fits, fit_jobs))
             if js]
    out = {_warm_renders: [], _warm_fits: []}
    failed, parts_time = [], {}
    for (fn, _), (done, bad, spent) in zip(parts, _run_parts(parts, workers), strict=True):
        out[fn] += done
        failed += bad
        parts_time[fn.__name__.removeprefix("_warm_")] = spent
    return {"seconds": time.perf_counter() - t0, "renders": out[_warm_renders],
            "fits": out[_warm_fits], "cached": cached, "failed": sorted(set(failed))[:10],
            "parts": parts_time}

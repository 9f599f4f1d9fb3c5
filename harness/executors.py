r'''Executors: run jobs in local processes or on a Dask cluster, storing records as they end

SYNOPSIS

    from harness.executors import run_jobs

    n_done = run_jobs(jobs, RunStore.open(run_dir), executor="local", workers=2)
    n_done = run_jobs(jobs, store, executor="dask", scheduler="tcp://host:8786")

Jobs are independent; the executor runs them in local processes
(concurrent.futures, forkserver) or on a Dask cluster (--executor dask
--scheduler ADDRESS). Each job's records are stored in the run directory as
soon as the job ends, so an interrupted run resumes with only the missing
jobs. A job travels pickled (harness.jobs.Job is a frozen dataclass) and the
job function by reference (module and name), so it must be a module-level
function (harness.runner.run_job).
'''

import os
import pickle
import shutil
import sys
import uuid
from pathlib import Path

from .job_records import failure_records
from .jobs import RunnerError, slug
from .progress import PROGRESS_DIR, Progress, watch_dir
from .stages import failure_reason
from .warmup import warm_up

EXECUTORS = ("local", "dask")


def _die_with_campaign(pid):
    r'''Worker initializer: end this worker when the campaign's process `pid` ends

Local workers are children of multiprocessing's fork server, and the fork server
lives as long as any of its workers does (each holds its "alive" pipe), so a worker
waiting for its next job would outlive a killed campaign forever. A daemon thread
waits on a pidfd of the campaign's process (Linux >= 5.3; elsewhere it polls the pid
every second) and ends the worker with os._exit: a worker has nothing to save, its
finished jobs' records are already stored by the campaign.'''
    import threading

    def watch():
        try:
            fd = os.pidfd_open(pid)
        except (AttributeError, OSError):
            fd = None
        if fd is not None:
            import select
            select.select([fd], [], [])
        else:
            import time
            while True:
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:
                    pass
                time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="camval-campaign-watch", daemon=True).start()


def local_context():
    r'''The multiprocessing context of local worker processes (the warm-up's too)

forkserver, not fork: the parent may hold threads (the progress bar, BLAS). The
server imports harness.runner and numba once (numba's import, ~0.19 CPU-s, starts no
thread; its parallel kernels' threads start at their first call, in a worker) and loads
the serial kernels numba's disk cache holds (harness._forkserver); each worker forks from
it, and the warm-up's processes and the jobs' workers share it.'''
    import multiprocessing
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["harness.runner", "numba", "harness._forkserver"])
    return ctx


def start_local_workers(executor="local", workers=None):
    r'''Start the fork server of local worker processes now (local_context), so that its
start-up (a Python process importing harness.runner, ~0.2 CPU-s) runs while the caller
prepares the jobs instead of before the first job; nothing for Dask or one worker

The server is multiprocessing's, started once per process: the pool's workers and the
warm-up's fork from it whenever they start.'''
    if executor != "local" or (workers is not None and workers <= 1):
        return
    from multiprocessing import forkserver
    local_context()
    forkserver.ensure_running()


# glibc malloc's settings a user (or a Dask nanny: distributed.nanny.pre-spawn-environ sets
# MALLOC_TRIM_THRESHOLD_) may give a process in its environment; with any of them set, the
# workers' malloc is left as the environment made it (keep_freed_memory)
MALLOC_ENV = ("MALLOC_TOP_PAD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_",
              "MALLOC_MMAP_MAX_")
_M_TOP_PAD, _M_MMAP_THRESHOLD = -2, -3     # glibc's mallopt parameters (malloc.h)
# the worker's top pad: a fixed part and two float64 images of the largest camera (bytes per
# pixel), see worker_top_pad
TOP_PAD_BASE = 256 * 2**20
TOP_PAD_PER_PIXEL = 16


def worker_top_pad(pixels):
    r'''The heap a local worker keeps free above its live memory (glibc's M_TOP_PAD), in bytes,
for jobs whose largest image has `pixels` pixels (None: no setting)

glibc gives freed memory back to the system: a large array is mmapped and unmapped, the
heap's top is trimmed on free. Each detection then faults its arrays' pages in again
(camera 8's near AprilTag pose through the realistic sensor, 1024x1024: 3,500-4,600 minor
faults, a tenth to a fifth of its CPU). With a top pad the heap grows by the pad beyond each request
and keeps the pad when trimmed, so large arrays are carved from the heap's top and their
pages stay mapped for the next one (keep_freed_memory also lets arrays up to 32 MiB come
from the heap). The pad must hold the span of heap a stage spreads its transient arrays
over, not only their sum: bisected with MALLOC_TOP_PAD_ alone (a detection repeated in one
process, /tmp/h-speed/faults.py), the faults vanish from ~160 MiB on a 1024x1024 image
(the arrays numpy allocates there peak at 30 MiB) and from ~320 MiB on 5120x3840 (199
MiB), not monotonically (1,400-1,600 faults left at 64-128 MiB; 900 at 384 MiB on
5120x3840). TOP_PAD_BASE + TOP_PAD_PER_PIXEL x pixels (two float64 images of the largest
camera) keeps a 1.6-1.7x margin over both. The pad is address space: the pages it keeps
are those the worker touched at its peak anyway, so the peak resident memory grows little
(2 workers, the quick campaign's: 235-240 -> 245-247 MiB each; the paper campaign's, pad
556 MiB: 453-458 -> 459-461 MiB). mallopt takes an int: at most 2 GiB - 1.'''
    if not pixels:
        return None
    return int(min(TOP_PAD_BASE + TOP_PAD_PER_PIXEL * int(pixels), 2**31 - 1))


def malloc_environment(environ=None):
    r'''{name: value} of the glibc malloc settings in the environment (MALLOC_ENV, and
GLIBC_TUNABLES where it sets a glibc.malloc.* tunable): a user's, which the workers keep'''
    env = os.environ if environ is None else environ
    out = {k: env[k] for k in MALLOC_ENV if k in env}
    if "glibc.malloc." in env.get("GLIBC_TUNABLES", ""):
        out["GLIBC_TUNABLES"] = env["GLIBC_TUNABLES"]
    return out


def keep_freed_memory(top_pad, environ=None):
    r'''Set this process's glibc malloc top pad (worker_top_pad) -> the pad set, or None:
no pad asked, a malloc setting in the environment (MALLOC_ENV, GLIBC_TUNABLES'
glibc.malloc.*: the user's, kept), or not glibc (no mallopt)

glibc reads MALLOC_TOP_PAD_ at the process's start; mallopt(M_TOP_PAD) sets the same
parameter in a running process (glibc's do_set_top_pad either way), so a worker forked
from the fork server sets it in its initializer: the campaign's own process and its
environment are not changed. Either freezes glibc's dynamic mmap threshold where it is
(128 KiB in a fresh process: every array above it mmapped and unmapped, whatever the pad),
so the threshold is set to the dynamic one's ceiling first.'''
    if not top_pad or malloc_environment(environ):
        return None
    try:
        if not os.confstr("CS_GNU_LIBC_VERSION"):
            return None
        import ctypes
        mallopt = ctypes.CDLL(None).mallopt
    except (AttributeError, OSError, ValueError):
        return None
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    # the dynamic mmap threshold's ceiling, glibc's DEFAULT_MMAP_THRESHOLD_MAX (32 MiB on 64
    # bits): what the threshold rises to anyway once such arrays are freed
    if mallopt(_M_MMAP_THRESHOLD, 4 * 2**20 * ctypes.sizeof(ctypes.c_long)) != 1:
        return None
    return int(top_pad) if mallopt(_M_TOP_PAD, int(top_pad)) == 1 else None


def _init_worker(pid, threads, top_pad=None):
    r'''Worker initializer: end with the campaign (_die_with_campaign), numpy's OpenBLAS
and numba's parallel kernels (the ray caster's bands) on `threads` threads, glibc's malloc
keeping `top_pad` bytes of freed memory (keep_freed_memory; None: as it is)'''
    import numba

    from . import blas
    blas.set_threads(threads)
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    keep_freed_memory(top_pad)
    _die_with_campaign(pid)


def threads_per_worker(workers, cores=None):
    r'''Threads for each of `workers` local workers (numpy's OpenBLAS, numba): the cores
left to each (at least 1). The workers fill the cores with jobs; more threads than that
only compete with the other workers' and wait for each other: OpenBLAS, harness/blas.py;
the ray caster's 6 renders of cameras 1 and 3 (CAHV, CAHVORE, dots and AprilTag) cost
6.61 CPU-s on 2 numba threads against 5.38 on 1 with the cores busy (2026-11-28, load 8-10,
`NUMBA_NUM_THREADS=N uv run --frozen python benchmarks/bench_render.py jobs --cameras 1,3
--families CAHV,CAHVORE`)'''
    cores = cores or len(os.sched_getaffinity(0))
    return max(1, cores // max(1, workers))


def local_pool(workers, top_pad=None):
    r'''A ProcessPoolExecutor of `workers` local processes (local_context) that end when
this process does (_die_with_campaign), each with numpy's OpenBLAS and numba on its share
of the cores (threads_per_worker) and glibc's malloc keeping `top_pad` bytes of freed
memory (keep_freed_memory; None: as it is): the jobs' workers and the warm-up's'''
    import concurrent.futures as cf
    return cf.ProcessPoolExecutor(max_workers=workers, mp_context=local_context(),
                                  initializer=_init_worker,
                                  initargs=(os.getpid(), threads_per_worker(workers), top_pad))


def _local_results(fn, jobs, workers, top_pad=None):
    r'''Yield (job, result or exception) as jobs finish, in local processes (top_pad: their
malloc's, local_pool; one worker runs the jobs in this process, its malloc as it is)'''
    if workers <= 1:
        for job in jobs:
            try:
                yield job, fn(job)
            except Exception as e:
                yield job, e
        return
    import concurrent.futures as cf
    with local_pool(workers, top_pad) as ex:
        futs = {ex.submit(fn, job): job for job in jobs}
        try:
            for fut in cf.as_completed(futs):
                try:
                    yield futs[fut], fut.result()
                except Exception as e:
                    yield futs[fut], e
        except BaseException:
            for f in futs:
                f.cancel()
            raise


def _call_pickled(fn, blob):
    return fn(pickle.loads(blob))


def _dask_results(fn, jobs, scheduler):
    r'''Yield (job, result or exception) as jobs finish on a Dask cluster'''
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise RunnerError("--executor dask needs dask.distributed; install camval's "
                          "dependencies (uv sync)") from None
    import dask.config
    # dask's own connect timeout (30 s unless configured, e.g. by
    # DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT): a loaded machine answers slowly
    timeout = dask.config.get("distributed.comm.timeouts.connect")
    try:
        client = Client(scheduler, timeout=timeout)
    except (OSError, TimeoutError) as e:
        raise RunnerError(f"cannot reach the Dask scheduler at {scheduler!r} within "
                          f"{timeout}: {e}") from None
    try:
        futs = {}
        for i, job in enumerate(jobs):
            # pickled: Dask must not take the Job dataclass apart and rebuild it
            f = client.submit(_call_pickled, fn, pickle.dumps(job), pure=False,
                              key=f"camval-{i}-{slug(job.key)}-{uuid.uuid4().hex[:8]}")
            futs[f] = job
        for fut in as_completed(list(futs)):
            try:
                yield futs[fut], fut.result()
            except Exception as e:
                yield futs[fut], e
    finally:
        _close_client(client)


def _close_client(client):
    r'''Close a Dask client; a slow or failed close (a loaded scheduler) is not an error:
every job's records are stored by then'''
    import dask.config
    from dask.utils import parse_timedelta
    timeout = 4 * parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), "s")
    try:
        client.close(timeout=timeout)
    except (OSError, TimeoutError) as e:
        print(f"camval: the Dask client did not close cleanly ({type(e).__name__}); the "
              f"records are stored", file=sys.stderr)


def run_jobs(jobs, store, fn=None, executor="local", workers=None, scheduler=None,
             progress=True, warm=True, report=None, pixels=None):
    r'''Run jobs, storing each job's records in `store` as it finishes

SYNOPSIS

    n_done = run_jobs(jobs, RunStore.open(run_dir), executor="local", workers=2)

Jobs already stored are skipped (resume). A job whose worker crashed is
stored as failed records (stage "worker") that resume runs again. Largest
jobs are started first, so the slowest ones do not finish last. Returns the
number of jobs run (a job with twins counts each of its cameras).

fn: the function run on each job (None: harness.runner.run_job); in worker
processes or on Dask, a module-level function (it travels by reference).
warm: before starting local worker processes (workers > 1, fn = run_job),
compile every numba kernel of the jobs once (warm_up, on `workers` processes)
so that the workers load them from numba's cache. report: a dict that receives {"warm_up": {...}}.
progress: True (a harness.progress.Progress of its own on stderr), False, or the
campaign's Progress (its "jobs" stage shows the running jobs' stages on a terminal).
pixels: the largest image of the jobs (width x height): local worker processes keep
worker_top_pad(pixels) bytes of freed memory (keep_freed_memory: unless the environment
has a malloc setting; None: their malloc as it is). Dask's workers are not started here:
their malloc is the cluster's (a nanny sets MALLOC_TRIM_THRESHOLD_ by default; a pad is
distributed.nanny.pre-spawn-environ's MALLOC_TOP_PAD_).
'''
    from .runner import run_job  # the job function the runner hands to the executors
    if fn is None:
        fn = run_job
    if executor not in EXECUTORS:
        raise RunnerError(f"unknown executor {executor!r}; known: {', '.join(EXECUTORS)}")
    if executor == "dask" and not scheduler:
        raise RunnerError("--executor dask needs --scheduler ADDRESS (e.g. tcp://host:8786)")
    done = store.done_jobs()
    todo = sorted((j for j in jobs if j.key not in done), key=lambda j: (-j.cost, j.key))
    if workers is None:
        workers = min(len(todo), os.cpu_count() or 1)
    own = not isinstance(progress, Progress)
    bar = Progress(enabled=bool(progress)) if own else progress
    if (warm and executor == "local" and workers > 1 and fn is run_job and todo):
        bar.stage("warm-up")
        info = warm_up(todo, workers=workers)
        if report is not None:
            report["warm_up"] = info
    watch = None
    if bar.rich and executor == "local" and getattr(store, "dir", None) is not None:
        watch = store.dir
        watch_dir(watch)
    bar.stage("jobs", total=len(todo), watch=watch)
    try:
        results = (_dask_results(fn, todo, scheduler) if executor == "dask"
                   else _local_results(fn, todo, workers, worker_top_pad(pixels)))
        for job, out in results:
            members = job.members()
            if isinstance(out, BaseException):
                # the worker died (killed, out of memory): reported, and retried on resume
                recs = [r for m in members
                        for r in failure_records(m, "worker", failure_reason(out))]
            else:
                recs = out["records"]
            for m in members:   # each camera's records under its own job key
                mine = [r for r in recs if r["fullname"].startswith(m.key + "/")]
                final = not isinstance(out, BaseException)
                if not mine:    # never silently done: reported, and run again on resume
                    mine = failure_records(m, "internal", "the job returned no records for "
                                                          f"camera {m.camera_key}")
                    recs = recs + mine
                    final = False
                store.save_job(m.key, mine, final=final)
            statuses = {}
            for r in recs:
                statuses[r["status"]] = statuses.get(r["status"], 0) + 1
            summary = ", ".join(f"{n} {s}" for s, n in sorted(statuses.items()))
            bar.advance(f"{job.key}: {summary}",
                        short=f"{'/'.join(job.key.split('/')[:2])}: {summary}")
    finally:
        if own:
            bar.close()
        if watch is not None:
            shutil.rmtree(Path(watch) / PROGRESS_DIR, ignore_errors=True)
    return sum(1 + len(j.twins) for j in todo)

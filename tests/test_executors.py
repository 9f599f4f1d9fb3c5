r'''Local executor: workers do not outlive the campaign, share the cores, keep freed memory'''

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

# Two workers each sleep 60 s in a job; the parent then dies by SIGKILL (no cleanup of its own)
_CAMPAIGN = '''
from harness.executors import _local_results
import time
for _ in _local_results(time.sleep, [60.0, 60.0, 60.0], 2):
    pass
'''


def _children():
    r'''{pid: ppid} of every process now alive'''
    out = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            out[int(d.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    return out


def _descendants(pid):
    tree = _children()
    found, todo = set(), [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in tree.items() if pp == p]
        found.update(kids)
        todo.extend(kids)
    return found


def _alive(pids):
    alive = set()
    for p in pids:
        try:
            state = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.add(p)
    return alive


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc (Linux)")
def test_workers_end_when_the_campaign_process_is_killed():
    p = subprocess.Popen([sys.executable, "-c", _CAMPAIGN], cwd=ROOT)
    try:
        # the fork server, its two workers (and multiprocessing's resource tracker)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            desc = _descendants(p.pid)
            if len(desc) >= 3:
                break
            time.sleep(0.2)
        time.sleep(1.0)                    # the workers have passed their initializer
        desc = _descendants(p.pid)
        assert len(desc) >= 3, f"workers did not start: {desc}"
        os.kill(p.pid, signal.SIGKILL)
        p.wait(timeout=30)
        # Without the guard the workers sleep out their 60 s job and then wait for the
        # next forever; with it they end as soon as the fork server does (at once)
        deadline = time.monotonic() + 20
        while _alive(desc) and time.monotonic() < deadline:
            time.sleep(0.2)
        left = _alive(desc)
        for q in left:
            os.kill(q, signal.SIGKILL)
        assert not left, f"processes outlived the campaign: {sorted(left)}"
    finally:
        if p.poll() is None:
            p.kill()


def _blas_threads(_):
    from harness import blas
    return blas.threads()


def _numba_threads(_):
    import numba
    return numba.get_num_threads()


def test_workers_share_the_cores_with_numpys_blas_and_numba():
    r'''Each local worker runs numpy's OpenBLAS and numba's parallel kernels on its share of
the cores: 2 workers on 2 cores, one thread each (more only wait for the other worker's,
harness/blas.py, harness.executors.threads_per_worker)'''
    from harness import blas
    from harness.executors import _local_results, threads_per_worker
    assert threads_per_worker(2, cores=2) == 1
    assert threads_per_worker(2, cores=8) == 4
    assert threads_per_worker(4, cores=2) == 1
    want = threads_per_worker(2)
    got = [r for _, r in _local_results(_numba_threads, [0, 1, 2, 3], 2)]
    assert got == [want] * 4
    if blas.threads() is None:
        pytest.skip("numpy's OpenBLAS is not found here (its thread count is not set)")
    got = [r for _, r in _local_results(_blas_threads, [0, 1, 2, 3], 2)]
    assert got == [want] * 4


def test_one_blas_thread_restores_the_thread_count():
    r'''blas.one_thread (the verdict's linear algebra) runs on one thread; the count is
restored after the block'''
    from harness import blas
    n = blas.threads()
    if n is None:
        pytest.skip("numpy's OpenBLAS is not found here (the block is a no-op)")
    with blas.one_thread():
        assert blas.threads() == 1
    assert blas.threads() == n


def _refaults(mib):
    r'''Minor page faults of touching a `mib` MiB array again after freeing one, twice'''
    import resource
    n = mib * 2**20 // 8
    out = []
    for _ in range(2):
        a = np.ones(n)
        del a
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        a = np.ones(n)
        del a
        out.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
    return out


def test_worker_top_pad_grows_with_the_largest_image():
    from harness.executors import TOP_PAD_BASE, worker_top_pad
    assert worker_top_pad(None) is None
    # two float64 images of the largest camera beyond the fixed part; mallopt's int at most
    assert worker_top_pad(1024 * 1024) == TOP_PAD_BASE + 16 * 2**20
    assert worker_top_pad(5120 * 3840) == TOP_PAD_BASE + 16 * 5120 * 3840
    assert worker_top_pad(10**9) == 2**31 - 1


def test_a_malloc_setting_in_the_environment_is_the_users():
    from harness.executors import keep_freed_memory, malloc_environment
    pad = 300 * 2**20
    assert keep_freed_memory(None, environ={}) is None
    # a Dask nanny's default, a user's variable, glibc's tunables: left as they are
    assert keep_freed_memory(pad, environ={"MALLOC_TRIM_THRESHOLD_": "65536"}) is None
    assert keep_freed_memory(pad, environ={"MALLOC_TOP_PAD_": "0"}) is None
    assert keep_freed_memory(pad, environ={"GLIBC_TUNABLES": "glibc.malloc.top_pad=0"}) is None
    assert malloc_environment({"GLIBC_TUNABLES": "glibc.rtld.nns=2", "HOME": "/"}) == {}


@pytest.mark.skipif(not (sys.platform.startswith("linux") and os.confstr("CS_GNU_LIBC_VERSION")),
                    reason="glibc's malloc (Linux)")
def test_local_workers_keep_freed_memory():
    r'''With a top pad each worker's freed arrays stay mapped: an 8 MiB array (2048 pages)
is touched again without page faults. glibc alone hands the first one back (mmapped, then
unmapped) and faults it in again.'''
    from harness.executors import _local_results, malloc_environment, worker_top_pad
    if malloc_environment():
        pytest.skip("a malloc setting in this environment: the workers keep it")
    kept = [r for _, r in _local_results(_refaults, [8] * 4, 2, worker_top_pad(1024 * 1024))]
    assert all(f < 20 for r in kept for f in r), kept
    plain = [r for _, r in _local_results(_refaults, [8] * 4, 2)]
    assert max(f for r in plain for f in r) > 200, plain

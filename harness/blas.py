r'''numpy's OpenBLAS thread count: one home for the campaign's workers and the verdict

SYNOPSIS

    from harness import blas
    blas.set_threads(1)          # this process's numpy linear algebra on one thread
    with blas.one_thread():      # one thread inside the block, the count restored after
        np.linalg.eigh(S)

numpy's bundled OpenBLAS starts as many threads as the machine has cores in every
process. A campaign's local workers already fill the cores (one job each), so in each
worker OpenBLAS's threads compete with the other worker's, and wait for each other on
small matrices: a 48 x 48 eigh took 0.3 ms on one thread and 0.2-0.4 s on two with both
cores busy (2026-11-25, load 11), a (77k,3) x (3,3) product 2 ms against 33 ms CPU (load
15). The paper campaign (2 workers, 2 cores, 2026-11-28, idle) with one OpenBLAS thread per
worker: 71.8 s (harness.executors' setting) and 68.1 s (OPENBLAS_NUM_THREADS=1) against
73.9 s, every record bit for bit the same (benchmarks/bench_fits.py diff); a few percent,
about the size of the run-to-run noise. Where numpy's OpenBLAS is not found (another
BLAS), everything here is a no-op.
'''

import numpy as np

_LIB = False        # not looked up yet; then None (not found) or (get, set)


def _openblas():
    r'''(get_num_threads, set_num_threads) of numpy's bundled OpenBLAS, or None'''
    global _LIB
    if _LIB is False:
        import ctypes
        import glob
        import os
        _LIB = None
        libs = os.path.join(os.path.dirname(os.path.dirname(np.__file__)), "numpy.libs")
        for path in sorted(glob.glob(os.path.join(libs, "lib*openblas*.so*"))):
            try:
                lib = ctypes.CDLL(path)     # the copy numpy loaded (same path: same handle)
            except OSError:
                continue
            for suffix in ("64_", ""):
                for pre in ("scipy_openblas", "openblas"):
                    get = getattr(lib, f"{pre}_get_num_threads{suffix}", None)
                    put = getattr(lib, f"{pre}_set_num_threads{suffix}", None)
                    if get is not None and put is not None:
                        _LIB = (get, put)
                        return _LIB
    return _LIB


def threads():
    r'''numpy's OpenBLAS thread count, or None where it is not found'''
    lib = _openblas()
    return None if lib is None else int(lib[0]())


def set_threads(n):
    r'''Set numpy's OpenBLAS thread count to n (>= 1); the count before, or None'''
    lib = _openblas()
    if lib is None:
        return None
    before = int(lib[0]())
    lib[1](max(1, int(n)))
    return before


class one_thread:
    r'''numpy's OpenBLAS on one thread inside the block, the count restored after'''

    def __enter__(self):
        self.before = set_threads(1)
        return self

    def __exit__(self, *exc):
        if self.before is not None:
            set_threads(self.before)
        return False

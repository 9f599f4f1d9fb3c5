r'''Imported once by the fork server of local workers (harness.executors.local_context)

Its import loads numba's cached kernels into the server (harness.warmup.load_cached_kernels),
so that every worker forked from it starts with them in memory.'''

from .warmup import load_cached_kernels

LOADED = load_cached_kernels()

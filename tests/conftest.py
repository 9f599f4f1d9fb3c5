r'''Shared fixtures: the camera catalogue and a parametrisation over its 33 models

    def test_x(catalogue): ...          # the packaged catalogue (session-wide)
    def test_y(catalogue_entry): ...    # once per camera (22 slots + 11 extras);
        m = catalogue_entry.model       # test ids are the keys ("15", "SuperCam")

CATALOGUE_KEYS lists the keys for parametrising by hand; SOURCES_DIR holds the
public source files the catalogue was copied from (PDS3 labels, M2020 JSON).
'''

import os
import sys
from pathlib import Path

import pytest

from reference_models.catalogue import load_catalogue

SOURCES_DIR = Path(__file__).parent / "data" / "catalogue_sources"

_CATALOGUE = load_catalogue()
CATALOGUE_KEYS = _CATALOGUE.keys()


@pytest.fixture(scope="session")
def catalogue():
    return _CATALOGUE


@pytest.fixture(params=CATALOGUE_KEYS, ids=CATALOGUE_KEYS)
def catalogue_entry(request):
    return _CATALOGUE.get(request.param)


# The test process ends with os._exit once pytest is done with it. A whole-suite run
# (in-process mrcal, pycolmap, OpenCV and many numba compilations) aborted AFTER every
# test had passed and pytest had printed its summary: glibc's "corrupted size vs.
# prev_size" inside llvmlite's LLVMContext destructor, run by exit() (gdb backtrace in
# the session notes). Smaller subsets of the same tests exit cleanly, and numba's kernels
# run with NUMBA_BOUNDSCHECK=1 found no out-of-bounds access. Moving OSMesa (Mesa's LLVM)
# into a worker process did not remove it: a whole-suite run with OSMesa out of process
# still ended "corrupted size vs. prev_size", status 134, after 1424 passed (fresh clone,
# 2026-11-25). Until the source is found, skip the C++ static destructors so the run's
# status is pytest's own (CAMVAL_TEST_NORMAL_EXIT=1 exits normally, to hunt it).
_EXIT_STATUS = []


def pytest_sessionfinish(session, exitstatus):
    _EXIT_STATUS.append(int(exitstatus))


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    if _EXIT_STATUS and os.environ.get("CAMVAL_TEST_NORMAL_EXIT") != "1":
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_EXIT_STATUS[-1])

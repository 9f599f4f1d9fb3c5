r'''Shared fixtures: the camera catalogue and a parametrisation over its 33 models

    def test_x(catalogue): ...          # the packaged catalogue (session-wide)
    def test_y(catalogue_entry): ...    # once per camera (22 slots + 11 extras);
        m = catalogue_entry.model       # test ids are the keys ("15", "SuperCam")

CATALOGUE_KEYS lists the keys for parametrising by hand; SOURCES_DIR holds the
public source files the catalogue was copied from (PDS3 labels, M2020 JSON).
'''

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

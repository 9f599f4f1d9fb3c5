r'''The calibrator registry: lazy built-ins, plugins of the entry-point group "camval.calibrators"

The plugin is a real installed distribution as importlib.metadata sees one: a
*.dist-info directory with METADATA and entry_points.txt on sys.path, and the
module it names (as tests/test_plugins.py does for renderers).
'''

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from synthetic import catalogue_models, default_target, exact_observations, synthetic_poses

from harness.calibrators import (
    BUILTIN_CALIBRATORS,
    ENTRY_POINT_GROUP,
    Calibrator,
    CalibratorError,
    calibrate,
    calibrator_module,
    known_calibrators,
    models_of,
    uses_world_frame,
)
from harness.calibrators.base import UnknownCalibratorError
from harness.campaign import CampaignError, parse_campaign

ROOT = Path(__file__).resolve().parent.parent
TARGET = default_target()

PLUGIN_MODULE = '''
from harness.calibrators import jpl_fit

NAME = "wrapped_jpl"
LIBRARY = "scipy"
MODELS = ("CAHV", "CAHVOR")


def library_version():
    return "camval-test-calibrator 0.1 over " + jpl_fit.library_version()


def canonical_model(name):
    return jpl_fit.canonical_model(name)


def fit(obs, target, model_name, truth=None, **options):
    result = jpl_fit.fit(obs, target, model_name, truth=truth, **options)
    return result.replace(calibrator=NAME, library_version=library_version())


class NotACalibrator:
    NAME = "broken"
'''


@pytest.fixture
def plugin_on_path(tmp_path, monkeypatch):
    (tmp_path / "camval_test_calibrator.py").write_text(PLUGIN_MODULE)
    info = tmp_path / "camval_test_calibrator-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: camval-test-calibrator\n"
                                   "Version: 0.1\n")
    (info / "entry_points.txt").write_text(
        f"[{ENTRY_POINT_GROUP}]\nwrapped_jpl = camval_test_calibrator\n"
        "broken = camval_test_calibrator:NotACalibrator\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop("camval_test_calibrator", None)


def test_the_built_in_calibrators_have_the_calibrator_shape():
    assert tuple(known_calibrators()) == ("jpl", "mrcal", "opencv", "colmap")
    for name in BUILTIN_CALIBRATORS:
        cal = calibrator_module(name)
        assert isinstance(cal, Calibrator), name
        assert cal.NAME == name
        assert known_calibrators()[name] == f"built-in ({BUILTIN_CALIBRATORS[name]})"


def test_listing_the_calibrators_imports_none_of_them():
    code = ("import sys, harness.calibrators as hc; names = hc.known_calibrators(); "
            "print(sorted(m for m in sys.modules if m.endswith('_fit')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, timeout=120, check=True)
    assert out.stdout.strip() == "[]"


def test_an_unknown_name_lists_the_known_calibrators():
    with pytest.raises(UnknownCalibratorError,
                       match=r"unknown calibrator 'bouguet'; known calibrators: "
                             r"colmap, jpl, mrcal, opencv$"):
        calibrator_module("bouguet")
    with pytest.raises(CalibratorError, match="known calibrators: colmap, jpl"):
        calibrate("bouguet", None, None, "CAHV")


def test_plugin_is_listed_beside_the_built_in_calibrators(plugin_on_path):
    known = known_calibrators()
    assert known["jpl"].startswith("built-in")
    assert known["wrapped_jpl"] == ("plugin (camval_test_calibrator, "
                                    "package camval-test-calibrator)")
    assert models_of("wrapped_jpl") == ("CAHV", "CAHVOR")
    # a plugin that does not say is taken to read the world frame
    assert uses_world_frame("wrapped_jpl", {})


def test_plugin_fits_exactly_what_its_library_fits(plugin_on_path):
    truth = dict(catalogue_models())["15"]
    obs = exact_observations(truth, TARGET, synthetic_poses(truth, TARGET), centroids=True)
    a = calibrate("wrapped_jpl", obs, TARGET, "cahvor", truth=truth)
    b = calibrate("jpl", obs, TARGET, "CAHVOR", truth=truth)
    assert a.ok, a.reason
    assert (a.calibrator, a.library, a.model_name) == ("wrapped_jpl", "scipy", "CAHVOR")
    assert a.library_version.startswith("camval-test-calibrator 0.1 over scipy")
    # the same code on the same data in the same process: the same numbers
    np.testing.assert_array_equal(a.residuals, b.residuals)
    for p in "CAHVOR":
        np.testing.assert_array_equal(getattr(a.model, p), getattr(b.model, p))


def test_a_model_the_plugin_does_not_fit_is_not_applicable(plugin_on_path):
    truth = dict(catalogue_models())["15"]
    obs = exact_observations(truth, TARGET, synthetic_poses(truth, TARGET))
    r = calibrate("wrapped_jpl", obs, TARGET, "CAHVORE", truth=truth)
    assert r.status == "not-applicable"
    assert r.reason == "wrapped_jpl cannot fit a 'CAHVORE' model; it fits CAHV, CAHVOR"


def test_a_plugin_without_the_calibrator_shape_says_what_it_lacks(plugin_on_path):
    with pytest.raises(CalibratorError, match=r"calibrator 'broken' \(camval_test_calibrator:"
                                              r"NotACalibrator\) is not a calibrator: it has "
                                              r"no LIBRARY, MODELS, library_version, fit"):
        calibrator_module("broken")


def test_without_the_plugin_the_name_is_unknown():
    assert "wrapped_jpl" not in known_calibrators()
    with pytest.raises(UnknownCalibratorError, match="known calibrators: colmap, jpl"):
        calibrator_module("wrapped_jpl")


def _campaign(calibrator):
    return parse_campaign({"name": "plugin", "cameras": [15], "models": ["CAHV"],
                           "calibrator": [calibrator]})


def test_campaigns_validate_plugin_names_and_models_through_the_registry(plugin_on_path):
    _campaign({"name": "wrapped_jpl", "models": ["family", "cahvor"]}).validate()
    with pytest.raises(CampaignError, match=r"calibrator\[0\]\.models: calibrator "
                                            r"'wrapped_jpl' has no model 'CAHVORE'; its "
                                            r"models: family, CAHV, CAHVOR"):
        _campaign({"name": "wrapped_jpl", "models": ["CAHVORE"]}).validate()
    with pytest.raises(CampaignError, match=r"calibrator\[0\]\.name: calibrator 'broken'.* "
                                            r"is not a calibrator"):
        _campaign({"name": "broken"}).validate()
    with pytest.raises(CampaignError, match=r"unknown calibrator 'bouguet'; known "
                                            r"calibrators: broken, colmap, jpl, mrcal, "
                                            r"opencv, wrapped_jpl"):
        _campaign({"name": "bouguet"}).validate()


def campaign_record(calibrator):
    import tempfile

    from harness.runner import run_campaign

    doc = {"name": "same-records", "cameras": [17], "models": ["CAHV"], "targets": ["dots"],
           "poses": {"n": 3, "seed": 0}, "renderer": [{"name": "raycast", "spp": 4}],
           "calibrator": [{"name": calibrator}]}
    run = run_campaign(parse_campaign(doc), tempfile.mkdtemp(prefix="camval-test-"),
                       progress=False, workers=1)
    (record,) = run["records"].values()
    return record


@pytest.mark.slow
def test_a_campaign_runs_the_plugin_as_it_runs_its_library(plugin_on_path):
    a = campaign_record("wrapped_jpl")
    b = campaign_record("jpl")
    assert a["status"] == "ok", a.get("reason")
    assert a["fullname"] != b["fullname"]
    for field in ("status", "residuals", "detections"):
        assert a[field] == b[field], field

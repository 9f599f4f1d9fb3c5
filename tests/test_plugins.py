r'''A renderer package registered under the entry-point group "camval.renderers"

The plugin is a real installed distribution as importlib.metadata sees one: a
*.dist-info directory with METADATA and entry_points.txt on sys.path, and the
module it names.
'''

import numpy as np
import pytest
from render_checks import board_pose, grid_board, small_model

from renderers.base import (
    ENTRY_POINT_GROUP,
    RenderSettings,
    UnknownRendererError,
    get_renderer,
    known_renderers,
)

PLUGIN_MODULE = '''
from renderers.raycast import RaycastRenderer


class WrappedRaycast:
    name = "wrapped_raycast"

    def __init__(self, **options):
        self.inner = RaycastRenderer(**options)

    def version(self):
        return "camval-test-plugin 0.1 over " + self.inner.version()

    def render(self, model, scene, Rt_cam_board, settings=None):
        result = self.inner.render(model, scene, Rt_cam_board, settings)
        result.metadata["renderer"] = self.name
        return result
'''


@pytest.fixture
def plugin_on_path(tmp_path, monkeypatch):
    (tmp_path / "camval_test_plugin.py").write_text(PLUGIN_MODULE)
    info = tmp_path / "camval_test_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: camval-test-plugin\n"
                                   "Version: 0.1\n")
    (info / "entry_points.txt").write_text(
        f"[{ENTRY_POINT_GROUP}]\nwrapped_raycast = camval_test_plugin:WrappedRaycast\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    import sys
    sys.modules.pop("camval_test_plugin", None)


def test_plugin_is_listed_beside_the_built_in_renderers(plugin_on_path):
    known = known_renderers()
    assert "raycast" in known and known["raycast"].startswith("built-in")
    assert known["wrapped_raycast"] == ("plugin (camval_test_plugin:WrappedRaycast, "
                                        "package camval-test-plugin)")


def test_plugin_renders_exactly_what_raycast_renders(plugin_on_path):
    m = small_model("CAHVOR", W=128, H=96, f=125.0)
    pat, _ = grid_board()
    settings = RenderSettings(spp=4)
    plugin = get_renderer("wrapped_raycast")
    a = plugin.render(m, pat, board_pose(), settings)
    b = get_renderer("raycast").render(m, pat, board_pose(), settings)
    assert a.metadata["renderer"] == "wrapped_raycast"
    assert plugin.version().startswith("camval-test-plugin 0.1")
    np.testing.assert_array_equal(a.image, b.image)


def test_without_the_plugin_the_name_is_unknown():
    assert "wrapped_raycast" not in known_renderers()
    with pytest.raises(UnknownRendererError, match="known renderers: .*raycast"):
        get_renderer("wrapped_raycast")


SAME_FIELDS = ("status", "params", "projection", "residuals", "detections")


def campaign_records(renderer):
    import tempfile

    from harness.campaign import parse_campaign
    from harness.runner import run_campaign

    doc = {"name": "same-records", "cameras": [17], "models": ["CAHV"], "targets": ["dots"],
           "poses": {"n": 3, "seed": 0}, "renderer": [dict(renderer, spp=4)],
           "calibrator": [{"name": "jpl"}]}
    run = run_campaign(parse_campaign(doc), tempfile.mkdtemp(prefix="camval-test-"),
                       progress=False, workers=1)
    (record,) = run["records"].values()
    return record


@pytest.mark.slow
def test_plugin_gives_the_same_records_as_the_built_in_adapter(plugin_on_path):
    a = campaign_records({"name": "wrapped_raycast"})
    b = campaign_records({"name": "raycast"})
    assert a["status"] == "ok"
    assert a["fullname"] != b["fullname"]
    for field in SAME_FIELDS:
        assert a[field] == b[field], field

import os
import sys

import numpy as np
import pytest
from render_checks import board_pose, grid_board, small_model

from renderers.base import RendererError, RenderSettings, get_renderer
from renderers.command import (
    CommandRenderer,
    RequestError,
    pattern_from_dict,
    pattern_to_dict,
    read_request,
    write_request,
)
from targets.pattern import Pattern

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLE = [sys.executable, os.path.join(ROOT, "examples", "external_renderer.py")]


def _script(tmp_path, body):
    path = tmp_path / "renderer.py"
    path.write_text("import sys, json, os\nimport numpy as np\n"
                    "req = json.load(open(sys.argv[1]))\n"
                    "out = os.path.join(os.path.dirname(sys.argv[1]), req['output'])\n" + body)
    return [sys.executable, str(path)]


def test_request_round_trip(tmp_path):
    m = small_model("CAHVORE")
    cells = np.array([[0.2, np.nan], [np.nan, 0.8]])
    pat = Pattern(extent=(-0.2, 0.2, -0.1, 0.1), board_value=0.9, background_value=0.1,
                  cells=cells, cell_origin=(-0.1, -0.1), cell_size=0.1,
                  circles=np.array([[0.05, 0.02, 0.01]]), circle_value=0.3)
    Rt = board_pose(15, 1.1)
    path = write_request(tmp_path, m, pat, Rt, RenderSettings(spp=3, adaptive=False,
                                                             options={"x": 1}), "npy")
    req = read_request(path)
    assert sorted(os.listdir(tmp_path)) == ["camera.cahvore", "request.json", "scene.json"]
    p = np.array([[0.1, -0.05, 1.2], [-0.3, 0.2, 2.0]])
    np.testing.assert_allclose(req.model.project(p), m.project(p), atol=1e-12)
    np.testing.assert_array_equal(req.Rt_cam_board, Rt)
    assert req.settings == RenderSettings(spp=3, adaptive=False, options={"x": 1})
    assert req.output == os.path.join(str(tmp_path), "image.npy")
    x, y = np.meshgrid(np.linspace(-0.25, 0.25, 51), np.linspace(-0.15, 0.15, 31))
    np.testing.assert_array_equal(req.pattern.albedo(x, y), pat.albedo(x, y))
    assert pattern_to_dict(pattern_from_dict(pattern_to_dict(pat))) == pattern_to_dict(pat)


def test_read_request_rejects_other_files(tmp_path):
    (tmp_path / "request.json").write_text('{"protocol": "something-else", "version": 1}')
    with pytest.raises(RequestError, match="not a camval-render-request request"):
        read_request(tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("output_format,tolerance", [("npy", 0.0), ("png16", 0.5 / 65535)])
def test_external_example_renders_what_raycast_renders(output_format, tolerance):
    m = small_model("CAHVORE", W=128, H=96, f=125.0)
    pat, _ = grid_board()
    Rt = board_pose(20, 1.0)
    settings = RenderSettings(spp=4)
    ext = get_renderer("command", command=EXAMPLE, output_format=output_format)
    a = ext.render(m, pat, Rt, settings)
    b = get_renderer("raycast").render(m, pat, Rt, settings)
    assert a.image.shape == (96, 128) and a.image.dtype == np.float32
    assert np.abs(a.image.astype(float) - b.image).max() <= tolerance + 1e-9
    assert a.metadata["renderer"] == "command"


def test_placeholder_and_npy_output(tmp_path):
    cmd = _script(tmp_path, "np.save(out, np.full((req['height'], req['width']), 0.25, "
                            "np.float32))\n")
    r = CommandRenderer(command=cmd[:1] + ["-X", "utf8"] + cmd[1:] + ["{request}"],
                        output_format="npy")
    res = r.render(small_model("CAHV", W=32, H=24, f=30.0), grid_board()[0], board_pose(),
                   RenderSettings(spp=1))
    assert res.image.shape == (24, 32) and np.all(res.image == 0.25)


def test_failures_are_renderer_errors_with_the_stderr_tail(tmp_path):
    m = small_model("CAHV", W=32, H=24, f=30.0)
    pat, _ = grid_board()

    def run(body, **kw):
        return CommandRenderer(command=_script(tmp_path, body), **kw).render(
            m, pat, board_pose(), RenderSettings(spp=1))

    with pytest.raises(RendererError, match=r"exit 3[\s\S]*the lens cap is on"):
        run("print('the lens cap is on', file=sys.stderr); sys.exit(3)\n")
    with pytest.raises(RendererError, match="wrote no image"):
        run("pass\n")
    with pytest.raises(RendererError, match=r"shape \(2, 2\); expected"):
        run("np.save(out, np.zeros((2, 2), np.float32))\n", output_format="npy")
    with pytest.raises(RendererError, match="outside"):
        run("np.save(out, np.full((24, 32), 2.0, np.float32))\n", output_format="npy")
    with pytest.raises(RendererError, match="16-bit PNG"):
        run("open(out, 'w').write('not an image')\n")
    with pytest.raises(RendererError, match="timed out"):
        run("import time; time.sleep(30)\n", timeout=1)


def test_command_given_per_render_as_campaigns_do(tmp_path):
    # campaigns construct renderers by name without arguments and pass options
    cmd = _script(tmp_path, "assert req['options'] == {'quality': 'high'}, req['options']\n"
                            "np.save(out, np.full((req['height'], req['width']), 0.5, "
                            "np.float32))\n")
    r = get_renderer("command")
    m = small_model("CAHV", W=32, H=24, f=30.0)
    res = r.render(m, grid_board()[0], board_pose(), RenderSettings(
        spp=1, options={"command": cmd, "output_format": "npy", "quality": "high"}))
    assert np.all(res.image == 0.5) and res.metadata["command"] == cmd
    with pytest.raises(RendererError, match="needs a command"):
        r.render(m, grid_board()[0], board_pose(), RenderSettings(spp=1))


def test_bad_construction():
    with pytest.raises(RendererError, match="needs command"):
        CommandRenderer(command=[])
    with pytest.raises(RendererError, match="not found"):
        CommandRenderer(command=["no-such-renderer-program"])
    with pytest.raises(RendererError, match="output format"):
        CommandRenderer(command=[sys.executable], output_format="exr")


@pytest.mark.slow
def test_external_example_gives_the_same_records_as_the_built_in_adapter(tmp_path):
    from harness.campaign import parse_campaign
    from harness.runner import run_campaign

    def record(renderer, where):
        doc = {"name": "same-records", "cameras": [17], "models": ["CAHV"],
               "targets": ["dots"], "poses": {"n": 3, "seed": 0},
               "renderer": [dict(renderer, spp=4)], "calibrator": [{"name": "jpl"}]}
        run = run_campaign(parse_campaign(doc), tmp_path / where, progress=False, workers=1)
        (r,) = run["records"].values()
        return r

    ext = record({"name": "command", "setup": {"command": EXAMPLE, "output_format": "npy"}},
                 "command")
    ref = record({"name": "raycast"}, "raycast")
    assert ext["status"] == "ok", ext.get("reason")
    # the ray caster's default coverage is named in its fullnames (renderers.base.DEFAULT_OPTIONS);
    # the example command renders through it with the same default, unnamed
    assert ext["fullname"] == ref["fullname"].replace("/raycast[", "/command[").replace(
        ",coverage=area", "")
    assert ext["settings"]["setup"]["command"] == EXAMPLE
    for field in ("status", "params", "projection", "residuals", "detections"):
        assert ext[field] == ref[field], field

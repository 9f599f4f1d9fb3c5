r'''The command renderer's request modes: rays (camval unprojects, the program looks up
what each ray sees; also a renderer written in C) and pinhole (camval's area-sampled warp)'''

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from render_checks import board_pose, grid_board, small_model

from reference_models.cahvore import CAHV, CAHVORE
from renderers.base import RendererError, RendererNotApplicable, RenderSettings, get_renderer
from renderers.command_modes import area_samples, bands, read_values, sample_rays
from renderers.warp import PinholeWarp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLE = [sys.executable, os.path.join(ROOT, "examples", "external_renderer.py")]
C_SOURCE = os.path.join(ROOT, "examples", "rays_renderer.c")
CC = shutil.which("cc") or shutil.which("gcc")


@pytest.fixture(scope="module")
def c_renderer(tmp_path_factory):
    if CC is None:
        pytest.skip("no C compiler (cc, gcc) on this machine")
    exe = tmp_path_factory.mktemp("c") / "rays_renderer"
    out = subprocess.run([CC, "-O2", "-Wall", "-Werror", "-o", str(exe), C_SOURCE, "-lm"],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return str(exe)


def _full(model, pattern, Rt, K):
    # rays mode sends K x K point samples per pixel: the ray caster's point sampling (its
    # default, area coverage, integrates edge pixels instead)
    return get_renderer("raycast").render(
        model, pattern, Rt,
        RenderSettings(spp=K, adaptive=False, options={"coverage": "point"})).image


def test_sample_rays_are_the_model_rays_in_the_camera_frame():
    m = small_model("CAHVORE", W=8, H=6, f=10.0)
    K = 3
    o, v = sample_rays(m, K, 2, 4)
    assert v.shape == (2 * 8 * 9, 3) and o.shape == (2 * 8 * 9, 3)
    # sample (i, j) = (2, 1) of pixel (ix, iy) = (5, 3): index ((3-2)*8 + 5)*9 + 1*3 + 2
    q = np.array([5 + (2.5 / 3 - 0.5), 3 + (1.5 / 3 - 0.5)])
    o_ref, v_ref = m.unproject(q)
    Rt = m.Rt_ref_cam()
    k = ((3 - 2) * 8 + 5) * 9 + 1 * 3 + 2
    # the ray caster's compiled Newton solve and model.unproject's agree to their
    # tolerance (1e-15 relative steps), a few ulps of a unit vector
    np.testing.assert_allclose(v[k], v_ref @ Rt[:3], atol=1e-13)
    np.testing.assert_allclose(o[k], (o_ref - Rt[3]) @ Rt[:3], atol=1e-13)
    # a central camera: one origin
    o, v = sample_rays(small_model("CAHVOR", W=8, H=6, f=10.0), K, 0, 6)
    assert o.shape == (1, 3) and not o.any() and v.shape == (6 * 8 * 9, 3)
    assert bands(small_model("CAHV", W=100, H=50), 4, max_rays=100 * 16 * 7) == [
        (0, 7), (7, 14), (14, 21), (21, 28), (28, 35), (35, 42), (42, 49), (49, 50)]


def test_values_per_ray_or_per_pixel(tmp_path):
    p = str(tmp_path / "values.npy")
    np.save(p, np.arange(2 * 3 * 4, dtype=np.float32) / 24)
    np.testing.assert_allclose(read_values(p, 24, 2, 3, 2),
                               (np.arange(24).reshape(2, 3, 4).mean(-1)) / 24)
    np.save(p, np.full((2, 3), 0.5, np.float32))
    assert np.all(read_values(p, 24, 2, 3, 2) == 0.5)
    np.save(p, np.zeros(5, np.float32))
    with pytest.raises(RendererError, match="has 5 values; expected one per ray"):
        read_values(p, 24, 2, 3, 2)


@pytest.mark.parametrize("family", ["CAHVOR", "CAHVORE"])
def test_rays_mode_in_python_gives_the_ray_casters_image(family):
    m = small_model(family, W=96, H=64, f=90.0)
    pat, _ = grid_board()
    Rt = board_pose(20, 1.0)
    r = get_renderer("command", command=EXAMPLE, mode="rays", persistent=True,
                     max_rays=96 * 16 * 10)
    try:
        a = r.render(m, pat, Rt, RenderSettings(spp=4))
    finally:
        r.close()
    assert a.metadata["rays"]["bands"] == 7
    # the same samples, looked up in the same pattern: the same image (the float32
    # directions move a board point by < 1e-7 of its range; no sample here changes side)
    np.testing.assert_array_equal(a.image, _full(m, pat, Rt, 4))


@pytest.mark.parametrize("persistent", [False, True])
def test_a_renderer_written_in_c_in_rays_mode(c_renderer, persistent):
    m = small_model("CAHVORE", W=96, H=64, f=90.0)
    pat, _ = grid_board()
    Rt = board_pose(25, 0.9)
    K = 4
    r = get_renderer("command", command=[c_renderer], mode="rays", persistent=persistent)
    try:
        a = r.render(m, pat, Rt, RenderSettings(spp=K))
        ref = _full(m, pat, Rt, K)
        # within the sampling difference: a sample on the other side of an edge moves its
        # pixel by (albedo step) / K^2 at most
        d = np.abs(a.image.astype(np.float64) - ref)
        assert d.max() <= 1.0 / K**2 + 1e-6 and np.mean(d > 1e-6) < 0.01
        # it declines what it cannot do, with its reason
        with pytest.raises(RendererNotApplicable, match='renders only "rays" requests'):
            r.render(m, pat, Rt, RenderSettings(spp=1, options={"mode": "image"}))
    finally:
        r.close()


def test_pinhole_mode_records_the_warps_share():
    m = small_model("CAHVOR", W=96, H=64, f=90.0)
    pat, _ = grid_board()
    Rt = board_pose(20, 1.0)
    r = get_renderer("command", command=EXAMPLE, mode="pinhole", output_format="npy",
                     persistent=True)
    try:
        a = r.render(m, pat, Rt, RenderSettings(spp=4))
    finally:
        r.close()
    pin = a.metadata["warp"]["pinhole"]
    assert pin["width"] > 96 * 2 - 1
    assert a.metadata["warp"]["samples"] == area_samples(PinholeWarp.for_model(m, scale=2.0))
    # the program renders the pinhole exactly, so the whole difference from the exact
    # image is the warp's, and the recorded share is all of it
    exact = get_renderer("raycast").render(m, pat, Rt, RenderSettings(spp=4)).image
    d = a.image.astype(np.float64) - exact
    assert a.metadata["warp_rms"] == pytest.approx(np.sqrt(np.mean(d * d)), rel=1e-6)
    assert a.metadata["warp_max"] == pytest.approx(np.abs(d).max(), rel=1e-6)
    assert 0 < a.metadata["warp_rms"] < 0.05


def test_area_samples_cover_each_pixels_footprint_in_the_pinhole():
    # a CAHV with square pixels is a pinhole: the warp's pinhole is exactly `scale` times
    # finer everywhere, so scale x scale samples integrate a model pixel
    m = small_model("CAHV", W=96, H=64, f=90.0)
    assert [area_samples(PinholeWarp.for_model(m, scale=s)) for s in (1.0, 2.0, 3.0)] == [1, 2, 3]
    # non-square pixels (Vs = 1.5 Hs): the pinhole follows the finer axis, the other is
    # 1.5 times coarser, so a model pixel spans 1.5 x scale pinhole pixels along it
    A = np.array([0.0, 0.0, 1.0])
    m = CAHV(C=[0, 0, 0], A=A, H=[90, 0, 48], V=[0, 135, 32], width=96, height=64)
    assert area_samples(PinholeWarp.for_model(m, scale=2.0)) == 3
    # a fisheye: the edge pixels cover many more pinhole pixels than the centre ones
    assert area_samples(PinholeWarp.for_model(small_model("CAHVORE", W=96, H=64, f=40.0),
                                              scale=2.0)) > 2


def test_pinhole_mode_declines_a_field_of_view_no_pinhole_covers():
    # a fisheye (linearity 0: chi = theta) whose corners see 2.5 rad off axis
    A = np.array([0.0, 0.0, 1.0])
    m = CAHVORE(C=[0, 0, 0], A=A, H=[30, 0, 64], V=[0, 30, 48], O=A, R=[0, 0, 0],
                E=[0, 0, 0], model_type=2, width=128, height=96)
    r = get_renderer("command", command=EXAMPLE, mode="pinhole")
    with pytest.raises(RendererNotApplicable):
        r.render(m, grid_board()[0], board_pose(), RenderSettings(spp=1))


@pytest.mark.slow
def test_c_renderer_records_equal_the_ray_casters(c_renderer, tmp_path):
    from harness.campaign import parse_campaign
    from harness.runner import run_campaign

    def record(renderer, where):
        doc = {"name": "c", "cameras": [17], "models": ["CAHVORE"], "targets": ["dots"],
               "poses": {"n": 3, "seed": 0},
               "renderer": [dict(renderer, spp=4, adaptive=False)],
               "calibrator": [{"name": "jpl"}]}
        run = run_campaign(parse_campaign(doc), tmp_path / where, progress=False, workers=1)
        (r,) = run["records"].values()
        return r

    c = record({"name": "command", "label": "c-rays",
                "setup": {"command": [c_renderer], "mode": "rays", "persistent": True}}, "c")
    # rays mode point-samples: the ray caster's point sampling is the reference
    ref = record({"name": "raycast", "options": {"coverage": "point"}}, "raycast")
    assert c["status"] == "ok", c["reason"]
    assert c["fullname"] == "17/CAHVORE/dots/c-rays[spp=4,full]/jpl[CAHVORE]"
    assert c["detections"] == ref["detections"]
    # within the sampling difference (measured: identical images)
    for field in ("rms", "max"):
        assert c["projection"][field] == pytest.approx(ref["projection"][field], abs=1e-4)
        assert c["residuals"][field] == pytest.approx(ref["residuals"][field], abs=1e-4)


def test_the_warps_share_reaches_the_record():
    from harness.stages import render_summary
    s = render_summary([{"samples": 4, "warp_rms": 0.01, "warp_max": 0.2},
                        {"samples": 4, "warp_rms": 0.03, "warp_max": 0.4}])
    assert s == {"images": 2, "samples": 8, "warp_rms": pytest.approx(0.02),
                 "warp_max": pytest.approx(0.3)}


@pytest.mark.slow
def test_camval_render_runs_a_command(tmp_path):
    out = tmp_path / "x.png"
    cmd = " ".join(EXAMPLE)
    p = subprocess.run([sys.executable, "-m", "camval.cli", "render", "17", "-o", str(out),
                        "--spp", "1", "--renderer", "command", "--command", cmd,
                        "--setup", "output_format=npy", "--setup", "timeout=300"],
                       capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert p.returncode == 0, p.stderr
    assert "command K=1" in p.stdout and out.is_file()
    import json
    meta = json.loads(out.with_suffix(".json").read_text())["render"]
    assert meta["command"] == EXAMPLE and meta["output_format"] == "npy"


@pytest.mark.slow
def test_a_pinhole_only_renderer_passes_the_default_gate_on_the_fisheye(tmp_path):
    # issue 17's bar: a pinhole-only renderer (the example's pinhole mode) + camval's
    # area-sampled warp on the Rocky8 CAHVORE fisheye (slot 17), K = 16, the shipped gate
    from harness.campaign import parse_campaign
    from harness.gate import check, load_gate_spec
    from harness.runner import run_campaign

    doc = {"name": "pinhole-17", "cameras": [17], "models": ["CAHVORE"], "targets": ["dots"],
           "renderer": [{"name": "command", "label": "pinhole-example", "spp": 16,
                         "setup": {"command": EXAMPLE, "mode": "pinhole", "persistent": True,
                                   "output_format": "npy", "pinhole_measure_warp": False}}],
           "calibrator": [{"name": "jpl"}]}
    run = run_campaign(parse_campaign(doc), tmp_path / "run", progress=False, workers=1)
    (rec,) = run["records"].values()
    assert rec["status"] == "ok", rec["reason"]
    assert check(run, load_gate_spec(os.path.join(ROOT, "campaigns", "gate.toml"))) == []

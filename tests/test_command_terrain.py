r'''Terrain scenes through the external renderer protocol (version 3): the request, the
example program in every mode against the built-in terrain ray caster, the shadow check,
the stereo range check on the command renderer, and bad requests

The example program (examples/external_renderer.py) renders terrain with
renderers.raycast_terrain as its stand-in engine, so what differs from the
built-in is only what crosses the protocol: float64 heights and float32
albedo as .npy (exact), the model as a JPL file (full precision), the image
as .npy float32 or 16-bit PNG, and in rays mode float32 ray directions.
'''

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from reference_models.poseutils import compose_Rt, invert_Rt
from renderers.base import (
    RendererError,
    RendererNotApplicable,
    RenderSettings,
    get_terrain_renderer,
    renderer_scenes,
)
from renderers.protocol import (
    SCENE_VERSIONS,
    RequestError,
    TerrainScene,
    read_request,
    write_request,
)
from renderers.raycast_terrain import cell_shadows as raycast_cell_shadows
from renderers.raycast_terrain import render_terrain
from targets.terrain import Sun, Terrain, make_terrain

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLE = [sys.executable, os.path.join(ROOT, "examples", "external_renderer.py")]
C_SOURCE = os.path.join(ROOT, "examples", "rays_renderer.c")
CC = shutil.which("cc") or shutil.which("gcc")
# exposure 0.8 keeps every sample's radiance below 1 (albedo <= 0.98, ambient 0.15 + cos i
# <= 1: 0.98 * 1.15 * 0.8 = 0.90), so clipping per ray (rays mode: values must be in
# [0,1]) and clipping the pixel mean (the built-in) agree
LIGHT = {"exposure": 0.8}


@pytest.fixture(scope="module")
def hazcam():
    r'''MER B front hazcam (slot 12, CAHVORE, noncentral) scaled to 128x128 over the stereo
check's generated terrain, and its pose'''
    from harness.studies.stereo import StereoSetup
    s = StereoSetup.from_catalogue(12, 11, scale=0.125)
    return s.left, s.terrain, s.Rt_ref_terrain


@pytest.fixture(scope="module")
def example():
    r'''The example program as a persistent command renderer (one process for the module:
its numba kernels load once); mode and output format are given per render'''
    r = get_terrain_renderer("command", command=EXAMPLE, persistent=True, timeout=600)
    yield r
    r.close()


@pytest.fixture(scope="module")
def c_renderer(tmp_path_factory):
    if CC is None:
        pytest.skip("no C compiler (cc, gcc) on this machine")
    exe = tmp_path_factory.mktemp("c") / "rays_renderer"
    out = subprocess.run([CC, "-O2", "-Wall", "-Wextra", "-Werror", "-o", str(exe), C_SOURCE,
                          "-lm"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return str(exe)


def small_terrain(**kw):
    return make_terrain(extent=(0, 2, -1, 1), cell=0.1, texel=0.05, seed=2, **kw)


# --- the request ---------------------------------------------------------------------------
def test_the_command_renderer_is_a_terrain_renderer_of_the_registry():
    assert renderer_scenes("command") == ("board", "terrain")
    assert hasattr(get_terrain_renderer("command", command=EXAMPLE), "cell_shadows")


def test_a_terrain_request_carries_the_scene_completely(tmp_path, hazcam):
    model, _, pose = hazcam
    t = small_terrain(sun=Sun(azimuth_deg=200.0, elevation_deg=25.0), ambient=0.2)
    settings = RenderSettings(spp=3, options={"shadows": False, "exposure": 0.7, "q": 1})
    path = write_request(tmp_path, model, t, pose, settings, "npy")
    raw = json.loads(Path(path).read_text())
    assert raw["version"] == 3 == SCENE_VERSIONS["terrain"] and raw["scene_kind"] == "terrain"
    # the lighting is scene, not the program's options
    assert raw["options"] == {"q": 1}
    assert raw["outputs"]["shadow"] == {"file": "shadow.npy", "required": False}
    req = read_request(path)
    ts = req.terrain
    assert isinstance(ts, TerrainScene) and req.pattern is None and req.scene_kind == "terrain"
    # .npy side files: the heights and texture bit for bit
    assert np.array_equal(ts.heights, t.heights) and ts.heights.dtype == np.float64
    assert np.array_equal(ts.albedo, t.albedo) and ts.albedo.dtype == np.float32
    assert (ts.cell, ts.origin, ts.extent()) == (t.cell, t.origin, t.extent())
    assert np.array_equal(ts.sun_direction, t.sun.direction())
    assert (ts.sun_azimuth_deg, ts.sun_elevation_deg, ts.ambient) == (200.0, 25.0, 0.2)
    assert ts.lighting() == {"shadows": False, "exposure": 0.7, "sky": 0.0}
    assert np.array_equal(ts.Rt_ref_terrain, pose)
    want = compose_Rt(invert_Rt(model.Rt_ref_cam()), pose)
    assert np.array_equal(ts.Rt_cam_terrain, want)
    # a terrain point maps to the same camera-frame point through either pose
    p = np.array([3.0, 0.5, 0.1])
    Rrc = model.Rt_ref_cam()
    p_ref = pose[:3] @ p + pose[3]
    np.testing.assert_allclose(want[:3] @ p + want[3], Rrc[:3].T @ (p_ref - Rrc[3]),
                               atol=1e-12)
    tt = ts.to_terrain()
    assert np.array_equal(tt.heights, t.heights) and tt.sun == t.sun
    # a board request is still version 2
    from render_checks import board_pose, grid_board
    b = write_request(tmp_path / "b", model, grid_board()[0], board_pose(), RenderSettings())
    assert json.loads(Path(b).read_text())["version"] == 2 and read_request(b).terrain is None


def _tamper(tmp_path, model, pose, what):
    t = small_terrain()
    path = write_request(tmp_path, model, t, pose, RenderSettings(spp=1))
    scene_path = tmp_path / "scene.json"
    scene = json.loads(scene_path.read_text())
    raw = json.loads(Path(path).read_text())
    if what == "heights_shape":
        np.save(tmp_path / "terrain-heights.npy", np.zeros((3, 4)))
    elif what == "heights_nan":
        h = t.heights.copy()
        h[2, 3] = np.nan
        np.save(tmp_path / "terrain-heights.npy", h)
        scene["heights"]["shape"] = None
    elif what == "albedo_missing":
        os.remove(tmp_path / "terrain-albedo.npy")
    elif what == "albedo_range":
        np.save(tmp_path / "terrain-albedo.npy", np.full(t.albedo.shape, 1.5, np.float32))
    elif what == "sun_below":
        scene["sun"]["elevation_deg"] = -5.0
    elif what == "sun_direction":
        scene["sun"]["direction"] = [0.0, 0.0, 1.0]
    elif what == "pose":
        scene["Rt_cam_terrain"][0][0] = 2.0
    elif what == "cell":
        scene["cell"] = 0.0
    elif what == "no_sun":
        del scene["sun"]
    elif what == "shadows":
        scene["shadows"] = "yes"
    elif what == "version":
        raw["version"] = 2
    scene_path.write_text(json.dumps(scene))
    Path(path).write_text(json.dumps(raw))
    return path


@pytest.mark.parametrize("what, reason", [
    ("heights_shape", r"has shape \[3, 4\]; scene.json says"),
    ("heights_nan", "not a usable terrain: the height field has non-finite heights"),
    ("albedo_missing", "cannot read the albedo texture"),
    ("albedo_range", r"not a usable terrain: albedo must be .* in \[0,1\]"),
    ("sun_below", "not a usable terrain: sun elevation -5.0 deg must be in"),
    ("sun_direction", "sun direction .* disagrees with azimuth"),
    ("pose", "Rt_cam_terrain's first 3 rows are not a rotation"),
    ("cell", "not a usable terrain: cell size must be > 0"),
    ("no_sun", "a terrain scene needs sun"),
    ("shadows", "shadows='yes'; expected true/false"),
    ("version", "scene kind 'terrain' needs request version 3; the request says 2"),
])
def test_a_bad_terrain_request_fails_with_its_reason(tmp_path, hazcam, what, reason):
    model, _, pose = hazcam
    path = _tamper(tmp_path, model, pose, what)
    with pytest.raises(RequestError, match=reason):
        read_request(path)


def test_a_bad_request_reaches_the_program_and_its_reason_the_record(tmp_path, hazcam):
    r'''The program's reader refuses the request; camval's error carries its reason'''
    from renderers.protocol import answer_request
    model, _, pose = hazcam
    path = _tamper(tmp_path, model, pose, "sun_below")
    a = answer_request(lambda req: None, path)
    assert a["status"] == "failed" and "sun elevation -5.0 deg" in a["reason"]


# --- the example program against the built-in ------------------------------------------------
@pytest.mark.parametrize("K", [1, 2])
def test_image_mode_equals_the_built_in_ray_caster(example, hazcam, K):
    r'''.npy: identical (same engine, same float64 inputs; the JPL file keeps the model to
full precision); 16-bit PNG: within half a step (rounding to 1/65535) plus float32 rounding;
the range and shadow outputs are the built-in's'''
    model, terrain, pose = hazcam
    want = render_terrain(model, terrain, pose, spp=K, **LIGHT)
    got = example.render_terrain(model, terrain, pose,
                                 RenderSettings(spp=K, options=dict(LIGHT, output_format="npy")))
    assert np.array_equal(got.image, want.image)
    assert np.array_equal(got.range, want.range, equal_nan=True)
    assert np.array_equal(got.shadow, want.shadow)
    assert got.metadata["mode"] == "image" and got.metadata["exposure"] == 0.8
    assert got.metadata["outputs"] == ["range", "shadow"]
    # the scene is varied enough for this to mean something: sky, lit, shadowed
    assert {0, 2, 255} <= set(np.unique(want.shadow).tolist())
    png = example.render_terrain(model, terrain, pose, RenderSettings(spp=K, options=LIGHT))
    d = np.abs(png.image.astype(np.float64) - want.image)
    assert d.max() <= 0.5 / 65535 + 1e-7


@pytest.mark.parametrize("K", [1, 2, 3])
def test_rays_mode_equals_the_built_in_within_float32_rays(example, hazcam, K):
    r'''rays mode: camval's rays as float32 (relative rounding 6e-8: ~1 micrometre at the
terrain's 5-20 m), the same K x K sample points as the built-in. Shading is continuous
except across triangle edges, shadow edges and the horizon, where a sample within
~1e-6 m of an edge may land on the other side: most pixels agree to float32 rounding,
a few (measured 0-1 of 16384) by up to 1/K^2 of a jump. Range and shadow codes (K odd:
the centre sample, the built-in's pixel-centre ray) likewise.'''
    model, terrain, pose = hazcam
    want = render_terrain(model, terrain, pose, spp=K, **LIGHT)
    got = example.render_terrain(model, terrain, pose,
                                 RenderSettings(spp=K, options=dict(LIGHT, mode="rays")))
    d = np.abs(got.image.astype(np.float64) - want.image)
    assert np.median(d) < 1e-6
    assert np.mean(d > 1e-4) < 0.002
    assert got.metadata["mode"] == "rays"
    if K % 2:
        sky = np.isnan(want.range)
        assert np.array_equal(np.isnan(got.range), sky)
        # float32 directions: range error ~ range * 1e-7, 20 m -> 2e-6 m (measured 1.6e-5 m
        # at most, on the steepest grazing ground)
        assert np.nanmax(np.abs(got.range - want.range) / want.range) < 1e-5
        assert np.mean(got.shadow != want.shadow) < 0.002
    else:
        # no sample is the pixel centre
        assert got.range is None and got.shadow is None


def test_pinhole_mode_on_terrain_is_the_warp_of_an_exact_pinhole(example, hazcam):
    r'''A central camera: the example renders the exact pinhole, so the command image minus
the built-in's is exactly the warp's share camval measures (warp_rms); a noncentral
camera is not applicable (a pinhole warps exactly only for a known depth per pixel), and
so is a field of view no pinhole covers (the hazcam, 94 deg off axis)'''
    from harness.studies.stereo import StereoSetup, rectifiable
    nav = StereoSetup.from_catalogue(21, 22, scale=0.05)        # navcam, 256x192, CAHVORE
    central = rectifiable(nav.left)                             # the same with E = 0
    assert central.is_central and not nav.left.is_central
    terrain, pose = nav.terrain, nav.Rt_ref_terrain
    want = render_terrain(central, terrain, pose, spp=2, **LIGHT)
    got = example.render_terrain(central, terrain, pose, RenderSettings(
        spp=2, options=dict(LIGHT, mode="pinhole", output_format="npy")))
    d = got.image.astype(np.float64) - want.image
    rms = float(np.sqrt(np.mean(d * d)))
    assert got.metadata["warp_rms"] == pytest.approx(rms, rel=1e-6)
    # the warp's share on the textured terrain (measured 0.0066 in image values, 2x
    # pinhole, 6 x 6 area samples)
    assert 0 < rms < 0.015
    assert got.range is None and got.shadow is None
    with pytest.raises(RendererNotApplicable, match="noncentral camera .* terrain has none"):
        example.render_terrain(nav.left, terrain, pose,
                               RenderSettings(spp=1, options={"mode": "pinhole"}))
    model, terrain, pose = hazcam
    with pytest.raises(RendererNotApplicable, match="field of view"):
        example.render_terrain(rectifiable(model), terrain, pose,
                               RenderSettings(spp=1, options={"mode": "pinhole"}))


# --- the shadow check ----------------------------------------------------------------------
def wall_terrain(elevation_deg=20.0):
    r'''Flat ground with a one-node ridge at x = 2 m whose shadow (sun from -x) ends at
x = 2.95 m, half way between two rows of centroids (tests/test_shadow_agreement.py)'''
    height = 0.95 * math.tan(math.radians(elevation_deg))
    return Terrain.from_function(lambda x, y: np.where(np.abs(x - 2.0) < 1e-6, height, 0.0)
                                 + 0 * y, (0, 6, 0, 3), 0.1, sun=Sun(180.0, elevation_deg))


def test_the_shadow_check_runs_on_the_command_renderer(example):
    r'''cell_shadows through a rays request: the analytic ridge shadow exactly, and a rough
terrain under a low sun as the exact shadow rays (float32 centroids move a ray by
< 1e-6 m, far from the 1.7 cm margin of the ridge; measured 0 of 12800 differ)'''
    from renderers.terrain_shadows import compare, sample_points
    t = wall_terrain()
    x, _ = sample_points(t)
    truth = np.zeros(x.shape, np.uint8)
    truth[(x > 2.0) & (x < 2.1)] = 1
    truth[(x > 2.1) & (x < 2.95)] = 2
    assert np.array_equal(example.cell_shadows(t), truth)
    rough = make_terrain(extent=(0, 8, 0, 8), cell=0.1, texel=0.05, seed=5, relief_m=0.3,
                         relief_wavelength_m=3.0, rocks_per_m2=1.5, rock_radius_m=(0.05, 0.4),
                         sun=Sun(120.0, 12.0))
    exact = raycast_cell_shadows(rough)
    c = compare(exact, example.cell_shadows(rough), rough)
    assert c["shadowed_fraction_a"] > 0.1          # a low sun: many shadows to get right
    assert c["disagree_fraction"] < 1e-3


def _program(tmp_path, body):
    p = tmp_path / "prog.py"
    p.write_text("import sys\nimport numpy as np\nfrom renderers.protocol import serve\n"
                 f"def render(req):\n{body}\nsys.exit(serve(render))\n")
    return [sys.executable, str(p)]


def test_the_shadow_check_needs_the_programs_shadow_codes(tmp_path):
    r'''A program that gives no shadow codes fails the check with the reason; one that
does not do rays mode declines it (not applicable)'''
    t = wall_terrain()
    quiet = _program(tmp_path, "    return np.zeros(req.raw['rays']['count'])")
    with pytest.raises(RendererError, match="wrote no shadow output .* requires it"):
        get_terrain_renderer("command", command=quiet).cell_shadows(t)
    na = _program(tmp_path, "    from renderers.protocol import NotApplicable\n"
                            "    raise NotApplicable('image mode only')")
    with pytest.raises(RendererNotApplicable, match="image mode only"):
        get_terrain_renderer("command", command=na).cell_shadows(t)


def test_bad_terrain_outputs_fail_with_the_reason(tmp_path, hazcam):
    model, terrain, pose = hazcam
    bad = _program(tmp_path, "    s = np.full((req.raw['height'], req.raw['width']), 7)\n"
                             "    return {'image': np.zeros(s.shape), 'shadow': s}")
    with pytest.raises(RendererError, match=r"shadow codes \[7\]"):
        get_terrain_renderer("command", command=bad).render_terrain(model, terrain, pose)


def test_a_renderer_written_in_c_renders_terrain_in_rays_mode(c_renderer, hazcam):
    r'''examples/rays_renderer.c walks each ray over the grid (DDA) and intersects the
triangles itself: its images equal the built-in's as the Python rays mode does (float32
rays; measured at most 1 pixel of 16384 off by more than 1e-4, median 0), its range and
shadow codes likewise, and the shadow check runs on it (exactly the analytic ridge; a rough
terrain as the exact shadow rays, measured 0 of 12800 differ). It declines image mode.'''
    from renderers.terrain_shadows import compare
    model, terrain, pose = hazcam
    for K, persistent in ((1, False), (2, True), (3, True)):
        r = get_terrain_renderer("command", command=[c_renderer], mode="rays",
                                 persistent=persistent)
        want = render_terrain(model, terrain, pose, spp=K, **LIGHT)
        got = r.render_terrain(model, terrain, pose, RenderSettings(spp=K, options=LIGHT))
        d = np.abs(got.image.astype(np.float64) - want.image)
        assert np.median(d) < 1e-6 and np.mean(d > 1e-4) < 0.002
        if K % 2:
            assert np.array_equal(np.isnan(got.range), np.isnan(want.range))
            assert np.nanmax(np.abs(got.range - want.range) / want.range) < 1e-5
            assert np.mean(got.shadow != want.shadow) < 0.002
        r.close()
    r = get_terrain_renderer("command", command=[c_renderer])
    t = wall_terrain()
    x = np.asarray(raycast_cell_shadows(t))
    assert (x == 2).any() and np.array_equal(r.cell_shadows(t), x)
    rough = make_terrain(extent=(0, 8, 0, 8), cell=0.1, texel=0.05, seed=5, relief_m=0.3,
                         relief_wavelength_m=3.0, rocks_per_m2=1.5, rock_radius_m=(0.05, 0.4),
                         sun=Sun(120.0, 12.0))
    assert compare(raycast_cell_shadows(rough), r.cell_shadows(rough))["disagree_fraction"] < 1e-3
    with pytest.raises(RendererNotApplicable, match='renders only "rays" requests'):
        r.render_terrain(model, terrain, pose)


# --- the stereo range check ----------------------------------------------------------------
def _stereo(tmp_path, extra):
    import argparse

    from camval.commands import stereo as cmd
    p = argparse.ArgumentParser()
    cmd.add_arguments(p)
    assert cmd.run(p.parse_args(["12", "11", "-o", str(tmp_path), "--scale", "0.25"]
                                + extra)) == 0
    return json.loads((tmp_path / "stereo_12_11.json").read_text())


@pytest.mark.slow
def test_camval_stereo_on_the_command_renderer_gives_the_built_ins_verdict(tmp_path,
                                                                           c_renderer):
    r'''camval stereo 12 11 --scale 0.25 through the example program (image mode, .npy,
persistent): its images are the built-in's, so every statistic is the same; the verdict
is test_stereo's quarter-scale bar (band median |range error| < 12%). Through the C
program in rays mode the images differ in a few edge samples (float32 rays), which moves
a few disparities: measured band median |error| 7.4188% against 7.4191%, the same
valid pixels.'''
    want = _stereo(tmp_path / "builtin", [])
    got = _stereo(tmp_path / "command", [
        "--renderer", "command", "--command", " ".join(EXAMPLE),
        "--setup", "persistent=true", "--setup", "output_format=npy"])
    assert got["meta"]["renderer"] == "command"
    assert want["meta"]["renderer"] == "raycast_terrain"
    s, s0 = got["variants"]["clean"]["stats"], want["variants"]["clean"]["stats"]
    assert s == s0
    assert s["band"]["median_abs_rel_error"] < 0.12 and s["band"]["n"] > 800
    c = _stereo(tmp_path / "c", ["--renderer", "command", "--command", c_renderer,
                                 "--setup", "mode=rays", "--setup", "persistent=true"])
    sc = c["variants"]["clean"]["stats"]
    assert sc["band"]["median_abs_rel_error"] < 0.12
    assert sc["band"]["median_abs_rel_error"] == pytest.approx(
        s0["band"]["median_abs_rel_error"], rel=0.01)
    assert sc["valid_fraction"] == pytest.approx(s0["valid_fraction"], abs=0.005)


def test_stereo_refuses_a_command_without_a_program(tmp_path):
    r'''The command renderer needs its program: a clear error before anything renders'''
    from harness.studies.stereo import StereoSetup, run_stereo_check
    setup = StereoSetup.from_catalogue(12, 11, scale=0.125)
    with pytest.raises(RendererError, match="needs a command"):
        run_stereo_check(setup, renderer="command")

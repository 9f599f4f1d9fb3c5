import shutil

import numpy as np
import pytest
from render_checks import (
    board_pose,
    dot_board,
    expected_centroid,
    grid_board,
    measured_centroid,
    small_model,
)

from renderers.base import RendererError, RendererUnavailableError, RenderSettings, get_renderer
from renderers.povray import (
    MeshRect,
    PovrayRenderer,
    edge_pixels,
    mesh_grid_step,
    mesh_interpolation_error,
    pack_rects,
    perspective_camera,
    split_supersampling,
)
from renderers.warp import Pinhole

needs_povray = pytest.mark.skipif(shutil.which("povray") is None,
                                  reason="POV-Ray is not installed: install Debian package povray")


def test_missing_binary_says_the_fix():
    with pytest.raises(RendererUnavailableError, match="install Debian package povray"):
        PovrayRenderer(binary="povray-not-installed-here")


def test_mesh_interpolation_error_is_quadratic_in_the_step():
    # POV-Ray mixes unit normals: even a pinhole's rays are off between the vertices
    m = small_model("CAHVOR", W=128, H=96, f=125.0)
    e8, e4 = mesh_interpolation_error(m, 8), mesh_interpolation_error(m, 4)
    assert 0.2 < e4 / e8 < 0.3, (e4, e8)
    assert 0.2 < e4 / mesh_interpolation_error(small_model("CAHV", W=128, H=96, f=125.0), 4) < 5
    step, err = mesh_grid_step(m, 1.01 * e4, (8, 4, 2, 1))
    assert step == 4 and err == pytest.approx(e4)
    assert mesh_grid_step(m, 1e-12, (2, 1))[0] == 1     # nothing fits: the finest


@needs_povray
def test_povray_mixes_unit_normals_as_modelled():
    # a CAHV camera on a 16-px grid: the model predicts rays off by up to 0.43 px, and
    # POV-Ray's image is off the ray caster's by about that (dot centroids, 25 dots)
    m = small_model("CAHV", W=128, H=96, f=125.0)
    pat, centres = grid_board()
    Rt = board_pose(25, 0.9, (0.02, -0.01))
    predicted = mesh_interpolation_error(m, 16)
    assert 0.3 < predicted < 0.6
    ref = get_renderer("raycast").render(m, pat, Rt, RenderSettings(spp=4, adaptive=False))
    r = PovrayRenderer()
    import tempfile
    d = tempfile.mkdtemp()
    placed = pack_rects([MeshRect(0, 0, 128, 96, 4)], [16])
    ((Wa, Ha, pl),) = placed
    from renderers.povray import box_downsample, mesh_camera_text, scene_header, scene_objects
    text, _ = mesh_camera_text(m, pl, Wa, Ha, 0.2)

    def write(f):
        f.write(scene_header(pat) + text)
        f.write("camera { mesh_camera { 1 3 mesh { CamvalRays } smooth } "
                "location <0,0,0> direction <0,0,1> }\n" + scene_objects(pat, Rt))

    img, _, _ = r._run(d, write, Wa, Ha, 1, None)
    img = box_downsample(img[1:1 + 96 * 4, :128 * 4], 4)
    exps = np.array([expected_centroid(m, Rt, c, 0.02) for c in centres])
    radius = 1.6 * 0.02 / 0.9 * m.photogrammetric().Hs
    shift = np.array([measured_centroid(img, e, radius) - measured_centroid(ref.image, e, radius)
                      for e in exps])
    worst = np.linalg.norm(shift, axis=-1).max()
    assert 0.1 * predicted < worst < 1.5 * predicted, (worst, predicted)


def test_edge_pixels_cover_every_pixel_an_edge_crosses():
    m = small_model("CAHVOR", W=128, H=96, f=125.0)
    pat, _ = grid_board()
    Rt = board_pose(25, 0.9, (0.02, -0.01))
    mask = edge_pixels(m, pat, Rt)
    # a pixel whose 8 x 8 samples disagree has an edge in it
    ref = get_renderer("raycast").render(m, pat, Rt, RenderSettings(spp=8, adaptive=False))
    ref1 = get_renderer("raycast").render(m, pat, Rt, RenderSettings(spp=1, adaptive=False))
    mixed = (ref.image > 0) & (ref.image < 1) | (ref.image != ref1.image)
    assert mixed.sum() > 300
    assert not np.any(mixed & ~mask)
    assert mask.sum() < 2.5 * mixed.sum()     # a thin band, not the whole board


def test_pack_rects_limits_pixels_and_faces_and_keeps_row_0_empty():
    cells = [MeshRect(2 * i, 0, 2, 2, 16) for i in range(300)]
    runs = pack_rects([MeshRect(0, 0, 512, 384, 1)] + cells, [32] + [2] * 300,
                      max_pixels=1 << 20, max_faces=400)
    placed = [p for _, _, pl in runs for p in pl]
    assert [p[0] for p in placed] == [MeshRect(0, 0, 512, 384, 1)] + cells
    for Wa, Ha, pl in runs:
        assert Wa * Ha <= 1 << 20 and sum(2 if s == 2 else 384 for _, s, _, _ in pl) <= 400
        boxes = [(ax, ay, ax + r.w * r.k, ay + r.h * r.k) for r, _, ax, ay in pl]
        assert min(b[1] for b in boxes) == 1 and max(b[2] for b in boxes) <= Wa
        assert max(b[3] for b in boxes) == Ha
        for i, a in enumerate(boxes):          # no overlaps
            for b in boxes[i + 1:]:
                assert a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1]
    # the image tile sets the width of its atlas; the cells fill the rows below it
    assert runs[0][0] == 512 and runs[0][2][1][3] == 385


def test_supersampling_split():
    assert split_supersampling(1) == (1, 1)
    assert split_supersampling(4) == (4, 1)
    assert split_supersampling(16) == (8, 2)
    assert split_supersampling(11) == (1, 11)


def test_perspective_camera_puts_the_principal_point_where_the_pinhole_has_it():
    pin = Pinhole(fx=200.0, fy=210.0, cx=60.25, cy=40.75, width=128, height=96)
    text = perspective_camera(pin)
    nums = [float(x) for x in text.split("direction <")[1].split(">")[0].split(",")]
    # POV-Ray 3.7.0 pixel (i, j) looks along direction + ((i+0.5)/W - 0.5) right + ...
    i = pin.cx
    x = nums[0] + ((i + 0.5) / pin.width - 0.5) * pin.width / pin.fx
    assert abs(x) < 1e-15


@needs_povray
def test_bad_input():
    r = PovrayRenderer()
    m = small_model("CAHVOR", W=64, H=48, f=60.0)
    pat, _ = grid_board()
    with pytest.raises(RendererError, match="camera"):
        r.render(m, pat, board_pose(), RenderSettings(spp=1, options={"camera": "fisheye"}))
    with pytest.raises(RendererError, match="unknown option"):
        r.render(m, pat, board_pose(), RenderSettings(spp=1, options={"colour": 1}))
    with pytest.raises(RendererError, match="Rt_cam_board"):
        r.render(m, pat, np.eye(3), RenderSettings(spp=1))
    with pytest.raises(RendererError, match="board plane"):
        r.render(m, pat, np.vstack((np.eye(3), [0.0, 0.0, 0.0])),
                 RenderSettings(spp=1, options={"camera": "mesh"}))


@needs_povray
def test_output_shape_dtype_range_and_metadata():
    m = small_model("CAHVOR", W=96, H=64, f=90.0)
    pat, _ = grid_board()
    res = get_renderer("povray").render(m, pat, board_pose(), RenderSettings(spp=1))
    assert res.image.shape == (64, 96) and res.image.dtype == np.float32
    assert res.image.min() == 0.0 and res.image.max() == 1.0   # background, board
    assert res.metadata["renderer"] == "povray" and res.metadata["version"].startswith("POV-Ray 3")
    assert res.metadata["camera"] == "perspective"


def _dot_error(model, camera, K, interpolation="bilinear"):
    centre, r = (0.03, -0.02), 0.02
    Rt = board_pose(20, 0.9)
    pat = dot_board([centre], r)
    exp = expected_centroid(model, Rt, centre, r)
    res = PovrayRenderer().render(model, pat, Rt, RenderSettings(
        spp=K, options={"camera": camera, "interpolation": interpolation}))
    return measured_centroid(res.image, exp, 1.6 * r / 0.9 * model.photogrammetric().Hs) - exp


@needs_povray
def test_pixel_convention_perspective_path():
    # a half-pixel slip would show as 0.5 px; the warp and K = 8 leave < 0.02 px
    err = _dot_error(small_model("CAHVOR"), "perspective", 8)
    assert np.abs(err).max() < 0.02, err


@needs_povray
@pytest.mark.slow
def test_pixel_convention_mesh_camera():
    # the mesh camera's row offset (POV-Ray 3.7.0 traces face row j - 1 for image row j)
    # would show as 1/K px = 0.5 px here; sampling at K = 2 leaves < 0.05 px
    err = _dot_error(small_model("CAHVOR", W=128, H=96, f=125.0), "mesh", 2)
    assert np.abs(err).max() < 0.05, err


def _agreement(model, options, K, K_ref=4):
    Rt = board_pose(25, 0.9, (0.02, -0.01))
    pat, centres = grid_board()
    ref = get_renderer("raycast").render(model, pat, Rt, RenderSettings(spp=K_ref)).image
    img = get_renderer("povray").render(model, pat, Rt, RenderSettings(spp=K, options=options))
    d = np.abs(img.image.astype(float) - ref)
    exps = np.array([expected_centroid(model, Rt, c, 0.02) for c in centres])
    radius = 1.6 * 0.02 / 0.9 * model.photogrammetric().Hs
    err = np.array([measured_centroid(img.image, e, radius) for e in exps]) - exps
    return d.mean(), np.sqrt((err ** 2).sum(1).mean())


@needs_povray
@pytest.mark.slow
def test_perspective_path_agrees_with_raycast():
    # measured: mean |difference| 0.0045 (the warp's bilinear blur at the dot edges),
    # centroid RMS 0.017 px over 25 dots at K = 4
    mean_abs, rms = _agreement(small_model("CAHVOR"), {"camera": "perspective"}, 4)
    assert mean_abs < 0.007
    assert rms < 0.03


@needs_povray
@pytest.mark.parametrize("family", ["CAHVOR", "CAHVORE"])
def test_mesh_camera_gives_the_ray_casters_image(family):
    # same sub-pixel samples, rays interpolated within 0.0014 px (step 1 on this strongly
    # distorted small camera): the K = 4 images are equal, full and adaptive (measured:
    # identical), noncentral CAHVORE included
    m = small_model(family, W=128, H=96, f=125.0)
    Rt = board_pose(25, 0.9, (0.02, -0.01))
    pat, _ = grid_board()
    # the mesh camera point-samples: the ray caster's point sampling is the reference
    ref = get_renderer("raycast").render(m, pat, Rt, RenderSettings(
        spp=4, adaptive=False, options={"coverage": "point"}))
    r = PovrayRenderer(camera="mesh")
    for adaptive in (False, True):
        res = r.render(m, pat, Rt, RenderSettings(spp=4, adaptive=adaptive))
        d = np.abs(res.image.astype(float) - ref.image)
        assert (d > 0).sum() <= 2 and d.max() <= 1 / 16, (adaptive, (d > 0).sum())
        assert res.metadata["adaptive_fraction"] == (
            pytest.approx(1.0) if not adaptive else pytest.approx(0.16, abs=0.03))

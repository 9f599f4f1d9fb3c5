'''camval render / camval renderers: images, sidecars, no overwriting, bad input'''

import json

import cv2
import numpy as np
import pytest

from camval.cli import main
from reference_models.catalogue import load_catalogue, model_from_fields
from reference_models.jpl_files import write_model
from renderers.base import RenderSettings, get_renderer
from renderers.png import load_png
from targets.boards import load_target
from targets.centroids import expected_centroids, projected_points
from targets.poses import plan_poses

CAMERA = "17"     # the 640x480 Rocky8 hazcam: quick to render


def _strict_json(path):
    def no_nan(x):
        raise AssertionError(f"{path} holds {x}")
    return json.loads(path.read_text(), parse_constant=no_nan)


@pytest.fixture(scope="module")
def model():
    return load_catalogue().get(CAMERA).model


def test_render_one_pose_writes_png16_and_sidecar(tmp_path, model, capsys):
    out = tmp_path / "p3.png"
    assert main(["render", CAMERA, "--target", "dots", "--pose", "3", "--spp", "4",
                 "-o", str(out)]) == 0
    assert "pose 3" in capsys.readouterr().out
    raw = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == (model.height, model.width)

    side = _strict_json(out.with_suffix(".json"))
    target = load_target("dots")
    Rt = plan_poses(model, target, n=6, seed=0)[3]
    assert side["pose_index"] == 3 and side["camera"]["id"] == 17
    m = model_from_fields(side["model"])
    assert side["model"]["family"] == model.family == m.family
    for k in ("C", "A", "H", "V", "O", "R", "E"):
        assert np.array_equal(getattr(m, k), getattr(model, k)), k
    assert (m.model_type, m.linearity, m.width, m.height) == \
        (model.model_type, model.linearity, 640, 480)
    np.testing.assert_array_equal(side["Rt_cam_board"], Rt)
    assert side["target"]["name"] == "dots" and len(side["points"]) == 100
    np.testing.assert_array_equal(side["points"], target.points())
    np.testing.assert_array_equal(side["point_ids"], target.point_ids())
    np.testing.assert_allclose(side["projected"], projected_points(model, target, Rt),
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(side["expected_centroids"],
                               expected_centroids(model, target, Rt), rtol=0, atol=1e-9)
    # the centroid bias is real: the two differ
    assert np.abs(np.subtract(side["expected_centroids"], side["projected"])).max() > 0.01
    md = side["render"]
    assert md["renderer"] == "raycast" and md["settings"]["spp"] == 4
    assert md["settings"]["adaptive"] is True and md["samples"] > 0

    # the image is the renderer's, rounded to 16 bits
    ref = get_renderer("raycast").render(model, target.pattern(), Rt,
                                         RenderSettings(spp=4)).image
    assert np.array_equal(raw, np.round(ref.astype(np.float64) * 65535).astype(np.uint16))
    assert np.abs(load_png(out) - ref).max() <= 0.5 / 65535 + 1e-7


def test_never_overwrites_without_force(tmp_path, capsys):
    out = tmp_path / "a.png"
    assert main(["render", CAMERA, "--spp", "1", "-o", str(out)]) == 0
    before = out.read_bytes()
    assert main(["render", CAMERA, "--spp", "2", "--pose", "1", "-o", str(out)]) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert out.read_bytes() == before
    # the sidecar alone blocks too
    out.unlink()
    assert main(["render", CAMERA, "--spp", "1", "-o", str(out)]) == 2
    assert main(["render", CAMERA, "--spp", "2", "--pose", "1", "-o", str(out),
                 "--force"]) == 0
    assert out.read_bytes() != before
    assert _strict_json(out.with_suffix(".json"))["pose_index"] == 1


def test_poses_writes_six_pairs_that_calibrate_reads(tmp_path, model):
    from camval.commands.calibrate import (
        _model_from_sidecar,
        _pose_files,
        _Rt_from_sidecar,
        _target_from_sidecar,
    )
    d = tmp_path / "poses"
    assert main(["render", CAMERA, "--target", "chessboard", "--poses", str(d), "--spp", "2",
                 "--seed", "3"]) == 0
    pairs = _pose_files(d)
    assert [p.name for p, _ in pairs] == [f"pose{i}.png" for i in range(6)]
    planned = plan_poses(model, load_target("chessboard"), n=6, seed=3)
    for i, (png, js) in enumerate(pairs):
        side = _strict_json(js)
        assert "expected_centroids" not in side          # not a dot target
        assert len(side["projected"]) == 100
        assert _target_from_sidecar(side, js).name == "chessboard"
        np.testing.assert_array_equal(_Rt_from_sidecar(side, js), planned[i])
        m = _model_from_sidecar(side, js)
        assert m.family == "CAHVORE" and np.array_equal(m.H, model.H)
        img = load_png(png)
        assert img.shape == (480, 640) and 0 <= img.min() < img.max() <= 1
    assert main(["render", CAMERA, "--target", "chessboard", "--poses", str(d)]) == 2


def test_model_file_as_camera(tmp_path, model):
    f = tmp_path / "cam.cahvore"
    write_model(model, f)
    out = tmp_path / "f.png"
    assert main(["render", str(f), "--spp", "1", "--no-adaptive", "-o", str(out)]) == 0
    side = _strict_json(out.with_suffix(".json"))
    assert side["render"]["settings"]["adaptive"] is False
    # the ray caster's default, area coverage, integrates the edge pixels it finds whatever
    # `adaptive` says: a fraction of the image, not all of it (point sampling with
    # --no-adaptive supersamples every pixel)
    assert side["render"]["coverage"] == "area"
    assert 0 < side["render"]["area_fraction"] < 0.5
    np.testing.assert_allclose(side["model"]["H"], model.H, rtol=1e-6)


@pytest.mark.parametrize("args,message", [
    (["nosuchcamera", "-o", "{d}/x.png"], "nosuchcamera"),
    ([CAMERA, "--spp", "0", "-o", "{d}/x.png"], "positive integer"),
    ([CAMERA], "either -o FILE.png"),
    ([CAMERA, "-o", "{d}/x.png", "--poses", "{d}/p"], "either -o FILE.png"),
    ([CAMERA, "-o", "{d}/x.tif"], "must be a .png"),
    ([CAMERA, "-o", "{d}/missing/x.png"], "does not exist"),
    ([CAMERA, "--pose", "-1", "-o", "{d}/x.png"], "--pose must be >= 0"),
    ([CAMERA, "--target", "nosuchtarget", "-o", "{d}/x.png"], "nosuchtarget"),
    ([CAMERA, "--renderer", "blender", "-o", "{d}/x.png"], "unknown renderer 'blender'"),
    (["SuperCam", "-o", "{d}/x.png"], "SuperCam|optical centre|cannot"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, args, message):
    args = [a.format(d=tmp_path) for a in args]
    assert main(["render"] + args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    import re
    assert re.search(message, err), err
    assert not (tmp_path / "x.png").exists()


def test_renderers_list(capsys):
    assert main(["renderers", "list"]) == 0
    out = capsys.readouterr().out
    names = [line.split()[0] for line in out.splitlines() if line and not line[0].isspace()]
    assert {"raycast", "povray", "osmesa", "command"} <= set(names)
    assert "built-in (renderers.raycast:RaycastRenderer)" in out


def test_renderers_list_check_reports_versions(capsys):
    assert main(["renderers", "list", "--check"]) == 0
    out = capsys.readouterr().out
    assert "ok: raycast " in out


# --- renderers.png ------------------------------------------------------------------------------
def test_png16_round_trip(tmp_path):
    from renderers.png import save_png16
    rng = np.random.default_rng(0)
    levels = rng.integers(0, 65536, (37, 53))
    img = (levels / 65535.0).astype(np.float32)
    save_png16(tmp_path / "a.png", img)
    raw = cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and np.array_equal(raw, levels)
    back = load_png(tmp_path / "a.png")
    assert back.dtype == np.float32 and back.shape == (37, 53)
    assert np.abs(back - img).max() < 1e-7
    assert back.min() >= 0 and back.max() <= 1


def test_load_png_reads_8_bit(tmp_path):
    raw = np.array([[0, 128, 255]], dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "b.png"), raw)
    np.testing.assert_allclose(load_png(tmp_path / "b.png"), [[0.0, 128 / 255, 1.0]], rtol=1e-6)


@pytest.mark.parametrize("image,name,match", [
    (np.full((4, 4), 1.5), "x.png", r"span \[1.5, 1.5\]; expected \[0, 1\]"),
    (np.full((4, 4), np.nan), "x.png", "non-finite"),
    (np.zeros((4, 4, 3)), "x.png", "expected \\(height, width\\)"),
    (np.zeros((4, 4)), "x.tif", "expected a .png"),
    (np.zeros((4, 4)), "missing/x.png", "does its directory exist"),
])
def test_save_png16_bad_input(tmp_path, image, name, match):
    from renderers.png import ImageFileError, save_png16
    with pytest.raises(ImageFileError, match=match):
        save_png16(tmp_path / name, image)


def test_load_png_bad_input(tmp_path):
    from renderers.png import ImageFileError
    with pytest.raises(ImageFileError, match="no such file"):
        load_png(tmp_path / "none.png")
    (tmp_path / "junk.png").write_bytes(b"not a png")
    with pytest.raises(ImageFileError, match="cv2 can decode"):
        load_png(tmp_path / "junk.png")
    cv2.imwrite(str(tmp_path / "rgb.png"), np.zeros((3, 3, 3), np.uint8))
    with pytest.raises(ImageFileError, match="3 channels"):
        load_png(tmp_path / "rgb.png")

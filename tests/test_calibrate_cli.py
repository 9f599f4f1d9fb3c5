'''camval calibrate: from rendered images + sidecars to a fitted model and a summary'''

import json

import cv2
import numpy as np
import pytest

from harness.calibrators.synthetic import catalogue_models, default_target
from harness.cli import main
from reference_models.cahvore import truncate
from reference_models.jpl_files import read_model


def _fields(m):
    d = {"C": m.C.tolist(), "A": m.A.tolist(), "H": m.H.tolist(), "V": m.V.tolist(),
         "width": m.width, "height": m.height}
    if m.family != "CAHV":
        d.update(O=m.O.tolist(), R=m.R.tolist())
    return d


@pytest.fixture(scope="module")
def rendered_dir(tmp_path_factory):
    r'''6 planned poses of the 640x480 Rocky8 hazcam (as CAHVOR), ray-cast K=16, 16-bit PNG,
with sidecars as `camval render --poses` writes them (model, Rt_cam_board, target)'''
    from renderers.base import RenderSettings, get_renderer
    from targets.poses import plan_poses
    d = tmp_path_factory.mktemp("poses")
    truth = truncate(dict(catalogue_models())["17"], "CAHVOR")
    target = default_target()
    r = get_renderer("raycast")
    for i, Rt in enumerate(plan_poses(truth, target, n=6, seed=0)):
        img = r.render(truth, target.pattern(), Rt, RenderSettings(spp=16)).image
        cv2.imwrite(str(d / f"pose{i}.png"),
                    np.round(np.clip(img, 0, 1) * 65535).astype(np.uint16))
        side = {"model": _fields(truth), "Rt_cam_board": Rt.tolist(), "target": "dots",
                "points": target.points().tolist()}
        (d / f"pose{i}.json").write_text(json.dumps(side))
    return d, truth


@pytest.mark.slow
def test_jpl_calibrates_rendered_images(rendered_dir, capsys):
    d, truth = rendered_dir
    out = d / "out-jpl"
    assert main(["calibrate", str(d), "--calibrator", "jpl", "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok"
    assert [x["n_found"] for x in s["detections"]] == [100] * 6
    assert s["residuals"]["rms"] < 0.005
    assert abs(s["parameters"]["Hc"]) < 0.02 and abs(s["parameters"]["theta_deg"]) < 0.002
    assert s["projection"]["rotation"]["rms"] < 0.005
    fitted = read_model(out / "fitted.cahvor")
    assert fitted.family == "CAHVOR"
    assert "residuals per point" in capsys.readouterr().out
    # never overwrite without --force
    assert main(["calibrate", str(d), "--calibrator", "jpl", "-o", str(out)]) == 2
    assert main(["calibrate", str(d), "--calibrator", "jpl", "-o", str(out), "--force"]) == 0


@pytest.mark.slow
def test_mrcal_and_a_not_applicable_request(rendered_dir):
    d, truth = rendered_dir
    out = d / "out-mrcal"
    assert main(["calibrate", str(d), "--calibrator", "mrcal", "--model", "CAHVOR",
                 "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["parameters"]["theta_deg"] is None
    assert (out / "fitted.cahvor").exists()
    # OpenCV cannot hold surveyed poses: a recorded not-applicable, exit 1
    out = d / "out-opencv"
    assert main(["calibrate", str(d), "--calibrator", "opencv", "--known-poses",
                 "-o", str(out)]) == 1
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "not-applicable"


def test_bad_input_exits_2(tmp_path, capsys):
    assert main(["calibrate", str(tmp_path / "nope")]) == 2
    assert "is not a directory" in capsys.readouterr().err
    assert main(["calibrate", str(tmp_path)]) == 2
    assert "no poseN.png + poseN.json pairs" in capsys.readouterr().err

'''camval calibrate: from rendered images + sidecars to a fitted model and a summary'''

import json

import pytest
from synthetic import catalogue_models

from camval.cli import main
from reference_models.cahvore import truncate
from reference_models.jpl_files import read_model


@pytest.fixture(scope="module")
def rendered_dir(tmp_path_factory):
    r'''`camval render MODEL --poses DIR`: 6 planned poses of the 640x480 Rocky8 hazcam
truncated to CAHVOR (ray-cast K=16, 16-bit PNG, JSON sidecars)'''
    from reference_models.jpl_files import write_model
    d = tmp_path_factory.mktemp("poses")
    truth = truncate(dict(catalogue_models())["17"], "CAHVOR")
    write_model(truth, d / "truth.cahvor")
    assert main(["render", str(d / "truth.cahvor"), "--poses", str(d / "poses")]) == 0
    return d / "poses", truth


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


def test_a_model_the_calibrator_cannot_fit_exits_2(tmp_path, capsys):
    import json

    import numpy as np

    from renderers.png import save_png16
    truth = dict(catalogue_models())["15"]
    save_png16(tmp_path / "pose0.png", np.zeros((truth.height, truth.width), np.float32))
    side = {"model": {"C": truth.C.tolist(), "A": truth.A.tolist(), "H": truth.H.tolist(),
                      "V": truth.V.tolist(), "O": truth.O.tolist(), "R": truth.R.tolist(),
                      "width": truth.width, "height": truth.height},
            "Rt_cam_board": np.vstack((np.eye(3), [0, 0, 2.0])).tolist(), "target": "dots"}
    (tmp_path / "pose0.json").write_text(json.dumps(side))
    assert main(["calibrate", str(tmp_path), "--calibrator", "opencv", "--model", "CAHVOR"]) == 2
    assert "calibrator opencv cannot fit 'CAHVOR'" in capsys.readouterr().err

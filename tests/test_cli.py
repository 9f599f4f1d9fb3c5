'''The camval command line: instant --help, the catalogue subcommand, user errors'''

import os
import subprocess
import sys
from pathlib import Path

import pytest

from camval.cli import main
from reference_models.jpl_files import read_model

REPO = Path(__file__).resolve().parent.parent


def camval(*args):
    r'''Run camval in a subprocess: (returncode, stdout, stderr)'''
    exe = Path(sys.executable).with_name("camval")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "camval.cli"]
    r = subprocess.run(cmd + list(args), capture_output=True, text=True, cwd=REPO,
                       timeout=120)
    return r.returncode, r.stdout, r.stderr


def test_help_is_instant():
    rc, out, err = camval("--help")
    assert rc == 0, err
    assert out.startswith("usage: camval")
    assert "catalogue" in out


def test_help_imports_nothing_heavy():
    # the proxy for "instant": no numpy/mrcal import before the arguments are parsed
    code = ("import sys\nfrom camval.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "heavy = [m for m in ('numpy', 'mrcal', 'cv2', 'scipy') if m in sys.modules]\n"
            "print('HEAVY', heavy)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=REPO, timeout=120)
    assert "HEAVY []" in r.stdout, r.stdout + r.stderr


def test_user_error_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.cahvor"
    bad.write_text("Model = CAHV = perspective, linear\nDimensions = 640 480\n"
                   "C = 0 0 0\nA = 0 0 5\nH = 500 0 320\nV = 0 500 240\n")
    rc, out, err = camval("catalogue", "show", str(bad))
    assert rc == 2
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert str(bad) in lines[0] and "line 4" in lines[0] and "unit vector" in lines[0]


def test_list(capsys):
    assert main(["catalogue", "list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:3] == ["id", "rover", "role"]
    rows = [line for line in out[1:] if not line.startswith("M:")]
    assert len(rows) == 33
    row15 = next(r for r in rows if r.split()[0] == "15").split()
    assert row15[1:3] == ["MER", "B"] and "CAHVOR" in row15 and "1024x1024" in row15
    assert "45.37" in row15 and "90.0239" in row15
    assert any(r.startswith("SuperCam") and r.endswith(" M") for r in rows)


def test_list_shows_overlay(tmp_path, capsys):
    model = tmp_path / "mine.cahvor"
    assert main(["catalogue", "export", "16", "--format", "cahvor", "-o", str(model)]) == 0
    ov = tmp_path / "ov.toml"
    ov.write_text('[[replace]]\nid = 15\nfile = "mine.cahvor"\n')
    capsys.readouterr()
    assert main(["catalogue", "list", "--overlay", str(ov)]) == 0
    row15 = next(r for r in capsys.readouterr().out.splitlines() if r.split()[0] == "15")
    assert "user (overlay)" in row15 and "45.51" in row15


def test_show(capsys):
    assert main(["catalogue", "show", "12"]) == 0
    out = capsys.readouterr().out
    for words in ("MER B front hazcam left", "CAHVORE (type 3, linearity 0.37)",
                  "Hc        496.06915", "Hs        454.771502", "theta     90.0221882",
                  "E           0.001442 0.001522 0.000483", "serial      120",
                  "central   no"):
        assert words in out, words


def test_export_cahvor_and_no_overwrite(tmp_path, capsys):
    out = tmp_path / "x.cahvor"
    assert main(["catalogue", "export", "SuperCam", "--format", "cahvor", "-o", str(out)]) == 0
    m = read_model(out)
    assert m.mirrored and m.family == "CAHV"
    before = out.read_text()
    assert main(["catalogue", "export", "15", "--format", "cahvor", "-o", str(out)]) == 2
    assert "not overwriting" in capsys.readouterr().err
    assert out.read_text() == before
    assert main(["catalogue", "export", "15", "--format", "cahvor", "-o", str(out),
                 "--force"]) == 0
    assert read_model(out).family == "CAHVOR"


def test_export_cameramodel(tmp_path, capsys):
    import mrcal

    out = tmp_path / "x.cameramodel"
    assert main(["catalogue", "export", "15", "--format", "cameramodel", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "mrcal cannot represent" in err and "--orthogonalise" in err
    assert not out.exists()
    assert main(["catalogue", "export", "15", "--format", "cameramodel", "-o", str(out),
                 "--orthogonalise"]) == 0
    assert mrcal.cameramodel(str(out)).intrinsics()[0] == "LENSMODEL_CAHVOR"


@pytest.mark.parametrize("args, words", [
    (["catalogue", "show", "99"], "no catalogue slot 99"),
    (["catalogue", "show", "NoSuchCam"], "unknown camera 'NoSuchCam'"),
    (["catalogue", "list", "--overlay", "/nonexistent/ov.toml"], "no such file"),
])
def test_user_errors_in_process(args, words, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and err[0].startswith("camval catalogue: error:")


def test_bad_arguments_exit_2(capsys):
    with pytest.raises(SystemExit) as info:
        main(["catalogue", "export", "15", "--format", "png", "-o", os.devnull])
    assert info.value.code == 2
    assert "invalid choice: 'png'" in capsys.readouterr().err

'''JPL model files (.cahv/.cahvor/.cahvore), PDS3 labels and the M2020 JSON list'''

import re
from pathlib import Path

import mrcal
import mrcal.cahvor
import numpy as np
import pytest

from reference_models.cahvore import CAHVOR
from reference_models.errors import ModelFileError
from reference_models.jpl_files import (
    OutputExistsError,
    jpl_theta,
    parse_model_text,
    read_model,
    write_model,
)
from reference_models.m2020_json import read_m2020_json
from reference_models.pds3 import read_pds3_model

SOURCES_DIR = Path(__file__).parent / "data" / "catalogue_sources"
FIELDS = ("C", "A", "H", "V", "O", "R", "E")
M2020_JSON = SOURCES_DIR / "m2020-camera-models.json"
PDS_LABELS = sorted((SOURCES_DIR / "pds_labels").glob("*.LBL"))


def assert_same_model(a, b):
    assert type(a) is type(b)
    assert (a.width, a.height) == (b.width, b.height)
    for name in FIELDS:
        if hasattr(a, name):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    if a.family == "CAHVORE":
        assert (a.model_type, a.linearity) == (b.model_type, b.linearity)


def grid_points(m, n=9, k=3.0):
    xs = np.linspace(-0.5, m.width - 0.5, n)
    ys = np.linspace(-0.5, m.height - 0.5, n)
    q = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    o, v = m.unproject(q)
    return o + k * v


def mrcal_project(cm, p):
    return mrcal.project(mrcal.transform_point_Rt(cm.Rt_cam_ref(), p), *cm.intrinsics())


# --- write -> read ---------------------------------------------------------------

def test_write_read_is_exact(catalogue_entry, tmp_path):
    m = catalogue_entry.model
    path = tmp_path / f"m.{m.family.lower()}"
    write_model(m, path)
    assert_same_model(read_model(path), m)
    # the derived lines agree with the vectors
    text = path.read_text()
    assert f"Theta = {jpl_theta(m)!r}" in text


def test_write_refuses_to_overwrite(tmp_path):
    path = tmp_path / "x.cahvor"
    path.write_text("precious\n")
    m = CAHVOR(C=[0, 0, 0], A=[0, 0, 1], H=[500, 0, 320], V=[0, 500, 240], O=[0, 0, 1],
               R=[0, 0.01, 0], width=640, height=480)
    with pytest.raises(OutputExistsError, match="not overwriting"):
        write_model(m, path)
    assert path.read_text() == "precious\n"
    write_model(m, path, overwrite=True)
    assert_same_model(read_model(path), m)


def test_jpl_theta_sign(catalogue):
    assert jpl_theta(catalogue.get(15).model) == pytest.approx(-np.radians(90.0239), abs=1e-6)
    assert jpl_theta(catalogue.get("SuperCam").model) == pytest.approx(np.radians(75.288),
                                                                       abs=1e-5)


# --- round trips through mrcal -----------------------------------------------------

def _not_mirrored(catalogue):
    return [e.key for e in catalogue if not e.model.mirrored]


def test_mrcal_reads_what_we_write(catalogue, tmp_path):
    keys = _not_mirrored(catalogue)
    assert len(keys) == 32
    for key in keys:
        m = catalogue.get(key).model.with_theta_90()
        path = tmp_path / f"{key}.cahvor"
        write_model(m, path)
        # mrcal's .cahvor reader itself; mrcal.cameramodel(path) would pass the
        # result through its .cameramodel text format, which keeps ~10 digits
        cm = mrcal.cahvor.read(str(path))
        p = grid_points(m)
        err = np.max(np.abs(mrcal_project(cm, p) - m.project(p)))
        assert err < 1e-9, f"{key}: {err:.3g} px"
        assert tuple(cm.imagersize()) == (m.width, m.height)
        cm = mrcal.cameramodel(str(path))
        err = np.max(np.abs(mrcal_project(cm, p) - m.project(p)))
        assert err < 1e-4, f"{key}: {err:.3g} px through mrcal.cameramodel"


def test_we_read_what_mrcal_writes(catalogue, tmp_path):
    from reference_models.mrcal_convert import to_mrcal

    for key in _not_mirrored(catalogue):
        m = catalogue.get(key).model.with_theta_90()
        cm = to_mrcal(m)
        path = tmp_path / f"{key}.cahvor"
        cm.write(str(path))
        ours = read_model(path)
        assert ours.family == m.family
        p = grid_points(m)
        # mrcal writes 10 decimals: C to 1e-10 m, A to 1e-10 rad
        err = np.max(np.abs(ours.project(p) - mrcal_project(cm, p)))
        assert err < 1e-5, f"{key}: {err:.3g} px"


# --- bad input: one case each --------------------------------------------------------

GOOD = """\
# a navcam-like CAHVOR
Model = CAHVOR = perspective, distortion
Dimensions = 1024 1024
C = 0.1 0.2 0.3
A = 0 0 1
H = 1200 0 511.5
V = 0 1200 511.5
O = 0 0.00999950003749688 0.99995000374968752
R = 0.001 -0.01 0.02
Hs    = 1200
Hc    = 511.5
Vs    = 1200
Vc    = 511.5
Theta = -1.5707963267948966 (-90.000000 deg)
"""

GOOD_CAHVORE = """\
Model = CAHVORE3,0.37 = general
Dimensions = 1024 1024
C = 0.1 0.2 0.3
A = 0 0 1
H = 450 0 511.5
V = 0 450 511.5
O = 0 0 1
R = 0 -0.012 -0.0075
E = 0.0014 0.0015 0.0005
"""


def _swap(text, old, new):
    assert old in text
    return text.replace(old, new)


def _lineno(text, start):
    return next(i for i, line in enumerate(text.splitlines(), 1) if line.startswith(start))


BAD = {
    # case: (text, the line the error must name (start of that line), words in the message)
    "missing vector": (_swap(GOOD, "V = 0 1200 511.5\n", ""), "Model", "V vector is missing"),
    "missing vector, no Model line": (
        _swap(_swap(GOOD, "H = 1200 0 511.5\n", ""), "Model = CAHVOR = perspective, distortion\n",
              ""), None, "H vector is missing"),
    "wrong count": (_swap(GOOD, "H = 1200 0 511.5", "H = 1200 0"), "H =",
                    "H has 2 number(s); expected 3"),
    "non-numeric": (_swap(GOOD, "C = 0.1 0.2 0.3", "C = 0.1 two 0.3"), "C =",
                    "'two' is not a number"),
    "NaN": (_swap(GOOD, "R = 0.001 -0.01 0.02", "R = 0.001 nan 0.02"), "R =", "not finite"),
    "inf": (_swap(GOOD, "C = 0.1 0.2 0.3", "C = 0.1 0.2 -inf"), "C =", "not finite"),
    "|A| far from 1": (_swap(GOOD, "A = 0 0 1", "A = 0 0 1.1"), "A =",
                       "expected a unit vector"),
    "|O| far from 1": (_swap(GOOD, "O = 0 0.00999950003749688 0.99995000374968752",
                             "O = 0 0 0.5"), "O =", "expected a unit vector"),
    "A parallel to H": (_swap(GOOD, "H = 1200 0 511.5", "H = 0 0 511.5"), "H =",
                        "A is parallel to H"),
    "A parallel to V": (_swap(GOOD, "V = 0 1200 511.5", "V = 0 0 -3"), "V =",
                        "A is parallel to V"),
    "negative focal length (Hs line)": (_swap(GOOD, "Hs    = 1200", "Hs    = -1200"), "Hs",
                                        "negative focal length"),
    "negative focal length (Theta sign)": (
        _swap(GOOD, "Theta = -1.5707963267948966", "Theta = 1.5707963267948966"), "Theta",
        "negative focal length"),
    "Hs disagrees": (_swap(GOOD, "Hs    = 1200", "Hs    = 1210"), "Hs", "disagrees"),
    "O behind the camera": (_swap(GOOD, "O = 0 0.00999950003749688 0.99995000374968752",
                                  "O = 0 0 -1"), "O =", "O points away from A"),
    "unknown CAHVORE type": (_swap(GOOD_CAHVORE, "CAHVORE3,0.37", "CAHVORE4,0.37"), "Model",
                             "unknown CAHVORE type 4"),
    "CAHVORE type 3 without linearity": (_swap(GOOD_CAHVORE, "CAHVORE3,0.37", "CAHVORE3"),
                                         "Model", "needs a linearity"),
    "CAHVORE type 1 with a linearity": (_swap(GOOD_CAHVORE, "CAHVORE3,0.37", "CAHVORE1,0.5"),
                                        "Model", "type 1 has linearity 1"),
    "E without a Model line": (_swap(GOOD_CAHVORE, "Model = CAHVORE3,0.37 = general\n", ""),
                               None, "no 'Model = CAHVORE"),
    "E in a CAHVOR": (_swap(GOOD, "R = 0.001 -0.01 0.02\n",
                            "R = 0.001 -0.01 0.02\nE = 0 0 0\n"), "E =",
                      "does not belong to a CAHVOR"),
    "unknown model": (_swap(GOOD, "Model = CAHVOR =", "Model = PSPH ="), "Model",
                      "unknown model 'PSPH'"),
    "image width 0": (_swap(GOOD, "Dimensions = 1024 1024", "Dimensions = 0 1024"),
                      "Dimensions", "expected positive width and height"),
    "image height negative": (_swap(GOOD, "Dimensions = 1024 1024", "Dimensions = 1024 -5"),
                              "Dimensions", "expected positive width and height"),
    "image size not an integer": (_swap(GOOD, "Dimensions = 1024 1024",
                                        "Dimensions = 1024.5 1024"), "Dimensions",
                                  "not an integer"),
    "image size missing": (_swap(GOOD, "Dimensions = 1024 1024\n", ""), None,
                           "image size is missing"),
    "vector given twice": (_swap(GOOD, "C = 0.1 0.2 0.3\n", "C = 0.1 0.2 0.3\nC = 0 0 0\n"),
                           "C = 0 0 0", "given twice"),
    "covariance of the wrong size": (GOOD + "S =\n" + " 0.0 0.0\n" * 2, "S =",
                                     "expected 18 rows of 18 numbers"),
    "mrcal OpenCV extension": (GOOD + "LENSMODEL_OPENCV4 = 0.1 0 0 0\n", "LENSMODEL",
                               "has no JPL equivalent"),
    "unparseable line": (_swap(GOOD, "C = 0.1 0.2 0.3", "C 0.1 0.2 0.3"), "C 0.1",
                         "expected 'NAME = values'"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_model_file(case, tmp_path):
    text, line_start, words = BAD[case]
    path = tmp_path / "bad.cahvor"
    path.write_text(text)
    with pytest.raises(ModelFileError) as info:
        read_model(path)
    e = info.value
    assert e.path == str(path)
    assert str(path) in str(e)
    assert words in str(e), str(e)
    if line_start is None:
        assert e.line is None
    else:
        expected = _lineno(text, line_start)
        assert e.line == expected, str(e)
        assert f"line {expected}:" in str(e)
    assert "\n" not in str(e)


def test_good_files_read():
    m = parse_model_text(GOOD)
    assert m.family == "CAHVOR"
    assert m.photogrammetric().Hs == pytest.approx(1200.0, abs=1e-9)
    e = parse_model_text(GOOD_CAHVORE)
    assert (e.family, e.model_type, e.linearity) == ("CAHVORE", 3, 0.37)
    e1 = parse_model_text(_swap(GOOD_CAHVORE, "CAHVORE3,0.37 = general", "CAHVORE1 = perspective"))
    assert (e1.model_type, e1.linearity) == (1, 1.0)
    # without a Model line the vectors decide
    c = parse_model_text(_swap(_swap(GOOD, "Model = CAHVOR = perspective, distortion\n", ""),
                               "O = 0 0.00999950003749688 0.99995000374968752\n"
                               "R = 0.001 -0.01 0.02\n", ""))
    assert c.family == "CAHV"


@pytest.mark.parametrize("mtype, linearity", [(1, None), (2, None), (3, 0.5)])
def test_cahvore_types_round_trip(mtype, linearity, tmp_path):
    m = parse_model_text(GOOD_CAHVORE)
    m = type(m)(C=m.C, A=m.A, H=m.H, V=m.V, O=m.O, R=m.R, E=m.E, model_type=mtype,
                linearity=linearity, width=m.width, height=m.height)
    path = tmp_path / "t.cahvore"
    write_model(m, path)
    assert_same_model(read_model(path), m)
    cm = mrcal.cahvor.read(str(path))
    assert cm.intrinsics()[0] == f"LENSMODEL_CAHVORE_linearity={m.linearity:g}"
    p = grid_points(m, 5)
    np.testing.assert_allclose(mrcal_project(cm, p), m.project(p), rtol=0, atol=1e-9)


def _cmod_text(m):
    r'''The text JPL's cmod_cahvore_write prints (its printf formats, blank lines)'''
    ph = m.photogrammetric()
    out = ["# written like cmod_cahvore_write\n", "\n",
           f"Model = CAHVORE3,{m.linearity:g} = general\n", "\n",
           f"Dimensions = {m.width} {m.height}\n", "\n"]
    for name in "CAHVORE":
        out.append(f"{name} = " + " ".join(f"{x:16.9f}" for x in getattr(m, name)) + "\n")
    out += ["\n", "S =\n"] + [" ".join(f"{0.0:16.9e}" for _ in range(21)) + "\n"] * 21
    theta = jpl_theta(m)
    out += ["\n", f"Hs    = {ph.Hs:16.9f}\n", f"Hc    = {ph.Hc:16.9f}\n",
            f"Vs    = {ph.Vs:16.9f}\n", f"Vc    = {ph.Vc:16.9f}\n",
            f"Theta = {theta:16.9f} ({np.degrees(theta):f} deg)\n", "\n", "S internal =\n"]
    out += [" ".join(f"{0.0:16.9e}" for _ in range(5)) + "\n"] * 5 + ["\n"]
    return "".join(out)


def test_reads_jpl_cmod_output(catalogue, tmp_path):
    m = catalogue.get(12).model
    path = tmp_path / "cmod.cahvore"
    path.write_text(_cmod_text(m))
    r = read_model(path)
    assert (r.family, r.model_type, r.linearity) == ("CAHVORE", 3, 0.37)
    for name in "CAHVORE":
        np.testing.assert_allclose(getattr(r, name), getattr(m, name), rtol=0, atol=1e-9)


def test_missing_file(tmp_path):
    with pytest.raises(ModelFileError, match="no such file"):
        read_model(tmp_path / "nothere.cahvor")


# --- PDS3 labels ----------------------------------------------------------------------

def _label_numbers(path):
    r'''MODEL_COMPONENT_n and the IMAGE size straight from the label text'''
    text = path.read_text(errors="replace")
    comps = {int(n): tuple(float(x) for x in v.split(","))
             for n, v in re.findall(r"MODEL_COMPONENT_(\d)\s*=\s*\(([^)]*)\)", text)}
    scalars = {int(n): float(v)
               for n, v in re.findall(r"MODEL_COMPONENT_(\d)\s*=\s*([-0-9.eE]+)\s*$", text,
                                      flags=re.M)}
    image = text[text.index("OBJECT                            = IMAGE\n"):]
    lines = int(re.search(r"^\s*LINES\s*=\s*(\d+)", image, re.M).group(1))
    samples = int(re.search(r"^\s*LINE_SAMPLES\s*=\s*(\d+)", image, re.M).group(1))
    return comps, scalars, (samples, lines)


def test_there_are_nine_labels():
    assert len(PDS_LABELS) == 9


@pytest.mark.parametrize("label", PDS_LABELS, ids=[p.stem for p in PDS_LABELS])
def test_pds3_label_imports_exactly(label, catalogue):
    m = read_pds3_model(label)
    citing = [e for e in catalogue if e.source and label.stem in e.source]
    if citing:
        # the catalogue entry citing the label holds exactly these numbers
        for e in citing:
            assert_same_model(m, e.model)
    comps, scalars, size = _label_numbers(label)
    assert (m.width, m.height) == size
    names = {1: "C", 2: "A", 3: "H", 4: "V", 5: "O", 6: "R", 7: "E"}
    for n, name in names.items():
        if n in comps:
            raw = np.array(comps[n])
            got = getattr(m, name)
            if name in ("A", "O"):
                np.testing.assert_array_equal(got, raw / np.linalg.norm(raw))
            else:
                np.testing.assert_array_equal(got, raw)
    if m.family == "CAHVORE":
        assert (m.model_type, m.linearity) == (int(scalars[8]), scalars[9])


def test_pds3_labels_cited_by_the_catalogue(catalogue):
    cited = {p.stem for p in PDS_LABELS if any(e.source and p.stem in e.source for e in catalogue)}
    assert cited == {"1F483288473EFFCMUFP1214L0M1", "1P491287702ILFCNY9P2584L2M1",
                     "1N491020376ILFCNY9P0706L0M1", "NRB_701383954RAS_F0933408NCAM00200M1"}


def test_pds3_bad_label(tmp_path):
    text = PDS_LABELS[0].read_text(errors="replace")
    bad = tmp_path / "bad.LBL"
    bad.write_text(text.replace("MODEL_COMPONENT_8               = 3.0",
                                "MODEL_COMPONENT_8               = 7.0"))
    with pytest.raises(ModelFileError) as info:
        read_pds3_model(bad)
    assert "unknown CAHVORE type 7" in str(info.value)
    assert info.value.line == _lineno(bad.read_text(), "  MODEL_COMPONENT_8")
    bad.write_text(text.replace("MODEL_COMPONENT_3               = (351.362,452.204,353.494)",
                                "MODEL_COMPONENT_3               = (351.362,452.204)"))
    with pytest.raises(ModelFileError, match=r"MODEL_COMPONENT_3 \(H\) has 2 number"):
        read_pds3_model(bad)
    parms = tmp_path / "parms.LBL"
    parms.write_text(text.replace("= GEOMETRIC_CAMERA_MODEL\n", "= GEOMETRIC_CAMERA_MODEL_PARMS\n"))
    assert "GEOMETRIC_CAMERA_MODEL_PARMS" in parms.read_text()
    assert_same_model(read_pds3_model(parms), read_pds3_model(PDS_LABELS[0]))
    bad.write_text("PDS_VERSION_ID = PDS3\nOBJECT = IMAGE\n LINES = 4\nEND_OBJECT = IMAGE\nEND\n")
    with pytest.raises(ModelFileError, match="no 'GROUP = GEOMETRIC_CAMERA_MODEL'"):
        read_pds3_model(bad)


# --- M2020 JSON -------------------------------------------------------------------------

def test_m2020_json_matches_the_catalogue(catalogue):
    models = read_m2020_json(M2020_JSON)
    assert len(models) == 27
    citing = 0
    for e in catalogue:
        m = re.search(r'm2020-camera-models\.json entry "([^"]+)"', e.source or "")
        if m:
            assert_same_model(models[m.group(1)], e.model)
            citing += 1
    assert citing == 20  # slots 1-4, 17, 19-22 and the 11 extras
    assert models["SuperCam"].family == "CAHV" and models["SuperCam"].mirrored
    assert models["NAVL"].family == "CAHVORE" and models["NAVL"].linearity == 0.37


def test_m2020_json_bad_entry(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('[{"name": "X", "model": {"type": "cahvor", "C": [0,0,0], "A": [0,0,1],'
                   ' "H": [1,0,0], "V": [0,1,0], "O": [0,0,1], "R": [0,0], '
                   '"width": 10, "height": 10}}]')
    with pytest.raises(ModelFileError, match=r"entry 'X': R = \[0, 0\]; expected 3 numbers"):
        read_m2020_json(bad)

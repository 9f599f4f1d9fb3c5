'''The packaged camera catalogue: contents, provenance, look-up and overlays'''

import numpy as np
import pytest

from reference_models.catalogue import (
    CatalogueError,
    field_of_view_deg,
    load_catalogue,
)
from reference_models.errors import ModelFileError, UnknownCameraError
from reference_models.jpl_files import write_model


def test_slots_and_extras(catalogue):
    slots = catalogue.slots()
    assert [e.id for e in slots] == list(range(1, 23))
    assert len(catalogue.extras()) == 11
    assert len(catalogue) == 33
    assert {e.status for e in catalogue} == {"real", "substitute", "derived"}
    # the paper's numbering: MER B navcams are 15 (left) and 16 (right)
    assert (slots[14].rover, slots[14].role, slots[14].side) == ("MER B", "navcam", "left")
    assert slots[14].name == "MER B navcam left"
    families = {e.model.family for e in catalogue}
    assert families == {"CAHV", "CAHVOR", "CAHVORE"}


def test_provenance_is_kept(catalogue):
    for e in catalogue:
        assert e.source, e.key
        assert e.provenance["source"] == e.source
        if e.status == "substitute":
            assert e.stands_in, e.key
        if e.status == "derived":
            assert e.derivation and e.source.startswith("slot "), e.key
    assert catalogue.get(12).provenance["serial"] == "120"
    assert "image size not in the source" in catalogue.get("SuperCam").provenance["size_note"]
    assert catalogue.get(21).frame == "Body_RSM_EL"


def test_derived_slots_keep_their_source_intrinsics(catalogue):
    derived = [e for e in catalogue.slots() if e.status == "derived"]
    assert len(derived) == 8
    for e in derived:
        src = catalogue.get(int(e.source.split()[1])).model
        m = e.model
        ph, phs = m.photogrammetric(), src.photogrammetric()
        for name in ("Hs", "Vs", "Hc", "Vc"):
            assert getattr(ph, name) == pytest.approx(getattr(phs, name), abs=2e-3), e.key
        np.testing.assert_array_equal(m.R, src.R)
        if m.family == "CAHVORE":
            np.testing.assert_array_equal(m.E, src.E)
        if "stereo partner" in e.derivation:
            # moved along H' by the stated baseline; same orientation
            baseline = float(e.derivation.split("moved ")[1].split(" m")[0])
            d = m.C - src.C
            assert np.linalg.norm(d) == pytest.approx(baseline, abs=1e-6)
            assert abs(d @ ph.Hp) == pytest.approx(baseline, abs=1e-5)


def test_catalogue_is_package_data():
    import importlib.resources
    import tomllib

    text = importlib.resources.files("reference_models").joinpath(
        "data", "cameras.toml").read_text()
    data = tomllib.loads(text)
    assert len(data["camera"]) == 22 and len(data["extra"]) == 11


def test_get(catalogue):
    assert catalogue.get(15) is catalogue.get("15") is catalogue.get(" 15 ")
    assert catalogue.get(np.int64(15)) is catalogue.get(15)
    assert catalogue.get("SuperCam") is catalogue.get("supercam")
    assert catalogue.get("MER B navcam left") is catalogue.get(15)
    assert catalogue.get("SuperCam").model.mirrored


@pytest.mark.parametrize("spec", [0, 23, "23", "NoSuchCam", 1.5, None])
def test_get_unknown(catalogue, spec):
    with pytest.raises(UnknownCameraError) as info:
        catalogue.get(spec)
    msg = str(info.value)
    assert "slot ids 1-22" in msg and "SuperCam" in msg and "MCAM_Z_LEFT-Z026" in msg


def test_get_model_file(catalogue, tmp_path):
    path = tmp_path / "mine.cahvor"
    write_model(catalogue.get(13).model, path)
    e = catalogue.get(str(path))
    assert (e.kind, e.status, e.id, e.source) == ("file", "file", None, str(path))
    np.testing.assert_array_equal(e.model.H, catalogue.get(13).model.H)
    assert catalogue.get(path).model.family == "CAHVOR"
    with pytest.raises(ModelFileError, match="no such file"):
        catalogue.get(str(tmp_path / "missing.cahvor"))


def test_field_of_view(catalogue):
    # published: MER navcam 45 deg, MER pancam 16 deg, MER hazcam ~124 deg
    assert field_of_view_deg(catalogue.get(15).model)[0] == pytest.approx(45.0, abs=0.5)
    assert field_of_view_deg(catalogue.get(13).model)[0] == pytest.approx(16.0, abs=0.2)
    assert field_of_view_deg(catalogue.get(12).model)[0] == pytest.approx(125.0, abs=1.5)


# --- overlays --------------------------------------------------------------------

def _overlay(tmp_path, text):
    p = tmp_path / "overlay.toml"
    p.write_text(text)
    return p


def test_overlay_replaces_a_slot(catalogue, tmp_path):
    mine = catalogue.get(16).model
    (tmp_path / "models").mkdir()
    write_model(mine, tmp_path / "models" / "navcam.cahvor")
    ov = _overlay(tmp_path, '[[replace]]\nid = 15\nfile = "models/navcam.cahvor"\n'
                            'note = "from the calibration bundle"\n'
                            '[[replace]]\nname = "SuperCam"\nfile = "models/navcam.cahvor"\n'
                            '[[extra]]\nname = "my-navcam"\nfile = "models/navcam.cahvor"\n'
                            'role = "navcam"\n')
    cat = load_catalogue(overlay=ov)
    e = cat.get(15)
    assert (e.id, e.rover, e.role, e.side, e.status) == (15, "MER B", "navcam", "left", "user")
    assert e.source == str(tmp_path / "models" / "navcam.cahvor")
    assert e.provenance["note"] == "from the calibration bundle"
    np.testing.assert_array_equal(e.model.C, mine.C)
    assert e.replaces.status == "real" and e.replaces.key == "15"
    np.testing.assert_array_equal(e.replaces.model.H, catalogue.get(15).model.H)
    assert cat.get("SuperCam").model.family == "CAHVOR"
    assert cat.get("my-navcam").role == "navcam"
    assert len(cat) == 34 and len(cat.slots()) == 22
    # the packaged catalogue is untouched
    assert load_catalogue().get(15).status == "real"


@pytest.mark.parametrize("text, error, words", [
    ('[[replace]]\nid = 99\nfile = "x.cahvor"\n', UnknownCameraError, "no catalogue slot 99"),
    ('[[replace]]\nid = 15\nfile = "missing.cahvor"\n', ModelFileError, "no such file"),
    ('[[replace]]\nid = 15\nfil = "x.cahvor"\n', CatalogueError, "unknown key(s) fil"),
    ('[[replace]]\nid = 15\nname = "SuperCam"\nfile = "x.cahvor"\n', CatalogueError,
     "either id"),
    ('[[replace]]\nid = 15\n', CatalogueError, 'needs file = "path"'),
    ('[[extra]]\nname = "SuperCam"\nfile = "x.cahvor"\n', CatalogueError, "exists already"),
    ('[[camera]]\nid = 1\n', CatalogueError, "unknown table(s) camera"),
    ('[[replace]\n', CatalogueError, "not valid TOML"),
])
def test_overlay_errors(tmp_path, text, error, words):
    with pytest.raises(error) as info:
        load_catalogue(overlay=_overlay(tmp_path, text))
    assert words in str(info.value)


def test_overlay_file_missing(tmp_path):
    with pytest.raises(CatalogueError, match="no such file"):
        load_catalogue(overlay=tmp_path / "none.toml")

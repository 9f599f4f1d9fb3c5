r'''benchmarks/random_cameras.py: the files it writes read back with the drawn field of view and
size, the same files for the same seed, and the draw in each file's note'''

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from reference_models.catalogue import field_of_view_deg, load_model_file

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def rc():
    spec = importlib.util.spec_from_file_location(
        "random_cameras", ROOT / "benchmarks" / "random_cameras.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _write(rc, seed, n, out):
    rc.main(["--seed", str(seed), "--n", str(n), "--out", str(out)])
    return sorted(Path(out).iterdir())


def test_files_read_back_with_the_drawn_field_and_size(rc, tmp_path):
    cams, _ = rc.generate(3, 6)
    files = _write(rc, 3, 6, tmp_path)
    assert [p.name for p in files] == sorted(name for name, *_ in cams)
    by_name = {name: d for name, _, _, d in cams}
    for path in files:
        d = by_name[path.name]
        m = load_model_file(path)
        assert (m.width, m.height) == (d["width"], d["height"])
        assert 320 <= m.width <= 5120 and 240 <= m.height <= 3840
        assert type(m).__name__ == d["family"]
        hfov, vfov = field_of_view_deg(m)
        # the file is written at full precision: the field is the drawn one to the solver's
        # tolerance (1e-6 deg)
        assert hfov == pytest.approx(d["hfov"], abs=1e-6)
        assert 15.0 <= hfov <= 180.0
        assert vfov == pytest.approx(d["vfov"], abs=1e-6)
        text = path.read_text()
        assert f"hfov {d['hfov']:.4f} deg" in text
        assert f"--seed 3) #{d['index']}" in text


def test_same_seed_same_files_other_seed_other_files(rc, tmp_path):
    a = _write(rc, 11, 4, tmp_path / "a")
    b = _write(rc, 11, 4, tmp_path / "b")
    c = _write(rc, 12, 4, tmp_path / "c")
    assert [p.name for p in a] == [p.name for p in b]
    assert all(p.read_bytes() == q.read_bytes() for p, q in zip(a, b, strict=True))
    assert [p.read_bytes() for p in a] != [p.read_bytes() for p in c]


def test_every_camera_is_one_to_one_over_its_image(rc):
    # a wide spread of draws (fisheyes among them): each unprojects and projects back to
    # itself and its ray angle grows outwards
    cams, _ = rc.generate(5, 40)
    fams = {d["family"] for *_, d in cams}
    assert fams == {"CAHV", "CAHVOR", "CAHVORE"}
    assert max(d["hfov"] for *_, d in cams) > 130
    for name, m, _, d in cams:
        assert rc.check_mapping(m) is None, name
        assert d["hfov"] < 90 or d["family"] != "CAHV"
        assert d["hfov"] <= 130 or d["family"] == "CAHVORE"
        # principal point within 10% of the size of the middle
        A = np.asarray(m.A)
        cx, cy = np.asarray(m.H) @ A, np.asarray(m.V) @ A
        assert abs(cx - (m.width - 1) / 2) <= 0.1 * m.width + 1e-9
        assert abs(cy - (m.height - 1) / 2) <= 0.1 * m.height + 1e-9
        if d["family"] == "CAHV":
            # skew: the angle between the image axes
            H1 = np.asarray(m.H) - cx * A
            V1 = np.asarray(m.V) - cy * A
            theta = math.degrees(math.acos(-(H1 @ V1) / np.linalg.norm(H1) / np.linalg.norm(V1)))
            assert theta == pytest.approx(d["theta_deg"], abs=1e-9)
            assert 89.0 <= theta <= 91.0
        else:
            tilt = math.degrees(math.acos(np.clip(np.asarray(m.O) @ A, -1, 1)))
            assert tilt <= 2.0 + 1e-9

r'''Target definitions: geometry, ids, the drawn pattern, the tag codes, bad definitions'''

import numpy as np
import pytest

from targets.boards import (
    TargetError,
    apply_grid_transform,
    grid_transforms,
    load_target,
    tag36h11_bits,
    tag36h11_family,
    target_from_dict,
)

DOTS = {"kind": "dots", "nx": 10, "ny": 10, "spacing": 0.1, "dot_diameter": 0.05}


@pytest.mark.parametrize("name,npoints", [("dots", 100), ("apriltag", 144), ("chessboard", 100)])
def test_named_targets_load(name, npoints):
    t = load_target(name)
    assert t.name == name and t.kind == name
    p, ids = t.points(), t.point_ids()
    assert p.shape == (npoints, 3) and p.dtype == np.float64
    assert ids.shape == (npoints,) and len(set(ids.tolist())) == npoints
    assert np.all(p[:, 2] == 0)
    xmin, xmax, ymin, ymax = t.extent
    # every point lies on the board, away from its edge
    assert np.all((p[:, 0] > xmin) & (p[:, 0] < xmax) & (p[:, 1] > ymin) & (p[:, 1] < ymax))
    o = t.outline(8)
    assert o.shape == (32, 3)
    assert np.allclose(o.min(axis=0)[:2], [xmin, ymin]) and np.allclose(o.max(axis=0)[:2],
                                                                         [xmax, ymax])
    d = t.as_dict()
    assert d["Npoints"] == npoints and d["kind"] == name
    import json
    json.dumps(d)


def test_dots_geometry_and_pattern():
    t = load_target("dots")
    p = t.points()
    # point (ix, iy) at (0.1 ix, 0.1 iy), id iy*10 + ix
    assert np.allclose(p[23], [0.3, 0.2, 0.0])
    r = t.dot_radii()
    assert np.isclose(np.median(r), 0.025)
    marks = [iy * 10 + ix for ix, iy in t.spec["orientation_mark"]["dots"]]
    assert np.allclose(r[marks], 0.035) and np.sum(r > 0.03) == 3
    pat = t.pattern()
    assert pat.albedo(0.3, 0.2) == pytest.approx(0.1)        # a dot centre
    assert pat.albedo(0.35, 0.25) == pytest.approx(0.9)      # between dots
    assert pat.albedo(0.3 + 0.024, 0.2) == pytest.approx(0.1)
    assert pat.albedo(0.3 + 0.026, 0.2) == pytest.approx(0.9)
    assert pat.albedo(-0.2, 0.2) == pytest.approx(0.0)       # off the board
    o = t.dot_outlines(1440)
    assert o.shape == (100, 1440, 3)
    assert np.allclose(np.linalg.norm(o[:, :, :2] - p[:, None, :2], axis=-1), r[:, None])


def test_mark_symmetry_is_rejected():
    # (2,2),(6,2),(2,6) is symmetric under the transpose of the grid
    spec = dict(DOTS, orientation_mark={"dot_diameter": 0.07, "dots": [[2, 2], [6, 2], [2, 6]]})
    with pytest.raises(TargetError, match="symmetric"):
        target_from_dict(spec)
    # each named target's mark survives no rotation or flip
    for name, key, n in (("dots", "dots", 10), ("chessboard", "squares", 11)):
        t = load_target(name)
        pos = np.array(t.spec["orientation_mark"][key])
        ref = {tuple(v) for v in pos.tolist()}
        images = []
        for tr in grid_transforms(n, n, n, n):
            i, j = apply_grid_transform(tr, pos[:, 0], pos[:, 1], n, n)
            images.append({(int(a), int(b)) for a, b in zip(i, j, strict=True)})
        assert len(images) == 8 and sum(s == ref for s in images) == 1


def test_grid_transforms_shapes():
    assert len(grid_transforms(10, 10, 10, 10)) == 8
    assert len(grid_transforms(9, 6, 9, 6)) == 4
    assert all(t[0] for t in grid_transforms(6, 9, 9, 6))
    assert grid_transforms(5, 5, 9, 6) == []


def test_chessboard_geometry_and_pattern():
    t = load_target("chessboard")
    p = t.points()
    assert np.allclose(p[0], [0, 0, 0]) and np.allclose(p[99], [0.9, 0.9, 0])
    pat = t.pattern()
    sq = 0.1
    # square (sx, sy) is centred at ((sx-0.5) sq, (sy-0.5) sq); dark when sx + sy is even
    marks = {tuple(v) for v in t.spec["orientation_mark"]["squares"]}
    for sx in range(11):
        for sy in range(11):
            a = pat.albedo((sx - 0.5) * sq, (sy - 0.5) * sq)
            dark = (sx + sy) % 2 == 0 and (sx, sy) not in marks
            assert a == pytest.approx(0.1 if dark else 0.9), (sx, sy)
            # away from the mark dot, a marked square is dark
            if (sx, sy) in marks:
                assert pat.albedo((sx - 0.5) * sq + 0.03, (sy - 0.5) * sq) == pytest.approx(0.1)


def test_tag36h11_codes_are_apriltags():
    fam = tag36h11_family()
    # values from AprilRobotics/apriltag tag36h11.c
    assert len(fam["codes"]) == 587
    assert fam["codes"][0] == 0xd7e00984b and fam["codes"][1] == 0xdda664ca7
    assert fam["codes"][100] == 0x533fe2404 and fam["codes"][586] == 0xe8b772fe0
    assert fam["bit_x"][:5] == [1, 2, 3, 4, 5] and fam["bit_y"][9:14] == [1, 2, 3, 4, 5]
    b = tag36h11_bits(0)
    assert b.shape == (8, 8)
    assert not b[0].any() and not b[-1].any() and not b[:, 0].any() and not b[:, -1].any()
    assert b[1:7, 1:7].sum() == bin(fam["codes"][0]).count("1")
    with pytest.raises(TargetError, match="ids 0..586"):
        tag36h11_bits(587)


def test_apriltag_geometry_and_pattern():
    t = load_target("apriltag")
    s, ratio = 0.13, 0.3
    pitch = s * (1 + ratio)
    p, ids = t.points(), t.point_ids()
    # tag 7 is column 1, row 1; corners bottom-left, bottom-right, top-right, top-left
    k = np.flatnonzero(ids == 4 * 7)[0]
    o = np.array([pitch, pitch])
    assert np.allclose(p[k:k + 4, :2], o + [[0, s], [s, s], [s, 0], [0, 0]])
    pat = t.pattern()
    bit = s / 8
    for tag_id, (i, j) in ((0, (0, 0)), (7, (1, 1)), (35, (5, 5))):
        bits = tag36h11_bits(tag_id)
        cy, cx = np.mgrid[0:8, 0:8]
        x = i * pitch + (cx + 0.5) * bit
        y = j * pitch + (cy + 0.5) * bit
        assert np.array_equal(pat.albedo(x, y) > 0.5, bits), tag_id
    # the gap between tags is light
    assert pat.albedo(s + 0.5 * ratio * s, 0.5 * s) == pytest.approx(0.9)


@pytest.mark.parametrize("change,match", [
    ({"dot_diameter": 0.0}, "dot_diameter"),
    ({"dot_diameter": -0.01}, "dot_diameter"),
    ({"dot_diameter": 0.1}, "smaller than spacing"),
    ({"nx": 0}, "nx, ny >= 1"),
    ({"nx": 2.5}, "integer"),
    ({"spacing": float("nan")}, "finite"),
    ({"board_albedo": 1.5}, "albedo"),
    ({"dot_albedo": 0.9}, "exceed"),
    ({"kind": "hexagons"}, "kind"),
])
def test_bad_definitions(change, match):
    with pytest.raises(TargetError, match=match):
        target_from_dict(dict(DOTS, **change))


def test_bad_files_and_names(tmp_path):
    with pytest.raises(TargetError, match="unknown target 'circles'.*apriltag, chessboard, dots"):
        load_target("circles")
    f = tmp_path / "bad.toml"
    f.write_text("kind = 'dots'\nnx = [\n")
    with pytest.raises(TargetError, match="bad.toml.*not valid TOML"):
        load_target(f)
    f.write_text("kind = 'dots'\nnx = 3\nny = 3\nspacing = 0.1\n")
    with pytest.raises(TargetError, match="missing 'dot_diameter'"):
        load_target(f)
    with pytest.raises(TargetError, match="tag_spacing"):
        target_from_dict({"kind": "apriltag", "nx": 2, "ny": 2, "tag_size": 0.1,
                          "tag_spacing": 0.3001})
    with pytest.raises(TargetError, match="ids"):
        target_from_dict({"kind": "apriltag", "nx": 30, "ny": 30, "tag_size": 0.1})
    with pytest.raises(TargetError, match="defined for 'dots' targets"):
        load_target("chessboard").dot_radii()


def test_target_from_file_round_trip(tmp_path):
    f = tmp_path / "small.toml"
    f.write_text('kind = "dots"\nnx = 3\nny = 2\nspacing = 0.2\ndot_diameter = 0.05\n')
    t = load_target(f)
    assert t.name == "small" and t.grid_shape == (3, 2)
    assert np.allclose(t.points()[5], [0.4, 0.2, 0.0])
    assert np.allclose(t.extent, (-0.2, 0.6, -0.2, 0.4))


def test_pattern_albedo_of_non_finite_points_is_background():
    # a ray missing the board plane gives NaN or inf; warnings are errors here
    for name in ("dots", "apriltag", "chessboard"):
        pat = load_target(name).pattern()
        a = pat.albedo(np.array([np.nan, np.inf, -np.inf, 1e300]), np.array([0.0, 0.0, 0, 0]))
        assert np.all(a == pat.background_value)


@pytest.mark.parametrize("name", ["dots", "apriltag", "chessboard"])
def test_as_dict_spec_rebuilds_the_target(name):
    import json
    t = load_target(name)
    spec = json.loads(json.dumps(t.as_dict()))["spec"]
    u = target_from_dict(spec, source="sidecar.json")
    assert np.array_equal(u.points(), t.points()) and np.array_equal(u.point_ids(), t.point_ids())
    assert u.extent == t.extent and u.kind == t.kind and u.name == t.name
    x = np.linspace(t.extent[0], t.extent[1], 97)
    y = np.linspace(t.extent[2], t.extent[3], 89)
    X, Y = np.meshgrid(x, y)
    assert np.array_equal(u.pattern().albedo(X, Y), t.pattern().albedo(X, Y))

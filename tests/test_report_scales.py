'''Report figures: no outlier swamps a linear axis; maps share one colour scale'''

import math

import numpy as np

from reports.build import verdict
from reports.figures import fig_center, fig_maps, robust_limit


def _rec(cam, cal, hc, family="CAHVOR", map_path=None):
    return {"fullname": f"{cam}/{family}/dots/raycast[spp=16,adaptive]/{cal}[{family}]",
            "camera": str(cam), "model": family, "calibrator": cal,
            "calibrator_model": family, "status": "ok", "renderer": "raycast",
            "settings": {"spp": 16, "adaptive": True},
            "params": {"Hc": hc, "Vc": -hc / 2},
            "artifacts": {"map": map_path} if map_path else {}}


def test_robust_limit_clips_a_diverged_fit_only():
    small = [0.01, -0.02, 0.015, 0.03, -0.01, 0.02, 0.012, 0.018]
    assert robust_limit(small) is None
    lim = robust_limit(small + [1.55e4])
    assert 0.03 < lim < 1.0
    # the paper's line stays on the axis
    assert robust_limit(small + [1.55e4], keep=[0.5]) >= 0.5
    assert robust_limit([1.0, 2.0]) is None     # too few points to call one an outlier


def test_center_figure_lists_what_is_off_scale(tmp_path):
    recs = [_rec(c, "mrcal", 0.02 * (1 + c % 3)) for c in range(1, 12)]
    recs.append(_rec(12, "mrcal", 1.55e4))
    records = {r["fullname"]: r for r in recs}
    f = fig_center(records, tmp_path)
    assert "Off scale" in f.caption and "12 CAHVOR Hc 1.55e+04" in f.caption
    assert "Vc" in f.caption and "11 CAHVOR" not in f.caption


def test_maps_share_one_colour_scale_and_name_the_saturated_panel(tmp_path):
    recs = []
    for i, peak in enumerate([0.01, 0.02, 0.015, 0.012, 50.0]):
        m = np.full((8, 8), peak / 10)
        m[0, 0] = peak
        rel = f"maps/{i}.npy"
        (tmp_path / "maps").mkdir(exist_ok=True)
        np.save(tmp_path / rel, m)
        recs.append(_rec(i + 1, "jpl", 0.0, map_path=rel))
    records = {r["fullname"]: r for r in recs}
    (f,) = fig_maps(records, tmp_path, tmp_path)
    assert "one logarithmic colour scale" in f.caption
    vmax = float(f.caption.split(" to ")[1].split(" px")[0])
    assert 0.02 <= vmax < 50.0 and math.isfinite(vmax)



def test_a_saturated_panel_keeps_its_red_title_in_the_palette_png(tmp_path):
    r'''Smooth maps fill the 256-colour palette with gradients; the saturated panel's title
must stay red (viridis holds no red: every red pixel is that title's), not turn grey'''
    from PIL import Image
    yy, xx = np.mgrid[0:64, 0:64] / 63.0
    (tmp_path / "maps").mkdir()
    recs = []
    for i, peak in enumerate([0.01, 0.02, 0.015, 0.012, 50.0]):
        # three decades across the panel, centred differently in each: many colours
        m = peak * 10.0 ** (-2.5 * np.hypot(xx - i / 5, yy - 0.5))
        np.save(tmp_path / f"maps/{i}.npy", m)
        recs.append(_rec(i + 1, "jpl", 0.0, map_path=f"maps/{i}.npy"))
    (f,) = fig_maps({r["fullname"]: r for r in recs}, tmp_path, tmp_path)
    with Image.open(f.path) as im:
        assert im.mode == "P"
        rgb = np.asarray(im.convert("RGB")).astype(int)
    red = (rgb[..., 0] - rgb[..., 1] > 60) & (rgb[..., 0] - rgb[..., 2] > 60)
    # "5 CAHVOR / max 50 px (saturated)" at 7 pt, 68 dpi: a few hundred red pixels
    assert red.sum() > 100


def test_verdict_line():
    from pathlib import Path
    rec = _rec(15, "jpl", 0.0)
    rec.update(residuals={"rms": 0.001, "max": 0.004}, projection={"rms": 0.001})
    # the default gate judges the renderer: a record without a verdict cannot pass it
    line, rows = verdict({"records": {rec["fullname"]: rec}})
    assert line.startswith("FAIL") and "gate-renderer.toml" in line, line
    assert {r[2] for r in rows} == {"missing"}
    # the absolute limits of campaigns/gate.toml, given explicitly
    absolute = Path(__file__).resolve().parents[1] / "campaigns" / "gate.toml"
    line, rows = verdict({"records": {rec["fullname"]: rec}}, absolute)
    assert line.startswith(("PASS", "FAIL")), line
    bad = dict(rec, residuals={"rms": 5.0, "max": 9.0})
    line, rows = verdict({"records": {rec["fullname"]: bad}}, absolute)
    assert line.startswith("FAIL") and any(r[1] == "residuals.rms" for r in rows)

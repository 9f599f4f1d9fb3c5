r'''The report: figures, tables and a self-contained HTML page checked in headless Chromium

The records are real: exact correspondences (projected dot centres of the
planned poses) recalibrated by the jpl calibrator and compared with the truth
by the runner's own compare stage, plus a genuinely failing calibration (too
few points) and a not-applicable record. The legacy run holds the exact
projections of the legacy (ROAMS) models recalibrated the same way, with the
clean control, and a slow test runs the legacy renderer itself through a
campaign.
'''

import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from synthetic import exact_observations

from harness.calibrators import calibrate
from harness.records import Record, RunStore, make_fullname
from harness.stages import compare_stage, downsample_map
from reference_models.cahvore import truncate
from reference_models.catalogue import load_catalogue
from renderers.legacy import legacy_model
from reports.build import build_report, build_sweep_report, find_sweeps
from reports.figures import (
    calibrator_panels,
    fig_speed,
    pareto_front,
    speed_accuracy_points,
    speed_series,
)
from reports.tables import legacy_signature_rows, render_mode, round_half, summary_tables
from targets.boards import load_target
from targets.poses import plan_poses

SETTINGS = ({"spp": 4, "adaptive": True, "options": {}}, 0.01, 3e-3)
SETTINGS2 = ({"spp": 16, "adaptive": True, "options": {}}, 0.05, 1e-3)


def _records(run_dir, cameras=(15, 17), families=("CAHV", "CAHVOR")):
    cat = load_catalogue()
    target = load_target("dots")
    out = []
    for cam in cameras:
        entry = cat.get(cam)
        for fam in families:
            truth = truncate(entry.model, fam)
            poses = plan_poses(truth, target, n=6, seed=0)
            obs = exact_observations(truth, target, poses)
            res = calibrate("jpl", obs, target, fam, truth=truth, bias_correction=False)
            assert res.status == "ok", res.reason
            params, proj, themap = compare_stage(truth, res)
            for settings, t_img, noise in (SETTINGS, SETTINGS2):
                # the renderer settings differ only in their (stated) cost and error here
                name = make_fullname(str(cam), fam, "dots", "raycast", settings, "jpl", fam)
                rel = Path("maps") / (re.sub(r"[^A-Za-z0-9=.,_-]+", "_", name) + ".npy")
                (run_dir / rel).parent.mkdir(parents=True, exist_ok=True)
                np.save(run_dir / rel, downsample_map(themap + noise).astype(np.float32))
                out.append(Record(
                    fullname=name, camera=str(cam), camera_label=entry.name, model=fam,
                    target="dots", renderer="raycast", settings=settings, calibrator="jpl",
                    calibrator_model=fam, status="ok", residuals=res.residual_stats(),
                    params=params, projection=dict(proj, rms=proj["rms"] + noise),
                    seconds={"render_per_image": t_img, "render": 6 * t_img},
                    image_size=[truth.width, truth.height], artifacts={"map": str(rel)}))
    # a real failure: two points are too few for any fit
    entry = cat.get(17)
    truth = truncate(entry.model, "CAHV")
    obs = exact_observations(truth, target, plan_poses(truth, target, n=6, seed=0))
    q = np.full_like(obs.q, np.nan)
    q[0, :2] = obs.q[0, :2]
    res = calibrate("jpl", obs.replace(q=q), target, "CAHV", truth=truth)
    assert res.status == "failed"
    settings = SETTINGS[0]
    out.append(Record(
        fullname=make_fullname("17", "CAHV", "dots", "raycast", settings, "jpl", "CAHV") + "x",
        camera="17", camera_label=entry.name, model="CAHV", target="dots", renderer="raycast",
        settings=settings, calibrator="jpl", calibrator_model="CAHV", status="failed",
        stage="calibrate", reason=res.reason))
    out.append(Record(
        fullname=make_fullname("15", "CAHVORE", "dots", "raycast", settings, "jpl", "CAHVORE"),
        camera="15", camera_label="MER B navcam left", model="CAHVORE", target="dots",
        renderer="raycast", settings=settings, calibrator="jpl", calibrator_model="CAHVORE",
        status="not-applicable", stage="camera",
        reason="camera 15 is a CAHVOR; a CAHVORE cannot be derived from it"))
    return out


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("run")
    store = RunStore.create(d, {"name": "report-test"})
    for r in _records(d):
        store.save_job(r.fullname, [r])
    store.assemble(adapters={"renderers": {"raycast": "raycast test"}})
    return d


def test_compare_stage_agrees_with_harness_compare():
    from harness.compare import compare
    cat = load_catalogue()
    target = load_target("dots")
    truth = cat.get(15).model
    obs = exact_observations(truth, target, plan_poses(truth, target, n=6, seed=0))
    res = calibrate("jpl", obs, target, "CAHVOR", truth=truth, bias_correction=False)
    params, proj, themap = compare_stage(truth, res)
    ref = compare(res, truth)
    assert params == ref["parameters"]
    for mode in ref["projection"]:
        assert proj[mode] == ref["projection"][mode]
    assert proj["rms"] == ref["projection"]["rotation"]["rms"] < 1e-6
    assert themap.ndim == 2 and np.nanmax(themap) == pytest.approx(proj["max"])


def test_tables_and_speed_points(run_dir):
    from harness.records import load_run
    records = load_run(run_dir)["records"]
    # two render settings: one table each, never pooled
    t16, t4 = summary_tables(records)
    assert t4.title == "Calibrator jpl on raycast[spp=4,adaptive,coverage=area]"
    assert t16.title == "Calibrator jpl on raycast[spp=16,adaptive,coverage=area]"
    for t, noise in ((t4, 3e-3), (t16, 1e-3)):
        assert t.header[:3] == ("quantity", "unit", "paper (ROAMS)")
        rows = {r[0]: r for r in t.rows}
        assert rows["worst residual"][2] == "0.14"
        # exact correspondences: the fit is exact, residuals tiny
        assert float(rows["worst residual"][3]) < 1e-6
        assert float(rows["projection difference RMS, median"][4]) == pytest.approx(
            noise, rel=1e-3)
    assert t4.header[3:] == ("CAHV (2 ok)", "CAHVOR (2 ok)", "CAHVORE (0 ok)")
    assert t16.header[3:] == ("CAHV (2 ok)", "CAHVOR (2 ok)")
    assert "1 failed" in t4.note and "1 not-applicable" in t4.note
    assert t16.note == "4 ok"
    # the per-camera figures get one panel per calibrator and setting
    panels = calibrator_panels(records)
    assert panels == [("jpl", "family", "raycast[spp=16,adaptive,coverage=area]"),
                      ("jpl", "family", "raycast[spp=4,adaptive,coverage=area]")]
    one = {k: r for k, r in records.items() if r["settings"]["spp"] == 4}
    assert calibrator_panels(one) == [("jpl", "family", "")]
    pts = speed_accuracy_points(records)
    assert [(p[0], p[1]) for p in pts] == [("raycast[spp=16,adaptive,coverage=area]", "jpl"),
                                           ("raycast[spp=4,adaptive,coverage=area]", "jpl")]
    assert pts[0][2] == pytest.approx(0.05) and pts[1][2] == pytest.approx(0.01)
    assert pareto_front([(p[2], p[3]) for p in pts]) == [1, 0]
    # a slower and worse setting is not on the front
    assert pareto_front([(1.0, 1.0), (2.0, 2.0), (3.0, 0.5)]) == [0, 2]


def _as_apriltag(records, **fields):
    r'''Copies of dot records as AprilTag records of the same jobs, their projection RMS
0.5 px (told apart from the dots' 0.001-level values), fields set on each'''
    import copy
    tags = {}
    for k, r in records.items():
        t = copy.deepcopy(r)
        t["target"] = "apriltag"
        t["fullname"] = k.replace("/dots/", "/apriltag/")
        t["projection"]["rms"] = 0.5
        t.update(copy.deepcopy(fields))
        tags[t["fullname"]] = t
    return tags


def test_targets_get_their_own_tables_and_panels(run_dir):
    r'''dots and an AprilTag grid in one run: one table and one figure panel per
calibrator and target (the AprilTag's corners and the dots' centroids have their own
accuracy); the statistics are the target's own'''
    from harness.records import load_run
    records = {k: r for k, r in load_run(run_dir)["records"].items()
               if r["settings"]["spp"] == 16}
    both = dict(records, **_as_apriltag(records))
    tables = summary_tables(both)
    assert [t.title for t in tables] == ["Calibrator jpl on apriltag", "Calibrator jpl on dots"]
    rms = {t.title: {r[0]: r for r in t.rows}["projection difference RMS, median"]
           for t in tables}
    assert rms["Calibrator jpl on apriltag"][3:] == ("0.5", "0.5")
    assert all(float(v) < 0.01 for v in rms["Calibrator jpl on dots"][3:])
    assert calibrator_panels(both) == [("jpl", "family", "apriltag"),
                                       ("jpl", "family", "dots")]
    # one target: the titles of before
    assert [t.title for t in summary_tables(records)] == ["Calibrator jpl"]


def test_report_files(run_dir):
    paths = build_report(run_dir)
    html = Path(paths["html"]).read_text()
    md = Path(paths["markdown"]).read_text()
    names = sorted(Path(p).name for p in paths["figures"])
    for key in ("fig03_residuals", "fig04_center", "fig06_focal", "fig_theta", "fig07_C",
                "fig08_A", "fig09_O", "fig10_R_abs", "fig11_R_frac", "fig_projection",
                "speed_accuracy"):
        assert f"{key}.png" in names
    # one map figure per render setting
    assert "maps_jpl_raycast_spp_4_adaptive_coverage_area_.png" in names
    assert "maps_jpl_raycast_spp_16_adaptive_coverage_area_.png" in names
    for p in paths["figures"]:
        assert Path(p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert html.count("<img ") == len(names)
    assert html.count('src="data:image/png;base64,') == len(names)
    assert "Failures (1)" in html and "Not applicable (1)" in html
    from harness.records import load_run
    (failed,) = [r for r in load_run(run_dir)["records"].values() if r["status"] == "failed"]
    import html as htmllib
    assert failed["reason"] and htmllib.escape(failed["reason"]) in html
    assert "camera 15 is a CAHVOR" in html
    # markdown links point at PNGs that exist
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md)
    assert len(links) == len(names)
    for link in links:
        assert (Path(paths["markdown"]).parent / link).is_file()
    assert "| RMS residual, median | px | about 1/30 = 0.033 |" in md


def _chromium():
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.mark.parametrize("which", ["run_dir", "legacy_run"])
def test_html_in_headless_chromium(which, request):
    run_dir = request.getfixturevalue(which)
    exe = _chromium()
    if exe is None:
        pytest.fail("chromium is not installed; scripts/setup.sh installs the Debian package")
    paths = build_report(run_dir)
    html = Path(paths["html"])
    with tempfile.TemporaryDirectory() as profile:
        t0 = time.time()
        out = subprocess.run(
            [exe, "--headless", "--no-sandbox", "--disable-gpu",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--no-first-run", f"--user-data-dir={profile}", "--virtual-time-budget=5000",
             "--dump-dom", html.resolve().as_uri()],
            capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    dom = out.stdout
    n = len(paths["figures"])
    assert f'data-images-total="{n}"' in dom, (dom[:500], time.time() - t0)
    assert f'data-images-loaded="{n}"' in dom
    # every link is an in-page anchor that exists
    anchors = re.findall(r'href="#([^"]+)"', dom)
    ids = set(re.findall(r'id="([^"]+)"', dom))
    assert anchors and all(a in ids for a in anchors)
    assert not re.findall(r'(?:href|src)="(?!#|data:)([^"]+)"', dom)


def test_cli_report(run_dir, tmp_path):
    import sys
    root = Path(__file__).resolve().parent.parent
    out = subprocess.run([sys.executable, "-m", "camval.cli", "report", str(run_dir), "--out",
                          str(tmp_path / "rep")], capture_output=True, text=True, cwd=root,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "rep" / "report.html").is_file()
    assert "figures in" in out.stdout
    out = subprocess.run([sys.executable, "-m", "camval.cli", "report", str(tmp_path)],
                         capture_output=True, text=True, cwd=root, timeout=120)
    assert out.returncode == 2 and "not a camval run directory" in out.stderr


# ---------------------------------------------------------------------------------------------
# the legacy signature (paper Figs. 4-5) and sweeps in a run's report
LEGACY = {"spp": 16, "adaptive": True, "options": {"legacy": True}}
CLEAN = {"spp": 16, "adaptive": True, "options": {}}


def _legacy_records(cameras=(15, 17), families=("CAHV", "CAHVOR")):
    r'''jpl fits of the exact projections of the legacy model (what a perfect detector sees
in the legacy renderer's images) and of the truth, compared with the truth'''
    cat = load_catalogue()
    target = load_target("dots")
    out = []
    for cam in cameras:
        entry = cat.get(cam)
        for fam in families:
            truth = truncate(entry.model, fam)
            poses = plan_poses(truth, target, n=6, seed=0)
            for renderer, settings, model in (("faulty", LEGACY, legacy_model(truth)),
                                              ("raycast", CLEAN, truth)):
                obs = exact_observations(model, target, poses)
                res = calibrate("jpl", obs, target, fam, truth=truth, bias_correction=False)
                assert res.status == "ok", res.reason
                params, proj, _ = compare_stage(truth, res)
                name = make_fullname(str(cam), fam, "dots", renderer, settings, "jpl", fam)
                out.append(Record(
                    fullname=name, camera=str(cam), camera_label=entry.name, model=fam,
                    target="dots", renderer=renderer, settings=settings, calibrator="jpl",
                    calibrator_model=fam, status="ok", residuals=res.residual_stats(),
                    params=params, projection=proj,
                    seconds={"render_per_image": 0.02 if renderer == "faulty" else 0.05},
                    image_size=[truth.width, truth.height]))
    return out


def _sweep_doc():
    from harness.studies.sweep import breakdowns
    levels = [0.0, 30.0, 60.0]
    recs = [{"level": lv, "calibrator": "jpl", "model": "CAHVOR", "status": st,
             "detection_rate": rate, "projection_rms_px": rms, "broken": broken,
             "reason": why, "scene": {"range_m": 1.2, "tilt_deg": lv, "dot_px": 12.0}}
            for lv, st, rate, rms, broken, why in (
                (0.0, "ok", 1.0, 0.005, False, ""), (30.0, "ok", 1.0, 0.017, False, ""),
                (60.0, "failed", 0.25, None, True, "degenerate poses"))]
    return {"difficulty": "tilt", "unit": "board tilt, deg off fronto-parallel",
            "levels": levels, "level_labels": [str(v) for v in levels], "camera": "17",
            "camera_label": "Rocky8 rear hazcam left", "family": "CAHVOR", "target": "dots",
            "renderer": "raycast", "spp": 2, "n_poses": 4, "bar_px": 0.05, "seed": 0,
            "seconds": 9.0, "records": recs, "breakdown": breakdowns(recs, levels)}


@pytest.fixture(scope="module")
def legacy_run(tmp_path_factory):
    import json
    d = tmp_path_factory.mktemp("legacy")
    store = RunStore.create(d, {"name": "legacy-test"})
    for r in _legacy_records():
        store.save_job(r.fullname, [r])
    store.assemble(adapters={"renderers": {"raycast": "raycast test"}})
    (d / "sweeps").mkdir()
    (d / "sweeps" / "sweep_tilt.json").write_text(json.dumps(_sweep_doc(), allow_nan=False))
    (d / "sweeps" / "notes.json").write_text("{}")        # not a sweep: ignored
    return d


def test_render_mode():
    def rec(opts):
        return {"settings": {"spp": 1, "options": opts}}
    assert render_mode(rec({"legacy": True})) == "legacy"
    assert render_mode(rec({"legacy": ["round_centre", "theta90"]})) == "legacy"
    assert render_mode(rec({"fault": "round_centre"})) == "legacy"
    assert render_mode(rec({"legacy": ["theta90"]})) == "faulty"
    assert render_mode(rec({"fault": "half_pixel"})) == "faulty"
    assert render_mode(rec({"legacy": False, "camera": "mesh"})) == "clean"
    assert round_half(500.7484) == 500.5 and round_half(327.2050) == 327.0


def test_legacy_signature_values(legacy_run):
    from harness.records import load_run
    from reports.build import truth_resolver
    doc = load_run(legacy_run)
    rows = legacy_signature_rows(doc["records"], truth_resolver(doc, legacy_run))
    assert len(rows) == 8
    legacy = [r for r in rows if r["mode"] == "legacy"]
    clean = [r for r in rows if r["mode"] == "clean"]
    assert len(legacy) == 4 and len(clean) == 4
    for r in legacy:
        # the recovered centre is the rounded one: error = rounding residual
        for name in ("Hc", "Vc"):
            assert abs(r[f"{name}_error"] - r[f"{name}_rounding"]) < 0.01, r
            assert abs(r[f"{name}_error_vs_rounded"]) < 0.01
        assert r["Hc_true"] + r["Hc_rounding"] == pytest.approx(round_half(r["Hc_true"]))
    # MER B navcam: its centre is a quarter pixel from the half pixel in both axes
    (nav,) = [r for r in legacy if r["camera"] == "15" and r["model"] == "CAHVOR"]
    assert nav["Hc_error"] == pytest.approx(-0.2484, abs=0.01)
    assert nav["Vc_error"] == pytest.approx(0.2230, abs=0.01)
    for r in clean:
        assert abs(r["Hc_error"]) < 0.01 and abs(r["Vc_error"]) < 0.01
        assert r["Hc_error_vs_rounded"] == pytest.approx(-r["Hc_rounding"], abs=0.01)


def test_legacy_and_sweep_sections(legacy_run):
    paths = build_report(legacy_run)
    html = Path(paths["html"]).read_text()
    md = Path(paths["markdown"]).read_text()
    fig = Path(paths["figures_dir"]) / "fig04_05_legacy_signature.png"
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert str(fig) in paths["figures"]
    assert 'id="legacy"' in html and 'id="fig04_05_legacy_signature"' in html
    assert "Legacy signature (paper Figs. 4-5)" in html
    assert "![Legacy signature" in md and "figures/fig04_05_legacy_signature.png" in md
    # the table holds the numbers: MER B navcam CAHVOR, legacy, Hc rounding -0.2484
    assert "| 15 | CAHVOR | jpl | legacy (faulty) | 500.7484 | 502.7770 | -0.2484 | +0.2230 |" \
        in md
    # sweeps found in the run's sweeps/ folder: one stability chart, the breakdown table
    assert paths["sweeps"] == ["sweeps/sweep_tilt.json"]
    assert (Path(paths["figures_dir"]) / "sweep_tilt_17.png").is_file()
    assert 'id="sweeps"' in html and 'id="sweep_tilt_17"' in html
    assert "| jpl/CAHVOR | 60 | detection rate 25.0%; degenerate poses |" in md
    assert html.count("<img ") == len(paths["figures"])


def test_sweep_report_page(legacy_run, tmp_path):
    assert len(find_sweeps(legacy_run)) == 1
    paths = build_sweep_report(legacy_run, out_dir=tmp_path)
    html = Path(paths["html"]).read_text()
    assert html.count('src="data:image/png;base64,') == 1
    assert Path(paths["figures"][0]).is_file()
    md = Path(paths["markdown"]).read_text()
    assert "](sweep_figures/sweep_tilt_17.png)" in md
    from reports.build import ReportError
    with pytest.raises(ReportError, match="holds no sweep document"):
        build_sweep_report(tmp_path / "sweep_figures")


def test_speed_chart_labels_renderer_paths(legacy_run, tmp_path):
    from harness.records import load_run
    records = load_run(legacy_run)["records"]
    base = next(r for r in records.values() if r["renderer"] == "raycast")
    recs = {}
    for name, opts, adaptive in (("povray", {"camera": "perspective"}, False),
                                 ("povray", {"camera": "mesh"}, False),
                                 ("raycast", {}, True)):
        for k in (1, 4, 16):
            s = {"spp": k, "adaptive": adaptive, "options": opts}
            r = dict(base, renderer=name, settings=s, seconds={"render_per_image": 0.1 * k},
                     fullname=make_fullname("15", "CAHVOR", "dots", name, s, "jpl", "CAHVOR"))
            recs[r["fullname"]] = r
    series = speed_series(recs)
    assert sorted(set(series.values())) == sorted(
        [(n, k) for n in ("povray (full) camera=mesh", "povray (full) camera=perspective",
                          "raycast coverage=area") for k in (1, 4, 16)])
    assert len(speed_accuracy_points(recs)) == 9
    assert Path(fig_speed(recs, tmp_path).path).is_file()


@pytest.mark.slow
def test_legacy_renderer_campaign_signature(tmp_path):
    r'''The legacy renderer itself (ray caster rendering the ROAMS model) through a campaign:
detection, jpl calibration; the report's rows put the recovered centre on the half pixel'''
    from harness.campaign import parse_campaign
    from harness.records import load_run
    from harness.runner import run_campaign
    from reports.build import truth_resolver
    doc = {"name": "legacy-mini", "cameras": [17], "models": ["CAHV"], "targets": ["dots"],
           "poses": {"n": 6, "seed": 0},
           "renderer": [{"name": "faulty", "spp": 8, "options": {"legacy": True}},
                        {"name": "raycast", "spp": 8}],
           "calibrator": [{"name": "jpl"}]}
    run_campaign(parse_campaign(doc), tmp_path / "run", progress=False, workers=1)
    run = load_run(tmp_path / "run")
    rows = legacy_signature_rows(run["records"], truth_resolver(run, tmp_path / "run"))
    (leg,) = [r for r in rows if r["mode"] == "legacy"]
    (cln,) = [r for r in rows if r["mode"] == "clean"]
    # Rocky8 rear hazcam: true centre (327.205, 249.656) -> rounded (327.0, 249.5)
    assert leg["Hc_rounding"] == pytest.approx(-0.2050, abs=1e-3)
    assert abs(leg["Hc_error"] - leg["Hc_rounding"]) < 0.01
    assert abs(leg["Vc_error"] - leg["Vc_rounding"]) < 0.01
    assert abs(cln["Hc_error"]) < 0.01 and abs(cln["Vc_error"]) < 0.01
    paths = build_report(tmp_path / "run")
    assert Path(paths["figures_dir"], "fig04_05_legacy_signature.png").is_file()
    assert 'id="fig04_05_legacy_signature"' in Path(paths["html"]).read_text()


def test_legacy_campaign_file():
    from harness.campaign import load_campaign
    c = load_campaign(Path(__file__).resolve().parent.parent / "campaigns" / "legacy.toml")
    c.validate()
    modes = sorted(render_mode({"settings": s}) for r in c.renderers for s in r.settings())
    assert modes == ["clean", "legacy"]
    assert [r.name for r in c.renderers] == ["raycast", "faulty"]
    assert [cal.name for cal in c.calibrators] == ["jpl"]


def test_targets_side_by_side_table_and_figure(run_dir, tmp_path):
    r'''A calibrator that fitted dots and an AprilTag grid gets one table with its targets
side by side under each family, the renderer verdict's rows first, and one figure'''
    from harness.records import load_run
    from reports.figures import fig_targets
    from reports.tables import target_tables
    records = {k: r for k, r in load_run(run_dir)["records"].items()
               if r["settings"]["spp"] == 16}
    assert target_tables(records) == [] and fig_targets(records, tmp_path) is None
    verdict = {"renderer": {"projection": {"rms": 0.0},
                            "z": {"projection_rms": 0.0, "Hc": 2.5}}}
    tags = _as_apriltag(records, verdict=verdict)
    both = dict(records, **tags)
    (table,) = target_tables(both)
    assert table.title == "jpl: dots and apriltag side by side"
    ok = {f: sum(r["status"] == "ok" and r["model"] == f for r in records.values())
          for f in ("CAHV", "CAHVOR")}
    assert table.header == ("quantity", "unit", f"CAHV dots ({ok['CAHV']} ok)",
                            f"CAHV apriltag ({ok['CAHV']} ok)",
                            f"CAHVOR dots ({ok['CAHVOR']} ok)",
                            f"CAHVOR apriltag ({ok['CAHVOR']} ok)")
    rows = {r[0]: r for r in table.rows}
    # the verdict first
    assert table.rows[0][0].startswith("renderer:")
    assert rows["total: projection difference RMS, median"][3::2] == ("0.5", "0.5")
    assert all(float(v) < 0.01 for v in rows["total: projection difference RMS, median"][2::2])
    assert rows["renderer: image fit vs exact fit, projection RMS, worst"][3::2] == ("0", "0")
    assert rows["renderer: projection RMS / its sigma, worst"][3::2] == ("0", "0")
    # a family the AprilTag grid was not run under ([target_models]) has no column
    cahv_tags = {k for k, r in tags.items() if r["model"] == "CAHV"}
    (table,) = target_tables({k: r for k, r in both.items() if k not in cahv_tags})
    assert table.header[2:4] == (f"CAHV dots ({ok['CAHV']} ok)",
                                 f"CAHVOR dots ({ok['CAHVOR']} ok)")
    fig = fig_targets(both, tmp_path)
    assert fig.key == "fig_targets" and Path(fig.path).read_bytes()[:4] == b"\x89PNG"
    assert "gate fails above 6" in fig.caption


@pytest.mark.parametrize("workers", [2, 3])
def test_figure_workers_draw_the_same_figures(run_dir, tmp_path, workers):
    r'''Processes sharing the figures (make_figures(workers=2 or 3)) give the figures, order,
captions and pixels of one process: the same matplotlib draws the same canvas in any
process of this machine'''
    from PIL import Image

    from harness.records import load_run
    from reports.figures import make_figures
    records = load_run(run_dir)["records"]
    one = make_figures(records, run_dir, tmp_path / "one", workers=1)
    two = make_figures(records, run_dir, tmp_path / "two", workers=workers)
    assert [(f.key, f.title, f.caption) for f in one] == [(f.key, f.title, f.caption)
                                                          for f in two]
    assert len(one) == 13   # 10 per-camera figures, 2 map figures, speed versus accuracy
    for a, b in zip(one, two, strict=True):
        assert Path(b.path).parent == tmp_path / "two"
        with Image.open(a.path) as ia, Image.open(b.path) as ib:
            assert np.array_equal(np.asarray(ia.convert("RGB")), np.asarray(ib.convert("RGB")))

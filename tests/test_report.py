r'''The report: figures, tables and a self-contained HTML page checked in headless Chromium

The records are real: exact correspondences (projected dot centres of the
planned poses) recalibrated by the jpl calibrator and compared with the truth
by the runner's own compare stage, plus a genuinely failing calibration (too
few points) and a not-applicable record.
'''

import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from harness.calibrators import calibrate
from harness.calibrators.synthetic import exact_observations
from harness.records import Record, RunStore, make_fullname
from harness.runner import _downsample, compare_stage
from reference_models.cahvore import truncate
from reference_models.catalogue import load_catalogue
from reports.build import build_report
from reports.figures import pareto_front, speed_accuracy_points
from reports.tables import summary_tables
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
                np.save(run_dir / rel, _downsample(themap + noise).astype(np.float32))
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
    (t,) = summary_tables(records)
    assert t.title == "Calibrator jpl"
    assert t.header[:3] == ("quantity", "unit", "paper (ROAMS)")
    assert t.header[3:] == ("CAHV (4 ok)", "CAHVOR (4 ok)", "CAHVORE (0 ok)")
    rows = {r[0]: r for r in t.rows}
    assert rows["worst residual"][2] == "0.14"
    # exact correspondences: the fit is exact, residuals tiny
    assert float(rows["worst residual"][3]) < 1e-6
    assert float(rows["projection difference RMS, median"][4]) == pytest.approx(
        (3e-3 + 1e-3) / 2, rel=1e-3)
    assert "1 failed" in t.note and "1 not-applicable" in t.note
    pts = speed_accuracy_points(records)
    assert [(p[0], p[1]) for p in pts] == [("raycast[spp=16,adaptive]", "jpl"),
                                           ("raycast[spp=4,adaptive]", "jpl")]
    assert pts[0][2] == pytest.approx(0.05) and pts[1][2] == pytest.approx(0.01)
    assert pareto_front([(p[2], p[3]) for p in pts]) == [1, 0]
    # a slower and worse setting is not on the front
    assert pareto_front([(1.0, 1.0), (2.0, 2.0), (3.0, 0.5)]) == [0, 2]


def test_report_files(run_dir):
    paths = build_report(run_dir)
    html = Path(paths["html"]).read_text()
    md = Path(paths["markdown"]).read_text()
    names = sorted(Path(p).name for p in paths["figures"])
    for key in ("fig03_residuals", "fig04_center", "fig06_focal", "fig_theta", "fig07_C",
                "fig08_A", "fig09_O", "fig10_R_abs", "fig11_R_frac", "fig_projection",
                "maps_jpl", "speed_accuracy"):
        assert f"{key}.png" in names
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


def test_html_in_headless_chromium(run_dir):
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
    out = subprocess.run([sys.executable, "-m", "harness.cli", "report", str(run_dir), "--out",
                          str(tmp_path / "rep")], capture_output=True, text=True, cwd=root,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "rep" / "report.html").is_file()
    assert "figures in" in out.stdout
    out = subprocess.run([sys.executable, "-m", "harness.cli", "report", str(tmp_path)],
                         capture_output=True, text=True, cwd=root, timeout=120)
    assert out.returncode == 2 and "not a camval run directory" in out.stderr
